//! Cluster-level integration tests: a real coordinator and real workers, in-process, on
//! loopback. Tests that render need the core (`render_tile` and the scene loaders); the API
//! tests use synthetic workers and a fake scene loader and run without it.

use raytile_coordinator::{Config, LoadedScene};
use raytile_core::film::ImageFormat;
use raytile_core::RenderSettings;
use raytile_proto::{self as proto, JobRequest, JobState, JobStatus, RenderOverrides};
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::watch;
use tokio::task::JoinHandle;

/// Helpers: start and stop coordinators and workers, talk to the API, render locally.
mod support {
    use super::*;

    /// The test scene: the repository's own Cornell box, which every checkout has. A scene
    /// that does not load fails the test; nothing here skips for want of a file.
    pub fn cornell() -> PathBuf {
        let p = raytile_tests::cornell_box();
        if let Err(e) = raytile_core::load_scene(&p) {
            panic!("{}: {e}", p.display());
        }
        p
    }

    /// A coordinator running in this process.
    pub struct Coord {
        /// `http://127.0.0.1:PORT`.
        pub base: String,
        /// Its port, to restart on the same one.
        pub port: u16,
        stop: watch::Sender<bool>,
        handle: JoinHandle<anyhow::Result<()>>,
    }

    impl Coord {
        /// Starts on `port` (0 = any) with `cfg`.
        pub async fn start(cfg: Config, port: u16) -> Coord {
            let listener = tokio::net::TcpListener::bind(("127.0.0.1", port))
                .await
                .unwrap();
            let port = listener.local_addr().unwrap().port();
            let (stop, rx) = watch::channel(false);
            let mut rx2 = rx.clone();
            let handle = tokio::spawn(raytile_coordinator::run(listener, cfg, async move {
                let _ = rx2.wait_for(|v| *v).await;
            }));
            drop(rx);
            Coord {
                base: format!("http://127.0.0.1:{port}"),
                port,
                stop,
                handle,
            }
        }

        /// Stops it and waits until it has.
        pub async fn stop(self) {
            let _ = self.stop.send(true);
            let _ = self.handle.await;
        }
    }

    /// Coordinator settings for tests: short leases and grace.
    pub fn test_config(dir: &std::path::Path) -> Config {
        let mut c = Config::new(dir);
        c.lease_timeout = Duration::from_secs(1);
        c.heartbeat_interval = Duration::from_millis(200);
        c.startup_grace = Duration::from_millis(0);
        c.long_poll_max = Duration::from_secs(2);
        c
    }

    /// Same, with a loader that accepts anything (for tests without the core).
    pub fn fake_config(dir: &std::path::Path) -> Config {
        let mut c = test_config(dir);
        c.scene_loader = Arc::new(|_p: &std::path::Path| Ok(LoadedScene::default()));
        c
    }

    /// A worker running in this process.
    pub struct Worker {
        stop: watch::Sender<bool>,
        /// Its task: abort it to kill the worker.
        pub handle: JoinHandle<anyhow::Result<()>>,
        /// Its counters.
        pub stats: Arc<raytile_worker::Stats>,
    }

    impl Worker {
        /// Starts a worker for `base` with `threads` threads.
        pub fn start(base: &str, threads: usize, cache: &std::path::Path, name: &str) -> Worker {
            Self::start_with(base, threads, cache, name, Default::default())
        }

        /// Starts a worker that keeps built scenes in `scenes` (shared, as `raytile cluster`
        /// shares one among its workers).
        pub fn start_with(
            base: &str,
            threads: usize,
            cache: &std::path::Path,
            name: &str,
            scenes: Arc<raytile_worker::SceneCache>,
        ) -> Worker {
            let mut c = Self::config(base, threads, cache, name);
            c.scene_cache = scenes;
            Self::spawn(c)
        }

        /// The settings [`Worker::start`] runs a worker with.
        pub fn config(
            base: &str,
            threads: usize,
            cache: &std::path::Path,
            name: &str,
        ) -> raytile_worker::Config {
            let mut c = raytile_worker::Config::new(base);
            c.threads = threads;
            c.name = name.into();
            c.cache_dir = cache.join(name);
            c.long_poll = Duration::from_secs(1);
            c.max_backoff = Duration::from_millis(300);
            c
        }

        /// Runs a worker with `c`.
        pub fn spawn(c: raytile_worker::Config) -> Worker {
            let stats = c.stats.clone();
            let (stop, rx) = watch::channel(false);
            let mut rx2 = rx.clone();
            let handle = tokio::spawn(raytile_worker::run(c, async move {
                let _ = rx2.wait_for(|v| *v).await;
            }));
            Worker {
                stop,
                handle,
                stats,
            }
        }

        /// Asks it to stop and waits.
        pub async fn stop(self) {
            let _ = self.stop.send(true);
            let _ = self.handle.await;
        }
    }

    /// A child process killed (SIGKILL) and reaped when dropped, also when a test fails.
    pub struct Proc(pub std::process::Child);

    impl Drop for Proc {
        fn drop(&mut self) {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }

    /// A built binary next to the test executable. With RAYTILE_SLOW_TESTS=1 a missing one is
    /// a failure, not a skip.
    pub fn built_binary(name: &str) -> PathBuf {
        let p = std::env::current_exe()
            .unwrap()
            .parent()
            .unwrap()
            .parent()
            .unwrap()
            .join(name);
        assert!(
            p.exists(),
            "{} not built: run the workspace's tests (cargo test --workspace builds it)",
            p.display()
        );
        p
    }

    /// Uploads a scene file, returns its id.
    pub async fn upload(base: &str, bytes: Vec<u8>) -> String {
        let r = reqwest::Client::new()
            .post(format!("{base}/v1/scenes"))
            .body(bytes)
            .send()
            .await
            .unwrap();
        assert!(r.status().is_success(), "{:?}", r.text().await);
        r.json::<proto::SceneCreated>().await.unwrap().id
    }

    /// Submits a job.
    pub async fn submit(base: &str, req: &JobRequest) -> JobStatus {
        let r = reqwest::Client::new()
            .post(format!("{base}/v1/jobs"))
            .json(req)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 201, "{:?}", r.text().await);
        r.json().await.unwrap()
    }

    /// The job's status.
    pub async fn status(base: &str, id: &str) -> JobStatus {
        reqwest::get(format!("{base}/v1/jobs/{id}"))
            .await
            .unwrap()
            .json()
            .await
            .unwrap()
    }

