//! The coordinator's connection limits on a real socket: the header read timeout, the cap on
//! open connections, the `Host` rule of HTTP/1.1, and a shutdown with idle connections open.

use raytile_coordinator::listen::ServeLimits;
use std::net::SocketAddr;
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

struct Coord {
    addr: SocketAddr,
    stop: tokio::sync::oneshot::Sender<()>,
    task: tokio::task::JoinHandle<anyhow::Result<()>>,
    _dir: tempfile::TempDir,
}

async fn start(limits: ServeLimits) -> Coord {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = raytile_coordinator::Config::new(dir.path().join("data"));
    cfg.serve_limits = limits;
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (stop, rx) = tokio::sync::oneshot::channel::<()>();
    let task = tokio::spawn(raytile_coordinator::run(listener, cfg, async {
        let _ = rx.await;
    }));
    Coord {
        addr,
        stop,
        task,
        _dir: dir,
    }
}

/// Sends `request` on a new connection and reads until the server closes it, or `wait` passes.
async fn exchange(addr: SocketAddr, request: &str, wait: Duration) -> String {
    let mut s = TcpStream::connect(addr).await.unwrap();
    s.write_all(request.as_bytes()).await.unwrap();
    read_to_close(&mut s, wait).await
}

async fn read_to_close(s: &mut TcpStream, wait: Duration) -> String {
    let mut got = Vec::new();
    let _ = tokio::time::timeout(wait, s.read_to_end(&mut got)).await;
    String::from_utf8_lossy(&got).into_owned()
}

/// Uploads `scene` on a connection of its own, in pieces of `piece` bytes each sent after
/// `pause`, and reads the answer until the server closes the connection.
async fn post_scene(addr: SocketAddr, scene: &[u8], piece: usize, pause: Duration) -> String {
    let mut s = TcpStream::connect(addr).await.unwrap();
    let head = format!(
        "POST /v1/scenes HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
        scene.len()
    );
    s.write_all(head.as_bytes()).await.unwrap();
    for part in scene.chunks(piece) {
        tokio::time::sleep(pause).await;
        s.write_all(part).await.unwrap();
    }
    read_to_close(&mut s, Duration::from_secs(30)).await
}

fn status(response: &str) -> &str {
    response.lines().next().unwrap_or_default()
}

