//! `raytile cluster`: a coordinator and N workers in one process, for one machine.

use crate::submit::{self, JobArgs};
use anyhow::Context;
use clap::Args;
use raytile_core::film::ImageFormat;
use raytile_proto::client::Client;
use std::path::PathBuf;

/// `raytile cluster` flags.
#[derive(Args, Debug)]
pub struct ClusterArgs {
    /// Number of local workers (at most 256).
    #[arg(long, default_value_t = 2,
          value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=256))]
    pub workers: usize,
    /// Render threads in total, split among the workers, each given at least one (default:
    /// every core; at most 1024).
    #[arg(long, value_parser = crate::threads_flag(1))]
    pub threads: Option<usize>,
    /// Address of the coordinator (default: 127.0.0.1:8080; with --render, any free port
    /// on 127.0.0.1).
    #[arg(long)]
    pub listen: Option<String>,
    /// Data directory (default: a temporary one, removed at exit).
    #[arg(long)]
    pub data_dir: Option<PathBuf>,
    /// Bearer token for the coordinator.
    #[arg(long, env = "RAYTILE_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// A token for workers apart from --token (the local workers use it; remote workers need
    /// it, users --token): see `raytile-coordinator --help`.
    #[arg(long, env = "RAYTILE_WORKER_TOKEN", hide_env_values = true)]
    pub worker_token: Option<String>,
    /// Allow a non-loopback --listen address without a token (anyone who reaches it may
    /// submit jobs).
    #[arg(long)]
    pub insecure: bool,
    /// Render this scene, write the image to -o and exit.
    #[arg(long)]
    pub render: Option<PathBuf>,
    /// Output image for --render (.png, .exr, .hdr; default render.png).
    #[arg(short = 'o', long)]
    pub output: Option<PathBuf>,
    /// Job settings for --render.
    #[command(flatten)]
    pub job: JobArgs,
}

/// Runs `raytile cluster`.
pub fn run(a: ClusterArgs) -> anyhow::Result<()> {
    let output = a
        .output
        .clone()
        .unwrap_or_else(|| PathBuf::from("render.png"));
    if a.render.is_some() {
        // Before the cluster starts: an unknown extension or a folder that does not exist
        // would fail only after the render.
        ImageFormat::from_path(&output)?;
        raytile_core::film::check_writable(&output)?;
    } else if a.output.is_some()
        || a.job.priority.is_some()
        || a.job.overrides != raytile_proto::settings::RenderOverrides::default()
    {
        // Without --render the cluster serves the jobs clients submit, with their settings.
        anyhow::bail!(
            "-o and the job settings (--spp, --width, --integrator, --priority...) are for \
             --render; without it, the cluster serves the jobs clients submit (raytile submit), \
             with their own settings"
        );
    }
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    rt.block_on(cluster(a, output))
}

