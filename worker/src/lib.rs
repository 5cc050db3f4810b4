//! The raytile worker: registers with a coordinator, long-polls for tile passes, renders them
//! with the core on its own rayon pool (inside `spawn_blocking`, never on the async threads),
//! heartbeats while rendering, and uploads the binary result.
//!
//! Built scenes are kept between jobs in a [`SceneCache`] (by scene id, bounded in bytes), so a
//! second job on a scene starts rendering at once.
//!
//! [`run`] takes a shutdown future, so tests run workers in-process; dropping or aborting the
//! task that runs it is how tests "kill" a worker.

mod cache;
mod files;

pub use cache::{SceneCache, DEFAULT_BUDGET as DEFAULT_SCENE_CACHE};
pub use files::DEFAULT_CACHE_MAX_BYTES;

use anyhow::{anyhow, Context};
use raytile_core::{RenderJob, Scene, TileAccum};
use raytile_proto::client::{Client, ClientError, StatusCode};
use raytile_proto::{self as proto, scene as pkg};
use std::collections::HashMap;
use std::future::Future;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Counters a worker keeps, shared with whoever started it (tests count renders with them).
#[derive(Debug, Default)]
pub struct Stats {
    /// Tile passes rendered to the end.
    pub renders: AtomicU64,
    /// Results the coordinator accepted.
    pub accepted: AtomicU64,
    /// Results the coordinator called duplicate or late.
    pub duplicates: AtomicU64,
    /// Failures reported.
    pub failures: AtomicU64,
    /// Scenes this worker loaded and built (a scene already in the cache is not built again).
    pub scene_builds: AtomicU64,
    /// Tile passes stopped part-way: the job was cancelled, or the lease was lost.
    pub cancelled: AtomicU64,
}

/// The most render threads a worker (or `raytile render`) starts: far more than any machine
/// has cores, and few enough that a mistyped count is an error rather than an hour of
/// spawning threads.
pub const MAX_THREADS: usize = 1024;

/// How a worker runs.
#[derive(Clone, Debug)]
pub struct Config {
    /// Base URL of the coordinator, e.g. `http://127.0.0.1:8080`.
    pub coordinator: String,
    /// Bearer token.
    pub token: Option<String>,
    /// Render threads; 0 means every core; at most [`MAX_THREADS`].
    pub threads: usize,
    /// Name shown in `GET /v1/workers`.
    pub name: String,
    /// Where downloaded scenes are kept, by id.
    pub cache_dir: PathBuf,
    /// Most bytes the scenes in `cache_dir` may hold (the least recently used go first; see
    /// [`files::trim`]); `None`: no bound.
    pub cache_max_bytes: Option<u64>,
    /// Built scenes kept between jobs; workers in one process may share one.
    pub scene_cache: Arc<SceneCache>,
    /// Bounds on loading a leased scene, which reads only files in its own folder.
    pub scene_limits: SceneLoadLimits,
    /// How long one lease request waits for work.
    pub long_poll: Duration,
    /// Longest pause between retries when the coordinator is unreachable.
    pub max_backoff: Duration,
    /// Counters.
    pub stats: Arc<Stats>,
}

impl Config {
    /// Defaults for a coordinator URL.
    pub fn new(coordinator: impl Into<String>) -> Config {
        Config {
            coordinator: coordinator.into(),
            token: None,
            threads: 0,
            name: default_name(),
            cache_dir: std::env::temp_dir().join("raytile-worker-cache"),
            cache_max_bytes: Some(files::DEFAULT_CACHE_MAX_BYTES),
            scene_cache: Arc::new(SceneCache::default()),
            scene_limits: SceneLoadLimits::default(),
            long_poll: Duration::from_secs(20),
            max_backoff: Duration::from_secs(30),
            stats: Arc::new(Stats::default()),
        }
    }
}

/// Bounds on loading a leased scene. A scene comes from the network: every file it names is
/// read through the core's confined resolver, inside the scene file's own folder.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SceneLoadLimits {
    /// Largest file a scene may name (and the scene file itself), in bytes.
    pub max_file_bytes: u64,
    /// Most bytes a scene may read, all its files together.
    pub max_scene_bytes: u64,
    /// Most memory loading a scene may allocate for decoded data (texels, vertices), in bytes.
    pub max_memory: u64,
}

impl Default for SceneLoadLimits {
    fn default() -> Self {
        use raytile_core::scene::files;
        SceneLoadLimits {
            max_file_bytes: files::DEFAULT_FILE_CAP,
            max_scene_bytes: files::DEFAULT_SCENE_BUDGET,
            max_memory: files::DEFAULT_MEMORY_LIMIT,
        }
    }
}

/// The host name, or `worker`.
pub fn default_name() -> String {
    std::env::var("HOSTNAME")
        .ok()
        .filter(|s| !s.is_empty())
        .or_else(|| {
            std::fs::read_to_string("/etc/hostname")
                .ok()
                .map(|s| s.trim().to_string())
        })
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "worker".into())
}

/// Exponential backoff, capped, with ±25 % jitter.
struct Backoff {
    next: Duration,
    max: Duration,
}

