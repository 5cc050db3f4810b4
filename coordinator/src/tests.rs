//! Coordinator tests at the HTTP level: the router called with `tower::ServiceExt::oneshot`,
//! no socket, a fake scene loader. (The scheduler's own tests are in `sched/tests.rs`.)

use crate::clock::Now;
use crate::{app, AppState, Config, LoadedScene};
use axum::body::Body;
use axum::http::{Method, Request, StatusCode};
use std::sync::{Arc, Mutex};
use tower::ServiceExt;

#[tokio::test]
async fn delete_with_purge_removes_the_job_from_the_api() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), None);
    let (code, job) = empty_scene_job(&st, "").await;
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

/// `GET /v1/jobs` lists every job, or pages of those in some states; a page goes on after a
/// job purged meanwhile, and a wrong parameter is an error naming it.
#[tokio::test]
async fn the_job_list_comes_in_pages_and_by_state() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), None);
    let mut ids = Vec::new();
    for _ in 0..5 {
        let (code, job) = empty_scene_job(&st, "").await;
        assert_eq!(code, StatusCode::CREATED);
        ids.push(job["id"].as_str().unwrap().to_string());
    }
    let listed = |body: &serde_json::Value| -> Vec<String> {
        body["jobs"]
            .as_array()
            .unwrap()
            .iter()
            .map(|j| j["id"].as_str().unwrap().to_string())
            .collect()
    };
    let (code, all) = call(&st, get("/v1/jobs")).await;
    assert_eq!((code, listed(&all)), (StatusCode::OK, ids.clone()));
    assert!(all.get("next").is_none(), "{all}");
    // Pages of two: 2, 2, 1.
    let (_, p1) = call(&st, get("/v1/jobs?limit=2")).await;
    assert_eq!(listed(&p1), ids[..2]);
    let next = p1["next"].as_str().unwrap().to_string();
    assert_eq!(next, ids[1]);
    // The page's last job purged meanwhile: the next page starts where it would have.
    let purge = Request::delete(format!("/v1/jobs/{next}?purge=true"))
        .body(Body::empty())
        .unwrap();
    assert_eq!(call(&st, purge).await.0, StatusCode::OK);
    let (_, p2) = call(&st, get(&format!("/v1/jobs?limit=2&after={next}"))).await;
    assert_eq!(listed(&p2), ids[2..4]);
    let (_, p3) = call(&st, get(&format!("/v1/jobs?limit=2&after={}", ids[3]))).await;
    assert_eq!(listed(&p3), ids[4..]);
    assert!(p3.get("next").is_none(), "{p3}");
    // By state.
    let cancel = Request::delete(format!("/v1/jobs/{}", ids[0]))
        .body(Body::empty())
        .unwrap();
    assert_eq!(call(&st, cancel).await.0, StatusCode::OK);
    let (_, c) = call(&st, get("/v1/jobs?state=cancelled")).await;
    assert_eq!(listed(&c), ids[..1]);
    let (_, q) = call(&st, get("/v1/jobs?state=queued,running&limit=10")).await;
    assert_eq!(listed(&q), [&ids[2..]].concat());
    // Wrong parameters name themselves.
    for (query, field) in [
        ("state=sleeping", "state"),
        ("after=nothing", "after"),
        ("limit=0", "limit"),
    ] {
        let (code, body) = call(&st, get(&format!("/v1/jobs?{query}"))).await;
        assert_eq!(code, StatusCode::UNPROCESSABLE_ENTITY, "{query}: {body}");
        assert_eq!(body["error"]["field"], field, "{query}: {body}");
    }
    for query in ["limit=x", "lmit=2"] {
        let (code, body) = call(&st, get(&format!("/v1/jobs?{query}"))).await;
        assert_eq!(code, StatusCode::BAD_REQUEST, "{query}: {body}");
    }
}

/// The defaults with `dir` as the data directory and a scene loader that takes every scene as
/// an empty one.
fn fake_config(dir: impl Into<std::path::PathBuf>) -> Config {
    let mut c = Config::new(dir);
    c.scene_loader = Arc::new(|_p: &std::path::Path| Ok(LoadedScene::default()));
    c
}

