//! Scheduler tests over a real store, with synthetic results (made-up tile sums, so nothing
//! here needs the renderer) and a clock the tests drive.

use super::*;
use raytile_core::TileAccum;
use tokio::time::Instant;

fn cfg() -> SchedConfig {
    SchedConfig {
        lease_timeout: Duration::from_secs(10),
        max_task_failures: 3,
        block_worker_after: 2,
    }
}

fn small(passes: u32) -> RenderSettings {
    RenderSettings {
        width: 32,
        height: 32,
        tile_size: 16,
        spp: 4,
        passes,
        ..Default::default()
    }
}

/// A start time far from the system clock's, so a value read from the system clock would show.
fn t0() -> Now {
    Now {
        instant: Instant::now(),
        wall_ms: 1_000_000_000,
    }
}

fn secs(n: u64) -> Duration {
    Duration::from_secs(n)
}

fn open_with(dir: &std::path::Path, cfg: SchedConfig, now: Now, grace: Duration) -> Sched {
    Sched::restore(cfg, Store::open(dir).unwrap(), now, grace).unwrap()
}

fn open(dir: &std::path::Path, now: Now) -> Sched {
    open_with(dir, cfg(), now, secs(5))
}

/// Uploads made-up sums for task `idx` of `job` as `worker`.
fn deliver(s: &mut Sched, job: &str, idx: u32, worker: &str, now: Now) -> ResultOutcome {
    let (tile, pass) = s.task_for_upload(job, idx).unwrap();
    let acc = TileAccum {
        tile,
        pixels: vec![[pass as f32 + 0.5, 1.0, 2.0, 1.0]; tile.pixel_count()],
        bad_samples: 0,
        splats: Vec::new(),
        coverage: Vec::new(),
    };
    let bytes = raytile_proto::tile::encode(&acc, pass);
    let d = Delivery {
        worker,
        tile,
        pass,
        bytes: &bytes,
        file: None,
    };
    s.complete(job, idx, d, now).unwrap()
}

/// Leases the next task to `w` and delivers it; `None` when there is none.
fn finish(s: &mut Sched, w: &str, now: Now) -> Option<Grant> {
    let g = s.lease(w, now).unwrap()?;
    assert_eq!(deliver(s, &g.job, g.task, w, now), ResultOutcome::Accepted);
    Some(g)
}

/// `create_job` with the layout made here, as the API makes it before taking the lock.
trait NewJob {
    fn new_job(
        &mut self,
        scene: String,
        settings: RenderSettings,
        priority: i32,
        now: Now,
    ) -> Result<JobStatus, SchedError>;
}

impl NewJob for Sched {
    fn new_job(
        &mut self,
        scene: String,
        settings: RenderSettings,
        priority: i32,
        now: Now,
    ) -> Result<JobStatus, SchedError> {
        let layout = Arc::new(TaskLayout::new(&settings));
        self.create_job(scene, settings, layout, priority, now)
    }
}

fn state_of(s: &Sched, job: &str) -> JobState {
    s.job_status(job).unwrap().state
}

#[test]
fn priority_then_fifo_then_pass_order() {
    let dir = tempfile::tempdir().unwrap();
    let now = t0();
    let mut s = open(dir.path(), now);
    let w = s.register("w", 1, now).unwrap();
    let a = s.new_job("s".into(), small(2), 0, now).unwrap().id;
    let b = s.new_job("s".into(), small(2), 5, now).unwrap().id;
    let c = s.new_job("s".into(), small(2), 0, now).unwrap().id;
    let mut grants = Vec::new();
    while let Some(g) = finish(&mut s, &w, now) {
        grants.push(g);
    }
    let n = s.job_status(&a).unwrap().tasks_total as usize;
    assert_eq!(grants.len(), 3 * n);
    assert!(
        grants[..n].iter().all(|g| g.job == b),
        "high priority first"
    );
    assert!(grants[n..2 * n].iter().all(|g| g.job == a), "then FIFO");
    assert!(grants[2 * n..].iter().all(|g| g.job == c));
    // Within a job: every tile of pass 0 before any of pass 1, the centre tile first.
    let passes: Vec<u32> = grants[n..2 * n].iter().map(|g| g.work.pass).collect();
    assert!(passes.windows(2).all(|w| w[0] <= w[1]), "{passes:?}");
    assert_eq!(passes.iter().filter(|&&p| p == 0).count(), n / 2);
    assert!(s.job_list().iter().all(|j| j.state == JobState::Done));
}

#[test]
fn the_extreme_priorities_order_without_overflow() {
    // A priority is any i32: i32::MIN once panicked the queue's ordering (it negated it).
    let dir = tempfile::tempdir().unwrap();
    let now = t0();
    let mut s = open(dir.path(), now);
    let w = s.register("w", 1, now).unwrap();
    let low = s.new_job("s".into(), small(2), i32::MIN, now).unwrap().id;
    let high = s.new_job("s".into(), small(2), i32::MAX, now).unwrap().id;
    let first = finish(&mut s, &w, now).unwrap();
    assert_eq!(first.job, high);
    let mut last = first;
    while let Some(g) = finish(&mut s, &w, now) {
        last = g;
    }
    assert_eq!(last.job, low);
}

#[test]
fn timestamps_come_from_the_callers_clock() {
    let dir = tempfile::tempdir().unwrap();
    let start = t0();
    let mut s = open(dir.path(), start);
    let w = s.register("w", 1, start.after(secs(1))).unwrap();
    let job = s
        .new_job("s".into(), small(1), 0, start.after(secs(2)))
        .unwrap()
        .id;
    finish(&mut s, &w, start.after(secs(3))).unwrap();
    while finish(&mut s, &w, start.after(secs(4))).is_some() {}
    let st = s.job_status(&job).unwrap();
    let ms = |n: u64| start.wall_ms + 1000 * n;
    assert_eq!(
        (st.created_ms, st.started_ms, st.finished_ms),
        (ms(2), Some(ms(3)), Some(ms(4)))
    );
    let info = &s.worker_list(t0())[0];
    assert_eq!((info.registered_ms, info.last_seen_ms), (ms(1), ms(4)));
    let cancelled = s
        .new_job("s".into(), small(1), 0, start.after(secs(5)))
        .unwrap()
        .id;
    let st = s.cancel(&cancelled, start.after(secs(6))).unwrap().unwrap();
    assert_eq!((st.started_ms, st.finished_ms), (None, Some(ms(6))));
    // Throughput: every sample of the first job within ten seconds of `start + 4 s`.
    let total = s.job_status(&job).unwrap().samples_total as f64;
    let m = s.metrics(start.after(secs(4)));
    assert_eq!(m.samples_per_second, total / 10.0);
    assert_eq!(s.metrics(start.after(secs(15))).samples_per_second, 0.0);
}

