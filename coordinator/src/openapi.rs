//! The OpenAPI 3 description of the API, written by hand (the API is small and this keeps
//! a derive-macro dependency out). It is checked against the real router and its real answers:
//! a test walks [`crate::api::routes`] (read from the code that builds the router) and sends
//! bad paths, queries and bodies to every route, and every status it gets must be listed here;
//! `scripts/api-fuzz.sh` runs schemathesis against a running coordinator with the same rule.
//!
//! Each operation lists every status its handler, its extractors and the auth layer can
//! answer: 401 on everything but `/healthz`; 400 where a path parameter or a query string can
//! fail to parse; 400, 413, 415 and 422 where a JSON body is read; 503 where the handler writes
//! the store (a failed write changes nothing and may be retried).

use raytile_proto::settings::{MAX_DEPTH, MAX_EDGE, MAX_SPP, MAX_TILE_EDGE};
use raytile_proto::{FilterKind, IntegratorKind, JobState};
use serde_json::{json, Map, Value};

const ERROR: &str = "#/components/schemas/Error";

fn err(desc: &str) -> Value {
    json!({"description": desc, "content": {"application/json": {"schema": {"$ref": ERROR}}}})
}

fn ok_json(desc: &str, schema: &str) -> Value {
    json!({"description": desc, "content": {"application/json": {"schema": {"$ref": format!("#/components/schemas/{schema}")}}}})
}

fn path_param(name: &str, desc: &str) -> Value {
    json!({"name": name, "in": "path", "required": true, "description": desc, "schema": {"type": "string"}})
}

fn json_body(schema: &str) -> Value {
    json!({"required": true, "content": {"application/json": {"schema": {"$ref": format!("#/components/schemas/{schema}")}}}})
}

fn binary_body() -> Value {
    json!({"required": true, "content": {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}}})
}

/// An operation with a request body.
fn with_body(body: Value, mut op: Value) -> Value {
    op["requestBody"] = body;
    op
}

/// What an operation's inputs can get wrong, and so which error statuses it lists.
#[derive(Clone, Copy, Default)]
struct Inputs {
    /// Path parameters or a query string (400 when one does not parse).
    params: bool,
    /// A JSON body (400 not JSON, 413 over the limit, 415 not declared JSON, 422 wrong shape).
    json: bool,
    /// Writes the store (503 when the write fails).
    writes: bool,
}

/// One operation: `responses` are its own answers; the ones its inputs imply are added.
fn op(summary: &str, parameters: Value, inputs: Inputs, responses: Value) -> Value {
    let mut r: Map<String, Value> = responses.as_object().cloned().unwrap_or_default();
    let mut add = |code: &str, v: Value| {
        r.entry(code.to_string()).or_insert(v);
    };
    add("401", err("Missing or wrong bearer token."));
    add(
        "403",
        err("A browser's request from another site's page that would change something (its Origin or Sec-Fetch-Site names another origin); on a coordinator without a token, a Host header that is not an IP address or localhost; on one with a worker token, the other kind's token."),
    );
    if inputs.params || inputs.json {
        add(
            "400",
            err("A path parameter, the query string or the body does not parse (field named)."),
        );
    }
    if inputs.json {
        add("413", err("Body over the JSON limit (1 MiB)."));
        add("415", err("Body not declared as application/json."));
        add(
            "422",
            err("Well-formed JSON of the wrong shape (field named)."),
        );
    }
    if inputs.writes {
        add(
            "503",
            err("The coordinator could not write its database: nothing changed, retry later (retryable: true, Retry-After)."),
        );
    }
    let mut o = json!({"summary": summary, "responses": r});
    if parameters.as_array().is_some_and(|p| !p.is_empty()) {
        o["parameters"] = parameters;
    }
    o
}

