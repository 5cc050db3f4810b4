//! HTTP handlers and the router. [`routes`] lists what the router serves, read from the same
//! code that builds it, so the OpenAPI test checks the real router, not a copy.

use crate::compose;
use crate::error::{AppError, Json, Path, Query};
use crate::images;
use crate::scenes::{self, UploadQuery};
use crate::sched::{Delivery, Heartbeat, ResultOutcome, Retried, Sched, TaskLayout};
use crate::store::Staged;
use crate::AppState;
use axum::body::{Body, Bytes};
use axum::extract::{DefaultBodyLimit, MatchedPath, Request, State};
use axum::http::{header, HeaderMap, HeaderValue, Method, StatusCode};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{on, MethodFilter, MethodRouter};
use axum::Router;
use futures_util::StreamExt;
use raytile_core::film::{ImageFormat, OutputOptions, ToneMap};
use raytile_proto::{self as proto, JobRequest};
use serde::Deserialize;
use std::fmt::Write as _;
use std::sync::Arc;
use std::time::Duration;
use tokio::time::Instant;

/// Largest JSON request body, in bytes; more is answered 413. (Uploads stream their `Body`
/// and enforce their own limits.)
pub const JSON_BODY_LIMIT: usize = 1 << 20;

/// Who may call a route, when the coordinator has a worker token apart from its token
/// ([`crate::Config::worker_token`]); with one token, its holder may call every route.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// Users and their programs: scenes, jobs, images, the farm's state.
    Client,
    /// Workers: registering, leasing, heartbeats, failures, releases and results.
    Worker,
    /// Either: the API's description, and scene downloads (workers load the scenes they
    /// lease, users fetch what they uploaded).
    Either,
}