#[test]
fn expired_leases_are_requeued_and_late_results_are_duplicates() {
    let dir = tempfile::tempdir().unwrap();
    let t0 = t0();
    let mut s = open(dir.path(), t0);
    let w1 = s.register("w1", 1, t0).unwrap();
    let w2 = s.register("w2", 1, t0).unwrap();
    let job = s.new_job("s".into(), small(1), 0, t0).unwrap().id;
    let g = s.lease(&w1, t0).unwrap().unwrap();
    assert_eq!(s.expire(t0.after(secs(5))).unwrap(), 0);
    assert_eq!(s.heartbeat(&g.lease, t0.after(secs(5))), Heartbeat::Renewed);
    // Renewed at 5 s: still alive at 14 s, gone at 15 s.
    assert_eq!(s.expire(t0.after(secs(14))).unwrap(), 0);
    assert_eq!(s.expire(t0.after(secs(15))).unwrap(), 1);
    let g2 = s.lease(&w2, t0.after(secs(15))).unwrap().unwrap();
    assert_eq!(g.task, g2.task, "the expired task is leased again first");
    // Taken by another: the first worker's heartbeat stops it.
    assert!(matches!(
        s.heartbeat(&g.lease, t0.after(secs(15))),
        Heartbeat::Stop { .. }
    ));
    let now = t0.after(secs(16));
    assert_eq!(
        deliver(&mut s, &job, g.task, &w2, now),
        ResultOutcome::Accepted
    );
    // The first worker's late result, and a plain duplicate.
    assert_eq!(
        deliver(&mut s, &job, g.task, &w1, now),
        ResultOutcome::Duplicate
    );
    let m = s.metrics(now);
    assert_eq!((m.counters.duplicates, m.counters.expired), (1, 1));
    // A result for the wrong pixels is refused.
    let (other, pass) = s.task_for_upload(&job, g.task + 1).unwrap();
    let d = Delivery {
        worker: &w1,
        tile: other,
        pass,
        bytes: &[],
        file: None,
    };
    let Err(SchedError::Mismatch(m)) = s.complete(&job, g.task, d, now) else {
        panic!("a result for other pixels must be refused");
    };
    // Tiles named as everywhere else: `[x0, x1) × [y0, y1)`.
    let (tile, _) = s.task_for_upload(&job, g.task).unwrap();
    let want = format!(
        "result is for tile [{}, {}) × [{}, {}) pass {pass}, task {} is tile [{}, {}) × [{}, {})",
        other.x0, other.x1, other.y0, other.y1, g.task, tile.x0, tile.x1, tile.y0, tile.y1
    );
    assert!(m.starts_with(&want), "{m}");
}

/// A worker stopped past its lease (SIGSTOP, a suspended laptop) takes its task back at its
/// next heartbeat while nobody else has, and goes on; not once another took it, nor once it
/// is blocked from the job or the job ended.
#[test]
fn an_expired_lease_comes_back_to_its_worker_while_nobody_took_the_task() {
    let dir = tempfile::tempdir().unwrap();
    let t0 = t0();
    let mut s = open(dir.path(), t0);
    let w1 = s.register("w1", 1, t0).unwrap();
    let w2 = s.register("w2", 1, t0).unwrap();
    let job = s.new_job("s".into(), small(1), 0, t0).unwrap().id;
    let g = s.lease(&w1, t0).unwrap().unwrap();
    assert_eq!(s.expire(t0.after(secs(10))).unwrap(), 1);
    // Back: the same lease lives again, with a new deadline.
    let back = t0.after(secs(30));
    assert_eq!(s.heartbeat(&g.lease, back), Heartbeat::Renewed);
    assert_eq!(s.expire(back.after(secs(9))).unwrap(), 0);
    assert_eq!(
        s.heartbeat(&g.lease, back.after(secs(9))),
        Heartbeat::Renewed
    );
    // The other worker is given other tasks, not this one.
    let g2 = s.lease(&w2, back).unwrap().unwrap();
    assert_ne!(g2.task, g.task);
    let now = back.after(secs(10));
    assert_eq!(
        deliver(&mut s, &job, g.task, &w1, now),
        ResultOutcome::Accepted
    );
    let c = s.metrics(now).counters;
    assert_eq!((c.expired, c.revived, c.leased), (1, 1, 2));

    // Expired, then taken by the other worker: not given back.
    let g3 = s.lease(&w1, now).unwrap().unwrap();
    let later = now.after(secs(60));
    s.heartbeat(&g2.lease, now.after(secs(55)));
    assert_eq!(s.expire(later).unwrap(), 1, "w1's lease alone");
    let g4 = s.lease(&w2, later).unwrap().unwrap();
    assert_eq!(g4.task, g3.task);
    let Heartbeat::Stop { reason } = s.heartbeat(&g3.lease, later) else {
        panic!("taken by another");
    };
    assert!(reason.contains("another worker"), "{reason}");

    // Expired in a job that was cancelled since: not given back.
    let job2 = s.new_job("s".into(), small(1), 0, later).unwrap().id;
    let mut g5 = s.lease(&w1, later).unwrap().unwrap();
    while g5.job != job2 {
        g5 = s.lease(&w1, later).unwrap().unwrap();
    }
    let end = later.after(secs(100));
    s.expire(end).unwrap();
    s.cancel(&job2, end).unwrap();
    let Heartbeat::Stop { reason } = s.heartbeat(&g5.lease, end) else {
        panic!("cancelled");
    };
    assert_eq!(reason, "job cancelled");
    // Nor after the job was retried: the old lease belongs to the job's former life.
    s.retry(&job2, end).unwrap();
    assert!(matches!(
        s.heartbeat(&g5.lease, end),
        Heartbeat::Stop { .. }
    ));

    // Expired while its worker got itself blocked from the job: not given back.
    let job3 = s.new_job("s".into(), small(1), 0, end).unwrap().id;
    let w3 = s.register("w3", 1, end).unwrap();
    // Another live worker, so that the job is not failed as one every live worker is blocked
    // from.
    s.register("w4", 1, end).unwrap();
    let mut mine = Vec::new();
    while mine.len() < 3 {
        let g = s.lease(&w3, end).unwrap().unwrap();
        if g.job == job3 {
            mine.push(g);
        }
    }
    for g in &mine[1..] {
        assert!(s.fail(&g.lease, "broken", end).unwrap());
    }
    let last = end.after(secs(20));
    s.expire(last).unwrap();
    assert!(matches!(
        s.heartbeat(&mine[0].lease, last),
        Heartbeat::Stop { .. }
    ));
    assert!(!s.job_status(&job3).unwrap().state.is_final());
}

