//! The HTTP client of the coordinator's API: one for the workers, `raytile submit` and any other
//! program that talks to a farm. It knows the routes, attaches the bearer token and turns the
//! coordinator's error bodies into [`ClientError`]s that keep the status and the field.
//!
//! Retries are the caller's business: a worker retries an unreachable coordinator for as long as
//! it takes, a user at a terminal wants the error at once. [`ClientError::status`] tells an
//! answer (the coordinator said no) from no answer (it could not be reached).

use crate::api::{
    ErrorBody, FailureReport, HeartbeatReply, JobList, JobRequest, JobStatus, Lease,
    RegisterRequest, Registered, ResultReply, SceneCreated, WorkerList,
};
use crate::scene::SceneFormat;
pub use bytes::Bytes;
pub use reqwest;
pub use reqwest::StatusCode;
use reqwest::{Method, RequestBuilder, Response};
use std::time::Duration;

/// Why a request did not give what was asked for.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    /// The coordinator address is not an `http://` or `https://` URL.
    #[error("bad coordinator URL '{url}': {message}")]
    BadUrl {
        /// The address given.
        url: String,
        /// What is wrong with it.
        message: String,
    },
    /// No answer: connection refused, name not resolved, timed out, connection cut.
    #[error("cannot reach the coordinator at {base}: {message}")]
    Unreachable {
        /// The coordinator's base URL.
        base: String,
        /// The cause, with its whole chain.
        message: String,
    },
    /// The coordinator answered with an error status.
    #[error("coordinator answered {status}: {message}")]
    Status {
        /// The HTTP status.
        status: StatusCode,
        /// The machine-readable code of the error body (`invalid`, `not_found`...), if any.
        code: Option<String>,
        /// The request field the coordinator named, if any (`spp`, `scene`...).
        field: Option<String>,
        /// The coordinator's message (or the raw body when it was not an error body).
        message: String,
    },
    /// A success whose body could not be read or was not what the route returns.
    #[error("unreadable answer from the coordinator: {0}")]
    Body(String),
}

impl ClientError {
    /// The status of an error answer; `None` when there was no answer (or a success answer that
    /// could not be read).
    pub fn status(&self) -> Option<StatusCode> {
        match self {
            Self::Status { status, .. } => Some(*status),
            _ => None,
        }
    }

    /// The request field an error answer names.
    pub fn field(&self) -> Option<&str> {
        match self {
            Self::Status { field, .. } => field.as_deref(),
            _ => None,
        }
    }

    /// Whether the coordinator could not be reached at all (worth retrying later).
    pub fn is_unreachable(&self) -> bool {
        matches!(self, Self::Unreachable { .. })
    }
}

/// reqwest's own message is only "error sending request for url (...)": the cause (DNS,
/// connection refused, timeout) is in the source chain.
fn chain(e: &reqwest::Error) -> String {
    let mut message = e.to_string();
    let mut source = std::error::Error::source(e);
    while let Some(s) = source {
        message.push_str(": ");
        message.push_str(&s.to_string());
        source = s.source();
    }
    message
}

/// A job's frame as `GET /v1/jobs/{id}/image` answers it.
#[derive(Clone, Debug)]
pub struct JobImage {
    /// The encoded image.
    pub bytes: Bytes,
    /// Its `ETag`: `None` when the frame is not one state of the job's stored results (a
    /// result arrived while it was made, or a stored tile was missing or damaged and is left
    /// out).
    pub etag: Option<String>,
    /// The samples its frame's results dropped as NaN, infinite or too large (the
    /// `X-Raytile-Dropped-Samples` header; `None` from a coordinator that does not say).
    pub dropped: Option<u64>,
}

/// A client of one coordinator. Cheap to clone (the connection pool is shared).
#[derive(Clone, Debug)]
pub struct Client {
    http: reqwest::Client,
    base: String,
    token: Option<String>,
}

/// How long a client keeps an idle connection to the coordinator for reuse: less than the
/// coordinator's default header timeout (30 s), after which it closes an idle connection, so a
/// request is not sent on a connection the coordinator is closing at that moment.
pub const POOL_IDLE: Duration = Duration::from_secs(20);

/// How long [`Client::new`]'s requests wait for the next byte of an answer.
pub const READ_TIMEOUT: Duration = Duration::from_secs(300);

/// What is wrong with the certificate store named by `SSL_CERT_FILE` or `SSL_CERT_DIR`, if
/// either is set: with them, `https://` clients trust what they name and the public CAs built
/// in, not the system's store, and a missing file is otherwise silent (until a certificate is
/// refused as of an unknown issuer).
pub fn cert_store_problem() -> Option<String> {
    let file = std::env::var_os("SSL_CERT_FILE").filter(|v| !v.is_empty());
    let dir = std::env::var_os("SSL_CERT_DIR").filter(|v| !v.is_empty());
    if let Some(f) = &file {
        if !std::path::Path::new(f).is_file() {
            return Some(format!(
                "SSL_CERT_FILE={} is not a readable file",
                f.to_string_lossy()
            ));
        }
    }
    if let Some(d) = &dir {
        if !std::path::Path::new(d).is_dir() {
            return Some(format!(
                "SSL_CERT_DIR={} is not a folder",
                d.to_string_lossy()
            ));
        }
    }
    None
}

