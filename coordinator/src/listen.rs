//! The HTTP/1.1 server loop, with the limits a server facing a network needs and
//! `axum::serve` does not offer:
//!
//! - at most [`ServeLimits::max_connections`] connections at once: at the cap, new connections
//!   wait in the kernel's accept queue until one closes, instead of taking file descriptors
//!   until `accept` fails for everyone;
//! - a client has [`ServeLimits::header_timeout`] to send a request's headers (hyper's header
//!   read timeout, which also closes a keep-alive connection idle that long): a client that
//!   opens connections and sends nothing, or one byte at a time, cannot hold them;
//! - an HTTP/1.1 request with no `Host`, more than one, or one that is not a host and maybe a
//!   port, is answered 400 before the router sees it (RFC 9112, section 3.2);
//! - a request body that pauses for [`ServeLimits::body_timeout`] between two reads fails (as
//!   nginx's `client_body_timeout`), and one that, past that long from its first read, has
//!   come at less than [`ServeLimits::min_body_rate`] on average fails too (as Apache's
//!   `mod_reqtimeout` with `MinRate`): an upload that stops coming, or trickles, does not hold
//!   its connection, nor a large result's slot.
//!
//! A client that closes its side of the connection is taken to be gone, as before (hyper's
//! `half_close` stays off): a long poll or an image request it left is dropped, so no lease is
//! handed to a worker that stopped while it waited.
//!
//! On shutdown it stops accepting, asks every connection to finish its request in progress and
//! close, and returns when all have; dropped before that (the caller's hard stop), it closes
//! them. A connection in the middle of a request's headers (bytes came since its last request,
//! none is being served) has nothing to finish: it gets a moment, then is closed, where it
//! would otherwise hold the stop until the hard stop.

use crate::error::AppError;
use axum::body::Body;
use axum::body::Bytes;
use axum::http::{header, Request, Response, Version};
use axum::response::IntoResponse;
use axum::BoxError;
use axum::Router;
use hyper::body::Frame;
use hyper::body::Incoming;
use hyper_util::rt::{TokioIo, TokioTimer};
use std::convert::Infallible;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{watch, Semaphore};
use tower::ServiceExt;
use tower_http::timeout::TimeoutBody;

/// Bounds on connections.
#[derive(Clone, Copy, Debug)]
pub struct ServeLimits {
    /// Most connections open at once.
    pub max_connections: usize,
    /// How long a client has to send a request's headers, from the connection's start or the
    /// end of its previous request.
    pub header_timeout: Duration,
    /// Longest pause between two reads of a request's body, once the handler reads it.
    pub body_timeout: Duration,
    /// Least average rate of a request's body in bytes a second, once `body_timeout` has
    /// passed since the handler began to read it (that time is free: a body may take
    /// `body_timeout` plus its length over this rate); 0 for none.
    pub min_body_rate: u64,
}

impl Default for ServeLimits {
    fn default() -> Self {
        ServeLimits {
            max_connections: 4096,
            header_timeout: Duration::from_secs(30),
            body_timeout: Duration::from_secs(60),
            min_body_rate: 32 * 1024,
        }
    }
}

/// Serves `app` on `listener` until `stop` turns `true`, then waits for the open connections
/// to finish their requests in progress. Dropped before that, it closes every connection.
pub async fn serve(
    listener: TcpListener,
    app: Router,
    limits: ServeLimits,
    mut stop: watch::Receiver<bool>,
) {
    let max = limits.max_connections.clamp(1, Semaphore::MAX_PERMITS);
    let slots = Arc::new(Semaphore::new(max));
    // The connections' tasks, aborted when this future is dropped.
    let mut conns = tokio::task::JoinSet::new();
    loop {
        while conns.try_join_next().is_some() {}
        // Stopping first: once it began, no connection is taken, even one that is ready.
        let slot = tokio::select! {
            biased;
            () = stopped(&mut stop) => break,
            s = slots.clone().acquire_owned() => s.expect("the semaphore is never closed"),
        };
        let (stream, peer) = tokio::select! {
            biased;
            () = stopped(&mut stop) => break,
            a = listener.accept() => match a {
                Ok(a) => a,
                Err(e) => {
                    accept_failed(e).await;
                    continue;
                }
            },
        };
        let _ = stream.set_nodelay(true);
        let app = app.clone();
        let stop = stop.clone();
        conns.spawn(async move {
            connection(stream, app, limits, stop).await;
            tracing::trace!(%peer, "connection closed");
            drop(slot);
        });
    }
    drop(listener);
    while conns.join_next().await.is_some() {}
}