#[test]
fn leases_extended_after_a_pause_expire_only_after_the_extension() {
    let dir = tempfile::tempdir().unwrap();
    let now = t0();
    let mut s = open_with(dir.path(), cfg(), now, Duration::ZERO);
    let w = s.register("w", 1, now).unwrap();
    s.new_job("s".into(), small(1), 0, now).unwrap();
    let g = s.lease(&w, now).unwrap().unwrap();
    // The lease lives 10 s; the coordinator was away for 60 s and extends it by 30.
    let back = now.after(secs(60));
    assert_eq!(s.extend_leases(back.instant + secs(30)), 1);
    assert_eq!(
        s.extend_leases(back.instant + secs(5)),
        0,
        "never shortened"
    );
    assert_eq!(s.expire(back.after(secs(29))).unwrap(), 0);
    assert_eq!(
        s.heartbeat(&g.lease, back.after(secs(29))),
        Heartbeat::Renewed
    );
    // The heartbeat renewed it for its usual 10 s from then.
    assert_eq!(s.expire(back.after(secs(38))).unwrap(), 0);
    assert_eq!(s.expire(back.after(secs(40))).unwrap(), 1);
}

#[test]
fn repeated_failures_fail_the_job_and_block_the_worker() {
    let dir = tempfile::tempdir().unwrap();
    let now = t0();
    let mut s = open(dir.path(), now);
    let bad = s.register("bad", 1, now).unwrap();
    let good = s.register("good", 1, now).unwrap();
    let job = s.new_job("s".into(), small(1), 0, now).unwrap().id;
    // The task bad failed waits for good, which may take it: bad gets the next one.
    for task in [0, 1] {
        let g = s.lease(&bad, now).unwrap().unwrap();
        assert_eq!(g.task, task);
        assert!(s.fail(&g.lease, "out of memory", now).unwrap());
    }
    assert!(
        s.lease(&bad, now).unwrap().is_none(),
        "blocked after two failures"
    );
    let g = s.lease(&good, now).unwrap().unwrap();
    assert_eq!(g.task, 0);
    assert!(s.fail(&g.lease, "disk full", now).unwrap());
    assert_eq!(state_of(&s, &job), JobState::Running);
    // No other worker may take task 0 now: good takes it again.
    let g = s.lease(&good, now).unwrap().unwrap();
    assert_eq!(g.task, 0);
    assert!(s.fail(&g.lease, "disk full", now).unwrap());
    let j = s.job_status(&job).unwrap();
    assert_eq!(j.state, JobState::Failed);
    let err = j.error.as_deref().unwrap();
    assert!(
        err.contains("failed 3 times") && err.contains("disk full"),
        "{err}"
    );
    assert!(s.lease(&good, now).unwrap().is_none());
    let failures: Vec<u64> = s.worker_list(t0()).iter().map(|w| w.failures).collect();
    assert_eq!(failures, [2, 2]);
}

#[test]
fn one_broken_worker_does_not_fail_a_job_that_others_can_render() {
    // A worker that fails every task it gets (too little memory for the scene) beside a
    // healthy one: the job is rendered. It used to take the task it had just failed again at
    // once, three times, and fail the job before the healthy worker got to it.
    let dir = tempfile::tempdir().unwrap();
    let now = t0();
    let mut s = open(dir.path(), now);
    let bad = s.register("bad", 1, now).unwrap();
    let good = s.register("good", 1, now).unwrap();
    let job = s.new_job("s".into(), small(1), 0, now).unwrap().id;
    loop {
        if let Some(g) = s.lease(&bad, now).unwrap() {
            assert!(s
                .fail(&g.lease, "scene over --scene-memory-mb", now)
                .unwrap());
        }
        if finish(&mut s, &good, now).is_none() {
            break;
        }
    }
    let j = s.job_status(&job).unwrap();
    assert_eq!(j.state, JobState::Done, "{:?}", j.error);
    // Alone, a worker retakes the task it failed (the job does not wait for another): its
    // failures end the job.
    let dir2 = tempfile::tempdir().unwrap();
    let mut alone = open(dir2.path(), now);
    let w = alone.register("w", 1, now).unwrap();
    let one = RenderSettings {
        width: 16,
        height: 16,
        ..small(1)
    };
    let only = alone.new_job("s".into(), one, 0, now).unwrap().id;
    for _ in 0..2 {
        let g = alone.lease(&w, now).unwrap().unwrap();
        assert_eq!(g.task, 0);
        assert!(alone.fail(&g.lease, "broken", now).unwrap());
    }
    assert_eq!(state_of(&alone, &only), JobState::Failed);
}

#[test]
fn a_job_every_live_worker_is_blocked_from_fails_instead_of_waiting() {
    let dir = tempfile::tempdir().unwrap();
    let start = t0();
    // Tasks may fail often (10 times) but a worker is blocked after 2 failures.
    let config = SchedConfig {
        max_task_failures: 10,
        ..cfg()
    };
    let mut s = open_with(dir.path(), config.clone(), start, Duration::ZERO);
    // A worker last seen at the start, long before the others fail: it does not keep the
    // job alive (live: seen within a minute, as the lease timeout is 10 s).
    s.register("gone", 1, start).unwrap();
    let now = start.after(secs(120));
    let a = s.register("a", 1, now).unwrap();
    let b = s.register("b", 1, now).unwrap();
    let job = s.new_job("s".into(), small(2), 0, now).unwrap().id;
    // Each worker fails twice: no task reaches 10 failures, both get blocked.
    for w in [&a, &b] {
        for _ in 0..2 {
            let g = s.lease(w, now).unwrap().unwrap();
            assert!(s.fail(&g.lease, &format!("no GPU on {w}"), now).unwrap());
        }
        if *w == a {
            assert_eq!(state_of(&s, &job), JobState::Running, "b may still take it");
        }
    }
    let j = s.job_status(&job).unwrap();
    assert_eq!(j.state, JobState::Failed);
    let err = j.error.as_deref().unwrap();
    assert!(
        err.contains("every worker") && err.contains("no GPU"),
        "{err}"
    );
    // The expiry tick fails a job once the peers of its last blocked worker have gone.
    let job2 = s.new_job("s".into(), small(1), 0, now).unwrap().id;
    for _ in 0..2 {
        let g = s.lease(&a, now).unwrap().unwrap();
        assert!(s.fail(&g.lease, "no GPU", now).unwrap());
    }
    assert_eq!(state_of(&s, &job2), JobState::Running, "b is live");
    // A minute without b: still live at the edge of the window.
    s.expire(now.after(secs(60))).unwrap();
    assert_eq!(state_of(&s, &job2), JobState::Running, "b is live for 60 s");
    // a calls in (and gets nothing: it is blocked); b has not for more than a minute.
    let later = now.after(secs(61));
    assert!(s.lease(&a, later).unwrap().is_none());
    let m = s.metrics(later);
    assert_eq!((m.workers, m.workers_live), (3, 1), "a alone is live");
    s.expire(later).unwrap();
    let j2 = s.job_status(&job2).unwrap();
    assert_eq!(j2.state, JobState::Failed);
    let err = j2.error.as_deref().unwrap();
    assert!(err.contains("every live worker"), "{err}");
    // With the cause, as a failure at a lease says it.
    assert!(
        err.contains("last error") && err.contains("no GPU"),
        "{err}"
    );
    // With no live worker at all, nothing is failed: workers may come back. Here a and b
    // are blocked while c may take the job; then nobody calls in for an hour.
    s.register("c", 1, later).unwrap();
    let job3 = s.new_job("s".into(), small(1), 0, later).unwrap().id;
    for w in [&a, &b] {
        for _ in 0..2 {
            let g = s.lease(w, later).unwrap().unwrap();
            assert!(s.fail(&g.lease, "oops", later).unwrap());
        }
    }
    assert_eq!(state_of(&s, &job3), JobState::Running, "c may take it");
    s.expire(later.after(secs(3600))).unwrap();
    assert_eq!(state_of(&s, &job3), JobState::Running, "nobody is live");
    // Persisted: a restarted coordinator sees the jobs failed.
    drop(s);
    let s = open_with(dir.path(), config, later, Duration::ZERO);
    assert_eq!(state_of(&s, &job), JobState::Failed);
    assert_eq!(state_of(&s, &job2), JobState::Failed);
}

