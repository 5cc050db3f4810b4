//! The scheduler: jobs, their tasks (one per tile and pass), leases and workers, behind one
//! lock in the app state. Its state is private; handlers call the methods of [`Sched`] and get
//! back plain values (`JobStatus`, [`Grant`], [`Metrics`]...).
//!
//! - `state`: the task and job state machines. Every task state change goes through one
//!   function, every job state change through another.
//! - `order`: which task comes next, and the [`TaskLayout`] that maps a task index to its tile
//!   and pass.
//! - `jobs`: a job in memory and its store rows; `workers`: registered workers and liveness;
//!   `ids`: id generation; `metrics`: counters and throughput.
//! - `view`: projections of the state to the API's types.
//! - [`events`]: every change, published as it is made for `GET /v1/events`.
//!
//! The scheduler reads no clock: every method that needs the time takes a [`Now`] read by its
//! caller (lease deadlines from `Now::instant`, times shown to users and worker liveness from
//! `Now::wall_ms`), so tests drive time. Its only IO is the store.
//!
//! Write, then apply: every operation works out the states it would change on copies, writes
//! them to the store in one transaction, and only when that succeeded puts them in memory. A
//! write that fails (a full disk, a read-only file) leaves memory as it was and returns
//! [`SchedError::Store`], which the API answers 503: the client's retry finds the same state,
//! so no result is lost and no task is handed out twice. A restarted coordinator finds every
//! change that was answered.

pub mod events;
mod ids;
mod jobs;
mod metrics;
mod order;
mod state;
#[cfg(test)]
mod tests;
mod view;
mod workers;

pub use metrics::{Counters, Metrics};
pub use order::{TaskLayout, TaskWork};

use crate::clock::Now;
use crate::store::{Store, TaskRow, Write};
use events::{Event, Events, Stamped};
use ids::Ids;
use jobs::Job;
use metrics::Throughput;
use raytile_core::{RenderSettings, Tile};
use raytile_proto::{JobState, JobStatus};
use state::{JobEvent, JobLife, Outcome, TaskEvent, TaskState};
use std::collections::{HashMap, HashSet};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;
use workers::{WorkerRec, Workers};

/// Leases of ended jobs whose reason is kept for a heartbeat that comes after they were
/// forgotten (beyond, the reasons are dropped and such a heartbeat hears "unknown").
const ENDED_LEASES_KEPT: usize = 4096;

/// How long a worker that is not heard from stays registered: a day.
pub const FORGET_WORKERS_AFTER_MS: u64 = 24 * 3600 * 1000;

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

impl SchedConfig {
    /// Expired leases of one task that fail its job: workers that die on a tile (out of
    /// memory, a crash the worker cannot report) would otherwise take it, and die, for ever.
    /// More than the failures a worker reports, since a network cut or a stopped machine
    /// expires leases too: `max_task_failures` + 2, and at least 5.
    pub fn max_task_expiries(&self) -> u32 {
        (self.max_task_failures + 2).max(5)
    }
}

/// A task given to a worker.
#[derive(Clone, Debug, PartialEq)]
pub struct Grant {
    /// The new lease's id.
    pub lease: String,
    /// Job id.
    pub job: String,
    /// Task index within the job.
    pub task: u32,
    /// Scene id.
    pub scene: String,
    /// The job's settings.
    pub settings: RenderSettings,
    /// The tile, pass and samples to render.
    pub work: TaskWork,
}

/// A result a worker uploads for a task.
#[derive(Clone, Copy, Debug)]
pub struct Delivery<'a> {
    /// Worker id (for the per-worker share).
    pub worker: &'a str,
    /// The pixels the decoded result covers.
    pub tile: Tile,
    /// The pass the decoded result says it is.
    pub pass: u32,
    /// The encoded result, stored as is.
    pub bytes: &'a [u8],
    /// The same bytes already in a file (a large result): stored as that file.
    pub file: Option<&'a crate::store::Staged>,
}

/// What a heartbeat tells the worker.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Heartbeat {
    /// The lease lives on until the new deadline.
    Renewed,
    /// Stop rendering: the lease or the job is over.
    Stop {
        /// Why, for the worker's log.
        reason: String,
    },
}

/// What a result upload did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
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

/// What a retry did to a job.
#[derive(Debug)]
pub enum Retried {
    /// A failed or cancelled job goes on: its status now.
    Resumed(JobStatus),
    /// The job is unfinished: nothing to retry.
    Unchanged(JobStatus),
    /// It cannot be retried, and why.
    Refused(String),
}

/// Everything the scheduler knows.
pub struct Sched {
    cfg: SchedConfig,
    store: Store,
    /// Jobs by id.
    jobs: HashMap<String, Job>,
    workers: Workers,
    /// Lease id → (job id, task index), for the leases out.
    leases: HashMap<String, (String, usize)>,
    next_seq: u64,
    ids: Ids,
    counters: Counters,
    throughput: Throughput,
    /// Samples accepted per worker over the throughput window.
    rates: HashMap<String, Throughput>,
    /// Workers reported gone (not live) on the event stream.
    gone: HashSet<String>,
    /// Why each lease forgotten with its job ended (memory only, bounded).
    ended_leases: HashMap<String, String>,
    /// Leases that expired, by id: their job, task and worker, so that the worker's next
    /// heartbeat can take the task back while nobody else has (memory only, bounded).
    expired_leases: HashMap<String, (String, usize, String)>,
    events: Events,
}

/// The store change that records `life` as job `id`'s.
fn life_write<'a>(id: &'a str, life: &'a JobLife) -> Write<'a> {
    Write::Job {
        id,
        state: life.state,
        error: life.error.as_deref(),
        started_ms: life.started_ms,
        finished_ms: life.finished_ms,
    }
}

/// The event that says job `id` now has `life`'s state.
fn job_state_event(id: &str, life: &JobLife) -> Event {
    Event::JobState {
        job: id.into(),
        state: life.state,
        error: life.error.clone(),
    }
}

/// The event that says task `idx` of job `id` (`work`) is out with `worker`.
fn task_leased_event(id: &str, idx: usize, work: &TaskWork, worker: &str) -> Event {
    Event::TaskLeased {
        job: id.into(),
        task: idx as u32,
        tile: work.tile,
        pass: work.pass,
        worker: worker.into(),
    }
}