impl Backoff {
    fn new(max: Duration) -> Backoff {
        Backoff {
            next: Duration::from_millis(100),
            max,
        }
    }
    fn reset(&mut self) {
        self.next = Duration::from_millis(100);
    }
    fn step(&mut self) -> Duration {
        let base = self.next.min(self.max);
        self.next = (self.next * 2).min(self.max);
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.subsec_nanos())
            .unwrap_or(0);
        // Cheap jitter: the clock's nanoseconds are random enough to spread reconnects.
        let frac = 0.75 + (nanos % 1000) as f64 / 2000.0;
        base.mul_f64(frac)
    }
}

enum Flow {
    Continue,
    Exit,
}

/// Runs the worker until `shutdown` completes. A task being rendered when it does is handed
/// back to the coordinator. Returns an error only for bad configuration.
pub async fn run(config: Config, shutdown: impl Future<Output = ()> + Send) -> anyhow::Result<()> {
    anyhow::ensure!(
        config.threads <= MAX_THREADS,
        "render threads: at most {MAX_THREADS}, not {}",
        config.threads
    );
    let threads = if config.threads == 0 {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    } else {
        config.threads
    };
    let pool = Arc::new(
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("raytile-render-{i}"))
            .build()
            .context("creating the render thread pool")?,
    );
    files::prepare_cache(&config.cache_dir)?;
    if let Some(max) = config.cache_max_bytes {
        let t = files::trim(&config.cache_dir, max, None);
        tracing::info!(
            "disk cache {}: {} MiB of scenes (bound {} MiB)",
            config.cache_dir.display(),
            t.held >> 20,
            max >> 20
        );
    }
    if let Some(problem) = raytile_proto::client::cert_store_problem() {
        tracing::warn!("{problem}: https:// coordinators are checked against the public CAs only");
    }
    let http = raytile_proto::client::reqwest::Client::builder()
        .connect_timeout(Duration::from_secs(5))
        // A partition leaves established connections silent, not closed: no read for
        // longer than a long poll plus slack means the coordinator is gone for now, and
        // the request fails into the usual retry with backoff instead of hanging.
        .read_timeout(config.long_poll + Duration::from_secs(30))
        .tcp_keepalive(Duration::from_secs(15))
        .pool_idle_timeout(raytile_proto::client::POOL_IDLE)
        .build()
        .context("creating the HTTP client")?;
    let client = Client::with_http(http, &config.coordinator, config.token.clone())?;
    let mut w = Worker {
        cfg: config,
        client,
        pool,
        threads,
        worker_id: None,
        heartbeat: Duration::from_secs(5),
        jobs: HashMap::new(),
        backoff: Backoff::new(Duration::from_secs(30)),
        uploads: tokio::task::JoinSet::new(),
    };
    w.backoff = Backoff::new(w.cfg.max_backoff);
    tokio::pin!(shutdown);
    loop {
        let next = tokio::select! {
            biased;
            _ = &mut shutdown => None,
            f = w.step_until_task() => Some(f),
        };
        let flow = match next {
            None => Flow::Exit,
            Some(Some(lease)) => w.process(lease, &mut shutdown).await,
            Some(None) => Flow::Continue,
        };
        if let Flow::Exit = flow {
            if !w.uploads.is_empty() {
                tracing::info!("worker stopping: delivering the last result first");
                let drain = async { while w.uploads.join_next().await.is_some() {} };
                if tokio::time::timeout(Duration::from_secs(30), drain)
                    .await
                    .is_err()
                {
                    tracing::warn!("the last result could not be delivered; its lease will expire");
                }
            }
            tracing::info!("worker stopping");
            return Ok(());
        }
    }
}

struct Worker {
    cfg: Config,
    client: Client,
    pool: Arc<rayon::ThreadPool>,
    threads: usize,
    worker_id: Option<String>,
    heartbeat: Duration,
    /// What each recent job adds to its scene (camera, lights), by job id.
    jobs: HashMap<String, Arc<RenderJob>>,
    backoff: Backoff,
    /// The result being uploaded while the next task renders (at most one). Dropping the
    /// worker aborts it, as killing the process would.
    uploads: tokio::task::JoinSet<()>,
}

fn panic_message(p: Box<dyn std::any::Any + Send>) -> String {
    if let Some(s) = p.downcast_ref::<&str>() {
        s.to_string()
    } else if let Some(s) = p.downcast_ref::<String>() {
        s.clone()
    } else {
        "panic".into()
    }
}

impl Worker {
    async fn pause(&mut self, why: &str) {
        let d = self.backoff.step();
        tracing::warn!("{why}; retrying in {:.1} s", d.as_secs_f64());
        tokio::time::sleep(d).await;
    }