#[test]
fn after_a_restart_workers_count_as_live_until_they_could_have_called_in() {
    let dir = tempfile::tempdir().unwrap();
    let start = t0();
    let (a, job) = {
        let mut s = open(dir.path(), start);
        let a = s.register("a", 1, start).unwrap();
        s.register("b", 1, start).unwrap();
        let job = s.new_job("s".into(), small(1), 0, start).unwrap().id;
        for _ in 0..2 {
            let g = s.lease(&a, start).unwrap().unwrap();
            assert!(s.fail(&g.lease, "no GPU", start).unwrap());
        }
        (a, job)
    };
    // An hour later: both workers were last seen an hour ago, but the coordinator has just
    // started, so b may still call in; a's block is restored.
    let restart = start.after(secs(3600));
    let mut s = open(dir.path(), restart);
    s.expire(restart.after(secs(1))).unwrap();
    assert_eq!(state_of(&s, &job), JobState::Running);
    assert!(s.lease(&a, restart.after(secs(61))).unwrap().is_none());
    s.expire(restart.after(secs(61))).unwrap();
    assert_eq!(state_of(&s, &job), JobState::Failed, "b never came back");
}

#[test]
fn workers_registering_again_replace_their_old_registration_and_quiet_ones_are_forgotten() {
    let dir = tempfile::tempdir().unwrap();
    let start = t0();
    let names = |s: &Sched| -> Vec<String> {
        let mut n: Vec<String> = s.worker_list(t0()).into_iter().map(|w| w.name).collect();
        n.sort();
        n
    };
    let (a, b) = {
        let mut s = open(dir.path(), start);
        let a = s.register("a", 1, start).unwrap();
        let b = s.register("b", 1, start).unwrap();
        s.new_job("s".into(), small(1), 0, start).unwrap();
        s.lease(&b, start).unwrap().unwrap();
        (a, b)
    };
    // The coordinator restarts; a's process restarted too and registers again under its name:
    // the registration it had, not heard from since, is forgotten. b, which holds a lease,
    // is kept.
    let restart = start.after(secs(10));
    let mut s = open(dir.path(), restart);
    let a2 = s.register("a", 1, restart).unwrap();
    let b2 = s.register("b", 1, restart).unwrap();
    assert_eq!(names(&s), ["a", "b", "b"]);
    assert!(matches!(s.lease(&a, restart), Err(SchedError::NoWorker(_))));
    // Two live workers of one name are both kept.
    let a3 = s.register("a", 1, restart).unwrap();
    assert_eq!(names(&s), ["a", "a", "b", "b"]);
    // A day without a word: forgotten, the store too; the others were seen since.
    let day = restart.after(Duration::from_millis(FORGET_WORKERS_AFTER_MS) + secs(120));
    s.lease(&a2, day).unwrap();
    s.lease(&b2, day).unwrap();
    s.expire(day).unwrap();
    let left: Vec<String> = s.worker_list(day).into_iter().map(|w| w.id).collect();
    assert!(left.contains(&a2) && left.contains(&b2), "{left:?}");
    assert!(!left.contains(&a3) && !left.contains(&b), "{left:?}");
    drop(s);
    let s = open(dir.path(), day);
    assert_eq!(names(&s), ["a", "b"]);
}

#[test]
fn restart_resumes_without_redoing_finished_tasks() {
    let dir = tempfile::tempdir().unwrap();
    let t0 = t0();
    let (job, out, w) = {
        let mut s = open(dir.path(), t0);
        let w = s.register("w", 1, t0).unwrap();
        let job = s.new_job("s".into(), small(2), 0, t0).unwrap().id;
        for _ in 0..3 {
            finish(&mut s, &w, t0).unwrap();
        }
        let g = s.lease(&w, t0).unwrap().unwrap();
        (job, g, w)
    };
    let t1 = t0.after(secs(100));
    let mut s = open(dir.path(), t1);
    let st = s.job_status(&job).unwrap();
    assert_eq!((st.tasks_done, st.tasks_leased), (3, 1));
    // The old lease survives the restart with a grace period (5 s), and can still deliver.
    assert_eq!(s.heartbeat(&out.lease, t1), Heartbeat::Renewed);
    assert_eq!(s.expire(t1.after(secs(9))).unwrap(), 0, "renewed at t1");
    assert_eq!(
        deliver(&mut s, &job, out.task, &w, t1),
        ResultOutcome::Accepted
    );
    let mut leased = std::collections::HashSet::new();
    while let Some(g) = finish(&mut s, &w, t1) {
        assert!(leased.insert(g.task));
        assert_ne!(g.lease, out.lease, "a new lease id after the restart");
    }
    assert_eq!(
        leased.len() as u64,
        st.tasks_total - 4,
        "no finished task redone"
    );
    assert_eq!(state_of(&s, &job), JobState::Done);
}