/// The event that says how far job `id` is.
fn job_progress_event(id: &str, job: &Job) -> Event {
    let (tiles_done, passes_done) = job.progress();
    let layout = &job.layout;
    Event::JobProgress {
        job: id.into(),
        tiles_done,
        tiles_total: layout.tile_count() as u64,
        passes_done,
        passes: layout.pass_count() as u32,
        tasks_done: job.tasks_done() as u64,
        tasks_total: layout.task_count() as u64,
    }
}

/// Publishes that `tasks` of job `id` went back to the queue for `reason`: a `task_queued`
/// each, or one `resync` for more than [`events::RESYNC_OVER`].
fn emit_queued(events: &mut Events, id: &str, job: &Job, tasks: &[usize], reason: &'static str) {
    let n = tasks.len();
    if n > events::RESYNC_OVER {
        events.emit(|| Event::Resync {
            reason: format!("{n} tasks queued again ({reason})"),
        });
        return;
    }
    for &i in tasks {
        if let Some(work) = job.work(i) {
            events.emit(|| Event::TaskQueued {
                job: id.into(),
                task: i as u32,
                tile: work.tile,
                pass: work.pass,
                reason,
            });
        }
    }
}

/// The tasks of job `job_id` still out on a lease in `leases`, each as it is once its lease
/// ends with the job (queued again, no failure counted), in task order: a job that ends
/// (cancelled or failed) holds no leases, so no tile of it shows a worker any more. The
/// workers learn it at their next heartbeat, which the lease ids in `leases` still answer.
fn leases_ending_with(
    leases: &HashMap<String, (String, usize)>,
    job_id: &str,
    job: &Job,
) -> Vec<(usize, state::Task)> {
    let mut ended: Vec<(usize, state::Task)> = leases
        .iter()
        .filter(|(_, (j, _))| j == job_id)
        .filter_map(|(lease, &(_, idx))| {
            let ev = TaskEvent::Release {
                lease: lease.clone(),
            };
            let (out, task) = job.next_task(idx, ev);
            (out == Outcome::Changed).then_some((idx, task))
        })
        .collect();
    ended.sort_by_key(|(i, _)| *i);
    ended
}

impl Sched {
    /// Opens the scheduler over `store` at `now` (the coordinator's start), restoring every
    /// job. Leases that were out get `grace` from `now` for their workers to report back.
    pub fn restore(
        cfg: SchedConfig,
        mut store: Store,
        now: Now,
        grace: Duration,
    ) -> Result<Sched, SchedError> {
        let epoch = store.next_epoch(now.wall_ms)?;
        let lease_key = store.lease_key()?;
        let mut s = Sched {
            workers: Workers::new(now.wall_ms, cfg.lease_timeout),
            cfg,
            store,
            jobs: HashMap::new(),
            leases: HashMap::new(),
            next_seq: 1,
            ids: Ids::new(epoch, lease_key),
            counters: Counters::default(),
            throughput: Throughput::default(),
            rates: HashMap::new(),
            gone: HashSet::new(),
            ended_leases: HashMap::new(),
            expired_leases: HashMap::new(),
            events: Events::new(),
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
            let tasks = s.store.tasks(&row.id)?;
            let failures = s.store.blocked(&row.id)?.into_iter().collect();
            let (mut job, leases) =
                Job::restore(row, settings, tasks, failures, now.instant + grace);
            let leases: HashMap<String, (String, usize)> = leases
                .into_iter()
                .map(|(lease, idx)| (lease, (job.id.clone(), idx)))
                .collect();
            // A stored state its tasks contradict (a row edited by hand, or damaged): a done
            // job lacking tasks renders them (unless another renderer made its tiles: its
            // frame stays as it is), an unfinished one with every task done is done.
            let (done, total) = (job.tasks_done(), job.layout.task_count());
            let repair = match job.life().state {
                JobState::Done
                    if done < total && job.render_version == Some(raytile_core::RENDER_VERSION) =>
                {
                    Some(JobEvent::Reopen)
                }
                JobState::Queued | JobState::Running if total > 0 && done == total => {
                    Some(JobEvent::Finish)
                }
                _ => None,
            };
            if let Some(life) = repair.and_then(|ev| job.next_life(ev, now.wall_ms)) {
                tracing::warn!(
                    job = %job.id,
                    "stored as {} with {done} of {total} tasks done: now {}",
                    job.life().state.name(),
                    life.state.name()
                );
                let mut writes = vec![life_write(&job.id, &life)];
                let reopened = !life.state.is_final();
                if reopened {
                    // As any done job reopened: no worker blocked from it, since those blocked
                    // may be all that is left.
                    writes.push(Write::ClearBlocked(&job.id));
                }
                s.store.write(&writes)?;
                if reopened {
                    job.worker_failures.clear();
                }
                job.set_life(life);
            }
            if job.is_final() {
                // A final job holds no leases; a database written before that was so may
                // still have some: they end now, and are stored as ended.
                let ended = leases_ending_with(&leases, &job.id, &job);
                let rows: Vec<TaskRow> = ended.iter().map(|(i, t)| Job::task_row(*i, t)).collect();
                let writes: Vec<Write> = rows
                    .iter()
                    .map(|row| Write::Task { job: &job.id, row })
                    .collect();
                s.store.write(&writes)?;
                for (i, t) in ended {
                    job.set_task(i, t);
                }
            } else {
                s.leases.extend(leases);
            }
            s.jobs.insert(job.id.clone(), job);
        }
        Ok(s)
    }

    /// A second connection to the store for long reads (image composition) that must not
    /// hold the scheduler's lock.
    pub fn reader(&self) -> rusqlite::Result<rusqlite::Connection> {
        self.store.reader()
    }

    /// Where results stored as files live.
    pub fn results_dir(&self) -> PathBuf {
        self.store.results_dir().to_path_buf()
    }

    /// A subscriber to the change events, and the id of the last event before it.
    pub fn subscribe(&self) -> (u64, tokio::sync::broadcast::Receiver<Arc<Stamped>>) {
        self.events.subscribe()
    }

    /// Jobs not yet final.
    pub fn unfinished_jobs(&self) -> usize {
        self.jobs.values().filter(|j| !j.is_final()).count()
    }

    /// Tasks of the jobs not yet final.
    pub fn unfinished_tasks(&self) -> u64 {
        self.jobs
            .values()
            .filter(|j| !j.is_final())
            .map(|j| j.tasks().len() as u64)
            .sum()
    }

