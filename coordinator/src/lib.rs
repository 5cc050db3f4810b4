//! The raytile coordinator: scene store, job queue, tile leases and the HTTP API.
//!
//! Shaped like mini-redis: callers bind the socket and call [`run`] with a shutdown future; the
//! router is [`app`], so tests can start the real server in-process on `127.0.0.1:0` or call
//! the router with `tower::ServiceExt::oneshot`.
//!
//! - [`sched`]: jobs, tasks, leases, workers and the state machines; it reads no clock:
//!   handlers pass it a reading of [`clock`].
//! - [`store`]: SQLite persistence under the data directory.
//! - [`api`]: the HTTP handlers; [`scenes`]: scene uploads; [`compose`]: frames from results.
//! - [`openapi`]: the OpenAPI description served at `/v1/openapi.json`.
//! - [`web`]: the web pages (`/`, `/jobs/{id}`, `/workers`) and their files, embedded.

pub mod api;
pub mod clock;
pub mod compose;
pub mod error;
pub mod images;
pub mod listen;
pub mod openapi;
pub mod scenes;
pub mod sched;
pub mod store;
#[cfg(test)]
mod tests;
pub mod web;

pub use api::app;
pub use scenes::{core_scene_loader, LoadError, LoadedScene, SceneLimits, SceneLoader};

use anyhow::Context;
use clock::{Clock, Now};
use sched::{Sched, SchedConfig};
use std::collections::HashMap;
use std::future::Future;
use std::net::IpAddr;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::{watch, Notify};

/// Limits on what clients may ask for. Every job limit is checked by arithmetic on the
/// settings alone, before anything of the job is allocated (see [`Limits::check_job`]).
#[derive(Clone, Debug)]
pub struct Limits {
    /// Largest upload (scene) in bytes; more is answered 413.
    pub max_upload_bytes: u64,
    /// Largest tile result in bytes (a `bdpt` tile's splats make results larger than their
    /// tile); more is answered 413, and a `bdpt` job whose results could be larger is refused.
    pub max_result_bytes: u64,
    /// Largest unpacked size of a scene archive.
    pub max_unpacked_bytes: u64,
    /// Largest width × height of a job.
    pub max_pixels: u64,
    /// Largest samples per pixel of a job.
    pub max_spp: u32,
    /// Most progressive passes of a job.
    pub max_passes: u32,
    /// Smallest tile edge of a job, in pixels: tiny tiles cost more in requests than in
    /// rendering.
    pub min_tile_size: u32,
    /// Most tasks (tiles × passes) of one job: the coordinator keeps every task in memory.
    pub max_tasks_per_job: u64,
    /// Most unfinished jobs at once; more is answered 429.
    pub max_queued_jobs: usize,
    /// Most tasks of all unfinished jobs together; a job that would go over is answered 429.
    /// With `max_queued_jobs`, bounds the memory that queued work takes.
    pub max_queued_tasks: u64,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_upload_bytes: 512 << 20,
            max_result_bytes: 2 << 30,
            max_unpacked_bytes: 2 << 30,
            max_pixels: raytile_core::settings::MAX_PIXELS,
            max_spp: raytile_core::settings::MAX_SPP,
            max_passes: 256,
            min_tile_size: 16,
            max_tasks_per_job: 1 << 18,
            max_queued_jobs: 1000,
            max_queued_tasks: 1 << 22,
        }
    }
}

/// A job setting over a limit: the field (as the API names it) and why.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OverLimit {
    /// The offending field: `width`, `spp`, `passes`, `tile_size`.
    pub field: &'static str,
    /// What is allowed, and what the job asked for.
    pub message: String,
}