fn test_state(dir: &std::path::Path, token: Option<&str>) -> AppState {
    let mut c = fake_config(dir);
    c.token = token.map(String::from);
    c.limits.max_upload_bytes = 4096;
    // Room for a result of a 32-pixel tile (16 KiB), not for a 64-pixel one's.
    c.limits.max_result_bytes = 1 << 15;
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

/// Uploads a scene with no objects and submits a job of it with the JSON members `fields`
/// (`""` for none): the job's answer.
async fn empty_scene_job(st: &AppState, fields: &str) -> (StatusCode, serde_json::Value) {
    let (_, scene) = call(st, post("/v1/scenes", r#"{"objects": []}"#)).await;
    let id = scene["id"].as_str().unwrap();
    let body = match fields {
        "" => format!(r#"{{"scene": "{id}"}}"#),
        f => format!(r#"{{"scene": "{id}", {f}}}"#),
    };
    call(st, post("/v1/jobs", body)).await
}

/// Registers a worker of this render version named `w` with one thread: the answer.
async fn register_worker(st: &AppState) -> (StatusCode, serde_json::Value) {
    let reg = format!(
        r#"{{"name": "w", "threads": 1, "render_version": {}}}"#,
        raytile_core::RENDER_VERSION
    );
    call(st, post("/v1/workers", reg)).await
}

/// A job of an empty scene with the JSON members `fields` and a newly registered worker:
/// their ids.
async fn job_and_worker(st: &AppState, fields: &str) -> (String, String) {
    let (code, job) = empty_scene_job(st, fields).await;
    assert_eq!(code, StatusCode::CREATED, "{job}");
    let (_, w) = register_worker(st).await;
    (
        job["id"].as_str().unwrap().to_string(),
        w["worker_id"].as_str().unwrap().to_string(),
    )
}

#[tokio::test]
async fn every_route_is_documented_and_routed() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), None);
    let doc = crate::openapi::document();
    let routes = crate::api::routes();
    for (method, path) in &routes {
        let method = method.as_str().to_lowercase();
        assert!(
            doc["paths"][path][&method].is_object(),
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
    assert_eq!(n, routes.len());
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
    // The scheme is case-insensitive (RFC 7235); the token is not, and a scheme is needed.
    for (header, want) in [
        ("Bearer sesame", StatusCode::OK),
        ("bearer sesame", StatusCode::OK),
        ("BEARER sesame", StatusCode::OK),
        ("Bearer Sesame", StatusCode::UNAUTHORIZED),
        ("Basic sesame", StatusCode::UNAUTHORIZED),
        ("Bearersesame", StatusCode::UNAUTHORIZED),
        ("sesame", StatusCode::UNAUTHORIZED),
    ] {
        let req = Request::get("/v1/jobs")
            .header("authorization", header)
            .body(Body::empty())
            .unwrap();
        assert_eq!(call(&st, req).await.0, want, "{header}");
    }
}

/// With a worker token, the workers' routes take it and only it, the others the clients'
/// token and only it; an unknown token is 401 everywhere, a known one on the wrong route 403.
#[tokio::test]
async fn a_worker_token_keeps_workers_and_clients_apart() {
    use crate::api::Role::{self, Client, Either, Worker};
    let dir = tempfile::tempdir().unwrap();
    let mut c = fake_config(dir.path());
    c.token = Some("users".into());
    c.worker_token = Some("workers".into());
    let st = AppState::open(c).unwrap();
    // Written out here, not read from the router's list: a route given the wrong role fails.
    let (get, post, put, delete) = (Method::GET, Method::POST, Method::PUT, Method::DELETE);
    let mut expected = vec![
        (get.clone(), "/healthz", Either),
        (get.clone(), "/metrics", Client),
        (get.clone(), "/v1/openapi.json", Either),
        (post.clone(), "/v1/scenes", Client),
        (get.clone(), "/v1/scenes/{id}", Either),
        (post.clone(), "/v1/jobs", Client),
        (get.clone(), "/v1/jobs", Client),
        (get.clone(), "/v1/jobs/{id}", Client),
        (delete, "/v1/jobs/{id}", Client),
        (get.clone(), "/v1/jobs/{id}/image", Client),
        (get.clone(), "/v1/jobs/{id}/tiles", Client),
        (post.clone(), "/v1/jobs/{id}/priority", Client),
        (post.clone(), "/v1/jobs/{id}/retry", Client),
        (get.clone(), "/v1/events", Client),
        (put, "/v1/jobs/{id}/tasks/{task}/result", Worker),
        (post.clone(), "/v1/workers", Worker),
        (get.clone(), "/v1/workers", Client),
        (post.clone(), "/v1/workers/{id}/lease", Worker),
        (post.clone(), "/v1/leases/{lease}/heartbeat", Worker),
        (post.clone(), "/v1/leases/{lease}/failure", Worker),
        (post, "/v1/leases/{lease}/release", Worker),
    ];
    let key = |r: &(Method, &str, Role)| (r.1.to_string(), r.0.to_string());
    let mut roles = crate::api::roles();
    roles.sort_by_key(key);
    expected.sort_by_key(key);
    assert_eq!(roles, expected);
    // HEAD is served by the GET route, and takes the same token; a method no route of a known
    // path serves (OPTIONS, or HEAD of a POST route) is the clients', answered 405 to them.
    let mut cases: Vec<(Method, &str, Role)> = expected.clone();
    for (m, p, r) in &expected {
        let head = if *m == get { *r } else { Client };
        cases.push((Method::HEAD, p, head));
        cases.push((Method::OPTIONS, p, Client));
    }
    for (method, path, role) in &cases {
        if *path == "/healthz" {
            continue;
        }
        let uri = path
            .replace("{id}", "x")
            .replace("{task}", "0")
            .replace("{lease}", "l-1-1-00");
        for token in [None, Some("users"), Some("workers"), Some("nope")] {
            let mut req = Request::builder().method(method.clone()).uri(&uri);
            if let Some(t) = token {
                req = req.header("authorization", format!("Bearer {t}"));
            }
            // Only the status: the event stream's body never ends.
            let resp = app(st.clone())
                .oneshot(req.body(Body::empty()).unwrap())
                .await
                .unwrap();
            let allowed = matches!(
                (role, token),
                (Client, Some("users"))
                    | (Worker, Some("workers"))
                    | (Either, Some("users" | "workers"))
            );
            let code = resp.status();
            if code == StatusCode::FORBIDDEN && *method != Method::HEAD {
                // Named as the header's fault, so that the pages ask for another token.
                let body = axum::body::to_bytes(resp.into_body(), usize::MAX)
                    .await
                    .unwrap();
                let body: serde_json::Value = serde_json::from_slice(&body).unwrap();
                assert_eq!(body["error"]["field"], "Authorization", "{body}");
            }
            let want = match token {
                _ if allowed => None,
                Some("users" | "workers") => Some(StatusCode::FORBIDDEN),
                _ => Some(StatusCode::UNAUTHORIZED),
            };
            match want {
                Some(want) => assert_eq!(code, want, "{method} {uri} {token:?}"),
                None => assert!(
                    code != StatusCode::UNAUTHORIZED && code != StatusCode::FORBIDDEN,
                    "{method} {uri} {token:?}: {code}"
                ),
            }
        }
    }
    // A path no route serves is 404 to either token, 401 to others.
    for token in ["users", "workers", "nope"] {
        let req = Request::get("/v1/nothing")
            .header("authorization", format!("Bearer {token}"))
            .body(Body::empty())
            .unwrap();
        let want = match token {
            "nope" => StatusCode::UNAUTHORIZED,
            _ => StatusCode::NOT_FOUND,
        };
        assert_eq!(call(&st, req).await.0, want, "{token}");
    }
    // A worker token needs a token, and another one.
    let loopback = std::net::IpAddr::from([127, 0, 0, 1]);
    let mut c = fake_config(dir.path());
    c.worker_token = Some("workers".into());
    let e = crate::check_exposure(loopback, &c).unwrap_err().to_string();
    assert!(e.contains("needs a token"), "{e}");
    c.token = Some("workers".into());
    let e = crate::check_exposure(loopback, &c).unwrap_err().to_string();
    assert!(e.contains("is the clients' token"), "{e}");
    c.token = Some("users".into());
    crate::check_exposure(loopback, &c).unwrap();
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

/// A JSON body of the wrong shape is answered with serde's own message alone, the offending
/// field's path first (`width: invalid type: ...`), and names that field.
#[tokio::test]
async fn wrong_json_is_answered_with_serdes_message_naming_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), None);
    let (_, scene) = call(&st, post("/v1/scenes", r#"{"objects": []}"#)).await;
    let id = scene["id"].as_str().unwrap();
    for (uri, body, field, want) in [
        (
            "/v1/jobs",
            format!(r#"{{"width": "x", "scene": "{id}"}}"#),
            "width",
            r#"width: invalid type: string "x", expected an integer from 0 to 4294967295"#,
        ),
        (
            "/v1/workers",
            r#"{"name": "w", "threads": "x"}"#.into(),
            "threads",
            r#"threads: invalid type: string "x", expected an integer from 0 to 4294967295 at line 1 column 28"#,
        ),
        (
            "/v1/workers",
            r#""x""#.into(),
            "body",
            r#"body: invalid type: string "x", expected an object at line 1 column 3"#,
        ),
    ] {
        let (code, b) = call(&st, post(uri, body.clone())).await;
        assert_eq!(code, StatusCode::UNPROCESSABLE_ENTITY, "{body} → {b}");
        assert_error_body(&body, &b);
        assert_eq!(b["error"]["field"], field, "{body} → {b}");
        assert_eq!(b["error"]["message"], want, "{body} → {b}");
    }
    // A body that is not JSON at all: a 400 with serde's message, no framework preface.
    let (code, b) = call(&st, post("/v1/workers", r#"{"name": "#)).await;
    assert_eq!(code, StatusCode::BAD_REQUEST, "{b}");
    assert_eq!(b["error"]["field"], "body", "{b}");
    assert_eq!(
        b["error"]["message"], "body: not valid JSON: EOF while parsing a value at line 1 column 9",
        "{b}"
    );
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
    let mut c = fake_config(dir.path());
    let start = Now {
        instant: tokio::time::Instant::now(),
        wall_ms: 42_000,
    };
    let clock = manual_clock(&mut c, start);
    let st = AppState::open(c).unwrap();
    let (_, job) = empty_scene_job(&st, "").await;
    let (code, worker) = register_worker(&st).await;
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

/// Checks that `body` is the documented error body: `{"error": {"code", "message"}}` with an
/// optional `field` and `retryable`, nothing else.
fn assert_error_body(what: &str, body: &serde_json::Value) {
    let e = body["error"]
        .as_object()
        .unwrap_or_else(|| panic!("{what}: {body}"));
    assert_eq!(body.as_object().unwrap().len(), 1, "{what}: {body}");
    assert!(
        e["code"].is_string() && e["message"].is_string(),
        "{what}: {body}"
    );
    for (k, v) in e {
        match k.as_str() {
            "code" | "message" => {}
            "field" => assert!(v.is_string(), "{what}: {body}"),
            "retryable" => assert!(v.is_boolean(), "{what}: {body}"),
            _ => panic!("{what}: unexpected key {k} in {body}"),
        }
    }
}

/// Every route of the real router gets bad path parameters, bad query strings, bad JSON
/// bodies, a method it does not serve and no token; every answer is the documented JSON error
/// with the expected status and field, and its status is listed for the operation in the
/// OpenAPI document.
#[tokio::test]
async fn every_rejection_of_every_route_is_the_documented_json_error() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), Some("sesame"));
    let doc = crate::openapi::document();
    let mut checked = 0;
    for (method, path) in crate::api::routes() {
        let op = &doc["paths"][path][method.as_str().to_lowercase()];
        assert!(op.is_object(), "{method} {path} is not documented");
        let params: Vec<&str> = path
            .split('/')
            .filter_map(|s| s.strip_prefix('{')?.strip_suffix('}'))
            .collect();
        let fill = |bad: Option<&str>| {
            let mut uri = path.to_string();
            for p in &params {
                let v = match (Some(*p) == bad, *p) {
                    (true, "task") => "abc",
                    (true, _) => "%FF",
                    (false, "task") => "0",
                    (false, _) => "x",
                };
                uri = uri.replace(&format!("{{{p}}}"), v);
            }
            uri
        };
        // (what, request, status, field)
        let mut cases: Vec<(String, Request<Body>, u16, Option<String>)> = Vec::new();
        let req = |uri: &str, ct: Option<&str>, body: Body, token: bool| {
            let mut b = Request::builder().method(method.clone()).uri(uri);
            if token {
                b = b.header("authorization", "Bearer sesame");
            }
            if let Some(ct) = ct {
                b = b.header("content-type", ct);
            }
            b.body(body).unwrap()
        };
        for p in &params {
            let uri = fill(Some(p));
            cases.push((
                format!("bad path parameter {p}"),
                req(&uri, None, Body::empty(), true),
                400,
                Some(p.to_string()),
            ));
        }
        let query: Vec<(&str, &str)> = op["parameters"]
            .as_array()
            .into_iter()
            .flatten()
            .filter(|p| p["in"] == "query")
            .map(|p| {
                (
                    p["name"].as_str().unwrap(),
                    p["schema"]["type"].as_str().unwrap(),
                )
            })
            .collect();
        for (name, ty) in &query {
            let uri = format!("{}?{name}=a&{name}=b", fill(None));
            cases.push((
                format!("{name} twice"),
                req(&uri, None, Body::empty(), true),
                400,
                Some(name.to_string()),
            ));
            // Bytes that are not UTF-8 once percent-decoded.
            let uri = format!("{}?{name}=%ff", fill(None));
            cases.push((
                format!("{name} not UTF-8"),
                req(&uri, None, Body::empty(), true),
                400,
                Some(name.to_string()),
            ));
            if *ty != "string" {
                let uri = format!("{}?{name}=x", fill(None));
                cases.push((
                    format!("{name} not a {ty}"),
                    req(&uri, None, Body::empty(), true),
                    400,
                    Some(name.to_string()),
                ));
            }
        }
        // A client's misspelt parameter is an error, not ignored (`?formt=exr` answered PNG),
        // on the routes that take none too (`GET /v1/jobs/ID?format=png` is not the status).
        let client = crate::api::roles()
            .into_iter()
            .any(|(m, p, r)| m == method && p == path && matches!(r, crate::api::Role::Client));
        if client {
            cases.push((
                "an unknown parameter".into(),
                req(
                    &format!("{}?nosuch=1", fill(None)),
                    None,
                    Body::empty(),
                    true,
                ),
                400,
                Some("nosuch".into()),
            ));
        }
        if op["requestBody"]["content"]["application/json"].is_object() {
            let uri = fill(None);
            let json = Some("application/json");
            for (what, ct, body, status, field) in [
                ("not JSON", json, Body::from("not json"), 400, Some("body")),
                ("no Content-Type", None, Body::from("{}"), 415, Some("body")),
                ("a JSON array", json, Body::from("[1]"), 422, Some("body")),
                // An object's values in order are not the object (serde's derived structs
                // would take them: a worker named "w" with 2 threads).
                (
                    "its values as an array",
                    json,
                    Body::from(r#"["w", 2, 0]"#),
                    422,
                    Some("body"),
                ),
                (
                    "over the limit",
                    json,
                    Body::from(vec![b' '; crate::api::JSON_BODY_LIMIT + 1]),
                    413,
                    None,
                ),
            ] {
                cases.push((
                    what.into(),
                    req(&uri, ct, body, true),
                    status,
                    field.map(String::from),
                ));
            }
        }
        if path != "/healthz" {
            cases.push((
                "no token".into(),
                req(&fill(None), None, Body::empty(), false),
                401,
                None,
            ));
        }
        for (what, r, status, field) in cases {
            let what = format!("{method} {path}: {what}");
            let (code, body) = call(&st, r).await;
            assert_eq!(code.as_u16(), status, "{what}: {body}");
            assert_error_body(&what, &body);
            assert_eq!(
                body["error"]["field"].as_str(),
                field.as_deref(),
                "{what}: {body}"
            );
            assert!(
                op["responses"][status.to_string()].is_object(),
                "{what}: {status} is not documented"
            );
            checked += 1;
        }
        // A method the path does not serve.
        let r = Request::builder()
            .method("PATCH")
            .uri(fill(None))
            .header("authorization", "Bearer sesame")
            .body(Body::empty())
            .unwrap();
        let (code, body) = call(&st, r).await;
        assert_eq!(code, StatusCode::METHOD_NOT_ALLOWED, "PATCH {path}: {body}");
        assert_error_body(&format!("PATCH {path}"), &body);
    }
    assert!(checked > 40, "only {checked} cases");
    let r = Request::get("/v1/nothing")
        .header("authorization", "Bearer sesame")
        .body(Body::empty())
        .unwrap();
    let (code, body) = call(&st, r).await;
    assert_eq!(code, StatusCode::NOT_FOUND);
    assert_error_body("unknown route", &body);
}

/// Each job limit is refused with 422 naming the field, by arithmetic before anything is
/// allocated: a frame of 8192² one-pixel tiles (67 million tasks) is answered at once.
#[tokio::test]
async fn jobs_over_the_limits_are_refused_at_once_naming_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), None);
    let (_, scene) = call(&st, post("/v1/scenes", r#"{"objects": []}"#)).await;
    let id = scene["id"].as_str().unwrap().to_string();
    let check = |fields: &str, field: &str| {
        let body = format!(r#"{{"scene": "{id}", {fields}}}"#);
        let (st, field) = (st.clone(), field.to_string());
        async move {
            let t = std::time::Instant::now();
            let (code, b) = call(&st, post("/v1/jobs", body.clone())).await;
            let took = t.elapsed();
            assert_eq!(code, StatusCode::UNPROCESSABLE_ENTITY, "{body}: {b}");
            assert_eq!(b["error"]["field"], field.as_str(), "{body}: {b}");
            assert!(
                took < std::time::Duration::from_millis(500),
                "{body}: {took:?}"
            );
            b
        }
    };
    let b = check(
        r#""width": 8192, "height": 8192, "tile_size": 1, "spp": 64, "passes": 64"#,
        "tile_size",
    )
    .await;
    assert!(
        b["error"]["message"]
            .as_str()
            .unwrap()
            .contains("at least 16"),
        "{b}"
    );
    // Tiles alone over the task limit (the minimum tile size allowed).
    check(
        r#""width": 16384, "height": 8192, "tile_size": 16"#,
        "tile_size",
    )
    .await;
    // Tiles × passes over it.
    let b = check(
        r#""width": 4096, "height": 4096, "tile_size": 16, "spp": 64, "passes": 8"#,
        "passes",
    )
    .await;
    assert!(
        b["error"]["message"]
            .as_str()
            .unwrap()
            .contains("524288 tasks"),
        "{b}"
    );
    check(r#""spp": 512, "passes": 512"#, "passes").await;
    // A bdpt tile's result can hold a splat for every pixel of the frame: 32 × 32 × 52 bytes
    // is over this coordinator's 32 KiB results.
    let b = check(
        r#""width": 32, "height": 32, "integrator": "bdpt""#,
        "width",
    )
    .await;
    let message = b["error"]["message"].as_str().unwrap();
    assert!(message.contains("--max-result-bytes"), "{b}");
    // Any job's tiles must fit: 64 × 64 pixels make 64 KiB results; 44 × 44 ones 30.3 KiB,
    // but 37.9 with an alpha channel.
    let b = check(r#""tile_size": 64"#, "tile_size").await;
    let message = b["error"]["message"].as_str().unwrap();
    assert!(message.contains("use smaller tiles"), "{b}");
    check(r#""tile_size": 44, "alpha": true"#, "tile_size").await;
    assert_eq!(st.sched().job_list().len(), 0, "nothing was created");
    let (code, b) = call(
        &st,
        post(
            "/v1/jobs",
            format!(r#"{{"scene": "{id}", "width": 6, "height": 6, "integrator": "bdpt"}}"#),
        ),
    )
    .await;
    assert_eq!(code, StatusCode::CREATED, "a small bdpt frame fits: {b}");
    let purge = Request::delete(format!("/v1/jobs/{}?purge=true", b["id"].as_str().unwrap()))
        .body(Body::empty())
        .unwrap();
    assert_eq!(call(&st, purge).await.0, StatusCode::OK);
    // Limits set by the operator.
    let mut c = fake_config(dir.path().join("b"));
    c.limits.max_pixels = 1000;
    c.limits.max_spp = 8;
    let st2 = AppState::open(c).unwrap();
    let (_, scene) = call(&st2, post("/v1/scenes", r#"{"objects": []}"#)).await;
    let id2 = scene["id"].as_str().unwrap();
    for (fields, field) in [
        (r#""width": 40, "height": 30"#, "width"),
        (r#""width": 10, "height": 10, "spp": 9"#, "spp"),
    ] {
        let body = format!(r#"{{"scene": "{id2}", {fields}}}"#);
        let (code, b) = call(&st2, post("/v1/jobs", body)).await;
        assert_eq!(
            (code, b["error"]["field"].as_str()),
            (StatusCode::UNPROCESSABLE_ENTITY, Some(field)),
            "{b}"
        );
    }
    let body = format!(r#"{{"scene": "{id2}", "width": 10, "height": 10, "spp": 8}}"#);
    assert_eq!(
        call(&st2, post("/v1/jobs", body)).await.0,
        StatusCode::CREATED
    );
    // Queued work as a whole: 2^22 tasks by default, 2^18 in a job; the 17th such job waits.
    let big =
        format!(r#"{{"scene": "{id}", "width": 8192, "height": 8192, "tile_size": 16, "spp": 1}}"#);
    for _ in 0..16 {
        let (code, b) = call(&st, post("/v1/jobs", big.clone())).await;
        assert_eq!(code, StatusCode::CREATED, "{b}");
    }
    let (code, b) = call(&st, post("/v1/jobs", big)).await;
    assert_eq!(code, StatusCode::TOO_MANY_REQUESTS, "{b}");
    assert_error_body("429", &b);
}

/// A store that cannot be written answers 503 with a retryable body and changes nothing; the
/// same request succeeds once the store is back.
#[tokio::test]
async fn a_store_fault_is_a_retryable_503_and_the_retry_succeeds() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), None);
    let (_, scene) = call(&st, post("/v1/scenes", r#"{"objects": []}"#)).await;
    let body = format!(r#"{{"scene": "{}"}}"#, scene["id"].as_str().unwrap());
    let failures = || crate::error::STORE_FAILURES.load(std::sync::atomic::Ordering::Relaxed);
    let before = failures();
    st.sched().store_faults().fail_next(1);
    let resp = app(st.clone())
        .oneshot(post("/v1/jobs", body.clone()))
        .await
        .unwrap();
    assert_eq!(resp.status(), StatusCode::SERVICE_UNAVAILABLE);
    // Counted for monitoring (other tests of this process may count theirs too).
    assert!(failures() > before);
    let metrics = app(st.clone()).oneshot(get("/metrics")).await.unwrap();
    let metrics = axum::body::to_bytes(metrics.into_body(), usize::MAX)
        .await
        .unwrap();
    assert!(String::from_utf8_lossy(&metrics).contains("raytile_store_failures_total "));
    assert_eq!(resp.headers()["retry-after"], "1");
    let b = axum::body::to_bytes(resp.into_body(), usize::MAX)
        .await
        .unwrap();
    let b: serde_json::Value = serde_json::from_slice(&b).unwrap();
    assert_error_body("503", &b);
    assert_eq!(
        (
            b["error"]["code"].as_str(),
            b["error"]["retryable"].as_bool()
        ),
        (Some("store_unavailable"), Some(true))
    );
    assert_eq!(st.sched().job_list().len(), 0);
    let (code, _) = call(&st, post("/v1/jobs", body)).await;
    assert_eq!(code, StatusCode::CREATED);
    assert_eq!(st.sched().job_list().len(), 1);
}

/// Every job setting (the fields of `RenderOverrides`, as `raytile submit` sends them) is
/// described in the OpenAPI document, in the request and in the settings a job reports.
#[test]
fn every_job_setting_is_documented() {
    let doc = crate::openapi::document();
    let schemas = &doc["components"]["schemas"];
    for field in raytile_proto::RenderOverrides::FIELDS {
        assert!(
            schemas["JobRequest"]["properties"][field].is_object(),
            "JobRequest lacks {field}"
        );
        assert!(
            schemas["RenderSettings"]["properties"][field].is_object(),
            "RenderSettings lacks {field}"
        );
    }
}

#[tokio::test]
async fn pages_are_served_without_the_token_and_load_nothing_from_elsewhere() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), Some("sesame"));
    for (uri, ct) in [
        ("/", "text/html"),
        ("/jobs/j-1", "text/html"),
        ("/workers", "text/html"),
        ("/ui/app.js", "text/javascript"),
        ("/ui/style.css", "text/css"),
        ("/ui/icon.svg", "image/svg+xml"),
    ] {
        let resp = app(st.clone()).oneshot(get(uri)).await.unwrap();
        assert_eq!(resp.status(), StatusCode::OK, "{uri}");
        let h = resp.headers();
        assert!(h["content-type"].to_str().unwrap().starts_with(ct), "{uri}");
        let csp = h["content-security-policy"].to_str().unwrap();
        assert!(csp.contains("default-src 'none'") && csp.contains("connect-src 'self'"));
        let body = axum::body::to_bytes(resp.into_body(), usize::MAX)
            .await
            .unwrap();
        let text = String::from_utf8(body.to_vec()).unwrap();
        // No absolute or protocol-relative URL: the SVG's XML namespace names, it loads nothing.
        let text = text.replace("xmlns=\"http://www.w3.org/2000/svg\"", "");
        for bad in [
            "http://",
            "https://",
            "src=\"//",
            "href=\"//",
            "url(",
            "@import",
        ] {
            assert!(!text.contains(bad), "{uri} contains {bad}");
        }
    }
    // Data still needs the token; a deeper path under /jobs/ is not a page.
    assert_eq!(call(&st, get("/v1/jobs")).await.0, StatusCode::UNAUTHORIZED);
    assert_eq!(
        call(&st, get("/jobs/a/b")).await.0,
        StatusCode::UNAUTHORIZED
    );
}

#[tokio::test]
async fn the_token_is_taken_from_the_header_only() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), Some("se/same+1"));
    let with = |method: &str, uri: &str, cookie: &str, auth: Option<&str>| {
        let mut b = Request::builder()
            .method(method)
            .uri(uri)
            .header("cookie", cookie);
        if let Some(a) = auth {
            b = b.header("authorization", a);
        }
        b.body(Body::empty()).unwrap()
    };
    // A browser sends cookies with other sites' requests and to other ports of the host: the
    // coordinator takes none.
    let cookie = "a=1; raytile_token=se%2Fsame%2B1";
    for method in ["GET", "DELETE"] {
        let (code, _) = call(&st, with(method, "/v1/jobs/x", cookie, None)).await;
        assert_eq!(code, StatusCode::UNAUTHORIZED, "{method}");
    }
    let auth = Some("Bearer se/same+1");
    let (code, _) = call(&st, with("DELETE", "/v1/jobs/x", "", auth)).await;
    assert_eq!(code, StatusCode::NOT_FOUND);
}

#[tokio::test]
async fn other_sites_pages_cannot_change_anything() {
    for token in [None, Some("t")] {
        let dir = tempfile::tempdir().unwrap();
        let st = test_state(dir.path(), token);
        let req = |method: &str, headers: &[(&str, &str)]| {
            let mut b = Request::builder()
                .method(method)
                .uri("/v1/scenes?format=json")
                .header("host", "127.0.0.1:8080")
                .header("authorization", "Bearer t");
            for (k, v) in headers {
                b = b.header(*k, *v);
            }
            b.body(Body::from("{}")).unwrap()
        };
        for headers in [
            &[("origin", "http://evil.example")][..],
            &[("origin", "http://127.0.0.1:9999")],
            &[("origin", "null")],
            &[("sec-fetch-site", "cross-site")],
            &[
                ("sec-fetch-site", "same-site"),
                ("origin", "http://127.0.0.1:8080"),
            ],
        ] {
            let (code, e) = call(&st, req("POST", headers)).await;
            assert_eq!(code, StatusCode::FORBIDDEN, "{token:?} {headers:?}: {e}");
            let says = e["error"]["message"].as_str().unwrap();
            assert!(says.contains("its own pages and from programs only"), "{e}");
        }
        // The coordinator's own pages, and programs (no such header), may.
        for headers in [
            &[
                ("origin", "http://127.0.0.1:8080"),
                ("sec-fetch-site", "same-origin"),
            ][..],
            &[],
        ] {
            let (code, e) = call(&st, req("POST", headers)).await;
            assert!(code.is_success(), "{token:?} {headers:?}: {code} {e}");
        }
        // Reading is not refused on these grounds (the browser does not let the page read the
        // answer).
        let mut get = req("GET", &[("origin", "http://evil.example")]);
        *get.uri_mut() = "/v1/jobs".parse().unwrap();
        assert_eq!(call(&st, get).await.0, StatusCode::OK, "{token:?}");
    }
}

#[tokio::test]
async fn a_coordinator_without_a_token_answers_only_to_its_addresses() {
    let dir = tempfile::tempdir().unwrap();
    let get = |host: &str| {
        Request::builder()
            .uri("/v1/jobs")
            .header("host", host)
            .body(Body::empty())
            .unwrap()
    };
    let st = test_state(dir.path(), None);
    for host in [
        "127.0.0.1:8080",
        "localhost:8080",
        "LOCALHOST",
        "farm.localhost:1",
        "[::1]:8080",
        "10.0.0.7",
    ] {
        assert_eq!(call(&st, get(host)).await.0, StatusCode::OK, "{host}");
    }
    // A name a DNS answer can turn to 127.0.0.1 (rebinding) is refused.
    for host in [
        "attacker.example:8080",
        "localhost.evil.example",
        "[::1",
        "127.0.0.1.nip.io",
    ] {
        let (code, e) = call(&st, get(host)).await;
        assert_eq!(code, StatusCode::FORBIDDEN, "{host}: {e}");
        assert!(
            e["error"]["message"]
                .as_str()
                .unwrap()
                .contains("127.0.0.1"),
            "{e}"
        );
    }
    // With a token, or with --insecure, any name.
    let mut with_token = get("farm-host:8080");
    with_token
        .headers_mut()
        .insert("authorization", "Bearer t".parse().unwrap());
    let other = tempfile::tempdir().unwrap();
    let with_a_token = test_state(other.path(), Some("t"));
    assert_eq!(call(&with_a_token, with_token).await.0, StatusCode::OK);
    let other = tempfile::tempdir().unwrap();
    let mut c = Config::new(other.path());
    c.insecure = true;
    let insecure = AppState::open(c).unwrap();
    assert_eq!(
        call(&insecure, get("farm-host:8080")).await.0,
        StatusCode::OK
    );
}

#[tokio::test]
async fn priority_and_tiles_of_a_job() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), None);
    let (_, job) = empty_scene_job(
        &st,
        r#""width": 48, "height": 32, "tile_size": 16, "passes": 2, "spp": 2"#,
    )
    .await;
    let id = job["id"].as_str().unwrap();
    let (code, j) = call(
        &st,
        post(&format!("/v1/jobs/{id}/priority"), r#"{"priority": 5}"#),
    )
    .await;
    assert_eq!((code, j["priority"].as_i64()), (StatusCode::OK, Some(5)));
    assert_eq!(
        call(&st, get(&format!("/v1/jobs/{id}"))).await.1["priority"],
        5
    );
    let (code, e) = call(
        &st,
        post(
            &format!("/v1/jobs/{id}/priority"),
            r#"{"priority": "high"}"#,
        ),
    )
    .await;
    assert_eq!(code, StatusCode::UNPROCESSABLE_ENTITY, "{e}");
    assert_eq!(e["error"]["field"], "priority", "{e}");
    // An unknown field is named, as `POST /v1/jobs` names one; a missing priority too.
    for (body, field, says) in [
        (
            r#"{"priority": 1, "x": 2}"#,
            "x",
            "x: unknown field `x`, expected `priority`",
        ),
        (r#"{}"#, "priority", "priority: missing field `priority`"),
    ] {
        let (code, e) = call(&st, post(&format!("/v1/jobs/{id}/priority"), body)).await;
        assert_eq!(code, StatusCode::UNPROCESSABLE_ENTITY, "{body}: {e}");
        assert_error_body(body, &e);
        assert_eq!(
            (&e["error"]["field"], &e["error"]["message"]),
            (&field.into(), &says.into()),
            "{body}"
        );
    }
    let (code, _) = call(&st, post("/v1/jobs/nope/priority", r#"{"priority": 1}"#)).await;
    assert_eq!(code, StatusCode::NOT_FOUND);
    // 3 × 2 tiles, none started, in row order.
    let (code, t) = call(&st, get(&format!("/v1/jobs/{id}/tiles"))).await;
    assert_eq!(code, StatusCode::OK);
    assert_eq!(t["passes"], 2);
    assert!(t["event_id"].is_u64(), "{t}");
    let tiles = t["tiles"].as_array().unwrap();
    assert_eq!(tiles.len(), 6);
    assert_eq!(tiles[1]["tile"]["x0"], 16);
    assert!(tiles
        .iter()
        .all(|t| t["passes_done"] == 0 && t["workers"].as_array().unwrap().is_empty()));
}

/// A tar archive of regular files (a name ending in '/' is a folder record), names written as
/// given: `./a` and `x//y` stay as they are.
fn raw_tar(members: &[(&str, &[u8])]) -> Vec<u8> {
    let mut out = Vec::new();
    for (name, data) in members {
        let dir = name.ends_with('/');
        let data: &[u8] = if dir { b"" } else { data };
        let mut h = [0u8; 512];
        h[..name.len()].copy_from_slice(name.as_bytes());
        h[100..107].copy_from_slice(b"0000644");
        h[108..115].copy_from_slice(b"0000000");
        h[116..123].copy_from_slice(b"0000000");
        h[124..135].copy_from_slice(format!("{:011o}", data.len()).as_bytes());
        h[136..147].copy_from_slice(b"00000000000");
        h[156] = if dir { b'5' } else { b'0' };
        h[257..265].copy_from_slice(b"ustar\x0000");
        h[148..156].copy_from_slice(b"        ");
        let sum: u32 = h.iter().map(|&b| b as u32).sum();
        h[148..155].copy_from_slice(format!("{sum:06o}\0").as_bytes());
        out.extend_from_slice(&h);
        out.extend_from_slice(data);
        out.resize(out.len().div_ceil(512) * 512, 0);
    }
    out.resize(out.len() + 1024, 0);
    out
}

/// A zip archive of stored members with names written as given, duplicates included (CRCs
/// left at zero: only the names are read before such an archive is refused).
fn raw_zip(names: &[&str]) -> Vec<u8> {
    let (mut out, mut central) = (Vec::new(), Vec::new());
    for name in names {
        let offset = out.len() as u32;
        let n = name.len() as u16;
        // Signature, version 2.0, no flags, stored, time, date, CRC and sizes zero.
        out.extend_from_slice(b"PK\x03\x04");
        out.extend_from_slice(&20u16.to_le_bytes());
        out.extend_from_slice(&[0u8; 20]);
        out.extend_from_slice(&n.to_le_bytes());
        out.extend_from_slice(&0u16.to_le_bytes());
        out.extend_from_slice(name.as_bytes());
        // The same in the central directory, made by Unix, then no extra field, no comment,
        // disk 0, attributes 0 and the local header's offset.
        central.extend_from_slice(b"PK\x01\x02");
        central.extend_from_slice(&0x0314u16.to_le_bytes());
        central.extend_from_slice(&20u16.to_le_bytes());
        central.extend_from_slice(&[0u8; 20]);
        central.extend_from_slice(&n.to_le_bytes());
        central.extend_from_slice(&[0u8; 12]);
        central.extend_from_slice(&offset.to_le_bytes());
        central.extend_from_slice(name.as_bytes());
    }
    let (start, len) = (out.len() as u32, central.len() as u32);
    out.extend_from_slice(&central);
    let count = (names.len() as u16).to_le_bytes();
    out.extend_from_slice(b"PK\x05\x06\0\0\0\0");
    out.extend_from_slice(&count);
    out.extend_from_slice(&count);
    out.extend_from_slice(&len.to_le_bytes());
    out.extend_from_slice(&start.to_le_bytes());
    out.extend_from_slice(&0u16.to_le_bytes());
    out
}

/// Archives whose member paths clash once normalised (a name twice, `./a` and `a`, `x//y` and
/// `x/y`, a file that another member needs as a folder) are refused with a 422 naming the
/// member, tar and zip alike, and leave nothing in the data directory.
#[tokio::test]
async fn archives_whose_paths_clash_are_refused_naming_the_member() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), None);
    let s: &[u8] = br#"{"objects": []}"#;
    let mut cases: Vec<(&str, Vec<u8>, &str)> = vec![
        (
            "tar",
            raw_tar(&[("scene.json", s), ("scene.json", s)]),
            "scene.json",
        ),
        (
            "tar",
            raw_tar(&[("scene.json", s), ("./scene.json", s)]),
            "./scene.json",
        ),
        (
            "tar",
            raw_tar(&[("scene.json", s), ("x//y", s), ("x/y", s)]),
            "x/y",
        ),
        (
            "tar",
            raw_tar(&[("scene.json", s), ("a", s), ("a/b", s)]),
            "a/b",
        ),
        (
            "tar",
            raw_tar(&[("scene.json", s), ("a/", s), ("a", s)]),
            "a",
        ),
    ];
    for (names, culprit) in [
        (&["scene.json", "scene.json"][..], "scene.json"),
        (&["scene.json", "./scene.json"][..], "./scene.json"),
        (&["scene.json", "a", "a/b"][..], "a/b"),
    ] {
        cases.push(("zip", raw_zip(names), culprit));
    }
    for (format, blob, culprit) in cases {
        let (code, body) = call(&st, post(&format!("/v1/scenes?format={format}"), blob)).await;
        assert_eq!(
            code,
            StatusCode::UNPROCESSABLE_ENTITY,
            "{format} {culprit}: {body}"
        );
        assert_error_body(culprit, &body);
        let message = body["error"]["message"].as_str().unwrap();
        assert!(
            message.contains(&format!("refusing archive member '{culprit}'")),
            "{format} {culprit}: {body}"
        );
        for d in ["scenes", "tmp"] {
            let left: Vec<_> = std::fs::read_dir(dir.path().join(d)).unwrap().collect();
            assert!(left.is_empty(), "{format} {culprit}: {d}/ holds {left:?}");
        }
    }
    // The same members without the clash are a scene.
    let ok = raw_tar(&[("scene.json", s), ("a/", s), ("a//b", s)]);
    let (code, body) = call(&st, post("/v1/scenes?format=tar", ok)).await;
    assert_eq!(code, StatusCode::CREATED, "{body}");
}

/// The same new bytes uploaded many times at once are checked once and stored once: exactly
/// one upload is answered 201, the others 200 `existed: true`, as they are afterwards.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn identical_uploads_at_once_are_checked_and_created_once() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = Config::new(dir.path());
    let parses = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let counted = parses.clone();
    c.scene_loader = Arc::new(move |_p: &std::path::Path| {
        counted.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        std::thread::sleep(std::time::Duration::from_millis(200));
        Ok(LoadedScene::default())
    });
    c.scene_limits.max_parallel_parses = 8;
    let st = AppState::open(c).unwrap();
    let uploads: Vec<_> = (0..8)
        .map(|_| {
            let st = st.clone();
            tokio::spawn(async move { call(&st, post("/v1/scenes", r#"{"objects": []}"#)).await })
        })
        .collect();
    let mut created = 0;
    for u in uploads {
        let (code, body) = u.await.unwrap();
        match code {
            StatusCode::CREATED => {
                created += 1;
                assert_eq!(body["existed"], false, "{body}");
            }
            StatusCode::OK => assert_eq!(body["existed"], true, "{body}"),
            _ => panic!("{code}: {body}"),
        }
    }
    assert_eq!(created, 1);
    assert_eq!(parses.load(std::sync::atomic::Ordering::SeqCst), 1);
    let (code, body) = call(&st, post("/v1/scenes", r#"{"objects": []}"#)).await;
    assert_eq!((code, &body["existed"]), (StatusCode::OK, &true.into()));
}

/// The answer to an upload does not depend on whether its bytes are stored already: a format
/// the request gives (`?format=`, a Content-Type naming one) that is not the bytes' is refused
/// either way, naming `format`; the right one, or none, is fine.
#[tokio::test]
async fn a_format_hint_is_checked_against_stored_bytes_too() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), None);
    let scene = r#"{"objects": []}"#;
    let (code, e) = call(&st, post("/v1/scenes?format=tar", scene)).await;
    assert_eq!(code, StatusCode::UNPROCESSABLE_ENTITY, "new bytes: {e}");
    let (code, stored) = call(&st, post("/v1/scenes", scene)).await;
    assert_eq!(code, StatusCode::CREATED, "{stored}");
    let id = stored["id"].as_str().unwrap();
    let (code, e) = call(&st, post("/v1/scenes?format=tar", scene)).await;
    assert_eq!(code, StatusCode::UNPROCESSABLE_ENTITY, "stored bytes: {e}");
    assert_error_body("format hint", &e);
    assert_eq!(e["error"]["field"], "format");
    assert_eq!(
        e["error"]["message"],
        format!("format: these bytes are stored as a json scene ({id}), not tar as ?format= says")
    );
    let as_zip = Request::post("/v1/scenes")
        .header("content-type", "application/zip")
        .body(Body::from(scene))
        .unwrap();
    let (code, e) = call(&st, as_zip).await;
    assert_eq!(code, StatusCode::UNPROCESSABLE_ENTITY, "{e}");
    assert!(
        e["error"]["message"]
            .as_str()
            .unwrap()
            .ends_with("not zip as the Content-Type says"),
        "{e}"
    );
    let (code, e) = call(&st, post("/v1/scenes?format=json", scene)).await;
    assert_eq!((code, &e["existed"]), (StatusCode::OK, &true.into()), "{e}");
}

/// `?entry=` naming a path no archive member may have is refused as the entry's fault, as an
/// entry the archive lacks is.
#[tokio::test]
async fn a_bad_entry_is_refused_naming_entry() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), None);
    let s: &[u8] = br#"{"objects": []}"#;
    for (entry, says) in [
        ("../a.json", "entry '../a.json' refused: contains '..'"),
        ("/a.json", "entry '/a.json' refused: absolute path"),
        ("b.json", "entry 'b.json' is not in the archive"),
    ] {
        let blob = raw_tar(&[("a.json", s)]);
        let uri = format!("/v1/scenes?format=tar&entry={}", entry.replace('/', "%2F"));
        let (code, e) = call(&st, post(&uri, blob)).await;
        assert_eq!(code, StatusCode::UNPROCESSABLE_ENTITY, "{entry}: {e}");
        assert_error_body(entry, &e);
        assert_eq!(
            (&e["error"]["field"], &e["error"]["message"]),
            (&"entry".into(), &says.into()),
            "{entry}"
        );
    }
}

/// A result whose sums hold a NaN or an infinity is refused with a 422 naming the pixel: the
/// task counts a failure of the worker holding its lease and is queued again at once, so
/// another result (a good one) completes it and no frame shows a corrupted tile.
#[tokio::test]
async fn results_with_non_finite_sums_are_refused_and_the_task_is_queued_again() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), None);
    let (job, worker) =
        job_and_worker(&st, r#""width": 4, "height": 2, "spp": 1, "tile_size": 16"#).await;
    let lease_uri = format!("/v1/workers/{worker}/lease");
    let upload = |task: u64, worker: &str, lease: &str, pixels: Vec<[f32; 4]>| {
        Request::put(format!(
            "/v1/jobs/{job}/tasks/{task}/result?worker={worker}&lease={lease}"
        ))
        .body(Body::from(result_4x2(pixels, 0)))
        .unwrap()
    };
    let good = vec![[0.5, 0.25, 0.125, 1.0]; 8];
    let mut task = 0;
    for (k, bad) in [(0, f32::NAN), (3, f32::INFINITY)] {
        let (code, lease) = call(&st, post(&lease_uri, "")).await;
        assert_eq!(code, StatusCode::OK, "{lease}");
        task = lease["task"].as_u64().unwrap();
        let lease_id = lease["lease_id"].as_str().unwrap();
        let mut pixels = good.clone();
        pixels[6][k] = bad;
        // Naming the holder without its lease (anyone can write a worker's id), or a lease
        // that is not the task's: refused, the lease stays, nobody is blamed.
        for (who, lease) in [
            (worker.as_str(), ""),
            (worker.as_str(), "l-forged"),
            ("someone-else", "l-forged"),
        ] {
            let (code, body) = call(&st, upload(task, who, lease, pixels.clone())).await;
            assert_eq!(code, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
            let (_, status) = call(&st, get(&format!("/v1/jobs/{job}"))).await;
            assert_eq!(status["tasks_leased"], 1, "{who} {lease}: {status}");
        }
        // From the lease holder: refused naming the pixel, the task queued again.
        let (code, body) = call(&st, upload(task, &worker, lease_id, pixels)).await;
        assert_eq!(code, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
        assert_error_body("non-finite result", &body);
        assert_eq!(body["error"]["field"], "body");
        let message = body["error"]["message"].as_str().unwrap();
        assert!(message.contains("pixel (2, 1)"), "{message}");
        let (_, status) = call(&st, get(&format!("/v1/jobs/{job}"))).await;
        assert_eq!(
            (&status["tasks_leased"], &status["tasks_done"]),
            (&0.into(), &0.into()),
            "{status}"
        );
        assert!(
            status["failures"]
                .as_array()
                .unwrap()
                .iter()
                .any(|f| f["error"].as_str().unwrap().contains("result refused")),
            "{status}"
        );
    }
    // Two failures of the one task (below the limit of three): a good result completes it.
    let (code, lease) = call(&st, post(&lease_uri, "")).await;
    assert_eq!(code, StatusCode::OK, "{lease}");
    let lease_id = lease["lease_id"].as_str().unwrap();
    let (code, body) = call(&st, upload(task, &worker, lease_id, good.clone())).await;
    assert_eq!(
        (code, &body["accepted"]),
        (StatusCode::OK, &true.into()),
        "{body}"
    );
    let (_, status) = call(&st, get(&format!("/v1/jobs/{job}"))).await;
    assert_eq!(status["state"], "done", "{status}");
}

/// A result must name a lease the coordinator gave for its task and the worker it gave it to:
/// a token holder cannot fill a task nobody leased, nor one leased to another worker, nor pass
/// a lease of another task, nor credit the tile to another worker; the holder of a lease that
/// expired still can (results are deterministic).
#[tokio::test]
async fn results_are_taken_only_under_a_lease_of_their_task() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), None);
    let (job, worker) = job_and_worker(
        &st,
        r#""width": 4, "height": 2, "spp": 2, "passes": 2, "tile_size": 16"#,
    )
    .await;
    let upload_as = |task: u64, lease: &str, worker: &str| {
        Request::put(format!(
            "/v1/jobs/{job}/tasks/{task}/result?worker={worker}&lease={lease}"
        ))
        .body(Body::from(result_4x2(vec![[0.5, 0.5, 0.5, 1.0]; 8], 0)))
        .unwrap()
    };
    let (code, lease) = call(&st, post(&format!("/v1/workers/{worker}/lease"), "")).await;
    assert_eq!(code, StatusCode::OK, "{lease}");
    let (task, lease_id) = (
        lease["task"].as_u64().unwrap(),
        lease["lease_id"].as_str().unwrap().to_string(),
    );
    let other = 1 - task;
    // The other task (never leased): no lease, the lease of this task, a made-up one.
    let last = if lease_id.ends_with('0') { "1" } else { "0" };
    let forged = format!("{}{last}", &lease_id[..lease_id.len() - 1]);
    let upload = |task: u64, lease: &str| upload_as(task, lease, &worker);
    // And the right lease, under another worker's name or none.
    for (t, l, w) in [
        (other, "", worker.as_str()),
        (other, lease_id.as_str(), worker.as_str()),
        (task, forged.as_str(), worker.as_str()),
        (task, lease_id.as_str(), "w-spoofed"),
        (task, lease_id.as_str(), ""),
    ] {
        let (code, body) = call(&st, upload_as(t, l, w)).await;
        assert_eq!(
            code,
            StatusCode::UNPROCESSABLE_ENTITY,
            "{t} {l} {w}: {body}"
        );
        assert_eq!(body["error"]["field"], "lease", "{body}");
        let (_, status) = call(&st, get(&format!("/v1/jobs/{job}"))).await;
        assert_eq!(status["tasks_done"], 0, "{status}");
    }
    // Lease ids cannot be guessed from the ids a worker sees.
    assert!(lease_id.len() > 32, "{lease_id}");
    // Released, the lease still names its task: a late result under it is taken.
    let (code, _) = call(&st, post(&format!("/v1/leases/{lease_id}/release"), "")).await;
    assert!(code.is_success(), "{code}");
    let (code, body) = call(&st, upload(task, &lease_id)).await;
    assert_eq!(
        (code, &body["accepted"]),
        (StatusCode::OK, &true.into()),
        "{body}"
    );
    // The tile counts for the worker that was given the lease.
    let (_, status) = call(&st, get(&format!("/v1/jobs/{job}"))).await;
    assert_eq!(status["tasks_done"], 1, "{status}");
    let shares = status["workers"].to_string();
    assert!(
        shares.contains(&worker) && !shares.contains("w-spoofed"),
        "{status}"
    );
}

/// A result's count of samples dropped as NaN or infinite counts into the frame's samples per
/// pixel (a `bdpt` frame's splats are divided by it): a count above the tile's pixels times the
/// pass's samples is refused like a bad pixel sum, counting a failure of the lease holder, so a
/// result cannot wipe the splat light out of the frame, nor two of them wrap the frame's count.
#[tokio::test]
async fn results_claiming_more_dropped_samples_than_the_pass_has_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), None);
    let (job, worker) = job_and_worker(
        &st,
        r#""width": 4, "height": 2, "spp": 3, "passes": 1, "tile_size": 16"#,
    )
    .await;
    let lease_uri = format!("/v1/workers/{worker}/lease");
    let upload = |bad_samples: u64, lease: &str| {
        Request::put(format!(
            "/v1/jobs/{job}/tasks/0/result?worker={worker}&lease={lease}"
        ))
        .body(Body::from(result_4x2(vec![[0.0; 4]; 8], bad_samples)))
        .unwrap()
    };
    for bad in [1 << 60, u64::MAX] {
        let (code, lease) = call(&st, post(&lease_uri, "")).await;
        assert_eq!(code, StatusCode::OK, "{lease}");
        let (code, body) = call(&st, upload(bad, lease["lease_id"].as_str().unwrap())).await;
        assert_eq!(code, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
        assert_error_body("too many dropped samples", &body);
        assert_eq!(body["error"]["field"], "body");
        let message = body["error"]["message"].as_str().unwrap();
        assert!(
            message.contains(&format!("{bad} samples dropped"))
                && message.contains("3 samples for each of the tile's 8 pixels, 24 in all"),
            "{message}"
        );
        let (_, status) = call(&st, get(&format!("/v1/jobs/{job}"))).await;
        assert_eq!(
            (&status["tasks_leased"], &status["tasks_done"]),
            (&0.into(), &0.into()),
            "the refusal counts a failure and queues the task again: {status}"
        );
    }
    // Every sample of the pass dropped is a result the pass can make.
    let (code, lease) = call(&st, post(&lease_uri, "")).await;
    assert_eq!(code, StatusCode::OK);
    let (code, body) = call(&st, upload(24, lease["lease_id"].as_str().unwrap())).await;
    assert_eq!(
        (code, &body["accepted"]),
        (StatusCode::OK, &true.into()),
        "{body}"
    );
}

/// A new worker leases the one task of `job` (a 4×2 frame in one tile) and uploads `pixels` as
/// its result: the upload's answer.
async fn lease_and_upload_4x2(
    st: &AppState,
    job: &str,
    pixels: Vec<[f32; 4]>,
) -> (StatusCode, serde_json::Value) {
    lease_and_upload_4x2_dropping(st, job, pixels, 0).await
}

/// The same, with `bad_samples` samples dropped as NaN or infinite.
async fn lease_and_upload_4x2_dropping(
    st: &AppState,
    job: &str,
    pixels: Vec<[f32; 4]>,
    bad_samples: u64,
) -> (StatusCode, serde_json::Value) {
    let (_, w) = register_worker(st).await;
    let worker = w["worker_id"].as_str().unwrap();
    let (_, lease) = call(st, post(&format!("/v1/workers/{worker}/lease"), "")).await;
    let upload = Request::put(format!(
        "/v1/jobs/{job}/tasks/{}/result?worker={worker}&lease={}",
        lease["task"],
        lease["lease_id"].as_str().unwrap()
    ))
    .body(Body::from(result_4x2(pixels, bad_samples)))
    .unwrap();
    call(st, upload).await
}

/// The bytes of a pass-0 result for the 4 × 2 tile at the origin.
fn result_4x2(pixels: Vec<[f32; 4]>, bad_samples: u64) -> Vec<u8> {
    let acc = raytile_proto::tile::TileAccum {
        tile: raytile_proto::Tile {
            x0: 0,
            y0: 0,
            x1: 4,
            y1: 2,
        },
        pixels,
        bad_samples,
        splats: Vec::new(),
        coverage: Vec::new(),
    };
    raytile_proto::tile::encode(&acc, 0)
}

/// A result's sums must be ones a pass of its samples can make: finite, weights from 0 to the
/// pass's samples, colour sums at most the weight times the film's largest sample value.
#[test]
fn result_sums_are_held_to_what_a_pass_can_make() {
    use raytile_proto::tile::TileAccum;
    let acc = |p: [f32; 4]| TileAccum {
        tile: raytile_proto::Tile {
            x0: 8,
            y0: 4,
            x1: 10,
            y1: 5,
        },
        pixels: vec![[0.5, 0.25, -0.125, 4.0], p],
        bad_samples: 0,
        splats: Vec::new(),
        coverage: Vec::new(),
    };
    let max = raytile_core::film::MAX_SAMPLE;
    // Fine: fewer samples kept than the pass has, negative sums (the normals integrator's),
    // the largest sample values.
    for p in [[0.0; 4], [1.0, -2.0, 3.0, 3.0], [max, -max, max * 2.0, 2.0]] {
        crate::api::check_sums(&acc(p), 4, false).unwrap();
    }
    let refused = [
        ([f32::NAN, 0.0, 0.0, 1.0], "red sum of NaN"),
        ([0.0, 0.0, 0.0, f32::INFINITY], "weight of inf"),
        ([0.0, 0.0, 0.0, 5.0], "weight of 5: the pass has 4 samples"),
        ([0.0, 0.0, 0.0, -1.0], "weight of -1"),
        (
            [100.0, 0.0, 0.0, 0.25],
            "weight of 0.25: a weight counts samples",
        ),
        ([0.0, max * 3.0, 0.0, 2.0], "colour sum"),
        ([1.0, 0.0, 0.0, 0.0], "colour sum of 1 over 0 samples"),
    ];
    for (p, want) in refused {
        let e = crate::api::check_sums(&acc(p), 4, false).unwrap_err();
        assert!(e.contains("pixel (9, 4)") && e.contains(want), "{p:?}: {e}");
    }
    // Coverage: one whole number from 0 to the weight per pixel for a job with an alpha
    // channel, none for any other.
    let p = [1.0, 1.0, 1.0, 3.0];
    let covered = |c: Vec<f32>| TileAccum {
        coverage: c,
        ..acc(p)
    };
    crate::api::check_sums(&covered(vec![4.0, 3.0]), 4, true).unwrap();
    crate::api::check_sums(&covered(vec![0.0, 0.0]), 4, true).unwrap();
    let refused = [
        (
            vec![],
            true,
            "need a coverage for each of the tile's 2 pixels, got 0",
        ),
        (vec![1.0], true, "got 1"),
        (vec![1.0, 1.0], false, "the job has no alpha channel"),
        (vec![1.0, 4.0], true, "pixel (9, 4) has a coverage of 4"),
        (vec![1.0, 0.5], true, "coverage of 0.5"),
        (vec![1.0, -1.0], true, "coverage of -1"),
        (vec![1.0, f32::NAN], true, "coverage of NaN"),
    ];
    for (c, alpha, want) in refused {
        let e = crate::api::check_sums(&covered(c.clone()), 4, alpha).unwrap_err();
        assert!(e.contains(want), "{c:?}: {e}");
    }
}

/// A job `sppm` cannot render (an unbounded plane under the sun, or under an environment the
/// job brings) is refused when it is submitted, naming `integrator`, as a worker would refuse
/// it; the same scene renders with `path`, and a plane under a lamp with `sppm`.
#[tokio::test]
async fn sppm_jobs_workers_would_refuse_are_refused_at_submission() {
    let dir = tempfile::tempdir().unwrap();
    let st = AppState::open(Config::new(dir.path())).unwrap();
    let scene = |light: &str| {
        format!(
            r#"{{"materials": {{"d": {{"type": "diffuse"}}}},
  "objects": [{{"shape": {{"type": "plane"}}, "material": "d"}}],
  "lights": [{{"type": "{light}", "direction": [0, -1, 0], "position": [0, 1, 0],
              "irradiance": [1, 1, 1], "intensity": [1, 1, 1]}}]}}"#
        )
    };
    let upload = |text: String| {
        let st = st.clone();
        async move {
            let (code, body) = call(&st, post("/v1/scenes", text)).await;
            assert!(code.is_success(), "{body}");
            body["id"].as_str().unwrap().to_string()
        }
    };
    // Fields the other light ignores are refused: keep each light's own.
    let sun = upload(
        scene("directional")
            .replace(r#""position": [0, 1, 0],"#, "")
            .replace(r#", "intensity": [1, 1, 1]"#, ""),
    )
    .await;
    let lamp = upload(
        scene("point")
            .replace(r#""direction": [0, -1, 0], "#, "")
            .replace(r#""irradiance": [1, 1, 1], "#, ""),
    )
    .await;
    let job = |scene: &str, extra: &str| {
        let st = st.clone();
        let body = format!(r#"{{"scene": "{scene}", "width": 8, "height": 8{extra}}}"#);
        async move { call(&st, post("/v1/jobs", body)).await }
    };
    for (scene, extra) in [
        (&sun, r#", "integrator": "sppm""#),
        (&lamp, r#", "integrator": "sppm", "environment": "1,1,1""#),
    ] {
        let (code, body) = job(scene, extra).await;
        assert_eq!(code, StatusCode::UNPROCESSABLE_ENTITY, "{extra}: {body}");
        assert_eq!(body["error"]["field"], "integrator", "{body}");
        let message = body["error"]["message"].as_str().unwrap();
        assert!(
            message.contains("sppm cannot render an unbounded plane"),
            "{message}"
        );
    }
    for (scene, extra) in [
        (&sun, r#", "integrator": "path""#),
        (&lamp, r#", "integrator": "sppm""#),
    ] {
        let (code, body) = job(scene, extra).await;
        assert_eq!(code, StatusCode::CREATED, "{extra}: {body}");
    }
}

/// A job's camera is checked against the scene's cameras: a name, or an index given as a JSON
/// integer or a string of digits; one the scene does not have is a 422 naming `camera` with
/// the cameras it has.
#[tokio::test]
async fn a_jobs_camera_must_be_one_of_the_scenes() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = Config::new(dir.path());
    c.scene_loader = Arc::new(|p: &std::path::Path| {
        let text = std::fs::read_to_string(p).unwrap();
        let cameras = if text.contains("no cameras") {
            vec![]
        } else {
            vec!["front".to_string(), "side".to_string()]
        };
        Ok(LoadedScene {
            cameras: Some(cameras),
            ..LoadedScene::default()
        })
    });
    let st = AppState::open(c).unwrap();
    let (_, scene) = call(&st, post("/v1/scenes", r#"{"objects": []}"#)).await;
    let id = scene["id"].as_str().unwrap().to_string();
    let (_, bare) = call(
        &st,
        post("/v1/scenes", r#"{"objects": [], "x": "no cameras"}"#),
    )
    .await;
    let bare = bare["id"].as_str().unwrap().to_string();
    let job = |scene: &str, camera: &str| {
        let st = st.clone();
        let camera = if camera.is_empty() {
            String::new()
        } else {
            format!(r#", "camera": {camera}"#)
        };
        let body = format!(r#"{{"scene": "{scene}", "width": 16, "height": 16{camera}}}"#);
        async move { call(&st, post("/v1/jobs", body)).await }
    };
    for (scene, camera, want) in [
        (&id, r#""side""#, Some("side")),
        (&id, "1", Some("1")),
        (&id, r#""1""#, Some("1")),
        (&id, "0", Some("0")),
        (&id, "", None),
        (&bare, "", None),
    ] {
        let (code, body) = job(scene, camera).await;
        assert_eq!(code, StatusCode::CREATED, "{camera}: {body}");
        assert_eq!(
            body["settings"]["camera"].as_str(),
            want,
            "{camera}: {body}"
        );
    }
    for (scene, camera, says) in [
        (
            &id,
            r#""zzz""#,
            "no camera named or numbered 'zzz' (its cameras: 0: 'front', 1: 'side')",
        ),
        (&id, "2", "no camera named or numbered '2'"),
        (&id, "-1", "camera name (string) or index"),
        (&id, "1.5", "camera name (string) or index"),
        (&bare, "0", "the scene has no camera"),
    ] {
        let (code, body) = job(scene, camera).await;
        assert_eq!(code, StatusCode::UNPROCESSABLE_ENTITY, "{camera}: {body}");
        assert_error_body(camera, &body);
        assert_eq!(body["error"]["field"], "camera", "{camera}: {body}");
        let message = body["error"]["message"].as_str().unwrap();
        assert!(
            message.starts_with("camera: ") && message.contains(says),
            "{camera}: {message}"
        );
    }
}

/// A PNG may be asked for with an exposure and a tone map, as `raytile render` makes it: its
/// own entity tag; the wrong values, or asking them of a linear image, are 422s naming them.
#[tokio::test]
async fn a_png_takes_an_exposure_and_a_tone_map() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), None);
    let (_, job) = empty_scene_job(&st, r#""width": 16, "height": 16, "spp": 1"#).await;
    let base = format!("/v1/jobs/{}/image", job["id"].as_str().unwrap());
    let tag = |q: &str| {
        let st = st.clone();
        let uri = format!("{base}?{q}");
        async move {
            let resp = app(st).oneshot(get(&uri)).await.unwrap();
            assert_eq!(resp.status(), StatusCode::OK, "{uri}");
            resp.headers()["etag"].to_str().unwrap().to_string()
        }
    };
    let plain = tag("format=png").await;
    let bright = tag("format=png&exposure=1.5&tonemap=aces").await;
    assert_ne!(plain, bright);
    assert_eq!(bright, tag("format=png&exposure=1.50&tonemap=aces").await);
    assert_eq!(
        plain,
        tag("format=png&exposure=0&tonemap=clamp").await,
        "the defaults"
    );
    assert_eq!(
        tag("format=png&exposure=-0&tonemap=aces").await,
        tag("format=png&exposure=0&tonemap=aces").await,
        "-0 is 0"
    );
    for (q, field) in [
        ("format=exr&exposure=1", "exposure"),
        ("format=hdr&tonemap=aces", "tonemap"),
        ("format=png&exposure=100", "exposure"),
        ("format=png&tonemap=sepia", "tonemap"),
    ] {
        let (code, body) = call(&st, get(&format!("{base}?{q}"))).await;
        assert_eq!(code, StatusCode::UNPROCESSABLE_ENTITY, "{q}: {body}");
        assert_eq!(body["error"]["field"], field, "{q}: {body}");
    }
}

/// Job images are made a few at a time (each holds its frame while it is encoded): a request
/// that finds every slot taken waits, and after the configured wait is answered a retryable
/// 503 with Retry-After; once a slot is free, the image is served.
#[tokio::test]
async fn image_requests_wait_for_a_slot_and_are_answered_busy_after_the_wait() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = fake_config(dir.path());
    c.max_parallel_images = 1;
    c.image_wait = std::time::Duration::from_millis(200);
    let st = AppState::open(c).unwrap();
    let (_, job) = empty_scene_job(&st, r#""width": 16, "height": 16, "spp": 1"#).await;
    let uri = format!("/v1/jobs/{}/image?format=exr", job["id"].as_str().unwrap());
    // Every slot taken (as by an image being made).
    let held = st.image_slots.clone().acquire_owned().await.unwrap();
    let resp = app(st.clone()).oneshot(get(&uri)).await.unwrap();
    assert_eq!(resp.status(), StatusCode::SERVICE_UNAVAILABLE);
    assert_eq!(resp.headers()["retry-after"], "2");
    let body = axum::body::to_bytes(resp.into_body(), usize::MAX)
        .await
        .unwrap();
    let body: serde_json::Value = serde_json::from_slice(&body).unwrap();
    assert_error_body("busy image", &body);
    assert_eq!(
        (&body["error"]["code"], &body["error"]["retryable"]),
        (&"busy".into(), &true.into()),
        "{body}"
    );
    // A request waiting when the slot frees gets its image.
    let waiting = tokio::spawn(app(st.clone()).oneshot(get(&uri)));
    tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    drop(held);
    let resp = waiting.await.unwrap().unwrap();
    assert_eq!(resp.status(), StatusCode::OK);
    assert_eq!(resp.headers()["content-type"], "image/x-exr");
    // Unknown jobs are answered at once, without a slot.
    let _held = st.image_slots.clone().acquire_owned().await.unwrap();
    assert_eq!(
        call(&st, get("/v1/jobs/nope/image")).await.0,
        StatusCode::NOT_FOUND
    );
    // HEAD makes no image, so it needs no slot: its headers come at once, without a body.
    let head = |uri: &str| Request::head(uri).body(Body::empty()).unwrap();
    let resp = app(st.clone()).oneshot(head(&uri)).await.unwrap();
    assert_eq!(resp.status(), StatusCode::OK);
    assert_eq!(resp.headers()["content-type"], "image/x-exr");
    let body = axum::body::to_bytes(resp.into_body(), usize::MAX).await;
    assert!(body.unwrap().is_empty());
    let resp = app(st.clone()).oneshot(head("/v1/jobs/nope/image")).await;
    assert_eq!(resp.unwrap().status(), StatusCode::NOT_FOUND);
    let resp = app(st.clone()).oneshot(head(&format!("{uri}x"))).await;
    assert_eq!(resp.unwrap().status(), StatusCode::UNPROCESSABLE_ENTITY);
}

#[tokio::test]
async fn a_data_directory_serves_one_coordinator_at_a_time() {
    let dir = tempfile::tempdir().unwrap();
    let first = test_state(dir.path(), None);
    let e = AppState::open(Config::new(dir.path()))
        .err()
        .expect("a second coordinator on the same data directory");
    let e = format!("{e:#}");
    assert!(
        e.contains("in use by another coordinator") && e.contains("--data-dir"),
        "{e}"
    );
    // The folder itself is locked: removing a "stale" lock file lets no second one in.
    std::fs::remove_file(dir.path().join("lock")).unwrap();
    let e = AppState::open(Config::new(dir.path()))
        .err()
        .expect("a second coordinator once the lock file was removed");
    assert!(format!("{e:#}").contains("in use by another coordinator"));
    // Once the first has stopped, the directory is free again (a restart).
    drop(first);
    assert!(AppState::open(Config::new(dir.path())).is_ok());
}

#[tokio::test]
async fn a_worker_needs_a_name() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), None);
    let reg = |name: &str| {
        format!(
            r#"{{"name": "{name}", "threads": 1, "render_version": {}}}"#,
            raytile_core::RENDER_VERSION
        )
    };
    for bad in ["", &"x".repeat(257)] {
        let (code, e) = call(&st, post("/v1/workers", reg(bad))).await;
        assert_eq!(code, StatusCode::UNPROCESSABLE_ENTITY, "{e}");
        assert_eq!(e["error"]["field"], "name", "{e}");
    }
    assert_eq!(register_worker(&st).await.0, StatusCode::OK);
}

/// A body without a member it needs, or with one given twice, names that member, as a wrong
/// value of it would.
#[tokio::test]
async fn a_missing_or_repeated_member_of_a_body_is_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let st = AppState::open(Config::new(dir.path())).unwrap();
    for (uri, body, field) in [
        ("/v1/jobs", "{}", "scene"),
        ("/v1/workers", "{}", "name"),
        // A member given twice is refused, not read as its last value.
        ("/v1/jobs", r#"{"scene": "s", "spp": 4, "spp": 8}"#, "spp"),
        (
            "/v1/workers",
            r#"{"name": "a", "name": "b", "threads": 1}"#,
            "name",
        ),
    ] {
        let (code, e) = call(&st, post(uri, body)).await;
        assert_eq!(code, StatusCode::UNPROCESSABLE_ENTITY, "{uri}: {e}");
        assert_error_body(uri, &e);
        assert_eq!(e["error"]["field"], field, "{uri}: {e}");
    }
}

/// What a killed coordinator left in tmp/ (a partial upload, an unpacking folder) is removed
/// when the next one opens the data directory.
#[test]
fn a_restart_clears_unfinished_uploads() {
    let dir = tempfile::tempdir().unwrap();
    drop(AppState::open(Config::new(dir.path())).unwrap());
    let tmp = dir.path().join("tmp");
    std::fs::write(tmp.join(".tmpA1b2C3"), vec![7u8; 4096]).unwrap();
    std::fs::create_dir_all(tmp.join("stage-x/root/textures")).unwrap();
    std::fs::write(tmp.join("stage-x/root/textures/a.png"), b"png").unwrap();
    let _st = AppState::open(Config::new(dir.path())).unwrap();
    let left: Vec<_> = std::fs::read_dir(&tmp).unwrap().collect();
    assert!(left.is_empty(), "tmp/ holds {left:?}");
}

/// A result for a task already done is answered `duplicate` without being decoded or checked:
/// its body is read to the end and dropped.
#[tokio::test]
async fn a_result_for_a_settled_task_is_dropped_unread() {
    let dir = tempfile::tempdir().unwrap();
    let st = test_state(dir.path(), None);
    let (job, worker) =
        job_and_worker(&st, r#""width": 4, "height": 2, "spp": 1, "tile_size": 16"#).await;
    let (code, lease) = call(&st, post(&format!("/v1/workers/{worker}/lease"), "")).await;
    assert_eq!(code, StatusCode::OK, "{lease}");
    let lease = lease["lease_id"].as_str().unwrap().to_string();
    let put = |body: Vec<u8>| {
        Request::put(format!(
            "/v1/jobs/{job}/tasks/0/result?worker={worker}&lease={lease}"
        ))
        .body(Body::from(body))
        .unwrap()
    };
    let (code, body) = call(&st, put(result_4x2(vec![[0.5, 0.5, 0.5, 1.0]; 8], 0))).await;
    assert_eq!(
        (code, &body["accepted"]),
        (StatusCode::OK, &true.into()),
        "{body}"
    );
    // Not a tile result at all, for the task now done: a duplicate, not a 422.
    let (code, body) = call(&st, put(b"not a tile".to_vec())).await;
    assert_eq!(
        (code, &body["duplicate"], &body["accepted"]),
        (StatusCode::OK, &true.into(), &false.into()),
        "{body}"
    );
}

/// Results at or over `Config::result_file_bytes` are files under `results/`, written before
/// the scheduler's lock is taken: the frame is the same as from results in the database, after
/// a restart too; files no row names are removed at start; a purge removes the job's files.
#[tokio::test]
async fn results_stored_as_files_make_the_same_frame_and_go_with_their_job() {
    async fn render(dir: &std::path::Path, file_bytes: usize) -> (String, Vec<u8>) {
        let mut c = fake_config(dir);
        c.result_file_bytes = file_bytes;
        let st = AppState::open(c).unwrap();
        let (code, job) =
            empty_scene_job(&st, r#""width": 4, "height": 2, "spp": 1, "tile_size": 16"#).await;
        assert_eq!(code, StatusCode::CREATED, "{job}");
        let job = job["id"].as_str().unwrap().to_string();
        let pixels = (0..8).map(|i| [i as f32 / 8.0, 0.5, 0.25, 1.0]).collect();
        let (code, body) = lease_and_upload_4x2(&st, &job, pixels).await;
        assert_eq!((code, &body["accepted"]), (StatusCode::OK, &true.into()));
        (job.clone(), image(&st, &job).await)
    }
    async fn image(st: &AppState, job: &str) -> Vec<u8> {
        let uri = format!("/v1/jobs/{job}/image?format=exr");
        let resp = app(st.clone()).oneshot(get(&uri)).await.unwrap();
        assert_eq!(resp.status(), StatusCode::OK);
        axum::body::to_bytes(resp.into_body(), usize::MAX)
            .await
            .unwrap()
            .to_vec()
    }
    let files = |d: &std::path::Path| -> Vec<String> {
        let mut v: Vec<String> = walk(d)
            .into_iter()
            .map(|p| p.strip_prefix(d).unwrap().display().to_string())
            .collect();
        v.sort();
        v
    };
    let in_db = tempfile::tempdir().unwrap();
    let (_, want) = render(in_db.path(), usize::MAX).await;
    assert!(files(&in_db.path().join("results")).is_empty());

    let dir = tempfile::tempdir().unwrap();
    let (job, got) = render(dir.path(), 0).await;
    assert_eq!(got, want, "the same frame from a result file");
    let results = dir.path().join("results");
    let stored = files(&results);
    assert_eq!(stored.len(), 1, "{stored:?}");
    assert!(stored[0].starts_with(&format!("{job}/0-")), "{stored:?}");
    assert!(
        files(&results.join(".staging")).is_empty(),
        "the staged file moved"
    );

    // Restarted, with files no row names: those of its jobs go, those of a job it does not
    // know are set aside, the frame stays.
    std::fs::write(results.join(&job).join("0-stray"), b"x").unwrap();
    std::fs::create_dir(results.join("j-gone")).unwrap();
    std::fs::write(results.join("j-gone").join("3-1"), b"x").unwrap();
    let st = AppState::open(fake_config(dir.path())).unwrap();
    let mut want_files = vec![".orphaned/j-gone/3-1".to_string()];
    want_files.extend(stored.iter().cloned());
    assert_eq!(files(&results), want_files);
    assert_eq!(image(&st, &job).await, want, "after a restart");
    std::fs::remove_dir_all(results.join(".orphaned")).unwrap();

    let purge = Request::delete(format!("/v1/jobs/{job}?purge=true"))
        .body(Body::empty())
        .unwrap();
    assert_eq!(call(&st, purge).await.0, StatusCode::OK);
    assert!(!results.join(&job).exists(), "purged with its job");
    // Set aside at once, removed by a thread of its own.
    let t = std::time::Instant::now();
    while !files(&results).is_empty() && t.elapsed() < std::time::Duration::from_secs(10) {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    assert!(files(&results).is_empty(), "{:?}", files(&results));
}

/// A failed job is retried with the tiles it has: its failed tile is queued again with no
/// failure held against it, and the worker that failed it, blocked before, may take it; a
/// cancelled job goes on the same way; a done job is 409, an unfinished one is answered as it
/// is, an unknown one 404, and past the queue limits 429.
#[tokio::test]
async fn failed_and_cancelled_jobs_are_retried_with_the_tiles_they_have() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = fake_config(dir.path());
    c.max_task_failures = 1;
    c.block_worker_after = 1;
    let st = AppState::open(c).unwrap();
    let (_, job) =
        empty_scene_job(&st, r#""width": 4, "height": 2, "spp": 1, "tile_size": 16"#).await;
    let job = job["id"].as_str().unwrap().to_string();
    let retry = |j: &str| post(&format!("/v1/jobs/{j}/retry"), "");
    let (code, body) = call(&st, retry(&job)).await;
    assert_eq!(
        (code, &body["state"]),
        (StatusCode::OK, &"queued".into()),
        "as it is"
    );

    // The one task fails, and with it the job.
    let (_, w) = register_worker(&st).await;
    let worker = w["worker_id"].as_str().unwrap().to_string();
    let lease_uri = format!("/v1/workers/{worker}/lease");
    let (_, lease) = call(&st, post(&lease_uri, "")).await;
    let lease_id = lease["lease_id"].as_str().unwrap();
    let (code, _) = call(
        &st,
        post(
            &format!("/v1/leases/{lease_id}/failure"),
            r#"{"error": "out of memory"}"#,
        ),
    )
    .await;
    assert_eq!(code, StatusCode::NO_CONTENT);
    let (_, status) = call(&st, get(&format!("/v1/jobs/{job}"))).await;
    assert_eq!(status["state"], "failed", "{status}");
    // With no tile done it has no image: not a black frame a client could save as the render.
    let image = |j: &str| get(&format!("/v1/jobs/{j}/image?format=exr"));
    let (code, body) = call(&st, image(&job)).await;
    assert_eq!(code, StatusCode::CONFLICT, "{body}");
    let message = body["error"]["message"].as_str().unwrap();
    assert!(
        message.contains("failed before any tile") && message.contains("out of memory"),
        "{message}"
    );

    let (code, body) = call(&st, retry(&job)).await;
    assert_eq!(code, StatusCode::OK, "{body}");
    assert_eq!(
        (&body["state"], &body["error"], &body["finished_ms"]),
        (
            &"running".into(),
            &serde_json::Value::Null,
            &serde_json::Value::Null
        ),
        "{body}"
    );
    // The worker blocked from it may take it again, and finish it.
    let (code, lease) = call(&st, post(&lease_uri, "")).await;
    assert_eq!(code, StatusCode::OK, "{lease}");
    let upload = Request::put(format!(
        "/v1/jobs/{job}/tasks/{}/result?worker={worker}&lease={}",
        lease["task"],
        lease["lease_id"].as_str().unwrap()
    ))
    .body(Body::from(result_4x2(vec![[0.5, 0.5, 0.5, 1.0]; 8], 0)))
    .unwrap();
    let (code, body) = call(&st, upload).await;
    assert_eq!((code, &body["accepted"]), (StatusCode::OK, &true.into()));
    let (_, status) = call(&st, get(&format!("/v1/jobs/{job}"))).await;
    assert_eq!(status["state"], "done");
    assert_eq!(call(&st, image(&job)).await.0, StatusCode::OK);
    let (code, body) = call(&st, retry(&job)).await;
    assert_eq!(
        (code, &body["error"]["code"]),
        (StatusCode::CONFLICT, &"conflict".into())
    );

    // Cancelled before it started: queued again.
    let (_, other) =
        empty_scene_job(&st, r#""width": 4, "height": 2, "spp": 1, "tile_size": 16"#).await;
    let other = other["id"].as_str().unwrap().to_string();
    let del = Request::delete(format!("/v1/jobs/{other}"))
        .body(Body::empty())
        .unwrap();
    assert_eq!(call(&st, del).await.1["state"], "cancelled");
    let (code, body) = call(&st, image(&other)).await;
    assert_eq!(code, StatusCode::CONFLICT, "{body}");
    let (code, body) = call(&st, retry(&other)).await;
    assert_eq!((code, &body["state"]), (StatusCode::OK, &"queued".into()));
    // Queued, its frame is a preview of nothing yet.
    assert_eq!(call(&st, image(&other)).await.0, StatusCode::OK);
    assert_eq!(call(&st, retry("j-none")).await.0, StatusCode::NOT_FOUND);

    // At the queue's limit, a retry is refused as a new job would be.
    let dir = tempfile::tempdir().unwrap();
    let mut c = fake_config(dir.path());
    c.limits.max_queued_jobs = 1;
    let st = AppState::open(c).unwrap();
    let (_, first) = empty_scene_job(&st, r#""width": 4, "height": 2"#).await;
    let first = first["id"].as_str().unwrap().to_string();
    let del = Request::delete(format!("/v1/jobs/{first}"))
        .body(Body::empty())
        .unwrap();
    call(&st, del).await;
    let (code, _) = empty_scene_job(&st, r#""width": 4, "height": 2"#).await;
    assert_eq!(code, StatusCode::CREATED);
    let (code, body) = call(&st, retry(&first)).await;
    assert_eq!(
        (code, &body["error"]["code"]),
        (StatusCode::TOO_MANY_REQUESTS, &"too_many".into())
    );
}

/// A stored result found damaged (its bytes changed, in the database or in its file) or
/// missing when an image is made is left out of that image, which gets no entity tag, and its
/// task is queued again: the done job runs again, a worker renders the tile, and the job
/// finishes with the frame it had.
#[tokio::test]
async fn a_damaged_result_is_rendered_again_and_its_job_finishes_again() {
    for (file_bytes, damage) in [(usize::MAX, "blob"), (0, "file"), (0, "gone")] {
        let dir = tempfile::tempdir().unwrap();
        let mut c = fake_config(dir.path());
        c.result_file_bytes = file_bytes;
        // Every image read from the store (a kept one is served as it was made).
        c.image_cache_bytes = 0;
        let st = AppState::open(c).unwrap();
        let (_, job) =
            empty_scene_job(&st, r#""width": 4, "height": 2, "spp": 1, "tile_size": 16"#).await;
        let job = job["id"].as_str().unwrap().to_string();
        let pixels: Vec<[f32; 4]> = (0..8).map(|i| [i as f32 / 8.0, 0.5, 0.25, 1.0]).collect();
        let (code, body) = lease_and_upload_4x2(&st, &job, pixels.clone()).await;
        assert_eq!((code, &body["accepted"]), (StatusCode::OK, &true.into()));
        let uri = format!("/v1/jobs/{job}/image?format=exr");
        let fetch = || async {
            let resp = app(st.clone()).oneshot(get(&uri)).await.unwrap();
            assert_eq!(resp.status(), StatusCode::OK);
            let tagged = resp.headers().contains_key("etag");
            let body = axum::body::to_bytes(resp.into_body(), usize::MAX)
                .await
                .unwrap();
            (tagged, body.to_vec())
        };
        let (tagged, want) = fetch().await;
        assert!(tagged);
        let status_uri = format!("/v1/jobs/{job}");
        let state = |st: AppState| {
            let uri = status_uri.clone();
            async move {
                let (_, status) = call(&st, get(&uri)).await;
                (status["state"].clone(), status["tasks_done"].clone())
            }
        };
        assert_eq!(state(st.clone()).await, ("done".into(), 1.into()));

        let db = rusqlite::Connection::open(dir.path().join("raytile.sqlite3")).unwrap();
        let file: Option<String> = db
            .query_row("SELECT file FROM results", [], |r| r.get(0))
            .unwrap();
        match damage {
            "blob" => {
                let mut data: Vec<u8> = db
                    .query_row("SELECT data FROM results", [], |r| r.get(0))
                    .unwrap();
                let last = data.len() - 1;
                data[last] ^= 0x40;
                db.execute("UPDATE results SET data = ?1", [data]).unwrap();
            }
            _ => {
                let path = dir.path().join("results").join(file.unwrap());
                if damage == "gone" {
                    std::fs::remove_file(path).unwrap();
                } else {
                    let mut bytes = std::fs::read(&path).unwrap();
                    let last = bytes.len() - 1;
                    bytes[last] ^= 0x40;
                    std::fs::write(&path, bytes).unwrap();
                }
            }
        }
        let (tagged, partial) = fetch().await;
        assert!(!tagged, "{damage}: an image lacking a tile has no name");
        assert_ne!(partial, want, "{damage}: the damaged tile is left out");
        assert_eq!(
            state(st.clone()).await,
            ("running".into(), 0.into()),
            "{damage}: queued again"
        );
        let (code, body) = lease_and_upload_4x2(&st, &job, pixels).await;
        assert_eq!((code, &body["accepted"]), (StatusCode::OK, &true.into()));
        assert_eq!(state(st.clone()).await, ("done".into(), 1.into()));
        let (tagged, again) = fetch().await;
        assert!(tagged);
        assert_eq!(again, want, "{damage}: the frame it had");
    }
}

/// A job image is named by an entity tag that changes when a result is stored and at every
/// start: a client that names the current one is answered 304, a byte range is served (206) or
/// refused (416) against it, and the image is kept for the requests that follow, until its job
/// is purged.
#[tokio::test]
async fn images_are_named_kept_revalidated_and_served_by_the_range() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = fake_config(dir.path());
    c.max_parallel_images = 1;
    c.image_wait = std::time::Duration::from_millis(100);
    let st = AppState::open(c).unwrap();
    let (_, job) =
        empty_scene_job(&st, r#""width": 4, "height": 2, "spp": 1, "tile_size": 16"#).await;
    let job = job["id"].as_str().unwrap().to_string();
    let uri = format!("/v1/jobs/{job}/image?format=exr");
    let with = |pairs: &[(&str, &str)]| {
        let mut r = Request::get(&uri);
        for (k, v) in pairs {
            r = r.header(*k, *v);
        }
        r.body(Body::empty()).unwrap()
    };
    async fn send(
        st: &AppState,
        req: Request<Body>,
    ) -> (StatusCode, axum::http::HeaderMap, Vec<u8>) {
        let resp = app(st.clone()).oneshot(req).await.unwrap();
        let (parts, body) = resp.into_parts();
        let body = axum::body::to_bytes(body, usize::MAX).await.unwrap();
        (parts.status, parts.headers, body.to_vec())
    }
    // Not made yet: a HEAD says nothing of its length (not `Content-Length: 0`).
    let head = || Request::head(&uri).body(Body::empty()).unwrap();
    let (code, h, _) = send(&st, head()).await;
    assert_eq!(code, StatusCode::OK);
    assert!(h.get("content-length").is_none(), "{h:?}");
    let (code, h, first) = send(&st, with(&[])).await;
    assert_eq!(code, StatusCode::OK);
    let tag = h["etag"].to_str().unwrap().to_string();
    assert!(tag.starts_with('"') && tag.ends_with("-exr\""), "{tag}");
    assert_eq!(
        (&h["cache-control"], &h["accept-ranges"], &h["content-type"]),
        (
            &"no-cache".parse().unwrap(),
            &"bytes".parse().unwrap(),
            &"image/x-exr".parse().unwrap()
        )
    );
    let (_, png, _) = send(&st, get(&format!("/v1/jobs/{job}/image?format=png"))).await;
    assert_ne!(png["etag"], h["etag"], "each format has its own name");

    // The client's copy is current: 304, no body, the same name.
    let (code, h, body) = send(&st, with(&[("if-none-match", &tag)])).await;
    assert_eq!((code, body.len()), (StatusCode::NOT_MODIFIED, 0));
    assert_eq!(h["etag"].to_str().unwrap(), tag);
    let (code, _, _) = send(&st, with(&[("if-none-match", "\"other\"")])).await;
    assert_eq!(code, StatusCode::OK);

    // Ranges of the named image.
    let len = first.len();
    let (code, h, body) = send(&st, with(&[("range", "bytes=0-9")])).await;
    assert_eq!(code, StatusCode::PARTIAL_CONTENT);
    assert_eq!(
        h["content-range"].to_str().unwrap(),
        format!("bytes 0-9/{len}")
    );
    assert_eq!(body, first[..10]);
    let (code, _, body) = send(&st, with(&[("range", "bytes=-5"), ("if-range", &tag)])).await;
    assert_eq!(
        (code, body.as_slice()),
        (StatusCode::PARTIAL_CONTENT, &first[len - 5..])
    );
    let (code, _, body) = send(
        &st,
        with(&[("range", "bytes=0-9"), ("if-range", "\"old\"")]),
    )
    .await;
    assert_eq!(
        (code, body.len()),
        (StatusCode::OK, len),
        "another image: all of this one"
    );
    let past = format!("bytes={len}-");
    let (code, h, body) = send(&st, with(&[("range", past.as_str())])).await;
    assert_eq!(code, StatusCode::RANGE_NOT_SATISFIABLE);
    assert_eq!(
        h["content-range"].to_str().unwrap(),
        format!("bytes */{len}")
    );
    let body: serde_json::Value = serde_json::from_slice(&body).unwrap();
    assert_error_body("range", &body);
    assert_eq!(body["error"]["field"], "Range");

    // Kept: served while every image slot is taken, and to HEAD with its length.
    let held = st.image_slots.clone().acquire_owned().await.unwrap();
    let (code, _, body) = send(&st, with(&[])).await;
    assert_eq!((code, &body), (StatusCode::OK, &first));
    let (code, h, body) = send(&st, head()).await;
    assert_eq!((code, body.len()), (StatusCode::OK, 0));
    assert_eq!(h["content-length"].to_str().unwrap(), len.to_string());
    assert_eq!(h["etag"].to_str().unwrap(), tag);
    drop(held);

    // A result stored: a new name, a new image, which says the samples its result dropped.
    let dropped =
        |h: &axum::http::HeaderMap| h[crate::api::DROPPED_SAMPLES].to_str().unwrap().to_string();
    assert_eq!(dropped(&h), "0");
    let (code, _) =
        lease_and_upload_4x2_dropping(&st, &job, vec![[0.5, 0.25, 1.0, 1.0]; 8], 2).await;
    assert_eq!(code, StatusCode::OK);
    let (code, h, second) = send(&st, with(&[("if-none-match", &tag)])).await;
    assert_eq!(code, StatusCode::OK, "the old name is not current");
    assert_eq!(dropped(&h), "2");
    // Kept, it still says so.
    assert_eq!(dropped(&send(&st, with(&[])).await.1), "2");
    let tag2 = h["etag"].to_str().unwrap().to_string();
    assert_ne!(tag2, tag);
    assert_ne!(second, first);
    let (code, _, body) = send(&st, with(&[("range", "bytes=0-9"), ("if-range", &tag)])).await;
    assert_eq!(
        (code, &body),
        (StatusCode::OK, &second),
        "no range of a superseded image"
    );

    // Another start of the coordinator names the same image anew.
    drop(st);
    let st = AppState::open(fake_config(dir.path())).unwrap();
    let (code, h, again) = send(&st, with(&[("if-none-match", &tag2)])).await;
    assert_eq!((code, &again), (StatusCode::OK, &second));
    assert_ne!(h["etag"].to_str().unwrap(), tag2);
    assert!(st.image_cache().held() > 0);
    let purge = Request::delete(format!("/v1/jobs/{job}?purge=true"))
        .body(Body::empty())
        .unwrap();
    assert_eq!(call(&st, purge).await.0, StatusCode::OK);
    assert_eq!(st.image_cache().held(), 0, "purged with its job");
    assert_eq!(send(&st, with(&[])).await.0, StatusCode::NOT_FOUND);
}

/// A scene upload that cannot be written to the data directory is answered a retryable 503,
/// as a database write is, not a 500; `tmp/` and `scenes/` removed while the coordinator runs
/// are made again by the next upload.
#[tokio::test]
async fn scene_uploads_that_cannot_be_written_are_retryable() {
    let dir = tempfile::tempdir().unwrap();
    let st = AppState::open(fake_config(dir.path())).unwrap();
    let tmp = dir.path().join("tmp");
    std::fs::remove_dir_all(&tmp).unwrap();
    std::fs::remove_dir_all(dir.path().join("scenes")).unwrap();
    let (code, body) = call(&st, post("/v1/scenes", r#"{"objects": []}"#)).await;
    assert_eq!(code, StatusCode::CREATED, "{body}");
    let stored = dir.path().join("scenes").join(body["id"].as_str().unwrap());
    assert!(
        stored.join("meta.json").is_file(),
        "stored, not only answered"
    );
    // tmp/ a file: nothing can be written under it.
    std::fs::remove_dir_all(&tmp).unwrap();
    std::fs::write(&tmp, b"in the way").unwrap();
    let (code, body) = call(&st, post("/v1/scenes", r#"{"objects": [], "lights": []}"#)).await;
    assert_eq!(code, StatusCode::SERVICE_UNAVAILABLE, "{body}");
    assert_error_body("upload", &body);
    assert_eq!(
        (&body["error"]["code"], &body["error"]["retryable"]),
        (&"store_unavailable".into(), &true.into()),
        "{body}"
    );
}

/// Every file under `d`, at any depth.
fn walk(d: &std::path::Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(d).into_iter().flatten().flatten() {
        if e.file_type().unwrap().is_dir() {
            out.extend(walk(&e.path()));
        } else {
            out.push(e.path());
        }
    }
    out
}

/// Large results are read and checked a few at a time: one that finds every slot taken for
/// `large_result_wait` is answered 503 `busy` with Retry-After (and nothing changes); one
/// waiting when a slot frees is stored. Small results need no slot.
#[tokio::test]
async fn large_results_wait_for_a_slot_and_are_answered_busy_after_the_wait() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = fake_config(dir.path());
    c.max_parallel_large_results = 1;
    c.large_result_wait = std::time::Duration::from_millis(200);
    // A 4×2 result is 160-odd bytes: "large" here.
    c.result_file_bytes = 100;
    let st = AppState::open(c).unwrap();
    let (job, worker) = job_and_worker(&st, r#""width": 4, "height": 2, "spp": 1"#).await;
    let lease = || async {
        let (code, l) = call(&st, post(&format!("/v1/workers/{worker}/lease"), "")).await;
        assert_eq!(code, StatusCode::OK, "{l}");
        l
    };
    let upload = |l: &serde_json::Value| {
        let body = result_4x2(vec![[0.5, 0.5, 0.5, 1.0]; 8], 0);
        assert!(body.len() >= 100);
        Request::put(format!(
            "/v1/jobs/{job}/tasks/{}/result?worker={worker}&lease={}",
            l["task"],
            l["lease_id"].as_str().unwrap()
        ))
        .header("content-length", body.len())
        .body(Body::from(body))
        .unwrap()
    };
    let first = lease().await;
    let held = st.large_result_slots.clone().acquire_owned().await.unwrap();
    let resp = app(st.clone()).oneshot(upload(&first)).await.unwrap();
    assert_eq!(resp.status(), StatusCode::SERVICE_UNAVAILABLE);
    assert_eq!(resp.headers()["retry-after"], "2");
    let (_, status) = call(&st, get(&format!("/v1/jobs/{job}"))).await;
    assert_eq!(status["tasks_done"], 0, "{status}");
    // One waiting when the slot frees is stored.
    let waiting = tokio::spawn(app(st.clone()).oneshot(upload(&first)));
    tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    drop(held);
    let resp = waiting.await.unwrap().unwrap();
    assert_eq!(resp.status(), StatusCode::OK);
    let (_, status) = call(&st, get(&format!("/v1/jobs/{job}"))).await;
    assert_eq!(status["tasks_done"], 1, "{status}");
    // Under the size, no slot is needed.
    drop(st);
    let dir2 = tempfile::tempdir().unwrap();
    let mut c = fake_config(dir2.path());
    c.large_result_wait = std::time::Duration::from_millis(200);
    let st = AppState::open(c).unwrap();
    let _held = st
        .large_result_slots
        .clone()
        .acquire_many_owned(2)
        .await
        .unwrap();
    let (_, job2) = empty_scene_job(&st, r#""width": 4, "height": 2, "spp": 1"#).await;
    let (_, w) = register_worker(&st).await;
    let worker2 = w["worker_id"].as_str().unwrap();
    let (_, l) = call(&st, post(&format!("/v1/workers/{worker2}/lease"), "")).await;
    let small = Request::put(format!(
        "/v1/jobs/{}/tasks/{}/result?worker={worker2}&lease={}",
        job2["id"].as_str().unwrap(),
        l["task"],
        l["lease_id"].as_str().unwrap()
    ))
    .body(Body::from(result_4x2(vec![[0.5, 0.5, 0.5, 1.0]; 8], 0)))
    .unwrap();
    let (code, body) = call(&st, small).await;
    assert_eq!(code, StatusCode::OK, "{body}");
}
