//! The API client of `raytile-proto` (the one workers and `raytile submit` use) against the real
//! coordinator on loopback: every route it knows, the token, and errors that keep their field.

use raytile_proto::client::{Client, ClientError, StatusCode};
use raytile_proto::scene::SceneFormat;
use raytile_proto::{
    FailureReport, IntegratorKind, JobRequest, JobState, RegisterRequest, RenderOverrides,
    TileAccum,
};
use std::time::Duration;

/// A scene with render settings of its own, which jobs inherit.
const SCENE: &str = r#"{
  "render": {"width": 40, "height": 20, "spp": 4, "integrator": "whitted"},
  "camera": {"position": [0, 0, 5], "look_at": [0, 0, 0], "fov": 40},
  "materials": {"m": {"type": "diffuse"}},
  "objects": [{"shape": {"type": "sphere", "radius": 1}, "material": "m"}]
}"#;

struct Coord {
    base: String,
    stop: tokio::sync::oneshot::Sender<()>,
    task: tokio::task::JoinHandle<anyhow::Result<()>>,
    _dir: tempfile::TempDir,
}

async fn start(token: &str) -> Coord {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = raytile_coordinator::Config::new(dir.path().join("data"));
    cfg.token = Some(token.into());
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let base = format!("http://{}", listener.local_addr().unwrap());
    let (stop, rx) = tokio::sync::oneshot::channel::<()>();
    let task = tokio::spawn(raytile_coordinator::run(listener, cfg, async {
        let _ = rx.await;
    }));
    Coord {
        base,
        stop,
        task,
        _dir: dir,
    }
}

#[tokio::test]
async fn the_client_speaks_every_route_it_knows() {
    let c = start("sesame").await;
    let api = Client::new(&c.base, Some("sesame".into())).unwrap();
    assert_eq!(api.health().await.unwrap().status, "ok");

    // Without the token: the coordinator's 401, kept as a status.
    let anonymous = Client::new(&c.base, None).unwrap();
    let e = anonymous.jobs().await.unwrap_err();
    assert_eq!(e.status(), Some(StatusCode::UNAUTHORIZED), "{e}");

    let scene = api
        .upload_scene(SCENE.as_bytes().to_vec(), Some(SceneFormat::Json), None)
        .await
        .unwrap();
    assert_eq!(scene.format, "json");

    // Settings: the override, then the scene's own, then the defaults.
    let req = JobRequest {
        scene: scene.id.clone(),
        overrides: RenderOverrides {
            width: Some(32),
            tile_size: Some(16),
            passes: Some(2),
            ..Default::default()
        },
        priority: Some(1),
    };
    let job = api.create_job(&req).await.unwrap();
    let s = &job.settings;
    assert_eq!((s.width, s.height, s.spp), (32, 20, 4));
    assert_eq!(s.integrator, IntegratorKind::Whitted);
    assert_eq!((job.priority, job.tasks_total), (1, 2 * 2 * 2));
    assert_eq!(api.job(&job.id).await.unwrap().id, job.id);
    assert_eq!(api.jobs().await.unwrap().jobs.len(), 1);

    // A refusal names its field, as the API does.
    let too_many_passes = JobRequest {
        overrides: RenderOverrides {
            passes: Some(5),
            ..Default::default()
        },
        ..req.clone()
    };
    match api.create_job(&too_many_passes).await.unwrap_err() {
        ClientError::Status {
            status,
            field,
            message,
            ..
        } => {
            assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY);
            assert_eq!(field.as_deref(), Some("passes"));
            assert!(message.contains("spp (4)"), "{message}");
        }
        e => panic!("{e}"),
    }

    // The worker's side: register, lease, download, heartbeat, upload, fail, release.
    let reg = api
        .register(&RegisterRequest {
            name: "test".into(),
            threads: 1,
            render_version: raytile_core::RENDER_VERSION,
        })
        .await
        .unwrap();
    let mut results = 0;
    while let Some(lease) = api
        .lease(&reg.worker_id, Duration::from_millis(50))
        .await
        .unwrap()
    {
        if results == 0 {
            let blob = api.download_scene(&lease.scene).await.unwrap();
            assert_eq!(&blob[..], SCENE.as_bytes());
            let hb = api
                .heartbeat(&lease.lease_id, Duration::from_secs(5))
                .await
                .unwrap();
            assert!(!hb.cancelled);
            // Handed back unrendered: it comes round again.
            api.release(&lease.lease_id, Duration::from_secs(5))
                .await
                .unwrap();
            results += 1;
            continue;
        }
        if results == 1 {
            let report = FailureReport {
                error: "a test failure".into(),
            };
            api.report_failure(&lease.lease_id, &report).await.unwrap();
            results += 1;
            continue;
        }
        let acc = TileAccum {
            tile: lease.tile,
            pixels: vec![[0.5, 0.25, 1.0, 1.0]; lease.tile.pixel_count()],
            bad_samples: 0,
            splats: Vec::new(),
            coverage: Vec::new(),
        };
        let body = raytile_proto::tile::encode(&acc, lease.pass);
        let reply = api
            .upload_result(
                &lease.job,
                lease.task,
                &reg.worker_id,
                &lease.lease_id,
                body,
            )
            .await
            .unwrap();
        assert!(reply.accepted && !reply.duplicate);
        results += 1;
    }
    let done = api.job(&job.id).await.unwrap();
    assert_eq!(done.state, JobState::Done, "{done:?}");
    assert_eq!(api.workers().await.unwrap().workers.len(), 1);

    let png = api.job_image(&job.id, "png").await.unwrap();
    assert!(png.starts_with(b"\x89PNG"));
    let e = api.job_image(&job.id, "jpg").await.unwrap_err();
    assert_eq!(e.field(), Some("format"), "{e}");

    let purged = api.cancel_job(&job.id, true).await.unwrap();
    assert_eq!(purged.id, job.id);
    let e = api.job(&job.id).await.unwrap_err();
    assert_eq!(e.status(), Some(StatusCode::NOT_FOUND), "{e}");

    let _ = c.stop.send(());
    c.task.await.unwrap().unwrap();
}