impl Limits {
    /// Checks valid settings against this coordinator's limits, by arithmetic alone (nothing
    /// is allocated, so a job of billions of tasks is refused as fast as any other).
    pub fn check_job(&self, s: &raytile_core::RenderSettings) -> Result<(), OverLimit> {
        let over = |field, message| Err(OverLimit { field, message });
        let pixels = u64::from(s.width) * u64::from(s.height);
        if pixels > self.max_pixels {
            return over(
                "width",
                format!(
                    "width × height must be at most {} pixels on this coordinator, got {pixels}",
                    self.max_pixels
                ),
            );
        }
        if s.spp > self.max_spp {
            return over(
                "spp",
                format!(
                    "must be at most {} on this coordinator, got {}",
                    self.max_spp, s.spp
                ),
            );
        }
        if s.passes > self.max_passes {
            return over(
                "passes",
                format!(
                    "must be at most {} on this coordinator, got {}",
                    self.max_passes, s.passes
                ),
            );
        }
        if s.tile_size < self.min_tile_size {
            return over(
                "tile_size",
                format!(
                    "must be at least {} on this coordinator, got {}",
                    self.min_tile_size, s.tile_size
                ),
            );
        }
        // As `RenderSettings::tiles` and `pass_ranges` count them.
        let ts = u64::from(s.tile_size.max(1));
        let tiles = u64::from(s.width).div_ceil(ts) * u64::from(s.height).div_ceil(ts);
        let passes = u64::from(s.passes.clamp(1, s.spp.max(1)));
        let max = self.max_tasks_per_job;
        if tiles > max {
            return over(
                "tile_size",
                format!(
                    "tiles of {ts} pixels cut the frame into {tiles} tiles, more than the {max} tasks a job may have on this coordinator: use larger tiles"
                ),
            );
        }
        if tiles * passes > max {
            return over(
                "passes",
                format!(
                    "{tiles} tiles × {passes} passes make {} tasks, more than the {max} a job may have on this coordinator: use fewer passes or larger tiles",
                    tiles * passes
                ),
            );
        }
        // Every result must fit --max-result-bytes, or a valid one could never be sent (and
        // the job would fail by its refused uploads). A tile's is 16 bytes a pixel (20 with an
        // alpha channel); a bdpt tile's may carry a splat for every pixel of the frame besides.
        let tile = raytile_proto::Tile {
            x0: 0,
            y0: 0,
            x1: s.tile_size.min(s.width),
            y1: s.tile_size.min(s.height),
        };
        let own = raytile_proto::tile::encoded_len(&tile, s.alpha) as u64;
        if s.integrator == raytile_core::IntegratorKind::Bdpt {
            let largest = own + pixels * raytile_proto::tile::SPLAT_LEN as u64;
            if largest > self.max_result_bytes {
                return over(
                    "width",
                    format!(
                        "a bdpt frame of {pixels} pixels can make tile results of up to {largest} \
                         bytes (a splat for every pixel of the frame), more than the {} a result \
                         may have on this coordinator (--max-result-bytes): render a smaller \
                         frame, or with path or volpath",
                        self.max_result_bytes
                    ),
                );
            }
        } else if own > self.max_result_bytes {
            return over(
                "tile_size",
                format!(
                    "tiles of {} × {} pixels make results of {own} bytes, more than the {} a \
                     result may have on this coordinator (--max-result-bytes): use smaller tiles",
                    tile.x1, tile.y1, self.max_result_bytes
                ),
            );
        }
        Ok(())
    }
}

/// The default of [`Config::image_cache_bytes`]: 256 MiB.
pub const IMAGE_CACHE_BYTES: usize = 256 << 20;

