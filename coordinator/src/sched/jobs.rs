//! A job in memory: its settings, its task layout, its tasks and its life, and how it maps to
//! and from a store row.

use super::order::{TaskLayout, TaskWork};
use super::state::{transition, JobEvent, JobLife, Outcome, Task, TaskEvent, TaskState};
use crate::store::{JobRow, StoredTask, TaskRow};
use raytile_core::RenderSettings;
use std::collections::HashMap;
use std::sync::Arc;
use tokio::time::Instant;

/// A job in memory.
#[derive(Clone, Debug)]
pub(super) struct Job {
    /// Id.
    pub id: String,
    /// Submission order (FIFO among equal priorities).
    pub seq: u64,
    /// Scene id.
    pub scene: String,
    /// Settings.
    pub settings: RenderSettings,
    /// Priority: higher first.
    pub priority: i32,
    /// The renderer version that made every stored tile, where known (see
    /// [`JobRow::render_version`]).
    pub render_version: Option<u32>,
    /// State, error and times; changed only through [`Job::apply`].
    life: JobLife,
    /// Task index → tile and pass (shared with image composition, outside the lock).
    pub layout: Arc<TaskLayout>,
    /// Tasks in layout order; changed only through [`Job::set_task`] and [`Job::renew`].
    tasks: Vec<Task>,
    /// How many tasks are done.
    done: usize,
    /// Changes of the set of done tasks in this process: with the coordinator's epoch it
    /// names one state of the job's stored results (an image's validator).
    results_changes: u64,
    /// Done passes of each tile, by position in the layout's tile order (task `i` is position
    /// `i % tiles`): the progress events are counted from these, not from every task.
    tile_passes: Vec<u32>,
    /// Tiles with every pass done.
    tiles_full: usize,
    /// Done tasks of each pass.
    pass_tasks_done: Vec<u32>,
    /// Lowest task index that may be queued: everything before it is leased or finished.
    cursor: usize,
    /// Failures per worker (a worker with enough is blocked from the job).
    pub worker_failures: HashMap<String, u32>,
    /// The last task failures reported, newest last (memory only).
    pub recent_failures: std::collections::VecDeque<raytile_proto::TaskFailure>,
}

impl Job {
    /// A job just submitted, every task queued. `layout` is `TaskLayout::new(&settings)`,
    /// made by the caller (outside the scheduler's lock: it is the costly part).
    pub fn new(
        id: String,
        seq: u64,
        scene: String,
        settings: RenderSettings,
        priority: i32,
        now_ms: u64,
        layout: Arc<TaskLayout>,
    ) -> Job {
        let tasks = vec![Task::queued(); layout.task_count()];
        let (tiles, passes) = (layout.tile_count(), layout.pass_count());
        Job {
            tile_passes: vec![0; tiles],
            tiles_full: 0,
            pass_tasks_done: vec![0; passes],
            id,
            seq,
            scene,
            settings,
            priority,
            render_version: Some(raytile_core::RENDER_VERSION),
            life: JobLife::queued(now_ms),
            layout,
            tasks,
            done: 0,
            results_changes: 0,
            cursor: 0,
            worker_failures: HashMap::new(),
            recent_failures: Default::default(),
        }
    }

    /// A job as stored. Task rows beyond the layout are ignored; leases that were out get
    /// `deadline`, their lease ids are returned with the task index.
    pub fn restore(
        row: JobRow,
        settings: RenderSettings,
        task_rows: Vec<TaskRow>,
        worker_failures: HashMap<String, u32>,
        deadline: Instant,
    ) -> (Job, Vec<(String, usize)>) {
        let layout = Arc::new(TaskLayout::new(&settings));
        let mut job = Job::new(
            row.id,
            row.seq,
            row.scene,
            settings,
            row.priority,
            0,
            layout,
        );
        job.life = JobLife {
            state: row.state,
            error: row.error,
            created_ms: row.created_ms,
            started_ms: row.started_ms,
            finished_ms: row.finished_ms,
        };
        job.render_version = row.render_version;
        job.worker_failures = worker_failures;
        let mut leases = Vec::new();
        for tr in task_rows {
            let Some(t) = job.tasks.get_mut(tr.idx as usize) else {
                continue;
            };
            t.failures = tr.failures;
            t.state = match tr.state {
                StoredTask::Queued => TaskState::Queued,
                StoredTask::Failed => TaskState::Failed,
                StoredTask::Done { worker } => {
                    job.done += 1;
                    TaskState::Done { worker }
                }
                StoredTask::Leased { worker, lease } => {
                    leases.push((lease.clone(), tr.idx as usize));
                    TaskState::Leased {
                        worker,
                        lease,
                        deadline,
                    }
                }
            };
        }
        let done: Vec<usize> = (0..job.tasks.len())
            .filter(|&i| matches!(job.tasks[i].state, TaskState::Done { .. }))
            .collect();
        for i in done {
            job.count_done(i, 1);
        }
        (job, leases)
    }

    /// The job's row in the store.
    pub fn row(&self) -> JobRow {
        JobRow {
            id: self.id.clone(),
            seq: self.seq,
            scene: self.scene.clone(),
            settings: serde_json::to_string(&self.settings).unwrap_or_default(),
            priority: self.priority,
            state: self.life.state,
            error: self.life.error.clone(),
            created_ms: self.life.created_ms,
            started_ms: self.life.started_ms,
            finished_ms: self.life.finished_ms,
            render_version: self.render_version,
        }
    }