    /// Registers if needed and asks for one task (one long poll). Cancel-safe.
    async fn step_until_task(&mut self) -> Option<proto::Lease> {
        let Some(id) = self.worker_id.clone() else {
            let body = proto::RegisterRequest {
                name: self.cfg.name.clone(),
                threads: self.threads as u32,
                render_version: raytile_core::RENDER_VERSION,
            };
            match self.client.register(&body).await {
                Ok(reg) => {
                    tracing::info!(worker = %reg.worker_id, "registered");
                    self.heartbeat = Duration::from_millis(
                        reg.heartbeat_ms.min(reg.lease_timeout_ms / 3).max(10),
                    );
                    self.worker_id = Some(reg.worker_id);
                    self.backoff.reset();
                }
                Err(e) => self.pause(&format!("cannot register: {e}")).await,
            }
            return None;
        };
        match self.client.lease(&id, self.cfg.long_poll).await {
            Ok(lease) => {
                self.backoff.reset();
                lease
            }
            Err(e) if e.status() == Some(StatusCode::NOT_FOUND) => {
                // The coordinator forgot us (new data directory): register again.
                self.worker_id = None;
                None
            }
            Err(e) => {
                self.pause(&format!("lease request failed: {e}")).await;
                None
            }
        }
    }

    async fn report_failure(&mut self, lease: &proto::Lease, error: String) {
        tracing::warn!(job = %lease.job, task = lease.task, "task failed: {error}");
        self.cfg.stats.failures.fetch_add(1, Ordering::Relaxed);
        let error = without_local_paths(&error, &self.cfg.cache_dir, &lease.scene);
        let body = proto::FailureReport { error };
        for _ in 0..5 {
            match self.client.report_failure(&lease.lease_id, &body).await {
                Ok(()) => return,
                // Nothing was recorded: worth another try (else the lease expires).
                Err(e) if e.status() == Some(StatusCode::SERVICE_UNAVAILABLE) => {
                    self.pause(&format!("cannot report failure: {e}")).await
                }
                Err(e) if e.status().is_some() => return,
                Err(e) => self.pause(&format!("cannot report failure: {e}")).await,
            }
        }
    }

    async fn release(&self, lease: &proto::Lease) {
        let r = self
            .client
            .release(&lease.lease_id, Duration::from_secs(3))
            .await;
        if let Err(e) = r {
            tracing::warn!("could not hand the lease back ({e}); it will expire");
        }
    }