/// Everything the coordinator is configured with.
#[derive(Clone)]
pub struct Config {
    /// Where the database, scenes and temporary files live.
    pub data_dir: PathBuf,
    /// Bearer token required on every endpoint but `/healthz`.
    pub token: Option<String>,
    /// A second token, for workers: when set, the workers' endpoints take it and only it, and
    /// the others take [`Config::token`] and only it (see [`api::Role`]), so a user cannot
    /// act as a worker nor a worker as a user. Needs `token`, and must differ from it.
    pub worker_token: Option<String>,
    /// Allow a non-loopback address without a token.
    pub insecure: bool,
    /// How long a lease lives without a heartbeat.
    pub lease_timeout: Duration,
    /// How often workers should heartbeat.
    pub heartbeat_interval: Duration,
    /// After start-up, no lease expires for this long, so workers can reconnect.
    pub startup_grace: Duration,
    /// Longest a lease request may wait for work.
    pub long_poll_max: Duration,
    /// Failures of one task that fail its job.
    pub max_task_failures: u32,
    /// Failures of one worker on one job after which it gets no more of the job's tasks.
    pub block_worker_after: u32,
    /// Request limits.
    pub limits: Limits,
    /// Bounds on checking uploaded scenes. The file and memory bounds are the core loader's:
    /// after changing them, make the loader again with [`core_scene_loader`].
    pub scene_limits: SceneLimits,
    /// Parses uploaded scenes (the core's loader; tests inject fakes).
    pub scene_loader: SceneLoader,
    /// Most job images composed and encoded at once. Each holds its whole frame and the
    /// encoded image while it runs (some 40 bytes per pixel at its peak, more for `bdpt`),
    /// so this bounds the memory image requests take together; further requests wait.
    pub max_parallel_images: usize,
    /// How long an image request waits for one of the others to end before it is answered
    /// 503 (retryable, with `Retry-After`).
    pub image_wait: Duration,
    /// Most bytes of encoded job images kept for the requests that follow (the newest image
    /// of each job and format, least recently used dropped first; 0 keeps none).
    pub image_cache_bytes: usize,
    /// Results of this many bytes or more are stored as files beside the database, written
    /// before the scheduler's lock is taken, rather than in it (default 1 MiB).
    pub result_file_bytes: usize,
    /// Most results of `result_file_bytes` or more read and checked at once. Each holds its
    /// body and its decoded splats in memory (about 1 GB for a 470 MB `bdpt` result), so this
    /// bounds the memory uploads take together; further uploads wait.
    pub max_parallel_large_results: usize,
    /// How long a large result waits for one of the others to end before it is answered 503
    /// (retryable, with `Retry-After`).
    pub large_result_wait: Duration,
    /// Bounds on connections: how many at once, how long a client may take to send headers.
    pub serve_limits: listen::ServeLimits,
    /// The time source of every scheduler call (the system clock; tests inject their own).
    pub clock: Clock,
}

impl Config {
    /// Defaults with the given data directory.
    pub fn new(data_dir: impl Into<PathBuf>) -> Config {
        Config {
            data_dir: data_dir.into(),
            token: None,
            worker_token: None,
            insecure: false,
            lease_timeout: Duration::from_secs(30),
            heartbeat_interval: Duration::from_secs(5),
            startup_grace: Duration::from_secs(30),
            long_poll_max: Duration::from_secs(30),
            max_task_failures: 3,
            block_worker_after: 3,
            limits: Limits::default(),
            scene_limits: SceneLimits::default(),
            scene_loader: core_scene_loader(SceneLimits::default()),
            max_parallel_images: 2,
            image_wait: Duration::from_secs(30),
            image_cache_bytes: IMAGE_CACHE_BYTES,
            result_file_bytes: 1 << 20,
            max_parallel_large_results: 2,
            large_result_wait: Duration::from_secs(30),
            serve_limits: listen::ServeLimits::default(),
            clock: clock::system_clock(),
        }
    }
}

impl std::fmt::Debug for Config {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Config")
            .field("data_dir", &self.data_dir)
            .field("token", &self.token.as_ref().map(|_| "***"))
            .field("worker_token", &self.worker_token.as_ref().map(|_| "***"))
            .field("lease_timeout", &self.lease_timeout)
            .finish_non_exhaustive()
    }
}

/// Shared state of the handlers.
#[derive(Clone)]
pub struct AppState(Arc<Inner>);

/// What [`AppState`] holds.
pub struct Inner {
    /// Configuration.
    pub cfg: Config,
    /// The scheduler (and its store) behind one lock; never held across an await.
    pub sched: Mutex<Sched>,
    /// Woken when tasks become available, for long-polling lease requests.
    pub notify: Notify,
    /// Start time, for the start-up grace period.
    pub started: Now,
    /// Scene metadata cache.
    pub scene_meta: Mutex<HashMap<String, Arc<scenes::SceneMeta>>>,
    /// The scenes being checked, by id: an identical upload waits for the check under way
    /// rather than run its own (see [`scenes::upload`]).
    pub scene_checks: scenes::Checks,
    /// One permit per scene parse that may run ([`SceneLimits::max_parallel_parses`]).
    pub parse_slots: Arc<tokio::sync::Semaphore>,
    /// One permit per job image that may be composed and encoded at once
    /// ([`Config::max_parallel_images`]).
    pub image_slots: Arc<tokio::sync::Semaphore>,
    /// The last job images made ([`Config::image_cache_bytes`]).
    pub images: Mutex<images::ImageCache>,
    /// One permit per large result being read and checked
    /// ([`Config::max_parallel_large_results`]).
    pub large_result_slots: Arc<tokio::sync::Semaphore>,
    shutdown_tx: watch::Sender<bool>,
    /// The data directory and its `lock` file, locked while the coordinator runs (see
    /// [`lock_data_dir`]); given up when [`run`] ends, even while a clone of the state lives on
    /// in a task being torn down.
    lock: Mutex<Vec<std::fs::File>>,
}