#[tokio::test]
async fn a_client_that_does_not_finish_its_headers_is_cut_off() {
    let c = start(ServeLimits {
        header_timeout: Duration::from_millis(300),
        ..ServeLimits::default()
    })
    .await;
    let mut s = TcpStream::connect(c.addr).await.unwrap();
    s.write_all(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
        .await
        .unwrap();
    let t = Instant::now();
    let got = read_to_close(&mut s, Duration::from_secs(10)).await;
    let waited = t.elapsed();
    assert!(
        waited < Duration::from_secs(5),
        "the connection stayed open {waited:?}"
    );
    assert!(!got.contains("200 OK"), "{got}");

    // A connection that sends nothing at all is closed the same way.
    let mut idle = TcpStream::connect(c.addr).await.unwrap();
    let t = Instant::now();
    read_to_close(&mut idle, Duration::from_secs(10)).await;
    assert!(t.elapsed() < Duration::from_secs(5), "{:?}", t.elapsed());

    // A keep-alive connection is closed when it stays idle that long after a request.
    let mut kept = TcpStream::connect(c.addr).await.unwrap();
    kept.write_all(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        .await
        .unwrap();
    let t = Instant::now();
    let got = read_to_close(&mut kept, Duration::from_secs(10)).await;
    assert_eq!(status(&got), "HTTP/1.1 200 OK", "{got}");
    assert!(t.elapsed() < Duration::from_secs(5), "{:?}", t.elapsed());

    // A complete request in time is served.
    let ok = exchange(
        c.addr,
        "GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n",
        Duration::from_secs(10),
    )
    .await;
    assert_eq!(status(&ok), "HTTP/1.1 200 OK", "{ok}");
    let _ = c.stop.send(());
    c.task.await.unwrap().unwrap();
}

#[tokio::test]
async fn connections_past_the_cap_wait_for_one_to_close() {
    let c = start(ServeLimits {
        max_connections: 2,
        header_timeout: Duration::from_secs(60),
        ..ServeLimits::default()
    })
    .await;
    let mut held = vec![
        TcpStream::connect(c.addr).await.unwrap(),
        TcpStream::connect(c.addr).await.unwrap(),
    ];
    // Both are accepted (a request on one is answered), and hold the two places.
    held[0]
        .write_all(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        .await
        .unwrap();
    let mut buf = [0u8; 512];
    let n = tokio::time::timeout(Duration::from_secs(10), held[0].read(&mut buf))
        .await
        .expect("the first connection is served")
        .unwrap();
    assert!(String::from_utf8_lossy(&buf[..n]).starts_with("HTTP/1.1 200"));

    // The third connects (the kernel's queue takes it) but is not served...
    let request = "GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n";
    let mut third = TcpStream::connect(c.addr).await.unwrap();
    third.write_all(request.as_bytes()).await.unwrap();
    let early = tokio::time::timeout(Duration::from_millis(500), third.read(&mut buf)).await;
    assert!(early.is_err(), "served past the cap: {early:?}");

    // ...until one of the two closes.
    held.pop();
    let got = read_to_close(&mut third, Duration::from_secs(10)).await;
    assert_eq!(status(&got), "HTTP/1.1 200 OK", "{got}");
    drop(held);
    let _ = c.stop.send(());
    c.task.await.unwrap().unwrap();
}

#[tokio::test]
async fn an_http_1_1_request_needs_exactly_one_host() {
    let c = start(ServeLimits::default()).await;
    let wait = Duration::from_secs(10);
    for (request, want) in [
        ("GET /healthz HTTP/1.1\r\nConnection: close\r\n\r\n", "400"),
        ("GET /v1/jobs HTTP/1.1\r\nConnection: close\r\n\r\n", "400"),
        (
            "GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n",
            "400",
        ),
        (
            "GET /healthz HTTP/1.1\r\nHost: a b\r\nConnection: close\r\n\r\n",
            "400",
        ),
        (
            "GET /healthz HTTP/1.1\r\nHost: user@127.0.0.1\r\nConnection: close\r\n\r\n",
            "400",
        ),
        (
            "GET /healthz HTTP/1.1\r\nHost: \r\nConnection: close\r\n\r\n",
            "400",
        ),
        (
            "GET /healthz HTTP/1.1\r\nHost: farm:99999\r\nConnection: close\r\n\r\n",
            "400",
        ),
        (
            "GET /healthz HTTP/1.1\r\nHost: farm:abc\r\nConnection: close\r\n\r\n",
            "400",
        ),
        (
            "GET /healthz HTTP/1.1\r\nHost: [::1]junk\r\nConnection: close\r\n\r\n",
            "400",
        ),
        (
            "GET /healthz HTTP/1.1\r\nHost: [garbage]\r\nConnection: close\r\n\r\n",
            "400",
        ),
        (
            "GET /healthz HTTP/1.1\r\nHost: LOCALHOST\r\nConnection: close\r\n\r\n",
            "200",
        ),
        (
            "GET /healthz HTTP/1.1\r\nHost: [::1]:8080\r\nConnection: close\r\n\r\n",
            "200",
        ),
        (
            "GET /healthz HTTP/1.1\r\nHost: farm.example:8080\r\nConnection: close\r\n\r\n",
            "200",
        ),
        ("GET /healthz HTTP/1.0\r\n\r\n", "200"),
        (
            "GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n",
            "200",
        ),
    ] {
        let got = exchange(c.addr, request, wait).await;
        assert!(
            status(&got).split(' ').nth(1) == Some(want),
            "{request:?}: {got}"
        );
        if want == "400" {
            assert!(got.contains(r#""field":"Host""#), "{got}");
        }
    }
    let _ = c.stop.send(());
    c.task.await.unwrap().unwrap();
}

#[tokio::test]
async fn shutdown_closes_idle_connections_at_once() {
    let c = start(ServeLimits::default()).await;
    let mut idle = TcpStream::connect(c.addr).await.unwrap();
    idle.write_all(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        .await
        .unwrap();
    let mut buf = [0u8; 512];
    let _ = idle.read(&mut buf).await.unwrap();
    let t = Instant::now();
    let _ = c.stop.send(());
    c.task.await.unwrap().unwrap();
    assert!(
        t.elapsed() < Duration::from_secs(3),
        "stopping took {:?} with an idle keep-alive connection open",
        t.elapsed()
    );
    assert_eq!(idle.read(&mut buf).await.unwrap_or(0), 0, "closed");
}

/// A connection in the middle of its request's headers has no request to finish: shutdown
/// closes it at once rather than wait for the hard stop.
#[tokio::test]
async fn shutdown_does_not_wait_for_a_request_still_sending_its_headers() {
    let c = start(ServeLimits::default()).await;
    let mut half = TcpStream::connect(c.addr).await.unwrap();
    half.write_all(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nAccept: ")
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(200)).await;
    let t = Instant::now();
    let _ = c.stop.send(());
    c.task.await.unwrap().unwrap();
    assert!(
        t.elapsed() < Duration::from_secs(3),
        "stopping took {:?} with a request's headers half sent",
        t.elapsed()
    );
    let mut buf = [0u8; 512];
    assert_eq!(half.read(&mut buf).await.unwrap_or(0), 0, "closed");
}

/// An answer still being written when the stop comes (a large download whose client reads
/// late) is sent whole before its connection closes.
#[tokio::test]
async fn shutdown_lets_an_answer_being_written_finish() {
    let c = start(ServeLimits::default()).await;
    // A scene of 8 MB (a JSON scene padded with spaces), so that its download outgrows the
    // sockets' buffers.
    let mut scene = br#"{"objects": []}"#.to_vec();
    scene.resize(8 << 20, b' ');
    let created = post_scene(c.addr, &scene, scene.len(), Duration::ZERO).await;
    assert!(status(&created).starts_with("HTTP/1.1 20"), "{created}");
    let body = &created[created.find("\r\n\r\n").unwrap() + 4..];
    let id: serde_json::Value = serde_json::from_str(body).unwrap();
    let id = id["id"].as_str().unwrap().to_string();

    let mut down = TcpStream::connect(c.addr).await.unwrap();
    down.write_all(format!("GET /v1/scenes/{id} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n").as_bytes())
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(300)).await;
    let _ = c.stop.send(());
    // The client reads only after the stop began.
    tokio::time::sleep(Duration::from_millis(700)).await;
    let mut got = Vec::new();
    let _ = tokio::time::timeout(Duration::from_secs(10), down.read_to_end(&mut got)).await;
    let split = got.windows(4).position(|w| w == b"\r\n\r\n").unwrap() + 4;
    let head = String::from_utf8_lossy(&got[..split]).to_lowercase();
    assert!(head.starts_with("http/1.1 200"), "{head}");
    assert_eq!(got.len() - split, scene.len(), "the whole scene, {head}");
    c.task.await.unwrap().unwrap();
}

/// The same for an answer held whole in memory (as a job's image is): its body is handed to
/// the connection in one piece, so the request is over while most of it waits to be written.
#[tokio::test]
async fn shutdown_lets_an_answer_held_in_memory_finish() {
    const SIZE: usize = 32 << 20;
    let app = axum::Router::new().route("/big", axum::routing::get(|| async { vec![b'x'; SIZE] }));
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (stop, rx) = tokio::sync::watch::channel(false);
    let server = tokio::spawn(raytile_coordinator::listen::serve(
        listener,
        app,
        ServeLimits::default(),
        rx,
    ));
    let mut s = TcpStream::connect(addr).await.unwrap();
    s.write_all(b"GET /big HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(300)).await;
    stop.send(true).unwrap();
    tokio::time::sleep(Duration::from_millis(700)).await;
    let mut got = Vec::new();
    let _ = tokio::time::timeout(Duration::from_secs(10), s.read_to_end(&mut got)).await;
    let split = got.windows(4).position(|w| w == b"\r\n\r\n").unwrap() + 4;
    assert_eq!(got.len() - split, SIZE, "the whole answer");
    server.await.unwrap();
}

/// A request still in progress 5 s after shutdown began (here an upload whose body stopped
/// coming) does not keep the coordinator from stopping, and its connection is closed then.
#[tokio::test]
async fn a_request_still_running_is_cut_off_by_the_hard_stop() {
    let c = start(ServeLimits::default()).await;
    let mut slow = TcpStream::connect(c.addr).await.unwrap();
    slow.write_all(
        b"POST /v1/scenes HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 1000\r\n\r\n{\"objects\"",
    )
    .await
    .unwrap();
    tokio::time::sleep(Duration::from_millis(200)).await;
    let t = Instant::now();
    let _ = c.stop.send(());
    c.task.await.unwrap().unwrap();
    let waited = t.elapsed();
    assert!(
        waited >= Duration::from_secs(4) && waited < Duration::from_secs(8),
        "{waited:?}"
    );
    let mut got = Vec::new();
    let closed = tokio::time::timeout(Duration::from_secs(2), slow.read_to_end(&mut got)).await;
    assert!(closed.is_ok(), "the connection is still open");
    assert!(!String::from_utf8_lossy(&got).contains("201"));
}

/// A result sent for a job that is gone (purged) is read to its end before the 404, so a client
/// that sends its whole body before it reads gets the answer, not a connection closed under its
/// upload (which a worker would take for a network fault, and send again).
#[tokio::test]
async fn an_upload_to_a_job_that_is_gone_gets_its_404() {
    let c = start(ServeLimits::default()).await;
    for size in [1usize << 10, 3 << 20, 24 << 20] {
        let mut s = TcpStream::connect(c.addr).await.unwrap();
        let head = format!(
            "PUT /v1/jobs/job-1-gone/tasks/0/result?lease=l HTTP/1.1\r\nHost: 127.0.0.1\r\n\
             Content-Length: {size}\r\nConnection: close\r\n\r\n"
        );
        s.write_all(head.as_bytes()).await.unwrap();
        let sent = s.write_all(&vec![0u8; size]).await;
        assert!(sent.is_ok(), "{size} bytes: {sent:?}");
        let got = read_to_close(&mut s, Duration::from_secs(10)).await;
        assert_eq!(
            status(&got),
            "HTTP/1.1 404 Not Found",
            "{size} bytes: {got}"
        );
    }
    let _ = c.stop.send(());
    c.task.await.unwrap().unwrap();
}

/// An upload whose body stops coming fails after the body timeout, answered 400 naming `body`,
/// instead of holding its connection (and a large result's slot) for ever; with no least rate,
/// one that keeps coming, however slowly, is read.
#[tokio::test]
async fn a_stalled_body_fails_after_the_body_timeout() {
    let c = start(ServeLimits {
        body_timeout: Duration::from_millis(300),
        min_body_rate: 0,
        ..ServeLimits::default()
    })
    .await;
    let mut s = TcpStream::connect(c.addr).await.unwrap();
    s.write_all(
        b"POST /v1/scenes HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 1000\r\n\r\n{\"objects\"",
    )
    .await
    .unwrap();
    let t = Instant::now();
    let got = read_to_close(&mut s, Duration::from_secs(10)).await;
    assert!(t.elapsed() < Duration::from_secs(5), "{:?}", t.elapsed());
    assert_eq!(status(&got), "HTTP/1.1 400 Bad Request", "{got}");
    assert!(got.contains(r#""field":"body""#), "{got}");

    // Ten pauses of 150 ms, each under the timeout: read whole.
    let body = br#"{"objects": []}"#;
    let got = post_scene(
        c.addr,
        body,
        body.len().div_ceil(10),
        Duration::from_millis(150),
    )
    .await;
    assert!(status(&got).starts_with("HTTP/1.1 20"), "{got}");
    let _ = c.stop.send(());
    c.task.await.unwrap().unwrap();
}

/// A body that keeps coming, but slower than the least rate once the body timeout has passed,
/// fails (400 naming `body`, saying the rate); one at a higher rate is read whole, however long
/// it takes.
#[tokio::test]
async fn a_trickling_body_fails_below_the_least_rate() {
    let c = start(ServeLimits {
        body_timeout: Duration::from_millis(300),
        min_body_rate: 200,
        ..ServeLimits::default()
    })
    .await;
    // 5 bytes every 100 ms: 50 bytes a second. Past 300 ms it owes 200 a second beyond them,
    // so it fails from about 400 ms, well before its 1000 bytes are sent.
    let mut s = TcpStream::connect(c.addr).await.unwrap();
    s.write_all(b"POST /v1/scenes HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 1000\r\n\r\n")
        .await
        .unwrap();
    let t = Instant::now();
    let (mut rd, mut wr) = s.into_split();
    let trickle = tokio::spawn(async move {
        for _ in 0..200 {
            tokio::time::sleep(Duration::from_millis(100)).await;
            if wr.write_all(b"     ").await.is_err() {
                break;
            }
        }
    });
    let mut got = Vec::new();
    let _ = tokio::time::timeout(Duration::from_secs(10), rd.read_to_end(&mut got)).await;
    let got = String::from_utf8_lossy(&got).to_string();
    assert!(t.elapsed() < Duration::from_secs(5), "{:?}", t.elapsed());
    assert_eq!(status(&got), "HTTP/1.1 400 Bad Request", "{got}");
    assert!(
        got.contains(r#""field":"body""#) && got.contains("--min-body-rate"),
        "{got}"
    );
    trickle.abort();

    // 100 bytes every 100 ms, 1000 a second, for 1.5 s: read whole.
    let body = format!("{{\"objects\": []{}}}", " ".repeat(1484));
    let got = post_scene(c.addr, body.as_bytes(), 100, Duration::from_millis(100)).await;
    assert!(status(&got).starts_with("HTTP/1.1 20"), "{got}");
    let _ = c.stop.send(());
    c.task.await.unwrap().unwrap();
}