fn settings_schema() -> Value {
    json!({"type": "object", "properties": {
        "width": {"type": "integer"}, "height": {"type": "integer"}, "spp": {"type": "integer"},
        "max_depth": {"type": "integer"},
        "integrator": {"type": "string", "enum": IntegratorKind::ALL.map(IntegratorKind::name)},
        "seed": {"type": "integer"}, "camera": {"type": "string", "nullable": true},
        "filter": {"type": "string", "enum": FilterKind::ALL.map(FilterKind::name)},
        "tile_size": {"type": "integer"}, "passes": {"type": "integer"},
        "default_light": {"type": "boolean"},
        "environment": {"type": "string", "nullable": true},
        "environment_rotation": {"type": "number"}, "environment_strength": {"type": "number"},
        "alpha": {"type": "boolean"}}})
}

fn schemas() -> Value {
    let u32_in = |lo: u32, hi: u32| json!({"type": "integer", "minimum": lo, "maximum": hi});
    json!({
        "Error": {"type": "object", "required": ["error"], "additionalProperties": false, "properties": {"error": {
            "type": "object", "required": ["code", "message"], "additionalProperties": false, "properties": {
                "code": {"type": "string"}, "message": {"type": "string"}, "field": {"type": "string"},
                "retryable": {"type": "boolean"}}}}},
        "Health": {"type": "object", "required": ["status"], "properties": {"status": {"type": "string"}}},
        "SceneCreated": {"type": "object", "required": ["id", "format", "entry", "existed"], "properties": {
            "id": {"type": "string"}, "format": {"type": "string"}, "entry": {"type": "string"},
            "existed": {"type": "boolean"}, "warnings": {"type": "array", "items": {"type": "string"}}}},
        "JobRequest": {"type": "object", "required": ["scene"], "additionalProperties": false, "properties": {
            "scene": {"type": "string"},
            "width": u32_in(1, MAX_EDGE), "height": u32_in(1, MAX_EDGE), "spp": u32_in(1, MAX_SPP),
            "max_depth": u32_in(0, MAX_DEPTH),
            "integrator": {"type": "string", "enum": IntegratorKind::ALL.map(IntegratorKind::name)},
            "seed": u32_in(0, u32::MAX),
            "camera": {"description": "a camera of the scene: its name, or its index from 0 (a string of digits is a name first, then an index); one the scene does not have is refused with 422",
                "oneOf": [{"type": "string"}, {"type": "integer", "minimum": 0}]},
            "filter": {"type": "string", "enum": FilterKind::ALL.map(FilterKind::name)},
            "tile_size": u32_in(1, MAX_TILE_EDGE), "passes": u32_in(1, MAX_SPP),
            "priority": {"type": "integer", "minimum": i32::MIN, "maximum": i32::MAX},
            "default_light": {"type": "boolean"},
            "environment": {"type": "string", "example": "0.5,0.5,0.5",
                "description": "the job's light, replacing the scene's environment: none, R,G,B (constant linear radiance, each ≥ 0) or the path of an equirectangular .hdr or .exr map inside the scene's folder (raytile submit packs it with the scene)"},
            "environment_rotation": {"type": "number", "description": "rotation of the environment map about +Y, degrees (needs environment)"},
            "environment_strength": {"type": "number", "minimum": 0, "description": "multiplies the environment (needs environment)"},
            "alpha": {"type": "boolean", "description": "an alpha channel: the environment seen straight from the camera is transparent (it still lights the scene) and colours are premultiplied by alpha; EXR and PNG images carry it, Radiance HDR has none"}}},
        "RenderSettings": settings_schema(),
        "JobStatus": {"type": "object", "required": ["id", "scene", "state", "settings", "tasks_total", "tasks_done"], "properties": {
            "id": {"type": "string"}, "scene": {"type": "string"}, "state": {"type": "string", "enum": JobState::ALL.map(JobState::name)},
            "priority": {"type": "integer"}, "settings": {"$ref": "#/components/schemas/RenderSettings"},
            "tiles_total": {"type": "integer"}, "tiles_done": {"type": "integer"},
            "passes": {"type": "integer"}, "passes_done": {"type": "integer"}, "tasks_total": {"type": "integer"}, "tasks_done": {"type": "integer"},
            "tasks_leased": {"type": "integer"}, "samples_done": {"type": "integer"}, "samples_total": {"type": "integer"},
            "workers": {"type": "object", "additionalProperties": {"type": "object", "properties": {"tasks": {"type": "integer"}, "samples": {"type": "integer"}}}},
            "created_ms": {"type": "integer"}, "started_ms": {"type": "integer", "nullable": true}, "finished_ms": {"type": "integer", "nullable": true},
            "error": {"type": "string", "nullable": true},
            "failures": {"type": "array", "description": "The last task failures workers reported (at most 20; memory only)", "items": {"$ref": "#/components/schemas/TaskFailure"}}}},
        "Tile": {"type": "object", "required": ["x0", "y0", "x1", "y1"], "properties": {"x0": {"type": "integer"}, "y0": {"type": "integer"}, "x1": {"type": "integer"}, "y1": {"type": "integer"}}},
        "TaskFailure": {"type": "object", "required": ["worker", "task", "tile", "pass", "error", "at_ms"], "properties": {
            "worker": {"type": "string"}, "task": {"type": "integer"}, "tile": {"$ref": "#/components/schemas/Tile"}, "pass": {"type": "integer"},
            "error": {"type": "string"}, "at_ms": {"type": "integer"}}},
        "TileList": {"type": "object", "required": ["event_id", "passes", "tiles"], "properties": {
            "event_id": {"type": "integer", "description": "Id of the last event of /v1/events published before this list: apply only later ones to it"},
            "passes": {"type": "integer"}, "tiles": {"type": "array", "items": {
            "type": "object", "required": ["tile", "passes_done", "workers"], "properties": {
                "tile": {"$ref": "#/components/schemas/Tile"}, "passes_done": {"type": "integer"},
                "workers": {"type": "array", "description": "Workers holding a lease on one of the tile's passes", "items": {"type": "string"}}}}}}},
        "PriorityRequest": {"type": "object", "required": ["priority"], "additionalProperties": false, "properties": {
            "priority": {"type": "integer", "minimum": i32::MIN, "maximum": i32::MAX}}},
        "JobList": {"type": "object", "required": ["jobs"], "properties": {"jobs": {"type": "array", "items": {"$ref": "#/components/schemas/JobStatus"}},
            "next": {"type": "string", "description": "When limit left jobs out: pass it as after= for the next page"}}},
        "RegisterRequest": {"type": "object", "required": ["name", "threads"], "properties": {
            "name": {"type": "string", "minLength": 1, "maxLength": 256}, "threads": u32_in(0, u32::MAX),
            "render_version": {"description": "the worker's renderer version; a mismatch with the coordinator's is refused with 409", "type": "integer", "minimum": 0, "maximum": u32::MAX, "example": raytile_core::RENDER_VERSION}}},
        "Registered": {"type": "object", "required": ["worker_id", "lease_timeout_ms", "heartbeat_ms"], "properties": {
            "worker_id": {"type": "string"}, "lease_timeout_ms": {"type": "integer"}, "heartbeat_ms": {"type": "integer"}}},
        "WorkerInfo": {"type": "object", "required": ["id", "name"], "properties": {
            "id": {"type": "string"}, "name": {"type": "string"}, "threads": {"type": "integer"},
            "registered_ms": {"type": "integer"}, "last_seen_ms": {"type": "integer"}, "leased": {"type": "integer"},
            "tasks_done": {"type": "integer"}, "failures": {"type": "integer"},
            "state": {"type": "string", "enum": ["rendering", "idle", "gone"]},
            "current": {"type": "array", "items": {"type": "object", "required": ["job", "task", "tile", "pass"], "properties": {
                "job": {"type": "string"}, "task": {"type": "integer"}, "tile": {"$ref": "#/components/schemas/Tile"}, "pass": {"type": "integer"}}}},
            "samples_per_second": {"type": "number"},
            "render_version": {"type": "integer"}}},
        "WorkerList": {"type": "object", "required": ["workers"], "properties": {"workers": {"type": "array", "items": {"$ref": "#/components/schemas/WorkerInfo"}}}},
        "Lease": {"type": "object", "required": ["lease_id", "job", "task", "scene", "settings", "tile", "pass", "sample_start", "sample_end"], "properties": {
            "lease_id": {"type": "string"}, "job": {"type": "string"}, "task": {"type": "integer"}, "scene": {"type": "string"},
            "scene_sha256": {"type": "string"}, "scene_format": {"type": "string"}, "scene_entry": {"type": "string"},
            "settings": {"$ref": "#/components/schemas/RenderSettings"},
            "tile": {"type": "object", "properties": {"x0": {"type": "integer"}, "y0": {"type": "integer"}, "x1": {"type": "integer"}, "y1": {"type": "integer"}}},
            "pass": {"type": "integer"}, "sample_start": {"type": "integer"}, "sample_end": {"type": "integer"}, "lease_timeout_ms": {"type": "integer"}}},
        "HeartbeatReply": {"type": "object", "required": ["cancelled"], "properties": {"cancelled": {"type": "boolean"}, "reason": {"type": "string"}}},
        "ResultReply": {"type": "object", "required": ["accepted", "duplicate", "job_finished"], "properties": {"accepted": {"type": "boolean"}, "duplicate": {"type": "boolean"}, "job_finished": {"type": "boolean"}}},
        "FailureReport": {"type": "object", "required": ["error"], "properties": {"error": {"type": "string"}}}
    })
}

