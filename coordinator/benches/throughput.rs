//! Coordinator throughput: synthetic workers on loopback lease 64×64 tiles and upload made-up
//! results as fast as they can. Prints leases+results per second.
//!
//! `cargo bench -p raytile-coordinator --bench throughput` (or `cargo run` it in debug for a
//! quick look; numbers from debug builds are not comparable).

mod common;

use raytile_proto as proto;
use std::sync::Arc;
use std::time::Instant;

const WORKERS: usize = 8;

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> anyhow::Result<()> {
    let farm = Arc::new(common::Farm::start().await?);
    let job = farm
        .job(proto::RenderOverrides {
            width: Some(1024),
            height: Some(1024),
            spp: Some(4),
            passes: Some(4),
            tile_size: Some(64),
            ..Default::default()
        })
        .await?;
    let start = Instant::now();
    let mut tasks = Vec::new();
    for i in 0..WORKERS {
        let farm = farm.clone();
        tasks.push(tokio::spawn(async move {
            let reg = farm.register(&format!("bench-{i}")).await?;
            let mut n = 0u64;
            while let Some(l) = farm.lease(&reg.worker_id).await? {
                let acc = raytile_core::TileAccum {
                    tile: l.tile,
                    pixels: vec![[0.5, 0.5, 0.5, 1.0]; l.tile.pixel_count()],
                    bad_samples: 0,
                    splats: Vec::new(),
                    coverage: Vec::new(),
                };
                farm.upload(&reg.worker_id, &l, proto::tile::encode(&acc, l.pass))
                    .await?;
                n += 1;
            }
            anyhow::Ok(n)
        }));
    }
    let mut total = 0;
    for t in tasks {
        total += t.await??;
    }
    let secs = start.elapsed().as_secs_f64();
    let st: proto::JobStatus = farm
        .http
        .get(format!("{}/v1/jobs/{}", farm.base, job.id))
        .send()
        .await?
        .json()
        .await?;
    println!(
        "{total} tasks (64×64 tiles) by {WORKERS} synthetic workers in {secs:.2} s: {:.0} leases+results/s; job {}",
        total as f64 / secs,
        st.state.name()
    );
    if let Ok(farm) = Arc::try_unwrap(farm) {
        farm.stop().await;
    }
    Ok(())
}
