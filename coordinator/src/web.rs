//! The web pages: `/` (jobs), `/jobs/{id}` (a job) and `/workers`, one HTML shell whose
//! script reads the path, plus its script, style sheet and icon under `/ui/`. Everything is
//! embedded in the binary (plain HTML, CSS and JavaScript, no build step) and served without
//! the token: the pages hold no data, they fetch it from the API with the token the user gives
//! them. The Content-Security-Policy lets a page load nothing but the coordinator's own files.

use crate::AppState;
use axum::http::header;
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;

const INDEX: &str = include_str!("../web/index.html");
const SCRIPT: &str = include_str!("../web/app.js");
const STYLE: &str = include_str!("../web/style.css");
const ICON: &str = include_str!("../web/icon.svg");

/// Served with every page and file: nothing from anywhere but the coordinator, no inline
/// script or style, no framing.
pub const CSP: &str = "default-src 'none'; script-src 'self'; style-src 'self'; \
     img-src 'self' blob:; connect-src 'self'; base-uri 'none'; form-action 'self'; \
     frame-ancestors 'none'";

/// The page paths and files: served without the token.
pub fn is_public(path: &str) -> bool {
    matches!(path, "/" | "/workers")
        || path.starts_with("/ui/")
        || path
            .strip_prefix("/jobs/")
            .is_some_and(|id| !id.is_empty() && !id.contains('/'))
}

/// The routes of the pages and their files.
pub fn router() -> Router<AppState> {
    Router::new()
        .route("/", get(page))
        .route("/jobs/{id}", get(page))
        .route("/workers", get(page))
        .route(
            "/ui/app.js",
            get(|| file("text/javascript; charset=utf-8", SCRIPT)),
        )
        .route(
            "/ui/style.css",
            get(|| file("text/css; charset=utf-8", STYLE)),
        )
        .route("/ui/icon.svg", get(|| file("image/svg+xml", ICON)))
}

async fn page() -> Response {
    file("text/html; charset=utf-8", INDEX).await
}

async fn file(content_type: &'static str, body: &'static str) -> Response {
    (
        [
            (header::CONTENT_TYPE, content_type),
            (header::CONTENT_SECURITY_POLICY, CSP),
            (header::X_CONTENT_TYPE_OPTIONS, "nosniff"),
            (header::REFERRER_POLICY, "no-referrer"),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        body,
    )
        .into_response()
}
