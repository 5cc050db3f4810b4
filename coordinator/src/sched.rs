//! The scheduler: jobs, their tasks (one per tile and pass), leases, and the one state machine
//! every task change goes through ([`transition`]).
//!
//! Time is always passed in (`now: Instant`, tokio's clock), so tests drive it; wall-clock
//! milliseconds are used only for the times shown to users.

use crate::store::{JobRow, Store, TaskRow};
use raytile_core::{RenderSettings, Tile, TileAccum};
use raytile_proto::{JobState, JobStatus, WorkerShare};
use std::collections::{BTreeMap, HashMap, VecDeque};
use std::time::{Duration, SystemTime, UNIX_EPOCH};
use tokio::time::Instant;

/// Milliseconds since the Unix epoch, for display.
pub fn wall_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_millis() as u64)
        .unwrap_or(0)
}

/// Scheduling knobs.
#[derive(Clone, Debug)]
pub struct SchedConfig {
    /// Lease lifetime without a heartbeat.
    pub lease_timeout: Duration,
    /// Failures of one task that fail the job.
    pub max_task_failures: u32,
    /// Failures of one worker on one job after which it gets no more of the job's tasks.
    pub block_worker_after: u32,
}

/// State of one task (one tile, one pass).
#[derive(Clone, Debug, PartialEq)]
pub enum TaskState {
    /// Waiting for a worker.
    Queued,
    /// Out with a worker until `deadline` unless renewed.
    Leased {
        /// Worker id.
        worker: String,
        /// Lease id.
        lease: String,
        /// Expiry.
        deadline: Instant,
    },
    /// Result stored.
    Done {
        /// Who delivered it.
        worker: String,
    },
    /// Failed too often; the job failed with it.
    Failed,
}

/// One tile pass of a job.
#[derive(Clone, Debug)]
pub struct Task {
    /// Index into the job's tiles.
    pub tile: u32,
    /// Pass index.
    pub pass: u32,
    /// State.
    pub state: TaskState,
    /// Failures reported so far.
    pub failures: u32,
}

/// Something that happens to a task.
#[derive(Clone, Debug)]
pub enum TaskEvent {
    /// A worker takes the task.
    Lease {
        /// Worker id.
        worker: String,
        /// New lease id.
        lease: String,
        /// Expiry.
        deadline: Instant,
    },
    /// The worker holding `lease` is still at it.
    Renew {
        /// Lease id.
        lease: String,
        /// New expiry.
        deadline: Instant,
    },
    /// A result arrived (from the lease holder, or late from an expired lease: results are
    /// deterministic, so any valid one is as good).
    Complete {
        /// Worker that delivered.
        worker: String,
    },
    /// The lease holder reports failure.
    Fail {
        /// Lease id.
        lease: String,
        /// Whether this failure is the last allowed.
        fatal: bool,
    },
    /// The lease holder hands the task back unrendered (shutting down).
    Release {
        /// Lease id.
        lease: String,
    },
    /// The lease ran out at `now`.
    Expire {
        /// The clock.
        now: Instant,
    },
}

/// What a [`transition`] did.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// The state changed.
    Changed,
    /// The task was already done: nothing changed (duplicate or late result).
    AlreadyDone,
    /// The event does not apply to the current state (stale lease, not expired yet...).
    Ignored,
}

/// The task state machine: every change of a task's state goes through here.
pub fn transition(task: &mut Task, ev: TaskEvent) -> Outcome {
    use TaskState::*;
    let next = match (&task.state, ev) {
        (Done { .. }, TaskEvent::Complete { .. }) => return Outcome::AlreadyDone,
        (Done { .. } | Failed, _) => return Outcome::Ignored,
        (_, TaskEvent::Complete { worker }) => Done { worker },
        (
            Queued,
            TaskEvent::Lease {
                worker,
                lease,
                deadline,
            },
        ) => Leased {
            worker,
            lease,
            deadline,
        },
        (Leased { worker, lease, .. }, TaskEvent::Renew { lease: l, deadline }) if *lease == l => {
            Leased {
                worker: worker.clone(),
                lease: l,
                deadline,
            }
        }
        (Leased { lease, .. }, TaskEvent::Fail { lease: l, fatal }) if *lease == l => {
            task.failures += 1;
            if fatal {
                Failed
            } else {
                Queued
            }
        }
        (Leased { lease, .. }, TaskEvent::Release { lease: l }) if *lease == l => Queued,
        (Leased { deadline, .. }, TaskEvent::Expire { now }) if *deadline <= now => Queued,
        _ => return Outcome::Ignored,
    };
    task.state = next;
    Outcome::Changed
}

