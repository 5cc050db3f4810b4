//! Ids of workers, leases and jobs: unique within a coordinator's life by a counter, and
//! across restarts by the epoch: the wall-clock millisecond the coordinator started at (passed
//! in, like every time the scheduler uses), raised above the previous start's epoch by the
//! store so that neither a clock set back nor two starts in one millisecond repeat an id.
//!
//! A lease id also carries a tag, a keyed SHA-256 of the job, the task, the worker it was given
//! to and the rest of the id under the data directory's secret key: nobody can guess a lease
//! id from the ids they see (to fail or release a task someone else holds), and a result names
//! a lease this coordinator gave for that very task and to the worker it says it comes from,
//! checked without remembering every lease ever given.

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

    /// A new lease id for task `task` of job `job`, given to `worker`: `l-EPOCH-N-TAG`.
    pub fn lease(&mut self, job: &str, task: u32, worker: &str) -> String {
        let base = self.next("l-");
        let tag = self.tag(job, task, worker, &base);
        format!("{base}-{tag}")
    }

    /// Whether `lease` is an id [`Ids::lease`] made for task `task` of job `job` and given to
    /// `worker` (under this key: at this start or an earlier one).
    pub fn lease_is_for(&self, lease: &str, job: &str, task: u32, worker: &str) -> bool {
        // Compared in constant time: the sender chooses both the id and the tag.
        lease.rsplit_once('-').is_some_and(|(base, tag)| {
            base.starts_with("l-")
                && crate::api::constant_time_eq(
                    self.tag(job, task, worker, base).as_bytes(),
                    tag.as_bytes(),
                )
        })
    }

    /// 128 bits of a keyed hash ([`Ids::keyed`]) of job, worker, task and base, in hex (the
    /// strings of variable length with their lengths).
    fn tag(&self, job: &str, task: u32, worker: &str, base: &str) -> String {
        let (job_len, worker_len) = (
            (job.len() as u64).to_le_bytes(),
            (worker.len() as u64).to_le_bytes(),
        );
        let hash = self.keyed(&[
            &job_len,
            job.as_bytes(),
            &worker_len,
            worker.as_bytes(),
            &task.to_le_bytes(),
            base.as_bytes(),
        ]);
        hex::encode(&hash[..16])
    }

    /// A new worker id: `w-EPOCH-N-TAG`, TAG 64 bits of a keyed hash of the rest. A worker's id
    /// is what it leases under and the name its results are credited to, so one worker must
    /// not be able to work out another's from its own.
    pub fn worker(&mut self) -> String {
        let base = self.next("w-");
        let hash = self.keyed(&[b"worker", base.as_bytes()]);
        format!("{base}-{}", hex::encode(&hash[..8]))
    }

    /// SHA-256(key ‖ SHA-256(key ‖ parts)): the nested hash leaves no room for a length
    /// extension.
    fn keyed(&self, parts: &[&[u8]]) -> [u8; 32] {
        let mut inner = Sha256::new();
        inner.update(self.key);
        for part in parts {
            inner.update(part);
        }
        let mut outer = Sha256::new();
        outer.update(self.key);
        outer.update(inner.finalize());
        outer.finalize().into()
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
    fn worker_ids_cannot_be_worked_out_from_one_another() {
        let mut a = Ids::new(1_000, [7; 32]);
        let (w1, w2) = (a.worker(), a.worker());
        assert!(
            w1.starts_with("w-3e8-1-") && w2.starts_with("w-3e8-2-"),
            "{w1} {w2}"
        );
        let tag = |w: &str| w.rsplit('-').next().unwrap().to_string();
        assert_eq!(tag(&w1).len(), 16);
        assert_ne!(tag(&w1), tag(&w2));
        // Another key, another tag for the same place in the sequence.
        assert_ne!(Ids::new(1_000, [8; 32]).worker(), w1);
    }

    #[test]
    fn a_lease_id_names_its_task_and_worker_and_cannot_be_made_without_the_key() {
        let mut a = Ids::new(1_000, [7; 32]);
        let (job, w) = ("job-1-3e8", "w-3e8-4");
        let lease = a.lease(job, 5, w);
        assert!(lease.starts_with("l-3e8-1-"), "{lease}");
        assert!(a.lease_is_for(&lease, job, 5, w));
        // Another task, job, worker or key, an edited id: not that worker's lease of the task.
        assert!(!a.lease_is_for(&lease, job, 6, w));
        assert!(!a.lease_is_for(&lease, "job-2-3e8", 5, w));
        assert!(!a.lease_is_for(&lease, job, 5, "w-3e8-5"));
        assert!(!a.lease_is_for(&lease, job, 5, ""));
        assert!(!Ids::new(1_000, [8; 32]).lease_is_for(&lease, job, 5, w));
        let next = lease.replacen("l-3e8-1-", "l-3e8-2-", 1);
        assert!(!a.lease_is_for(&next, job, 5, w));
        for forged in ["", "l-", "l-3e8-1", "-", "l-3e8-1-"] {
            assert!(!a.lease_is_for(forged, job, 5, w), "{forged}");
        }
        // The lengths keep the job and the worker apart: no other split of the same bytes.
        let split = a.lease("job-1", 5, "3e8w");
        assert!(!a.lease_is_for(&split, "job-13e8", 5, "w"));
        // The same key after a restart still knows it.
        assert!(Ids::new(1_001, [7; 32]).lease_is_for(&lease, job, 5, w));
    }
}
