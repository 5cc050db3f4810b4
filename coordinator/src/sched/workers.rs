//! Registered workers: what the API lists about them, and whether they are live.
//!
//! Liveness is read from wall-clock milliseconds passed in by the caller, not from an
//! `Instant`: a worker's last contact must mean something after a restart too.

use std::collections::HashMap;
use std::time::Duration;

/// A registered worker.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(super) struct WorkerRec {
    /// Name.
    pub name: String,
    /// Threads.
    pub threads: u32,
    /// Registration time (wall ms).
    pub registered_ms: u64,
    /// Last contact (wall ms).
    pub last_seen_ms: u64,
    /// Tasks delivered since this coordinator started.
    pub tasks_done: u64,
    /// Failures reported since this coordinator started.
    pub failures: u64,
}

/// Every registered worker, and the rule that says which are live.
#[derive(Debug)]
pub(super) struct Workers {
    recs: HashMap<String, WorkerRec>,
    /// When this coordinator started (wall ms): restored workers count as live from then on
    /// until they have had time to call in.
    started_ms: u64,
    /// How long after its last contact a worker is still live.
    live_ms: u64,
}

impl Workers {
    /// No workers yet; the coordinator started at `started_ms`. A worker is live for three
    /// lease timeouts (at least a minute) after its last contact: long enough to ride out a
    /// long render between heartbeats, short enough that a vanished worker stops counting.
    pub fn new(started_ms: u64, lease_timeout: Duration) -> Workers {
        Workers {
            recs: HashMap::new(),
            started_ms,
            live_ms: (3 * lease_timeout.as_millis() as u64).max(60_000),
        }
    }

    /// Adds (or replaces) a worker.
    pub fn insert(&mut self, id: String, rec: WorkerRec) {
        self.recs.insert(id, rec);
    }

    /// Registered workers.
    pub fn len(&self) -> usize {
        self.recs.len()
    }

    /// Every worker with its id.
    pub fn iter(&self) -> impl Iterator<Item = (&String, &WorkerRec)> {
        self.recs.iter()
    }

    /// Records contact from `id` at `now_ms`; returns its record if it is registered.
    pub fn touch(&mut self, id: &str, now_ms: u64) -> Option<&mut WorkerRec> {
        let w = self.recs.get_mut(id)?;
        w.last_seen_ms = w.last_seen_ms.max(now_ms);
        Some(w)
    }

    /// Whether `w` is live at `now_ms`: seen, or restored at start-up, within the live window.
    fn is_live(&self, w: &WorkerRec, now_ms: u64) -> bool {
        now_ms.saturating_sub(w.last_seen_ms.max(self.started_ms)) <= self.live_ms
    }

    /// Workers not live at `now_ms` that are not in `gone` yet, and workers in `gone` that
    /// are live again (with their last contact and tasks done).
    #[allow(clippy::type_complexity)]
    pub fn liveness_changes(
        &self,
        gone: &std::collections::HashSet<String>,
        now_ms: u64,
    ) -> (Vec<String>, Vec<(String, u64, u64)>) {
        let (mut newly_gone, mut back) = (Vec::new(), Vec::new());
        for (id, w) in &self.recs {
            match (self.is_live(w, now_ms), gone.contains(id)) {
                (false, false) => newly_gone.push(id.clone()),
                (true, true) => back.push((id.clone(), w.last_seen_ms, w.tasks_done)),
                _ => {}
            }
        }
        newly_gone.sort();
        back.sort();
        (newly_gone, back)
    }

    /// Workers to forget at `now_ms`, holding none of `leased`: with `name`, those of that
    /// name not live or not heard from since this coordinator started (a worker registering
    /// again under its name after it, or the coordinator, restarted); without, those not
    /// live and not heard from for `after_ms`. Sorted.
    pub fn forgettable(
        &self,
        name: Option<&str>,
        leased: &std::collections::HashSet<&str>,
        after_ms: u64,
        now_ms: u64,
    ) -> Vec<String> {
        let mut out: Vec<String> = self
            .recs
            .iter()
            .filter(|(id, w)| {
                let quiet = now_ms.saturating_sub(w.last_seen_ms.max(self.started_ms));
                let live = self.is_live(w, now_ms);
                !leased.contains(id.as_str())
                    && match name {
                        Some(n) => w.name == n && (!live || w.last_seen_ms < self.started_ms),
                        None => !live && quiet > after_ms,
                    }
            })
            .map(|(id, _)| id.clone())
            .collect();
        out.sort();
        out
    }