/// Every (method, path) the router serves, with who may call it.
type RouteRoles = Arc<Vec<(Method, &'static str, Role)>>;

/// The router being built, and every (method, path) it routes with who may call it.
struct Routes {
    router: Router<AppState>,
    list: Vec<(Method, &'static str, Role)>,
}

impl Routes {
    fn add<H, T>(mut self, method: Method, path: &'static str, role: Role, handler: H) -> Routes
    where
        H: axum::handler::Handler<T, AppState>,
        T: 'static,
    {
        let filter = MethodFilter::try_from(method.clone()).expect("a method axum routes");
        let route: MethodRouter<AppState> = on(filter, handler);
        self.router = self.router.route(path, route);
        self.list.push((method, path, role));
        self
    }
}

/// Every route, built once for the router and once for [`routes`].
fn build() -> Routes {
    use Role::{Client, Either, Worker};
    let r = Routes {
        router: Router::new(),
        list: Vec::new(),
    };
    r.add(Method::GET, "/healthz", Either, healthz)
        .add(Method::GET, "/metrics", Client, metrics)
        .add(Method::GET, "/v1/openapi.json", Either, openapi)
        .add(Method::POST, "/v1/scenes", Client, upload_scene)
        .add(Method::GET, "/v1/scenes/{id}", Either, download_scene)
        .add(Method::POST, "/v1/jobs", Client, create_job)
        .add(Method::GET, "/v1/jobs", Client, list_jobs)
        .add(Method::GET, "/v1/jobs/{id}", Client, get_job)
        .add(Method::DELETE, "/v1/jobs/{id}", Client, cancel_job)
        .add(Method::GET, "/v1/jobs/{id}/image", Client, job_image)
        .add(Method::GET, "/v1/jobs/{id}/tiles", Client, job_tiles)
        .add(Method::POST, "/v1/jobs/{id}/priority", Client, set_priority)
        .add(Method::POST, "/v1/jobs/{id}/retry", Client, retry_job)
        .add(Method::GET, "/v1/events", Client, events)
        .add(
            Method::PUT,
            "/v1/jobs/{id}/tasks/{task}/result",
            Worker,
            upload_result,
        )
        .add(Method::POST, "/v1/workers", Worker, register)
        .add(Method::GET, "/v1/workers", Client, list_workers)
        .add(Method::POST, "/v1/workers/{id}/lease", Worker, lease)
        .add(
            Method::POST,
            "/v1/leases/{lease}/heartbeat",
            Worker,
            heartbeat,
        )
        .add(Method::POST, "/v1/leases/{lease}/failure", Worker, failure)
        .add(Method::POST, "/v1/leases/{lease}/release", Worker, release)
}

/// Every (method, path) the router serves, as the router was built.
pub fn routes() -> Vec<(Method, &'static str)> {
    build().list.into_iter().map(|(m, p, _)| (m, p)).collect()
}

/// Every (method, path) the router serves, with who may call it.
pub fn roles() -> Vec<(Method, &'static str, Role)> {
    build().list
}

/// The router with every route, the auth layer and the JSON body limit. Unknown paths (404),
/// known paths with another method (405) and every extractor's rejection answer the API's
/// JSON error body.
pub fn app(state: AppState) -> Router {
    let Routes { router, list } = build();
    let roles = Arc::new(list);
    router
        .merge(crate::web::router())
        .fallback(|| async { AppError::NotFound("no such endpoint".into()) })
        .method_not_allowed_fallback(|| async { AppError::MethodNotAllowed })
        .layer(middleware::from_fn_with_state((state.clone(), roles), auth))
        .layer(DefaultBodyLimit::max(JSON_BODY_LIMIT))
        .with_state(state)
}

/// Every request but `/healthz` and the web pages ([`crate::web::is_public`]) needs the
/// token, as `Authorization: Bearer TOKEN` (the scheme in any case). The token is taken from
/// that header only: a browser sends cookies along with requests other sites' pages make, and
/// to other services on the same host, so the pages send the header themselves.
///
/// A coordinator with a worker token ([`crate::Config::worker_token`]) takes it, and only it,
/// on the workers' routes ([`Role::Worker`]), and takes its token, and only it, on the others
/// ([`Role::Client`]); either on [`Role::Either`]. A known token on a route of the other role
/// is answered 403, an unknown one 401.
///
/// Two more rules keep other sites' pages out, with or without a token:
/// - a request that would change something (any method but GET, HEAD and OPTIONS) made by a
///   browser for a page of another origin is refused (its `Sec-Fetch-Site` or `Origin`);
///   programs send neither header;
/// - a coordinator without a token (on loopback, unless `--insecure`) answers only requests
///   that name it by an IP address or `localhost` in `Host`: a page on a domain whose DNS
///   answer turns to 127.0.0.1 (DNS rebinding) cannot read or change anything.
async fn auth(
    State((state, roles)): State<(AppState, RouteRoles)>,
    req: Request,
    next: Next,
) -> Response {
    let path = req.uri().path();
    if path == "/healthz" || crate::web::is_public(path) {
        return next.run(req).await;
    }
    if let Some(refused) = cross_site(&req) {
        return AppError::Forbidden(refused).into_response();
    }
    match &state.cfg.token {
        Some(token) => {
            let given = req
                .headers()
                .get(header::AUTHORIZATION)
                .and_then(|v| v.to_str().ok())
                .and_then(|v| {
                    // The scheme is case-insensitive (RFC 7235): `bearer` is `Bearer`.
                    let (scheme, token) = v.split_once(' ')?;
                    scheme
                        .eq_ignore_ascii_case("bearer")
                        .then_some(token.trim())
                });
            let is = |t: &str| given.is_some_and(|g| constant_time_eq(g.as_bytes(), t.as_bytes()));
            let client = is(token);
            let Some(worker_token) = &state.cfg.worker_token else {
                if !client {
                    return AppError::Unauthorized.into_response();
                }
                return next.run(req).await;
            };
            let worker = is(worker_token);
            // A route's role from the path it matched and the method (HEAD is served by the
            // GET route). A path no route serves is answered 404, which tells nothing, to
            // either token; a method a known path does not serve is the clients'.
            let method = match req.method() {
                &Method::HEAD => &Method::GET,
                m => m,
            };
            let role = match req.extensions().get::<MatchedPath>() {
                None => Role::Either,
                Some(matched) => roles
                    .iter()
                    .find(|(m, p, _)| m == method && *p == matched.as_str())
                    .map_or(Role::Client, |r| r.2),
            };
            let allowed = match role {
                Role::Client => client,
                Role::Worker => worker,
                Role::Either => client || worker,
            };
            if !allowed {
                if !(client || worker) {
                    return AppError::Unauthorized.into_response();
                }
                return AppError::WrongToken(
                    if worker {
                        "this endpoint is the clients': it takes the coordinator's token, not \
                         the worker token"
                    } else {
                        "this endpoint is the workers': it takes the worker token \
                         (--worker-token), not the clients' token"
                    }
                    .into(),
                )
                .into_response();
            }
        }
        None if !state.cfg.insecure => {
            let host = req.headers().get(header::HOST).map(|h| h.to_str().ok());
            if let Some(host) = host.filter(|h| !h.is_some_and(names_this_machine)) {
                return AppError::Forbidden(format!(
                    "a coordinator without a token answers only requests to an IP address or \
                     localhost, not to {:?}: use http://127.0.0.1:PORT/, or give the \
                     coordinator a token",
                    host.unwrap_or("(not text)")
                ))
                .into_response();
            }
        }
        None => {}
    }
    next.run(req).await
}

/// Why `req`, made by a browser for a page of another origin, is refused, if it is such a
/// request and would change something.
fn cross_site(req: &Request) -> Option<String> {
    if matches!(*req.method(), Method::GET | Method::HEAD | Method::OPTIONS) {
        return None;
    }
    let headers = req.headers();
    let text = |name| {
        headers
            .get(name)
            .map(|v| v.to_str().unwrap_or("(not text)"))
    };
    let refused = |what: String| {
        format!("{what}: the coordinator takes changes from its own pages and from programs only")
    };
    if let Some(site) = text(header::HeaderName::from_static("sec-fetch-site")) {
        if !matches!(site, "same-origin" | "none") {
            return Some(refused(format!(
                "a request from another site's page (Sec-Fetch-Site {site})"
            )));
        }
    }
    if let Some(origin) = text(header::ORIGIN) {
        let authority = origin.split_once("://").map(|(_, a)| a);
        if authority.is_none() || authority != text(header::HOST) {
            return Some(refused(format!("a request from a page of {origin:?}")));
        }
    }
    None
}

/// Whether `host` (a `Host` header: a name or address, and maybe a port) names this machine in
/// a way no DNS answer can redirect: an IP address, `localhost` or a name under `.localhost`.
fn names_this_machine(host: &str) -> bool {
    if host.starts_with('[') {
        return host
            .split_once(']')
            .is_some_and(|(ip, _)| ip[1..].parse::<std::net::Ipv6Addr>().is_ok());
    }
    let name = host
        .split(':')
        .next()
        .unwrap_or_default()
        .to_ascii_lowercase();
    name.parse::<std::net::Ipv4Addr>().is_ok()
        || name == "localhost"
        || name.ends_with(".localhost")
}

pub(crate) fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

async fn healthz() -> Json<proto::Health> {
    Json(proto::Health {
        status: "ok".into(),
    })
}

async fn openapi() -> Response {
    axum::Json(crate::openapi::document()).into_response()
}

/// The query of a user's route that takes no parameters: any parameter is a 400 naming it, as
/// on the routes that take some (`GET /v1/jobs/ID?format=png` is not silently the job's
/// status). The worker routes, and `/healthz` (load balancers add their own), stay lenient.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct NoQuery {}

async fn metrics(State(state): State<AppState>, _: Query<NoQuery>) -> Response {
    let now = state.now();
    let m = state.sched().metrics(now);
    let (c, workers, sps) = (m.counters, m.workers, m.samples_per_second);
    let mut out = String::new();
    let _ = writeln!(
        out,
        "# HELP raytile_jobs Jobs by state.\n# TYPE raytile_jobs gauge"
    );
    for (st, n) in m.jobs {
        let _ = writeln!(out, "raytile_jobs{{state=\"{}\"}} {n}", st.name());
    }
    for (name, help, v) in [
        ("raytile_tiles_leased_total", "Leases granted.", c.leased),
        ("raytile_tiles_done_total", "Tile results accepted.", c.done),
        (
            "raytile_tiles_expired_total",
            "Leases expired and re-queued.",
            c.expired,
        ),
        (
            "raytile_tiles_revived_total",
            "Expired leases given back to their workers at a heartbeat, nobody having taken the task (a worker stopped or cut off past its lease).",
            c.revived,
        ),
        (
            "raytile_tiles_failed_total",
            "Failures reported by workers.",
            c.failed,
        ),
        (
            "raytile_tiles_duplicate_total",
            "Results ignored because their task was done already (late or repeated uploads).",
            c.duplicates,
        ),
        (
            "raytile_tiles_for_ended_jobs_total",
            "Results ignored because their job was cancelled or had failed.",
            c.for_ended_jobs,
        ),
        ("raytile_samples_total", "Samples accepted.", c.samples),
        (
            "raytile_store_failures_total",
            "Requests answered 503 because the store (database or files) could not be written: a full or read-only disk.",
            crate::error::STORE_FAILURES.load(std::sync::atomic::Ordering::Relaxed),
        ),
    ] {
        let _ = writeln!(
            out,
            "# HELP {name} {help}\n# TYPE {name} counter\n{name} {v}"
        );
    }
    let _ = writeln!(
        out,
        "# HELP raytile_workers Registered workers, those gone included (a worker not heard from for a day is forgotten).\n# TYPE raytile_workers gauge\nraytile_workers {workers}"
    );
    let _ = writeln!(
        out,
        "# HELP raytile_workers_live Registered workers heard from lately, heartbeats included (those not gone in GET /v1/workers).\n# TYPE raytile_workers_live gauge\nraytile_workers_live {}",
        m.workers_live
    );
    let _ = writeln!(
        out,
        "# HELP raytile_samples_per_second Samples accepted per second over the last 10 s.\n# TYPE raytile_samples_per_second gauge\nraytile_samples_per_second {sps}"
    );
    ([(header::CONTENT_TYPE, "text/plain; version=0.0.4")], out).into_response()
}

async fn upload_scene(
    State(state): State<AppState>,
    Query(q): Query<UploadQuery>,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, AppError> {
    let ct = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok());
    let len = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse().ok());
    let (created, ans) = scenes::upload(&state, q, ct, len, body).await?;
    let code = if created {
        StatusCode::CREATED
    } else {
        StatusCode::OK
    };
    Ok((code, Json(ans)).into_response())
}

async fn download_scene(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Response, AppError> {
    let m =
        scenes::meta(&state, &id).ok_or_else(|| AppError::NotFound(format!("no scene '{id}'")))?;
    let path = scenes::scene_dir(&state, &id).join("blob");
    let f = tokio::fs::File::open(&path)
        .await
        .map_err(AppError::internal)?;
    let len = f.metadata().await.map_err(AppError::internal)?.len();
    let body = Body::from_stream(tokio_util::io::ReaderStream::new(f));
    Ok((
        [
            (header::CONTENT_TYPE, "application/octet-stream".to_string()),
            (header::CONTENT_LENGTH, len.to_string()),
            (
                header::HeaderName::from_static("x-raytile-sha256"),
                m.sha256.clone(),
            ),
            (
                header::HeaderName::from_static("x-raytile-format"),
                m.format.clone(),
            ),
            (
                header::HeaderName::from_static("x-raytile-entry"),
                m.entry.clone(),
            ),
        ],
        body,
    )
        .into_response())
}

async fn create_job(
    State(state): State<AppState>,
    _: Query<NoQuery>,
    Json(req): Json<JobRequest>,
) -> Result<Response, AppError> {
    let m = scenes::meta(&state, &req.scene)
        .ok_or_else(|| AppError::invalid("scene", format!("no scene '{}'", req.scene)))?;
    let settings = m
        .defaults
        .resolve(&req.overrides)
        .map_err(|e| AppError::invalid(e.field, e.message))?;
    m.check_camera(settings.camera.as_deref())
        .map_err(|e| AppError::invalid("camera", e))?;
    // What a worker would refuse after its third try, refused now.
    if let Some(facts) = &m.sppm {
        facts
            .check(&settings)
            .map_err(|e| AppError::invalid("integrator", e))?;
    }
    let lim = &state.cfg.limits;
    lim.check_job(&settings)
        .map_err(|e| AppError::invalid(e.field, e.message))?;
    // The job's environment times its strength, as a worker will set it up.
    match &settings.environment {
        Some(proto::EnvironmentChoice::Map(map)) => {
            scenes::check_environment_map(&state, &m, map, settings.environment_strength).await?;
        }
        Some(proto::EnvironmentChoice::Constant(c)) => {
            let scaled = glam::Vec3A::from(*c) * settings.environment_strength;
            raytile_core::light::check_radiance("the environment colour times it", scaled)
                .map_err(|e| AppError::invalid("environment_strength", e))?;
        }
        _ => {}
    }
    // The layout (every tile, ordered centre-out) is the costly part of a large job: made here,
    // outside the scheduler's lock, which then only stores one row.
    let layout = {
        let s = settings.clone();
        tokio::task::spawn_blocking(move || Arc::new(TaskLayout::new(&s)))
            .await
            .map_err(AppError::internal)?
    };
    let status = {
        let mut s = state.sched();
        check_queue_room(&s, lim, layout.task_count() as u64)?;
        s.create_job(
            req.scene.clone(),
            settings,
            layout,
            req.priority.unwrap_or(0),
            state.now(),
        )?
    };
    state.notify.notify_waiters();
    tracing::info!(job = %status.id, "job created");
    Ok((StatusCode::CREATED, Json(status)).into_response())
}

/// Query of `GET /v1/jobs`; without parameters, every job.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ListQuery {
    /// Only jobs in these states, comma-separated.
    state: Option<String>,
    /// Only jobs submitted after this one (a job id: the `next` of the page before).
    after: Option<String>,
    /// At most this many jobs (at least 1).
    limit: Option<usize>,
}

async fn list_jobs(
    State(state): State<AppState>,
    Query(q): Query<ListQuery>,
) -> Result<Json<proto::JobList>, AppError> {
    let states = match q.state.as_deref() {
        None => Vec::new(),
        Some(list) => list
            .split(',')
            .map(|name| {
                proto::JobState::from_name(name.trim()).ok_or_else(|| {
                    let names: Vec<&str> = proto::JobState::ALL.iter().map(|s| s.name()).collect();
                    AppError::invalid(
                        "state",
                        format!("unknown job state '{name}' (expected {})", names.join(", ")),
                    )
                })
            })
            .collect::<Result<_, _>>()?,
    };
    // A job id is `job-SEQ-EPOCH`: the sequence number orders the list, and a page goes on
    // after a job that was purged meanwhile.
    let after = match q.after.as_deref() {
        None => 0,
        Some(id) => id
            .strip_prefix("job-")
            .and_then(|rest| rest.split('-').next())
            .and_then(|seq| seq.parse::<u64>().ok())
            .ok_or_else(|| {
                AppError::invalid("after", format!("'{id}' is not a job id (job-N-EPOCH)"))
            })?,
    };
    let limit = match q.limit {
        Some(0) => return Err(AppError::invalid("limit", "must be at least 1")),
        Some(n) => n,
        None => usize::MAX,
    };
    let (jobs, next) = state.sched().job_page(&states, after, limit);
    Ok(Json(proto::JobList { jobs, next }))
}

fn no_job(id: &str) -> AppError {
    AppError::NotFound(format!("no job '{id}'"))
}

async fn get_job(
    State(state): State<AppState>,
    Path(id): Path<String>,
    _: Query<NoQuery>,
) -> Result<Json<proto::JobStatus>, AppError> {
    let status = state.sched().job_status(&id);
    status.map(Json).ok_or_else(|| no_job(&id))
}

// A client's request is strict: a misspelt parameter is an error, not ignored.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DeleteQuery {
    /// Also delete the job and its tile data (default: only cancel).
    purge: Option<bool>,
}

async fn cancel_job(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Query(q): Query<DeleteQuery>,
) -> Result<Json<proto::JobStatus>, AppError> {
    let now = state.now();
    let st = if q.purge.unwrap_or(false) {
        let st = state.sched().purge(&id, now)?;
        state.image_cache().forget(&id);
        st
    } else {
        state.sched().cancel(&id, now)?
    };
    st.map(Json).ok_or_else(|| no_job(&id))
}

/// A 429 unless the queue has room for one more unfinished job of `tasks` tasks.
fn check_queue_room(s: &Sched, lim: &crate::Limits, tasks: u64) -> Result<(), AppError> {
    if s.unfinished_jobs() >= lim.max_queued_jobs {
        return Err(AppError::TooMany(format!(
            "{} unfinished jobs already (limit {})",
            s.unfinished_jobs(),
            lim.max_queued_jobs
        )));
    }
    let queued = s.unfinished_tasks();
    if queued + tasks > lim.max_queued_tasks {
        return Err(AppError::TooMany(format!(
            "unfinished jobs hold {queued} tasks already; this job's {tasks} would pass the limit of {}",
            lim.max_queued_tasks
        )));
    }
    Ok(())
}

/// `POST /v1/jobs/{id}/retry`: a failed or cancelled job goes on with the tiles it has.
async fn retry_job(
    State(state): State<AppState>,
    Path(id): Path<String>,
    _: Query<NoQuery>,
) -> Result<Json<proto::JobStatus>, AppError> {
    let lim = &state.cfg.limits;
    let now = state.now();
    let mut s = state.sched();
    let status = s.job_status(&id).ok_or_else(|| no_job(&id))?;
    if let Some(why) = s.retry_refusal(&id) {
        return Err(AppError::Conflict(why));
    }
    if matches!(
        status.state,
        proto::JobState::Failed | proto::JobState::Cancelled
    ) {
        // Retried, it is an unfinished job again, held to the same limits as a new one.
        check_queue_room(&s, lim, status.tasks_total)?;
    }
    match s.retry(&id, now)?.ok_or_else(|| no_job(&id))? {
        Retried::Resumed(status) => {
            drop(s);
            state.notify.notify_waiters();
            Ok(Json(status))
        }
        Retried::Unchanged(status) => Ok(Json(status)),
        Retried::Refused(why) => Err(AppError::Conflict(why)),
    }
}

async fn job_tiles(
    State(state): State<AppState>,
    Path(id): Path<String>,
    _: Query<NoQuery>,
) -> Result<Json<proto::TileList>, AppError> {
    let tiles = state.sched().tile_list(&id);
    tiles.map(Json).ok_or_else(|| no_job(&id))
}

async fn set_priority(
    State(state): State<AppState>,
    Path(id): Path<String>,
    _: Query<NoQuery>,
    Json(proto::json::Members(mut body)): Json<proto::json::Members>,
) -> Result<Json<proto::JobStatus>, AppError> {
    // Read from an object only (serde would take `[5]` for `{"priority": 5}`), by hand, so
    // that an unknown field is named as `POST /v1/jobs` names one.
    let value = body
        .remove("priority")
        .ok_or_else(|| AppError::invalid("priority", "missing field `priority`"))?;
    if let Some(unknown) = body.keys().next() {
        return Err(AppError::invalid(
            unknown.clone(),
            format!("{unknown}: unknown field `{unknown}`, expected `priority`"),
        ));
    }
    let priority: i32 = serde_json::from_value(value).map_err(|e| {
        let message = proto::json::plain_message(&e.to_string());
        AppError::invalid("priority", format!("priority: {message}"))
    })?;
    let st = state.sched().set_priority(&id, priority)?;
    if st.is_some() {
        state.notify.notify_waiters();
    }
    st.map(Json).ok_or_else(|| no_job(&id))
}

/// The change stream: server-sent events, one JSON object each (see `sched::events`), with
/// the id the scheduler gave it. It opens with a `resync` (fetch what you show now), and a
/// subscriber that fell behind by more than the channel holds gets a `resync` instead of what
/// it missed. Resyncs carry no id. The stream ends when the coordinator shuts down (browsers
/// reconnect by themselves).
async fn events(State(state): State<AppState>, _: Query<NoQuery>) -> Response {
    use axum::response::sse::{Event, KeepAlive, Sse};
    use tokio::sync::broadcast::error::RecvError;
    let resync = |reason: &str| {
        Event::default().data(serde_json::json!({"type": "resync", "reason": reason}).to_string())
    };
    let (_, rx) = state.sched().subscribe();
    let first = resync("connected");
    let rest = futures_util::stream::unfold(
        (rx, state.shutdown_rx()),
        move |(mut rx, mut shutdown)| async move {
            if *shutdown.borrow() {
                return None;
            }
            let ev = tokio::select! {
                r = rx.recv() => match r {
                    Ok(ev) => Event::default().id(ev.id.to_string()).data(&ev.json),
                    Err(RecvError::Lagged(n)) => resync(&format!("{n} events missed")),
                    Err(RecvError::Closed) => return None,
                },
                _ = shutdown.changed() => return None,
            };
            Some((Ok::<_, std::convert::Infallible>(ev), (rx, shutdown)))
        },
    );
    let stream = futures_util::stream::once(async move { Ok(first) }).chain(rest);
    (
        [(header::HeaderName::from_static("x-accel-buffering"), "no")],
        Sse::new(stream).keep_alive(KeepAlive::default()),
    )
        .into_response()
}

// A client's request is strict: a misspelt parameter is an error, not ignored.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ImageQuery {
    format: Option<String>,
    /// PNG only: exposure in stops (-64 to 64), as `raytile render --exposure`.
    exposure: Option<f32>,
    /// PNG only: `clamp` or `aces`, as `raytile render --tonemap`.
    tonemap: Option<String>,
}

