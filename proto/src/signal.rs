//! The end of a service process: Ctrl-C, or SIGTERM from systemd, Docker or Kubernetes.

/// Completes at Ctrl-C or SIGTERM. The coordinator and the worker pass it to their `run` as the
/// shutdown future; both then stop gracefully (leases handed back, the last result delivered).
pub async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            // Without a SIGTERM handler, Ctrl-C still works.
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! { _ = ctrl_c => {}, _ = term => {} }
}
