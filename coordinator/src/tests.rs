//! Coordinator unit tests with synthetic results: fake workers post made-up tile sums, so
//! nothing here needs the renderer.

use crate::sched::{
    transition, Outcome, ResultOutcome, Sched, SchedConfig, Task, TaskEvent, TaskState,
};
use crate::store::Store;
use crate::{app, AppState, Config, LoadedScene};
use axum::body::Body;
use axum::http::{Request, StatusCode};
use raytile_core::{RenderSettings, TileAccum};
use raytile_proto::JobState;
use std::sync::Arc;
use std::time::Duration;
use tokio::time::Instant;
use tower::ServiceExt;

fn cfg() -> SchedConfig {
    SchedConfig {
        lease_timeout: Duration::from_secs(10),
        max_task_failures: 3,
        block_worker_after: 2,
    }
}

fn small(passes: u32) -> RenderSettings {
    RenderSettings {
        width: 32,
        height: 32,
        tile_size: 16,
        spp: 4,
        passes,
        ..Default::default()
    }
}

fn fake_result(s: &Sched, job: &str, idx: usize) -> (TileAccum, u32, Vec<u8>) {
    let (tile, pass, _) = s.jobs[job].task_work(idx);
    let acc = TileAccum {
        tile,
        pixels: vec![[pass as f32 + 0.5, 1.0, 2.0, 1.0]; tile.pixel_count()],
        bad_samples: 0,
    };
    let bytes = raytile_proto::tile::encode(&acc, pass);
    (acc, pass, bytes)
}

fn open(dir: &std::path::Path, now: Instant) -> Sched {
    Sched::restore(
        cfg(),
        Store::open(dir).unwrap(),
        now,
        Duration::from_secs(5),
    )
    .unwrap()
}

fn finish(s: &mut Sched, w: &str, now: Instant) -> Option<(String, usize)> {
    let (job, idx, _) = s.lease(w, now).unwrap()?;
    let (acc, pass, bytes) = fake_result(s, &job, idx);
    assert_eq!(
        s.complete(&job, idx as u32, w, &acc, pass, &bytes, now)
            .unwrap(),
        ResultOutcome::Accepted
    );
    Some((job, idx))
}

#[test]
fn state_machine_refuses_stale_events() {
    let now = Instant::now();
    let mut t = Task {
        tile: 0,
        pass: 0,
        state: TaskState::Queued,
        failures: 0,
    };
    let lease = |l: &str| TaskEvent::Lease {
        worker: "w".into(),
        lease: l.into(),
        deadline: now + Duration::from_secs(1),
    };
    assert_eq!(transition(&mut t, lease("a")), Outcome::Changed);
    assert_eq!(transition(&mut t, lease("b")), Outcome::Ignored);
    let renew_b = TaskEvent::Renew {
        lease: "b".into(),
        deadline: now,
    };
    assert_eq!(transition(&mut t, renew_b), Outcome::Ignored);
    assert_eq!(
        transition(&mut t, TaskEvent::Expire { now }),
        Outcome::Ignored
    );
    let later = now + Duration::from_secs(2);
    assert_eq!(
        transition(&mut t, TaskEvent::Expire { now: later }),
        Outcome::Changed
    );
    assert_eq!(t.state, TaskState::Queued);
    let done = TaskEvent::Complete { worker: "w".into() };
    assert_eq!(transition(&mut t, done.clone()), Outcome::Changed);
    assert_eq!(transition(&mut t, done), Outcome::AlreadyDone);
    assert_eq!(transition(&mut t, lease("c")), Outcome::Ignored);
}

#[test]
fn priority_then_fifo_then_pass_order() {
    let dir = tempfile::tempdir().unwrap();
    let now = Instant::now();
    let mut s = open(dir.path(), now);
    let w = s.register("w", 1).unwrap();
    let a = s.create_job("s".into(), small(2), 0).unwrap().id;
    let b = s.create_job("s".into(), small(2), 5).unwrap().id;
    let c = s.create_job("s".into(), small(2), 0).unwrap().id;
    let mut order = Vec::new();
    while let Some((job, _)) = finish(&mut s, &w, now) {
        order.push(job);
    }
    let jobs: Vec<&String> = order.iter().collect();
    let n = s.jobs[&a].tasks.len();
    assert!(jobs[..n].iter().all(|j| **j == b), "high priority first");
    assert!(jobs[n..2 * n].iter().all(|j| **j == a), "then FIFO");
    assert!(jobs[2 * n..].iter().all(|j| **j == c));
    // Within a job: every tile of pass 0 before any of pass 1.
    let passes: Vec<u32> = s.jobs[&a].tasks.iter().map(|t| t.pass).collect();
    assert!(passes.windows(2).all(|w| w[0] <= w[1]));
    assert!(s.jobs.values().all(|j| j.state == JobState::Done));
}

