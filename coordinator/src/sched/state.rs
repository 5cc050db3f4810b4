//! The state machines. Every change of a task's state goes through [`transition`], every
//! change of a job's state through [`JobLife::apply`]; the rest of the scheduler decides which
//! event to send and persists what changed.

use raytile_proto::JobState;
use tokio::time::Instant;

/// State of one task (one tile, one pass).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum TaskState {
    /// Waiting for a worker.
    Queued,
    /// Out with a worker until `deadline` unless renewed.
    Leased {
        /// Worker id.
        worker: String,
        /// Lease id.
        lease: String,
        /// Expiry. It lives in memory only: after a restart every lease gets the grace period.
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

/// One tile pass of a job. Which tile and pass it is follows from its index in the job's
/// [`TaskLayout`](super::TaskLayout).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Task {
    /// State.
    pub state: TaskState,
    /// Failures reported so far.
    pub failures: u32,
    /// The worker that failed it last, while it waits for another (kept in memory only: after
    /// a restart any worker may take it).
    pub failed_by: Option<String>,
    /// Leases of it that expired (their workers stopped answering: killed, crashed, cut off),
    /// in memory only; too many fail the job (see `Sched::expire`).
    pub expiries: u32,
}

impl Task {
    /// A task waiting for its first worker.
    pub fn queued() -> Task {
        Task {
            state: TaskState::Queued,
            failures: 0,
            failed_by: None,
            expiries: 0,
        }
    }
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
    /// The worker of an expired lease is heard from again, while nobody took the task: the
    /// lease is its again, and its expiry no longer counts (the worker was alive all along:
    /// stopped, or cut off for a while, not killed by the task).
    Revive {
        /// Worker id.
        worker: String,
        /// The expired lease's id.
        lease: String,
        /// New expiry.
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
    /// The clock reads `now`: a lease whose deadline has passed runs out.
    Expire {
        /// The clock.
        now: Instant,
    },
    /// The stored result of a done task was found missing or damaged: it is rendered again.
    Lost,
    /// A user retries the task's failed or cancelled job: a failed task is queued again, and
    /// every task not done starts over with no failures held against it.
    Retry,
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
        (Failed, TaskEvent::Retry) => {
            task.failures = 0;
            task.failed_by = None;
            task.expiries = 0;
            Queued
        }
        (Queued, TaskEvent::Retry)
            if task.failures > 0 || task.failed_by.is_some() || task.expiries > 0 =>
        {
            task.failures = 0;
            task.failed_by = None;
            task.expiries = 0;
            Queued
        }
        (Done { .. }, TaskEvent::Lost) => {
            // A new start: the failures before its result are not held against it.
            task.failures = 0;
            task.failed_by = None;
            task.expiries = 0;
            Queued
        }
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
        (
            Queued,
            TaskEvent::Revive {
                worker,
                lease,
                deadline,
            },
        ) => {
            task.expiries = task.expiries.saturating_sub(1);
            Leased {
                worker,
                lease,
                deadline,
            }
        }
        (Leased { worker, lease, .. }, TaskEvent::Renew { lease: l, deadline }) if *lease == l => {
            Leased {
                worker: worker.clone(),
                lease: l,
                deadline,
            }
        }
        (Leased { worker, lease, .. }, TaskEvent::Fail { lease: l, fatal }) if *lease == l => {
            task.failures += 1;
            task.failed_by = Some(worker.clone());
            if fatal {
                Failed
            } else {
                Queued
            }
        }
        (Leased { lease, .. }, TaskEvent::Release { lease: l }) if *lease == l => Queued,
        (Leased { deadline, .. }, TaskEvent::Expire { now }) if *deadline <= now => {
            task.expiries += 1;
            Queued
        }
        _ => return Outcome::Ignored,
    };
    task.state = next;
    Outcome::Changed
}

/// A job's state with the times and the message shown to users.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct JobLife {
    /// State.
    pub state: JobState,
    /// Why it failed.
    pub error: Option<String>,
    /// Submission (wall ms).
    pub created_ms: u64,
    /// First lease.
    pub started_ms: Option<u64>,
    /// End: done, failed or cancelled.
    pub finished_ms: Option<u64>,
}

/// Something that happens to a job.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum JobEvent {
    /// A first task was leased.
    Start,
    /// Every task is done.
    Finish,
    /// The job cannot finish.
    Fail {
        /// Shown to users.
        error: String,
    },
    /// Cancelled by a user.
    Cancel,
    /// A done job lost stored tiles (missing or damaged), which are to be rendered again.
    Reopen,
    /// A user retries a failed or cancelled job: it goes on with the tiles it has.
    Retry,
}

