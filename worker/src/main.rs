//! `raytile-worker`: renders tiles for a coordinator.

use clap::Parser;
use std::path::PathBuf;

/// A raytile render worker.
#[derive(Parser, Debug)]
#[command(version)]
struct Args {
    /// Coordinator URL, e.g. http://127.0.0.1:8080.
    #[arg(long, env = "RAYTILE_COORDINATOR")]
    coordinator: String,
    /// Bearer token.
    #[arg(long, env = "RAYTILE_TOKEN", hide_env_values = true)]
    token: Option<String>,
    /// Render threads (default: every core).
    #[arg(long, env = "RAYTILE_THREADS", default_value_t = 0)]
    threads: usize,
    /// Name shown by the coordinator (default: host name).
    #[arg(long, env = "RAYTILE_NAME")]
    name: Option<String>,
    /// Scene cache folder.
    #[arg(long, env = "RAYTILE_CACHE_DIR")]
    cache_dir: Option<PathBuf>,
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
    let mut cfg = raytile_worker::Config::new(a.coordinator);
    cfg.token = a.token.filter(|t| !t.is_empty());
    cfg.threads = a.threads;
    if let Some(n) = a.name {
        cfg.name = n;
    }
    if let Some(d) = a.cache_dir {
        cfg.cache_dir = d;
    }
    if let Err(e) = raytile_worker::run(cfg, raytile_proto::shutdown_signal()).await {
        eprintln!("raytile-worker: {e:#}");
        std::process::exit(1);
    }
}