#[test]
fn centre_tiles_go_first() {
    let s = RenderSettings {
        width: 48,
        height: 48,
        tile_size: 16,
        ..Default::default()
    };
    let tiles = s.tiles();
    let order = crate::sched::centre_out(&s, &tiles);
    assert_eq!(
        tiles[order[0] as usize],
        raytile_core::Tile {
            x0: 16,
            y0: 16,
            x1: 32,
            y1: 32
        }
    );
}

#[test]
fn expired_leases_are_requeued_and_late_results_are_duplicates() {
    let dir = tempfile::tempdir().unwrap();
    let t0 = Instant::now();
    let mut s = open(dir.path(), t0);
    let w1 = s.register("w1", 1).unwrap();
    let w2 = s.register("w2", 1).unwrap();
    let job = s.create_job("s".into(), small(1), 0).unwrap().id;
    let (_, idx, lease) = s.lease(&w1, t0).unwrap().unwrap();
    assert_eq!(s.expire(t0 + Duration::from_secs(5)).unwrap(), 0);
    assert_eq!(
        s.heartbeat(&lease, t0 + Duration::from_secs(5)).unwrap(),
        Ok(())
    );
    // Renewed at 5 s: still alive at 14 s, gone at 15 s.
    assert_eq!(s.expire(t0 + Duration::from_secs(14)).unwrap(), 0);
    assert_eq!(s.expire(t0 + Duration::from_secs(15)).unwrap(), 1);
    assert!(s
        .heartbeat(&lease, t0 + Duration::from_secs(15))
        .unwrap()
        .is_err());
    let (_, idx2, _) = s.lease(&w2, t0 + Duration::from_secs(15)).unwrap().unwrap();
    assert_eq!(idx, idx2, "the expired task is leased again first");
    let (acc, pass, bytes) = fake_result(&s, &job, idx);
    let now = t0 + Duration::from_secs(16);
    assert_eq!(
        s.complete(&job, idx as u32, &w2, &acc, pass, &bytes, now)
            .unwrap(),
        ResultOutcome::Accepted
    );
    // The first worker's late result, and a plain duplicate.
    assert_eq!(
        s.complete(&job, idx as u32, &w1, &acc, pass, &bytes, now)
            .unwrap(),
        ResultOutcome::Duplicate
    );
    assert_eq!(s.counters.duplicates, 1);
    // A result for the wrong pixels is refused.
    let (other, _, _) = fake_result(&s, &job, idx + 1);
    assert!(s
        .complete(&job, idx as u32, &w1, &other, pass, &bytes, now)
        .is_err());
}

#[test]
fn repeated_failures_fail_the_job_and_block_the_worker() {
    let dir = tempfile::tempdir().unwrap();
    let now = Instant::now();
    let mut s = open(dir.path(), now);
    let bad = s.register("bad", 1).unwrap();
    let good = s.register("good", 1).unwrap();
    let job = s.create_job("s".into(), small(1), 0).unwrap().id;
    for _ in 0..2 {
        let (_, _, l) = s.lease(&bad, now).unwrap().unwrap();
        assert!(s.fail(&l, "out of memory").unwrap());
    }
    assert!(
        s.lease(&bad, now).unwrap().is_none(),
        "blocked after two failures"
    );
    let (_, _, l) = s.lease(&good, now).unwrap().unwrap();
    assert!(s.fail(&l, "disk full").unwrap());
    let j = &s.jobs[&job];
    assert_eq!(j.state, JobState::Failed);
    let err = j.error.as_deref().unwrap();
    assert!(
        err.contains("failed 3 times") && err.contains("disk full"),
        "{err}"
    );
    assert!(s.lease(&good, now).unwrap().is_none());
}