impl ImageQuery {
    /// The output options asked for (the defaults unless the image is a PNG), and what they
    /// add to the image's entity tag (nothing for the defaults).
    fn look(&self, format: ImageFormat) -> Result<(OutputOptions, String), AppError> {
        let mut opts = OutputOptions::default();
        if let Some(e) = self.exposure {
            if !(e.is_finite() && e.abs() <= 64.0) {
                return Err(AppError::invalid(
                    "exposure",
                    format!("must be a finite number of stops from -64 to 64, got {e}"),
                ));
            }
            // -0 makes the image 0 makes, and is named as it.
            opts.exposure = e + 0.0;
        }
        if let Some(t) = &self.tonemap {
            opts.tonemap = t
                .parse()
                .map_err(|e: String| AppError::invalid("tonemap", e))?;
        }
        if opts == OutputOptions::default() {
            return Ok((opts, String::new()));
        }
        if format != ImageFormat::Png {
            let field = if self.exposure.is_some() {
                "exposure"
            } else {
                "tonemap"
            };
            return Err(AppError::invalid(
                field,
                format!(
                    "exposure and tonemap shape PNG images only; {} images are linear",
                    format.name().to_ascii_uppercase()
                ),
            ));
        }
        let curve = match opts.tonemap {
            ToneMap::Clamp => "clamp",
            ToneMap::Aces => "aces",
        };
        // The exposure's bits: two spellings of one number name one image.
        Ok((opts, format!("-{:08x}-{curve}", opts.exposure.to_bits())))
    }
}