    /// Creates a job submitted at `now`; `settings` must be valid and within the
    /// coordinator's limits, and `layout` is `TaskLayout::new(&settings)`, made by the caller
    /// before it takes the lock (it is what costs time on a large job). Storing the job writes
    /// one row whatever its size: its tasks get rows as they leave the queue.
    pub fn create_job(
        &mut self,
        scene: String,
        settings: RenderSettings,
        layout: Arc<TaskLayout>,
        priority: i32,
        now: Now,
    ) -> Result<JobStatus, SchedError> {
        debug_assert_eq!(*layout, TaskLayout::new(&settings));
        let seq = self.next_seq;
        let id = self.ids.job(seq);
        let job = Job::new(
            id.clone(),
            seq,
            scene,
            settings,
            priority,
            now.wall_ms,
            layout,
        );
        self.store.write(&[Write::InsertJob(&job.row())])?;
        self.next_seq += 1;
        let status = job.status();
        self.jobs.insert(id, job);
        self.events.emit(|| Event::JobSubmitted {
            job: Box::new(status.clone()),
        });
        Ok(status)
    }

    /// Registers a worker at `now` and returns its id.
    pub fn register(&mut self, name: &str, threads: u32, now: Now) -> Result<String, SchedError> {
        let id = self.ids.worker();
        // A worker that restarts registers again: its earlier registrations under the same
        // name that are no longer live (and hold no lease) are forgotten, rather than listed
        // for ever.
        let earlier = self
            .workers
            .forgettable(Some(name), &self.leased_by(), 0, now.wall_ms);
        let mut writes = vec![Write::Worker {
            id: &id,
            name,
            threads,
            registered_ms: now.wall_ms,
        }];
        writes.extend(earlier.iter().map(|w| Write::ForgetWorker(w)));
        self.store.write(&writes)?;
        for w in &earlier {
            self.workers.remove(w);
            self.gone.remove(w);
        }
        self.workers.insert(
            id.clone(),
            WorkerRec {
                name: name.into(),
                threads,
                registered_ms: now.wall_ms,
                last_seen_ms: now.wall_ms,
                tasks_done: 0,
                failures: 0,
            },
        );
        self.events.emit(|| Event::WorkerRegistered {
            worker: id.clone(),
            name: name.into(),
            threads,
        });
        Ok(id)
    }

    /// Gives `worker` the next task (see the `order` module), leased until `now` plus the
    /// lease timeout; `None` when there is nothing for it.
    pub fn lease(&mut self, worker: &str, now: Now) -> Result<Option<Grant>, SchedError> {
        if self.workers.touch(worker, now.wall_ms).is_none() {
            return Err(SchedError::NoWorker(worker.into()));
        }
        let block = self.cfg.block_worker_after;
        let queue = order::job_queue(&self.jobs, |j| {
            !j.is_final() && j.failures_of(worker) < block
        });
        for id in queue {
            // A task goes back to the worker that failed it last only when no other live
            // worker may take the job's tasks: one broken worker would otherwise fail the
            // same task again at once, until the task's failures failed the job.
            let others = self.workers.another_may_take(
                worker,
                &self.jobs[&id].worker_failures,
                block,
                now.wall_ms,
            );
            let job = self.jobs.get_mut(&id).expect("listed above");
            let Some(idx) = job.next_queued(|t| !others || t.failed_by.as_deref() != Some(worker))
            else {
                continue;
            };
            let lease = self.ids.lease(&id, idx as u32, worker);
            let ev = TaskEvent::Lease {
                worker: worker.into(),
                lease: lease.clone(),
                deadline: now.instant + self.cfg.lease_timeout,
            };
            let (out, task) = job.next_task(idx, ev);
            if out != Outcome::Changed {
                continue;
            }
            let life = job.next_life(JobEvent::Start, now.wall_ms);
            let row = Job::task_row(idx, &task);
            let mut writes = vec![Write::Task {
                job: &id,
                row: &row,
            }];
            writes.extend(life.as_ref().map(|l| life_write(&id, l)));
            self.store.write(&writes)?;
            job.set_task(idx, task);
            let work = job.work(idx).expect("a queued task is in the layout");
            self.events
                .emit(|| task_leased_event(&id, idx, &work, worker));
            if let Some(l) = life {
                self.events.emit(|| job_state_event(&id, &l));
                job.set_life(l);
            }
            self.leases.insert(lease.clone(), (id.clone(), idx));
            self.counters.leased += 1;
            return Ok(Some(Grant {
                lease,
                job: id,
                task: idx as u32,
                scene: job.scene.clone(),
                settings: job.settings.clone(),
                work,
            }));
        }
        Ok(None)
    }

    /// Renews a lease until `now` plus the lease timeout, or tells its worker to stop.
    pub fn heartbeat(&mut self, lease: &str, now: Now) -> Heartbeat {
        let stop = |reason: String| Heartbeat::Stop { reason };
        let Some((job_id, idx)) = self.leases.get(lease).cloned() else {
            if self.revive(lease, now) {
                return Heartbeat::Renewed;
            }
            let why = self
                .ended_leases
                .remove(lease)
                .or_else(|| self.why_not_revived(lease));
            return stop(why.unwrap_or_else(|| "unknown or expired lease".into()));
        };
        let Some(job) = self.jobs.get_mut(&job_id) else {
            return stop("job gone".into());
        };
        if job.is_final() {
            return stop(format!("job {}", job.life().state.name()));
        }
        let worker = job.lease_of(idx).map(|(w, _)| w.to_string());
        let ev = TaskEvent::Renew {
            lease: lease.into(),
            deadline: now.instant + self.cfg.lease_timeout,
        };
        if job.renew(idx, ev) {
            if let Some(w) = worker {
                if let Some(rec) = self.workers.touch(&w, now.wall_ms) {
                    let (last_seen_ms, tasks_done) = (rec.last_seen_ms, rec.tasks_done);
                    self.events.emit(|| Event::WorkerSeen {
                        worker: w,
                        last_seen_ms,
                        tasks_done,
                    });
                }
            }
            Heartbeat::Renewed
        } else {
            self.leases.remove(lease);
            stop("lease expired".into())
        }
    }