impl std::ops::Deref for AppState {
    type Target = Inner;
    fn deref(&self) -> &Inner {
        &self.0
    }
}

/// Removes what `dir` holds, logging what cannot be removed.
fn clear_dir(dir: &std::path::Path) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let path = e.path();
        let gone = match e.file_type() {
            Ok(t) if t.is_dir() => std::fs::remove_dir_all(&path),
            _ => std::fs::remove_file(&path),
        };
        match gone {
            Ok(()) => tracing::info!(path = %path.display(), "removed an unfinished upload"),
            Err(err) => tracing::warn!(path = %path.display(), "cannot remove: {err}"),
        }
    }
}

/// Bytes free for an unprivileged writer on the file system of `dir`, if it can be asked.
#[cfg(unix)]
fn free_bytes(dir: &std::path::Path) -> Option<u64> {
    use std::os::unix::ffi::OsStrExt;
    let path = std::ffi::CString::new(dir.as_os_str().as_bytes()).ok()?;
    // SAFETY: statvfs writes the one struct this function owns; `path` is NUL-terminated.
    unsafe {
        let mut st: libc::statvfs = std::mem::zeroed();
        (libc::statvfs(path.as_ptr(), &mut st) == 0)
            .then(|| (st.f_bavail as u64).saturating_mul(st.f_frsize as u64))
    }
}

#[cfg(not(unix))]
fn free_bytes(_dir: &std::path::Path) -> Option<u64> {
    None
}

impl AppState {
    /// Opens the data directory and restores every job.
    pub fn open(cfg: Config) -> anyhow::Result<AppState> {
        for d in ["scenes", "tmp"] {
            std::fs::create_dir_all(cfg.data_dir.join(d))
                .with_context(|| format!("creating {}", cfg.data_dir.join(d).display()))?;
        }
        let lock = lock_data_dir(&cfg.data_dir)?;
        // Uploads and unpackings in progress live in tmp/ until they are renamed into scenes/:
        // what a killed coordinator left there is no use to anyone (the lock above says no
        // other coordinator is writing it).
        clear_dir(&cfg.data_dir.join("tmp"));
        let store = store::Store::open(&cfg.data_dir).map_err(|e| {
            let db = cfg.data_dir.join("raytile.sqlite3");
            // SQLite says "disk I/O error" for a full disk, among others: say what is left. It
            // names no file, and says "readonly database" for one the user may not write.
            let why = match free_bytes(&cfg.data_dir) {
                Some(free) if free < 1 << 20 => format!(
                    "opening the database {} (the file system of {} has {free} bytes free)",
                    db.display(),
                    cfg.data_dir.display()
                ),
                _ if e.sqlite_error_code() == Some(rusqlite::ErrorCode::ReadOnly) => format!(
                    "opening the database {} (the coordinator's user must be able to write it, \
                     and its folder, on a file system mounted read-write)",
                    db.display()
                ),
                _ => format!("opening the database {}", db.display()),
            };
            anyhow::Error::new(e).context(why)
        })?;
        let now = (cfg.clock)();
        let grace = cfg.startup_grace.max(cfg.lease_timeout);
        let sched = Sched::restore(
            SchedConfig {
                lease_timeout: cfg.lease_timeout,
                max_task_failures: cfg.max_task_failures.max(1),
                block_worker_after: cfg.block_worker_after.max(1),
            },
            store,
            now,
            grace,
        )
        .context("restoring jobs")?;
        let unfinished = sched.unfinished_jobs();
        if unfinished > 0 {
            tracing::info!(unfinished, "resuming unfinished jobs");
        }
        let (shutdown_tx, _) = watch::channel(false);
        let parse_slots = Arc::new(tokio::sync::Semaphore::new(
            cfg.scene_limits.max_parallel_parses.max(1),
        ));
        let image_slots = Arc::new(tokio::sync::Semaphore::new(cfg.max_parallel_images.max(1)));
        let large_result_slots = Arc::new(tokio::sync::Semaphore::new(
            cfg.max_parallel_large_results.max(1),
        ));
        let image_cache = Mutex::new(images::ImageCache::new(cfg.image_cache_bytes));
        Ok(AppState(Arc::new(Inner {
            cfg,
            sched: Mutex::new(sched),
            notify: Notify::new(),
            started: now,
            scene_meta: Mutex::new(HashMap::new()),
            scene_checks: Default::default(),
            parse_slots,
            image_slots,
            images: image_cache,
            large_result_slots,
            shutdown_tx,
            lock: Mutex::new(lock),
        })))
    }