impl JobLife {
    /// A job just submitted at `now_ms`.
    pub fn queued(now_ms: u64) -> JobLife {
        JobLife {
            state: JobState::Queued,
            error: None,
            created_ms: now_ms,
            started_ms: None,
            finished_ms: None,
        }
    }

    /// The job state machine: every change of a job's state goes through here. Returns
    /// whether anything changed (so the caller persists it). A final job never changes, but
    /// that a done job whose stored tiles were lost runs again until they are made again.
    pub fn apply(&mut self, ev: JobEvent, now_ms: u64) -> bool {
        if ev == JobEvent::Reopen && self.state == JobState::Done {
            self.state = JobState::Running;
            self.finished_ms = None;
            return true;
        }
        if ev == JobEvent::Retry && matches!(self.state, JobState::Failed | JobState::Cancelled) {
            self.state = if self.started_ms.is_some() {
                JobState::Running
            } else {
                JobState::Queued
            };
            self.error = None;
            self.finished_ms = None;
            return true;
        }
        if self.state.is_final() {
            return false;
        }
        let state = match ev {
            JobEvent::Start if self.state == JobState::Queued => {
                self.started_ms = Some(now_ms);
                JobState::Running
            }
            JobEvent::Start => return false,
            JobEvent::Finish => JobState::Done,
            JobEvent::Fail { error } => {
                self.error = Some(error);
                JobState::Failed
            }
            JobEvent::Cancel => JobState::Cancelled,
            // An unfinished job has nothing finished to reopen, nor anything to retry.
            JobEvent::Reopen | JobEvent::Retry => return false,
        };
        if state.is_final() {
            self.finished_ms = Some(now_ms);
        }
        self.state = state;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn task_machine_refuses_stale_events() {
        let now = Instant::now();
        let mut t = Task::queued();
        let lease = |l: &str| TaskEvent::Lease {
            worker: "w".into(),
            lease: l.into(),
            deadline: now + Duration::from_secs(1),
        };
        assert_eq!(transition(&mut t, lease("a")), Outcome::Changed);
        assert_eq!(transition(&mut t, lease("b")), Outcome::Ignored);
        let renew_b = TaskEvent::Renew {
            lease: "b".into(),
            deadline: now,
        };
        assert_eq!(transition(&mut t, renew_b), Outcome::Ignored);
        assert_eq!(
            transition(&mut t, TaskEvent::Expire { now }),
            Outcome::Ignored
        );
        let later = now + Duration::from_secs(2);
        assert_eq!(
            transition(&mut t, TaskEvent::Expire { now: later }),
            Outcome::Changed
        );
        assert_eq!(t.state, TaskState::Queued);
        let done = TaskEvent::Complete { worker: "w".into() };
        assert_eq!(transition(&mut t, done.clone()), Outcome::Changed);
        assert_eq!(transition(&mut t, done), Outcome::AlreadyDone);
        assert_eq!(transition(&mut t, lease("c")), Outcome::Ignored);
    }

    #[test]
    fn failures_count_and_the_last_one_fails_the_task() {
        let now = Instant::now();
        let mut t = Task::queued();
        let lease = TaskEvent::Lease {
            worker: "w".into(),
            lease: "a".into(),
            deadline: now,
        };
        let fail = |fatal| TaskEvent::Fail {
            lease: "a".into(),
            fatal,
        };
        transition(&mut t, lease.clone());
        assert_eq!(transition(&mut t, fail(false)), Outcome::Changed);
        assert_eq!((&t.state, t.failures), (&TaskState::Queued, 1));
        // A failure for a lease no longer held counts nothing.
        assert_eq!(transition(&mut t, fail(false)), Outcome::Ignored);
        assert_eq!(t.failures, 1);
        transition(&mut t, lease);
        assert_eq!(transition(&mut t, fail(true)), Outcome::Changed);
        assert_eq!((&t.state, t.failures), (&TaskState::Failed, 2));
        let done = TaskEvent::Complete { worker: "w".into() };
        assert_eq!(transition(&mut t, done), Outcome::Ignored);
    }

    #[test]
    fn a_released_task_is_queued_without_a_failure() {
        let now = Instant::now();
        let mut t = Task::queued();
        transition(
            &mut t,
            TaskEvent::Lease {
                worker: "w".into(),
                lease: "a".into(),
                deadline: now,
            },
        );
        let release = |l: &str| TaskEvent::Release { lease: l.into() };
        assert_eq!(transition(&mut t, release("b")), Outcome::Ignored);
        assert_eq!(transition(&mut t, release("a")), Outcome::Changed);
        assert_eq!(t, Task::queued());
    }

    #[test]
    fn job_machine_stamps_times_and_never_leaves_a_final_state() {
        let mut j = JobLife::queued(10);
        assert!(j.apply(JobEvent::Start, 20));
        assert!(!j.apply(JobEvent::Start, 25), "started once");
        assert_eq!((j.state, j.started_ms), (JobState::Running, Some(20)));
        let fail = JobEvent::Fail {
            error: "boom".into(),
        };
        assert!(j.apply(fail, 30));
        assert_eq!(
            (j.state, j.finished_ms, j.error.as_deref()),
            (JobState::Failed, Some(30), Some("boom"))
        );
        for ev in [
            JobEvent::Start,
            JobEvent::Finish,
            JobEvent::Cancel,
            JobEvent::Reopen,
        ] {
            assert!(!j.apply(ev, 40));
        }
        assert_eq!((j.state, j.finished_ms), (JobState::Failed, Some(30)));
        // Cancelled before any lease: it never started.
        let mut j = JobLife::queued(10);
        assert!(j.apply(JobEvent::Cancel, 50));
        assert_eq!(
            (j.state, j.started_ms, j.finished_ms),
            (JobState::Cancelled, None, Some(50))
        );
    }

    #[test]
    fn a_lost_result_queues_its_task_with_no_failures_held() {
        let mut t = Task {
            state: TaskState::Done { worker: "w".into() },
            failures: 2,
            failed_by: Some("v".into()),
            expiries: 1,
        };
        assert_eq!(transition(&mut t, TaskEvent::Lost), Outcome::Changed);
        assert_eq!(t, Task::queued());
        assert_eq!(transition(&mut t, TaskEvent::Lost), Outcome::Ignored);
    }

    #[test]
    fn a_failed_or_cancelled_job_is_retried_as_it_was_before_it_ended() {
        let mut j = JobLife::queued(10);
        assert!(!j.apply(JobEvent::Retry, 15), "not ended");
        assert!(j.apply(JobEvent::Cancel, 20));
        assert!(j.apply(JobEvent::Retry, 30));
        assert_eq!(
            (j.state, j.started_ms, j.finished_ms),
            (JobState::Queued, None, None),
            "never started: queued again"
        );
        assert!(j.apply(JobEvent::Start, 40));
        let fail = JobEvent::Fail {
            error: "boom".into(),
        };
        assert!(j.apply(fail, 50));
        assert!(j.apply(JobEvent::Retry, 60));
        assert_eq!(
            (j.state, j.started_ms, j.finished_ms, j.error.as_deref()),
            (JobState::Running, Some(40), None, None)
        );
        assert!(j.apply(JobEvent::Finish, 70));
        assert!(!j.apply(JobEvent::Retry, 80), "a done job is not retried");
        let mut t = Task {
            state: TaskState::Failed,
            failures: 3,
            failed_by: Some("w".into()),
            expiries: 2,
        };
        assert_eq!(transition(&mut t, TaskEvent::Retry), Outcome::Changed);
        assert_eq!(t, Task::queued());
        assert_eq!(transition(&mut t, TaskEvent::Retry), Outcome::Ignored);
        t.failures = 1;
        assert_eq!(transition(&mut t, TaskEvent::Retry), Outcome::Changed);
        assert_eq!(t, Task::queued());
    }

    #[test]
    fn only_a_done_job_reopens_and_it_finishes_again() {
        let mut j = JobLife::queued(10);
        assert!(!j.apply(JobEvent::Reopen, 15), "nothing finished to reopen");
        assert!(j.apply(JobEvent::Start, 20));
        assert!(!j.apply(JobEvent::Reopen, 25));
        assert!(j.apply(JobEvent::Finish, 30));
        assert!(j.apply(JobEvent::Reopen, 40));
        assert_eq!(
            (j.state, j.started_ms, j.finished_ms),
            (JobState::Running, Some(20), None)
        );
        assert!(j.apply(JobEvent::Finish, 50));
        assert_eq!((j.state, j.finished_ms), (JobState::Done, Some(50)));
        let mut c = JobLife::queued(10);
        assert!(c.apply(JobEvent::Cancel, 20));
        assert!(
            !c.apply(JobEvent::Reopen, 30),
            "a cancelled job stays cancelled"
        );
    }
}