    /// Makes sure the scene is in the cache (downloaded and verified) and returns the scene
    /// file to load, with the folder held in use (no worker sharing the cache removes it
    /// while the guard lives; `None` where it could not be held).
    async fn scene_file(
        &mut self,
        lease: &proto::Lease,
    ) -> Result<(PathBuf, Option<files::InUse>), anyhow::Error> {
        if !pkg::is_scene_id(&lease.scene) {
            return Err(anyhow!("bad scene id '{}'", lease.scene));
        }
        let dir = self.cfg.cache_dir.join(&lease.scene);
        let entry = dir.join("root").join(&lease.scene_entry);
        if let Some(held) = cached(&dir, lease).await? {
            return Ok((entry, Some(held)));
        }
        // Fetched and unpacked by one process sharing the cache at a time (see the `files`
        // module): the others wait, and use the scene once it is installed. The lock is held
        // while the scene is fetched and unpacked, not while anyone checks it.
        let mut waited = None;
        let mut checked = false;
        let installing = loop {
            let d = dir.clone();
            let (lock, installed) = tokio::task::spawn_blocking(move || {
                let lock = files::try_install_lock(&d);
                (lock, d.join("ok").exists())
            })
            .await?;
            // Installed meanwhile by another (before this lock, or while this one waited).
            if installed && !checked {
                drop(lock);
                checked = true;
                if let Some(held) = cached(&dir, lease).await? {
                    return Ok((entry, Some(held)));
                }
                continue;
            }
            if let Some(l) = lock {
                break Some(l);
            }
            let since = *waited.get_or_insert_with(|| {
                tracing::info!(scene = %lease.scene, "waiting for another worker sharing the cache to fetch the scene");
                std::time::Instant::now()
            });
            if since.elapsed() > files::INSTALL_WAIT {
                tracing::warn!(scene = %lease.scene, "another worker sharing the cache has been fetching the scene for {} minutes: fetching it here too", files::INSTALL_WAIT.as_secs() / 60);
                break None;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        };
        // A coordinator out of reach is waited for; a download that keeps breaking (a proxy
        // that cuts large answers) fails the task after a few tries, as a lease renewed
        // meanwhile would otherwise hold the task for ever.
        let mut broken = 0;
        let bytes = loop {
            match self.client.download_scene(&lease.scene).await {
                Ok(b) => break b,
                Err(e) if e.status().is_some() => return Err(anyhow!("scene download: {e}")),
                Err(e) if matches!(e, ClientError::Body(_)) && broken >= 4 => {
                    return Err(anyhow!("scene download broke off 5 times: {e}"))
                }
                Err(e) => {
                    broken += usize::from(matches!(e, ClientError::Body(_)));
                    self.pause(&format!("scene download: {e}")).await
                }
            }
        };
        let sha = pkg::sha256_hex(&bytes);
        if sha != lease.scene_sha256 {
            return Err(anyhow!(
                "scene {} download has sha256 {sha}, expected {}",
                lease.scene,
                lease.scene_sha256
            ));
        }
        let format = pkg::SceneFormat::from_name(&lease.scene_format)
            .ok_or_else(|| anyhow!("unknown scene format '{}'", lease.scene_format))?;
        let scene_entry = lease.scene_entry.clone();
        let (d, cache, max) = (
            dir.clone(),
            self.cfg.cache_dir.clone(),
            self.cfg.cache_max_bytes,
        );
        let held = tokio::task::spawn_blocking(move || {
            // The install lock lives as long as the unpack, even if the lease ends meanwhile.
            let installing = installing;
            let mut installed = files::install(&d, &bytes, format, &scene_entry);
            // A full disk: the scenes not used lately make room, and the unpack is tried once
            // more (a full disk is this machine's trouble, not the scene's).
            if installed.as_ref().is_err_and(files::disk_full) {
                let t = files::trim(&cache, 0, None);
                if t.removed > 0 {
                    tracing::warn!(
                        "the cache disk is full: removed {} scenes ({} MiB) no worker was using lately",
                        t.removed,
                        t.freed >> 20
                    );
                    installed = files::install(&d, &bytes, format, &scene_entry);
                }
            }
            installed.map_err(|e| {
                if files::disk_full(&e) {
                    e.context(format!(
                        "the worker's cache disk is full ({}), even without the scenes no \
                         worker was using lately",
                        cache.display(),
                    ))
                } else {
                    e
                }
            })?;
            drop(installing);
            let held = files::hold(&d);
            if let Some(max) = max {
                files::trim(&cache, max, Some(&d));
            }
            anyhow::Ok(held)
        })
        .await??;
        Ok((entry, held))
    }

    /// Whether the cached files of `lease`'s scene are still those recorded when they were
    /// unpacked.
    async fn cached_scene_intact(&self, lease: &proto::Lease) -> bool {
        let (d, sha) = (
            self.cfg.cache_dir.join(&lease.scene),
            lease.scene_sha256.clone(),
        );
        tokio::task::spawn_blocking(move || files::verify(&d, &sha))
            .await
            .unwrap_or(false)
    }

    /// The built scene of `lease`: from the scene cache, or downloaded and built on the
    /// render pool (off the async threads).
    async fn scene(&mut self, lease: &proto::Lease) -> Result<Arc<Scene>, anyhow::Error> {
        // The entry matters too: one archive may hold several scenes.
        let key = format!("{}/{}", lease.scene, lease.scene_entry);
        let cache = self.cfg.scene_cache.clone();
        cache
            .get_or_build(&key, || async {
                let t = std::time::Instant::now();
                let mut tries = 0;
                let scene = loop {
                    tries += 1;
                    // Held until the build has read the files.
                    let (file, _in_use) = self.scene_file(lease).await?;
                    let pool = self.pool.clone();
                    let limits = self.cfg.scene_limits;
                    let built = tokio::task::spawn_blocking(move || {
                        pool.install(|| load_and_build(&file, limits))
                    })
                    .await
                    .map_err(|e| anyhow!("scene build task: {e}"))?;
                    match built {
                        Ok(scene) => break scene,
                        // Files changed or removed under the build (a worker sharing the cache
                        // removed the scene, a disk fault): once more, from a fresh copy.
                        Err(e) if tries == 1 && !self.cached_scene_intact(lease).await => {
                            tracing::warn!(scene = %lease.scene, "the cached scene changed while it was built ({e:#}); fetching it again");
                        }
                        Err(e) => return Err(e),
                    }
                };
                self.cfg.stats.scene_builds.fetch_add(1, Ordering::Relaxed);
                tracing::info!(
                    scene = %lease.scene,
                    secs = t.elapsed().as_secs_f64(),
                    mib = scene.memory_bytes() >> 20,
                    "scene built"
                );
                Ok(scene)
            })
            .await
    }

    async fn process(
        &mut self,
        lease: proto::Lease,
        shutdown: &mut (impl Future<Output = ()> + Unpin),
    ) -> Flow {
        tracing::debug!(job = %lease.job, task = lease.task, "leased");
        let job = self.jobs.get(&lease.job).cloned();
        // The scene, and the scene file whose folder a job's environment map is read from
        // (like the scene's own files) when the job is new here.
        let needs_map = job.is_none()
            && matches!(
                lease.settings.environment,
                Some(raytile_core::EnvironmentChoice::Map(_))
            );
        let client = self.client.clone();
        let heartbeat = self.heartbeat;
        let load = async {
            let scene = self.scene(&lease).await?;
            let map_base = match needs_map {
                // The map is read from the scene's folder by the first render: held till then.
                true => Some(self.scene_file(&lease).await?),
                false => None,
            };
            Ok::<_, anyhow::Error>((scene, map_base))
        };
        // The lease is renewed while the scene is fetched, checked and built, which can take
        // longer than the lease timeout (a large scene, a slow link).
        let renewing = renew_lease(&client, &lease.lease_id, heartbeat);
        let loaded = tokio::select! {
            biased;
            _ = &mut *shutdown => {
                self.release(&lease).await;
                return Flow::Exit;
            }
            r = load => r,
            () = renewing => {
                // The job was cancelled, or the task is another worker's now.
                self.cfg.stats.cancelled.fetch_add(1, Ordering::Relaxed);
                return Flow::Continue;
            }
        };
        let (scene, map_base) = match loaded {
            Ok(l) => l,
            Err(e) => {
                self.report_failure(&lease, format!("{e:#}")).await;
                return Flow::Continue;
            }
        };
        let pool = self.pool.clone();
        let (settings, tile, samples) = (
            lease.settings.clone(),
            lease.tile,
            lease.sample_start..lease.sample_end,
        );
        let limits = self.cfg.scene_limits;
        // Set when the coordinator says stop: the render returns within a fraction of a
        // second instead of keeping the render threads busy to the end of the tile.
        let cancel = Arc::new(raytile_core::Cancel::new());
        let watched = cancel.clone();
        let mut render = tokio::task::spawn_blocking(move || {
            pool.install(|| {
                std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                    let job = match job {
                        Some(j) => j,
                        None => Arc::new(
                            job_for(
                                &scene,
                                &settings,
                                map_base.as_ref().map(|(file, _in_use)| file.as_path()),
                                limits,
                            )
                            .map_err(|e| format!("job: {e}"))?,
                        ),
                    };
                    let accum = raytile_core::render_tile(&scene, &job, tile, samples, &watched);
                    Ok::<_, String>((accum, job))
                }))
            })
            .map_err(|p| format!("render panicked: {}", panic_message(p)))
            .and_then(|r| r)
        });
        let (accum, job): (TileAccum, Arc<RenderJob>) = loop {
            tokio::select! {
                biased;
                _ = &mut *shutdown => {
                    // Hand the lease back so another worker takes the tile at once; the render
                    // stops at its next look at the flag.
                    cancel.cancel();
                    self.release(&lease).await;
                    return Flow::Exit;
                }
                r = &mut render => match r {
                    Ok(Ok((Ok(acc), job))) => break (acc, job),
                    Ok(Ok((Err(raytile_core::Cancelled), _))) => {
                        self.cfg.stats.cancelled.fetch_add(1, Ordering::Relaxed);
                        return Flow::Continue;
                    }
                    Ok(Err(msg)) => {
                        self.report_failure(&lease, msg).await;
                        return Flow::Continue;
                    }
                    Err(e) => {
                        self.report_failure(&lease, format!("render task: {e}")).await;
                        return Flow::Continue;
                    }
                },
                _ = tokio::time::sleep(self.heartbeat) => {
                    let timeout = self.heartbeat.max(Duration::from_secs(2));
                    if let Ok(reply) = self.client.heartbeat(&lease.lease_id, timeout).await {
                        if reply.cancelled {
                            tracing::info!(job = %lease.job, task = lease.task,
                                reason = reply.reason.as_deref().unwrap_or(""), "stopping task");
                            // Stop the render and wait for it, so the render threads are free
                            // for the next task.
                            cancel.cancel();
                            let _ = (&mut render).await;
                            self.cfg.stats.cancelled.fetch_add(1, Ordering::Relaxed);
                            return Flow::Continue;
                        }
                    }
                    // An unreachable coordinator is not a reason to stop: the result is
                    // uploaded with retries, and a restarted coordinator accepts it.
                }
            }
        };
        self.cfg.stats.renders.fetch_add(1, Ordering::Relaxed);
        // Keep a few jobs' camera and light selection: jobs interleave by priority.
        if !self.jobs.contains_key(&lease.job) {
            if self.jobs.len() >= 8 {
                self.jobs.clear();
            }
            self.jobs.insert(lease.job.clone(), job);
        }
        let bytes = proto::tile::encode(&accum, lease.pass);
        let target = ResultTarget {
            job: lease.job.clone(),
            task: lease.task,
            worker: self.worker_id.clone().unwrap_or_default(),
            lease: lease.lease_id.clone(),
        };
        // Upload in the background while the next task renders (the round trip and the
        // coordinator's commit would otherwise idle the render threads), but keep at most one
        // result in flight: wait for the previous upload first.
        let stopping = tokio::select! {
            biased;
            _ = &mut *shutdown => true,
            _ = async { while self.uploads.join_next().await.is_some() {} } => false,
        };
        self.uploads.spawn(upload_result(
            self.client.clone(),
            target,
            bytes,
            self.cfg.stats.clone(),
            Retry {
                max_backoff: self.cfg.max_backoff,
                heartbeat: self.heartbeat,
            },
        ));
        if stopping {
            Flow::Exit
        } else {
            Flow::Continue
        }
    }
}