/// A job in memory.
#[derive(Clone, Debug)]
pub struct Job {
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
    /// State.
    pub state: JobState,
    /// Failure message.
    pub error: Option<String>,
    /// Times for display.
    pub created_ms: u64,
    /// First lease.
    pub started_ms: Option<u64>,
    /// End.
    pub finished_ms: Option<u64>,
    /// Tiles in `RenderSettings::tiles` order.
    pub tiles: Vec<Tile>,
    /// Sample ranges of the passes.
    pub passes: Vec<std::ops::Range<u32>>,
    /// Tasks: pass-major, tiles centre-out within a pass.
    pub tasks: Vec<Task>,
    /// Lowest task index that may be queued.
    cursor: usize,
    /// Failures per worker.
    pub worker_failures: HashMap<String, u32>,
}

impl Job {
    fn status_name(&self) -> &'static str {
        self.state.name()
    }

    fn row(&self) -> JobRow {
        JobRow {
            id: self.id.clone(),
            seq: self.seq,
            scene: self.scene.clone(),
            settings: serde_json::to_string(&self.settings).unwrap_or_default(),
            priority: self.priority,
            state: self.status_name().into(),
            error: self.error.clone(),
            created_ms: self.created_ms,
            started_ms: self.started_ms,
            finished_ms: self.finished_ms,
        }
    }

    /// The tile and sample range of task `idx`.
    pub fn task_work(&self, idx: usize) -> (Tile, u32, std::ops::Range<u32>) {
        let t = &self.tasks[idx];
        (
            self.tiles[t.tile as usize],
            t.pass,
            self.passes[t.pass as usize].clone(),
        )
    }

    /// Index of the task for (tile index, pass).
    pub fn tasks_per_pass(&self) -> usize {
        self.tiles.len()
    }

    /// The job as the API shows it.
    pub fn status(&self) -> JobStatus {
        let mut workers: BTreeMap<String, WorkerShare> = BTreeMap::new();
        let (mut done, mut leased, mut samples_done, mut samples_total) = (0u64, 0u64, 0u64, 0u64);
        let ntiles = self.tiles.len();
        let mut tile_passes_done = vec![0u32; ntiles];
        for t in &self.tasks {
            let px = self.tiles[t.tile as usize].pixel_count() as u64;
            let r = &self.passes[t.pass as usize];
            let s = px * u64::from(r.end - r.start);
            samples_total += s;
            match &t.state {
                TaskState::Done { worker } => {
                    done += 1;
                    samples_done += s;
                    tile_passes_done[t.tile as usize] += 1;
                    let w = workers.entry(worker.clone()).or_default();
                    w.tasks += 1;
                    w.samples += s;
                }
                TaskState::Leased { .. } => leased += 1,
                _ => {}
            }
        }
        let npasses = self.passes.len() as u32;
        let mut passes_done = 0;
        for p in 0..npasses as usize {
            if self.tasks[p * ntiles..(p + 1) * ntiles]
                .iter()
                .all(|t| matches!(t.state, TaskState::Done { .. }))
            {
                passes_done += 1;
            } else {
                break;
            }
        }
        JobStatus {
            id: self.id.clone(),
            scene: self.scene.clone(),
            state: self.state,
            priority: self.priority,
            settings: self.settings.clone(),
            tiles_total: ntiles as u64,
            tiles_done: tile_passes_done.iter().filter(|&&n| n == npasses).count() as u64,
            passes: npasses,
            passes_done,
            tasks_total: self.tasks.len() as u64,
            tasks_done: done,
            tasks_leased: leased,
            samples_done,
            samples_total,
            workers,
            created_ms: self.created_ms,
            started_ms: self.started_ms,
            finished_ms: self.finished_ms,
            error: self.error.clone(),
        }
    }
}