/// Stored states that contradict the stored tasks (a row edited by hand, or damaged) are
/// mended at a start: a done job lacking a task renders it, a running one whose tasks are all
/// done is done; unknown state names read as queued.
#[test]
fn a_restart_mends_job_states_their_tasks_contradict() {
    let dir = tempfile::tempdir().unwrap();
    let t0 = t0();
    let (job, total) = {
        let mut s = open(dir.path(), t0);
        let w = s.register("w", 1, t0).unwrap();
        let job = s.new_job("s".into(), small(1), 0, t0).unwrap().id;
        while finish(&mut s, &w, t0).is_some() {}
        assert_eq!(state_of(&s, &job), JobState::Done);
        let total = s.job_status(&job).unwrap().tasks_total;
        (job, total)
    };
    let edit = |sql: &str| {
        let db = rusqlite::Connection::open(dir.path().join("raytile.sqlite3")).unwrap();
        db.execute_batch(sql).unwrap();
    };
    edit("UPDATE tasks SET state = 'bogus' WHERE idx = 1");
    let t1 = t0.after(secs(100));
    let mut s = open(dir.path(), t1);
    let st = s.job_status(&job).unwrap();
    assert_eq!((st.state, st.tasks_done), (JobState::Running, total - 1));
    let w = s.register("w2", 1, t1).unwrap();
    let g = finish(&mut s, &w, t1).expect("the task queued again");
    assert_eq!(g.task, 1);
    assert_eq!(state_of(&s, &job), JobState::Done);
    drop(s);
    edit("UPDATE jobs SET state = 'exploded'");
    let s = open(dir.path(), t1.after(secs(100)));
    assert_eq!(state_of(&s, &job), JobState::Done);
}

/// A task whose workers keep vanishing while they hold it (killed or out of memory on its
/// scene, where a worker cannot report a failure) fails its job after a few expiries, naming
/// the tile, instead of being handed out for ever.
#[test]
fn a_task_whose_workers_keep_vanishing_fails_its_job() {
    let dir = tempfile::tempdir().unwrap();
    let mut now = t0();
    let mut s = open(dir.path(), now);
    let job = s.new_job("s".into(), small(1), 0, now).unwrap().id;
    let limit = cfg().max_task_expiries();
    assert_eq!(limit, 5);
    for n in 1..=limit {
        let w = s.register(&format!("w{n}"), 1, now).unwrap();
        let g = s.lease(&w, now).unwrap().unwrap();
        assert_eq!(g.task, 0, "the task queued again is handed out first");
        now = now.after(secs(100));
        assert_eq!(s.expire(now).unwrap(), 1);
        let want = if n < limit {
            JobState::Running
        } else {
            JobState::Failed
        };
        assert_eq!(state_of(&s, &job), want, "after {n} expiries");
    }
    let err = s.job_status(&job).unwrap().error.unwrap();
    assert!(err.contains("its lease expired 5 times"), "{err}");
    // Retried, it starts over with no expiry held against it.
    s.retry(&job, now).unwrap();
    let w = s.register("again", 1, now).unwrap();
    s.lease(&w, now).unwrap().unwrap();
    now = now.after(secs(100));
    s.expire(now).unwrap();
    assert_eq!(state_of(&s, &job), JobState::Running);
}

/// A worker stopped past its lease again and again (a laptop suspended, a process stopped by
/// its user) takes the task back each time: those expiries do not count towards the limit,
/// so the job does not fail while the worker is alive.
#[test]
fn revived_expiries_do_not_fail_the_job() {
    let dir = tempfile::tempdir().unwrap();
    let mut now = t0();
    let mut s = open(dir.path(), now);
    // One tile, one pass: one task per job.
    let one = RenderSettings {
        width: 16,
        height: 16,
        ..small(1)
    };
    let job = s.new_job("s".into(), one.clone(), 0, now).unwrap().id;
    let w = s.register("w", 1, now).unwrap();
    let g = s.lease(&w, now).unwrap().unwrap();
    let limit = cfg().max_task_expiries();
    for n in 1..=2 * limit {
        now = now.after(secs(100));
        assert_eq!(s.expire(now).unwrap(), 1, "expiry {n}");
        assert_eq!(state_of(&s, &job), JobState::Running, "after {n} expiries");
        assert_eq!(
            s.heartbeat(&g.lease, now),
            Heartbeat::Renewed,
            "revival {n}"
        );
    }
    assert_eq!(
        deliver(&mut s, &job, g.task, &w, now),
        ResultOutcome::Accepted
    );
    assert_eq!(state_of(&s, &job), JobState::Done);
    assert_eq!(s.metrics(now).counters.revived, u64::from(2 * limit));
    // An expiry that is not revived still counts: with one revived before them, the limit's
    // worth of workers vanishing fails the job at the limit, not one later.
    let job = s.new_job("s".into(), one, 0, now).unwrap().id;
    let g = s.lease(&w, now).unwrap().unwrap();
    assert_eq!(g.job, job);
    now = now.after(secs(100));
    s.expire(now).unwrap();
    assert_eq!(s.heartbeat(&g.lease, now), Heartbeat::Renewed);
    for n in 1..=limit {
        now = now.after(secs(100));
        assert_eq!(s.expire(now).unwrap(), 1);
        let want = if n < limit {
            JobState::Running
        } else {
            JobState::Failed
        };
        assert_eq!(state_of(&s, &job), want, "after {n} expiries not revived");
        if n < limit {
            let other = s.register(&format!("v{n}"), 1, now).unwrap();
            s.lease(&other, now).unwrap().unwrap();
        }
    }
}

#[test]
fn a_lease_out_at_a_restart_expires_after_the_grace() {
    let dir = tempfile::tempdir().unwrap();
    let t0 = t0();
    {
        let mut s = open(dir.path(), t0);
        let w = s.register("w", 1, t0).unwrap();
        s.new_job("s".into(), small(1), 0, t0).unwrap();
        s.lease(&w, t0).unwrap().unwrap();
    }
    let t1 = t0.after(secs(100));
    let mut s = open(dir.path(), t1);
    assert_eq!(s.expire(t1.after(Duration::from_millis(4999))).unwrap(), 0);
    assert_eq!(s.expire(t1.after(secs(5))).unwrap(), 1);
}

#[test]
fn purge_deletes_a_job_and_its_tiles_for_good() {
    let dir = tempfile::tempdir().unwrap();
    let now = t0();
    let mut s = open(dir.path(), now);
    let w = s.register("w", 1, now).unwrap();
    let keep = s.new_job("s".into(), small(1), 0, now).unwrap().id;
    let gone = s.new_job("s".into(), small(1), 1, now).unwrap().id;
    finish(&mut s, &w, now).unwrap();
    let g = s.lease(&w, now).unwrap().unwrap();
    let st = s.purge(&gone, now).unwrap().unwrap();
    assert_eq!(
        st.state,
        JobState::Cancelled,
        "a running job is cancelled first"
    );
    assert!(s.job_status(&gone).is_none());
    assert!(
        s.purge(&gone, now).unwrap().is_none(),
        "unknown after the purge"
    );
    assert!(
        !s.fail(&g.lease, "late", now).unwrap(),
        "its leases are gone too"
    );
    drop(s);
    let s = open(dir.path(), now.after(secs(1)));
    assert!(s.job_status(&gone).is_none(), "purged for good");
    assert!(s.job_status(&keep).is_some(), "other jobs untouched");
}