/// Serves one connection until it closes, or until `stop` and its request in progress ends.
async fn connection(
    stream: TcpStream,
    app: Router,
    limits: ServeLimits,
    mut stop: watch::Receiver<bool>,
) {
    // Capped at a day: hyper and tokio add them to the clock's reading, which must not
    // overflow.
    let day = Duration::from_secs(86_400);
    let body_timeout = limits.body_timeout.min(day);
    let activity = Arc::new(Activity::default());
    let in_service = activity.clone();
    let service = hyper::service::service_fn(move |req: Request<Incoming>| {
        let app = app.clone();
        let busy = Busy::new(&in_service);
        async move {
            if let Some(refused) = host_problem(&req) {
                return Ok::<_, Infallible>(refused.into_response());
            }
            let req = req.map(|b| {
                Body::new(MinRateBody {
                    inner: Box::pin(TimeoutBody::new(body_timeout, b)),
                    min_rate: limits.min_body_rate,
                    grace: body_timeout,
                    started: None,
                    read: 0,
                })
            });
            let resp = app.oneshot(req).await?;
            // Busy until the answer's body is sent (an image, an event stream).
            Ok(resp.map(|body| Body::new(Guarded { body, _busy: busy })))
        }
    });
    let mut http = hyper::server::conn::http1::Builder::new();
    http.timer(TokioTimer::new())
        .header_read_timeout(limits.header_timeout.min(day));
    let stream = Marked {
        inner: stream,
        activity: activity.clone(),
    };
    let conn = http.serve_connection(TokioIo::new(stream), service);
    let mut conn = std::pin::pin!(conn);
    tokio::select! {
        r = conn.as_mut() => log_end(r),
        () = stopped(&mut stop) => {
            conn.as_mut().graceful_shutdown();
            if activity.mid_headers() {
                // A request whose headers have not all come has nothing to finish: a moment
                // for them, then the connection goes (unless they came, and it is served).
                let wait = Duration::from_millis(250);
                match tokio::time::timeout(wait, conn.as_mut()).await {
                    Ok(r) => return log_end(r),
                    Err(_) if activity.busy.load(Ordering::SeqCst) == 0 => return,
                    Err(_) => {}
                }
            }
            log_end(conn.await);
        }
    }
}

/// What a connection is doing, as far as a stop needs to know.
#[derive(Default)]
struct Activity {
    /// Requests in the router, or whose answer's body is still being sent.
    busy: AtomicUsize,
    /// Bytes were read since the last request was handed to the router or answered: the
    /// start of a request not yet whole.
    read_since: AtomicBool,
}

impl Activity {
    /// Whether the connection is in the middle of a request's headers: bytes came, and no
    /// request is being served.
    fn mid_headers(&self) -> bool {
        self.busy.load(Ordering::SeqCst) == 0 && self.read_since.load(Ordering::SeqCst)
    }
}

/// One request in the router, or whose answer is still being sent: counted in its
/// connection's [`Activity`] while it lives. The bytes read before and during it were its own.
struct Busy(Arc<Activity>);

impl Busy {
    fn new(activity: &Arc<Activity>) -> Busy {
        activity.busy.fetch_add(1, Ordering::SeqCst);
        activity.read_since.store(false, Ordering::SeqCst);
        Busy(activity.clone())
    }
}

impl Drop for Busy {
    fn drop(&mut self) {
        self.0.read_since.store(false, Ordering::SeqCst);
        self.0.busy.fetch_sub(1, Ordering::SeqCst);
    }
}