async fn cluster(a: ClusterArgs, output: PathBuf) -> anyhow::Result<()> {
    // The scene loader's warnings are said once, by the job's submission (as `raytile render`
    // says them), not again by the coordinator's check and by every worker's load.
    let _ = tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| "warn,raytile_core::scene=error".into()),
        )
        .with_writer(std::io::stderr)
        .try_init();
    let tmp = tempfile::tempdir()?;
    let data_dir = a
        .data_dir
        .clone()
        .unwrap_or_else(|| tmp.path().join("data"));
    let mut cfg = raytile_coordinator::Config::new(&data_dir);
    cfg.token = raytile_coordinator::token_setting(a.token.clone());
    cfg.worker_token = raytile_coordinator::token_setting(a.worker_token.clone());
    cfg.insecure = a.insecure;
    cfg.startup_grace = std::time::Duration::from_secs(5);
    // The job of --render may have any tile size `raytile render` takes (within the limit on
    // tasks per job): it is the user's own. Serving clients, the cluster keeps a farm
    // coordinator's floor of 16 against floods of tiny tasks.
    if a.render.is_some() {
        cfg.limits.min_tile_size = 1;
    }
    let listen = a.listen.clone().unwrap_or_else(|| {
        if a.render.is_some() {
            "127.0.0.1:0".into()
        } else {
            "127.0.0.1:8080".into()
        }
    });
    let addr: std::net::SocketAddr = listen
        .parse()
        .map_err(|e| anyhow::anyhow!("--listen {listen}: {e}"))?;
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .with_context(|| format!("cannot listen on {addr}"))?;
    let addr = listener.local_addr()?;
    let base = format!("http://{addr}");
    // Workers stop first (handing back leases, delivering their last result), then the
    // coordinator: each has its own signal.
    let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
    let (stop_workers_tx, stop_workers_rx) = tokio::sync::watch::channel(false);
    let stopped = |mut rx: tokio::sync::watch::Receiver<bool>| async move {
        let _ = rx.wait_for(|v| *v).await;
    };
    let mut coord = tokio::spawn(raytile_coordinator::run(
        listener,
        cfg,
        stopped(stop_rx.clone()),
    ));
    // The coordinator refuses to start on a bad data folder or an exposed address without a
    // token: wait until it answers, or stop with its error, before any worker starts.
    let api = Client::new(&base, a.token.clone())?;
    loop {
        tokio::select! {
            r = &mut coord => return Err(coordinator_stopped(r)),
            up = api.health() => match up {
                Ok(_) => break,
                Err(_) => tokio::time::sleep(std::time::Duration::from_millis(20)).await,
            },
        }
    }
    let total = a
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let n = a.workers.max(1);
    let mut workers = Vec::new();
    let local_token = raytile_coordinator::token_setting(a.worker_token.clone())
        .or_else(|| raytile_coordinator::token_setting(a.token.clone()));
    // One cache of built scenes for every local worker: a scene is built once per process.
    let scene_cache = std::sync::Arc::new(raytile_worker::SceneCache::default());
    for i in 0..n {
        let mut wc = raytile_worker::Config::new(base.clone());
        wc.scene_cache = scene_cache.clone();
        wc.token = local_token.clone();
        wc.threads = (total / n + usize::from(i < total % n)).max(1);
        wc.name = format!("local-{i}");
        wc.cache_dir = tmp.path().join(format!("cache-{i}"));
        workers.push(tokio::spawn(raytile_worker::run(
            wc,
            stopped(stop_workers_rx.clone()),
        )));
    }
    let work = async {
        match &a.render {
            Some(scene) => tokio::select! {
                r = submit::submit_and_follow(&api, scene, &a.job, true, Some(output.as_path())) => {
                    r.map(|_| ())
                }
                _ = raytile_proto::shutdown_signal() => {
                    Err(anyhow::anyhow!("stopped by a signal before the render was done"))
                }
            },
            None => {
                eprintln!(
                    "raytile cluster: coordinator on {base} with {n} workers; Ctrl-C to stop"
                );
                raytile_proto::shutdown_signal().await;
                Ok(())
            }
        }
    };
    // A coordinator that stops on its own (its database failing, say) ends the cluster with
    // its error rather than leaving the workers asking a dead address.
    let (result, coord_done) = tokio::select! {
        r = work => (r, None),
        r = &mut coord => (Err(coordinator_stopped(r)), Some(())),
    };
    let _ = stop_workers_tx.send(true);
    for w in workers {
        let _ = w.await;
    }
    let _ = stop_tx.send(true);
    if coord_done.is_none() {
        let _ = coord.await;
    }
    result
}

/// The error of a coordinator task that ended before it was asked to stop.
fn coordinator_stopped(r: Result<anyhow::Result<()>, tokio::task::JoinError>) -> anyhow::Error {
    match r {
        Ok(Err(e)) => e.context("the coordinator stopped"),
        Ok(Ok(())) => anyhow::anyhow!("the coordinator stopped unexpectedly"),
        Err(e) => anyhow::anyhow!("the coordinator failed: {e}"),
    }
}