#[test]
fn a_job_every_live_worker_is_blocked_from_fails_instead_of_waiting() {
    let dir = tempfile::tempdir().unwrap();
    let now = Instant::now();
    // Tasks may fail often (10 times) but a worker is blocked after 2 failures.
    let config = SchedConfig {
        max_task_failures: 10,
        ..cfg()
    };
    let mut s = Sched::restore(
        config.clone(),
        Store::open(dir.path()).unwrap(),
        now,
        Duration::ZERO,
    )
    .unwrap();
    let a = s.register("a", 1).unwrap();
    let b = s.register("b", 1).unwrap();
    // A worker not seen for a long time (nor restored at a recent start) does not keep the
    // job alive.
    let gone = s.register("gone", 1).unwrap();
    s.workers.get_mut(&gone).unwrap().last_seen_ms = 0;
    s.started_ms = 0;
    let job = s.create_job("s".into(), small(2), 0).unwrap().id;
    // Each worker fails twice: no task reaches 10 failures, both get blocked.
    for w in [&a, &b] {
        for _ in 0..2 {
            let (_, _, l) = s.lease(w, now).unwrap().unwrap();
            assert!(s.fail(&l, &format!("no GPU on {w}")).unwrap());
        }
        if *w == a {
            assert_eq!(s.jobs[&job].state, JobState::Running, "b may still take it");
        }
    }
    let j = &s.jobs[&job];
    assert_eq!(j.state, JobState::Failed);
    let err = j.error.as_deref().unwrap();
    assert!(
        err.contains("every worker") && err.contains("no GPU"),
        "{err}"
    );
    // The expiry tick fails a job whose last blocked worker's peers have gone since.
    let job2 = s.create_job("s".into(), small(1), 0).unwrap().id;
    for _ in 0..2 {
        let (_, _, l) = s.lease(&a, now).unwrap().unwrap();
        assert!(s.fail(&l, "no GPU").unwrap());
    }
    assert_eq!(s.jobs[&job2].state, JobState::Running, "b is live");
    s.workers.get_mut(&b).unwrap().last_seen_ms = 0;
    s.expire(now).unwrap();
    let j2 = &s.jobs[&job2];
    assert_eq!(j2.state, JobState::Failed);
    assert!(j2.error.as_deref().unwrap().contains("every live worker"));
    // With no live worker at all, nothing is failed: workers may come back.
    let job3 = s.create_job("s".into(), small(1), 0).unwrap().id;
    let (_, _, l) = s.lease(&b, now).unwrap().unwrap();
    assert!(s.fail(&l, "oops").unwrap());
    for w in s.workers.values_mut() {
        w.last_seen_ms = 0;
    }
    s.expire(now).unwrap();
    assert_ne!(s.jobs[&job3].state, JobState::Failed);
    // Persisted: a restarted coordinator sees the jobs failed.
    drop(s);
    let s = Sched::restore(
        config,
        Store::open(dir.path()).unwrap(),
        now,
        Duration::ZERO,
    )
    .unwrap();
    assert_eq!(s.jobs[&job].state, JobState::Failed);
}

#[test]
fn restart_resumes_without_redoing_finished_tasks() {
    let dir = tempfile::tempdir().unwrap();
    let t0 = Instant::now();
    let (job, done_before, out_lease) = {
        let mut s = open(dir.path(), t0);
        let w = s.register("w", 1).unwrap();
        let job = s.create_job("s".into(), small(2), 0).unwrap().id;
        for _ in 0..3 {
            finish(&mut s, &w, t0).unwrap();
        }
        let (_, idx, lease) = s.lease(&w, t0).unwrap().unwrap();
        (job, 3, (idx, lease, w))
    };
    let t1 = t0 + Duration::from_secs(100);
    let mut s = open(dir.path(), t1);
    let j = &s.jobs[&job];
    assert_eq!(j.status().tasks_done, done_before);
    assert_eq!(j.status().tasks_leased, 1);
    let (idx, lease, w) = out_lease;
    // The old lease survives the restart with a grace period, and can still deliver.
    assert_eq!(s.heartbeat(&lease, t1).unwrap(), Ok(()));
    let (acc, pass, bytes) = fake_result(&s, &job, idx);
    assert_eq!(
        s.complete(&job, idx as u32, &w, &acc, pass, &bytes, t1)
            .unwrap(),
        ResultOutcome::Accepted
    );
    let mut leased = std::collections::HashSet::new();
    while let Some((_, i)) = finish(&mut s, &w, t1) {
        assert!(leased.insert(i));
    }
    assert_eq!(
        leased.len() as u64,
        s.jobs[&job].tasks.len() as u64 - 4,
        "no finished task redone"
    );
    assert_eq!(s.jobs[&job].state, JobState::Done);
}

