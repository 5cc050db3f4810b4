//! Ids of workers, leases and jobs: unique within a coordinator's life by a counter, and
//! across restarts by the epoch: the wall-clock millisecond the coordinator started at (passed
//! in, like every time the scheduler uses), raised above the previous start's epoch by the
//! store so that neither a clock set back nor two starts in one millisecond repeat an id.
//!
//! A lease id also carries a tag, a keyed SHA-256 of the job, the task and the rest of the id
//! under the data directory's secret key: nobody can guess a lease id from the ids they see
//! (to fail or release a task someone else holds), and a result names a lease this
//! coordinator gave for that very task, checked without remembering every lease ever given.

use sha2::{Digest, Sha256};

/// Makes ids.
pub(super) struct Ids {
    epoch: u64,
    next: u64,
    /// The secret key of lease tags (kept in the store, the same across restarts).
    key: [u8; 32],
}

impl std::fmt::Debug for Ids {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Ids")
            .field("epoch", &self.epoch)
            .field("next", &self.next)
            .finish_non_exhaustive()
    }
}

impl Ids {
    /// Ids of a coordinator that started at `epoch_ms`, its lease tags keyed by `key`.
    pub fn new(epoch_ms: u64, key: [u8; 32]) -> Ids {
        Ids {
            epoch: epoch_ms,
            next: 0,
            key,
        }
    }

    /// A new lease id for task `task` of job `job`: `l-EPOCH-N-TAG`.
    pub fn lease(&mut self, job: &str, task: u32) -> String {
        let base = self.next("l-");
        let tag = self.tag(job, task, &base);
        format!("{base}-{tag}")
    }

    /// Whether `lease` is an id [`Ids::lease`] made for task `task` of job `job` (under this
    /// key: at this start or an earlier one).
    pub fn lease_is_for(&self, lease: &str, job: &str, task: u32) -> bool {
        // Compared in constant time: the sender chooses both the id and the tag.
        lease.rsplit_once('-').is_some_and(|(base, tag)| {
            base.starts_with("l-")
                && crate::api::constant_time_eq(
                    self.tag(job, task, base).as_bytes(),
                    tag.as_bytes(),
                )
        })
    }

    /// 128 bits of SHA-256(key ‖ SHA-256(key ‖ job ‖ task ‖ base)), in hex: the nested hash
    /// leaves no room for a length extension.
    fn tag(&self, job: &str, task: u32, base: &str) -> String {
        let mut inner = Sha256::new();
        inner.update(self.key);
        inner.update((job.len() as u64).to_le_bytes());
        inner.update(job.as_bytes());
        inner.update(task.to_le_bytes());
        inner.update(base.as_bytes());
        let mut outer = Sha256::new();
        outer.update(self.key);
        outer.update(inner.finalize());
        hex::encode(&outer.finalize()[..16])
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
        let mut a = Ids::new(1_000, [7; 32]);
        let (a1, a2) = (a.next("l-"), a.next("l-"));
        assert_ne!(a1, a2);
        let mut b = Ids::new(1_001, [7; 32]);
        assert_ne!(b.next("l-"), a1, "a restart starts its counter again");
        assert_ne!(
            Ids::new(1_000, [7; 32]).job(1),
            Ids::new(1_001, [7; 32]).job(1)
        );
    }

    #[test]
    fn a_lease_id_names_its_task_and_cannot_be_made_without_the_key() {
        let mut a = Ids::new(1_000, [7; 32]);
        let lease = a.lease("job-1-3e8", 5);
        assert!(lease.starts_with("l-3e8-1-"), "{lease}");
        assert!(a.lease_is_for(&lease, "job-1-3e8", 5));
        // Another task, another job, another key, an edited id: not a lease of the task.
        assert!(!a.lease_is_for(&lease, "job-1-3e8", 6));
        assert!(!a.lease_is_for(&lease, "job-2-3e8", 5));
        assert!(!Ids::new(1_000, [8; 32]).lease_is_for(&lease, "job-1-3e8", 5));
        let next = lease.replacen("l-3e8-1-", "l-3e8-2-", 1);
        assert!(!a.lease_is_for(&next, "job-1-3e8", 5));
        for forged in ["", "l-", "l-3e8-1", "-", "l-3e8-1-"] {
            assert!(!a.lease_is_for(forged, "job-1-3e8", 5), "{forged}");
        }
        // The same key after a restart still knows it.
        assert!(Ids::new(1_001, [7; 32]).lease_is_for(&lease, "job-1-3e8", 5));
    }
}
