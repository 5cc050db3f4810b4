//! JSON bodies of the HTTP API (see `docs/farm.md`).

use raytile_core::settings::FilterKind;
use raytile_core::{IntegratorKind, RenderSettings, Tile};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Error body of every 4xx/5xx response: `{"error": {"code", "message", "field"}}`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct ErrorBody {
    /// The error.
    pub error: ErrorDetail,
}

/// What went wrong.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct ErrorDetail {
    /// Machine-readable code (`invalid_field`, `not_found`, `unauthorized`, ...).
    pub code: String,
    /// Human-readable message, naming the offending field or object.
    pub message: String,
    /// The offending request field, when there is one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub field: Option<String>,
}

/// Response of `POST /v1/scenes`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct SceneCreated {
    /// Content id (hex sha256) of the scene.
    pub id: String,
    /// How the upload was read: `gltf`, `glb`, `json`, `tar` or `zip`.
    pub format: String,
    /// The scene file inside an archive (or the file name for single files).
    pub entry: String,
    /// Whether these bytes were already stored.
    pub existed: bool,
    /// Non-fatal problems the loader reported.
    #[serde(default)]
    pub warnings: Vec<String>,
}

/// Body of `POST /v1/jobs`: every field but `scene` is optional; missing fields take the scene's
/// own render settings, then `RenderSettings::default()`.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct JobRequest {
    /// Scene id from `POST /v1/scenes`.
    pub scene: String,
    /// Image width in pixels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub width: Option<u32>,
    /// Image height in pixels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub height: Option<u32>,
    /// Samples per pixel.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub spp: Option<u32>,
    /// Maximum path depth.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_depth: Option<u32>,
    /// Integrator.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub integrator: Option<IntegratorKind>,
    /// Random seed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u32>,
    /// Camera name or index.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<String>,
    /// Reconstruction filter.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub filter: Option<FilterKind>,
    /// Tile edge in pixels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tile_size: Option<u32>,
    /// Progressive passes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub passes: Option<u32>,
    /// Higher runs first; equal priorities run in submission order. Default 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub priority: Option<i32>,
    /// `false`: no default environment for a glTF scene without lights (default true).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub default_light: Option<bool>,
}

/// State of a job.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq, Hash)]
#[serde(rename_all = "snake_case")]
pub enum JobState {
    /// No tile leased yet.
    Queued,
    /// At least one tile leased or done.
    Running,
    /// Every tile of every pass done.
    Done,
    /// A tile failed too often.
    Failed,
    /// Cancelled by `DELETE /v1/jobs/{id}`.
    Cancelled,
}

impl JobState {
    /// Every state, for metrics.
    pub const ALL: [JobState; 5] = [
        Self::Queued,
        Self::Running,
        Self::Done,
        Self::Failed,
        Self::Cancelled,
    ];

    /// The name used in JSON and in the store.
    pub fn name(self) -> &'static str {
        match self {
            Self::Queued => "queued",
            Self::Running => "running",
            Self::Done => "done",
            Self::Failed => "failed",
            Self::Cancelled => "cancelled",
        }
    }

    /// Parses [`JobState::name`].
    pub fn from_name(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == s)
    }

    /// Whether the job will not change any more.
    pub fn is_final(self) -> bool {
        matches!(self, Self::Done | Self::Failed | Self::Cancelled)
    }
}

/// A worker's part in a job.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct WorkerShare {
    /// Tasks (tile passes) the worker delivered.
    pub tasks: u64,
    /// Samples the worker delivered.
    pub samples: u64,
}