/// The frame so far. Each image is named by an entity tag that changes whenever a result of the
/// job is stored ([`images`]): a request naming the current one in `If-None-Match` is answered
/// 304 without a body, one with `Range` gets those bytes (206), and the last images made are
/// kept for the requests that follow.
async fn job_image(
    State(state): State<AppState>,
    method: Method,
    headers: HeaderMap,
    Path(id): Path<String>,
    Query(q): Query<ImageQuery>,
) -> Result<Response, AppError> {
    let name = q.format.clone().unwrap_or_else(|| "png".into());
    let format = ImageFormat::from_extension(&name).ok_or_else(|| {
        AppError::invalid(
            "format",
            format!("unknown image format '{name}' (expected png, exr or hdr)"),
        )
    })?;
    let ext = format.name();
    let (look, look_tag) = q.look(format)?;
    let version = state.sched().results_version(&id);
    let etag = images::entity_tag(
        &version.ok_or_else(|| no_job(&id))?,
        &format!("{ext}{look_tag}"),
    );
    // A frame of black alone is no image: a client that saved it would take it for the render.
    if let Some(why) = state.sched().no_image(&id) {
        return Err(AppError::Conflict(why));
    }
    if images::not_modified(&headers, &etag) {
        return Ok(image_response(
            StatusCode::NOT_MODIFIED,
            format,
            Some(&etag),
            no_length(),
        ));
    }
    let kept = state.image_cache().get(&id, &etag);
    if let Some((bytes, dropped)) = kept {
        return image_answer(&method, &headers, format, Some(&etag), bytes, dropped);
    }
    if method == Method::HEAD {
        // The headers a GET would send, but for the length, which only encoding the frame
        // would tell (HTTP lets a HEAD answer leave it out).
        return Ok(image_response(
            StatusCode::OK,
            format,
            Some(&etag),
            no_length(),
        ));
    }
    // A frame takes memory in proportion to its pixels while it is composed and encoded: a
    // bounded number at once, the other requests wait here holding nothing.
    let permit = slot(&state.image_slots, state.cfg.image_wait, |wait| {
        format!(
            "{} images are being made and none ended within {wait} s: try again shortly",
            state.cfg.max_parallel_images.max(1),
        )
    })
    .await?;
    let (layout, settings, conn, results, etag) = {
        let s = state.sched();
        // Looked up again: the job may have been purged, or have results more, since.
        let version = s.results_version(&id).ok_or_else(|| no_job(&id))?;
        let layout = s.layout(&id).ok_or_else(|| no_job(&id))?;
        let settings = s.settings(&id).ok_or_else(|| no_job(&id))?;
        let conn = s.reader().map_err(AppError::internal)?;
        (
            layout,
            settings,
            conn,
            s.results_dir(),
            images::entity_tag(&version, &format!("{ext}{look_tag}")),
        )
    };
    let job_id = id.clone();
    // Pass by pass, one stored tile decoded at a time: the frame and one tile in memory.
    let (bytes, lost, dropped) = tokio::task::spawn_blocking(move || -> Result<_, AppError> {
        let _permit = permit;
        // Tasks whose stored result is missing, damaged or does not decode.
        let mut lost = Vec::new();
        let (film, refused) = compose::compose_by_pass(&layout, |tasks, add| {
            let mut unreadable = Vec::new();
            let gone =
                crate::store::for_each_result(&conn, &results, &job_id, tasks, |idx, data| {
                    match proto::tile::decode(data) {
                        Ok((acc, _)) => add(idx, acc),
                        Err(e) => {
                            unreadable.push(idx);
                            tracing::error!(job = %job_id, idx, "stored result unreadable: {e}")
                        }
                    }
                })?;
            lost.extend(gone.into_iter().chain(unreadable));
            Ok::<_, rusqlite::Error>(())
        })
        .map_err(AppError::internal)?;
        lost.extend(refused);
        // The store's connection is not needed while the image is encoded.
        drop(conn);
        let mut bytes =
            compose::encode(&film, format, &look, &settings).map_err(AppError::internal)?;
        // Kept, the buffer should hold what is counted.
        bytes.shrink_to_fit();
        Ok((bytes, lost, film.bad_samples))
    })
    .await
    .map_err(AppError::internal)??;
    let bytes = Bytes::from(bytes);
    let named = {
        let mut s = state.sched();
        // Purged while it was made: its result files may have gone with it.
        let after = s.results_version(&id).ok_or_else(|| no_job(&id))?;
        // Named only if no result came in while it was made (it may hold some of the new
        // results, not all) and every stored result was read. Kept under the scheduler's lock,
        // so that a purge, which forgets the job's images after it, cannot come in between.
        let unchanged = images::entity_tag(&after, &format!("{ext}{look_tag}")) == etag;
        if unchanged && !lost.is_empty() {
            // Rendered again where the job can be; the image lacks them until then. Only while
            // the job's results are still those read: one of them may since have been
            // rendered again, and the next image looks again.
            match s.repair(&id, &lost, state.now()) {
                Ok(0) => {}
                Ok(_) => state.notify.notify_waiters(),
                // The image is served all the same; the next one looks again.
                Err(e) => tracing::error!(job = %id, "lost tiles not queued again: {e}"),
            }
        }
        let named = unchanged && lost.is_empty();
        // Only the plain image of each format is kept: another exposure is made when asked.
        if named && look_tag.is_empty() {
            state
                .image_cache()
                .put(&id, ext, etag.clone(), bytes.clone(), dropped);
        }
        named.then_some(etag)
    };
    image_answer(&method, &headers, format, named.as_deref(), bytes, dropped)
}

