//! Coordinator tests at the HTTP level: the router called with `tower::ServiceExt::oneshot`,
//! no socket, a fake scene loader. (The scheduler's own tests are in `sched/tests.rs`.)

use crate::clock::Now;
use crate::{app, AppState, Config, LoadedScene};
use axum::body::Body;
use axum::http::{Request, StatusCode};
use std::sync::{Arc, Mutex};
use tower::ServiceExt;

#[tokio::test]
async fn delete_with_purge_removes_the_job_from_the_api() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), None);
    let (_, scene) = call(&st, post("/v1/scenes", r#"{"objects": []}"#)).await;
    let body = format!(r#"{{"scene": "{}"}}"#, scene["id"].as_str().unwrap());
    let (code, job) = call(&st, post("/v1/jobs", body)).await;
    assert_eq!(code, StatusCode::CREATED);
    let uri = format!("/v1/jobs/{}", job["id"].as_str().unwrap());
    let del = |q: &str| {
        Request::delete(format!("{uri}{q}"))
            .body(Body::empty())
            .unwrap()
    };
    let (code, body) = call(&st, del("")).await;
    assert_eq!(
        (code, body["state"].as_str()),
        (StatusCode::OK, Some("cancelled"))
    );
    assert_eq!(
        call(&st, get(&uri)).await.0,
        StatusCode::OK,
        "cancel keeps the job"
    );
    assert_eq!(call(&st, del("?purge=true")).await.0, StatusCode::OK);
    assert_eq!(call(&st, get(&uri)).await.0, StatusCode::NOT_FOUND);
    assert_eq!(call(&st, del("?purge=true")).await.0, StatusCode::NOT_FOUND);
}

fn test_state(dir: &std::path::Path, token: Option<&str>) -> AppState {
    let mut c = Config::new(dir);
    c.token = token.map(String::from);
    c.limits.max_upload_bytes = 4096;
    c.scene_loader = Arc::new(|_p: &std::path::Path| Ok(LoadedScene::default()));
    AppState::open(c).unwrap()
}

async fn call(state: &AppState, req: Request<Body>) -> (StatusCode, serde_json::Value) {
    let resp = app(state.clone()).oneshot(req).await.unwrap();
    let status = resp.status();
    let bytes = axum::body::to_bytes(resp.into_body(), usize::MAX)
        .await
        .unwrap();
    (
        status,
        serde_json::from_slice(&bytes).unwrap_or(serde_json::Value::Null),
    )
}

fn get(uri: &str) -> Request<Body> {
    Request::get(uri).body(Body::empty()).unwrap()
}

fn post(uri: &str, body: impl Into<Body>) -> Request<Body> {
    Request::post(uri)
        .header("content-type", "application/json")
        .body(body.into())
        .unwrap()
}

#[tokio::test]
async fn every_route_is_documented_and_routed() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), None);
    let doc = crate::openapi::document();
    for (method, path) in crate::api::ROUTES {
        assert!(
            doc["paths"][path][method].is_object(),
            "{method} {path} missing from OpenAPI"
        );
        let uri = path
            .replace("{id}", "x")
            .replace("{task}", "0")
            .replace("{lease}", "x");
        let req = Request::builder()
            .method(method.to_uppercase().as_str())
            .uri(&uri)
            .header("content-type", "application/json")
            .body(Body::from("{}"))
            .unwrap();
        let resp = app(st.clone()).oneshot(req).await.unwrap();
        assert_ne!(
            resp.status(),
            StatusCode::METHOD_NOT_ALLOWED,
            "{method} {path}"
        );
        if resp.status() == StatusCode::NOT_FOUND {
            let b = axum::body::to_bytes(resp.into_body(), usize::MAX)
                .await
                .unwrap();
            let v: serde_json::Value = serde_json::from_slice(&b).unwrap();
            assert_ne!(
                v["error"]["message"], "no such endpoint",
                "{method} {path} not routed"
            );
        }
    }
    // And every documented path is a route.
    let n: usize = doc["paths"]
        .as_object()
        .unwrap()
        .values()
        .map(|p| p.as_object().unwrap().len())
        .sum();
    assert_eq!(n, crate::api::ROUTES.len());
}

#[tokio::test]
async fn token_is_required_except_for_healthz() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), Some("sesame"));
    assert_eq!(call(&st, get("/healthz")).await.0, StatusCode::OK);
    let (code, body) = call(&st, get("/v1/jobs")).await;
    assert_eq!(code, StatusCode::UNAUTHORIZED);
    assert_eq!(body["error"]["code"], "unauthorized");
    let wrong = Request::get("/v1/jobs")
        .header("authorization", "Bearer nope")
        .body(Body::empty())
        .unwrap();
    assert_eq!(call(&st, wrong).await.0, StatusCode::UNAUTHORIZED);
    let right = Request::get("/v1/jobs")
        .header("authorization", "Bearer sesame")
        .body(Body::empty())
        .unwrap();
    assert_eq!(call(&st, right).await.0, StatusCode::OK);
}