/// Tiles ordered centre-out: by distance of the tile centre from the image centre, ties by
/// row order, so the interesting middle of the frame appears first.
pub fn centre_out(settings: &RenderSettings, tiles: &[Tile]) -> Vec<u32> {
    let (cx, cy) = (settings.width as f64 / 2.0, settings.height as f64 / 2.0);
    let mut order: Vec<u32> = (0..tiles.len() as u32).collect();
    let d = |t: &Tile| {
        let x = (t.x0 + t.x1) as f64 / 2.0 - cx;
        let y = (t.y0 + t.y1) as f64 / 2.0 - cy;
        x * x + y * y
    };
    order.sort_by(|&a, &b| {
        d(&tiles[a as usize])
            .total_cmp(&d(&tiles[b as usize]))
            .then(a.cmp(&b))
    });
    order
}

fn build_tasks(settings: &RenderSettings) -> (Vec<Tile>, Vec<std::ops::Range<u32>>, Vec<Task>) {
    let tiles = settings.tiles();
    let passes = settings.pass_ranges();
    let order = centre_out(settings, &tiles);
    let mut tasks = Vec::with_capacity(tiles.len() * passes.len());
    for p in 0..passes.len() as u32 {
        for &t in &order {
            tasks.push(Task {
                tile: t,
                pass: p,
                state: TaskState::Queued,
                failures: 0,
            });
        }
    }
    (tiles, passes, tasks)
}

/// A registered worker.
#[derive(Clone, Debug)]
pub struct WorkerRec {
    /// Name.
    pub name: String,
    /// Threads.
    pub threads: u32,
    /// Registration time.
    pub registered_ms: u64,
    /// Last contact.
    pub last_seen_ms: u64,
    /// Tasks delivered.
    pub tasks_done: u64,
    /// Failures reported.
    pub failures: u64,
}

/// Counters for `/metrics`.
#[derive(Clone, Debug, Default)]
pub struct Counters {
    /// Leases granted.
    pub leased: u64,
    /// Results accepted.
    pub done: u64,
    /// Leases expired.
    pub expired: u64,
    /// Failures reported.
    pub failed: u64,
    /// Duplicate or late results ignored.
    pub duplicates: u64,
    /// Samples accepted.
    pub samples: u64,
}

/// What a result upload did.
#[derive(Debug, PartialEq, Eq)]
pub enum ResultOutcome {
    /// Stored.
    Accepted,
    /// The task was already done.
    Duplicate,
    /// The job is over (cancelled or failed).
    JobFinished,
}

