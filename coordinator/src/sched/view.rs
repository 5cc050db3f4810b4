//! Projections: the scheduler's state as the API shows it (`JobStatus`, `WorkerInfo`, the
//! metrics). Read-only; the handlers get these values and never the state itself.

use super::jobs::Job;
use super::metrics::Metrics;
use super::order::TaskLayout;
use super::state::TaskState;
use super::Sched;
use crate::clock::Now;
use raytile_proto::{
    CurrentTask, JobState, JobStatus, TileList, TileProgress, WorkerInfo, WorkerShare,
};
use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;

impl Job {
    /// The job as the API shows it.
    pub(super) fn status(&self) -> JobStatus {
        let mut workers: BTreeMap<String, WorkerShare> = BTreeMap::new();
        let (mut done, mut leased, mut samples_done, mut samples_total) = (0u64, 0u64, 0u64, 0u64);
        let layout = &self.layout;
        let mut tile_passes_done = vec![0u32; layout.tile_count()];
        for (i, t) in self.tasks().iter().enumerate() {
            let work = layout.task(i).expect("one task per layout slot");
            let s = work.sample_count();
            samples_total += s;
            match &t.state {
                TaskState::Done { worker } => {
                    done += 1;
                    samples_done += s;
                    tile_passes_done[work.tile_index as usize] += 1;
                    let w = workers.entry(worker.clone()).or_default();
                    w.tasks += 1;
                    w.samples += s;
                }
                TaskState::Leased { .. } => leased += 1,
                _ => {}
            }
        }
        let npasses = layout.pass_count() as u32;
        let passes_done = (0..layout.pass_count())
            .take_while(|&p| {
                self.tasks()[layout.pass_tasks(p)]
                    .iter()
                    .all(|t| matches!(t.state, TaskState::Done { .. }))
            })
            .count() as u32;
        let life = self.life();
        JobStatus {
            id: self.id.clone(),
            scene: self.scene.clone(),
            state: life.state,
            priority: self.priority,
            settings: self.settings.clone(),
            tiles_total: layout.tile_count() as u64,
            tiles_done: tile_passes_done.iter().filter(|&&n| n == npasses).count() as u64,
            passes: npasses,
            passes_done,
            tasks_total: self.tasks().len() as u64,
            tasks_done: done,
            tasks_leased: leased,
            samples_done,
            samples_total,
            workers,
            created_ms: life.created_ms,
            started_ms: life.started_ms,
            finished_ms: life.finished_ms,
            error: life.error.clone(),
            failures: self.recent_failures.iter().cloned().collect(),
        }
    }
}

impl Sched {
    /// The status of job `id`, or `None` if it is unknown.
    pub fn job_status(&self, id: &str) -> Option<JobStatus> {
        self.jobs.get(id).map(Job::status)
    }

    /// Every job's status, in submission order.
    pub fn job_list(&self) -> Vec<JobStatus> {
        self.job_page(&[], 0, usize::MAX).0
    }

    /// One page of the job list, oldest first: the jobs submitted after the `after`-th (0:
    /// from the first) in one of `states` (empty: any), at most `limit`; and, when jobs were
    /// left out, the id of the last one given (to ask for the next page).
    pub fn job_page(
        &self,
        states: &[JobState],
        after: u64,
        limit: usize,
    ) -> (Vec<JobStatus>, Option<String>) {
        let mut jobs: Vec<&Job> = self
            .jobs
            .values()
            .filter(|j| j.seq > after)
            .filter(|j| states.is_empty() || states.contains(&j.life().state))
            .collect();
        jobs.sort_by_key(|j| j.seq);
        let more = jobs.len() > limit;
        jobs.truncate(limit);
        let next = more.then(|| jobs.last().map(|j| j.id.clone())).flatten();
        (jobs.into_iter().map(Job::status).collect(), next)
    }

    /// Each tile of job `id` with its passes done and the workers rendering it, or `None`.
    pub fn tile_list(&self, id: &str) -> Option<TileList> {
        let j = self.jobs.get(id)?;
        let layout = &j.layout;
        let mut tiles: Vec<TileProgress> = Vec::with_capacity(layout.tile_count());
        let mut by_index: Vec<usize> = vec![usize::MAX; layout.tile_count()];
        for (i, t) in j.tasks().iter().enumerate() {
            let work = layout.task(i).expect("one task per layout slot");
            let slot = &mut by_index[work.tile_index as usize];
            if *slot == usize::MAX {
                *slot = tiles.len();
                tiles.push(TileProgress {
                    tile: work.tile,
                    passes_done: 0,
                    workers: Vec::new(),
                });
            }
            let tp = &mut tiles[*slot];
            match &t.state {
                TaskState::Done { .. } => tp.passes_done += 1,
                TaskState::Leased { worker, .. } if !tp.workers.contains(worker) => {
                    tp.workers.push(worker.clone())
                }
                _ => {}
            }
        }
        tiles.sort_by_key(|t| (t.tile.y0, t.tile.x0));
        Some(TileList {
            event_id: self.events.last_id(),
            passes: layout.pass_count() as u32,
            tiles,
        })
    }