    /// Gives an expired lease back to its worker at its heartbeat, when the task still waits
    /// for a worker: a worker stopped (SIGSTOP, a suspended machine) or cut off past its lease
    /// goes on with the tile it has half rendered instead of dropping it, as long as nobody
    /// else took it meanwhile. Not when the worker is gone from the register or blocked from
    /// the job, nor when the job ended. Returns whether the lease lives again.
    fn revive(&mut self, lease: &str, now: Now) -> bool {
        let Some((job_id, idx, worker)) = self.expired_leases.get(lease).cloned() else {
            return false;
        };
        let block = self.cfg.block_worker_after;
        let Some(job) = self
            .jobs
            .get_mut(&job_id)
            .filter(|j| !j.is_final() && j.failures_of(&worker) < block)
        else {
            return false;
        };
        if self.workers.touch(&worker, now.wall_ms).is_none() {
            return false;
        }
        let ev = TaskEvent::Revive {
            worker: worker.clone(),
            lease: lease.into(),
            deadline: now.instant + self.cfg.lease_timeout,
        };
        let (out, task) = job.next_task(idx, ev);
        if out != Outcome::Changed {
            return false;
        }
        let row = Job::task_row(idx, &task);
        if let Err(e) = self.store.write(&[Write::Task {
            job: &job_id,
            row: &row,
        }]) {
            tracing::warn!(job = %job_id, task = idx, "an expired lease not renewed: {e}");
            return false;
        }
        job.set_task(idx, task);
        let work = job.work(idx).expect("a leased task is in the layout");
        self.events
            .emit(|| task_leased_event(&job_id, idx, &work, &worker));
        tracing::info!(job = %job_id, task = idx, %worker, "expired lease renewed by its worker; nobody had taken the task");
        self.expired_leases.remove(lease);
        self.leases.insert(lease.into(), (job_id, idx));
        self.counters.revived += 1;
        true
    }

    /// Why an expired lease was not given back to its worker, when it is on record.
    fn why_not_revived(&self, lease: &str) -> Option<String> {
        let (job_id, idx, worker) = self.expired_leases.get(lease)?;
        let Some(job) = self.jobs.get(job_id) else {
            return Some("job deleted".into());
        };
        Some(if job.is_final() {
            format!("job {}", job.life().state.name())
        } else if job.failures_of(worker) >= self.cfg.block_worker_after {
            "lease expired, and this worker is blocked from the job".into()
        } else {
            match job.tasks()[*idx].state {
                TaskState::Done { .. } => "lease expired, and the task was done by another worker",
                TaskState::Leased { .. } => "lease expired, and the task went to another worker",
                _ => "lease expired",
            }
            .into()
        })
    }

    /// Looks up a task for an upload: its tile and pass, to check the result against.
    pub fn task_for_upload(&self, job: &str, idx: u32) -> Result<(Tile, u32), SchedError> {
        let j = self
            .jobs
            .get(job)
            .ok_or_else(|| SchedError::NoJob(job.into()))?;
        let work = j
            .work(idx as usize)
            .ok_or_else(|| SchedError::NoTask(job.into(), idx))?;
        Ok((work.tile, work.pass))
    }

    /// What [`Scheduler::complete`] would answer task `idx` of `job` whatever its result holds:
    /// `Duplicate` for a task already done (or a job done), `JobFinished` for a cancelled or
    /// failed job; `None` while a result can still be stored. The upload route asks first, so
    /// that a result nobody can use is not held in memory (it is read and dropped), and counts
    /// it with [`Sched::count_duplicate`] once it has been read, as `complete` would.
    pub fn settled(&self, job: &str, idx: u32) -> Option<ResultOutcome> {
        let j = self.jobs.get(job)?;
        let outcome = if j.is_final() {
            if j.life().state == JobState::Done {
                ResultOutcome::Duplicate
            } else {
                ResultOutcome::JobFinished
            }
        } else if matches!(j.tasks().get(idx as usize)?.state, TaskState::Done { .. }) {
            ResultOutcome::Duplicate
        } else {
            return None;
        };
        Some(outcome)
    }

    /// Counts a result that came for a task already settled ([`Sched::settled`]).
    pub fn count_duplicate(&mut self, outcome: ResultOutcome) {
        self.count_ignored(outcome);
    }

    /// Counts a result ignored with `outcome`: a duplicate, or one for a job that ended.
    fn count_ignored(&mut self, outcome: ResultOutcome) {
        match outcome {
            ResultOutcome::JobFinished => self.counters.for_ended_jobs += 1,
            _ => self.counters.duplicates += 1,
        }
    }

    /// Whether `lease` is an id this coordinator gave, at this start or an earlier one, for
    /// task `idx` of `job` to `worker` (out now, or expired, released or finished since).
    pub fn lease_is_for(&self, lease: &str, job: &str, idx: u32, worker: &str) -> bool {
        self.ids.lease_is_for(lease, job, idx, worker)
    }

    /// The id of the lease out on task `idx` of `job`, if one is.
    pub fn current_lease(&self, job: &str, idx: u32) -> Option<String> {
        let j = self
            .jobs
            .get(job)
            .filter(|j| (idx as usize) < j.tasks().len())?;
        j.lease_of(idx as usize).map(|(_, lease)| lease.to_string())
    }

    /// The number of samples per pixel in pass `pass` of `job` (0 for an unknown job or pass).
    pub fn pass_samples(&self, job: &str, pass: u32) -> u32 {
        self.jobs
            .get(job)
            .and_then(|j| {
                j.settings
                    .pass_ranges()
                    .get(pass as usize)
                    .map(|r| r.len() as u32)
            })
            .unwrap_or(0)
    }

    /// The number of pixels of `job`'s frame when its results may carry splats (light that
    /// one tile's samples carry to other pixels: `bdpt`), else `None`.
    pub fn splat_pixels(&self, job: &str) -> Option<u64> {
        let s = &self.jobs.get(job)?.settings;
        (s.integrator == raytile_core::IntegratorKind::Bdpt)
            .then(|| s.width as u64 * s.height as u64)
    }

    /// Whether `job`'s results carry coverage (the job has an alpha channel); false for an
    /// unknown job.
    pub fn alpha(&self, job: &str) -> bool {
        self.jobs.get(job).is_some_and(|j| j.settings.alpha)
    }