    /// Polls until `pred` holds (or panics after `secs`).
    pub async fn wait_for(
        base: &str,
        id: &str,
        secs: u64,
        pred: impl Fn(&JobStatus) -> bool,
    ) -> JobStatus {
        let end = tokio::time::Instant::now() + Duration::from_secs(secs);
        loop {
            let s = status(base, id).await;
            if pred(&s) {
                return s;
            }
            assert!(tokio::time::Instant::now() < end, "timed out; job is {s:?}");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    /// Downloads the image.
    pub async fn image(base: &str, id: &str, format: &str) -> Vec<u8> {
        let r = reqwest::get(format!("{base}/v1/jobs/{id}/image?format={format}"))
            .await
            .unwrap();
        assert_eq!(r.status(), 200);
        r.bytes().await.unwrap().to_vec()
    }

    /// The job request used by the rendering tests.
    pub fn job(scene: &str, tile_size: u32) -> JobRequest {
        JobRequest {
            scene: scene.into(),
            overrides: RenderOverrides {
                width: Some(64),
                height: Some(64),
                spp: Some(16),
                max_depth: Some(8),
                tile_size: Some(tile_size),
                passes: Some(2),
                ..Default::default()
            },
            ..Default::default()
        }
    }

    /// The EXR of the same job rendered locally.
    pub fn local_exr(scene: &std::path::Path, s: &RenderSettings) -> Vec<u8> {
        let desc = raytile_core::load_scene(scene).unwrap();
        let built = raytile_core::Scene::build(&desc).unwrap();
        let job = raytile_core::RenderJob::new(&built, s).unwrap();
        let film = raytile_core::render(&built, &job, &());
        raytile_coordinator::compose::encode(&film, ImageFormat::Exr, &Default::default(), s)
            .unwrap()
    }

    /// Renders the cornell box with `workers` workers and `tile_size`, checks the EXR
    /// against the local render.
    pub async fn check_cluster_matches_local(workers: usize, tile_size: u32) {
        let scene = cornell();
        let dir = tempfile::tempdir().unwrap();
        let c = Coord::start(test_config(&dir.path().join("data")), 0).await;
        let ws: Vec<Worker> = (0..workers)
            .map(|i| Worker::start(&c.base, 1, dir.path(), &format!("w{i}")))
            .collect();
        let id = upload(&c.base, std::fs::read(&scene).unwrap()).await;
        let j = submit(&c.base, &job(&id, tile_size)).await;
        let done = wait_for(&c.base, &j.id, 120, |s| s.state.is_final()).await;
        assert_eq!(done.state, JobState::Done, "{done:?}");
        let got = image(&c.base, &j.id, "exr").await;
        let want = local_exr(&scene, &done.settings);
        assert!(
            got == want,
            "{workers} workers, tile {tile_size}: EXR differs from the local render"
        );
        for w in ws {
            w.stop().await;
        }
        c.stop().await;
    }

    /// A synthetic worker speaking the protocol with made-up tile sums.
    pub struct Fake {
        pub base: String,
        pub id: String,
        http: reqwest::Client,
    }

    impl Fake {
        /// Registers.
        pub async fn register(base: &str, name: &str) -> Fake {
            let http = reqwest::Client::new();
            let r: proto::Registered = http
                .post(format!("{base}/v1/workers"))
                .json(&proto::RegisterRequest {
                    name: name.into(),
                    threads: 1,
                    render_version: raytile_core::RENDER_VERSION,
                })
                .send()
                .await
                .unwrap()
                .json()
                .await
                .unwrap();
            Fake {
                base: base.into(),
                id: r.worker_id,
                http,
            }
        }

        /// Leases (short poll).
        pub async fn lease(&self) -> Option<proto::Lease> {
            let r = self
                .http
                .post(format!(
                    "{}/v1/workers/{}/lease?wait_ms=200",
                    self.base, self.id
                ))
                .send()
                .await
                .unwrap();
            if r.status() == 204 {
                return None;
            }
            assert_eq!(r.status(), 200);
            Some(r.json().await.unwrap())
        }

        /// Uploads made-up sums for the lease's tile.
        pub async fn upload(&self, l: &proto::Lease) -> (u16, serde_json::Value) {
            let acc = raytile_core::TileAccum {
                tile: l.tile,
                pixels: vec![[1.0, 0.5, 0.25, 1.0]; l.tile.pixel_count()],
                bad_samples: 0,
                splats: Vec::new(),
                coverage: Vec::new(),
            };
            let r = self
                .http
                .put(format!(
                    "{}/v1/jobs/{}/tasks/{}/result?worker={}&lease={}",
                    self.base, l.job, l.task, self.id, l.lease_id
                ))
                .body(proto::tile::encode(&acc, l.pass))
                .send()
                .await
                .unwrap();
            (r.status().as_u16(), r.json().await.unwrap_or_default())
        }

        /// Heartbeats.
        pub async fn heartbeat(&self, l: &proto::Lease) -> proto::HeartbeatReply {
            self.http
                .post(format!("{}/v1/leases/{}/heartbeat", self.base, l.lease_id))
                .send()
                .await
                .unwrap()
                .json()
                .await
                .unwrap()
        }
    }

    /// Sends `request` (a request head, perhaps with the start of a body) on a new connection
    /// to `base` and reads until the server closes it; returns (status code, rest of the
    /// answer). Plain TCP rather than an HTTP client, because the tests that use it stop
    /// sending in the middle of a request on purpose, and a client would wait to finish it.
    pub async fn raw_exchange(base: &str, request: &[u8]) -> (u16, String) {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let addr = base.trim_start_matches("http://");
        let mut conn = tokio::net::TcpStream::connect(addr).await.unwrap();
        conn.write_all(request).await.unwrap();
        let mut answer = Vec::new();
        tokio::time::timeout(Duration::from_secs(10), conn.read_to_end(&mut answer))
            .await
            .expect("the server neither answered nor closed the connection within 10 s")
            .expect("the connection was reset before the answer was read");
        let text = String::from_utf8_lossy(&answer).into_owned();
        let status = text
            .strip_prefix("HTTP/1.1 ")
            .and_then(|t| t.get(..3))
            .and_then(|c| c.parse().ok())
            .unwrap_or_else(|| panic!("not an HTTP answer: {text:?}"));
        (status, text)
    }

    /// A small job on a fake scene.
    pub async fn fake_job(base: &str) -> JobStatus {
        let scene = upload(base, br#"{"objects": []}"#.to_vec()).await;
        submit(
            base,
            &JobRequest {
                scene,
                overrides: RenderOverrides {
                    width: Some(32),
                    height: Some(32),
                    spp: Some(2),
                    tile_size: Some(16),
                    passes: Some(2),
                    ..Default::default()
                },
                ..Default::default()
            },
        )
        .await
    }
}

use support::*;

/// Determinism: the farm's image equals a local render, bit for bit, whatever the number of
/// workers and the tile size. (Needs the core.)
mod determinism {
    use super::*;

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn two_workers_match_local_render() {
        check_cluster_matches_local(2, 16).await;
    }

    /// A `bdpt` job (the glass ball's caustic in `scenes/caustic.json`): tiles carry the light
    /// their samples splat onto other pixels, and the frame adds it in fixed point, so two
    /// workers with tiles of 16 and of 64 pixels give the local render's bits.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn bdpt_on_two_workers_matches_local_render_whatever_the_tiles() {
        caustic_on_two_workers_matches_local_render(proto::IntegratorKind::Bdpt, 4, false).await;
    }

    /// A job with an alpha channel: tile results carry coverage, which the frame adds as it
    /// adds the sums, so two workers give the local render's EXR (its alpha too) whatever the
    /// tiles, with `path`, and with `bdpt`'s splats beside the coverage.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn alpha_on_two_workers_matches_local_render_whatever_the_tiles() {
        caustic_on_two_workers_matches_local_render(proto::IntegratorKind::Path, 3, true).await;
        caustic_on_two_workers_matches_local_render(proto::IntegratorKind::Bdpt, 2, true).await;
    }

    /// An `sppm` job: each tile task runs every iteration of its pixels against whole-frame
    /// photon maps that each worker traces (and keeps) itself, from (seed, iteration, photon)
    /// alone, so two workers with tiles of 16 and of 64 pixels give the local render's bits.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn sppm_on_two_workers_matches_local_render_whatever_the_tiles() {
        caustic_on_two_workers_matches_local_render(proto::IntegratorKind::Sppm, 1, false).await;
    }

