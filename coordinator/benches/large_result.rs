//! How long a large result holds up the rest of the API: one `bdpt` result of a 64×64 tile
//! carrying a splat for every pixel of a 4096 × 4096 frame (about 470 MB) is uploaded while
//! another client reads the job's status (which takes the scheduler's lock) every 10 ms.
//! Prints the upload's time and the slowest status read during it. The data directory is in
//! the system's temporary folder (`TMPDIR`): put it on a disk, not in memory.
//!
//! `cargo bench -p raytile-coordinator --bench large_result`

use raytile_coordinator::{Config, LoadedScene};
use raytile_proto as proto;
use std::sync::Arc;
use std::time::{Duration, Instant};

const SIDE: u32 = 4096;

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
            width: Some(SIDE),
            height: Some(SIDE),
            spp: Some(1),
            tile_size: Some(64),
            integrator: Some(proto::IntegratorKind::Bdpt),
            ..Default::default()
        },
        ..Default::default()
    };
    let job: proto::JobStatus = http
        .post(format!("{base}/v1/jobs"))
        .json(&req)
        .send()
        .await?
        .error_for_status()?
        .json()
        .await?;
    let reg: proto::Registered = http
        .post(format!("{base}/v1/workers"))
        .json(&proto::RegisterRequest {
            name: "bench".into(),
            threads: 1,
            render_version: raytile_core::RENDER_VERSION,
        })
        .send()
        .await?
        .json()
        .await?;
    let l: proto::Lease = http
        .post(format!("{base}/v1/workers/{}/lease", reg.worker_id))
        .send()
        .await?
        .json()
        .await?;
    let acc = raytile_core::TileAccum {
        tile: l.tile,
        pixels: vec![[0.5, 0.5, 0.5, 1.0]; l.tile.pixel_count()],
        bad_samples: 0,
        splats: (0..SIDE * SIDE).map(|i| (i, [1 << 20; 3])).collect(),
    };
    let body = proto::tile::encode(&acc, l.pass);
    drop(acc);
    let mb = body.len() as f64 / 1e6;

    let done = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let poll = {
        let (http, url, done) = (
            http.clone(),
            format!("{base}/v1/jobs/{}", job.id),
            done.clone(),
        );
        tokio::spawn(async move {
            let mut slowest = Duration::ZERO;
            let mut n = 0;
            while !done.load(std::sync::atomic::Ordering::Relaxed) {
                let t = Instant::now();
                http.get(&url).send().await?.error_for_status()?;
                slowest = slowest.max(t.elapsed());
                n += 1;
                tokio::time::sleep(Duration::from_millis(10)).await;
            }
            anyhow::Ok((slowest, n))
        })
    };
    let start = Instant::now();
    let reply: proto::ResultReply = http
        .put(format!(
            "{base}/v1/jobs/{}/tasks/{}/result?worker={}&lease={}",
            l.job, l.task, reg.worker_id, l.lease_id
        ))
        .body(body)
        .send()
        .await?
        .error_for_status()?
        .json()
        .await?;
    let upload = start.elapsed();
    done.store(true, std::sync::atomic::Ordering::Relaxed);
    let (slowest, n) = poll.await??;
    anyhow::ensure!(reply.accepted, "the result was not accepted: {reply:?}");
    println!(
        "a {mb:.0} MB bdpt result stored in {:.2} s; the slowest of {n} status reads during it took {:.3} s",
        upload.as_secs_f64(),
        slowest.as_secs_f64()
    );
    let _ = stop.send(true);
    let _ = server.await;
    Ok(())
}