impl Client {
    /// A client of the coordinator at `base` (`http://farm-host:8080`, or `https://` through a
    /// TLS proxy); an empty token counts as none.
    pub fn new(base: &str, token: Option<String>) -> Result<Client, ClientError> {
        let http = reqwest::Client::builder()
            .connect_timeout(Duration::from_secs(10))
            // A network cut leaves an open connection silent, not closed: a request fails
            // after this long without a byte (ample for the coordinator's check of a large
            // upload) instead of waiting for the kernel to give up on the connection.
            .read_timeout(READ_TIMEOUT)
            .tcp_keepalive(Duration::from_secs(15))
            .pool_idle_timeout(POOL_IDLE)
            .build()
            .map_err(|e| ClientError::BadUrl {
                url: base.into(),
                message: chain(&e),
            })?;
        Client::with_http(http, base, token)
    }

    /// A client that sends through `http` (a worker sets its own timeouts and keep-alive).
    pub fn with_http(
        http: reqwest::Client,
        base: &str,
        token: Option<String>,
    ) -> Result<Client, ClientError> {
        let bad = |message: String| ClientError::BadUrl {
            url: base.into(),
            message,
        };
        let url = reqwest::Url::parse(base).map_err(|e| bad(e.to_string()))?;
        if !matches!(url.scheme(), "http" | "https") || url.host_str().is_none() {
            return Err(bad("expected http://HOST:PORT".into()));
        }
        Ok(Client {
            http,
            base: base.trim_end_matches('/').to_string(),
            token: token.filter(|t| !t.is_empty()),
        })
    }

    /// The coordinator's base URL, without a trailing `/`.
    pub fn base(&self) -> &str {
        &self.base
    }

    /// A request to `path` (`/v1/jobs`) with the token attached: for routes without a method
    /// here, or requests that need more (pass it to [`Client::send`]).
    pub fn request(&self, method: Method, path: &str) -> RequestBuilder {
        let r = self.http.request(method, format!("{}{path}", self.base));
        match &self.token {
            Some(t) => r.bearer_auth(t),
            None => r,
        }
    }

    /// Sends a request; an error status becomes [`ClientError::Status`] with the message and
    /// field of the coordinator's error body.
    pub async fn send(&self, r: RequestBuilder) -> Result<Response, ClientError> {
        let resp = r.send().await.map_err(|e| ClientError::Unreachable {
            base: self.base.clone(),
            message: chain(&e),
        })?;
        let status = resp.status();
        if status.is_success() {
            return Ok(resp);
        }
        let text = resp.text().await.unwrap_or_default();
        Err(match serde_json::from_str::<ErrorBody>(&text) {
            Ok(b) => ClientError::Status {
                status,
                code: Some(b.error.code),
                field: b.error.field,
                message: b.error.message,
            },
            Err(_) => ClientError::Status {
                status,
                code: None,
                field: None,
                message: text.trim().chars().take(500).collect(),
            },
        })
    }

    async fn json<T: serde::de::DeserializeOwned>(
        &self,
        r: RequestBuilder,
    ) -> Result<T, ClientError> {
        self.send(r)
            .await?
            .json()
            .await
            .map_err(|e| ClientError::Body(chain(&e)))
    }

    async fn bytes(&self, r: RequestBuilder) -> Result<Bytes, ClientError> {
        self.send(r)
            .await?
            .bytes()
            .await
            .map_err(|e| ClientError::Body(chain(&e)))
    }

    /// `GET /healthz`.
    pub async fn health(&self) -> Result<crate::api::Health, ClientError> {
        self.json(self.request(Method::GET, "/healthz")).await
    }

    /// `POST /v1/scenes`: uploads a scene (a file's bytes, or an archive of a folder). Without
    /// `format`, the coordinator tells it from the content; `entry` picks the scene file in an
    /// archive.
    pub async fn upload_scene(
        &self,
        body: impl Into<reqwest::Body>,
        format: Option<SceneFormat>,
        entry: Option<&str>,
    ) -> Result<SceneCreated, ClientError> {
        self.json(self.scene_request(format, entry).body(body))
            .await
    }

