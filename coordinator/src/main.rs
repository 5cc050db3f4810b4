//! `raytile-coordinator`: serves the farm's HTTP API.

use clap::Parser;
use raytile_coordinator::listen::ServeLimits;
use raytile_coordinator::{core_scene_loader, run, Config, Limits, SceneLimits};
use std::path::PathBuf;
use std::time::Duration;

// A build for newer CPUs stops before `main` on a CPU without them, with a message.
raytile_core::cpu_gate!();

/// The raytile coordinator: scene store, job queue, tile leases.
#[derive(Parser, Debug)]
#[command(version)]
struct Args {
    /// Address to listen on.
    #[arg(long, env = "RAYTILE_LISTEN", default_value = "127.0.0.1:8080")]
    listen: String,
    /// Where the database and scenes live.
    #[arg(long, env = "RAYTILE_DATA_DIR", default_value = "raytile-data")]
    data_dir: PathBuf,
    /// Bearer token required on every endpoint but /healthz.
    #[arg(long, env = "RAYTILE_TOKEN", hide_env_values = true)]
    token: Option<String>,
    /// A token for workers, apart from --token: the workers' endpoints (register, lease,
    /// heartbeat, failure, release, result) then take it and only it, the others take
    /// --token and only it. Give workers this one and users --token.
    #[arg(long, env = "RAYTILE_WORKER_TOKEN", hide_env_values = true)]
    worker_token: Option<String>,
    /// Allow a non-loopback address without a token.
    #[arg(long)]
    insecure: bool,
    /// Lease lifetime without a heartbeat, in seconds.
    #[arg(long, env = "RAYTILE_LEASE_TIMEOUT", default_value_t = 30.0)]
    lease_timeout: f64,
    /// Start-up grace period before leases expire, in seconds.
    #[arg(long, env = "RAYTILE_STARTUP_GRACE", default_value_t = 30.0)]
    startup_grace: f64,
    /// Failures of one tile that fail its job.
    #[arg(long, default_value_t = 3)]
    max_task_failures: u32,
    /// Largest scene upload in bytes.
    #[arg(long, default_value_t = Limits::default().max_upload_bytes)]
    max_upload_bytes: u64,
    /// Largest tile result in bytes (a `bdpt` job whose tile results could be larger, with a
    /// splat for every pixel of its frame, is refused: 2 GiB allows 41 M pixels).
    #[arg(long, default_value_t = Limits::default().max_result_bytes)]
    max_result_bytes: u64,
    /// Most unfinished jobs at once (more: 429).
    #[arg(long, default_value_t = Limits::default().max_queued_jobs)]
    max_queued_jobs: usize,
    /// Most tasks of all unfinished jobs together (a job that would go over: 429).
    #[arg(long, default_value_t = Limits::default().max_queued_tasks)]
    max_queued_tasks: u64,
    /// Largest width × height of a job (more: 422 naming width).
    #[arg(long, default_value_t = Limits::default().max_pixels)]
    max_pixels: u64,
    /// Largest samples per pixel of a job (more: 422 naming spp).
    #[arg(long, default_value_t = Limits::default().max_spp)]
    max_spp: u32,
    /// Most progressive passes of a job (more: 422 naming passes).
    #[arg(long, default_value_t = Limits::default().max_passes)]
    max_passes: u32,
    /// Smallest tile edge of a job, in pixels (less: 422 naming tile_size).
    #[arg(long, default_value_t = Limits::default().min_tile_size)]
    min_tile_size: u32,
    /// Most tasks (tiles × passes) of one job (more: 422 naming tile_size or passes).
    #[arg(long, default_value_t = Limits::default().max_tasks_per_job)]
    max_tasks_per_job: u64,
    /// Longest a worker's lease request waits for work, in seconds.
    #[arg(long, default_value_t = 30.0)]
    long_poll_max: f64,
    /// Largest file an uploaded scene may name (and the scene file itself), in bytes.
    #[arg(long, default_value_t = SceneLimits::default().max_file_bytes)]
    max_scene_file_bytes: u64,
    /// Most bytes an uploaded scene may read, all its files together.
    #[arg(long, default_value_t = SceneLimits::default().max_scene_bytes)]
    max_scene_bytes: u64,
    /// Most memory checking one uploaded scene may allocate for decoded data, in bytes.
    #[arg(long, default_value_t = SceneLimits::default().max_parse_memory)]
    max_parse_memory: u64,
    /// Most uploaded scenes checked at once; further uploads wait.
    #[arg(long, default_value_t = SceneLimits::default().max_parallel_parses)]
    scene_parses: usize,
    /// How long an upload waits for a check to end before it is answered 503, in seconds.
    #[arg(long, default_value_t = SceneLimits::default().parse_wait.as_secs_f64())]
    scene_parse_wait: f64,
    /// Most job images composed and encoded at once (each holds its whole frame while it
    /// runs); further image requests wait.
    #[arg(long, default_value_t = 2)]
    image_encodes: usize,
    /// How long an image request waits for another to end before it is answered 503, in
    /// seconds.
    #[arg(long, default_value_t = 30.0)]
    image_wait: f64,
    /// Most bytes of encoded job images kept for the requests that follow: the newest image of
    /// each job and format, the least recently used dropped first (0 keeps none).
    #[arg(long, default_value_t = raytile_coordinator::IMAGE_CACHE_BYTES)]
    image_cache_bytes: usize,
    /// Most tile results of 1 MiB or more (`bdpt` splats) read and checked at once; each holds
    /// about twice its size in memory meanwhile. Further uploads wait, and are answered 503
    /// (retryable) after 30 s.
    #[arg(long, default_value_t = 2)]
    large_results: usize,
    /// Most connections open at once; more wait to be accepted until one closes. The
    /// open-file limit is raised to fit, where the hard limit allows.
    #[arg(long, default_value_t = ServeLimits::default().max_connections)]
    max_connections: usize,
    /// How long a client has to send a request's headers, in seconds; a keep-alive
    /// connection idle that long is closed.
    #[arg(long, default_value_t = ServeLimits::default().header_timeout.as_secs_f64())]
    header_timeout: f64,
    /// Longest pause between two reads of a request's body, in seconds: an upload that stalls
    /// longer fails.
    #[arg(long, default_value_t = ServeLimits::default().body_timeout.as_secs_f64())]
    body_timeout: f64,
    /// Least average rate of a request's body, in bytes a second, past its first
    /// --body-timeout seconds: an upload that trickles slower fails (400), rather than hold
    /// its connection and a large result's slot for hours. 0 for no least rate.
    #[arg(long, default_value_t = ServeLimits::default().min_body_rate)]
    min_body_rate: u64,
    /// Do not serve: ask the coordinator listening on --listen for /healthz and exit 0 when
    /// it answers 200 (a container health check; images have no curl).
    #[arg(long)]
    healthcheck: bool,
}