    /// `scenes/caustic.json` with `integrator` in `passes` passes on two workers, with tiles of
    /// 16 and of 64 pixels: the local render's EXR both times. With `alpha`, the EXR's alpha
    /// channel is checked to be opaque on the floor and clear beyond it.
    async fn caustic_on_two_workers_matches_local_render(
        integrator: proto::IntegratorKind,
        passes: u32,
        alpha: bool,
    ) {
        let scene = std::path::PathBuf::from(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../scenes/caustic.json"
        ));
        let dir = tempfile::tempdir().unwrap();
        let c = Coord::start(test_config(&dir.path().join("data")), 0).await;
        let ws: Vec<Worker> = (0..2)
            .map(|i| Worker::start(&c.base, 1, dir.path(), &format!("w{i}")))
            .collect();
        let id = upload(&c.base, std::fs::read(&scene).unwrap()).await;
        let mut want = None;
        for tile in [16, 64] {
            let mut req = job(&id, tile);
            req.overrides.width = Some(40);
            req.overrides.height = Some(30);
            req.overrides.spp = Some(4);
            req.overrides.passes = Some(passes);
            req.overrides.max_depth = Some(6);
            req.overrides.integrator = Some(integrator);
            req.overrides.alpha = Some(alpha);
            let j = submit(&c.base, &req).await;
            let done = wait_for(&c.base, &j.id, 120, |s| s.state.is_final()).await;
            assert_eq!(done.state, JobState::Done, "{done:?}");
            assert_eq!(done.settings.integrator, integrator);
            assert_eq!(done.settings.alpha, alpha);
            let got = image(&c.base, &j.id, "exr").await;
            if alpha {
                let img = ::image::load_from_memory(&got).unwrap().into_rgba32f();
                let a: Vec<f32> = img.pixels().map(|p| p.0[3]).collect();
                // The camera looks down at the floor: the corners of its top row see past it
                // (the lamp and the ball are in the middle).
                let top = [&a[..8], &a[32..40]].concat();
                assert!(top.iter().all(|&a| a == 0.0), "{:?}", &a[..40]);
                assert!(a.contains(&1.0));
                let png = image(&c.base, &j.id, "png").await;
                let png = ::image::load_from_memory(&png).unwrap();
                assert_eq!(png.color(), ::image::ColorType::Rgba8);
            }
            let local = want.get_or_insert_with(|| local_exr(&scene, &done.settings));
            assert!(
                got == *local,
                "{}, tile {tile}: EXR differs from the local render",
                integrator.name()
            );
        }
        for w in ws {
            w.stop().await;
        }
        c.stop().await;
    }

    /// A `volpath` job (fog, smoke and milk in `scenes/fog.json`) is a job like any other.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn volpath_on_two_workers_matches_local_render() {
        let scene =
            std::path::PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/fog.json"));
        let dir = tempfile::tempdir().unwrap();
        let c = Coord::start(test_config(&dir.path().join("data")), 0).await;
        let ws: Vec<Worker> = (0..2)
            .map(|i| Worker::start(&c.base, 1, dir.path(), &format!("w{i}")))
            .collect();
        let id = upload(&c.base, std::fs::read(&scene).unwrap()).await;
        let mut req = job(&id, 16);
        req.overrides.width = Some(40);
        req.overrides.height = Some(32);
        req.overrides.spp = Some(4);
        req.overrides.integrator = Some(proto::IntegratorKind::Volpath);
        let j = submit(&c.base, &req).await;
        let done = wait_for(&c.base, &j.id, 120, |s| s.state.is_final()).await;
        assert_eq!(done.state, JobState::Done, "{done:?}");
        assert_eq!(done.settings.integrator, proto::IntegratorKind::Volpath);
        let got = image(&c.base, &j.id, "exr").await;
        let want = local_exr(&scene, &done.settings);
        assert!(got == want, "volpath: EXR differs from the local render");
        for w in ws {
            w.stop().await;
        }
        c.stop().await;
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn one_and_three_workers_any_tile_size_match_local_render() {
        for (workers, tile) in [(1, 16), (3, 16), (1, 64), (3, 64)] {
            check_cluster_matches_local(workers, tile).await;
        }
    }
}

/// Faults: workers and the coordinator die mid-job; the job still finishes with the same
/// image and no finished tile is rendered twice. (Needs the core.)
mod faults {
    use super::*;

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn killed_worker_lease_expires_and_others_finish() {
        let scene = cornell();
        let dir = tempfile::tempdir().unwrap();
        let c = Coord::start(test_config(&dir.path().join("data")), 0).await;
        let victim = Worker::start(&c.base, 1, dir.path(), "victim");
        let id = upload(&c.base, std::fs::read(&scene).unwrap()).await;
        let j = submit(&c.base, &job(&id, 16)).await;
        wait_for(&c.base, &j.id, 60, |s| {
            s.tasks_leased > 0 || s.state.is_final()
        })
        .await;
        victim.handle.abort();
        let survivor = Worker::start(&c.base, 1, dir.path(), "survivor");
        let done = wait_for(&c.base, &j.id, 120, |s| s.state.is_final()).await;
        assert_eq!(done.state, JobState::Done);
        assert_eq!(
            image(&c.base, &j.id, "exr").await,
            local_exr(&scene, &done.settings)
        );
        survivor.stop().await;
        c.stop().await;
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn restarted_coordinator_resumes_without_rerendering() {
        let scene = cornell();
        let dir = tempfile::tempdir().unwrap();
        let data = dir.path().join("data");
        let mut cfg = test_config(&data);
        cfg.startup_grace = Duration::from_secs(5);
        let c = Coord::start(cfg.clone(), 0).await;
        let port = c.port;
        let ws: Vec<Worker> = (0..2)
            .map(|i| Worker::start(&c.base, 1, dir.path(), &format!("w{i}")))
            .collect();
        let id = upload(&c.base, std::fs::read(&scene).unwrap()).await;
        let j = submit(&c.base, &job(&id, 16)).await;
        wait_for(&c.base, &j.id, 60, |s| s.tasks_done >= 2).await;
        c.stop().await;
        tokio::time::sleep(Duration::from_millis(300)).await;
        let c = Coord::start(cfg, port).await;
        let done = wait_for(&c.base, &j.id, 120, |s| s.state.is_final()).await;
        assert_eq!(done.state, JobState::Done);
        let renders: u64 = ws
            .iter()
            .map(|w| w.stats.renders.load(Ordering::Relaxed))
            .sum();
        let dups: u64 = ws
            .iter()
            .map(|w| w.stats.duplicates.load(Ordering::Relaxed))
            .sum();
        assert_eq!(
            (renders, dups),
            (done.tasks_total, 0),
            "a finished tile was rendered twice"
        );
        assert_eq!(
            image(&c.base, &j.id, "exr").await,
            local_exr(&scene, &done.settings)
        );
        for w in ws {
            w.stop().await;
        }
        c.stop().await;
    }

    /// A finished job whose stored tiles were lost while the coordinator was stopped (a result
    /// file deleted) or damaged (a byte of another changed) is running again after the restart,
    /// and again when an image reads the damaged one; the workers render just those two tiles
    /// again, and the job ends with the frame a local render makes.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn lost_and_damaged_tiles_of_a_finished_job_are_rendered_again() {
        let scene = cornell();
        let dir = tempfile::tempdir().unwrap();
        let data = dir.path().join("data");
        let mut cfg = test_config(&data);
        // Every result a file, so that one can be removed and another changed by hand.
        cfg.result_file_bytes = 0;
        let c = Coord::start(cfg.clone(), 0).await;
        let port = c.port;
        let ws: Vec<Worker> = (0..2)
            .map(|i| Worker::start(&c.base, 1, dir.path(), &format!("w{i}")))
            .collect();
        let id = upload(&c.base, std::fs::read(&scene).unwrap()).await;
        let j = submit(&c.base, &job(&id, 16)).await;
        let done = wait_for(&c.base, &j.id, 120, |s| s.state.is_final()).await;
        assert_eq!(done.state, JobState::Done);
        let want = local_exr(&scene, &done.settings);
        assert_eq!(image(&c.base, &j.id, "exr").await, want);
        c.stop().await;

        let mut files: Vec<PathBuf> = std::fs::read_dir(data.join("results").join(&j.id))
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        files.sort();
        assert_eq!(files.len() as u64, done.tasks_total);
        std::fs::remove_file(&files[3]).unwrap();
        let mut bytes = std::fs::read(&files[7]).unwrap();
        let last = bytes.len() - 1;
        bytes[last] ^= 0x01;
        std::fs::write(&files[7], bytes).unwrap();

        let c = Coord::start(cfg, port).await;
        let after = status(&c.base, &j.id).await;
        assert_eq!(
            (after.state, after.tasks_done),
            (JobState::Running, done.tasks_total - 1),
            "the missing file's task is queued again at start"
        );
        // The frame reads every stored tile: the damaged one is queued too.
        let partial = image(&c.base, &j.id, "exr").await;
        assert_ne!(partial, want);
        let again = wait_for(&c.base, &j.id, 120, |s| {
            s.state.is_final() && s.tasks_done == s.tasks_total
        })
        .await;
        assert_eq!(again.state, JobState::Done);
        assert_eq!(image(&c.base, &j.id, "exr").await, want);
        let renders: u64 = ws
            .iter()
            .map(|w| w.stats.renders.load(Ordering::Relaxed))
            .sum();
        assert_eq!(renders, done.tasks_total + 2, "just the two tiles again");
        for w in ws {
            w.stop().await;
        }
        c.stop().await;
    }

