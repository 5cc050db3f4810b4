//! Cluster-level integration tests live in `tests/`; this library holds what they share.

/// A TCP port that was free on 127.0.0.1 a moment ago (the OS picked it).
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .expect("binding 127.0.0.1:0")
        .local_addr()
        .expect("local address")
        .port()
}

/// The repository's Cornell box (`scenes/cornell-box.json`): part of the repository, so the
/// tests that render it never depend on files outside it. Panics, never skips, when it is
/// missing or does not load.
pub fn cornell_box() -> std::path::PathBuf {
    let p = std::path::PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../scenes/cornell-box.json"
    ));
    assert!(
        p.is_file(),
        "{} is missing from the repository",
        p.display()
    );
    p
}