fn secs(v: f64, flag: &str) -> anyhow::Result<Duration> {
    Duration::try_from_secs_f64(v)
        .map_err(|_| anyhow::anyhow!("--{flag}: not a valid duration: {v}"))
}

#[tokio::main]
async fn main() {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let a = Args::parse();
    if a.healthcheck {
        match healthcheck(&a.listen) {
            Ok(()) => std::process::exit(0),
            Err(e) => {
                eprintln!("raytile-coordinator: unhealthy: {e:#}");
                std::process::exit(1);
            }
        }
    }
    if let Err(e) = real_main(a).await {
        eprintln!("raytile-coordinator: {e:#}");
        std::process::exit(1);
    }
    // Stopped: every change is stored. A scene check or an image encoding still running on a
    // blocking thread would hold the runtime's end (and the exit) until it finished.
    std::process::exit(0);
}

async fn real_main(a: Args) -> anyhow::Result<()> {
    let mut cfg = Config::new(a.data_dir);
    cfg.token = raytile_coordinator::token_setting(a.token);
    cfg.worker_token = raytile_coordinator::token_setting(a.worker_token);
    cfg.insecure = a.insecure;
    cfg.lease_timeout = secs(a.lease_timeout, "lease-timeout")?;
    cfg.startup_grace = secs(a.startup_grace, "startup-grace")?;
    cfg.max_task_failures = a.max_task_failures;
    cfg.limits.max_upload_bytes = a.max_upload_bytes;
    cfg.limits.max_result_bytes = a.max_result_bytes;
    cfg.limits.max_queued_jobs = a.max_queued_jobs;
    cfg.limits.max_queued_tasks = a.max_queued_tasks;
    cfg.limits.max_pixels = a.max_pixels;
    cfg.limits.max_spp = a.max_spp;
    cfg.limits.max_passes = a.max_passes;
    cfg.limits.min_tile_size = a.min_tile_size;
    cfg.limits.max_tasks_per_job = a.max_tasks_per_job;
    cfg.long_poll_max = secs(a.long_poll_max, "long-poll-max")?;
    cfg.scene_limits = SceneLimits {
        max_file_bytes: a.max_scene_file_bytes,
        max_scene_bytes: a.max_scene_bytes,
        max_parse_memory: a.max_parse_memory,
        max_parallel_parses: a.scene_parses.max(1),
        parse_wait: secs(a.scene_parse_wait, "scene-parse-wait")?,
    };
    cfg.scene_loader = core_scene_loader(cfg.scene_limits.clone());
    cfg.max_parallel_images = a.image_encodes.max(1);
    cfg.image_wait = secs(a.image_wait, "image-wait")?;
    cfg.image_cache_bytes = a.image_cache_bytes;
    if a.large_results == 0 {
        anyhow::bail!("--large-results: must be at least 1");
    }
    cfg.max_parallel_large_results = a.large_results;
    if a.max_connections == 0 {
        anyhow::bail!("--max-connections: must be at least 1");
    }
    cfg.serve_limits = ServeLimits {
        max_connections: a.max_connections,
        header_timeout: secs(a.header_timeout, "header-timeout")?,
        body_timeout: secs(a.body_timeout, "body-timeout")?,
        min_body_rate: a.min_body_rate,
    };
    for (flag, t) in [
        ("header-timeout", cfg.serve_limits.header_timeout),
        ("body-timeout", cfg.serve_limits.body_timeout),
    ] {
        if t.is_zero() || t > Duration::from_secs(86_400) {
            anyhow::bail!("--{flag}: must be more than 0 and at most 86400 seconds");
        }
    }
    let addr: std::net::SocketAddr = a
        .listen
        .parse()
        .map_err(|e| anyhow::anyhow!("--listen {}: {e}", a.listen))?;
    raytile_coordinator::check_exposure(addr.ip(), &cfg)?;
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .map_err(|e| anyhow::anyhow!("cannot listen on {addr}: {e}"))?;
    let shutdown = async {
        raytile_proto::shutdown_signal().await;
        tracing::info!("shutting down");
    };
    run(listener, cfg, shutdown).await
}