/// A connection's stream that notes in its [`Activity`] when bytes are read.
struct Marked {
    inner: TcpStream,
    activity: Arc<Activity>,
}

impl tokio::io::AsyncRead for Marked {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut tokio::io::ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        let before = buf.filled().len();
        let polled = Pin::new(&mut self.inner).poll_read(cx, buf);
        if buf.filled().len() > before {
            self.activity.read_since.store(true, Ordering::SeqCst);
        }
        polled
    }
}

impl tokio::io::AsyncWrite for Marked {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.inner).poll_write(cx, buf)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.inner).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }
}

/// An answer's body that keeps its request counted as [`Busy`] until it is sent or dropped.
struct Guarded {
    body: Body,
    _busy: Busy,
}

impl hyper::body::Body for Guarded {
    type Data = Bytes;
    type Error = axum::Error;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, axum::Error>>> {
        Pin::new(&mut self.body).poll_frame(cx)
    }

    fn is_end_stream(&self) -> bool {
        self.body.is_end_stream()
    }

    fn size_hint(&self) -> hyper::body::SizeHint {
        self.body.size_hint()
    }
}

/// A request body that, once `grace` has passed since it was first read, must have come at
/// `min_rate` bytes a second beyond it: past `grace + read / min_rate` it fails at its next
/// frame. (A body that stops coming altogether is [`TimeoutBody`]'s.)
struct MinRateBody<B> {
    inner: Pin<Box<B>>,
    min_rate: u64,
    grace: Duration,
    started: Option<tokio::time::Instant>,
    read: u64,
}

/// Why a body that came too slowly failed (the handler answers 400 naming `body`).
#[derive(Debug, thiserror::Error)]
#[error(
    "the body came too slowly: {read} bytes in {elapsed:.1} s, where this coordinator reads \
     bodies that come at {min_rate} bytes a second or more past their first {grace} s \
     (--min-body-rate)"
)]
struct TooSlow {
    read: u64,
    elapsed: f64,
    min_rate: u64,
    grace: f64,
}