/// `error` as the job's owner should read it: paths of the worker's cache are named as paths
/// of the scene's folder (`textures/a.png`, not `/var/cache/raytile/ID/root/textures/a.png`),
/// and the cache folder itself as "the worker's cache". The log keeps the full message.
fn without_local_paths(error: &str, cache_dir: &std::path::Path, scene: &str) -> String {
    let root = cache_dir.join(scene).join("root");
    let (root, cache) = (root.display().to_string(), cache_dir.display().to_string());
    let mut out = error.replace(&format!("{root}/"), "");
    out = out.replace(&root, "the scene's folder");
    if !cache.is_empty() {
        out = out.replace(&cache, "the worker's cache");
    }
    out
}

/// Server errors (5xx) after which a result upload is given up.
const UPLOAD_SERVER_ERRORS: u32 = 5;

/// How a result upload waits: its longest backoff, and how often it renews its lease.
#[derive(Clone, Copy)]
struct Retry {
    max_backoff: Duration,
    heartbeat: Duration,
}

/// The cached folder `dir` of `lease`'s scene, held in use, when it is there and its files are
/// what was unpacked; a folder that is not (incomplete, edited, rotted) is removed, and `None`
/// says the scene is to be fetched. Checked whenever the files are to be read (a build; a
/// scene in the memory cache reads none), so that a file edited or rotted since the last build
/// is fetched again rather than rendered; hashing costs a fraction of what building costs.
async fn cached(dir: &Path, lease: &proto::Lease) -> anyhow::Result<Option<files::InUse>> {
    if !dir.exists() {
        return Ok(None);
    }
    let (d, sha) = (dir.to_path_buf(), lease.scene_sha256.clone());
    let held = tokio::task::spawn_blocking(move || {
        // Held first: a worker sharing the cache must not remove it while this one checks and
        // builds from it.
        let held = files::hold(&d)?;
        files::verify(&d, &sha).then_some(held)
    })
    .await?;
    if held.is_none() {
        tracing::warn!(scene = %lease.scene, "cached scene is incomplete or corrupt; downloading again");
        let d = dir.to_path_buf();
        tokio::task::spawn_blocking(move || files::discard(&d)).await?;
    }
    Ok(held)
}