/// Errors of scheduler operations that the API turns into 4xx/5xx.
#[derive(Debug, thiserror::Error)]
pub enum SchedError {
    /// No such job.
    #[error("no job '{0}'")]
    NoJob(String),
    /// No such task.
    #[error("job '{0}' has no task {1}")]
    NoTask(String, u32),
    /// No such worker.
    #[error("no worker '{0}'")]
    NoWorker(String),
    /// The result is for other pixels or another pass than the task.
    #[error("{0}")]
    Mismatch(String),
    /// The store failed.
    #[error("store: {0}")]
    Store(#[from] rusqlite::Error),
}

/// Everything the scheduler knows, behind one lock in the app state.
pub struct Sched {
    cfg: SchedConfig,
    store: Store,
    /// Jobs by id.
    pub jobs: HashMap<String, Job>,
    /// Workers by id.
    pub workers: HashMap<String, WorkerRec>,
    /// Lease id → (job id, task index).
    leases: HashMap<String, (String, usize)>,
    next_seq: u64,
    ids: u64,
    /// Metrics counters.
    pub counters: Counters,
    /// Recent (time, samples) for the samples-per-second gauge.
    recent: VecDeque<(Instant, u64)>,
    /// When this coordinator started (wall ms): restored workers count as live from then on
    /// until they have had time to call in.
    pub(crate) started_ms: u64,
}

/// Whether every live worker is blocked from a job (and at least one is live). Live: seen,
/// or restored at start-up, within three lease timeouts (at least a minute).
fn all_live_blocked(
    workers: &HashMap<String, WorkerRec>,
    failures: &HashMap<String, u32>,
    cfg: &SchedConfig,
    started_ms: u64,
) -> bool {
    let live_ms = (3 * cfg.lease_timeout.as_millis() as u64).max(60_000);
    let now_ms = wall_ms();
    let mut live = workers
        .iter()
        .filter(|(_, w)| now_ms.saturating_sub(w.last_seen_ms.max(started_ms)) <= live_ms)
        .peekable();
    live.peek().is_some()
        && live.all(|(id, _)| failures.get(id).copied().unwrap_or(0) >= cfg.block_worker_after)
}

fn task_row(idx: usize, t: &Task) -> TaskRow {
    let (state, worker, lease) = match &t.state {
        TaskState::Queued => ("queued", None, None),
        TaskState::Leased { worker, lease, .. } => {
            ("leased", Some(worker.clone()), Some(lease.clone()))
        }
        TaskState::Done { worker } => ("done", Some(worker.clone()), None),
        TaskState::Failed => ("failed", None, None),
    };
    TaskRow {
        idx: idx as u32,
        state: state.into(),
        failures: t.failures,
        worker,
        lease,
    }
}

impl Sched {
    /// Opens the scheduler over `store`, restoring every job. Leases that were out get
    /// `grace` from `now` for their workers to report back.
    pub fn restore(
        cfg: SchedConfig,
        store: Store,
        now: Instant,
        grace: Duration,
    ) -> Result<Sched, SchedError> {
        let mut s = Sched {
            cfg,
            store,
            jobs: HashMap::new(),
            workers: HashMap::new(),
            leases: HashMap::new(),
            next_seq: 1,
            ids: 0,
            counters: Counters::default(),
            recent: VecDeque::new(),
            started_ms: wall_ms(),
        };
        for (id, name, threads, registered_ms) in s.store.workers()? {
            s.workers.insert(
                id,
                WorkerRec {
                    name,
                    threads,
                    registered_ms,
                    last_seen_ms: registered_ms,
                    tasks_done: 0,
                    failures: 0,
                },
            );
        }
        for row in s.store.jobs()? {
            s.next_seq = s.next_seq.max(row.seq + 1);
            let Ok(settings) = serde_json::from_str::<RenderSettings>(&row.settings) else {
                tracing::error!(job = %row.id, "stored settings unreadable; skipping job");
                continue;
            };
            let (tiles, passes, mut tasks) = build_tasks(&settings);
            for tr in s.store.tasks(&row.id)? {
                let Some(t) = tasks.get_mut(tr.idx as usize) else {
                    continue;
                };
                t.failures = tr.failures;
                t.state = match tr.state.as_str() {
                    "done" => TaskState::Done {
                        worker: tr.worker.unwrap_or_default(),
                    },
                    "failed" => TaskState::Failed,
                    "leased" => match (tr.worker, tr.lease) {
                        (Some(worker), Some(lease)) => {
                            s.leases
                                .insert(lease.clone(), (row.id.clone(), tr.idx as usize));
                            TaskState::Leased {
                                worker,
                                lease,
                                deadline: now + grace,
                            }
                        }
                        _ => TaskState::Queued,
                    },
                    _ => TaskState::Queued,
                };
            }
            let worker_failures = s.store.blocked(&row.id)?.into_iter().collect();
            let job = Job {
                id: row.id.clone(),
                seq: row.seq,
                scene: row.scene,
                settings,
                priority: row.priority,
                state: JobState::from_name(&row.state).unwrap_or(JobState::Queued),
                error: row.error,
                created_ms: row.created_ms,
                started_ms: row.started_ms,
                finished_ms: row.finished_ms,
                tiles,
                passes,
                tasks,
                cursor: 0,
                worker_failures,
            };
            s.jobs.insert(row.id, job);
        }
        Ok(s)
    }

    /// The store, for reads that need it (image composition opens its own reader).
    pub fn store(&self) -> &Store {
        &self.store
    }