impl<B> hyper::body::Body for MinRateBody<B>
where
    B: hyper::body::Body<Data = Bytes>,
    B::Error: Into<BoxError>,
{
    type Data = Bytes;
    type Error = BoxError;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, BoxError>>> {
        let this = &mut *self;
        let started = *this.started.get_or_insert_with(tokio::time::Instant::now);
        let frame = match this.inner.as_mut().poll_frame(cx) {
            Poll::Pending => return Poll::Pending,
            Poll::Ready(None) => return Poll::Ready(None),
            Poll::Ready(Some(Err(e))) => return Poll::Ready(Some(Err(e.into()))),
            Poll::Ready(Some(Ok(frame))) => frame,
        };
        this.read += frame.data_ref().map_or(0, |d| d.len() as u64);
        let elapsed = started.elapsed();
        if this.min_rate > 0 && elapsed > this.grace {
            let owed = this.min_rate as f64 * (elapsed - this.grace).as_secs_f64();
            if (this.read as f64) < owed {
                return Poll::Ready(Some(Err(TooSlow {
                    read: this.read,
                    elapsed: elapsed.as_secs_f64(),
                    min_rate: this.min_rate,
                    grace: this.grace.as_secs_f64(),
                }
                .into())));
            }
        }
        Poll::Ready(Some(Ok(frame)))
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> hyper::body::SizeHint {
        self.inner.size_hint()
    }
}

/// Returns once `stop` is `true` (at once if it is), holding no borrow of its value.
async fn stopped(stop: &mut watch::Receiver<bool>) {
    let _ = stop.wait_for(|v| *v).await;
}

fn log_end(r: hyper::Result<()>) {
    if let Err(e) = r {
        tracing::debug!("connection ended: {e}");
    }
}

/// Why an HTTP/1.1 request is refused for its `Host` headers: RFC 9112 requires exactly one,
/// a host and maybe a port. (HTTP/1.0 has no such rule.)
fn host_problem<B>(req: &Request<B>) -> Option<Response<Body>> {
    if req.version() != Version::HTTP_11 {
        return None;
    }
    let hosts = req.headers().get_all(header::HOST);
    let mut values = hosts.iter();
    let message = match (values.next(), values.next()) {
        (Some(host), None) if is_authority(host.as_bytes()) => return None,
        (Some(_), None) => "the Host header is not a host name or address and a port",
        (None, _) => "an HTTP/1.1 request needs a Host header",
        (Some(_), Some(_)) => "a request may have only one Host header",
    };
    Some(
        AppError::BadRequest {
            field: Some("Host".into()),
            message: message.into(),
        }
        .into_response(),
    )
}

/// Whether `host` is a host and maybe a port, as `Host` must be: `name`, `name:port`,
/// `1.2.3.4:port`, `[::1]:port` (no user information, a port of digits that fits 16 bits, an
/// IPv6 address only in brackets).
fn is_authority(host: &[u8]) -> bool {
    let Ok(text) = std::str::from_utf8(host) else {
        return false;
    };
    let Ok(a) = axum::http::uri::Authority::try_from(text) else {
        return false;
    };
    let name = a.host();
    let rest = text.get(name.len()..).unwrap_or_default();
    let port_ok = rest.is_empty() || (rest.starts_with(':') && a.port_u16().is_some());
    let name_ok = match name.strip_prefix('[') {
        Some(inner) => inner.strip_suffix(']').is_some_and(|ip| {
            // A zone id (`%25eth0`) may follow the address.
            let ip = ip.split('%').next().unwrap_or_default();
            ip.parse::<std::net::Ipv6Addr>().is_ok()
        }),
        None => !name.is_empty() && !name.contains(['[', ']']),
    };
    !text.contains('@') && a.as_str() == text && name_ok && port_ok
}

/// Waits after a failed `accept`: at once for an error of the one connection (it was reset
/// before it was accepted), a second for one of the process (out of file descriptors), so as
/// not to spin.
async fn accept_failed(e: std::io::Error) {
    use std::io::ErrorKind::*;
    if matches!(
        e.kind(),
        ConnectionAborted | ConnectionReset | ConnectionRefused | Interrupted
    ) {
        return;
    }
    tracing::error!("accepting a connection: {e}; trying again in a second");
    tokio::time::sleep(Duration::from_secs(1)).await;
}

/// Raises the soft limit on open files toward `max_connections` and some to spare (the
/// database, scene files, the store's temporary files), up to the hard limit; returns the
/// connection cap the limit allows.
#[cfg(unix)]
pub fn fit_file_limit(max_connections: usize) -> usize {
    const SPARE: u64 = 256;
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit and setrlimit read and write the one struct this function owns.
    unsafe {
        if libc::getrlimit(libc::RLIMIT_NOFILE, &mut lim) != 0 {
            return max_connections;
        }
        let want = (max_connections as u64).saturating_add(SPARE);
        if lim.rlim_cur != libc::RLIM_INFINITY && lim.rlim_cur < want {
            let raised = libc::rlimit {
                rlim_cur: want.min(lim.rlim_max),
                rlim_max: lim.rlim_max,
            };
            if libc::setrlimit(libc::RLIMIT_NOFILE, &raised) == 0 {
                lim.rlim_cur = raised.rlim_cur;
            }
        }
    }
    if lim.rlim_cur == libc::RLIM_INFINITY {
        return max_connections;
    }
    let fits = lim.rlim_cur.saturating_sub(SPARE).max(16) as usize;
    if fits < max_connections {
        tracing::warn!(
            "the open-file limit ({}) leaves room for {fits} connections, not {max_connections}: \
             raise it (ulimit -n) or lower --max-connections",
            lim.rlim_cur
        );
    }
    fits.min(max_connections)
}

#[cfg(not(unix))]
pub fn fit_file_limit(max_connections: usize) -> usize {
    max_connections
}