/// Uploads one tile result. While the coordinator cannot be reached, or answers 503 (it could
/// not write its store, or it is shutting down: nothing was stored, the same request may
/// succeed later), it retries with backoff for as long as it takes: a result is never thrown
/// away for a fault the coordinator recovers from. A refusal (4xx) is dropped at once (the
/// task is someone else's by now, or the job is gone), and another server error (500) after
/// [`UPLOAD_SERVER_ERRORS`] attempts, so that one result the coordinator cannot take never
/// wedges the worker: its lease expires and the tile is rendered again.
///
/// The lease is renewed by heartbeats until the upload ends, as while the tile rendered: a
/// coordinator that cannot write its store still renews leases (they live in memory), so the
/// tile is not given to another worker to render again while this one waits to deliver it.
/// A heartbeat that says the task is no longer this worker's (the job was cancelled, or the
/// lease expired during a longer outage) ends the heartbeats, not the upload: the coordinator
/// still takes a late result of a task not done yet, and answers one it no longer wants at
/// once.
async fn upload_result(
    client: Client,
    to: ResultTarget,
    bytes: Vec<u8>,
    stats: Arc<Stats>,
    retry: Retry,
) {
    let upload = upload_with_retries(&client, &to, bytes, &stats, retry);
    // A lease that ended ends the heartbeats, not the upload.
    let renewing = async {
        renew_lease(&client, &to.lease, retry.heartbeat).await;
        std::future::pending::<()>().await
    };
    tokio::select! {
        () = upload => {}
        () = renewing => {}
    }
}

/// Renews lease `lease` every `every` for as long as it is polled; ends when the coordinator
/// says the lease is over (the job was cancelled, or the task is another worker's now).
async fn renew_lease(client: &Client, lease: &str, every: Duration) {
    loop {
        tokio::time::sleep(every).await;
        let timeout = every.max(Duration::from_secs(2));
        if let Ok(reply) = client.heartbeat(lease, timeout).await {
            if reply.cancelled {
                tracing::info!(
                    lease,
                    reason = reply.reason.as_deref().unwrap_or(""),
                    "the lease ended"
                );
                return;
            }
        }
    }
}

/// [`upload_result`]'s attempts, until one is answered.
async fn upload_with_retries(
    client: &Client,
    to: &ResultTarget,
    bytes: Vec<u8>,
    stats: &Stats,
    retry: Retry,
) {
    let mut backoff = Backoff::new(retry.max_backoff);
    let mut server_errors = 0;
    let what = format!("job {} task {}", to.job, to.task);
    loop {
        let r = client
            .upload_result(&to.job, to.task, &to.worker, &to.lease, bytes.clone())
            .await;
        match r {
            Ok(reply) => {
                let c = if reply.accepted {
                    &stats.accepted
                } else {
                    &stats.duplicates
                };
                c.fetch_add(1, Ordering::Relaxed);
                return;
            }
            // The coordinator took the result but its answer was cut off: not worth a retry.
            Err(ClientError::Body(_)) => {
                stats.duplicates.fetch_add(1, Ordering::Relaxed);
                return;
            }
            Err(e) if e.status().is_some_and(|s| s.is_client_error()) => {
                tracing::warn!("result refused ({what}): {e}");
                return;
            }
            Err(e) => {
                if e.status()
                    .is_some_and(|s| s != StatusCode::SERVICE_UNAVAILABLE)
                {
                    server_errors += 1;
                    if server_errors >= UPLOAD_SERVER_ERRORS {
                        tracing::warn!("result dropped after {server_errors} errors ({what}): {e}");
                        return;
                    }
                }
                let d = backoff.step();
                tracing::warn!(
                    "result upload failed ({e}); retrying in {:.1} s",
                    d.as_secs_f64()
                );
                tokio::time::sleep(d).await;
            }
        }
    }
}