    /// Stores a result for task `idx` of `job_id`, delivered at `now`.
    pub fn complete(
        &mut self,
        job_id: &str,
        idx: u32,
        d: Delivery<'_>,
        now: Now,
    ) -> Result<ResultOutcome, SchedError> {
        let job = self
            .jobs
            .get_mut(job_id)
            .ok_or_else(|| SchedError::NoJob(job_id.into()))?;
        let i = idx as usize;
        let work = job
            .work(i)
            .ok_or_else(|| SchedError::NoTask(job_id.into(), idx))?;
        if d.tile != work.tile || d.pass != work.pass {
            return Err(SchedError::Mismatch(format!(
                "result is for tile {} pass {}, task {idx} is tile {} pass {}",
                d.tile, d.pass, work.tile, work.pass
            )));
        }
        if job.is_final() {
            let outcome = if job.life().state == JobState::Done {
                ResultOutcome::Duplicate
            } else {
                ResultOutcome::JobFinished
            };
            self.count_ignored(outcome);
            return Ok(outcome);
        }
        let ev = TaskEvent::Complete {
            worker: d.worker.into(),
        };
        let (out, task) = job.next_task(i, ev);
        match out {
            Outcome::Changed => {}
            Outcome::AlreadyDone => {
                self.counters.duplicates += 1;
                return Ok(ResultOutcome::Duplicate);
            }
            Outcome::Ignored => {
                self.counters.for_ended_jobs += 1;
                return Ok(ResultOutcome::JobFinished);
            }
        }
        let finished = if job.all_done_but(i) {
            job.next_life(JobEvent::Finish, now.wall_ms)
        } else {
            None
        };
        let row = Job::task_row(i, &task);
        let mut writes = vec![Write::Result {
            job: job_id,
            row: &row,
            data: d.bytes,
            file: d.file,
        }];
        writes.extend(finished.as_ref().map(|l| life_write(job_id, l)));
        // Stored first: if this fails, nothing changed and the worker's retry is accepted.
        self.store.write(&writes)?;
        if let Some((holder, lease)) = job.lease_of(i) {
            if holder != d.worker {
                // Its holder learns why at its next heartbeat.
                self.ended_leases.insert(
                    lease.to_string(),
                    "task done: another worker's result for it came first".into(),
                );
            }
            self.leases.remove(lease);
        }
        job.set_task(i, task);
        self.events.emit(|| Event::TaskDone {
            job: job_id.into(),
            task: idx,
            tile: work.tile,
            pass: work.pass,
            worker: d.worker.into(),
        });
        self.events.emit(|| job_progress_event(job_id, job));
        if let Some(l) = finished {
            self.events.emit(|| job_state_event(job_id, &l));
            job.set_life(l);
        }
        let samples = work.sample_count();
        self.counters.done += 1;
        self.counters.samples += samples;
        self.throughput.record(now.instant, samples);
        if let Some(w) = self.workers.touch(d.worker, now.wall_ms) {
            w.tasks_done += 1;
            self.rates
                .entry(d.worker.to_string())
                .or_default()
                .record(now.instant, samples);
        }
        Ok(ResultOutcome::Accepted)
    }

    /// A worker reports at `now` that it could not render its leased task. Returns whether
    /// the report applied (a stale lease changes nothing).
    pub fn fail(&mut self, lease: &str, error: &str, now: Now) -> Result<bool, SchedError> {
        let Some((job_id, idx)) = self.leases.get(lease).cloned() else {
            return Ok(false);
        };
        let Some(job) = self.jobs.get_mut(&job_id) else {
            self.leases.remove(lease);
            return Ok(false);
        };
        let Some(worker) = job.lease_of(idx).map(|(w, _)| w.to_string()) else {
            self.leases.remove(lease);
            return Ok(false);
        };
        if job.is_final() {
            self.leases.remove(lease);
            return Ok(false);
        }
        let fatal = job.tasks()[idx].failures + 1 >= self.cfg.max_task_failures;
        let ev = TaskEvent::Fail {
            lease: lease.into(),
            fatal,
        };
        let (out, task) = job.next_task(idx, ev);
        if out != Outcome::Changed {
            self.leases.remove(lease);
            return Ok(false);
        }
        let wf = job.failures_of(&worker) + 1;
        let reported = error.to_string();
        let work = job.work(idx).expect("a leased task is in the layout");
        let (t, pass) = (work.tile, work.pass);
        // A job every live worker is blocked from would wait for ever: fail it instead.
        // Workers that vanished long ago do not keep it alive (see `Workers::all_live_blocked`;
        // the expiry tick catches the case where the last live peer goes later).
        let block = self.cfg.block_worker_after;
        let all_blocked = !fatal && wf >= block && {
            let mut failures = job.worker_failures.clone();
            failures.insert(worker.clone(), wf);
            self.workers.all_live_blocked(&failures, block, now.wall_ms)
        };
        let error = if all_blocked {
            Some(format!(
                "every worker failed this job {block} times, so none may take it any more; last error, from worker {worker} on tile [{}, {}) × [{}, {}) pass {pass}: {error}",
                t.x0, t.x1, t.y0, t.y1
            ))
        } else if fatal {
            Some(format!(
                "tile [{}, {}) × [{}, {}) pass {pass} failed {} times; last error from worker {worker}: {error}",
                t.x0, t.x1, t.y0, t.y1, task.failures
            ))
        } else {
            None
        };
        let failed = error.and_then(|error| job.next_life(JobEvent::Fail { error }, now.wall_ms));
        // The job failing ends the other leases out on it.
        let ended: Vec<(usize, state::Task)> = match failed {
            Some(_) => leases_ending_with(&self.leases, &job_id, job)
                .into_iter()
                .filter(|(i, _)| *i != idx)
                .collect(),
            None => Vec::new(),
        };
        let row = Job::task_row(idx, &task);
        let ended_rows: Vec<TaskRow> = ended.iter().map(|(i, t)| Job::task_row(*i, t)).collect();
        let mut writes = vec![
            Write::Task {
                job: &job_id,
                row: &row,
            },
            Write::Blocked {
                job: &job_id,
                worker: &worker,
                failures: wf,
            },
        ];
        writes.extend(failed.as_ref().map(|l| life_write(&job_id, l)));
        writes.extend(
            ended_rows
                .iter()
                .map(|row| Write::Task { job: &job_id, row }),
        );
        self.store.write(&writes)?;
        self.leases.remove(lease);
        job.set_task(idx, task);
        for (i, t) in ended {
            job.set_task(i, t);
        }
        job.worker_failures.insert(worker.clone(), wf);
        if job.recent_failures.len() == 20 {
            job.recent_failures.pop_front();
        }
        job.recent_failures.push_back(raytile_proto::TaskFailure {
            worker: worker.clone(),
            task: idx as u32,
            tile: t,
            pass,
            error: reported.clone(),
            at_ms: now.wall_ms,
        });
        self.events.emit(|| Event::TaskFailed {
            job: job_id.clone(),
            task: idx as u32,
            tile: t,
            pass,
            worker: worker.clone(),
            error: reported,
        });
        if let Some(l) = failed {
            self.events.emit(|| job_state_event(&job_id, &l));
            job.set_life(l);
        }
        self.counters.failed += 1;
        if let Some(w) = self.workers.touch(&worker, now.wall_ms) {
            w.failures += 1;
        }
        Ok(true)
    }