    /// The same with real processes and SIGKILL (slow: RAYTILE_SLOW_TESTS=1, built binaries).
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn sigkilled_worker_process() {
        if std::env::var("RAYTILE_SLOW_TESTS").as_deref() != Ok("1") {
            eprintln!("skipping: set RAYTILE_SLOW_TESTS=1");
            return;
        }
        let scene = cornell();
        let worker_bin = built_binary("raytile-worker");
        let dir = tempfile::tempdir().unwrap();
        let c = Coord::start(test_config(&dir.path().join("data")), 0).await;
        let spawn = |name: &str| {
            Proc(
                std::process::Command::new(&worker_bin)
                    .args(["--coordinator", &c.base, "--threads", "1", "--name", name])
                    .arg("--cache-dir")
                    .arg(dir.path().join(name))
                    .stdout(std::process::Stdio::null())
                    .stderr(std::process::Stdio::null())
                    .spawn()
                    .unwrap(),
            )
        };
        let mut victim = spawn("victim");
        let id = upload(&c.base, std::fs::read(&scene).unwrap()).await;
        let j = submit(&c.base, &job(&id, 16)).await;
        wait_for(&c.base, &j.id, 60, |s| {
            s.tasks_leased > 0 || s.state.is_final()
        })
        .await;
        victim.0.kill().unwrap(); // SIGKILL
        let _ = victim.0.wait();
        let survivor = spawn("survivor");
        let done = wait_for(&c.base, &j.id, 300, |s| s.state.is_final()).await;
        drop(survivor);
        assert_eq!(done.state, JobState::Done);
        assert_eq!(
            image(&c.base, &j.id, "exr").await,
            local_exr(&scene, &done.settings)
        );
        c.stop().await;
    }