// --- HTTP level (router called with oneshot, no socket) -------------------------------------

#[test]
fn purge_deletes_a_job_and_its_tiles_for_good() {
    let dir = tempfile::tempdir().unwrap();
    let now = Instant::now();
    let mut s = open(dir.path(), now);
    let w = s.register("w", 1).unwrap();
    let keep = s.create_job("s".into(), small(1), 0).unwrap().id;
    let gone = s.create_job("s".into(), small(1), 1).unwrap().id;
    finish(&mut s, &w, now).unwrap();
    let (_, _, lease) = s.lease(&w, now).unwrap().unwrap();
    let st = s.purge(&gone).unwrap().unwrap();
    assert_eq!(
        st.state,
        JobState::Cancelled,
        "a running job is cancelled first"
    );
    assert!(!s.jobs.contains_key(&gone));
    assert!(s.purge(&gone).unwrap().is_none(), "unknown after the purge");
    assert!(!s.fail(&lease, "late").unwrap(), "its leases are gone too");
    drop(s);
    let s = open(dir.path(), now);
    assert!(!s.jobs.contains_key(&gone), "purged for good");
    assert!(s.jobs.contains_key(&keep), "other jobs untouched");
}

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

#[test]
fn restart_under_another_renderer_version_renders_unfinished_jobs_again() {
    let dir = tempfile::tempdir().unwrap();
    let t0 = Instant::now();
    let (finished_job, open_job) = {
        let mut s = open(dir.path(), t0);
        let w = s.register("w", 1).unwrap();
        let finished_job = s.create_job("s".into(), small(1), 0).unwrap().id;
        while finish(&mut s, &w, t0).is_some() {}
        let open_job = s.create_job("s".into(), small(2), 0).unwrap().id;
        for _ in 0..3 {
            finish(&mut s, &w, t0).unwrap();
        }
        s.lease(&w, t0).unwrap().unwrap();
        (finished_job, open_job)
    };
    let db = dir.path().join("raytile.sqlite3");
    let results = |job: &str| -> i64 {
        let c = rusqlite::Connection::open(&db).unwrap();
        c.query_row(
            "SELECT COUNT(*) FROM results WHERE job_id = ?1",
            [job],
            |r| r.get(0),
        )
        .unwrap()
    };
    let (kept, before) = (results(&finished_job), results(&open_job));
    assert!(kept > 0 && before == 3);
    // Same version: a restart keeps everything.
    drop(open(dir.path(), t0));
    assert_eq!(results(&open_job), 3);
    // As if these tiles came from another renderer version.
    rusqlite::Connection::open(&db)
        .unwrap()
        .execute(
            "UPDATE meta SET value = 'older' WHERE key = 'render_version'",
            [],
        )
        .unwrap();
    let t1 = t0 + Duration::from_secs(100);
    let mut s = open(dir.path(), t1);
    assert_eq!(results(&open_job), 0, "the other renderer's tiles are gone");
    assert_eq!(results(&finished_job), kept, "finished frames are kept");
    let st = s.jobs[&open_job].status();
    assert_eq!((st.tasks_done, st.tasks_leased), (0, 0));
    assert_eq!(s.jobs[&finished_job].state, JobState::Done);
    // Every task is rendered again, and the job finishes.
    let w = s.register("w2", 1).unwrap();
    let mut n = 0;
    while finish(&mut s, &w, t1).is_some() {
        n += 1;
    }
    assert_eq!(n, s.jobs[&open_job].tasks.len());
    assert_eq!(s.jobs[&open_job].state, JobState::Done);
}
