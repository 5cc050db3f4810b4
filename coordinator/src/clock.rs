//! The coordinator's clock. Handlers and the timeout checker read it once per request or tick
//! and pass the reading into the scheduler, which reads no clock itself: tests drive time by
//! passing readings of their own, or by injecting a [`Clock`] into the [`Config`](crate::Config).

use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};
use tokio::time::Instant;

/// One reading of the clock, taken by the caller of a scheduler method.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Now {
    /// Monotonic time (tokio's, so `tokio::time::pause` drives it): lease deadlines and the
    /// throughput window.
    pub instant: Instant,
    /// Milliseconds since the Unix epoch: times shown to users, worker liveness (which must
    /// survive a restart, unlike an `Instant`) and the epoch of generated ids.
    pub wall_ms: u64,
}

impl Now {
    /// The system clock: tokio's `Instant::now()` and `SystemTime::now()`.
    pub fn system() -> Now {
        Now {
            instant: Instant::now(),
            wall_ms: SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .map(|d| d.as_millis() as u64)
                .unwrap_or(0),
        }
    }

    /// This reading moved `d` forward on both clocks.
    pub fn after(self, d: Duration) -> Now {
        Now {
            instant: self.instant + d,
            wall_ms: self.wall_ms + d.as_millis() as u64,
        }
    }
}

/// Where the coordinator reads the time: [`system_clock`], or one a test drives.
pub type Clock = Arc<dyn Fn() -> Now + Send + Sync>;

/// The system clock as a [`Clock`].
pub fn system_clock() -> Clock {
    Arc::new(Now::system)
}