    /// A coordinator process killed with SIGKILL mid-job and restarted on the same data
    /// directory: every finished task survives (SQLite commits each result before answering),
    /// no task is rendered twice, and the frame equals the local render. (Slow:
    /// RAYTILE_SLOW_TESTS=1, built binaries.)
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn sigkilled_coordinator_process_loses_no_finished_tile() {
        if std::env::var("RAYTILE_SLOW_TESTS").as_deref() != Ok("1") {
            eprintln!("skipping: set RAYTILE_SLOW_TESTS=1");
            return;
        }
        let scene = cornell();
        let bin = built_binary("raytile-coordinator");
        let dir = tempfile::tempdir().unwrap();
        let port = raytile_tests::free_port();
        let base = format!("http://127.0.0.1:{port}");
        // Leases long enough that no stall on a loaded machine expires one (a task rendered
        // twice would fail the count below); the grace covers the leases out at the kill.
        let start = |log: &str| {
            Proc(
                std::process::Command::new(&bin)
                    .args(["--listen", &format!("127.0.0.1:{port}")])
                    .arg("--data-dir")
                    .arg(dir.path().join("data"))
                    .args(["--lease-timeout", "10", "--startup-grace", "10"])
                    .env_remove("RAYTILE_TOKEN")
                    .stdout(std::process::Stdio::null())
                    .stderr(std::fs::File::create(dir.path().join(log)).unwrap())
                    .spawn()
                    .unwrap(),
            )
        };
        let wait_healthy = || async {
            for _ in 0..300 {
                if reqwest::get(format!("{base}/healthz"))
                    .await
                    .is_ok_and(|r| r.status().is_success())
                {
                    return;
                }
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            let logs: Vec<String> = ["first.log", "second.log"]
                .iter()
                .map(|l| std::fs::read_to_string(dir.path().join(l)).unwrap_or_default())
                .collect();
            panic!("the coordinator process did not come up; its logs:\n{logs:#?}");
        };
        let mut coord = start("first.log");
        wait_healthy().await;
        let ws: Vec<Worker> = (0..2)
            .map(|i| Worker::start(&base, 1, dir.path(), &format!("w{i}")))
            .collect();
        let id = upload(&base, std::fs::read(&scene).unwrap()).await;
        let mut req = job(&id, 16);
        req.overrides.spp = Some(128);
        let j = submit(&base, &req).await;
        let before = wait_for(&base, &j.id, 60, |s| s.tasks_done >= 3).await;
        coord.0.kill().unwrap(); // SIGKILL: no shutdown code runs
        let _ = coord.0.wait();
        let coord = start("second.log");
        wait_healthy().await;
        let resumed = status(&base, &j.id).await;
        assert!(
            !resumed.state.is_final(),
            "the job ended before the kill: make it longer"
        );
        assert!(
            resumed.tasks_done >= before.tasks_done,
            "finished tasks were lost: {} before the kill, {} after",
            before.tasks_done,
            resumed.tasks_done
        );
        let done = wait_for(&base, &j.id, 300, |s| s.state.is_final()).await;
        assert_eq!(done.state, JobState::Done, "{done:?}");
        let renders: u64 = ws
            .iter()
            .map(|w| w.stats.renders.load(Ordering::Relaxed))
            .sum();
        assert_eq!(
            renders, done.tasks_total,
            "a finished task was rendered again"
        );
        assert_eq!(
            image(&base, &j.id, "exr").await,
            local_exr(&scene, &done.settings)
        );
        for w in ws {
            w.stop().await;
        }
        drop(coord);
    }
}

/// API behaviour with synthetic workers: cancel, duplicates, late results, bad requests; the
/// coordinator keeps serving after each. (No core needed, except the hostile-glTF test.)
mod api {
    use super::*;

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn cancel_stops_workers_at_their_next_heartbeat() {
        let dir = tempfile::tempdir().unwrap();
        let c = Coord::start(fake_config(dir.path()), 0).await;
        let j = fake_job(&c.base).await;
        let w = Fake::register(&c.base, "w").await;
        let l = w.lease().await.unwrap();
        assert!(!w.heartbeat(&l).await.cancelled);
        let r = reqwest::Client::new()
            .delete(format!("{}/v1/jobs/{}", c.base, j.id))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200);
        assert!(w.heartbeat(&l).await.cancelled);
        let (code, body) = w.upload(&l).await;
        assert_eq!((code, body["job_finished"].as_bool()), (200, Some(true)));
        assert!(w.lease().await.is_none(), "no tasks of a cancelled job");
        assert_eq!(status(&c.base, &j.id).await.state, JobState::Cancelled);
        c.stop().await;
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn duplicate_and_late_results_are_ignored() {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = fake_config(dir.path());
        cfg.lease_timeout = Duration::from_millis(300);
        let c = Coord::start(cfg, 0).await;
        let j = fake_job(&c.base).await;
        let slow = Fake::register(&c.base, "slow").await;
        let fast = Fake::register(&c.base, "fast").await;
        let l1 = slow.lease().await.unwrap();
        tokio::time::sleep(Duration::from_millis(800)).await;
        let l2 = fast.lease().await.unwrap();
        assert_eq!(
            (l2.job.clone(), l2.task),
            (l1.job.clone(), l1.task),
            "re-queued task first"
        );
        // Expired and taken by another: the first holder's heartbeat stops it.
        assert!(slow.heartbeat(&l1).await.cancelled, "lease expired");
        let (code, body) = fast.upload(&l2).await;
        assert_eq!((code, body["accepted"].as_bool()), (200, Some(true)));
        let (code, body) = slow.upload(&l1).await;
        assert_eq!(
            (code, body["duplicate"].as_bool()),
            (200, Some(true)),
            "late"
        );
        let (code, body) = fast.upload(&l2).await;
        assert_eq!(
            (code, body["duplicate"].as_bool()),
            (200, Some(true)),
            "duplicate"
        );
        // Finish the job; the partial and final image are served.
        while let Some(l) = fast.lease().await {
            fast.upload(&l).await;
        }
        let s = status(&c.base, &j.id).await;
        assert_eq!(
            (s.state, s.tasks_done, s.tasks_total),
            (JobState::Done, 8, 8)
        );
        assert_eq!(&image(&c.base, &j.id, "png").await[1..4], b"PNG");
        let metrics = reqwest::get(format!("{}/metrics", c.base))
            .await
            .unwrap()
            .text()
            .await
            .unwrap();
        assert!(
            metrics.contains("raytile_tiles_duplicate_total 2"),
            "{metrics}"
        );
        assert!(
            metrics.contains("raytile_tiles_expired_total 1"),
            "{metrics}"
        );
        c.stop().await;
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn bad_requests_get_4xx_and_the_coordinator_keeps_serving() {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = test_config(dir.path());
        cfg.token = Some("sesame".into());
        cfg.limits.max_upload_bytes = 64 << 10;
        let c = Coord::start(cfg, 0).await;
        let http = reqwest::Client::new();
        let url = |p: &str| format!("{}{p}", c.base);
        // Token.
        assert_eq!(
            http.get(url("/healthz")).send().await.unwrap().status(),
            200
        );
        assert_eq!(
            http.get(url("/v1/jobs")).send().await.unwrap().status(),
            401
        );
        assert_eq!(
            http.get(url("/v1/jobs"))
                .bearer_auth("wrong")
                .send()
                .await
                .unwrap()
                .status(),
            401
        );
        let ok = |r: reqwest::RequestBuilder| r.bearer_auth("sesame");
        // Unknown ids.
        for p in [
            "/v1/jobs/job-1-x",
            "/v1/jobs/job-1-x/image",
            "/v1/scenes/abc",
            "/v1/nothing",
        ] {
            assert_eq!(
                ok(http.get(url(p))).send().await.unwrap().status(),
                404,
                "{p}"
            );
        }
        let r = ok(http.put(url("/v1/jobs/nope/tasks/0/result")))
            .body(vec![0u8; 10])
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 404);
        let r = ok(http.post(url("/v1/workers/nope/lease")))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 404);
        // Oversize uploads, over a plain connection so that the answer is always read: an
        // HTTP client sending the whole body may see the connection closed under it (the
        // server stops reading at the limit) and report that instead of the answer.
        // Declared too long: refused before any body byte is read.
        let (code, answer) = raw_exchange(
            &c.base,
            b"POST /v1/scenes HTTP/1.1\r\nHost: t\r\nAuthorization: Bearer sesame\r\n\
              Content-Length: 1048576\r\nConnection: close\r\n\r\n",
        )
        .await;
        assert_eq!(code, 413, "{answer}");
        assert!(answer.contains(r#""code":"too_large""#), "{answer}");
        // No declared length: cut off by counting. The client sends one byte more than the
        // limit and stops (no end of the chunk): the server has read all it was sent when it
        // answers, so it closes the connection cleanly rather than resetting it.
        let limit = 64 << 10;
        let mut req = format!(
            "POST /v1/scenes HTTP/1.1\r\nHost: t\r\nAuthorization: Bearer sesame\r\n\
             Transfer-Encoding: chunked\r\nConnection: close\r\n\r\n{:x}\r\n",
            limit + 1
        )
        .into_bytes();
        req.extend(std::iter::repeat_n(b' ', limit + 1));
        let (code, answer) = raw_exchange(&c.base, &req).await;
        assert_eq!(code, 413, "{answer}");
        assert!(answer.contains(r#""code":"too_large""#), "{answer}");
        // Malformed scenes: not a scene at all, and broken glTF.
        let r = ok(http.post(url("/v1/scenes")))
            .body("garbage")
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 422);
        let body: proto::ErrorBody = r.json().await.unwrap();
        assert_eq!(body.error.field.as_deref(), Some("body"));
        let r = ok(http.post(url("/v1/scenes?format=gltf")))
            .body(r#"{"asset": {"version": "2.0"}, "meshes": 7}"#)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 422, "{:?}", r.text().await);
        // Hostile archive.
        let mut b = tar_builder();
        let mut h = tar_header(3);
        h.as_old_mut().name[..14].copy_from_slice(b"../escape.gltf");
        h.set_cksum();
        b.append(&h, &b"{}\n"[..]).unwrap();
        let r = ok(http.post(url("/v1/scenes")))
            .body(b.into_inner().unwrap())
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 422);
        assert_eq!(
            ok(http.get(url("/v1/jobs"))).send().await.unwrap().status(),
            200,
            "still serving"
        );
        c.stop().await;
    }

    /// A worker that cannot render (the scene is refused by its loader) reports failures;
    /// after three the job fails with the worker's message, and the worker carries on.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn failing_worker_fails_the_job_with_its_error() {
        let dir = tempfile::tempdir().unwrap();
        let c = Coord::start(fake_config(&dir.path().join("data")), 0).await;
        let w = Worker::start(&c.base, 1, dir.path(), "w");
        // The coordinator's fake loader accepts it; the worker's real loader does not.
        let scene = upload(&c.base, br#"{"objects": "not a list"}"#.to_vec()).await;
        let req = JobRequest {
            scene,
            overrides: RenderOverrides {
                width: Some(16),
                height: Some(16),
                spp: Some(1),
                ..Default::default()
            },
            ..Default::default()
        };
        let j = submit(&c.base, &req).await;
        let s = wait_for(&c.base, &j.id, 30, |s| s.state.is_final()).await;
        assert_eq!(s.state, JobState::Failed);
        let err = s.error.unwrap_or_default();
        assert!(
            err.contains("failed 3 times") && err.contains("scene"),
            "{err}"
        );
        assert_eq!(w.stats.failures.load(Ordering::Relaxed), 3);
        w.stop().await;
        c.stop().await;
    }

    fn tar_builder() -> tar::Builder<Vec<u8>> {
        tar::Builder::new(Vec::new())
    }

    fn tar_header(size: u64) -> tar::Header {
        let mut h = tar::Header::new_gnu();
        h.set_size(size);
        h.set_mode(0o644);
        h.set_entry_type(tar::EntryType::Regular);
        h
    }

    /// A glTF whose buffer URI points outside its folder is refused with 422 (needs the
    /// core's glTF loader), and the coordinator keeps serving.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn hostile_gltf_uri_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let c = Coord::start(test_config(dir.path()), 0).await;
        let gltf = r#"{"asset": {"version": "2.0"}, "buffers": [{"byteLength": 4, "uri": "../../../../etc/passwd"}],
            "bufferViews": [{"buffer": 0, "byteLength": 4}], "scenes": [{"nodes": []}]}"#;
        let r = reqwest::Client::new()
            .post(format!("{}/v1/scenes?format=gltf", c.base))
            .body(gltf)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 422, "{:?}", r.text().await);
        assert_eq!(
            reqwest::get(format!("{}/healthz", c.base))
                .await
                .unwrap()
                .status(),
            200
        );
        c.stop().await;
    }