const EVENTS_SUMMARY: &str = "Live changes of jobs, tasks and workers (server-sent events)";

const EVENTS_DESCRIPTION: &str = "A text/event-stream that stays open. Each event's data is one JSON object with a `type`; \
each has an `id` that increases by one with every change the coordinator makes (resyncs have none). Types: \
`resync` {reason} (sent first, and whenever the subscriber fell behind or many things changed at once: fetch everything again); \
`job_submitted` {job: JobStatus}; `job_progress` {job, tiles_done, tiles_total, passes_done, passes, tasks_done, tasks_total}; \
`job_state` {job, state, error?} (running, done, failed, cancelled; a done job whose stored tiles were lost runs again; a retried job is queued or running again); `job_priority` {job, priority}; `job_purged` {job}; \
`task_leased` {job, task, tile, pass, worker}; `task_done` {job, task, tile, pass, worker}; \
`task_failed` {job, task, tile, pass, worker, error}; `task_queued` {job, task, tile, pass, reason: expired|released|lost|retried}; \
`worker_registered` {worker, name, threads}; `worker_seen` {worker, last_seen_ms, tasks_done}; `worker_gone` {worker}. \
A comment line keeps the connection alive every 15 s.";

/// The whole document.
pub fn document() -> Value {
    let none = Inputs::default();
    let params = Inputs {
        params: true,
        ..none
    };
    let job_id = path_param("id", "Job id");
    let lease_id = path_param("lease", "Lease id");
    json!({
        "openapi": "3.0.3",
        "info": {
            "title": "raytile coordinator",
            "version": env!("CARGO_PKG_VERSION"),
            "description": "Distributed path tracing: upload scenes, submit jobs, fetch images; workers lease tile passes and upload binary results. Every endpoint but /healthz needs `Authorization: Bearer TOKEN` when the coordinator has a token. A coordinator with a worker token as well (--worker-token) takes it, and only it, on the workers' endpoints (register, lease, heartbeat, failure, release, result upload), either token on scene downloads and this document, and the other token only on every other endpoint; a known token on an endpoint of the other kind is answered 403. Every error answer is the Error schema; a 405 (known path, other method) and a 404 (unknown path) are too. Only a request that cannot be parsed as HTTP at all is answered without it, by the HTTP layer: 400 (malformed request line or header), 414 (path and query over 65,534 bytes), 431 (headers too large), with an empty body. The token is taken from that header only. A browser's request from another site's page that would change something, and, on a coordinator without a token, a request whose Host is not an IP address or localhost, are answered 403. The web pages (/, /jobs/{id}, /workers and their files under /ui/) are served without the token and are not part of this API."
        },
        "components": {
            "securitySchemes": {"bearer": {"type": "http", "scheme": "bearer"}},
            "schemas": schemas()
        },
        "security": [{"bearer": []}],
        "paths": {
            "/healthz": {"get": {"summary": "Liveness (no token needed)", "security": [],
                "responses": {"200": ok_json("ok", "Health")}}},
            "/metrics": {"get": op("Prometheus metrics", json!([]), params,
                json!({"200": {"description": "Prometheus text exposition format", "content": {"text/plain": {"schema": {"type": "string"}}}}}))},
            "/v1/openapi.json": {"get": op("This document", json!([]), none,
                json!({"200": {"description": "OpenAPI 3 JSON", "content": {"application/json": {"schema": {"type": "object"}}}}}))},
            "/v1/scenes": {"post": with_body(binary_body(), op("Upload a scene (.gltf with data URIs, .glb, JSON scene, or .tar/.zip of a scene folder)",
                json!([
                    {"name": "format", "in": "query", "schema": {"type": "string", "enum": ["gltf", "glb", "json", "tar", "zip"]}, "description": "Format hint; otherwise Content-Type, then magic bytes."},
                    {"name": "entry", "in": "query", "schema": {"type": "string"}, "description": "Scene file inside an archive."}]),
                params,
                json!({"201": ok_json("Stored", "SceneCreated"), "200": ok_json("Already stored", "SceneCreated"),
                    "413": err("Over the upload limit"), "422": err("Not a valid scene, or a file it names is refused (message names the JSON path or glTF field), or an archive member is refused: a link, a path out of the folder, or a path that clashes with another member's (the same path twice, a file that is also a folder; message names the member), or an entry that is absolute, holds '..' or is not in the archive (field entry), or a format that is not the stored bytes' (field format)"),
                    "503": err("Every scene check stayed busy (code busy): retry after Retry-After seconds")})))},
            "/v1/scenes/{id}": {"get": op("Download a scene blob (workers)", json!([path_param("id", "Scene id")]), params,
                json!({"200": {"description": "The bytes as uploaded; headers x-raytile-sha256, x-raytile-format, x-raytile-entry", "content": {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}}},
                    "404": err("Unknown scene")}))},
            "/v1/jobs": {
                "post": with_body(json_body("JobRequest"), op("Submit a job", json!([]), Inputs { json: true, writes: true, ..none },
                    json!({"201": ok_json("Created", "JobStatus"),
                        "422": err("Invalid settings, a setting over this coordinator's limits, a camera the scene does not have, or an unknown scene (field named)"),
                        "429": err("Too many unfinished jobs")}))),
                "get": op("List jobs, oldest first: every job, or a page of those in some states",
                    json!([{"name": "state", "in": "query", "schema": {"type": "string"}, "description": "Only jobs in these states, comma-separated (queued, running, done, failed, cancelled)"},
                        {"name": "after", "in": "query", "schema": {"type": "string"}, "description": "Only jobs submitted after this one: the next of the page before"},
                        {"name": "limit", "in": "query", "schema": {"type": "integer", "minimum": 1}, "description": "At most this many jobs; next names where the page ended"}]),
                    params,
                    json!({"200": ok_json("Jobs", "JobList"), "422": err("An unknown state, an after that is not a job id, or a limit of 0 (field named)")}))},
            "/v1/jobs/{id}": {
                "get": op("Job status", json!([job_id]), params,
                    json!({"200": ok_json("Job", "JobStatus"), "404": err("Unknown job")})),
                "delete": op("Cancel a job; with purge=true also delete it and its tile data",
                    json!([job_id, {"name": "purge", "in": "query", "schema": {"type": "boolean"}, "description": "Delete the job and its stored tiles after cancelling it."}]),
                    Inputs { params: true, writes: true, ..none },
                    json!({"200": ok_json("Job", "JobStatus"), "404": err("Unknown job")}))},
            "/v1/jobs/{id}/image": {"get": op("The frame so far (partial while running). Its ETag changes whenever a result of the job is stored and at every start of the coordinator: the same ETag, the same bytes",
                json!([job_id, {"name": "format", "in": "query", "schema": {"type": "string", "enum": ["png", "exr", "hdr"]}},
                    {"name": "exposure", "in": "query", "schema": {"type": "number", "minimum": -64, "maximum": 64}, "description": "PNG only: exposure in stops, as raytile render --exposure"},
                    {"name": "tonemap", "in": "query", "schema": {"type": "string", "enum": ["clamp", "aces"]}, "description": "PNG only: the tone-mapping curve, as raytile render --tonemap"},
                    {"name": "If-None-Match", "in": "header", "schema": {"type": "string"}, "description": "ETags of copies the client holds: 304 if one is current"},
                    {"name": "Range", "in": "header", "schema": {"type": "string"}, "description": "One byte range (bytes=a-b, bytes=a-, bytes=-n): 206 with those bytes; anything else is answered with the whole image"},
                    {"name": "If-Range", "in": "header", "schema": {"type": "string"}, "description": "Serve the Range only if this is the current ETag, else the whole image"}]), params,
                json!({"200": {"description": "Image (with ETag, Cache-Control: no-cache and Accept-Ranges: bytes)", "headers": dropped_header(), "content": {"image/png": {"schema": {"type": "string", "format": "binary"}}, "image/x-exr": {"schema": {"type": "string", "format": "binary"}}, "image/vnd.radiance": {"schema": {"type": "string", "format": "binary"}}}},
                    "206": {"description": "The requested bytes of the image (Content-Range)", "headers": dropped_header(), "content": {"image/png": {"schema": {"type": "string", "format": "binary"}}, "image/x-exr": {"schema": {"type": "string", "format": "binary"}}, "image/vnd.radiance": {"schema": {"type": "string", "format": "binary"}}}},
                    "304": {"description": "The copy named in If-None-Match is current; no body"},
                    "404": err("Unknown job"), "409": err("The job failed or was cancelled before any tile was finished: it has no image"), "416": err("The range starts past the end of the image (Content-Range: bytes */LENGTH; code range_not_satisfiable, field Range)"), "422": err("Unknown format; an exposure or tone map that is not one, or one asked of an EXR or HDR image (field named)"),
                    "503": err("Every image slot stayed busy (code busy; a few images are made at once, see --image-encodes): retry after Retry-After seconds")}))},
            "/v1/jobs/{id}/tiles": {"get": op("Each tile of the job: passes done and the workers rendering it", json!([job_id]), params,
                json!({"200": ok_json("Tiles", "TileList"), "404": err("Unknown job")}))},
            "/v1/jobs/{id}/priority": {"post": with_body(json_body("PriorityRequest"), op("Change a job's priority (higher runs first)", json!([job_id]),
                Inputs { params: true, json: true, writes: true },
                json!({"200": ok_json("Job", "JobStatus"), "404": err("Unknown job"), "422": err("No priority, a priority that is not a 32-bit integer (field priority), or an unknown field (field named)")})))},
            "/v1/jobs/{id}/retry": {"post": op("Retry a failed or cancelled job: it goes on (running, or queued if it never started) with the tiles it has, its failed tiles queued again with no failures held against them or against any worker. An unfinished job is answered as it is",
                json!([job_id]), Inputs { params: true, writes: true, ..none },
                json!({"200": ok_json("Job", "JobStatus"), "404": err("Unknown job"),
                    "409": err("The job is done, or its tiles were made by another renderer version (code conflict): submit it again instead"),
                    "429": err("Retried, the job would pass --max-queued-jobs or --max-queued-tasks (code too_many)")}))},
            "/v1/events": {"get": op(EVENTS_SUMMARY, json!([]), params,
                json!({"200": {"description": EVENTS_DESCRIPTION, "content": {"text/event-stream": {"schema": {"type": "string"}}}}}))},
            "/v1/jobs/{id}/tasks/{task}/result": {"put": with_body(binary_body(), op("Upload a tile result (workers): binary, see docs/farm.md",
                json!([job_id, {"name": "task", "in": "path", "required": true, "description": "Task index", "schema": {"type": "integer", "minimum": 0, "maximum": u32::MAX}},
                    {"name": "worker", "in": "query", "required": true, "description": "The id of the worker the lease was given to (the lease's tag covers it)", "schema": {"type": "string"}},
                    {"name": "lease", "in": "query", "required": true, "description": "The lease the result was rendered under: a result naming no lease of this task given to this worker is refused (422, field lease)", "schema": {"type": "string"}}]),
                Inputs { params: true, writes: true, ..none },
                json!({"200": ok_json("Accepted, or ignored as duplicate/late (duplicate: true) or for a finished job (job_finished: true)", "ResultReply"),
                    "404": err("Unknown job or task"), "413": err("Larger than the tile with its splats, or than --max-result-bytes"),
                    "503": err("The coordinator could not write its database, or every slot for large results (1 MiB or more) stayed busy (code busy): nothing changed, retry after Retry-After seconds"), "422": err("No lease or worker, or a lease this coordinator did not give for this task to this worker (field lease), a malformed result, wrong tile/pass, or a pixel sum that is NaN, infinite or out of what the pass can make, or more dropped samples than the tile's pixels times the pass's samples (then the task is queued again, counting a failure of the worker holding its lease when the upload names that lease)")})))},
            "/v1/workers": {
                "post": with_body(json_body("RegisterRequest"), op("Register a worker", json!([]), Inputs { json: true, writes: true, ..none },
                    json!({"200": ok_json("Registered", "Registered"), "409": err("Another renderer version: run one release on the whole farm")}))),
                "get": op("List workers", json!([]), params, json!({"200": ok_json("Workers", "WorkerList")}))},
            "/v1/workers/{id}/lease": {"post": op("Lease a task (long poll)",
                json!([path_param("id", "Worker id"), {"name": "wait_ms", "in": "query", "schema": {"type": "integer", "minimum": 0, "maximum": u64::MAX}, "description": "Longest wait for work (capped by the coordinator)"}]),
                Inputs { params: true, writes: true, ..none },
                json!({"200": ok_json("A task", "Lease"), "204": {"description": "No work within wait_ms"}, "404": err("Unknown worker: register again"),
                    "503": err("Shutting down, or the coordinator could not write its database: retry later")}))},
            "/v1/leases/{lease}/heartbeat": {"post": op("Extend a lease; says whether to stop", json!([lease_id]), params,
                json!({"200": ok_json("Reply", "HeartbeatReply")}))},
            "/v1/leases/{lease}/failure": {"post": with_body(json_body("FailureReport"), op("Report that the task failed", json!([lease_id]),
                Inputs { params: true, json: true, writes: true },
                json!({"204": {"description": "Recorded (or ignored for a stale lease)"}})))},
            "/v1/leases/{lease}/release": {"post": op("Hand a task back unrendered (worker shutting down)", json!([lease_id]),
                Inputs { params: true, writes: true, ..none },
                json!({"204": {"description": "Re-queued (or ignored for a stale lease)"}}))}
        }
    })
}

/// The image answers' header that counts the samples their frame dropped.
fn dropped_header() -> Value {
    json!({"X-Raytile-Dropped-Samples": {
        "description": "Samples the frame's results dropped as NaN, infinite or above 1.6e32 (not in the image; a pixel all of whose samples were dropped is black). Sent with every GET and with a HEAD of an image made already",
        "schema": {"type": "integer", "minimum": 0}}})
}