    /// The lease holder hands its task back (shutting down): re-queued, no failure counted.
    pub fn release(&mut self, lease: &str) -> Result<bool, SchedError> {
        let Some((job_id, idx)) = self.leases.get(lease).cloned() else {
            return Ok(false);
        };
        let Some(job) = self.jobs.get_mut(&job_id) else {
            self.leases.remove(lease);
            return Ok(false);
        };
        let ev = TaskEvent::Release {
            lease: lease.into(),
        };
        let (out, task) = job.next_task(idx, ev);
        if out != Outcome::Changed {
            self.leases.remove(lease);
            return Ok(false);
        }
        let row = Job::task_row(idx, &task);
        self.store.write(&[Write::Task {
            job: &job_id,
            row: &row,
        }])?;
        self.leases.remove(lease);
        job.set_task(idx, task);
        if let Some(work) = job.work(idx) {
            self.events.emit(|| Event::TaskQueued {
                job: job_id.clone(),
                task: idx as u32,
                tile: work.tile,
                pass: work.pass,
                reason: "released",
            });
        }
        Ok(true)
    }

    /// Tasks `lost` of job `job_id`, whose stored results an image found missing or damaged,
    /// are queued again with their results deleted, so that the tile is rendered again (to
    /// the same bits) rather than missing from the frame. A done job runs again until they
    /// are, and a cancelled or failed one renders them if it is retried, where the current
    /// renderer made the job's tiles (a finished job of another renderer keeps its frame as
    /// it is). Returns how many were queued.
    pub fn repair(&mut self, job_id: &str, lost: &[u32], now: Now) -> Result<usize, SchedError> {
        let Some(job) = self.jobs.get_mut(job_id) else {
            return Ok(0);
        };
        let state = job.life().state;
        let current = job.render_version == Some(raytile_core::RENDER_VERSION);
        // A cancelled or failed job keeps its state, its lost tasks queued for a retry.
        if !(matches!(state, JobState::Queued | JobState::Running) || current) {
            tracing::error!(job = %job_id, tasks = ?lost, ?state,
                "stored results are lost, and the job cannot render them again: its frame lacks those tiles");
            return Ok(0);
        }
        let mut queued: Vec<(usize, state::Task)> = Vec::new();
        for &idx in lost {
            let i = idx as usize;
            if i >= job.tasks().len() || queued.iter().any(|(q, _)| *q == i) {
                continue;
            }
            let (out, task) = job.next_task(i, TaskEvent::Lost);
            if out == Outcome::Changed {
                queued.push((i, task));
            }
        }
        if queued.is_empty() {
            return Ok(0);
        }
        let reopened = job.next_life(JobEvent::Reopen, now.wall_ms);
        let rows: Vec<TaskRow> = queued.iter().map(|(i, t)| Job::task_row(*i, t)).collect();
        let mut writes: Vec<Write> = rows
            .iter()
            .map(|row| Write::DropResult { job: job_id, row })
            .collect();
        writes.extend(reopened.as_ref().map(|l| life_write(job_id, l)));
        if reopened.is_some() {
            // A done job starts over with no worker blocked from it: those blocked may be all
            // that is left, and the job would fail for want of one.
            writes.push(Write::ClearBlocked(job_id));
        }
        self.store.write(&writes)?;
        if reopened.is_some() {
            job.worker_failures.clear();
        }
        let n = queued.len();
        let mut tasks = Vec::with_capacity(n);
        for (i, t) in queued {
            job.set_task(i, t);
            tasks.push(i);
        }
        emit_queued(&mut self.events, job_id, job, &tasks, "lost");
        self.events.emit(|| job_progress_event(job_id, job));
        if let Some(l) = reopened {
            self.events.emit(|| job_state_event(job_id, &l));
            job.set_life(l);
        }
        tracing::warn!(job = %job_id, tasks = n, ?state,
            "stored results were missing or damaged: their tasks are queued to be rendered again");
        Ok(n)
    }

    /// Gives every lease out at least until `until` (deadlines live in memory: nothing is
    /// stored); returns how many it extended. For a coordinator that was not running for
    /// longer than a lease lives (see [`crate::timeout_checker`]).
    pub fn extend_leases(&mut self, until: tokio::time::Instant) -> usize {
        let mut n = 0;
        for (lease, (job_id, idx)) in &self.leases {
            let Some(job) = self.jobs.get_mut(job_id) else {
                continue;
            };
            let short = matches!(
                &job.tasks()[*idx].state,
                state::TaskState::Leased { deadline, .. } if *deadline < until
            );
            let renew = TaskEvent::Renew {
                lease: lease.clone(),
                deadline: until,
            };
            if short && job.renew(*idx, renew) {
                n += 1;
            }
        }
        n
    }