    /// With a worker token, a worker holding only it renders a job a user submitted with the
    /// other token; neither token works on the other's endpoints.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_worker_token_renders_and_keeps_users_and_workers_apart() {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = test_config(&dir.path().join("data"));
        cfg.token = Some("users".into());
        cfg.worker_token = Some("workers".into());
        let c = Coord::start(cfg, 0).await;
        let mut wc = Worker::config(&c.base, 1, dir.path(), "w");
        wc.token = Some("workers".into());
        let w = Worker::spawn(wc);
        let user = raytile_proto::client::Client::new(&c.base, Some("users".into())).unwrap();
        let scene = std::fs::read(cornell()).unwrap();
        let scene = user.upload_scene(scene, None, None).await.unwrap().id;
        let mut req = job(&scene, 32);
        req.overrides.spp = Some(2);
        let id = user.create_job(&req).await.unwrap().id;
        let end = tokio::time::Instant::now() + Duration::from_secs(120);
        while user.job(&id).await.unwrap().state != JobState::Done {
            assert!(tokio::time::Instant::now() < end, "timed out");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        assert!(!user.job_image(&id, "png").await.unwrap().is_empty());
        // The worker's token reads no job; the users' registers no worker.
        let worker = raytile_proto::client::Client::new(&c.base, Some("workers".into())).unwrap();
        let e = worker.job(&id).await.unwrap_err();
        assert_eq!(e.status(), Some(reqwest::StatusCode::FORBIDDEN), "{e}");
        let register = proto::RegisterRequest {
            name: "user".into(),
            threads: 1,
            render_version: raytile_core::RENDER_VERSION,
        };
        let e = user.register(&register).await.unwrap_err();
        assert_eq!(e.status(), Some(reqwest::StatusCode::FORBIDDEN), "{e}");
        w.stop().await;
        c.stop().await;
    }

    /// A worker of another renderer version is refused with 409 (its tiles would not match
    /// the frame bit for bit), and no worker is registered.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn worker_of_another_render_version_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let c = Coord::start(test_config(dir.path()), 0).await;
        let http = reqwest::Client::new();
        for version in [None, Some(raytile_core::RENDER_VERSION + 1)] {
            let mut body = serde_json::json!({"name": "stale", "threads": 1});
            if let Some(v) = version {
                body["render_version"] = v.into();
            }
            let r = http
                .post(format!("{}/v1/workers", c.base))
                .json(&body)
                .send()
                .await
                .unwrap();
            assert_eq!(r.status(), 409, "{version:?}");
            let text = r.text().await.unwrap();
            assert!(text.contains("renderer version"), "{text}");
        }
        let workers: proto::WorkerList = http
            .get(format!("{}/v1/workers", c.base))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        assert!(workers.workers.is_empty());
        Fake::register(&c.base, "current").await;
        c.stop().await;
    }
}

/// Store faults for real: the coordinator's data directory on a small tmpfs that fills up
/// mid-job, then is freed. Needs root with CAP_SYS_ADMIN (mount); under `CI=true` a machine
/// where that fails fails the test rather than skipping it. (Needs the core.)
mod store_faults {
    use super::*;

    /// A tmpfs mounted on a folder, unmounted when dropped (also when a test fails).
    struct Tmpfs(PathBuf);

    impl Tmpfs {
        /// Mounts a tmpfs of `size` (`8m`) on `dir`; `Err` says why it could not.
        fn mount(dir: &std::path::Path, size: &str) -> Result<Tmpfs, String> {
            std::fs::create_dir_all(dir).map_err(|e| e.to_string())?;
            let out = std::process::Command::new("mount")
                .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"])
                .arg(dir)
                .output()
                .map_err(|e| format!("running mount: {e}"))?;
            if !out.status.success() {
                return Err(String::from_utf8_lossy(&out.stderr).trim().to_string());
            }
            Ok(Tmpfs(dir.to_path_buf()))
        }

        /// Writes a file until the file system is full; returns its path.
        fn fill(&self) -> PathBuf {
            use std::io::Write;
            let p = self.0.join("filler");
            let mut f = std::fs::File::create(&p).unwrap();
            let chunk = vec![0xa5u8; 4096];
            loop {
                match f.write_all(&chunk) {
                    Ok(()) => {}
                    Err(e) if e.raw_os_error() == Some(28) => break, // ENOSPC
                    Err(e) => panic!("filling {}: {e}", p.display()),
                }
            }
            let _ = f.sync_all();
            p
        }
    }

    impl Drop for Tmpfs {
        fn drop(&mut self) {
            let _ = std::process::Command::new("umount")
                .arg("-l")
                .arg(&self.0)
                .status();
        }
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_full_disk_mid_job_loses_no_tile_and_renders_none_twice() {
        let scene = cornell();
        let dir = tempfile::tempdir().unwrap();
        let data = dir.path().join("data");
        let fs = match Tmpfs::mount(&data, "16m") {
            Ok(fs) => fs,
            Err(e) if !std::env::var("CI").is_ok_and(|v| v == "true" || v == "1") => {
                eprintln!(
                    "skipping: cannot mount a tmpfs here ({e}); CI=true makes this a failure"
                );
                return;
            }
            Err(e) => panic!("cannot mount a tmpfs for the store-fault test: {e}"),
        };
        let mut cfg = test_config(&data);
        // Leases outlast the fault, so that no task is leased twice because of it.
        cfg.lease_timeout = Duration::from_secs(30);
        let c = Coord::start(cfg, 0).await;
        let id = upload(&c.base, std::fs::read(&scene).unwrap()).await;
        let mut req = job(&id, 16);
        req.overrides.spp = Some(256);
        req.overrides.passes = Some(8);
        let j = submit(&c.base, &req).await;
        let ws: Vec<Worker> = (0..2)
            .map(|i| Worker::start(&c.base, 1, dir.path(), &format!("w{i}")))
            .collect();
        wait_for(&c.base, &j.id, 60, |s| {
            s.tasks_done >= 2 || s.state.is_final()
        })
        .await;
        let filler = fs.fill();
        let during = status(&c.base, &j.id).await;
        assert!(
            !during.state.is_final(),
            "the job ended before the disk filled"
        );
        // The fault is real: a new job cannot be stored, and the answer says to retry.
        let r = reqwest::Client::new()
            .post(format!("{}/v1/jobs", c.base))
            .json(&job(&id, 16))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 503);
        let body: proto::ErrorBody = r.json().await.unwrap();
        assert!(body.error.retryable, "{body:?}");
        // Workers keep trying for a while: results, leases and expiry all fail to store.
        tokio::time::sleep(Duration::from_secs(3)).await;
        let stuck = status(&c.base, &j.id).await;
        assert!(
            stuck.tasks_done <= during.tasks_done + 2,
            "results were accepted with the disk full: {} → {}",
            during.tasks_done,
            stuck.tasks_done
        );
        std::fs::remove_file(&filler).unwrap();
        let done = wait_for(&c.base, &j.id, 300, |s| s.state.is_final()).await;
        assert_eq!(done.state, JobState::Done, "{done:?}");
        let renders: u64 = ws
            .iter()
            .map(|w| w.stats.renders.load(Ordering::Relaxed))
            .sum();
        let (accepted, dups): (u64, u64) = ws.iter().fold((0, 0), |(a, d), w| {
            (
                a + w.stats.accepted.load(Ordering::Relaxed),
                d + w.stats.duplicates.load(Ordering::Relaxed),
            )
        });
        assert_eq!(
            (renders, accepted, dups),
            (done.tasks_total, done.tasks_total, 0),
            "every task rendered and accepted exactly once"
        );
        assert_eq!(
            image(&c.base, &j.id, "exr").await,
            local_exr(&scene, &done.settings),
            "the frame differs from the local render"
        );
        for w in ws {
            w.stop().await;
        }
        c.stop().await;
        drop(fs);
    }
}