    /// `POST /v1/scenes` with a body streamed as it is made (`reqwest::Body::wrap_stream`) of
    /// exactly `len` bytes: the length is sent first, so a coordinator refuses an upload over
    /// its limit before any of it is sent.
    pub async fn upload_scene_stream(
        &self,
        body: reqwest::Body,
        len: u64,
        format: Option<SceneFormat>,
        entry: Option<&str>,
    ) -> Result<SceneCreated, ClientError> {
        self.json(
            self.scene_request(format, entry)
                .header(reqwest::header::CONTENT_LENGTH, len)
                .body(body),
        )
        .await
    }

    fn scene_request(&self, format: Option<SceneFormat>, entry: Option<&str>) -> RequestBuilder {
        let mut q: Vec<(&str, &str)> = Vec::new();
        if let Some(f) = format {
            q.push(("format", f.name()));
        }
        if let Some(e) = entry {
            q.push(("entry", e));
        }
        self.request(Method::POST, "/v1/scenes").query(&q)
    }

    /// `POST /v1/jobs`: submits a job.
    pub async fn create_job(&self, req: &JobRequest) -> Result<JobStatus, ClientError> {
        self.json(self.request(Method::POST, "/v1/jobs").json(req))
            .await
    }

    /// `GET /v1/jobs/{id}`.
    pub async fn job(&self, id: &str) -> Result<JobStatus, ClientError> {
        self.json(self.request(Method::GET, &format!("/v1/jobs/{id}")))
            .await
    }

    /// `GET /v1/jobs`.
    pub async fn jobs(&self) -> Result<JobList, ClientError> {
        self.json(self.request(Method::GET, "/v1/jobs")).await
    }

    /// `DELETE /v1/jobs/{id}`: cancels the job; with `purge`, deletes it and its tiles.
    pub async fn cancel_job(&self, id: &str, purge: bool) -> Result<JobStatus, ClientError> {
        let path = format!("/v1/jobs/{id}?purge={purge}");
        self.json(self.request(Method::DELETE, &path)).await
    }

    /// `GET /v1/jobs/{id}/image?format=`: the frame so far, encoded as `format` (`png`, `exr`,
    /// `hdr`: the tracer's `ImageFormat::name`).
    pub async fn job_image(&self, id: &str, format: &str) -> Result<Bytes, ClientError> {
        Ok(self.job_image_tagged(id, format, &[]).await?.bytes)
    }

