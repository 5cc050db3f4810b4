//! Change events for `GET /v1/events`: every state change the scheduler makes is published,
//! numbered, on a broadcast channel. Publishing is a counter increment and a channel send
//! (no I/O, nothing awaited), so it happens under the scheduler's lock, which keeps the ids in
//! the order the changes were made. A subscriber that falls behind the channel's capacity is
//! told to resync (see [`crate::api`]).

use raytile_core::Tile;
use raytile_proto::{JobState, JobStatus};
use serde::Serialize;
use std::sync::Arc;
use tokio::sync::broadcast;

/// Events the channel holds for a slow subscriber before it lags (and is told to resync).
pub const CAPACITY: usize = 4096;

/// More task changes than this at once (a mass lease expiry) are published as one
/// [`Event::Resync`] instead.
pub const RESYNC_OVER: usize = 64;

/// One change, as `data:` of a server-sent event (JSON, tagged by `type`).
#[derive(Clone, Debug, Serialize, PartialEq)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Event {
    /// Too much changed (or the subscriber fell behind): fetch everything again.
    Resync {
        /// Why, for people reading the stream.
        reason: String,
    },
    /// A job was submitted.
    JobSubmitted {
        /// Its status.
        job: Box<JobStatus>,
    },
    /// A task of a job finished: the job's progress.
    JobProgress {
        /// Job id.
        job: String,
        /// Tiles with every pass done.
        tiles_done: u64,
        /// Tiles in the frame.
        tiles_total: u64,
        /// Passes complete for every tile.
        passes_done: u32,
        /// Passes of the job.
        passes: u32,
        /// Tasks done.
        tasks_done: u64,
        /// Tasks of the job.
        tasks_total: u64,
    },
    /// A job changed state (running, done, failed, cancelled).
    JobState {
        /// Job id.
        job: String,
        /// New state.
        state: JobState,
        /// Why it failed.
        #[serde(skip_serializing_if = "Option::is_none")]
        error: Option<String>,
    },
    /// A job's priority changed.
    JobPriority {
        /// Job id.
        job: String,
        /// New priority.
        priority: i32,
    },
    /// A job and its tiles were deleted.
    JobPurged {
        /// Job id.
        job: String,
    },
    /// A worker took a task.
    TaskLeased {
        /// Job id.
        job: String,
        /// Task index.
        task: u32,
        /// Its pixels.
        tile: Tile,
        /// Its pass.
        pass: u32,
        /// Worker id.
        worker: String,
    },
    /// A task's result was stored.
    TaskDone {
        /// Job id.
        job: String,
        /// Task index.
        task: u32,
        /// Its pixels.
        tile: Tile,
        /// Its pass.
        pass: u32,
        /// Worker id.
        worker: String,
    },
    /// A worker reported that it could not render a task.
    TaskFailed {
        /// Job id.
        job: String,
        /// Task index.
        task: u32,
        /// Its pixels.
        tile: Tile,
        /// Its pass.
        pass: u32,
        /// Worker id.
        worker: String,
        /// The worker's message.
        error: String,
    },
    /// A task went back to the queue: its lease expired, its worker handed it back, or its
    /// stored result was lost.
    TaskQueued {
        /// Job id.
        job: String,
        /// Task index.
        task: u32,
        /// Its pixels.
        tile: Tile,
        /// Its pass.
        pass: u32,
        /// `expired`, `released`, `lost` or `retried`.
        reason: &'static str,
    },
    /// A worker registered.
    WorkerRegistered {
        /// Worker id.
        worker: String,
        /// Name.
        name: String,
        /// Render threads.
        threads: u32,
    },
    /// A worker called in (heartbeat), or came back after being gone.
    WorkerSeen {
        /// Worker id.
        worker: String,
        /// Last contact, ms since the Unix epoch.
        last_seen_ms: u64,
        /// Tasks delivered.
        tasks_done: u64,
    },
    /// A worker has not called in for longer than the liveness window.
    WorkerGone {
        /// Worker id.
        worker: String,
    },
}

/// A published event: its id and its JSON.
#[derive(Clone, Debug)]
pub struct Stamped {
    /// Increases by one with every event published.
    pub id: u64,
    /// The event as JSON.
    pub json: String,
}

/// The scheduler's end of the channel.
pub(super) struct Events {
    tx: broadcast::Sender<Arc<Stamped>>,
    last_id: u64,
}

impl Events {
    pub fn new() -> Events {
        Events {
            tx: broadcast::channel(CAPACITY).0,
            last_id: 0,
        }
    }

    /// Publishes the event `make` builds, if anyone listens (nobody pays for events
    /// otherwise).
    pub fn emit(&mut self, make: impl FnOnce() -> Event) {
        if self.tx.receiver_count() == 0 {
            return;
        }
        self.last_id += 1;
        let json = serde_json::to_string(&make()).unwrap_or_default();
        let _ = self.tx.send(Arc::new(Stamped {
            id: self.last_id,
            json,
        }));
    }

    /// The id of the last event published.
    pub fn last_id(&self) -> u64 {
        self.last_id
    }

    /// A new subscriber and the id of the last event published before it.
    pub fn subscribe(&self) -> (u64, broadcast::Receiver<Arc<Stamped>>) {
        (self.last_id, self.tx.subscribe())
    }
}