    fn new_id(&mut self, prefix: &str) -> String {
        self.ids += 1;
        let nanos = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map(|d| d.as_nanos() as u64)
            .unwrap_or(0);
        // Unique within this process by the counter, and across restarts by the clock.
        format!("{prefix}{:x}{:04x}", nanos, self.ids & 0xffff)
    }

    /// Jobs not yet final.
    pub fn unfinished_jobs(&self) -> usize {
        self.jobs.values().filter(|j| !j.state.is_final()).count()
    }

    /// Creates a job; `settings` must be valid.
    pub fn create_job(
        &mut self,
        scene: String,
        settings: RenderSettings,
        priority: i32,
    ) -> Result<JobStatus, SchedError> {
        let seq = self.next_seq;
        self.next_seq += 1;
        let id = format!("job-{seq}-{}", &self.new_id("")[8..]);
        let (tiles, passes, tasks) = build_tasks(&settings);
        let job = Job {
            id: id.clone(),
            seq,
            scene,
            settings,
            priority,
            state: JobState::Queued,
            error: None,
            created_ms: wall_ms(),
            started_ms: None,
            finished_ms: None,
            tiles,
            passes,
            tasks,
            cursor: 0,
            worker_failures: HashMap::new(),
        };
        self.store.insert_job(&job.row(), job.tasks.len() as u32)?;
        let status = job.status();
        self.jobs.insert(id, job);
        Ok(status)
    }

    /// Registers a worker and returns its id.
    pub fn register(&mut self, name: &str, threads: u32) -> Result<String, SchedError> {
        let id = self.new_id("w-");
        let now = wall_ms();
        self.store.insert_worker(&id, name, threads, now)?;
        self.workers.insert(
            id.clone(),
            WorkerRec {
                name: name.into(),
                threads,
                registered_ms: now,
                last_seen_ms: now,
                tasks_done: 0,
                failures: 0,
            },
        );
        Ok(id)
    }

    fn touch(&mut self, worker: &str) {
        if let Some(w) = self.workers.get_mut(worker) {
            w.last_seen_ms = wall_ms();
        }
    }

    fn save_task(&self, job: &Job, idx: usize) -> Result<(), SchedError> {
        self.store
            .update_task(&job.id, &task_row(idx, &job.tasks[idx]))?;
        Ok(())
    }

    fn save_job(&self, job: &Job) -> Result<(), SchedError> {
        self.store.update_job(
            &job.id,
            job.state.name(),
            job.error.as_deref(),
            job.started_ms,
            job.finished_ms,
        )?;
        Ok(())
    }

    /// Gives `worker` the next task: highest priority, then oldest job; within a job, pass
    /// by pass, tiles centre-out. Returns (job id, task index, lease id).
    pub fn lease(
        &mut self,
        worker: &str,
        now: Instant,
    ) -> Result<Option<(String, usize, String)>, SchedError> {
        if !self.workers.contains_key(worker) {
            return Err(SchedError::NoWorker(worker.into()));
        }
        self.touch(worker);
        let mut order: Vec<(i32, u64, String)> = self
            .jobs
            .values()
            .filter(|j| !j.state.is_final())
            .filter(|j| {
                j.worker_failures.get(worker).copied().unwrap_or(0) < self.cfg.block_worker_after
            })
            .map(|j| (-j.priority, j.seq, j.id.clone()))
            .collect();
        order.sort();
        for (_, _, id) in order {
            let lease = self.new_id("l-");
            let deadline = now + self.cfg.lease_timeout;
            let job = self.jobs.get_mut(&id).expect("listed above");
            let mut found = None;
            let mut i = job.cursor;
            while i < job.tasks.len() {
                if job.tasks[i].state == TaskState::Queued {
                    found = Some(i);
                    break;
                }
                i += 1;
            }
            // Everything before the first queued task is leased or finished; a re-queue
            // moves the cursor back.
            job.cursor = found.unwrap_or(job.tasks.len());
            let Some(idx) = found else { continue };
            let ev = TaskEvent::Lease {
                worker: worker.into(),
                lease: lease.clone(),
                deadline,
            };
            if transition(&mut job.tasks[idx], ev) != Outcome::Changed {
                continue;
            }
            let mut job_changed = false;
            if job.state == JobState::Queued {
                job.state = JobState::Running;
                job.started_ms = Some(wall_ms());
                job_changed = true;
            }
            let job = self.jobs.get(&id).expect("present");
            self.save_task(job, idx)?;
            if job_changed {
                self.save_job(job)?;
            }
            self.leases.insert(lease.clone(), (id.clone(), idx));
            self.counters.leased += 1;
            return Ok(Some((id, idx, lease)));
        }
        Ok(None)
    }