    /// The store row of task `idx` in state `t` (the lease deadline is not stored).
    pub fn task_row(idx: usize, t: &Task) -> TaskRow {
        let state = match &t.state {
            TaskState::Queued => StoredTask::Queued,
            TaskState::Leased { worker, lease, .. } => StoredTask::Leased {
                worker: worker.clone(),
                lease: lease.clone(),
            },
            TaskState::Done { worker } => StoredTask::Done {
                worker: worker.clone(),
            },
            TaskState::Failed => StoredTask::Failed,
        };
        TaskRow {
            idx: idx as u32,
            state,
            failures: t.failures,
        }
    }

    /// State, error and times.
    pub fn life(&self) -> &JobLife {
        &self.life
    }

    /// Whether the job has ended (see [`JobState::is_final`](raytile_proto::JobState::is_final)).
    pub fn is_final(&self) -> bool {
        self.life.state.is_final()
    }

    /// What the job's life would become on `ev` at `now_ms`, or `None` if `ev` changes
    /// nothing. The job itself is unchanged until [`Job::set_life`].
    pub fn next_life(&self, ev: JobEvent, now_ms: u64) -> Option<JobLife> {
        let mut life = self.life.clone();
        life.apply(ev, now_ms).then_some(life)
    }

    /// Puts a life from [`Job::next_life`] in place, once the store has it.
    pub fn set_life(&mut self, life: JobLife) {
        self.life = life;
    }

    /// The tasks, in layout order.
    pub fn tasks(&self) -> &[Task] {
        &self.tasks
    }

    /// What task `idx` renders, or `None` if the job has no such task.
    pub fn work(&self, idx: usize) -> Option<TaskWork> {
        self.layout.task(idx)
    }

    /// What task `idx` would become on `ev` (the task state machine's answer and the new
    /// task). The job is unchanged until [`Job::set_task`]: the caller stores the new state
    /// first.
    pub fn next_task(&self, idx: usize, ev: TaskEvent) -> (Outcome, Task) {
        let mut t = self.tasks[idx].clone();
        let out = transition(&mut t, ev);
        (out, t)
    }

    /// Puts a task from [`Job::next_task`] in place, once the store has it. A task queued
    /// again moves the cursor back so the next lease finds it first.
    pub fn set_task(&mut self, idx: usize, t: Task) {
        let was_done = matches!(self.tasks[idx].state, TaskState::Done { .. });
        let is_done = matches!(t.state, TaskState::Done { .. });
        self.done = self.done + usize::from(is_done) - usize::from(was_done);
        if is_done != was_done {
            self.count_done(idx, if is_done { 1 } else { -1 });
            self.results_changes += 1;
        }
        if t.state == TaskState::Queued {
            self.cursor = self.cursor.min(idx);
        }
        self.tasks[idx] = t;
    }

    /// Counts task `idx` as newly done (`delta` 1) or no longer done (-1).
    fn count_done(&mut self, idx: usize, delta: i32) {
        let n = self.layout.tile_count().max(1);
        let passes = self.layout.pass_count() as u32;
        let (k, p) = (idx % n, idx / n);
        let was_full = self.tile_passes[k] == passes;
        self.tile_passes[k] = self.tile_passes[k].saturating_add_signed(delta);
        self.pass_tasks_done[p] = self.pass_tasks_done[p].saturating_add_signed(delta);
        let is_full = self.tile_passes[k] == passes;
        self.tiles_full = self.tiles_full + usize::from(is_full) - usize::from(was_full);
    }

    /// Tiles with every pass done, and passes done for every tile (as [`Job::status`] counts
    /// them), from counters: no walk over the tasks.
    pub fn progress(&self) -> (u64, u32) {
        let n = self.layout.tile_count() as u32;
        let passes = self.pass_tasks_done.iter().take_while(|&&d| d == n).count();
        (self.tiles_full as u64, passes as u32)
    }

    /// Done tasks.
    pub fn tasks_done(&self) -> usize {
        self.done
    }

    /// How often the set of done tasks changed since this process restored or created the
    /// job: the same count, the same stored results.
    pub fn results_changes(&self) -> u64 {
        self.results_changes
    }

    /// Renews the lease of task `idx`: the deadline lives in memory only (after a restart
    /// every lease gets the grace period), so nothing is stored. Whether it applied.
    pub fn renew(&mut self, idx: usize, ev: TaskEvent) -> bool {
        debug_assert!(matches!(ev, TaskEvent::Renew { .. }));
        transition(&mut self.tasks[idx], ev) == Outcome::Changed
    }

    /// The first queued task in layout order that `take` accepts, if any. (The cursor stays at
    /// the first queued task, whether taken or not.)
    pub fn next_queued(&mut self, take: impl Fn(&Task) -> bool) -> Option<usize> {
        let first = self.tasks[self.cursor..]
            .iter()
            .position(|t| t.state == TaskState::Queued)
            .map(|i| self.cursor + i);
        self.cursor = first.unwrap_or(self.tasks.len());
        let first = first?;
        self.tasks[first..]
            .iter()
            .position(|t| t.state == TaskState::Queued && take(t))
            .map(|i| first + i)
    }

    /// Whether every task but `idx` is done (so that `idx` done finishes the job).
    pub fn all_done_but(&self, idx: usize) -> bool {
        let own = usize::from(matches!(self.tasks[idx].state, TaskState::Done { .. }));
        self.done - own + 1 == self.tasks.len()
    }

    /// The worker holding task `idx` and its lease id, while the task is leased.
    pub fn lease_of(&self, idx: usize) -> Option<(&str, &str)> {
        match &self.tasks[idx].state {
            TaskState::Leased { worker, lease, .. } => Some((worker, lease)),
            _ => None,
        }
    }

    /// Failures of `worker` on this job.
    pub fn failures_of(&self, worker: &str) -> u32 {
        self.worker_failures.get(worker).copied().unwrap_or(0)
    }
}
