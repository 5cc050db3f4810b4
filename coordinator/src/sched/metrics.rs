//! What the scheduler counts for `/metrics`: event counters and the recent throughput.

use raytile_proto::JobState;
use std::collections::VecDeque;
use std::time::Duration;
use tokio::time::Instant;

/// Counters since this coordinator started.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Counters {
    /// Leases granted.
    pub leased: u64,
    /// Results accepted.
    pub done: u64,
    /// Leases expired.
    pub expired: u64,
    /// Expired leases given back to their workers at a heartbeat (the task still queued).
    pub revived: u64,
    /// Failures reported.
    pub failed: u64,
    /// Results ignored because their task was done already.
    pub duplicates: u64,
    /// Results ignored because their job was cancelled or had failed.
    pub for_ended_jobs: u64,
    /// Samples accepted.
    pub samples: u64,
}

/// Samples accepted over a sliding window, for the samples-per-second gauge.
#[derive(Debug, Default)]
pub(super) struct Throughput {
    recent: VecDeque<(Instant, u64)>,
}

impl Throughput {
    /// The window the gauge averages over.
    pub const WINDOW: Duration = Duration::from_secs(10);

    /// `samples` accepted at `at`.
    pub fn record(&mut self, at: Instant, samples: u64) {
        self.recent.push_back((at, samples));
    }

    /// Samples per second over the window before `now`, dropping nothing.
    pub fn per_second_at(&self, now: Instant) -> f64 {
        let recent = self
            .recent
            .iter()
            .filter(|(t, _)| now.saturating_duration_since(*t) <= Self::WINDOW);
        recent.map(|(_, s)| *s).sum::<u64>() as f64 / Self::WINDOW.as_secs_f64()
    }

    /// Samples per second over the window before `now` (older entries are dropped).
    pub fn per_second(&mut self, now: Instant) -> f64 {
        while let Some((t, _)) = self.recent.front() {
            if now.saturating_duration_since(*t) > Self::WINDOW {
                self.recent.pop_front();
            } else {
                break;
            }
        }
        self.recent.iter().map(|(_, s)| *s).sum::<u64>() as f64 / Self::WINDOW.as_secs_f64()
    }
}

/// One reading of everything `/metrics` shows.
#[derive(Clone, Debug, PartialEq)]
pub struct Metrics {
    /// Jobs in each state, every state listed.
    pub jobs: Vec<(JobState, u64)>,
    /// Event counters.
    pub counters: Counters,
    /// Registered workers.
    pub workers: usize,
    /// Registered workers that are live (heard from lately, a heartbeat included): those not
    /// `gone` in `GET /v1/workers`.
    pub workers_live: usize,
    /// Samples accepted per second over the last ten seconds.
    pub samples_per_second: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn throughput_forgets_what_left_the_window() {
        let t0 = Instant::now();
        let mut t = Throughput::default();
        t.record(t0, 1000);
        t.record(t0 + Duration::from_secs(5), 500);
        assert_eq!(t.per_second(t0 + Duration::from_secs(10)), 150.0);
        assert_eq!(t.per_second(t0 + Duration::from_secs(11)), 50.0);
        assert_eq!(t.per_second(t0 + Duration::from_secs(16)), 0.0);
    }
}