/// The header that says how many samples the frame's results dropped as NaN, infinite or too
/// large (they are not in the image; a pixel all of whose samples were dropped is black).
pub const DROPPED_SAMPLES: &str = "x-raytile-dropped-samples";

/// An empty body of no stated length: a HEAD answer (or a 304) that is not to say
/// `Content-Length: 0` about an image whose length it does not know.
fn no_length() -> Body {
    Body::from_stream(futures_util::stream::empty::<
        Result<Bytes, std::convert::Infallible>,
    >())
}

/// An image's answer: the part of `bytes` the request asks for, where the image has a name
/// (`etag`) that a range can be taken of; all of it otherwise; only the headers to a HEAD.
/// `dropped`: the samples its results dropped ([`DROPPED_SAMPLES`]).
fn image_answer(
    method: &Method,
    headers: &HeaderMap,
    format: ImageFormat,
    etag: Option<&str>,
    bytes: Bytes,
    dropped: u64,
) -> Result<Response, AppError> {
    let len = bytes.len();
    let part = match etag {
        Some(etag) if method == Method::GET => images::requested_part(headers, etag, len),
        _ => images::Part::Whole,
    };
    let (status, range, body) = match part {
        images::Part::Whole => (StatusCode::OK, None, bytes),
        images::Part::Bytes(r) => {
            let range = format!("bytes {}-{}/{len}", r.start, r.end - 1);
            (StatusCode::PARTIAL_CONTENT, Some(range), bytes.slice(r))
        }
        images::Part::Unsatisfiable => return Err(AppError::RangeNotSatisfiable(len)),
    };
    let dropped = (
        header::HeaderName::from_static(DROPPED_SAMPLES),
        HeaderValue::from(dropped),
    );
    if method == Method::HEAD {
        let mut resp = image_response(status, format, etag, Body::empty());
        resp.headers_mut()
            .insert(header::CONTENT_LENGTH, HeaderValue::from(body.len()));
        resp.headers_mut().insert(dropped.0, dropped.1);
        return Ok(resp);
    }
    let mut resp = image_response(status, format, etag, Body::from(body));
    resp.headers_mut().insert(dropped.0, dropped.1);
    if let Some(v) = range.and_then(|r| HeaderValue::from_str(&r).ok()) {
        resp.headers_mut().insert(header::CONTENT_RANGE, v);
    }
    Ok(resp)
}