    /// Re-queues every lease whose deadline has passed at `now`, and fails the jobs every live
    /// worker is blocked from; returns how many leases expired. Only the leases out are
    /// looked at, not every task of every job.
    pub fn expire(&mut self, now: Now) -> Result<usize, SchedError> {
        let mut expired = Vec::new();
        for (lease, (job_id, idx)) in &self.leases {
            let Some(job) = self.jobs.get(job_id).filter(|j| !j.is_final()) else {
                continue;
            };
            let (out, task) = job.next_task(*idx, TaskEvent::Expire { now: now.instant });
            if out == Outcome::Changed {
                let worker = job.lease_of(*idx).map(|(w, _)| w.to_string());
                expired.push((job_id.clone(), *idx, lease.clone(), task, worker));
            }
        }
        expired.sort_by(|a, b| (&a.0, a.1).cmp(&(&b.0, b.1)));
        let rows: Vec<TaskRow> = expired
            .iter()
            .map(|(_, i, _, t, _)| Job::task_row(*i, t))
            .collect();
        let writes: Vec<Write> = expired
            .iter()
            .zip(&rows)
            .map(|((job, ..), row)| Write::Task { job, row })
            .collect();
        self.store.write(&writes)?;
        let n = expired.len();
        if n > events::RESYNC_OVER {
            self.events.emit(|| Event::Resync {
                reason: format!("{n} leases expired"),
            });
        }
        // Jobs with a task whose leases expired too often: the first such task of each.
        let mut expiring: HashMap<String, String> = HashMap::new();
        let limit = self.cfg.max_task_expiries();
        for (job_id, i, lease, task, worker) in expired {
            self.leases.remove(&lease);
            if let Some(worker) = worker {
                if self.expired_leases.len() >= ENDED_LEASES_KEPT {
                    self.expired_leases.clear();
                }
                self.expired_leases
                    .insert(lease.clone(), (job_id.clone(), i, worker));
            }
            if let Some(job) = self.jobs.get_mut(&job_id) {
                if let Some(work) = job.work(i).filter(|_| task.expiries >= limit) {
                    let t = work.tile;
                    expiring.entry(job_id.clone()).or_insert_with(|| {
                        format!(
                            "tile [{}, {}) × [{}, {}) pass {}: its lease expired {} times, \
                             the workers that took it having stopped answering (killed, \
                             crashed, out of memory, or cut off from the coordinator): see \
                             their logs",
                            t.x0, t.x1, t.y0, t.y1, work.pass, task.expiries
                        )
                    });
                }
                job.set_task(i, task);
                if let Some(work) = job.work(i).filter(|_| n <= events::RESYNC_OVER) {
                    self.events.emit(|| Event::TaskQueued {
                        job: job_id.clone(),
                        task: i as u32,
                        tile: work.tile,
                        pass: work.pass,
                        reason: "expired",
                    });
                }
            }
            tracing::info!(job = %job_id, task = i, "lease expired; task re-queued");
        }
        self.counters.expired += n as u64;

        // Leases of jobs that ended or were purged stop nothing any more: forget them (memory
        // only), keeping why for a heartbeat on one.
        let jobs = &self.jobs;
        let ended = &mut self.ended_leases;
        self.leases
            .retain(|lease, (j, _)| match jobs.get(j.as_str()) {
                Some(job) if !job.is_final() => true,
                job => {
                    let why = job.map_or("job deleted".into(), |j| {
                        format!("job {}", j.life().state.name())
                    });
                    ended.insert(lease.clone(), why);
                    false
                }
            });
        if self.ended_leases.len() > ENDED_LEASES_KEPT {
            self.ended_leases.clear();
        }
        // Jobs every live worker is blocked from (the last one blocked may have gone since).
        let block = self.cfg.block_worker_after;
        let error = |j: &Job| {
            let mut error = format!(
                "every live worker failed this job {block} times, so none may take it any more"
            );
            // The cause, as the failure at a lease says it (the failures may be the memory's
            // only: a restart keeps the counts, not the messages).
            if let Some(f) = j.recent_failures.back() {
                let t = f.tile;
                error.push_str(&format!(
                    "; last error, from worker {} on tile [{}, {}) × [{}, {}) pass {}: {}",
                    f.worker, t.x0, t.x1, t.y0, t.y1, f.pass, f.error
                ));
            }
            error
        };
        #[allow(clippy::type_complexity)]
        let stuck: Vec<(String, JobLife, Vec<(usize, state::Task)>)> = self
            .jobs
            .values()
            .filter(|j| !j.is_final())
            .filter_map(|j| {
                let error = match expiring.get(&j.id) {
                    Some(e) => e.clone(),
                    None if !j.worker_failures.is_empty()
                        && self.workers.all_live_blocked(
                            &j.worker_failures,
                            block,
                            now.wall_ms,
                        ) =>
                    {
                        error(j)
                    }
                    None => return None,
                };
                let ev = JobEvent::Fail { error };
                let life = j.next_life(ev, now.wall_ms)?;
                Some((
                    j.id.clone(),
                    life,
                    leases_ending_with(&self.leases, &j.id, j),
                ))
            })
            .collect();
        let rows: Vec<(&str, TaskRow)> = stuck
            .iter()
            .flat_map(|(id, _, ended)| {
                ended
                    .iter()
                    .map(|(i, t)| (id.as_str(), Job::task_row(*i, t)))
            })
            .collect();
        let mut writes: Vec<Write> = stuck.iter().map(|(id, l, _)| life_write(id, l)).collect();
        writes.extend(rows.iter().map(|(job, row)| Write::Task { job, row }));
        self.store.write(&writes)?;
        for (id, life, ended) in stuck {
            tracing::warn!(job = %id, error = life.error.as_deref().unwrap_or(""), "failed");
            self.events.emit(|| job_state_event(&id, &life));
            if let Some(job) = self.jobs.get_mut(&id) {
                job.set_life(life);
                for (i, t) in ended {
                    job.set_task(i, t);
                }
            }
        }
        // Workers not heard from for a day are forgotten (their failure counts on jobs stay).
        let quiet = self.workers.forgettable(
            None,
            &self.leased_by(),
            FORGET_WORKERS_AFTER_MS,
            now.wall_ms,
        );
        if !quiet.is_empty() {
            let writes: Vec<Write> = quiet.iter().map(|w| Write::ForgetWorker(w)).collect();
            self.store.write(&writes)?;
            for w in &quiet {
                self.workers.remove(w);
                self.gone.remove(w);
            }
            self.events.emit(|| Event::Resync {
                reason: format!("{} workers not heard from for a day forgotten", quiet.len()),
            });
        }
        // Workers that went quiet, or came back.
        let (gone, back) = self.workers.liveness_changes(&self.gone, now.wall_ms);
        for w in gone {
            self.events.emit(|| Event::WorkerGone { worker: w.clone() });
            self.gone.insert(w);
        }
        for (w, last_seen_ms, tasks_done) in back {
            self.gone.remove(&w);
            self.events.emit(|| Event::WorkerSeen {
                worker: w,
                last_seen_ms,
                tasks_done,
            });
        }
        Ok(n)
    }

    /// The workers holding a lease.
    fn leased_by(&self) -> HashSet<&str> {
        self.leases
            .values()
            .filter_map(|(job, idx)| self.jobs.get(job)?.lease_of(*idx).map(|(w, _)| w))
            .collect()
    }