/// `GET /healthz` on the address the coordinator listens on (an unspecified address such as
/// 0.0.0.0 is reached on loopback), with short timeouts; Ok when the status is 200.
fn healthcheck(listen: &str) -> anyhow::Result<()> {
    use std::io::{Read, Write};
    let mut addr: std::net::SocketAddr = listen
        .parse()
        .map_err(|e| anyhow::anyhow!("--listen {listen}: {e}"))?;
    if addr.ip().is_unspecified() {
        addr.set_ip(match addr {
            std::net::SocketAddr::V4(_) => std::net::Ipv4Addr::LOCALHOST.into(),
            std::net::SocketAddr::V6(_) => std::net::Ipv6Addr::LOCALHOST.into(),
        });
    }
    let timeout = Duration::from_secs(3);
    let mut s = std::net::TcpStream::connect_timeout(&addr, timeout)?;
    s.set_read_timeout(Some(timeout))?;
    s.set_write_timeout(Some(timeout))?;
    write!(
        s,
        "GET /healthz HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    )?;
    let mut head = Vec::new();
    s.take(4096).read_to_end(&mut head)?;
    let status_line = String::from_utf8_lossy(&head);
    let status_line = status_line.lines().next().unwrap_or("");
    if status_line.split_whitespace().nth(1) == Some("200") {
        Ok(())
    } else {
        anyhow::bail!("{addr}/healthz answered {status_line:?}")
    }
}