/// An image answer's status and headers: its content type, its entity tag if it has one (with
/// `Cache-Control: no-cache`, so that a browser asks again, naming it, before it shows its copy)
/// and `Accept-Ranges`.
fn image_response(
    status: StatusCode,
    format: ImageFormat,
    etag: Option<&str>,
    body: Body,
) -> Response {
    let mut resp = (status, body).into_response();
    let h = resp.headers_mut();
    if status != StatusCode::NOT_MODIFIED {
        h.insert(
            header::CONTENT_TYPE,
            HeaderValue::from_static(compose::content_type(format)),
        );
    }
    if let Some(v) = etag.and_then(|t| HeaderValue::from_str(t).ok()) {
        h.insert(header::ETAG, v);
        h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
        h.insert(header::ACCEPT_RANGES, HeaderValue::from_static("bytes"));
    }
    resp
}

async fn register(
    State(state): State<AppState>,
    Json(req): Json<proto::RegisterRequest>,
) -> Result<Json<proto::Registered>, AppError> {
    if req.name.is_empty() || req.name.len() > 256 {
        return Err(AppError::invalid("name", "must be 1 to 256 bytes"));
    }
    if req.render_version != raytile_core::RENDER_VERSION {
        // Tiles from another renderer version would not match the rest of the frame bit for
        // bit: such a worker must be upgraded (or the coordinator), not mixed in.
        tracing::warn!(name = %req.name, version = req.render_version, "worker refused: renderer version");
        return Err(AppError::Conflict(format!(
            "worker '{}' renders with renderer version {}, this coordinator's jobs need version {}: \
             run the same raytile release on every worker and the coordinator",
            req.name,
            req.render_version,
            raytile_core::RENDER_VERSION
        )));
    }
    let now = state.now();
    let id = state.sched().register(&req.name, req.threads, now)?;
    tracing::info!(worker = %id, name = %req.name, threads = req.threads, "worker registered");
    Ok(Json(proto::Registered {
        worker_id: id,
        lease_timeout_ms: state.cfg.lease_timeout.as_millis() as u64,
        heartbeat_ms: state.cfg.heartbeat_interval.as_millis() as u64,
    }))
}

async fn list_workers(State(state): State<AppState>, _: Query<NoQuery>) -> Json<proto::WorkerList> {
    Json(proto::WorkerList {
        workers: state.sched().worker_list(state.now()),
    })
}

#[derive(Deserialize)]
struct LeaseQuery {
    /// Longest wait for work, in ms (long poll).
    wait_ms: Option<u64>,
}

fn try_lease(state: &AppState, worker: &str) -> Result<Option<proto::Lease>, AppError> {
    let now = state.now();
    let Some(g) = state.sched().lease(worker, now)? else {
        return Ok(None);
    };
    let m = scenes::meta(state, &g.scene).ok_or_else(|| {
        AppError::internal(format!("scene {} of job {} is missing", g.scene, g.job))
    })?;
    Ok(Some(proto::Lease {
        lease_id: g.lease,
        job: g.job,
        task: g.task,
        scene: g.scene,
        scene_sha256: m.sha256.clone(),
        scene_format: m.format.clone(),
        scene_entry: m.entry.clone(),
        settings: g.settings,
        tile: g.work.tile,
        pass: g.work.pass,
        sample_start: g.work.samples.start,
        sample_end: g.work.samples.end,
        lease_timeout_ms: state.cfg.lease_timeout.as_millis() as u64,
    }))
}

async fn lease(
    State(state): State<AppState>,
    Path(worker): Path<String>,
    Query(q): Query<LeaseQuery>,
) -> Result<Response, AppError> {
    let wait = Duration::from_millis(q.wait_ms.unwrap_or(0)).min(state.cfg.long_poll_max);
    let deadline = Instant::now() + wait;
    let mut shutdown = state.shutdown_rx();
    loop {
        let notified = state.notify.notified();
        tokio::pin!(notified);
        notified.as_mut().enable();
        if let Some(l) = try_lease(&state, &worker)? {
            return Ok(Json(l).into_response());
        }
        if *shutdown.borrow() {
            return Err(AppError::Unavailable);
        }
        tokio::select! {
            _ = notified => {}
            _ = tokio::time::sleep_until(deadline) => return Ok(StatusCode::NO_CONTENT.into_response()),
            _ = shutdown.changed() => return Err(AppError::Unavailable),
        }
    }
}

async fn heartbeat(
    State(state): State<AppState>,
    Path(lease): Path<String>,
) -> Result<Json<proto::HeartbeatReply>, AppError> {
    let now = state.now();
    let r = state.sched().heartbeat(&lease, now);
    Ok(Json(match r {
        Heartbeat::Renewed => proto::HeartbeatReply {
            cancelled: false,
            reason: None,
        },
        Heartbeat::Stop { reason } => proto::HeartbeatReply {
            cancelled: true,
            reason: Some(reason),
        },
    }))
}

async fn failure(
    State(state): State<AppState>,
    Path(lease): Path<String>,
    Json(report): Json<proto::FailureReport>,
) -> Result<StatusCode, AppError> {
    let error: String = report.error.chars().take(4000).collect();
    tracing::warn!(%lease, %error, "worker reports failure");
    let now = state.now();
    let changed = state.sched().fail(&lease, &error, now)?;
    if changed {
        state.notify.notify_waiters();
    }
    Ok(StatusCode::NO_CONTENT)
}

async fn release(
    State(state): State<AppState>,
    Path(lease): Path<String>,
) -> Result<StatusCode, AppError> {
    if state.sched().release(&lease)? {
        state.notify.notify_waiters();
    }
    Ok(StatusCode::NO_CONTENT)
}

