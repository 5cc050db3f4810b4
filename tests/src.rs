//! Cluster-level integration tests live in `tests/`; this library holds what they share.

/// A TCP port that was free on 127.0.0.1 a moment ago (the OS picked it).
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .expect("binding 127.0.0.1:0")
        .local_addr()
        .expect("local address")
        .port()
}