    /// Renews a lease. Returns `Err(reason)` in the Ok when the worker should stop.
    pub fn heartbeat(
        &mut self,
        lease: &str,
        now: Instant,
    ) -> Result<Result<(), String>, SchedError> {
        let Some((job_id, idx)) = self.leases.get(lease).cloned() else {
            return Ok(Err("unknown or expired lease".into()));
        };
        let deadline = now + self.cfg.lease_timeout;
        let Some(job) = self.jobs.get_mut(&job_id) else {
            return Ok(Err("job gone".into()));
        };
        if job.state.is_final() {
            return Ok(Err(format!("job {}", job.state.name())));
        }
        let worker = match &job.tasks[idx].state {
            TaskState::Leased { worker, .. } => worker.clone(),
            _ => String::new(),
        };
        let ev = TaskEvent::Renew {
            lease: lease.into(),
            deadline,
        };
        if transition(&mut job.tasks[idx], ev) == Outcome::Changed {
            // The deadline lives in memory only: after a restart every lease gets the grace.
            self.touch(&worker);
            Ok(Ok(()))
        } else {
            self.leases.remove(lease);
            Ok(Err("lease expired".into()))
        }
    }

    /// Looks up a task for an upload: its tile and pass, to check the result against.
    pub fn task_for_upload(&self, job: &str, idx: u32) -> Result<(Tile, u32), SchedError> {
        let j = self
            .jobs
            .get(job)
            .ok_or_else(|| SchedError::NoJob(job.into()))?;
        if idx as usize >= j.tasks.len() {
            return Err(SchedError::NoTask(job.into(), idx));
        }
        let (tile, pass, _) = j.task_work(idx as usize);
        Ok((tile, pass))
    }

    /// Stores a result for task `idx` of `job`. `bytes` is the encoded result (stored as is).
    // The decoded sums are checked against the task, the bytes stored: both are needed.
    #[allow(clippy::too_many_arguments)]
    pub fn complete(
        &mut self,
        job_id: &str,
        idx: u32,
        worker: &str,
        accum: &TileAccum,
        pass: u32,
        bytes: &[u8],
        now: Instant,
    ) -> Result<ResultOutcome, SchedError> {
        let job = self
            .jobs
            .get_mut(job_id)
            .ok_or_else(|| SchedError::NoJob(job_id.into()))?;
        let i = idx as usize;
        if i >= job.tasks.len() {
            return Err(SchedError::NoTask(job_id.into(), idx));
        }
        let (tile, tpass, range) = job.task_work(i);
        if accum.tile != tile || pass != tpass {
            return Err(SchedError::Mismatch(format!(
                "result is for tile {:?} pass {pass}, task {idx} is tile {tile:?} pass {tpass}",
                accum.tile
            )));
        }
        if job.state.is_final() {
            self.counters.duplicates += 1;
            return Ok(if job.state == JobState::Done {
                ResultOutcome::Duplicate
            } else {
                ResultOutcome::JobFinished
            });
        }
        if let TaskState::Leased { lease, .. } = &job.tasks[i].state {
            self.leases.remove(lease);
        }
        match transition(
            &mut job.tasks[i],
            TaskEvent::Complete {
                worker: worker.into(),
            },
        ) {
            Outcome::Changed => {}
            Outcome::AlreadyDone => {
                self.counters.duplicates += 1;
                return Ok(ResultOutcome::Duplicate);
            }
            Outcome::Ignored => return Ok(ResultOutcome::JobFinished),
        }
        let all_done = job
            .tasks
            .iter()
            .all(|t| matches!(t.state, TaskState::Done { .. }));
        if all_done {
            job.state = JobState::Done;
            job.finished_ms = Some(wall_ms());
        }
        let job = self.jobs.get(job_id).expect("present");
        self.store
            .finish_task(job_id, &task_row(i, &job.tasks[i]), bytes)?;
        if all_done {
            self.save_job(job)?;
        }
        let samples = tile.pixel_count() as u64 * u64::from(range.end - range.start);
        self.counters.done += 1;
        self.counters.samples += samples;
        self.recent.push_back((now, samples));
        if let Some(w) = self.workers.get_mut(worker) {
            w.tasks_done += 1;
            w.last_seen_ms = wall_ms();
        }
        Ok(ResultOutcome::Accepted)
    }