    /// Forgets worker `id`.
    pub fn remove(&mut self, id: &str) {
        self.recs.remove(id);
    }

    /// Whether `id` is live at `now_ms`.
    pub fn is_live_id(&self, id: &str, now_ms: u64) -> bool {
        self.recs.get(id).is_some_and(|w| self.is_live(w, now_ms))
    }

    /// Whether a live worker other than `worker` has fewer than `block_after` failures in
    /// `failures` (it may take the job's tasks).
    pub fn another_may_take(
        &self,
        worker: &str,
        failures: &HashMap<String, u32>,
        block_after: u32,
        now_ms: u64,
    ) -> bool {
        self.recs.iter().any(|(id, w)| {
            id != worker
                && self.is_live(w, now_ms)
                && failures.get(id).copied().unwrap_or(0) < block_after
        })
    }

    /// Whether every live worker has `block_after` failures or more in `failures` (and at least
    /// one worker is live): a job in that state would wait for ever.
    pub fn all_live_blocked(
        &self,
        failures: &HashMap<String, u32>,
        block_after: u32,
        now_ms: u64,
    ) -> bool {
        let mut live = self
            .recs
            .iter()
            .filter(|(_, w)| self.is_live(w, now_ms))
            .peekable();
        live.peek().is_some()
            && live.all(|(id, _)| failures.get(id).copied().unwrap_or(0) >= block_after)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(last_seen_ms: u64) -> WorkerRec {
        WorkerRec {
            name: "w".into(),
            threads: 1,
            registered_ms: 0,
            last_seen_ms,
            tasks_done: 0,
            failures: 0,
        }
    }

    #[test]
    fn live_for_three_lease_timeouts_but_at_least_a_minute() {
        let started = 1_000_000;
        for (timeout, window) in [(10, 60_000), (30, 90_000)] {
            let mut ws = Workers::new(started, Duration::from_secs(timeout));
            ws.insert("a".into(), rec(started + 5_000));
            let seen = started + 5_000;
            let a = ws.recs["a"].clone();
            assert!(ws.is_live(&a, seen + window));
            assert!(!ws.is_live(&a, seen + window + 1));
        }
    }

    #[test]
    fn restored_workers_are_live_from_the_start_until_they_could_have_called_in() {
        let started = 10_000_000;
        let ws = Workers::new(started, Duration::from_secs(10));
        // Last seen long before this coordinator started (restored from the store).
        let old = rec(5);
        assert!(ws.is_live(&old, started + 60_000));
        assert!(!ws.is_live(&old, started + 60_001));
    }

    #[test]
    fn touch_never_moves_last_contact_back() {
        let mut ws = Workers::new(0, Duration::from_secs(10));
        ws.insert("a".into(), rec(500));
        assert_eq!(ws.touch("a", 400).unwrap().last_seen_ms, 500);
        assert_eq!(ws.touch("a", 600).unwrap().last_seen_ms, 600);
        assert!(ws.touch("b", 600).is_none());
    }

    #[test]
    fn blocked_counts_only_live_workers_and_needs_one() {
        let mut ws = Workers::new(0, Duration::from_secs(10));
        let failures: HashMap<String, u32> = [("a".to_string(), 2)].into();
        assert!(!ws.all_live_blocked(&failures, 2, 0), "no worker at all");
        ws.insert("a".into(), rec(0));
        ws.insert("b".into(), rec(0));
        assert!(!ws.all_live_blocked(&failures, 2, 1_000), "b may take it");
        ws.touch("a", 100_000);
        // b was last seen 100 s ago: gone; a alone is live, and blocked.
        assert!(ws.all_live_blocked(&failures, 2, 100_000));
        assert!(!ws.all_live_blocked(&failures, 3, 100_000), "a has 2 of 3");
        // Nobody live: workers may come back, so nothing is blocked for good.
        assert!(!ws.all_live_blocked(&failures, 2, 1_000_000));
    }
}