/// A result's splats must name pixels of the frame, each once, in increasing order, and only a
/// job whose integrator splats (`splat_pixels`: its frame's pixel count) may carry any.
fn check_splats(splats: &[(u32, [i128; 3])], splat_pixels: Option<u64>) -> Result<(), AppError> {
    let Some(n) = splat_pixels else {
        if splats.is_empty() {
            return Ok(());
        }
        return Err(AppError::invalid(
            "body",
            "result carries splats, but the job's integrator does not splat",
        ));
    };
    let mut prev: Option<u32> = None;
    for &(i, _) in splats {
        if i as u64 >= n || prev.is_some_and(|p| p >= i) {
            return Err(AppError::invalid(
                "body",
                format!(
                    "splat for pixel {i}: not a pixel of the {n}-pixel frame in increasing order"
                ),
            ));
        }
        prev = Some(i);
    }
    Ok(())
}

/// Every pixel sum of a result must be one a renderer can have made from a pass of
/// `samples` samples: finite (a NaN or an infinity would turn the tile black, or spread into
/// the frame, when it is composed), a weight (the samples kept, a whole number) from 0 to `samples`, and
/// colour sums at most the weight times the largest sample value the film takes (so that
/// adding passes never overflows). (Splats are integers, always finite.) The error names the
/// first pixel, in frame coordinates, and the value. The samples dropped as NaN or infinite
/// are at most the tile's pixels times `samples`, as each pixel's weight is at most `samples`:
/// they count into the frame's samples per pixel, by which a `bdpt` frame's splats are divided.
/// A job with an alpha channel (`alpha`) needs a coverage for each pixel, a whole number from 0
/// to the pixel's weight; any other job's results carry none.
pub(crate) fn check_sums(
    acc: &proto::tile::TileAccum,
    samples: u32,
    alpha: bool,
) -> Result<(), String> {
    let want = if alpha { acc.tile.pixel_count() } else { 0 };
    if acc.coverage.len() != want {
        return Err(if alpha {
            format!(
                "the job has an alpha channel: its results need a coverage for each of the \
                 tile's {want} pixels, got {}",
                acc.coverage.len()
            )
        } else {
            "result carries coverage, but the job has no alpha channel".to_string()
        });
    }
    let most_dropped = (acc.tile.pixel_count() as u64).saturating_mul(u64::from(samples));
    if acc.bad_samples > most_dropped {
        return Err(format!(
            "{} samples dropped as NaN or infinite: the pass has {samples} samples for each of \
             the tile's {} pixels, {most_dropped} in all",
            acc.bad_samples,
            acc.tile.pixel_count()
        ));
    }
    let w = acc.tile.width().max(1) as usize;
    let limit = f64::from(raytile_core::film::MAX_SAMPLE);
    for (i, p) in acc.pixels.iter().enumerate() {
        let at = || (acc.tile.x0 as usize + i % w, acc.tile.y0 as usize + i / w);
        if let Some(k) = p.iter().position(|v| !v.is_finite()) {
            let (x, y) = at();
            let what = ["red sum", "green sum", "blue sum", "weight"][k];
            return Err(format!(
                "pixel ({x}, {y}) has a {what} of {}: a result's sums must be finite numbers",
                p[k]
            ));
        }
        let weight = p[3];
        if !(0.0..=samples as f32).contains(&weight) {
            let (x, y) = at();
            return Err(format!(
                "pixel ({x}, {y}) has a weight of {weight}: the pass has {samples} samples"
            ));
        }
        // Every sample kept weighs 1 (the filter is importance-sampled).
        if weight.fract() != 0.0 {
            let (x, y) = at();
            return Err(format!(
                "pixel ({x}, {y}) has a weight of {weight}: a weight counts samples, a whole number"
            ));
        }
        if let Some(&c) = acc.coverage.get(i) {
            if !(0.0..=weight).contains(&c) || c.fract() != 0.0 {
                let (x, y) = at();
                return Err(format!(
                    "pixel ({x}, {y}) has a coverage of {c}: it counts samples, a whole number \
                     from 0 to the weight ({weight})"
                ));
            }
        }
        if let Some(k) = (0..3).find(|&k| f64::from(p[k].abs()) > f64::from(weight) * limit) {
            let (x, y) = at();
            return Err(format!(
                "pixel ({x}, {y}) has a colour sum of {} over {weight} samples: above the \
                 largest sample value ({limit:e}) times the weight",
                p[k]
            ));
        }
    }
    Ok(())
}

/// Path parameters of a result upload (by name, so that a bad one is named in the answer).
#[derive(Deserialize)]
struct TaskPath {
    id: String,
    task: u32,
}

#[derive(Deserialize)]
struct ResultQuery {
    /// Worker id, for the per-worker share.
    worker: Option<String>,
    /// The lease the result was rendered under: a refused result counts as a failure of the
    /// worker only when it names the lease that worker holds.
    lease: Option<String>,
}