    /// The same, with the image's `ETag` and the samples its frame dropped; `look` adds query
    /// parameters (a PNG's `exposure` and `tonemap`).
    pub async fn job_image_tagged(
        &self,
        id: &str,
        format: &str,
        look: &[(&str, String)],
    ) -> Result<JobImage, ClientError> {
        let path = format!("/v1/jobs/{id}/image");
        let resp = self
            .send(
                self.request(Method::GET, &path)
                    .query(&[("format", format)])
                    .query(look),
            )
            .await?;
        let etag = resp
            .headers()
            .get(reqwest::header::ETAG)
            .and_then(|v| v.to_str().ok())
            .map(String::from);
        let dropped = resp
            .headers()
            .get("x-raytile-dropped-samples")
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.parse().ok());
        let bytes = resp
            .bytes()
            .await
            .map_err(|e| ClientError::Body(chain(&e)))?;
        Ok(JobImage {
            bytes,
            etag,
            dropped,
        })
    }

    /// `GET /v1/workers`.
    pub async fn workers(&self) -> Result<WorkerList, ClientError> {
        self.json(self.request(Method::GET, "/v1/workers")).await
    }

    /// `POST /v1/workers`: registers a worker.
    pub async fn register(&self, req: &RegisterRequest) -> Result<Registered, ClientError> {
        self.json(self.request(Method::POST, "/v1/workers").json(req))
            .await
    }

    /// `POST /v1/workers/{id}/lease?wait_ms=`: waits up to `wait` for a task (a long poll);
    /// `None` when none came.
    pub async fn lease(
        &self,
        worker_id: &str,
        wait: Duration,
    ) -> Result<Option<Lease>, ClientError> {
        let path = format!("/v1/workers/{worker_id}/lease?wait_ms={}", wait.as_millis());
        // The coordinator answers within `wait`; the margin covers a slow network.
        let r = self
            .request(Method::POST, &path)
            .timeout(wait + Duration::from_secs(10));
        let resp = self.send(r).await?;
        if resp.status() == StatusCode::NO_CONTENT {
            return Ok(None);
        }
        resp.json()
            .await
            .map(Some)
            .map_err(|e| ClientError::Body(chain(&e)))
    }

    /// `GET /v1/scenes/{id}`: the scene's bytes as uploaded (check them against the lease's
    /// sha256).
    pub async fn download_scene(&self, id: &str) -> Result<Bytes, ClientError> {
        self.bytes(self.request(Method::GET, &format!("/v1/scenes/{id}")))
            .await
    }

    /// `POST /v1/leases/{id}/heartbeat`, given up after `timeout`.
    pub async fn heartbeat(
        &self,
        lease_id: &str,
        timeout: Duration,
    ) -> Result<HeartbeatReply, ClientError> {
        let path = format!("/v1/leases/{lease_id}/heartbeat");
        self.json(self.request(Method::POST, &path).timeout(timeout))
            .await
    }

    /// `PUT /v1/jobs/{job}/tasks/{task}/result?worker=&lease=`: uploads a tile result (the
    /// bytes of [`crate::tile::encode`]) rendered under lease `lease_id`.
    pub async fn upload_result(
        &self,
        job: &str,
        task: u32,
        worker_id: &str,
        lease_id: &str,
        body: Vec<u8>,
    ) -> Result<ResultReply, ClientError> {
        let path = format!("/v1/jobs/{job}/tasks/{task}/result");
        self.json(
            self.request(Method::PUT, &path)
                .query(&[("worker", worker_id), ("lease", lease_id)])
                .header(reqwest::header::CONTENT_TYPE, "application/octet-stream")
                .body(body),
        )
        .await
    }

    /// `POST /v1/leases/{id}/failure`: the task failed on this worker.
    pub async fn report_failure(
        &self,
        lease_id: &str,
        report: &FailureReport,
    ) -> Result<(), ClientError> {
        let path = format!("/v1/leases/{lease_id}/failure");
        self.send(self.request(Method::POST, &path).json(report))
            .await
            .map(drop)
    }

    /// `POST /v1/leases/{id}/release`: hands a task back unrendered, given up after `timeout`.
    pub async fn release(&self, lease_id: &str, timeout: Duration) -> Result<(), ClientError> {
        let path = format!("/v1/leases/{lease_id}/release");
        self.send(self.request(Method::POST, &path).timeout(timeout))
            .await
            .map(drop)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_http_urls_make_a_client() {
        for bad in ["farm-host:8080", "ftp://farm-host", "", "http://"] {
            assert!(
                matches!(Client::new(bad, None), Err(ClientError::BadUrl { .. })),
                "{bad}"
            );
        }
        let c = Client::new("http://farm-host:8080/", Some(String::new())).unwrap();
        assert_eq!(c.base(), "http://farm-host:8080");
        assert!(c.token.is_none(), "an empty token is no token");
    }

    #[test]
    fn requests_carry_the_token() {
        let c = Client::new("http://127.0.0.1:1", Some("sesame".into())).unwrap();
        let r = c.request(Method::GET, "/v1/jobs").build().unwrap();
        assert_eq!(r.url().as_str(), "http://127.0.0.1:1/v1/jobs");
        assert_eq!(r.headers()["authorization"], "Bearer sesame");
    }

    /// Serves one canned HTTP answer on a free port; returns the base URL.
    fn answer_once(response: &'static str) -> String {
        use std::io::{Read, Write};
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let base = format!("http://{}", l.local_addr().unwrap());
        std::thread::spawn(move || {
            let (mut s, _) = l.accept().unwrap();
            let mut buf = [0u8; 4096];
            let _ = s.read(&mut buf);
            let _ = s.write_all(response.as_bytes());
        });
        base
    }

    #[tokio::test]
    async fn error_bodies_keep_status_and_field() {
        let body = r#"{"error": {"code": "invalid", "message": "spp: must be between 1 and 1048576, got 0", "field": "spp"}}"#;
        let resp = Box::leak(
            format!(
                "HTTP/1.1 422 Unprocessable Entity\r\ncontent-type: application/json\r\ncontent-length: {}\r\nconnection: close\r\n\r\n{body}",
                body.len()
            )
            .into_boxed_str(),
        );
        let c = Client::new(&answer_once(resp), None).unwrap();
        let e = c.job("job-1").await.unwrap_err();
        assert_eq!(e.status(), Some(StatusCode::UNPROCESSABLE_ENTITY));
        assert_eq!(e.field(), Some("spp"));
        assert!(!e.is_unreachable());
        assert!(
            e.to_string()
                .ends_with("spp: must be between 1 and 1048576, got 0"),
            "{e}"
        );
    }

    #[tokio::test]
    async fn no_work_is_none_and_no_answer_is_unreachable() {
        let base = answer_once("HTTP/1.1 204 No Content\r\nconnection: close\r\n\r\n");
        let c = Client::new(&base, None).unwrap();
        assert_eq!(c.lease("w", Duration::from_millis(10)).await.unwrap(), None);
        let dead = {
            let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
            format!("http://{}", l.local_addr().unwrap())
        };
        // Nothing listens on the port any more.
        let e = Client::new(&dead, None).unwrap().jobs().await.unwrap_err();
        assert!(e.is_unreachable() && e.status().is_none(), "{e}");
        assert!(e.to_string().contains(&dead), "{e}");
    }
}