/// A job as the API shows it.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct JobStatus {
    /// Job id.
    pub id: String,
    /// Scene id.
    pub scene: String,
    /// State.
    pub state: JobState,
    /// Priority.
    pub priority: i32,
    /// The full settings the job renders with.
    pub settings: RenderSettings,
    /// Tiles in the frame.
    pub tiles_total: u64,
    /// Tiles with every pass done.
    pub tiles_done: u64,
    /// Passes of the job.
    pub passes: u32,
    /// Passes complete for every tile.
    pub passes_done: u32,
    /// Tasks (tile × pass) in the job.
    pub tasks_total: u64,
    /// Tasks done.
    pub tasks_done: u64,
    /// Tasks currently leased.
    pub tasks_leased: u64,
    /// Samples done (pixels × samples).
    pub samples_done: u64,
    /// Samples in the whole job.
    pub samples_total: u64,
    /// Delivered work per worker id.
    pub workers: BTreeMap<String, WorkerShare>,
    /// Submission time, ms since the Unix epoch.
    pub created_ms: u64,
    /// First lease, ms since the Unix epoch.
    pub started_ms: Option<u64>,
    /// End (done, failed or cancelled), ms since the Unix epoch.
    pub finished_ms: Option<u64>,
    /// Why the job failed.
    pub error: Option<String>,
}

/// Response of `GET /v1/jobs`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct JobList {
    /// Jobs, oldest first.
    pub jobs: Vec<JobStatus>,
}

/// Body of `POST /v1/workers`.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct RegisterRequest {
    /// Human-readable name (host name by default).
    pub name: String,
    /// Render threads.
    pub threads: u32,
    /// The version of the worker's renderer arithmetic (`raytile_core::RENDER_VERSION`;
    /// missing: 0, a worker older than the check). The coordinator takes workers of its own
    /// version only.
    #[serde(default)]
    pub render_version: u32,
}

/// Response of `POST /v1/workers`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Registered {
    /// The worker's id, used in lease requests.
    pub worker_id: String,
    /// How long a lease lives without a heartbeat, in ms.
    pub lease_timeout_ms: u64,
    /// How often to heartbeat while rendering, in ms.
    pub heartbeat_ms: u64,
}

/// A worker as `GET /v1/workers` shows it.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct WorkerInfo {
    /// Id.
    pub id: String,
    /// Name.
    pub name: String,
    /// Render threads.
    pub threads: u32,
    /// Registration time, ms since the Unix epoch.
    pub registered_ms: u64,
    /// Last contact, ms since the Unix epoch.
    pub last_seen_ms: u64,
    /// Tasks currently leased.
    pub leased: u64,
    /// Tasks delivered since registration.
    pub tasks_done: u64,
    /// Failures reported.
    pub failures: u64,
}

/// Response of `GET /v1/workers`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct WorkerList {
    /// Workers.
    pub workers: Vec<WorkerInfo>,
}

/// A leased task: render `samples` of `tile` for `job`, then upload the result.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Lease {
    /// Lease id: pass it on heartbeat, result and failure.
    pub lease_id: String,
    /// Job id.
    pub job: String,
    /// Task index within the job.
    pub task: u32,
    /// Scene id (download with `GET /v1/scenes/{id}`).
    pub scene: String,
    /// sha256 of the scene download.
    pub scene_sha256: String,
    /// How the scene download is to be read (`gltf`, `glb`, `json`, `tar`, `zip`).
    pub scene_format: String,
    /// The scene file inside an archive.
    pub scene_entry: String,
    /// Settings of the job.
    pub settings: RenderSettings,
    /// Pixels to render.
    pub tile: Tile,
    /// Pass index.
    pub pass: u32,
    /// First sample index.
    pub sample_start: u32,
    /// One past the last sample index.
    pub sample_end: u32,
    /// Lease lifetime without heartbeat, in ms.
    pub lease_timeout_ms: u64,
}

/// Response of a heartbeat.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct HeartbeatReply {
    /// Stop working on the task: the job was cancelled or the lease is no longer yours.
    pub cancelled: bool,
    /// Why, when `cancelled`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
}

/// Response of a result upload.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct ResultReply {
    /// The result was stored.
    pub accepted: bool,
    /// The task was already done: this result was ignored.
    pub duplicate: bool,
    /// The job was cancelled or failed: this result was ignored.
    pub job_finished: bool,
}

/// Body of a failure report.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct FailureReport {
    /// What went wrong on the worker.
    pub error: String,
}

/// Response of `GET /healthz`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Health {
    /// Always `"ok"`.
    pub status: String,
}