/// Where a tile result goes.
struct ResultTarget {
    job: String,
    task: u32,
    worker: String,
    lease: String,
}

/// The job of `settings` on `scene`; an environment map it names is read from the folder of
/// the scene file `scene_file`, confined to it within `limits` like the scene's own files.
fn job_for(
    scene: &Scene,
    settings: &raytile_core::RenderSettings,
    scene_file: Option<&Path>,
    limits: SceneLoadLimits,
) -> Result<RenderJob, raytile_core::SceneError> {
    let Some(file) = scene_file else {
        return RenderJob::new(scene, settings);
    };
    let files = raytile_core::scene::files::SceneFiles::confined_to_scene(
        file,
        limits.max_file_bytes,
        limits.max_scene_bytes,
    )
    .map_err(|e| raytile_core::SceneError::Invalid(format!("scene folder: {e}")))?
    .with_memory_limit(limits.max_memory);
    let base = file.parent().unwrap_or(Path::new("."));
    RenderJob::with_files(scene, settings, &files, base)
}

/// Loads (confined to the scene file's folder, within `limits`) and builds a scene, turning
/// panics into errors.
fn load_and_build(file: &Path, limits: SceneLoadLimits) -> anyhow::Result<Scene> {
    let files = raytile_core::scene::files::SceneFiles::confined_to_scene(
        file,
        limits.max_file_bytes,
        limits.max_scene_bytes,
    )
    .map_err(|e| anyhow!("the folder of {}: {e}", file.display()))?
    .with_memory_limit(limits.max_memory);
    let f = file.to_path_buf();
    match std::panic::catch_unwind(move || -> Result<Scene, raytile_core::SceneError> {
        let desc = raytile_core::load_scene_with(&f, &files)?;
        Scene::build_owned(desc)
    }) {
        Ok(Ok(scene)) => Ok(scene),
        Ok(Err(e)) => Err(anyhow!("scene: {e}")),
        Err(p) => Err(anyhow!("scene loading panicked: {}", panic_message(p))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    /// A failure the job's owner reads names files of the scene, not of the worker's disk.
    #[test]
    fn failure_messages_name_scene_files_not_cache_paths() {
        let cache = std::path::Path::new("/srv/raytile-cache");
        let msg = "scene: /srv/raytile-cache/s1/root/textures/a.png: image too large; \
                   /srv/raytile-cache/s1/root: denied; \
                   creating /srv/raytile-cache: read-only";
        assert_eq!(
            without_local_paths(msg, cache, "s1"),
            "scene: textures/a.png: image too large; the scene's folder: denied; \
             creating the worker's cache: read-only"
        );
    }

    /// Serves `answers` in order, one per connection, reading each request to its end, and
    /// answers every heartbeat `beat`; returns the base URL and counters of the requests
    /// served from `answers` and of the heartbeats.
    async fn serve_beating(
        answers: Vec<(u16, &'static str)>,
        beat: &'static str,
    ) -> (String, Arc<AtomicU64>, Arc<AtomicU64>) {
        let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let base = format!("http://{}", l.local_addr().unwrap());
        let served = Arc::new(AtomicU64::new(0));
        let beats = Arc::new(AtomicU64::new(0));
        let (count, beat_count) = (served.clone(), beats.clone());
        tokio::spawn(async move {
            let mut answers = answers.into_iter();
            loop {
                let (mut s, _) = l.accept().await.unwrap();
                let mut req = Vec::new();
                let mut buf = [0u8; 65536];
                // Head, then as many body bytes as Content-Length says.
                loop {
                    let n = s.read(&mut buf).await.unwrap();
                    req.extend_from_slice(&buf[..n]);
                    let text = String::from_utf8_lossy(&req).to_lowercase();
                    if let Some(end) = text.find("\r\n\r\n") {
                        let len: usize = text
                            .lines()
                            .find_map(|l| l.strip_prefix("content-length: "))
                            .and_then(|v| v.trim().parse().ok())
                            .unwrap_or(0);
                        if req.len() >= end + 4 + len {
                            break;
                        }
                    }
                    if n == 0 {
                        break;
                    }
                }
                let (status, body) = if req.starts_with(b"POST /v1/leases/") {
                    beat_count.fetch_add(1, Ordering::SeqCst);
                    (200, beat)
                } else {
                    let Some(answer) = answers.next() else { break };
                    count.fetch_add(1, Ordering::SeqCst);
                    answer
                };
                let resp = format!(
                    "HTTP/1.1 {status} X\r\ncontent-type: application/json\r\ncontent-length: {}\r\nconnection: close\r\n\r\n{body}",
                    body.len()
                );
                s.write_all(resp.as_bytes()).await.unwrap();
            }
        });
        (base, served, beats)
    }

    /// [`serve_beating`] whose heartbeats are all answered "carry on".
    async fn serve(answers: Vec<(u16, &'static str)>) -> (String, Arc<AtomicU64>) {
        let (base, served, _) = serve_beating(answers, r#"{"cancelled": false}"#).await;
        (base, served)
    }

    fn target() -> ResultTarget {
        ResultTarget {
            job: "j".into(),
            task: 0,
            worker: "w".into(),
            lease: "l".into(),
        }
    }

    /// `n` answers of a coordinator that cannot write its store, then one taking the result.
    fn busy_then_accepted(n: usize) -> Vec<(u16, &'static str)> {
        let busy = r#"{"error": {"code": "store_unavailable", "message": "retry later", "retryable": true}}"#;
        let mut answers = vec![(503, busy); n];
        answers.push((
            200,
            r#"{"accepted": true, "duplicate": false, "job_finished": false}"#,
        ));
        answers
    }

    const RETRY: Retry = Retry {
        max_backoff: Duration::from_millis(5),
        heartbeat: Duration::from_secs(3600),
    };

    /// While its upload is retried, the lease is renewed, so that the tile is not rendered
    /// again elsewhere; a heartbeat saying the task is no longer the worker's ends the
    /// heartbeats, and the coordinator's answer to the upload has the last word.
    #[tokio::test]
    async fn a_result_waiting_to_be_taken_keeps_its_lease() {
        let retry = Retry {
            max_backoff: Duration::from_millis(40),
            heartbeat: Duration::from_millis(10),
        };
        // 12 answers of "cannot write", then the result taken, with heartbeats answered
        // `beat`: (results accepted, uploads served, heartbeats).
        let run = |beat: &'static str| async move {
            let (base, served, beats) = serve_beating(busy_then_accepted(12), beat).await;
            let stats = Arc::new(Stats::default());
            let client = Client::new(&base, None).unwrap();
            let upload = upload_result(client, target(), vec![0; 64], stats.clone(), retry);
            tokio::time::timeout(Duration::from_secs(20), upload)
                .await
                .expect("the upload gave up or hung");
            (
                stats.accepted.load(Ordering::SeqCst),
                served.load(Ordering::SeqCst),
                beats.load(Ordering::SeqCst),
            )
        };
        let (accepted, served, beats) = run(r#"{"cancelled": false}"#).await;
        assert_eq!((accepted, served), (1, 13));
        assert!(beats >= 3, "heartbeats while it waited");

        // A late result is still the coordinator's to take or refuse.
        let (accepted, served, beats) =
            run(r#"{"cancelled": true, "reason": "lease expired"}"#).await;
        assert_eq!((accepted, served), (1, 13));
        assert_eq!(beats, 1, "no heartbeats after the first 'no'");
    }

    /// A coordinator that cannot write its database answers 503 for a while: the worker keeps
    /// the result and retries, past the cap on other server errors, until it is accepted.
    #[tokio::test]
    async fn result_uploads_outlast_a_coordinator_answering_503() {
        let answers = busy_then_accepted(UPLOAD_SERVER_ERRORS as usize + 2);
        let (base, served) = serve(answers).await;
        let stats = Arc::new(Stats::default());
        let client = Client::new(&base, None).unwrap();
        let upload = upload_result(client, target(), vec![0; 64], stats.clone(), RETRY);
        tokio::time::timeout(Duration::from_secs(20), upload)
            .await
            .expect("the upload gave up or hung");
        assert_eq!(stats.accepted.load(Ordering::SeqCst), 1);
        assert_eq!(
            served.load(Ordering::SeqCst),
            UPLOAD_SERVER_ERRORS as u64 + 3
        );
    }

    /// Other server errors are given up after a few attempts, so one result the coordinator
    /// cannot take never wedges the worker.
    #[tokio::test]
    async fn result_uploads_give_up_after_repeated_internal_errors() {
        let err = r#"{"error": {"code": "internal", "message": "internal error"}}"#;
        let (base, served) = serve(vec![(500, err); UPLOAD_SERVER_ERRORS as usize]).await;
        let stats = Arc::new(Stats::default());
        let client = Client::new(&base, None).unwrap();
        let upload = upload_result(client, target(), vec![0; 64], stats.clone(), RETRY);
        tokio::time::timeout(Duration::from_secs(20), upload)
            .await
            .expect("the upload hung");
        assert_eq!(stats.accepted.load(Ordering::SeqCst), 0);
        assert_eq!(served.load(Ordering::SeqCst), UPLOAD_SERVER_ERRORS as u64);
    }

    /// A configuration asking for more render threads than [`MAX_THREADS`] is an error before
    /// any thread starts or the coordinator is asked for work.
    #[tokio::test]
    async fn too_many_threads_is_a_configuration_error() {
        let mut config = Config::new("http://127.0.0.1:9");
        config.threads = MAX_THREADS + 1;
        let err = run(config, std::future::pending()).await.unwrap_err();
        assert!(err.to_string().contains("at most 1024"), "{err}");
    }
}