    /// A worker reports that it could not render its leased task.
    pub fn fail(&mut self, lease: &str, error: &str) -> Result<bool, SchedError> {
        let Some((job_id, idx)) = self.leases.remove(lease) else {
            return Ok(false);
        };
        let max = self.cfg.max_task_failures;
        let Some(job) = self.jobs.get_mut(&job_id) else {
            return Ok(false);
        };
        let worker = match &job.tasks[idx].state {
            TaskState::Leased { worker, .. } => worker.clone(),
            _ => return Ok(false),
        };
        if job.state.is_final() {
            return Ok(false);
        }
        let fatal = job.tasks[idx].failures + 1 >= max;
        let ev = TaskEvent::Fail {
            lease: lease.into(),
            fatal,
        };
        if transition(&mut job.tasks[idx], ev) != Outcome::Changed {
            return Ok(false);
        }
        self.counters.failed += 1;
        let wf = job.worker_failures.entry(worker.clone()).or_insert(0);
        *wf += 1;
        let wf = *wf;
        job.cursor = job.cursor.min(idx);
        let (tile, pass, _) = job.task_work(idx);
        // A job every live worker is blocked from would wait for ever: fail it instead.
        // Workers that vanished long ago do not keep it alive (see `all_live_blocked`; the
        // expiry tick checks again as workers come and go).
        let block = self.cfg.block_worker_after;
        if let Some(w) = self.workers.get_mut(&worker) {
            w.last_seen_ms = wall_ms();
        }
        let all_blocked = !fatal
            && wf >= block
            && all_live_blocked(
                &self.workers,
                &job.worker_failures,
                &self.cfg,
                self.started_ms,
            );
        if all_blocked {
            job.state = JobState::Failed;
            job.finished_ms = Some(wall_ms());
            job.error = Some(format!(
                "every worker failed this job {block} times, so none may take it any more; last error, from worker {worker} on tile [{}, {}) × [{}, {}) pass {pass}: {error}",
                tile.x0, tile.x1, tile.y0, tile.y1
            ));
        }
        let fatal = fatal || all_blocked;
        if fatal && !all_blocked {
            job.state = JobState::Failed;
            job.finished_ms = Some(wall_ms());
            job.error = Some(format!(
                "tile [{}, {}) × [{}, {}) pass {pass} failed {} times; last error from worker {worker}: {error}",
                tile.x0, tile.x1, tile.y0, tile.y1, job.tasks[idx].failures
            ));
        }
        let job = self.jobs.get(&job_id).expect("present");
        self.save_task(job, idx)?;
        self.store.set_blocked(&job_id, &worker, wf)?;
        if fatal {
            self.save_job(job)?;
        }
        if let Some(w) = self.workers.get_mut(&worker) {
            w.failures += 1;
        }
        Ok(true)
    }

    /// The lease holder hands its task back (shutting down): re-queued, no failure counted.
    pub fn release(&mut self, lease: &str) -> Result<bool, SchedError> {
        let Some((job_id, idx)) = self.leases.remove(lease) else {
            return Ok(false);
        };
        let Some(job) = self.jobs.get_mut(&job_id) else {
            return Ok(false);
        };
        let ok = transition(
            &mut job.tasks[idx],
            TaskEvent::Release {
                lease: lease.into(),
            },
        ) == Outcome::Changed;
        if ok {
            job.cursor = job.cursor.min(idx);
            let job = self.jobs.get(&job_id).expect("present");
            self.save_task(job, idx)?;
        }
        Ok(ok)
    }