/// Built scenes are kept between jobs: a second job on a scene does not build it again.
/// (Needs the core.)
mod scene_cache {
    use super::*;

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_second_job_on_a_scene_reuses_the_built_scene() {
        let scene = PathBuf::from(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../scenes/cornell-box.json"
        ));
        let dir = tempfile::tempdir().unwrap();
        let c = Coord::start(test_config(&dir.path().join("data")), 0).await;
        // Two workers sharing one cache, as `raytile cluster` runs them.
        let scenes = Arc::new(raytile_worker::SceneCache::default());
        let ws: Vec<Worker> = (0..2)
            .map(|i| Worker::start_with(&c.base, 1, dir.path(), &format!("w{i}"), scenes.clone()))
            .collect();
        let id = upload(&c.base, std::fs::read(&scene).unwrap()).await;
        let builds = || -> u64 {
            ws.iter()
                .map(|w| w.stats.scene_builds.load(Ordering::Relaxed))
                .sum()
        };
        for (n, seed) in [(1, 1), (2, 2)] {
            let mut req = job(&id, 32);
            req.overrides.seed = Some(seed);
            req.overrides.spp = Some(2);
            let j = submit(&c.base, &req).await;
            let done = wait_for(&c.base, &j.id, 120, |s| s.state.is_final()).await;
            assert_eq!(done.state, JobState::Done, "job {n}: {:?}", done.error);
            assert_eq!(
                image(&c.base, &j.id, "exr").await,
                local_exr(&scene, &done.settings),
                "job {n}"
            );
            assert_eq!(builds(), 1, "after job {n}: the scene is built once");
        }
        assert_eq!(scenes.builds(), 1);
        assert!(scenes.memory_bytes() > 0);
        for w in ws {
            w.stop().await;
        }
        c.stop().await;
    }
}

/// Cancel: a worker rendering a long tile of a cancelled job stops within about a second (its
/// next heartbeat, then the render's next look at its cancel flag) and takes the next job.
/// (Needs the core.)
mod cancel {
    use super::*;

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_cancel_frees_the_worker_within_a_second() {
        let scene = cornell();
        let dir = tempfile::tempdir().unwrap();
        let c = Coord::start(test_config(&dir.path().join("data")), 0).await;
        let w = Worker::start(&c.base, 1, dir.path(), "w");
        let id = upload(&c.base, std::fs::read(&scene).unwrap()).await;
        // One 64×64 tile of 2^20 samples per pixel: hours of work unless cancelled.
        let mut long = job(&id, 64);
        long.overrides.spp = Some(1 << 20);
        long.overrides.passes = Some(1);
        let j = submit(&c.base, &long).await;
        wait_for(&c.base, &j.id, 60, |s| s.tasks_leased == 1).await;
        tokio::time::sleep(Duration::from_millis(500)).await;
        let r = reqwest::Client::new()
            .delete(format!("{}/v1/jobs/{}", c.base, j.id))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200);
        let cancelled = tokio::time::Instant::now();
        while w.stats.cancelled.load(Ordering::Relaxed) == 0 {
            assert!(
                cancelled.elapsed() < Duration::from_secs(10),
                "the worker is still rendering the cancelled tile"
            );
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        let took = cancelled.elapsed();
        assert!(took < Duration::from_millis(1500), "freed after {took:?}");
        assert_eq!(w.stats.renders.load(Ordering::Relaxed), 0);
        // Free: the next job is rendered.
        let next = submit(&c.base, &job(&id, 32)).await;
        let done = wait_for(&c.base, &next.id, 120, |s| s.state.is_final()).await;
        assert_eq!(done.state, JobState::Done);
        eprintln!("the worker stopped rendering {took:?} after the cancel");
        w.stop().await;
        c.stop().await;
    }
}

/// A job's own environment (`environment`: a map packed with the scene, or a colour): the
/// farm's image equals the local render bit for bit, and a map outside the scene's folder or
/// missing from it, or an environment too bright once scaled, is refused with 422 naming the
/// field. (Needs the core.)
mod environment {
    use super::*;
    use raytile_core::scene::files::SceneFiles;
    use raytile_proto::EnvironmentChoice;

    /// A scene without lights of its own (a diffuse ball on a floor), open to the sky.
    const SCENE: &str = r#"{
        "camera": {"position": [0, 1, 4], "look_at": [0, 0.5, 0], "fov": 50},
        "materials": {"grey": {"type": "diffuse", "albedo": [0.6, 0.6, 0.6]}},
        "objects": [
            {"shape": {"type": "sphere", "center": [0, 0.5, 0], "radius": 0.5}, "material": "grey"},
            {"shape": {"type": "disk", "center": [0, 0, 0], "normal": [0, 1, 0], "radius": 3}, "material": "grey"}
        ]
    }"#;

    /// The EXR of `s` rendered locally, the map read from `dir`.
    fn local(dir: &std::path::Path, s: &RenderSettings) -> Vec<u8> {
        let desc = raytile_core::load_scene(&dir.join("ball.json")).unwrap();
        let built = raytile_core::Scene::build(&desc).unwrap();
        let job =
            raytile_core::RenderJob::with_files(&built, s, &SceneFiles::trusted(), dir).unwrap();
        let film = raytile_core::render(&built, &job, &());
        raytile_coordinator::compose::encode(&film, ImageFormat::Exr, &Default::default(), s)
            .unwrap()
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_jobs_map_and_colour_render_as_locally_on_two_workers() {
        let dir = tempfile::tempdir().unwrap();
        let scene_dir = dir.path().join("scene");
        std::fs::create_dir(&scene_dir).unwrap();
        std::fs::write(scene_dir.join("ball.json"), SCENE).unwrap();
        let studio = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/studio.hdr");
        std::fs::copy(studio, scene_dir.join("studio.hdr")).unwrap();
        // The scene and its map in one archive, as `raytile submit --environment` packs them.
        let mut tar = tar::Builder::new(Vec::new());
        tar.append_path_with_name(scene_dir.join("ball.json"), "ball.json")
            .unwrap();
        tar.append_path_with_name(scene_dir.join("studio.hdr"), "studio.hdr")
            .unwrap();
        let bytes = tar.into_inner().unwrap();

        let c = Coord::start(test_config(&dir.path().join("data")), 0).await;
        let ws: Vec<Worker> = (0..2)
            .map(|i| Worker::start(&c.base, 1, dir.path(), &format!("w{i}")))
            .collect();
        let r = reqwest::Client::new()
            .post(format!("{}/v1/scenes?format=tar&entry=ball.json", c.base))
            .body(bytes)
            .send()
            .await
            .unwrap();
        assert!(r.status().is_success(), "{:?}", r.text().await);
        let id = r.json::<proto::SceneCreated>().await.unwrap().id;
        let choices = [
            (
                EnvironmentChoice::Map("studio.hdr".into()),
                Some(90.0),
                Some(1.5),
            ),
            (
                EnvironmentChoice::Constant([0.2, 0.3, 0.4]),
                None,
                Some(2.0),
            ),
        ];
        let mut images = Vec::new();
        for (env, rotation, strength) in choices {
            let mut req = job(&id, 16);
            req.overrides.environment = Some(env.clone());
            req.overrides.environment_rotation = rotation;
            req.overrides.environment_strength = strength;
            let j = submit(&c.base, &req).await;
            let done = wait_for(&c.base, &j.id, 120, |s| s.state.is_final()).await;
            assert_eq!(done.state, JobState::Done, "{env}: {:?}", done.error);
            assert_eq!(done.settings.environment, Some(env.clone()));
            let got = image(&c.base, &j.id, "exr").await;
            assert!(
                got == local(&scene_dir, &done.settings),
                "{env}: the farm's EXR differs from the local render"
            );
            images.push(got);
        }
        assert_ne!(
            images[0], images[1],
            "the job's environment lights the scene"
        );
        // A map the scene's folder does not hold, or one outside it, and a colour or a map
        // that the strength takes above the largest radiance (1e30): 422 naming the field at
        // submission, not a failure on every worker.
        let map = |m: &str| EnvironmentChoice::Map(m.into());
        let refused = [
            (map("sky.hdr"), None, "environment", ""),
            (map("../studio.hdr"), None, "environment", ""),
            (map("/etc/sky.hdr"), None, "environment", ""),
            (
                EnvironmentChoice::Constant([1.0; 3]),
                Some(1e38),
                "environment_strength",
                "1e30",
            ),
            (map("studio.hdr"), Some(1e38), "environment", "1e30"),
        ];
        for (env, strength, field, needle) in refused {
            let mut req = job(&id, 16);
            req.overrides.environment = Some(env.clone());
            req.overrides.environment_strength = strength;
            let r = reqwest::Client::new()
                .post(format!("{}/v1/jobs", c.base))
                .json(&req)
                .send()
                .await
                .unwrap();
            assert_eq!(r.status(), 422, "{env}");
            let body: serde_json::Value = r.json().await.unwrap();
            assert_eq!(body["error"]["field"], field, "{env}: {body}");
            let message = body["error"]["message"].as_str().unwrap_or_default();
            assert!(message.contains(needle), "{env}: {body}");
        }
        for w in ws {
            w.stop().await;
        }
        c.stop().await;
    }
}

