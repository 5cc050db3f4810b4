//! `raytile-worker`: renders tiles for a coordinator.

use clap::Parser;
use std::path::PathBuf;

// A build for newer CPUs stops before `main` on a CPU without them, with a message.
raytile_core::cpu_gate!();

/// Large blocks (a big scene's arrays) in mappings of their own: less memory held while a
/// scene loads and builds (see `raytile_core::alloc`).
#[global_allocator]
static ALLOC: raytile_core::alloc::LargeBlocks = raytile_core::alloc::LargeBlocks;

/// A raytile render worker.
#[derive(Parser, Debug)]
#[command(version)]
struct Args {
    /// Coordinator URL, e.g. http://127.0.0.1:8080.
    #[arg(long, env = "RAYTILE_COORDINATOR")]
    coordinator: String,
    /// Bearer token: the coordinator's worker token (its --worker-token) when it has one,
    /// else its --token.
    #[arg(long, env = "RAYTILE_TOKEN", hide_env_values = true)]
    token: Option<String>,
    /// Render threads (default, or 0: every core; at most 1024).
    #[arg(long, env = "RAYTILE_THREADS", default_value_t = 0, value_parser = threads_flag())]
    threads: usize,
    /// Name shown by the coordinator (default: host name).
    #[arg(long, env = "RAYTILE_NAME")]
    name: Option<String>,
    /// Scene cache folder.
    #[arg(long, env = "RAYTILE_CACHE_DIR")]
    cache_dir: Option<PathBuf>,
    /// Most disk space the scene cache folder may take, in MiB: beyond it the scenes used
    /// least recently are removed (those a worker sharing the folder is reading, or used in
    /// the last two minutes, stay). 0: no bound.
    #[arg(long, env = "RAYTILE_CACHE_MAX_MB", default_value_t = raytile_worker::DEFAULT_CACHE_MAX_BYTES >> 20)]
    cache_max_mb: u64,
    /// Memory for built scenes kept between jobs, in MiB: a second job on a scene starts at
    /// once. Beyond it, the least recently used scenes are dropped (the scene in use is kept,
    /// however large).
    #[arg(long, env = "RAYTILE_SCENE_CACHE_MB", default_value_t = (raytile_worker::DEFAULT_SCENE_CACHE >> 20) as u64)]
    scene_cache_mb: u64,
    /// Most memory loading one scene may allocate for its decoded data (texels, vertices), in
    /// MiB: a larger scene fails its tasks with a message.
    #[arg(long, env = "RAYTILE_SCENE_MEMORY_MB", default_value_t = raytile_worker::SceneLoadLimits::default().max_memory >> 20)]
    scene_memory_mb: u64,
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
    // Which build serves this host: the default one, or one for newer CPUs (the same bits).
    let features = raytile_core::cpu::compiled_features();
    tracing::info!(
        "raytile-worker {}, built for {}",
        env!("CARGO_PKG_VERSION"),
        if features.is_empty() {
            format!("baseline {}", std::env::consts::ARCH)
        } else {
            format!("CPUs with {}", features.join(", "))
        }
    );
    let mut cfg = raytile_worker::Config::new(a.coordinator);
    cfg.token = a.token.filter(|t| !t.is_empty());
    cfg.threads = a.threads;
    if let Some(n) = a.name {
        cfg.name = n;
    }
    if let Some(d) = a.cache_dir {
        cfg.cache_dir = d;
    }
    cfg.cache_max_bytes = (a.cache_max_mb > 0).then(|| a.cache_max_mb.saturating_mul(1 << 20));
    let budget = usize::try_from(a.scene_cache_mb.saturating_mul(1 << 20)).unwrap_or(usize::MAX);
    cfg.scene_cache = std::sync::Arc::new(raytile_worker::SceneCache::new(budget));
    cfg.scene_limits.max_memory = a.scene_memory_mb.saturating_mul(1 << 20);
    if let Err(e) = raytile_worker::run(cfg, raytile_proto::shutdown_signal()).await {
        eprintln!("raytile-worker: {e:#}");
        std::process::exit(1);
    }
}

/// The parser of `--threads`: 0 (every core) to [`raytile_worker::MAX_THREADS`].
fn threads_flag() -> clap::builder::RangedU64ValueParser<usize> {
    clap::builder::RangedU64ValueParser::<usize>::new()
        .range(0..=raytile_worker::MAX_THREADS as u64)
}