#[test]
fn restart_under_another_renderer_version_renders_unfinished_jobs_again() {
    let dir = tempfile::tempdir().unwrap();
    let t0 = t0();
    let (finished_job, open_job) = {
        let mut s = open(dir.path(), t0);
        let w = s.register("w", 1, t0).unwrap();
        let finished_job = s.new_job("s".into(), small(1), 0, t0).unwrap().id;
        while finish(&mut s, &w, t0).is_some() {}
        let open_job = s.new_job("s".into(), small(2), 0, t0).unwrap().id;
        for _ in 0..3 {
            finish(&mut s, &w, t0).unwrap();
        }
        s.lease(&w, t0).unwrap().unwrap();
        (finished_job, open_job)
    };
    let db = dir.path().join("raytile.sqlite3");
    let results = |job: &str| -> i64 {
        let c = rusqlite::Connection::open(&db).unwrap();
        c.query_row(
            "SELECT COUNT(*) FROM results WHERE job_id = ?1",
            [job],
            |r| r.get(0),
        )
        .unwrap()
    };
    let (kept, before) = (results(&finished_job), results(&open_job));
    assert!(kept > 0 && before == 3);
    // Same version: a restart keeps everything.
    drop(open(dir.path(), t0));
    assert_eq!(results(&open_job), 3);
    // As if these tiles came from another renderer version.
    rusqlite::Connection::open(&db)
        .unwrap()
        .execute(
            "UPDATE meta SET value = 'older' WHERE key = 'render_version'",
            [],
        )
        .unwrap();
    let t1 = t0.after(secs(100));
    let mut s = open(dir.path(), t1);
    assert_eq!(results(&open_job), 0, "the other renderer's tiles are gone");
    assert_eq!(results(&finished_job), kept, "finished frames are kept");
    let st = s.job_status(&open_job).unwrap();
    assert_eq!((st.tasks_done, st.tasks_leased), (0, 0));
    assert_eq!(state_of(&s, &finished_job), JobState::Done);
    // Every task is rendered again, and the job finishes.
    let w = s.register("w2", 1, t1).unwrap();
    let mut n = 0;
    while finish(&mut s, &w, t1).is_some() {
        n += 1;
    }
    assert_eq!(n, st.tasks_total);
    assert_eq!(state_of(&s, &open_job), JobState::Done);
}

#[test]
fn ids_stay_unique_across_restarts_in_the_same_millisecond() {
    let dir = tempfile::tempdir().unwrap();
    let now = t0();
    let mut seen = std::collections::HashSet::new();
    for _ in 0..3 {
        let mut s = open(dir.path(), now);
        let w = s.register("w", 1, now).unwrap();
        assert!(seen.insert(w.clone()), "worker id {w} repeated");
        let j = s.new_job("s".into(), small(1), 0, now).unwrap().id;
        assert!(seen.insert(j.clone()), "job id {j} repeated");
        let g = s.lease(&w, now).unwrap().unwrap();
        assert!(
            seen.insert(g.lease.clone()),
            "lease id {} repeated",
            g.lease
        );
    }
}

/// Runs `op` once with the store's next write failing, checks that it returned the store
/// error and changed nothing (jobs, counters, what a restart would find), then runs it again
/// with the store healthy and returns its answer.
fn with_one_fault<T: std::fmt::Debug>(
    s: &mut Sched,
    dir: &std::path::Path,
    mut op: impl FnMut(&mut Sched) -> Result<T, SchedError>,
) -> T {
    let before = (s.job_list(), s.metrics(t0()).counters);
    let stored = restored_jobs(dir);
    s.store_faults().fail_next(1);
    let r = op(s);
    assert!(matches!(r, Err(SchedError::Store(_))), "{r:?}");
    assert_eq!((s.job_list(), s.metrics(t0()).counters), before);
    assert_eq!(restored_jobs(dir), stored, "the store changed");
    op(s).unwrap()
}

/// The jobs a coordinator restarted on `dir` would find (tasks and states, not times).
fn restored_jobs(dir: &std::path::Path) -> Vec<(String, JobState, u64, u64)> {
    let s = Sched::restore(cfg(), Store::open(dir).unwrap(), t0(), secs(5)).unwrap();
    s.job_list()
        .into_iter()
        .map(|j| (j.id, j.state, j.tasks_done, j.tasks_leased))
        .collect()
}

#[test]
fn a_failed_write_changes_nothing_and_the_retry_applies_once() {
    let dir = tempfile::tempdir().unwrap();
    let now = t0();
    let mut s = open(dir.path(), now);
    // Register and create.
    let w = with_one_fault(&mut s, dir.path(), |s| s.register("w", 1, now));
    let w2 = s.register("w2", 1, now).unwrap();
    let job = with_one_fault(&mut s, dir.path(), |s| {
        s.new_job("s".into(), small(2), 0, now)
    })
    .id;
    assert_eq!(s.job_list().len(), 1, "one job, not two");
    // Lease: the first task, once; the failed attempt handed nothing out.
    let g = with_one_fault(&mut s, dir.path(), |s| s.lease(&w, now)).expect("a task for w");
    assert_eq!(g.task, 0);
    assert_eq!(s.job_status(&job).unwrap().state, JobState::Running);
    // Complete: the retry is accepted, not called a duplicate.
    let out = with_one_fault(&mut s, dir.path(), |s| {
        let (tile, pass) = s.task_for_upload(&job, g.task).unwrap();
        let acc = TileAccum {
            tile,
            pixels: vec![[1.0; 4]; tile.pixel_count()],
            bad_samples: 0,
            splats: Vec::new(),
            coverage: Vec::new(),
        };
        let bytes = raytile_proto::tile::encode(&acc, pass);
        let d = Delivery {
            worker: &w,
            tile,
            pass,
            bytes: &bytes,
            file: None,
        };
        s.complete(&job, g.task, d, now)
    });
    assert_eq!(out, ResultOutcome::Accepted);
    assert_eq!(
        deliver(&mut s, &job, g.task, &w, now),
        ResultOutcome::Duplicate
    );
    // Fail: counted once.
    let g = s.lease(&w, now).unwrap().unwrap();
    assert!(with_one_fault(&mut s, dir.path(), |s| s.fail(&g.lease, "oops", now)));
    assert_eq!(s.worker_list(t0())[0].failures, 1);
    // Release.
    let g = s.lease(&w, now).unwrap().unwrap();
    assert!(with_one_fault(&mut s, dir.path(), |s| s.release(&g.lease)));
    // Expire: the lease stays out until the write succeeds, then is re-queued once.
    let g = s.lease(&w2, now).unwrap().unwrap();
    let late = now.after(secs(60));
    assert_eq!(with_one_fault(&mut s, dir.path(), |s| s.expire(late)), 1);
    // Nobody took it since: its worker's heartbeat takes it back, and its result is in.
    assert_eq!(s.heartbeat(&g.lease, late), Heartbeat::Renewed);
    assert_eq!(
        deliver(&mut s, &job, g.task, &w2, late),
        ResultOutcome::Accepted
    );
    // Finish the job: every task exactly once (the one w failed waits for w2, which may take
    // it).
    let mut n = 2;
    while finish(&mut s, &w, late).is_some() || finish(&mut s, &w2, late).is_some() {
        n += 1;
    }
    let st = s.job_status(&job).unwrap();
    assert_eq!((st.state, n), (JobState::Done, st.tasks_total));
    // Cancel and purge another job.
    let other = s.new_job("s".into(), small(1), 0, late).unwrap().id;
    let st = with_one_fault(&mut s, dir.path(), |s| s.cancel(&other, late)).unwrap();
    assert_eq!(st.state, JobState::Cancelled);
    with_one_fault(&mut s, dir.path(), |s| s.purge(&other, late)).unwrap();
    assert!(s.job_status(&other).is_none());
    // What a restart finds is what memory holds.
    let mem: Vec<_> = s
        .job_list()
        .into_iter()
        .map(|j| (j.id, j.state, j.tasks_done, j.tasks_leased))
        .collect();
    assert_eq!(restored_jobs(dir.path()), mem);
}