    /// Cancels a job at `now` if it is not finished. Returns its status, or `None` if unknown.
    pub fn cancel(&mut self, job_id: &str, now: Now) -> Result<Option<JobStatus>, SchedError> {
        let Some(job) = self.jobs.get_mut(job_id) else {
            return Ok(None);
        };
        if let Some(life) = job.next_life(JobEvent::Cancel, now.wall_ms) {
            let ended = leases_ending_with(&self.leases, job_id, job);
            let rows: Vec<TaskRow> = ended.iter().map(|(i, t)| Job::task_row(*i, t)).collect();
            let mut writes = vec![life_write(job_id, &life)];
            writes.extend(rows.iter().map(|row| Write::Task { job: job_id, row }));
            self.store.write(&writes)?;
            self.events.emit(|| job_state_event(job_id, &life));
            job.set_life(life);
            for (i, t) in ended {
                job.set_task(i, t);
            }
        }
        Ok(Some(job.status()))
    }

    /// Retries job `job_id` at `now`: a failed or cancelled job goes on (running, or queued if
    /// it never started) with the tiles it has, its failed tasks queued again and every task
    /// and worker starting over with no failures held against them. An unfinished job is
    /// left as it is. `None` if the job is unknown.
    pub fn retry(&mut self, job_id: &str, now: Now) -> Result<Option<Retried>, SchedError> {
        if let Some(why) = self.retry_refusal(job_id) {
            return Ok(Some(Retried::Refused(why)));
        }
        let Some(job) = self.jobs.get_mut(job_id) else {
            return Ok(None);
        };
        let state = job.life().state;
        if !matches!(state, JobState::Failed | JobState::Cancelled) {
            return Ok(Some(Retried::Unchanged(job.status())));
        }
        let life = job
            .next_life(JobEvent::Retry, now.wall_ms)
            .expect("a failed or cancelled job is retried");
        let mut changed = Vec::new();
        for i in 0..job.tasks().len() {
            let (out, task) = job.next_task(i, TaskEvent::Retry);
            if out == Outcome::Changed {
                changed.push((i, task));
            }
        }
        let rows: Vec<TaskRow> = changed.iter().map(|(i, t)| Job::task_row(*i, t)).collect();
        let mut writes = vec![life_write(job_id, &life), Write::ClearBlocked(job_id)];
        writes.extend(rows.iter().map(|row| Write::Task { job: job_id, row }));
        self.store.write(&writes)?;
        job.worker_failures.clear();
        // Leases the job's end ended may still be on record until the next expiry: they are
        // over (their tasks were queued), and must not end the tasks' new leases.
        let ended = &mut self.ended_leases;
        self.leases.retain(|lease, (j, _)| {
            if j == job_id {
                ended.insert(lease.clone(), format!("job {}", state.name()));
            }
            j != job_id
        });
        // Nor may a lease that expired before: its worker's heartbeat would take back a task
        // of the job's new life (whose expiries start again from zero).
        self.expired_leases.retain(|_, (j, ..)| j != job_id);
        let requeued: Vec<usize> = changed
            .iter()
            .filter(|(i, _)| job.tasks()[*i].state == state::TaskState::Failed)
            .map(|(i, _)| *i)
            .collect();
        for (i, t) in changed {
            job.set_task(i, t);
        }
        self.events.emit(|| job_state_event(job_id, &life));
        job.set_life(life);
        emit_queued(&mut self.events, job_id, job, &requeued, "retried");
        tracing::info!(job = %job_id, from = ?state, "job retried");
        Ok(Some(Retried::Resumed(job.status())))
    }

    /// Why job `job_id` cannot be retried: it is done, or another renderer made its tiles.
    /// `None` for a job that can be, one that is unfinished (a retry leaves it as it is), and
    /// an unknown one.
    pub fn retry_refusal(&self, job_id: &str) -> Option<String> {
        let job = self.jobs.get(job_id)?;
        match job.life().state {
            JobState::Done => Some(
                "the job is done: there is nothing to render again (submit it again to render \
                 it anew)"
                    .into(),
            ),
            JobState::Failed | JobState::Cancelled
                if job.render_version != Some(raytile_core::RENDER_VERSION) =>
            {
                Some(
                    "the job's tiles were made by another renderer version, which a frame \
                     cannot mix with this one's: submit it again instead"
                        .into(),
                )
            }
            _ => None,
        }
    }

    /// Cancels a job if it is not finished, then deletes it with its tiles from memory and the
    /// store. Returns its last status, or `None` if unknown. Workers still holding one of its
    /// leases learn it is gone at their next heartbeat; their results are refused (404).
    pub fn purge(&mut self, job_id: &str, now: Now) -> Result<Option<JobStatus>, SchedError> {
        if !self.jobs.contains_key(job_id) {
            return Ok(None);
        }
        self.store.write(&[Write::DeleteJob(job_id)])?;
        let mut job = self.jobs.remove(job_id).expect("checked above");
        if let Some(life) = job.next_life(JobEvent::Cancel, now.wall_ms) {
            job.set_life(life);
        }
        let ended = &mut self.ended_leases;
        self.leases.retain(|lease, (j, _)| {
            if j == job_id {
                ended.insert(lease.clone(), "job deleted".into());
            }
            j != job_id
        });
        self.events.emit(|| Event::JobPurged { job: job_id.into() });
        Ok(Some(job.status()))
    }

    /// Called now and then: checks that the database file is still there
    /// ([`Store::check_file`](crate::store::Store::check_file)), and gives back a few more of
    /// its free pages, if it holds any (what the purges' own
    /// [`Store::shrink`](crate::store::Store::shrink) left).
    pub fn tend_store(&self) {
        self.store.check_file();
        self.store.shrink(crate::store::SHRINK_PAGES);
    }

    /// Sets the priority of job `job_id`. Returns its status, or `None` if unknown.
    pub fn set_priority(
        &mut self,
        job_id: &str,
        priority: i32,
    ) -> Result<Option<JobStatus>, SchedError> {
        let Some(job) = self.jobs.get_mut(job_id) else {
            return Ok(None);
        };
        if job.priority != priority {
            self.store.write(&[Write::Priority {
                id: job_id,
                priority,
            }])?;
            job.priority = priority;
            self.events.emit(|| Event::JobPriority {
                job: job_id.into(),
                priority,
            });
        }
        Ok(Some(job.status()))
    }

    /// The store's fault switch (tests only).
    #[cfg(test)]
    pub fn store_faults(&self) -> crate::store::Faults {
        self.store.faults()
    }
}
