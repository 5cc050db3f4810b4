//! What the coordinator's benches share: a coordinator on loopback with a fake scene loader,
//! and an empty scene uploaded to it.

use raytile_coordinator::{Config, LoadedScene};
use raytile_proto as proto;
use std::sync::Arc;
use std::time::Duration;

/// A coordinator serving on a loopback port, its data in a temporary folder.
pub struct Farm {
    /// `http://127.0.0.1:PORT`.
    pub base: String,
    /// The scene id of an empty scene uploaded to it.
    pub scene: String,
    pub http: reqwest::Client,
    stop: tokio::sync::watch::Sender<bool>,
    server: tokio::task::JoinHandle<anyhow::Result<()>>,
    _dir: tempfile::TempDir,
}

impl Farm {
    /// Starts a coordinator whose scenes all load as empty ones (no scene is rendered), and
    /// uploads one scene.
    pub async fn start() -> anyhow::Result<Farm> {
        let dir = tempfile::tempdir()?;
        let mut cfg = Config::new(dir.path());
        cfg.scene_loader = Arc::new(|_p: &std::path::Path| Ok(LoadedScene::default()));
        cfg.startup_grace = Duration::ZERO;
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
        let base = format!("http://{}", listener.local_addr()?);
        let (stop, mut rx) = tokio::sync::watch::channel(false);
        let server = tokio::spawn(raytile_coordinator::run(listener, cfg, async move {
            let _ = rx.wait_for(|v| *v).await;
        }));
        let http = reqwest::Client::new();
        let scene: proto::SceneCreated = http
            .post(format!("{base}/v1/scenes"))
            .body(r#"{"objects": []}"#)
            .send()
            .await?
            .error_for_status()?
            .json()
            .await?;
        Ok(Farm {
            base,
            scene: scene.id,
            http,
            stop,
            server,
            _dir: dir,
        })
    }

    /// Submits a job of the scene with `overrides`.
    pub async fn job(&self, overrides: proto::RenderOverrides) -> anyhow::Result<proto::JobStatus> {
        let req = proto::JobRequest {
            scene: self.scene.clone(),
            overrides,
            ..Default::default()
        };
        Ok(self
            .http
            .post(format!("{}/v1/jobs", self.base))
            .json(&req)
            .send()
            .await?
            .error_for_status()?
            .json()
            .await?)
    }

    /// Registers a worker of this renderer version.
    pub async fn register(&self, name: &str) -> anyhow::Result<proto::Registered> {
        Ok(self
            .http
            .post(format!("{}/v1/workers", self.base))
            .json(&proto::RegisterRequest {
                name: name.into(),
                threads: 1,
                render_version: raytile_core::RENDER_VERSION,
            })
            .send()
            .await?
            .error_for_status()?
            .json()
            .await?)
    }

    /// Leases a task for `worker`: `None` when there is no more work.
    pub async fn lease(&self, worker: &str) -> anyhow::Result<Option<proto::Lease>> {
        let r = self
            .http
            .post(format!("{}/v1/workers/{worker}/lease", self.base))
            .send()
            .await?
            .error_for_status()?;
        if r.status() == 204 {
            return Ok(None);
        }
        Ok(Some(r.json().await?))
    }

    /// Uploads `body` as the result of `lease`, held by `worker`.
    pub async fn upload(
        &self,
        worker: &str,
        lease: &proto::Lease,
        body: Vec<u8>,
    ) -> anyhow::Result<proto::ResultReply> {
        Ok(self
            .http
            .put(format!(
                "{}/v1/jobs/{}/tasks/{}/result?worker={worker}&lease={}",
                self.base, lease.job, lease.task, lease.lease_id
            ))
            .body(body)
            .send()
            .await?
            .error_for_status()?
            .json()
            .await?)
    }

    /// Stops the coordinator and waits for it.
    pub async fn stop(self) {
        let _ = self.stop.send(true);
        let _ = self.server.await;
    }
}