    /// Reads the clock, once per request or tick: the scheduler takes the reading.
    pub fn now(&self) -> Now {
        (self.cfg.clock)()
    }

    /// Locks the scheduler (a poisoned lock is still usable: every change is persisted first).
    pub fn sched(&self) -> std::sync::MutexGuard<'_, Sched> {
        self.sched.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Locks the cache of job images (a poisoned lock is still usable: it holds only copies).
    pub fn image_cache(&self) -> std::sync::MutexGuard<'_, images::ImageCache> {
        self.images.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Tells long-polls to return and the server to stop.
    pub fn begin_shutdown(&self) {
        self.shutdown_tx.send_replace(true);
        self.notify.notify_waiters();
    }

    /// A receiver that sees `true` once shutdown began.
    pub fn shutdown_rx(&self) -> watch::Receiver<bool> {
        self.shutdown_tx.subscribe()
    }
}

/// Locks the data directory `dir` for as long as the returned files are open: a second
/// coordinator on the same data directory would resume the same jobs and hand out their tasks
/// too, and each would overwrite the other's state (a job one cancelled, the other finished).
/// Both the folder itself and its `lock` file are locked: the folder's lock cannot be deleted
/// from under a running coordinator (an operator removing a "stale" `lock` file), and the
/// file's is the one coordinators of earlier releases take. A file system without locks (some
/// network ones) is used unlocked, with a warning.
fn lock_data_dir(dir: &std::path::Path) -> anyhow::Result<Vec<std::fs::File>> {
    let in_use = |what: &std::path::Path| {
        anyhow::anyhow!(
            "{} is in use by another coordinator (which holds a lock on {}): give each \
             coordinator a --data-dir of its own",
            dir.display(),
            what.display()
        )
    };
    let mut held = Vec::new();
    // A folder that cannot be opened or locked (some network file systems lock only files
    // open for writing) leaves the lock file alone to keep a second coordinator out.
    if let Ok(folder) = std::fs::File::open(dir) {
        match try_lock(&folder) {
            Ok(true) => held.push(folder),
            Ok(false) => return Err(in_use(dir)),
            Err(_) => {}
        }
    }
    let path = dir.join("lock");
    let file = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&path)
        .with_context(|| format!("creating {}", path.display()))?;
    match try_lock(&file) {
        Ok(true) => held.push(file),
        Ok(false) => return Err(in_use(&path)),
        // The folder's lock, if it was taken, still keeps coordinators of this release out.
        Err(e) if held.is_empty() => tracing::warn!(
            "cannot lock {}: {e}; nothing stops a second coordinator on this data directory",
            path.display()
        ),
        Err(e) => tracing::warn!(
            "cannot lock {}: {e}; only the folder's lock keeps a second coordinator out (one \
             of an earlier release, which looks at the file alone, is not)",
            path.display()
        ),
    }
    Ok(held)
}

/// Takes an exclusive advisory lock (flock) on `file` without waiting: whether it got it.
/// (std's `File::try_lock` needs Rust 1.89; the workspace builds with 1.85.)
#[cfg(unix)]
fn try_lock(file: &std::fs::File) -> std::io::Result<bool> {
    use std::os::fd::AsRawFd;
    // SAFETY: flock on a file descriptor this function borrows; no memory is passed.
    if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } == 0 {
        return Ok(true);
    }
    let e = std::io::Error::last_os_error();
    if e.kind() == std::io::ErrorKind::WouldBlock {
        Ok(false)
    } else {
        Err(e)
    }
}

#[cfg(not(unix))]
fn try_lock(_file: &std::fs::File) -> std::io::Result<bool> {
    Err(std::io::Error::new(
        std::io::ErrorKind::Unsupported,
        "no file locks here",
    ))
}