    /// A name for the current state of job `id`'s stored results, or `None` for an unknown
    /// job: it changes whenever a result is stored (and at every start of the coordinator),
    /// so two images of the job made under the same name are the same bytes.
    pub fn results_version(&self, id: &str) -> Option<String> {
        let job = self.jobs.get(id)?;
        Some(format!(
            "{:x}-{:x}",
            self.ids.epoch(),
            job.results_changes()
        ))
    }

    /// Why job `id` has no frame to show: it ended, failed or cancelled, before any task was
    /// done, so every pixel of its image would be black. `None` for an unknown job, and for
    /// one whose frame has something (or may yet have: a queued or running job's frame is a
    /// preview).
    pub fn no_image(&self, id: &str) -> Option<String> {
        let job = self.jobs.get(id)?;
        let life = job.life();
        if job.tasks_done() > 0 {
            return None;
        }
        let why = match life.state {
            JobState::Failed => format!(
                "job '{id}' failed before any tile was finished, so it has no image ({})",
                life.error.as_deref().unwrap_or("no reason recorded")
            ),
            JobState::Cancelled => {
                format!("job '{id}' was cancelled before any tile was finished, so it has no image")
            }
            _ => return None,
        };
        Some(why)
    }

    /// The task layout of job `id` (to compose its frame outside the lock), or `None`.
    pub fn layout(&self, id: &str) -> Option<Arc<TaskLayout>> {
        self.jobs.get(id).map(|j| j.layout.clone())
    }

    /// The settings of job `id`.
    pub fn settings(&self, id: &str) -> Option<raytile_proto::settings::RenderSettings> {
        self.jobs.get(id).map(|j| j.settings.clone())
    }

    /// Every registered worker at `now`, in registration order.
    pub fn worker_list(&self, now: Now) -> Vec<WorkerInfo> {
        let mut current: HashMap<&str, Vec<CurrentTask>> = HashMap::new();
        let mut jobs: Vec<&Job> = self.jobs.values().filter(|j| !j.is_final()).collect();
        jobs.sort_by_key(|j| j.seq);
        for j in jobs {
            for (i, t) in j.tasks().iter().enumerate() {
                if let TaskState::Leased { worker, .. } = &t.state {
                    let work = j.work(i).expect("one task per layout slot");
                    current.entry(worker).or_default().push(CurrentTask {
                        job: j.id.clone(),
                        task: i as u32,
                        tile: work.tile,
                        pass: work.pass,
                    });
                }
            }
        }
        let mut workers: Vec<WorkerInfo> = self
            .workers
            .iter()
            .map(|(id, w)| {
                let current = current.remove(id.as_str()).unwrap_or_default();
                let state = if !self.workers.is_live_id(id, now.wall_ms) {
                    "gone"
                } else if current.is_empty() {
                    "idle"
                } else {
                    "rendering"
                };
                WorkerInfo {
                    id: id.clone(),
                    name: w.name.clone(),
                    threads: w.threads,
                    registered_ms: w.registered_ms,
                    last_seen_ms: w.last_seen_ms,
                    leased: current.len() as u64,
                    tasks_done: w.tasks_done,
                    failures: w.failures,
                    state: state.into(),
                    current,
                    samples_per_second: self
                        .rates
                        .get(id)
                        .map_or(0.0, |r| r.per_second_at(now.instant)),
                    render_version: raytile_core::RENDER_VERSION,
                }
            })
            .collect();
        workers.sort_by(|a, b| a.registered_ms.cmp(&b.registered_ms).then(a.id.cmp(&b.id)));
        workers
    }

    /// Everything `/metrics` shows, at `now` (older throughput entries are dropped).
    pub fn metrics(&mut self, now: Now) -> Metrics {
        let mut by_state: HashMap<JobState, u64> = HashMap::new();
        for j in self.jobs.values() {
            *by_state.entry(j.life().state).or_insert(0) += 1;
        }
        Metrics {
            jobs: JobState::ALL
                .into_iter()
                .map(|s| (s, by_state.get(&s).copied().unwrap_or(0)))
                .collect(),
            counters: self.counters.clone(),
            workers: self.workers.len(),
            workers_live: self
                .workers
                .iter()
                .filter(|(id, _)| self.workers.is_live_id(id, now.wall_ms))
                .count(),
            samples_per_second: self.throughput.per_second(now.instant),
        }
    }
}