#[tokio::test]
async fn jobs_validate_fields_and_scenes() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), None);
    let (code, body) = call(&st, post("/v1/scenes", r#"{"objects": []}"#)).await;
    assert_eq!(code, StatusCode::CREATED, "{body}");
    let id = body["id"].as_str().unwrap().to_string();
    let (code, again) = call(&st, post("/v1/scenes", r#"{"objects": []}"#)).await;
    assert_eq!(
        (code, again["id"].as_str().unwrap()),
        (StatusCode::OK, id.as_str())
    );
    let check = |json: String, code: StatusCode, field: Option<&'static str>| {
        let st = st.clone();
        async move {
            let (c, b) = call(&st, post("/v1/jobs", json.clone())).await;
            assert_eq!(c, code, "{json} → {b}");
            if let Some(f) = field {
                assert_eq!(b["error"]["field"], f, "{json} → {b}");
            }
            b
        }
    };
    check(
        format!(r#"{{"scene": "{id}", "spp": 0}}"#),
        StatusCode::UNPROCESSABLE_ENTITY,
        Some("spp"),
    )
    .await;
    check(
        format!(r#"{{"scene": "{id}", "width": 0}}"#),
        StatusCode::UNPROCESSABLE_ENTITY,
        Some("width"),
    )
    .await;
    check(
        format!(r#"{{"scene": "{id}", "spp": 4, "passes": 5}}"#),
        StatusCode::UNPROCESSABLE_ENTITY,
        Some("passes"),
    )
    .await;
    check(
        r#"{"scene": "nope"}"#.into(),
        StatusCode::UNPROCESSABLE_ENTITY,
        Some("scene"),
    )
    .await;
    check(
        format!(r#"{{"scene": "{id}", "integrator": "magic"}}"#),
        StatusCode::UNPROCESSABLE_ENTITY,
        Some("integrator"),
    )
    .await;
    check(
        format!(r#"{{"scene": "{id}", "spp": "many"}}"#),
        StatusCode::UNPROCESSABLE_ENTITY,
        Some("spp"),
    )
    .await;
    check(
        format!(r#"{{"scene": "{id}", "colour": 1}}"#),
        StatusCode::UNPROCESSABLE_ENTITY,
        Some("colour"),
    )
    .await;
    check("not json".into(), StatusCode::BAD_REQUEST, Some("body")).await;
    let b = check(
        format!(r#"{{"scene": "{id}", "width": 20, "height": 10, "spp": 2}}"#),
        StatusCode::CREATED,
        None,
    )
    .await;
    assert_eq!(b["state"], "queued");
    assert_eq!(b["settings"]["max_depth"], 16);
    let (code, _) = call(&st, get("/v1/jobs/job-404")).await;
    assert_eq!(code, StatusCode::NOT_FOUND);
    let (code, _) = call(&st, get("/v1/scenes/0000")).await;
    assert_eq!(code, StatusCode::NOT_FOUND);
}

#[tokio::test]
async fn oversize_and_unknown_uploads_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), None);
    let big = vec![b' '; 10_000];
    let (code, body) = call(&st, post("/v1/scenes", big)).await;
    assert_eq!(code, StatusCode::PAYLOAD_TOO_LARGE, "{body}");
    let (code, body) = call(&st, post("/v1/scenes", "hello")).await;
    assert_eq!(code, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    let (code, _) = call(&st, post("/v1/scenes?format=bmp", "{}")).await;
    assert_eq!(code, StatusCode::UNPROCESSABLE_ENTITY);
    // Still serving.
    assert_eq!(call(&st, get("/healthz")).await.0, StatusCode::OK);
}

/// A clock the test moves: every handler reads the time from the injected clock only.
fn manual_clock(c: &mut Config, start: Now) -> Arc<Mutex<Now>> {
    let now = Arc::new(Mutex::new(start));
    let read = now.clone();
    c.clock = Arc::new(move || *read.lock().unwrap());
    now
}

#[tokio::test]
async fn handlers_take_the_time_from_the_injected_clock() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = Config::new(dir.path());
    c.scene_loader = Arc::new(|_p: &std::path::Path| Ok(LoadedScene::default()));
    let start = Now {
        instant: tokio::time::Instant::now(),
        wall_ms: 42_000,
    };
    let clock = manual_clock(&mut c, start);
    let st = AppState::open(c).unwrap();
    let (_, scene) = call(&st, post("/v1/scenes", r#"{"objects": []}"#)).await;
    let body = format!(r#"{{"scene": "{}"}}"#, scene["id"].as_str().unwrap());
    let (_, job) = call(&st, post("/v1/jobs", body)).await;
    let reg = format!(
        r#"{{"name": "w", "threads": 1, "render_version": {}}}"#,
        raytile_core::RENDER_VERSION
    );
    let (code, worker) = call(&st, post("/v1/workers", reg)).await;
    assert_eq!(code, StatusCode::OK, "{worker}");
    *clock.lock().unwrap() = start.after(std::time::Duration::from_secs(5));
    let lease = format!(
        "/v1/workers/{}/lease",
        worker["worker_id"].as_str().unwrap()
    );
    let (code, _) = call(&st, post(&lease, "")).await;
    assert_eq!(code, StatusCode::OK);
    let (_, job) = call(
        &st,
        get(&format!("/v1/jobs/{}", job["id"].as_str().unwrap())),
    )
    .await;
    assert_eq!(
        (job["created_ms"].as_u64(), job["started_ms"].as_u64()),
        (Some(42_000), Some(47_000))
    );
    let (_, workers) = call(&st, get("/v1/workers")).await;
    let w = &workers["workers"][0];
    assert_eq!(
        (
            w["registered_ms"].as_u64(),
            w["last_seen_ms"].as_u64(),
            w["leased"].as_u64()
        ),
        (Some(42_000), Some(47_000), Some(1))
    );
}