async fn upload_result(
    State(state): State<AppState>,
    Path(TaskPath { id: job, task }): Path<TaskPath>,
    Query(q): Query<ResultQuery>,
    headers: HeaderMap,
    body: Body,
) -> Result<Json<proto::ResultReply>, AppError> {
    let lease = q.lease.as_deref().unwrap_or("");
    let worker = q.worker.as_deref().unwrap_or("");
    let found = {
        let s = state.sched();
        s.task_for_upload(&job, task).map(|(tile, pass)| {
            let settled = s.settled(&job, task);
            (
                tile,
                pass,
                s.pass_samples(&job, pass),
                s.splat_pixels(&job),
                s.alpha(&job),
                settled,
                s.lease_is_for(lease, &job, task, worker),
            )
        })
    };
    let (tile, task_pass, pass_samples, splat_pixels, alpha, settled, leased) = match found {
        Ok(found) => found,
        Err(e) => {
            // No such job (purged) or task: the body is read and dropped first, so that the
            // worker gets this answer rather than a connection closed under its upload, which
            // it would take for a network fault and send again.
            let _ = drain(body, state.cfg.limits.max_result_bytes).await;
            return Err(e.into());
        }
    };
    let expected = proto::tile::encoded_len(&tile, alpha);
    // A bdpt result carries at most one splat per pixel of the frame after its pixels.
    let room = splat_pixels.map_or(0, |n| n * proto::tile::SPLAT_LEN as u64);
    let limit = (expected as u64 + room).min(state.cfg.limits.max_result_bytes);
    let declared: Option<u64> = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse().ok());
    if declared.is_some_and(|n| n > limit) {
        return Err(AppError::TooLarge(limit));
    }
    // Only a worker that was given a lease of this task may send its result (a late one
    // too: results are deterministic), naming itself: the lease's tag covers the worker's id.
    // Lease ids cannot be guessed, so a token holder cannot slip a tile of its own into
    // someone's frame, nor fill a task nobody leased, nor credit a lease's tile to another
    // worker than the one that leased it.
    if !leased {
        let _ = drain(body, limit).await;
        return Err(AppError::invalid(
            "lease",
            format!(
                "{}: send the lease_id of the lease task {task} of job {job} was rendered \
                 under, and the id of the worker it was given to",
                if lease.is_empty() {
                    "no lease named"
                } else if worker.is_empty() {
                    "no worker named"
                } else {
                    "not a lease this coordinator gave for this task to this worker"
                }
            ),
        ));
    }
    // A large result is held whole and decoded before it is stored: a bounded number at once,
    // the others wait here holding nothing.
    let large = declared.unwrap_or(limit) >= state.cfg.result_file_bytes as u64;
    let _permit = if large && settled.is_none() {
        let n = state.cfg.max_parallel_large_results.max(1);
        Some(
            slot(
                &state.large_result_slots,
                state.cfg.large_result_wait,
                |wait| {
                    format!(
                        "{n} large results are being stored and none ended within {wait} s: send \
                     it again shortly"
                    )
                },
            )
            .await?,
        )
    } else {
        None
    };
    // A result for a task already done or a job that is over is read and dropped, not held
    // (the answer does not depend on it, and a worker expects its whole body to be read).
    if let Some(outcome) = settled {
        drain(body, limit).await?;
        state.sched().count_duplicate(outcome);
        return Ok(Json(reply(outcome)));
    }
    // The size is known from the task: read at most that much.
    let mut buf = Vec::with_capacity(declared.map_or(expected as u64, |n| n.min(limit)) as usize);
    read_body(body, limit, |chunk| buf.extend_from_slice(chunk)).await?;
    let (acc, pass) =
        proto::tile::decode(&buf).map_err(|e| AppError::invalid("body", e.to_string()))?;
    check_splats(&acc.splats, splat_pixels)?;
    if let Err(why) = check_sums(&acc, pass_samples, alpha) {
        // Refused, so that no frame shows a corrupted tile. When the sender holds the task's
        // lease, the refusal counts as a failure of the task on that worker: the task is
        // queued again at once for another worker (or fails its job after
        // --max-task-failures), and a worker that keeps sending such results is blocked from
        // the job like any failing worker. Nothing is lost: the tile is rendered again.
        let message = format!("result refused: {why}");
        if acc.tile == tile && pass == task_pass {
            let now = state.now();
            let changed = {
                let mut s = state.sched();
                // Named by its lease, not by a worker id: anyone may write a worker's id, only
                // its holder was given the lease.
                match s.current_lease(&job, task) {
                    Some(lease) if q.lease.as_deref() == Some(lease.as_str()) => {
                        s.fail(&lease, &message, now)?
                    }
                    _ => false,
                }
            };
            if changed {
                tracing::warn!(%job, task, %worker, "{message}");
                state.notify.notify_waiters();
            }
        }
        return Err(AppError::invalid("body", message));
    }
    // Refused before anything is written (the scheduler checks it again under its lock).
    if acc.tile != tile || pass != task_pass {
        return Err(AppError::invalid(
            "body",
            format!(
                "result is for tile {} pass {pass}, task {task} is tile {tile} pass {task_pass}",
                acc.tile
            ),
        ));
    }
    // Only the tile is needed from here: the decoded splats (as large as the body) go now.
    let result_tile = acc.tile;
    drop(acc);
    // A large result is written to a file now, before the scheduler's lock: the store then
    // only moves it into place, and other requests do not wait for hundreds of MB to be
    // written.
    let buf = Arc::new(buf);
    let file = if buf.len() >= state.cfg.result_file_bytes {
        let (dir, bytes) = (state.cfg.data_dir.clone(), buf.clone());
        let staged = tokio::task::spawn_blocking(move || Staged::write(&dir, &bytes))
            .await
            .map_err(AppError::internal)?;
        Some(staged.map_err(AppError::StoreUnavailable)?)
    } else {
        None
    };
    let delivery = Delivery {
        worker,
        tile: result_tile,
        pass,
        bytes: &buf,
        file: file.as_ref(),
    };
    let now = state.now();
    let outcome = state.sched().complete(&job, task, delivery, now)?;
    Ok(Json(reply(outcome)))
}

/// Reads `body` to its end, giving each chunk to `keep`: a 413 past `limit` bytes, a 400 when
/// the body cannot be read (the client went, or paused past the body timeout).
async fn read_body(body: Body, limit: u64, mut keep: impl FnMut(&[u8])) -> Result<(), AppError> {
    let mut stream = body.into_data_stream();
    let mut read = 0u64;
    while let Some(chunk) = stream.next().await {
        let chunk = chunk.map_err(|e| AppError::bad("body", format!("reading body: {e}")))?;
        read += chunk.len() as u64;
        if read > limit {
            return Err(AppError::TooLarge(limit));
        }
        keep(&chunk);
    }
    Ok(())
}

/// Reads `body` to its end and drops it (see [`read_body`]).
async fn drain(body: Body, limit: u64) -> Result<(), AppError> {
    read_body(body, limit, |_| {}).await
}

/// Waits up to `wait` for a permit of `slots`; past it, a 503 `busy` saying `why(seconds)`.
async fn slot(
    slots: &Arc<tokio::sync::Semaphore>,
    wait: Duration,
    why: impl FnOnce(f64) -> String,
) -> Result<tokio::sync::OwnedSemaphorePermit, AppError> {
    match tokio::time::timeout(wait, slots.clone().acquire_owned()).await {
        Ok(Ok(permit)) => Ok(permit),
        Ok(Err(_)) => Err(AppError::Unavailable),
        Err(_) => Err(AppError::Busy(why(wait.as_secs_f64()))),
    }
}

/// The answer to a result upload.
fn reply(outcome: ResultOutcome) -> proto::ResultReply {
    match outcome {
        ResultOutcome::Accepted => proto::ResultReply {
            accepted: true,
            duplicate: false,
            job_finished: false,
        },
        ResultOutcome::Duplicate => proto::ResultReply {
            accepted: false,
            duplicate: true,
            job_finished: false,
        },
        ResultOutcome::JobFinished => proto::ResultReply {
            accepted: false,
            duplicate: false,
            job_finished: true,
        },
    }
}

#[cfg(test)]
mod splat_checks {
    use super::*;

    fn message(e: AppError) -> String {
        match e {
            AppError::Invalid { field, message } => {
                assert_eq!(field.as_deref(), Some("body"));
                message
            }
            other => panic!("expected a 422, got {other:?}"),
        }
    }

    #[test]
    fn splats_must_name_frame_pixels_in_order_and_only_for_jobs_that_splat() {
        let ok = [(0, [1, 2, 3]), (5, [0, 0, 1]), (11, [-1, 0, 0])];
        assert!(check_splats(&ok, Some(12)).is_ok());
        assert!(check_splats(&[], None).is_ok());
        assert!(check_splats(&[], Some(12)).is_ok());
        let e = message(check_splats(&ok, None).unwrap_err());
        assert!(e.contains("does not splat"), "{e}");
        let e = message(check_splats(&ok, Some(11)).unwrap_err());
        assert!(e.contains("pixel 11"), "{e}");
        let e = message(check_splats(&[(3, [0; 3]), (3, [0; 3])], Some(12)).unwrap_err());
        assert!(e.contains("increasing"), "{e}");
    }
}