/// A token as given on the command line or in the environment: without the white space
/// around it (as the token a request sends is read), none when that leaves nothing.
pub fn token_setting(given: Option<String>) -> Option<String> {
    given
        .map(|t| t.trim().to_string())
        .filter(|t| !t.is_empty())
}

/// Refuses a non-loopback address without a token unless `insecure`, and a worker token
/// without a token or equal to it.
pub fn check_exposure(ip: IpAddr, cfg: &Config) -> anyhow::Result<()> {
    if let Some(worker_token) = &cfg.worker_token {
        match &cfg.token {
            None => anyhow::bail!(
                "a worker token needs a token for the clients: set --token (or RAYTILE_TOKEN) too"
            ),
            Some(token) if token == worker_token => anyhow::bail!(
                "the worker token is the clients' token: give the workers a token of their own"
            ),
            Some(_) => {}
        }
    }
    if !ip.is_loopback() && cfg.token.is_none() && !cfg.insecure {
        anyhow::bail!(
            "refusing to listen on {ip} without a token: set --token (or RAYTILE_TOKEN), or pass --insecure"
        );
    }
    Ok(())
}

/// Re-queues expired leases, forever; waits out the start-up grace period first.
///
/// When it finds that it did not run for longer than a lease lives (the process was stopped,
/// or its machine paused), the workers' heartbeats and results of that time are still waiting
/// in the sockets: every lease out gets the start-up grace period to be heard from, as after a
/// restart, instead of all expiring at once and their tiles being rendered twice.
pub async fn timeout_checker(state: AppState) {
    let tick = (state.cfg.lease_timeout / 4).max(Duration::from_millis(20));
    let mut last = state.now().instant;
    loop {
        tokio::time::sleep(tick).await;
        let now = state.now();
        let away = now.instant.saturating_duration_since(last);
        last = now.instant;
        if now.instant < state.started.instant + state.cfg.startup_grace {
            continue;
        }
        if away > state.cfg.lease_timeout {
            let grace = state.cfg.startup_grace.max(state.cfg.lease_timeout);
            let n = state.sched().extend_leases(now.instant + grace);
            tracing::warn!(
                "the coordinator did not run for {:.1} s (stopped, or its machine paused): \
                 {n} leases get {:.0} s to be heard from before they expire",
                away.as_secs_f64(),
                grace.as_secs_f64()
            );
            continue;
        }
        let res = {
            let mut s = state.sched();
            // Purged jobs' pages go back to the file system a few MB at a time; a database
            // file removed from under the coordinator is reported.
            s.tend_store();
            s.expire(now)
        };
        match res {
            Ok(0) => {}
            Ok(_) => state.notify.notify_waiters(),
            Err(e) => tracing::error!("expiring leases: {e}"),
        }
    }
}

/// Serves the API on `listener` until `shutdown` completes, then stops gracefully (in-flight
/// requests get a few seconds; long-polls return at once).
pub async fn run(
    listener: tokio::net::TcpListener,
    config: Config,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> anyhow::Result<()> {
    let addr = listener.local_addr()?;
    check_exposure(addr.ip(), &config)?;
    let state = AppState::open(config)?;
    tracing::info!(%addr, "coordinator listening");
    let checker = tokio::spawn(timeout_checker(state.clone()));
    let st = state.clone();
    tokio::spawn(async move {
        shutdown.await;
        st.begin_shutdown();
    });
    let mut rx = state.shutdown_rx();
    let hard_stop = async move {
        let _ = rx.wait_for(|v| *v).await;
        tokio::time::sleep(Duration::from_secs(5)).await;
    };
    let mut limits = state.cfg.serve_limits;
    limits.max_connections = listen::fit_file_limit(limits.max_connections);
    let server = listen::serve(listener, app(state.clone()), limits, state.shutdown_rx());
    let res = tokio::select! {
        () = server => Ok(()),
        _ = hard_stop => {
            tracing::warn!("connections still open 5 s after shutdown; closing them");
            Ok(())
        }
    };
    checker.abort();
    let _ = checker.await;
    // A coordinator restarted in the same process may open the data directory at once.
    drop(std::mem::take(
        &mut *state.lock.lock().unwrap_or_else(|e| e.into_inner()),
    ));
    res
}
