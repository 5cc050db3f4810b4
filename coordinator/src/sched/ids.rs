//! Ids of workers, leases and jobs: unique within a coordinator's life by a counter, and
//! across restarts by the epoch: the wall-clock millisecond the coordinator started at (passed
//! in, like every time the scheduler uses), raised above the previous start's epoch by the
//! store so that neither a clock set back nor two starts in one millisecond repeat an id.

/// Makes ids.
#[derive(Debug)]
pub(super) struct Ids {
    epoch: u64,
    next: u64,
}

impl Ids {
    /// Ids of a coordinator that started at `epoch_ms`.
    pub fn new(epoch_ms: u64) -> Ids {
        Ids {
            epoch: epoch_ms,
            next: 0,
        }
    }

    /// The epoch: a different one at every start of the coordinator.
    pub fn epoch(&self) -> u64 {
        self.epoch
    }

    /// A new id starting with `prefix`, for example `w-` or `l-`.
    pub fn next(&mut self, prefix: &str) -> String {
        self.next += 1;
        format!("{prefix}{:x}-{:x}", self.epoch, self.next)
    }

    /// The id of the job submitted `seq`-th: the sequence number shows the submission order,
    /// the epoch keeps it apart from a job of an earlier data directory with the same number.
    pub fn job(&self, seq: u64) -> String {
        format!("job-{seq}-{:x}", self.epoch)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_differ_within_a_run_and_across_restarts() {
        let mut a = Ids::new(1_000);
        let (a1, a2) = (a.next("l-"), a.next("l-"));
        assert_ne!(a1, a2);
        let mut b = Ids::new(1_001);
        assert_ne!(b.next("l-"), a1, "a restart starts its counter again");
        assert_ne!(Ids::new(1_000).job(1), Ids::new(1_001).job(1));
    }
}