#[test]
fn the_last_result_finishes_the_job_only_when_stored() {
    let dir = tempfile::tempdir().unwrap();
    let now = t0();
    let mut s = open(dir.path(), now);
    let w = s.register("w", 1, now).unwrap();
    let job = s.new_job("s".into(), small(1), 0, now).unwrap().id;
    let total = s.job_status(&job).unwrap().tasks_total;
    for _ in 1..total {
        finish(&mut s, &w, now).unwrap();
    }
    let g = s.lease(&w, now).unwrap().unwrap();
    let out = with_one_fault(&mut s, dir.path(), |s| {
        let (tile, pass) = s.task_for_upload(&job, g.task).unwrap();
        let acc = TileAccum {
            tile,
            pixels: vec![[1.0; 4]; tile.pixel_count()],
            bad_samples: 0,
            splats: Vec::new(),
            coverage: Vec::new(),
        };
        let bytes = raytile_proto::tile::encode(&acc, pass);
        let d = Delivery {
            worker: &w,
            tile,
            pass,
            bytes: &bytes,
            file: None,
        };
        s.complete(&job, g.task, d, now)
    });
    assert_eq!(out, ResultOutcome::Accepted);
    assert_eq!(state_of(&s, &job), JobState::Done);
    drop(s);
    let s = open(dir.path(), now);
    assert_eq!(state_of(&s, &job), JobState::Done);
}

#[test]
fn creating_the_largest_allowed_job_stores_one_row() {
    let dir = tempfile::tempdir().unwrap();
    let now = t0();
    let mut s = open(dir.path(), now);
    // 2^18 tasks (the default limit): 512 × 512 tiles of 16 pixels, one pass.
    let settings = RenderSettings {
        width: 8192,
        height: 8192,
        tile_size: 16,
        spp: 1,
        passes: 1,
        ..Default::default()
    };
    let layout = Arc::new(TaskLayout::new(&settings));
    assert_eq!(layout.task_count(), 1 << 18);
    let t = std::time::Instant::now();
    let st = s.create_job("s".into(), settings, layout, 0, now).unwrap();
    let took = t.elapsed();
    assert_eq!(st.tasks_total, 1 << 18);
    let rows: i64 = rusqlite::Connection::open(dir.path().join("raytile.sqlite3"))
        .unwrap()
        .query_row("SELECT COUNT(*) FROM tasks", [], |r| r.get(0))
        .unwrap();
    assert_eq!(rows, 0, "queued tasks have no rows");
    eprintln!("creating a job of 2^18 tasks held the scheduler for {took:?}");
    assert!(took < Duration::from_secs(2), "{took:?}");
}

#[test]
fn leases_of_cancelled_jobs_are_forgotten_at_the_next_expiry_tick() {
    let dir = tempfile::tempdir().unwrap();
    let now = t0();
    let mut s = open(dir.path(), now);
    let w = s.register("w", 1, now).unwrap();
    let job = s.new_job("s".into(), small(1), 0, now).unwrap().id;
    let g = s.lease(&w, now).unwrap().unwrap();
    s.cancel(&job, now).unwrap();
    assert_eq!(s.leases.len(), 1);
    assert_eq!(s.expire(now).unwrap(), 0);
    assert!(s.leases.is_empty());
    // The heartbeat still hears why.
    assert_eq!(
        s.heartbeat(&g.lease, now),
        Heartbeat::Stop {
            reason: "job cancelled".into()
        }
    );
    assert!(!s.fail(&g.lease, "late", now).unwrap());
    // A purged job's lease, too.
    let job = s.new_job("s".into(), small(1), 0, now).unwrap().id;
    let g = s.lease(&w, now).unwrap().unwrap();
    s.purge(&job, now).unwrap();
    assert_eq!(
        s.heartbeat(&g.lease, now),
        Heartbeat::Stop {
            reason: "job deleted".into()
        }
    );
}