/// A farm behind a TLS proxy, as docs/farm.md tells an operator to set one up on a network it
/// does not trust: `raytile submit` and a worker process reach the coordinator over https://,
/// trusting a private CA through `SSL_CERT_FILE`, and the frame is the local render's; without
/// the CA the client refuses the proxy's certificate. (Slow: RAYTILE_SLOW_TESTS=1, built
/// binaries.)
mod tls {
    use super::support::*;
    use super::*;
    use std::process::{Command, Stdio};
    use tokio_rustls::rustls;

    fn fixture(name: &str) -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("fixtures/tls")
            .join(name)
    }

    /// A TLS-terminating relay on 127.0.0.1 to the plain port `to`, with the fixture's
    /// certificate for `localhost`: its port.
    async fn tls_proxy(to: u16) -> u16 {
        use rustls::pki_types::{pem::PemObject, CertificateDer, PrivateKeyDer};
        let certs: Vec<CertificateDer> = CertificateDer::pem_file_iter(fixture("cert.pem"))
            .unwrap()
            .collect::<Result<_, _>>()
            .unwrap();
        let key = PrivateKeyDer::from_pem_file(fixture("key.pem")).unwrap();
        // The crate's one provider (ring, as reqwest's rustls has it).
        let config = rustls::ServerConfig::builder()
            .with_no_client_auth()
            .with_single_cert(certs, key)
            .unwrap();
        let acceptor = tokio_rustls::TlsAcceptor::from(Arc::new(config));
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let port = listener.local_addr().unwrap().port();
        tokio::spawn(async move {
            while let Ok((tcp, _)) = listener.accept().await {
                let acceptor = acceptor.clone();
                tokio::spawn(async move {
                    let Ok(mut tls) = acceptor.accept(tcp).await else {
                        return;
                    };
                    if let Ok(mut up) = tokio::net::TcpStream::connect(("127.0.0.1", to)).await {
                        let _ = tokio::io::copy_bidirectional(&mut tls, &mut up).await;
                    }
                });
            }
        });
        port
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_farm_behind_a_tls_proxy_renders_the_local_image() {
        if std::env::var("RAYTILE_SLOW_TESTS").as_deref() != Ok("1") {
            eprintln!("skipping: set RAYTILE_SLOW_TESTS=1");
            return;
        }
        let scene = cornell();
        let dir = tempfile::tempdir().unwrap();
        let c = Coord::start(test_config(&dir.path().join("data")), 0).await;
        let https = format!("https://localhost:{}", tls_proxy(c.port).await);
        // The children's environment: no proxy of the runner's between them and the relay,
        // and only the CA store a child is given.
        let clean = |cmd: &mut Command| {
            for v in ["HTTPS_PROXY", "https_proxy", "ALL_PROXY", "all_proxy"] {
                cmd.env_remove(v);
            }
            cmd.env("NO_PROXY", "localhost,127.0.0.1")
                .env_remove("SSL_CERT_FILE")
                .env_remove("SSL_CERT_DIR");
        };
        let worker_log = dir.path().join("worker.log");
        let mut worker = Command::new(built_binary("raytile-worker"));
        worker
            .args(["--coordinator", &https, "--threads", "1", "--name", "tls"])
            .arg("--cache-dir")
            .arg(dir.path().join("worker"))
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&worker_log).unwrap());
        clean(&mut worker);
        let _worker = Proc(
            worker
                .env("SSL_CERT_FILE", fixture("ca.pem"))
                .spawn()
                .unwrap(),
        );
        // `raytile submit … -o OUT`, given two minutes: its exit status and stderr.
        let submit = |out: PathBuf, ca: Option<PathBuf>| {
            let mut cmd = Command::new(built_binary("raytile"));
            cmd.arg("submit")
                .arg(&scene)
                .args(["--coordinator", &https, "--spp", "4", "--width", "32"])
                .args(["--height", "24", "--tile-size", "16", "-o"])
                .arg(out)
                .stdout(Stdio::null())
                .stderr(Stdio::piped());
            clean(&mut cmd);
            if let Some(ca) = ca {
                cmd.env("SSL_CERT_FILE", ca);
            }
            let log = worker_log.clone();
            tokio::task::spawn_blocking(move || {
                let mut child = Proc(cmd.spawn().unwrap());
                let deadline = std::time::Instant::now() + Duration::from_secs(120);
                while child.0.try_wait().unwrap().is_none() {
                    if std::time::Instant::now() > deadline {
                        let worker = std::fs::read_to_string(&log).unwrap_or_default();
                        panic!("raytile submit still waits after 2 minutes; the worker:\n{worker}");
                    }
                    std::thread::sleep(Duration::from_millis(50));
                }
                let mut stderr = String::new();
                std::io::Read::read_to_string(child.0.stderr.as_mut().unwrap(), &mut stderr)
                    .unwrap();
                (child.0.wait().unwrap().success(), stderr)
            })
        };
        // Without the private CA: the proxy's certificate is refused, nothing is submitted.
        let (ok, stderr) = submit(dir.path().join("no.exr"), None).await.unwrap();
        assert!(!ok && stderr.contains("certificate"), "{stderr}");
        // With it: submitted, rendered by the worker over https, downloaded.
        let out = dir.path().join("frame.exr");
        let (ok, stderr) = submit(out.clone(), Some(fixture("ca.pem"))).await.unwrap();
        assert!(ok, "{stderr}");
        let jobs = raytile_proto::client::Client::new(&c.base, None)
            .unwrap()
            .jobs()
            .await
            .unwrap();
        assert_eq!(jobs.jobs.len(), 1, "the refused submission made no job");
        let job = &jobs.jobs[0];
        assert_eq!(job.state, JobState::Done);
        assert_eq!(
            std::fs::read(&out).unwrap(),
            local_exr(&scene, &job.settings)
        );
        c.stop().await;
    }
}
