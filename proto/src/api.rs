//! JSON bodies of the HTTP API (see `docs/farm.md`).

use crate::settings::{RenderOverrides, RenderSettings, Tile};
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
    /// Whether the same request may succeed if sent again later, unchanged (a 503 while the
    /// coordinator cannot write its database, or while it shuts down). Absent means false.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub retryable: bool,
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

/// Body of `POST /v1/jobs`: the scene, the settings that differ from the scene's own (every
/// field optional, flat in the JSON object: `{"scene": "…", "spp": 256}`) and a priority.
/// Missing settings take the scene's own render settings, then `RenderSettings::default()`.
///
/// Unknown fields are refused (422 naming the field), so a misspelt setting is caught; a client
/// sending a field this coordinator does not know learns so rather than getting a job without it.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
#[serde(try_from = "crate::json::Members")]
pub struct JobRequest {
    /// Scene id from `POST /v1/scenes`.
    pub scene: String,
    /// Settings that differ from the scene's own.
    #[serde(flatten)]
    pub overrides: RenderOverrides,
    /// Higher runs first; equal priorities run in submission order. Default 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub priority: Option<i32>,
}

impl TryFrom<crate::json::Members> for JobRequest {
    type Error = String;

    /// A member given twice is refused while reading (`duplicate field \`spp\``).
    fn try_from(m: crate::json::Members) -> Result<Self, String> {
        JobRequest::try_from(m.0)
    }
}

impl TryFrom<serde_json::Map<String, serde_json::Value>> for JobRequest {
    type Error = String;

    /// Reads the object by hand rather than with `#[serde(flatten)]`, whose errors lose the
    /// field: here a wrong type still says `spp: invalid type: …`, and the API names `spp`.
    fn try_from(mut m: serde_json::Map<String, serde_json::Value>) -> Result<Self, String> {
        fn field<T: serde::de::DeserializeOwned>(
            name: &str,
            v: serde_json::Value,
        ) -> Result<T, String> {
            crate::json::from_objects(v)
                .map_err(|e| format!("{name}: {}", crate::json::plain_message(&e.to_string())))
        }
        let scene = m.remove("scene").ok_or("missing field `scene`")?;
        let scene = field("scene", scene)?;
        let priority = match m.remove("priority") {
            Some(v) => field("priority", v)?,
            None => None,
        };
        let body = crate::json::Objects(serde_json::Value::Object(m));
        let overrides = serde_path_to_error::deserialize(body).map_err(
            |e: serde_path_to_error::Error<serde_json::Error>| {
                let path = e.path().to_string();
                let inner = crate::json::plain_message(&e.inner().to_string());
                if inner.starts_with("unknown field") {
                    // serde's list would lack `scene` and `priority`.
                    format!(
                        "{path}: unknown field `{path}`, expected one of: scene, priority, {}",
                        RenderOverrides::FIELDS.join(", ")
                    )
                } else if path == "." {
                    inner
                } else {
                    format!("{path}: {inner}")
                }
            },
        )?;
        Ok(JobRequest {
            scene,
            overrides,
            priority,
        })
    }
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

    /// Whether the job has ended: it changes no more, but that a `Done` job whose stored
    /// tiles were lost (missing or damaged) is `Running` again until they are rendered again.
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

/// One tile of a job as `GET /v1/jobs/{id}/tiles` shows it.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct TileProgress {
    /// Its pixels.
    pub tile: Tile,
    /// Passes done.
    pub passes_done: u32,
    /// Workers holding a lease on one of its passes now.
    pub workers: Vec<String>,
}

/// Response of `GET /v1/jobs/{id}/tiles`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct TileList {
    /// The id of the last change event (`GET /v1/events`) published before this list was
    /// made: events with a larger id are not in it yet.
    #[serde(default)]
    pub event_id: u64,
    /// Passes of the job.
    pub passes: u32,
    /// Every tile, in row order.
    pub tiles: Vec<TileProgress>,
}

/// Body of `POST /v1/jobs/{id}/priority`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PriorityRequest {
    /// The job's new priority: higher runs first.
    pub priority: i32,
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
    /// The last task failures workers reported (at most 20, newest last; kept in memory
    /// only, so empty after a restart).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub failures: Vec<TaskFailure>,
}

/// Response of `GET /v1/jobs`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct JobList {
    /// Jobs, oldest first.
    pub jobs: Vec<JobStatus>,
    /// When `limit` left jobs out: the id to ask for the next page with (`after=`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub next: Option<String>,
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
    /// `rendering` (holds a lease), `idle`, or `gone` (no contact for longer than three lease
    /// timeouts, at least a minute).
    #[serde(default)]
    pub state: String,
    /// The tasks it holds now.
    #[serde(default)]
    pub current: Vec<CurrentTask>,
    /// Samples it delivered per second over the last 10 s.
    #[serde(default)]
    pub samples_per_second: f64,
    /// Renderer version it renders with: registration refuses any other than the
    /// coordinator's, so this is the coordinator's.
    #[serde(default)]
    pub render_version: u32,
}

/// A task a worker holds.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct CurrentTask {
    /// Job id.
    pub job: String,
    /// Task index.
    pub task: u32,
    /// Its pixels.
    pub tile: Tile,
    /// Its pass.
    pub pass: u32,
}

/// A task failure a worker reported, as a job's status lists it.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct TaskFailure {
    /// Worker id.
    pub worker: String,
    /// Task index.
    pub task: u32,
    /// Its pixels.
    pub tile: Tile,
    /// Its pass.
    pub pass: u32,
    /// The worker's message.
    pub error: String,
    /// When, ms since the Unix epoch.
    pub at_ms: u64,
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::settings::IntegratorKind;

    fn parse(json: &str) -> Result<JobRequest, String> {
        serde_json::from_str(json).map_err(|e| e.to_string())
    }

    #[test]
    fn job_requests_are_flat_and_round_trip() {
        let r = parse(r#"{"scene": "s", "spp": 8, "integrator": "ao", "priority": -2}"#).unwrap();
        assert_eq!(
            r,
            JobRequest {
                scene: "s".into(),
                overrides: RenderOverrides {
                    spp: Some(8),
                    integrator: Some(IntegratorKind::Ao),
                    ..Default::default()
                },
                priority: Some(-2),
            }
        );
        let json = serde_json::to_value(&r).unwrap();
        assert_eq!(
            json,
            serde_json::json!({"scene": "s", "spp": 8, "integrator": "ao", "priority": -2})
        );
        assert_eq!(parse(&json.to_string()).unwrap(), r);
        assert_eq!(
            parse(r#"{"scene": "s", "priority": null}"#)
                .unwrap()
                .priority,
            None
        );
    }

    #[test]
    fn job_request_errors_name_the_field() {
        let check = |json: &str, start: &str| {
            let e = parse(json).unwrap_err();
            assert!(e.starts_with(start), "{json}: {e}");
        };
        check(r#"{"scene": "s", "spp": "many"}"#, "spp: invalid type");
        check(
            r#"{"scene": "s", "integrator": "magic"}"#,
            "integrator: unknown variant `magic`",
        );
        check(r#"{"scene": 3}"#, "scene: invalid type");
        check(
            r#"{"scene": "s", "priority": 1.5}"#,
            "priority: invalid type",
        );
        check(r#"{"spp": 8}"#, "missing field `scene`");
        check(
            r#"{"scene": "s", "sp": 8}"#,
            "sp: unknown field `sp`, expected one of: scene,",
        );
        check(r#"[1]"#, "invalid type");
    }
}