/// The progress the events carry is counted incrementally; it must agree with the status
/// (which walks every task) at every step, out of order, and after a restart.
#[test]
fn progress_counters_agree_with_the_status_and_events_are_numbered() {
    let dir = tempfile::tempdir().unwrap();
    let now = t0();
    let mut s = open(dir.path(), now);
    let (last, mut rx) = s.subscribe();
    assert_eq!(last, 0);
    let w = s.register("w", 1, now).unwrap();
    let job = s.new_job("s".into(), small(3), 0, now).unwrap().id;
    let mut grants = Vec::new();
    while let Some(g) = s.lease(&w, now).unwrap() {
        grants.push(g);
    }
    assert_eq!(grants.len(), 12);
    // Pass 2 first, then pass 0, then pass 1: tiles fill up only at the end.
    let order = grants[8..].iter().chain(&grants[..4]).chain(&grants[4..8]);
    for (i, g) in order.enumerate() {
        assert_eq!(
            deliver(&mut s, &job, g.task, &w, now),
            ResultOutcome::Accepted
        );
        let st = s.job_status(&job).unwrap();
        assert_eq!(s.jobs[&job].progress(), (st.tiles_done, st.passes_done));
        assert_eq!(s.jobs[&job].tasks_done(), i + 1);
    }
    let mut events = Vec::new();
    while let Ok(ev) = rx.try_recv() {
        events.push(ev);
    }
    let ids: Vec<u64> = events.iter().map(|e| e.id).collect();
    assert_eq!(ids, (1..=ids.len() as u64).collect::<Vec<_>>());
    let kinds: Vec<serde_json::Value> = events
        .iter()
        .map(|e| serde_json::from_str::<serde_json::Value>(&e.json).unwrap()["type"].clone())
        .collect();
    let count = |k: &str| kinds.iter().filter(|t| *t == k).count();
    assert_eq!(kinds[0], "worker_registered");
    assert_eq!(kinds[1], "job_submitted");
    assert_eq!(
        (
            count("task_leased"),
            count("task_done"),
            count("job_progress")
        ),
        (12, 12, 12)
    );
    assert_eq!(kinds.last().unwrap(), "job_state");
    let last: serde_json::Value = serde_json::from_str(&events.last().unwrap().json).unwrap();
    assert_eq!(last["state"], "done");
    drop(s);
    // Restored: the counters are rebuilt from the stored tasks.
    let s = open(dir.path(), now);
    assert_eq!(s.jobs[&job].progress(), (4, 3));
}

/// What job `id` shows of its leases: the status's count, and the workers its tiles list.
fn leases_shown(s: &Sched, id: &str) -> (u64, usize) {
    let leased = s.job_status(id).unwrap().tasks_leased;
    let holders = s
        .tile_list(id)
        .unwrap()
        .tiles
        .iter()
        .map(|t| t.workers.len())
        .sum();
    (leased, holders)
}

/// A job that ends while workers hold leases on it (cancelled, or failed by another task's
/// failures, or by every live worker being blocked) holds none any more, as its status and
/// tiles show, also after a restart; the workers are told to stop at their next heartbeat.
#[test]
fn a_job_that_ends_holds_no_leases() {
    let dir = tempfile::tempdir().unwrap();
    let now = t0();
    // One task failing three times fails its job; no worker is blocked before that.
    let cfg = SchedConfig {
        block_worker_after: 10,
        ..cfg()
    };
    let mut s = open_with(dir.path(), cfg, now, secs(5));
    let a = s.register("a", 1, now).unwrap();
    let b = s.register("b", 1, now).unwrap();
    // Cancelled with two leases out.
    let cancelled = s.new_job("s".into(), small(1), 0, now).unwrap().id;
    let ga = s.lease(&a, now).unwrap().unwrap();
    s.lease(&b, now).unwrap().unwrap();
    assert_eq!(leases_shown(&s, &cancelled), (2, 2));
    let st = s.cancel(&cancelled, now).unwrap().unwrap();
    assert_eq!((st.state, st.tasks_leased), (JobState::Cancelled, 0));
    assert_eq!(leases_shown(&s, &cancelled), (0, 0));
    assert_eq!(
        s.heartbeat(&ga.lease, now),
        Heartbeat::Stop {
            reason: "job cancelled".into()
        }
    );
    // Failed by one task's failures while another worker holds a lease.
    // (A failed task waits for another worker than the one that failed it: a and c take
    // turns.)
    let c = s.register("c", 1, now).unwrap();
    let failed = s.new_job("s".into(), small(1), 0, now).unwrap().id;
    s.lease(&b, now).unwrap().unwrap();
    for w in [&a, &c, &a] {
        let g = s.lease(w, now).unwrap().unwrap();
        assert_eq!(g.task, 1);
        assert!(s.fail(&g.lease, "boom", now).unwrap());
    }
    assert_eq!(state_of(&s, &failed), JobState::Failed);
    assert_eq!(leases_shown(&s, &failed), (0, 0));
    assert!(s.worker_list(now).iter().all(|w| w.leased == 0));
    drop(s);
    let s = open(dir.path(), now.after(secs(1)));
    assert_eq!(leases_shown(&s, &cancelled), (0, 0), "after a restart");
    assert_eq!(leases_shown(&s, &failed), (0, 0), "after a restart");
}

/// A job that every live worker is blocked from fails at the expiry tick, ending the leases
/// still out on it.
#[test]
fn a_job_failed_at_the_expiry_tick_holds_no_leases() {
    let dir = tempfile::tempdir().unwrap();
    let start = t0();
    let cfg = SchedConfig {
        max_task_failures: 10,
        ..cfg()
    };
    let mut s = open_with(dir.path(), cfg, start, secs(5));
    let a = s.register("a", 1, start).unwrap();
    s.register("b", 1, start).unwrap();
    let job = s.new_job("s".into(), small(1), 0, start).unwrap().id;
    // `a` holds one task and fails another twice: blocked from the job, but `b` is live.
    let held = s.lease(&a, start).unwrap().unwrap();
    for _ in 0..2 {
        let g = s.lease(&a, start).unwrap().unwrap();
        assert!(s.fail(&g.lease, "boom", start).unwrap());
    }
    assert_eq!(state_of(&s, &job), JobState::Running);
    // Later `b` is gone (no contact) while `a` renews its lease: every live worker is blocked.
    let later = start.after(secs(61));
    assert_eq!(s.heartbeat(&held.lease, later), Heartbeat::Renewed);
    s.expire(later).unwrap();
    assert_eq!(state_of(&s, &job), JobState::Failed);
    assert_eq!(leases_shown(&s, &job), (0, 0));
}

/// A database written when ended jobs could keep leases opens without them, and stores that.
#[test]
fn leases_of_an_ended_job_in_an_older_database_end_at_the_restart() {
    let dir = tempfile::tempdir().unwrap();
    let now = t0();
    let mut s = open(dir.path(), now);
    let w = s.register("w", 1, now).unwrap();
    let job = s.new_job("s".into(), small(1), 0, now).unwrap().id;
    s.lease(&w, now).unwrap().unwrap();
    // Cancelled as an older coordinator did: the job's row only.
    s.store
        .write(&[Write::Job {
            id: &job,
            state: JobState::Cancelled,
            error: None,
            started_ms: Some(now.wall_ms),
            finished_ms: Some(now.wall_ms),
        }])
        .unwrap();
    drop(s);
    let s = open(dir.path(), now.after(secs(1)));
    assert_eq!(state_of(&s, &job), JobState::Cancelled);
    assert_eq!(leases_shown(&s, &job), (0, 0));
    assert!(s.leases.is_empty());
    drop(s);
    let stored = Store::open(dir.path()).unwrap().tasks(&job).unwrap();
    assert!(
        stored
            .iter()
            .all(|t| !matches!(t.state, crate::store::StoredTask::Leased { .. })),
        "{stored:?}"
    );
}