    /// Re-queues every lease whose deadline has passed; returns how many.
    pub fn expire(&mut self, now: Instant) -> Result<usize, SchedError> {
        let mut expired = Vec::new();
        for job in self.jobs.values_mut().filter(|j| !j.state.is_final()) {
            for i in 0..job.tasks.len() {
                let lease = match &job.tasks[i].state {
                    TaskState::Leased { lease, .. } => lease.clone(),
                    _ => continue,
                };
                if transition(&mut job.tasks[i], TaskEvent::Expire { now }) == Outcome::Changed {
                    job.cursor = job.cursor.min(i);
                    expired.push((job.id.clone(), i, lease));
                }
            }
        }
        for (job_id, i, lease) in &expired {
            self.leases.remove(lease);
            let job = self.jobs.get(job_id).expect("present");
            self.save_task(job, *i)?;
            tracing::info!(job = %job_id, task = i, "lease expired; task re-queued");
        }
        self.counters.expired += expired.len() as u64;
        // Jobs every live worker is blocked from (the last one blocked may have gone since).
        let stuck: Vec<String> = self
            .jobs
            .values()
            .filter(|j| !j.state.is_final() && !j.worker_failures.is_empty())
            .filter(|j| {
                all_live_blocked(
                    &self.workers,
                    &j.worker_failures,
                    &self.cfg,
                    self.started_ms,
                )
            })
            .map(|j| j.id.clone())
            .collect();
        for id in stuck {
            let job = self.jobs.get_mut(&id).expect("listed above");
            job.state = JobState::Failed;
            job.finished_ms = Some(wall_ms());
            job.error = Some(format!(
                "every live worker failed this job {} times, so none may take it any more",
                self.cfg.block_worker_after
            ));
            tracing::warn!(job = %id, "failed: every live worker is blocked from it");
            let job = self.jobs.get(&id).expect("present");
            self.save_job(job)?;
        }
        Ok(expired.len())
    }

    /// Cancels a job if it is not finished, then deletes it with its tiles from memory and the
    /// store. Returns its last status, or `None` if unknown. Workers still holding one of its
    /// leases learn it is gone at their next heartbeat; their results are refused (404).
    pub fn purge(&mut self, job_id: &str) -> Result<Option<JobStatus>, SchedError> {
        let Some(status) = self.cancel(job_id)? else {
            return Ok(None);
        };
        self.store.delete_job(job_id)?;
        self.jobs.remove(job_id);
        self.leases.retain(|_, (j, _)| j != job_id);
        Ok(Some(status))
    }

    /// Cancels a job. Returns its status, or `None` if unknown.
    pub fn cancel(&mut self, job_id: &str) -> Result<Option<JobStatus>, SchedError> {
        let Some(job) = self.jobs.get_mut(job_id) else {
            return Ok(None);
        };
        if !job.state.is_final() {
            job.state = JobState::Cancelled;
            job.finished_ms = Some(wall_ms());
            let job = self.jobs.get(job_id).expect("present");
            self.save_job(job)?;
        }
        Ok(self.jobs.get(job_id).map(Job::status))
    }

    /// Samples accepted per second over the last ten seconds.
    pub fn samples_per_second(&mut self, now: Instant) -> f64 {
        let window = Duration::from_secs(10);
        while let Some((t, _)) = self.recent.front() {
            if now.duration_since(*t) > window {
                self.recent.pop_front();
            } else {
                break;
            }
        }
        self.recent.iter().map(|(_, s)| *s).sum::<u64>() as f64 / window.as_secs_f64()
    }

    /// Tasks currently leased by each worker.
    pub fn leased_by_worker(&self) -> HashMap<String, u64> {
        let mut m = HashMap::new();
        for j in self.jobs.values() {
            for t in &j.tasks {
                if let TaskState::Leased { worker, .. } = &t.state {
                    *m.entry(worker.clone()).or_insert(0) += 1;
                }
            }
        }
        m
    }
}
