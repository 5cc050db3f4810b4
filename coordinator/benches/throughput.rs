//! Coordinator throughput: synthetic workers on loopback lease 64×64 tiles and upload made-up
//! results as fast as they can. Prints leases+results per second.
//!
//! `cargo bench -p raytile-coordinator --bench throughput` (or `cargo run` it in debug for a
//! quick look; numbers from debug builds are not comparable).

use raytile_coordinator::{Config, LoadedScene};
use raytile_proto as proto;
use std::sync::Arc;
use std::time::{Duration, Instant};

const WORKERS: usize = 8;

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let mut cfg = Config::new(dir.path());
    cfg.scene_loader = Arc::new(|_p: &std::path::Path| Ok(LoadedScene::default()));
    cfg.startup_grace = Duration::ZERO;
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let base = format!("http://{}", listener.local_addr()?);
    let (stop, rx) = tokio::sync::watch::channel(false);
    let mut rx2 = rx.clone();
    let server = tokio::spawn(raytile_coordinator::run(listener, cfg, async move {
        let _ = rx2.wait_for(|v| *v).await;
    }));
    let http = reqwest::Client::new();
    let scene: proto::SceneCreated = http
        .post(format!("{base}/v1/scenes"))
        .body(r#"{"objects": []}"#)
        .send()
        .await?
        .json()
        .await?;
    let req = proto::JobRequest {
        scene: scene.id,
        overrides: proto::RenderOverrides {
            width: Some(1024),
            height: Some(1024),
            spp: Some(4),
            passes: Some(4),
            tile_size: Some(64),
            ..Default::default()
        },
        ..Default::default()
    };
    let job: proto::JobStatus = http
        .post(format!("{base}/v1/jobs"))
        .json(&req)
        .send()
        .await?
        .json()
        .await?;
    let start = Instant::now();
    let mut tasks = Vec::new();
    for i in 0..WORKERS {
        let (http, base) = (http.clone(), base.clone());
        tasks.push(tokio::spawn(async move {
            let reg: proto::Registered = http
                .post(format!("{base}/v1/workers"))
                .json(&proto::RegisterRequest {
                    name: format!("bench-{i}"),
                    threads: 1,
                    render_version: raytile_core::RENDER_VERSION,
                })
                .send()
                .await?
                .json()
                .await?;
            let mut n = 0u64;
            loop {
                let r = http
                    .post(format!("{base}/v1/workers/{}/lease", reg.worker_id))
                    .send()
                    .await?;
                if r.status() == 204 {
                    return anyhow::Ok(n);
                }
                let l: proto::Lease = r.json().await?;
                let acc = raytile_core::TileAccum {
                    tile: l.tile,
                    pixels: vec![[0.5, 0.5, 0.5, 1.0]; l.tile.pixel_count()],
                    bad_samples: 0,
                    splats: Vec::new(),
                };
                http.put(format!(
                    "{base}/v1/jobs/{}/tasks/{}/result?worker={}&lease={}",
                    l.job, l.task, reg.worker_id, l.lease_id
                ))
                .body(proto::tile::encode(&acc, l.pass))
                .send()
                .await?
                .error_for_status()?;
                n += 1;
            }
        }));
    }
    let mut total = 0;
    for t in tasks {
        total += t.await??;
    }
    let secs = start.elapsed().as_secs_f64();
    let st: proto::JobStatus = http
        .get(format!("{base}/v1/jobs/{}", job.id))
        .send()
        .await?
        .json()
        .await?;
    println!(
        "{total} tasks (64×64 tiles) by {WORKERS} synthetic workers in {secs:.2} s: {:.0} leases+results/s; job {}",
        total as f64 / secs,
        st.state.name()
    );
    let _ = stop.send(true);
    let _ = server.await;
    Ok(())
}
