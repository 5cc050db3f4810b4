//! How long a large result holds up the rest of the API: one `bdpt` result of a 64×64 tile
//! carrying a splat for every pixel of a 4096 × 4096 frame (about 470 MB) is uploaded while
//! another client reads the job's status (which takes the scheduler's lock) every 10 ms.
//! Prints the upload's time and the slowest status read during it. The data directory is in
//! the system's temporary folder (`TMPDIR`): put it on a disk, not in memory.
//!
//! `cargo bench -p raytile-coordinator --bench large_result`

mod common;

use raytile_proto as proto;
use std::sync::Arc;
use std::time::{Duration, Instant};

const SIDE: u32 = 4096;

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> anyhow::Result<()> {
    let farm = common::Farm::start().await?;
    let job = farm
        .job(proto::RenderOverrides {
            width: Some(SIDE),
            height: Some(SIDE),
            spp: Some(1),
            tile_size: Some(64),
            integrator: Some(proto::IntegratorKind::Bdpt),
            ..Default::default()
        })
        .await?;
    let reg = farm.register("bench").await?;
    let l = farm
        .lease(&reg.worker_id)
        .await?
        .ok_or_else(|| anyhow::anyhow!("no task to lease"))?;
    let acc = raytile_core::TileAccum {
        tile: l.tile,
        pixels: vec![[0.5, 0.5, 0.5, 1.0]; l.tile.pixel_count()],
        bad_samples: 0,
        splats: (0..SIDE * SIDE).map(|i| (i, [1 << 20; 3])).collect(),
        coverage: Vec::new(),
    };
    let body = proto::tile::encode(&acc, l.pass);
    drop(acc);
    let mb = body.len() as f64 / 1e6;

    let done = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let poll = {
        let (http, url, done) = (
            farm.http.clone(),
            format!("{}/v1/jobs/{}", farm.base, job.id),
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
    let reply = farm.upload(&reg.worker_id, &l, body).await?;
    let upload = start.elapsed();
    done.store(true, std::sync::atomic::Ordering::Relaxed);
    let (slowest, n) = poll.await??;
    anyhow::ensure!(reply.accepted, "the result was not accepted: {reply:?}");
    println!(
        "a {mb:.0} MB bdpt result stored in {:.2} s; the slowest of {n} status reads during it took {:.3} s",
        upload.as_secs_f64(),
        slowest.as_secs_f64()
    );
    farm.stop().await;
    Ok(())
}
