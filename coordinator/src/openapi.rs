//! The OpenAPI 3 description of the API, written by hand (the API is small and this keeps
//! a derive-macro dependency out). A test checks it lists every route of the router.

use raytile_proto::{FilterKind, IntegratorKind, JobState};
use serde_json::{json, Value};

fn err(desc: &str) -> Value {
    json!({"description": desc, "content": {"application/json": {"schema": {"$ref": "#/components/schemas/Error"}}}})
}

fn ok_json(desc: &str, schema: &str) -> Value {
    json!({"description": desc, "content": {"application/json": {"schema": {"$ref": format!("#/components/schemas/{schema}")}}}})
}

fn path_param(name: &str, desc: &str) -> Value {
    json!({"name": name, "in": "path", "required": true, "description": desc, "schema": {"type": "string"}})
}

/// The whole document.
pub fn document() -> Value {
    let unauthorized = err("Missing or wrong bearer token.");
    json!({
        "openapi": "3.0.3",
        "info": {
            "title": "raytile coordinator",
            "version": env!("CARGO_PKG_VERSION"),
            "description": "Distributed path tracing: upload scenes, submit jobs, fetch images; workers lease tile passes and upload binary results. Every endpoint but /healthz needs `Authorization: Bearer TOKEN` when the coordinator has a token."
        },
        "components": {
            "securitySchemes": {"bearer": {"type": "http", "scheme": "bearer"}},
            "schemas": {
                "Error": {"type": "object", "required": ["error"], "properties": {"error": {"type": "object", "required": ["code", "message"], "properties": {
                    "code": {"type": "string"}, "message": {"type": "string"}, "field": {"type": "string"}}}}},
                "SceneCreated": {"type": "object", "properties": {"id": {"type": "string"}, "format": {"type": "string"}, "entry": {"type": "string"}, "existed": {"type": "boolean"}, "warnings": {"type": "array", "items": {"type": "string"}}}},
                "JobRequest": {"type": "object", "required": ["scene"], "additionalProperties": false, "properties": {
                    "scene": {"type": "string"}, "width": {"type": "integer"}, "height": {"type": "integer"}, "spp": {"type": "integer"},
                    "max_depth": {"type": "integer"}, "integrator": {"type": "string", "enum": IntegratorKind::ALL.map(IntegratorKind::name)},
                    "seed": {"type": "integer"}, "camera": {"type": "string"}, "filter": {"type": "string", "enum": FilterKind::ALL.map(FilterKind::name)},
                    "tile_size": {"type": "integer"}, "passes": {"type": "integer"}, "priority": {"type": "integer"},
                    "default_light": {"type": "boolean"}}},
                "JobStatus": {"type": "object", "properties": {
                    "id": {"type": "string"}, "scene": {"type": "string"}, "state": {"type": "string", "enum": JobState::ALL.map(JobState::name)},
                    "priority": {"type": "integer"}, "settings": {"type": "object"}, "tiles_total": {"type": "integer"}, "tiles_done": {"type": "integer"},
                    "passes": {"type": "integer"}, "passes_done": {"type": "integer"}, "tasks_total": {"type": "integer"}, "tasks_done": {"type": "integer"},
                    "tasks_leased": {"type": "integer"}, "samples_done": {"type": "integer"}, "samples_total": {"type": "integer"},
                    "workers": {"type": "object", "additionalProperties": {"type": "object", "properties": {"tasks": {"type": "integer"}, "samples": {"type": "integer"}}}},
                    "created_ms": {"type": "integer"}, "started_ms": {"type": "integer", "nullable": true}, "finished_ms": {"type": "integer", "nullable": true},
                    "error": {"type": "string", "nullable": true}}},
                "JobList": {"type": "object", "properties": {"jobs": {"type": "array", "items": {"$ref": "#/components/schemas/JobStatus"}}}},
                "RegisterRequest": {"type": "object", "properties": {"name": {"type": "string"}, "threads": {"type": "integer"}, "render_version": {"type": "integer", "description": "the worker's renderer version; a mismatch with the coordinator's is refused with 409"}}},
                "Registered": {"type": "object", "properties": {"worker_id": {"type": "string"}, "lease_timeout_ms": {"type": "integer"}, "heartbeat_ms": {"type": "integer"}}},
                "WorkerList": {"type": "object", "properties": {"workers": {"type": "array", "items": {"type": "object"}}}},
                "Lease": {"type": "object", "properties": {
                    "lease_id": {"type": "string"}, "job": {"type": "string"}, "task": {"type": "integer"}, "scene": {"type": "string"},
                    "scene_sha256": {"type": "string"}, "scene_format": {"type": "string"}, "scene_entry": {"type": "string"},
                    "settings": {"type": "object"}, "tile": {"type": "object", "properties": {"x0": {"type": "integer"}, "y0": {"type": "integer"}, "x1": {"type": "integer"}, "y1": {"type": "integer"}}},
                    "pass": {"type": "integer"}, "sample_start": {"type": "integer"}, "sample_end": {"type": "integer"}, "lease_timeout_ms": {"type": "integer"}}},
                "HeartbeatReply": {"type": "object", "properties": {"cancelled": {"type": "boolean"}, "reason": {"type": "string"}}},
                "ResultReply": {"type": "object", "properties": {"accepted": {"type": "boolean"}, "duplicate": {"type": "boolean"}, "job_finished": {"type": "boolean"}}},
                "FailureReport": {"type": "object", "properties": {"error": {"type": "string"}}}
            }
        },
        "security": [{"bearer": []}],
        "paths": {
            "/healthz": {"get": {"summary": "Liveness (no token needed)", "security": [], "responses": {"200": {"description": "ok"}}}},
            "/metrics": {"get": {"summary": "Prometheus metrics", "responses": {"200": {"description": "text/plain exposition format"}, "401": unauthorized}}},
            "/v1/openapi.json": {"get": {"summary": "This document", "responses": {"200": {"description": "OpenAPI 3 JSON"}, "401": unauthorized}}},
            "/v1/scenes": {"post": {
                "summary": "Upload a scene (.gltf with data URIs, .glb, JSON scene, or .tar/.zip of a scene folder)",
                "parameters": [
                    {"name": "format", "in": "query", "schema": {"type": "string", "enum": ["gltf", "glb", "json", "tar", "zip"]}, "description": "Format hint; otherwise Content-Type, then magic bytes."},
                    {"name": "entry", "in": "query", "schema": {"type": "string"}, "description": "Scene file inside an archive."}],
                "requestBody": {"required": true, "content": {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}}},
                "responses": {"201": ok_json("Stored", "SceneCreated"), "200": ok_json("Already stored", "SceneCreated"),
                    "413": err("Over the upload limit"), "422": err("Not a valid scene, or a file it names is refused (message names the JSON path or glTF field)"),
                    "503": err("Every scene check stayed busy (code busy): retry after Retry-After seconds"), "401": unauthorized}}},
            "/v1/scenes/{id}": {"get": {"summary": "Download a scene blob (workers)", "parameters": [path_param("id", "Scene id")],
                "responses": {"200": {"description": "The bytes as uploaded; headers x-raytile-sha256, x-raytile-format, x-raytile-entry", "content": {"application/octet-stream": {}}},
                    "404": err("Unknown scene"), "401": unauthorized}}},
            "/v1/jobs": {
                "post": {"summary": "Submit a job", "requestBody": {"required": true, "content": {"application/json": {"schema": {"$ref": "#/components/schemas/JobRequest"}}}},
                    "responses": {"201": ok_json("Created", "JobStatus"), "422": err("Invalid settings or unknown scene (field named)"), "429": err("Too many unfinished jobs"), "401": unauthorized}},
                "get": {"summary": "List jobs", "responses": {"200": ok_json("Jobs", "JobList"), "401": unauthorized}}},
            "/v1/jobs/{id}": {
                "get": {"summary": "Job status", "parameters": [path_param("id", "Job id")], "responses": {"200": ok_json("Job", "JobStatus"), "404": err("Unknown job"), "401": unauthorized}},
                "delete": {"summary": "Cancel a job; with purge=true also delete it and its tile data", "parameters": [path_param("id", "Job id"), {"name": "purge", "in": "query", "schema": {"type": "boolean"}, "description": "Delete the job and its stored tiles after cancelling it."}], "responses": {"200": ok_json("Job", "JobStatus"), "404": err("Unknown job"), "401": unauthorized}}},
            "/v1/jobs/{id}/image": {"get": {"summary": "The frame so far (partial while running)",
                "parameters": [path_param("id", "Job id"), {"name": "format", "in": "query", "schema": {"type": "string", "enum": ["png", "exr", "hdr"]}}],
                "responses": {"200": {"description": "Image", "content": {"image/png": {}, "image/x-exr": {}, "image/vnd.radiance": {}}}, "404": err("Unknown job"), "422": err("Unknown format"), "401": unauthorized}}},
            "/v1/jobs/{id}/tasks/{task}/result": {"put": {"summary": "Upload a tile result (workers): binary, see docs/farm.md",
                "parameters": [path_param("id", "Job id"), path_param("task", "Task index"), {"name": "worker", "in": "query", "schema": {"type": "string"}}],
                "requestBody": {"required": true, "content": {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}}},
                "responses": {"200": ok_json("Accepted, or ignored as duplicate/late (duplicate: true)", "ResultReply"), "404": err("Unknown job or task"),
                    "413": err("Larger than the tile"), "422": err("Malformed result or wrong tile/pass"), "401": unauthorized}}},
            "/v1/workers": {
                "post": {"summary": "Register a worker", "requestBody": {"required": true, "content": {"application/json": {"schema": {"$ref": "#/components/schemas/RegisterRequest"}}}},
                    "responses": {"200": ok_json("Registered", "Registered"), "401": unauthorized}},
                "get": {"summary": "List workers", "responses": {"200": ok_json("Workers", "WorkerList"), "401": unauthorized}}},
            "/v1/workers/{id}/lease": {"post": {"summary": "Lease a task (long poll)",
                "parameters": [path_param("id", "Worker id"), {"name": "wait_ms", "in": "query", "schema": {"type": "integer"}, "description": "Longest wait for work"}],
                "responses": {"200": ok_json("A task", "Lease"), "204": {"description": "No work within wait_ms"}, "404": err("Unknown worker: register again"),
                    "503": err("Shutting down"), "401": unauthorized}}},
            "/v1/leases/{lease}/heartbeat": {"post": {"summary": "Extend a lease; says whether to stop", "parameters": [path_param("lease", "Lease id")],
                "responses": {"200": ok_json("Reply", "HeartbeatReply"), "401": unauthorized}}},
            "/v1/leases/{lease}/failure": {"post": {"summary": "Report that the task failed", "parameters": [path_param("lease", "Lease id")],
                "requestBody": {"required": true, "content": {"application/json": {"schema": {"$ref": "#/components/schemas/FailureReport"}}}},
                "responses": {"204": {"description": "Recorded (or ignored for a stale lease)"}, "401": unauthorized}}},
            "/v1/leases/{lease}/release": {"post": {"summary": "Hand a task back unrendered (worker shutting down)", "parameters": [path_param("lease", "Lease id")],
                "responses": {"204": {"description": "Re-queued (or ignored for a stale lease)"}, "401": unauthorized}}}
        }
    })
}
