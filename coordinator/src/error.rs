//! The one error type of the HTTP API and its JSON body, and the extractors ([`Json`],
//! [`Query`], [`Path`]) whose rejections use it: no answer of the coordinator is axum's plain
//! text.

use axum::extract::rejection::{JsonRejection, PathRejection};
use axum::extract::{FromRequest, FromRequestParts};
use axum::http::request::Parts;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use raytile_proto::{ErrorBody, ErrorDetail};

/// Everything a handler can answer other than success.
#[derive(Debug, thiserror::Error)]
pub enum AppError {
    /// 400: the request is malformed (bad JSON, bad query).
    #[error("{message}")]
    BadRequest {
        /// Offending field, if known.
        field: Option<String>,
        /// What is wrong.
        message: String,
    },
    /// 401: missing or wrong bearer token.
    #[error("missing or wrong bearer token")]
    Unauthorized,
    /// 403: a request the coordinator refuses whoever sends it: a browser's request from
    /// another site's page, or a name for the coordinator it cannot trust.
    #[error("{0}")]
    Forbidden(String),
    /// 403: a token the coordinator knows, on an endpoint of the other kind (a worker's token
    /// on a user's endpoint, or the other way round); names the field `Authorization`.
    #[error("{0}")]
    WrongToken(String),
    /// 404: no such object.
    #[error("{0}")]
    NotFound(String),
    /// 409: the request conflicts with the object's state.
    #[error("{0}")]
    Conflict(String),
    /// 405: the path exists, the method does not.
    #[error("method not allowed here")]
    MethodNotAllowed,
    /// 413: the body is over the limit.
    #[error("request body over the limit of {0} bytes")]
    TooLarge(u64),
    /// 416: a byte range that starts past the end of an image of this many bytes.
    #[error("the range starts past the end of the image's {0} bytes")]
    RangeNotSatisfiable(usize),
    /// 415: a JSON body without `Content-Type: application/json`.
    #[error("{0}")]
    UnsupportedMediaType(String),
    /// 422: well-formed but invalid (settings, scene content).
    #[error("{message}")]
    Invalid {
        /// Offending field, if known.
        field: Option<String>,
        /// What is wrong.
        message: String,
    },
    /// 429: too many queued jobs.
    #[error("{0}")]
    TooMany(String),
    /// 503: shutting down (retryable: another coordinator, or this one restarted, answers).
    #[error("shutting down")]
    Unavailable,
    /// 503: the store could not be written (disk full, read-only...): nothing changed, and
    /// the same request may succeed later. Logged in full, answered briefly.
    #[error(
        "the coordinator cannot write its store (its database or result files) at the moment; nothing was changed: retry later"
    )]
    StoreUnavailable(#[source] rusqlite::Error),
    /// 503: a file in the data directory could not be written (disk full, read-only, a
    /// folder removed...): nothing was kept, and the same request may succeed later. Answered
    /// as [`AppError::StoreUnavailable`]; the log says which file and why.
    #[error(
        "the coordinator cannot write its data directory at the moment; nothing was changed: retry later"
    )]
    DiskUnavailable {
        /// What was being written, with its path.
        what: String,
        /// The error.
        #[source]
        error: std::io::Error,
    },
    /// 503: too busy to take this request now (every scene parse slot stayed taken); answered
    /// with `Retry-After`.
    #[error("{0}")]
    Busy(String),
    /// 500: anything else; logged in full, answered briefly.
    #[error("internal error")]
    Internal(#[from] anyhow::Error),
}

impl AppError {
    /// 422 naming `field`.
    pub fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        AppError::Invalid {
            field: Some(field.into()),
            message: message.into(),
        }
    }

    /// 400 naming `field`.
    pub fn bad(field: impl Into<String>, message: impl Into<String>) -> Self {
        AppError::BadRequest {
            field: Some(field.into()),
            message: message.into(),
        }
    }

    /// A 503 for a failed write of `what` (a file in the data directory, named with its path).
    pub fn disk(what: impl std::fmt::Display) -> impl FnOnce(std::io::Error) -> AppError {
        let what = what.to_string();
        move |error| AppError::DiskUnavailable { what, error }
    }

    /// 500 from anything displayable.
    pub fn internal(e: impl std::fmt::Display) -> Self {
        AppError::Internal(anyhow::anyhow!("{e}"))
    }
}

impl From<crate::sched::SchedError> for AppError {
    fn from(e: crate::sched::SchedError) -> Self {
        use crate::sched::SchedError as S;
        match e {
            S::NoJob(_) | S::NoTask(..) | S::NoWorker(_) => AppError::NotFound(e.to_string()),
            S::Mismatch(m) => AppError::invalid("body", m),
            S::Store(e) => AppError::StoreUnavailable(e),
        }
    }
}

impl AppError {
    /// The status, the machine-readable code and the field of the answer.
    fn parts(&self) -> (StatusCode, &'static str, Option<String>) {
        match self {
            AppError::BadRequest { field, .. } => {
                (StatusCode::BAD_REQUEST, "bad_request", field.clone())
            }
            AppError::Unauthorized => (StatusCode::UNAUTHORIZED, "unauthorized", None),
            AppError::Forbidden(_) => (StatusCode::FORBIDDEN, "forbidden", None),
            AppError::WrongToken(_) => (
                StatusCode::FORBIDDEN,
                "forbidden",
                Some("Authorization".into()),
            ),
            AppError::NotFound(_) => (StatusCode::NOT_FOUND, "not_found", None),
            AppError::MethodNotAllowed => {
                (StatusCode::METHOD_NOT_ALLOWED, "method_not_allowed", None)
            }
            AppError::Conflict(_) => (StatusCode::CONFLICT, "conflict", None),
            AppError::TooLarge(_) => (StatusCode::PAYLOAD_TOO_LARGE, "too_large", None),
            AppError::RangeNotSatisfiable(_) => (
                StatusCode::RANGE_NOT_SATISFIABLE,
                "range_not_satisfiable",
                Some("Range".into()),
            ),
            AppError::UnsupportedMediaType(_) => (
                StatusCode::UNSUPPORTED_MEDIA_TYPE,
                "unsupported_media_type",
                Some("body".into()),
            ),
            AppError::Invalid { field, .. } => {
                (StatusCode::UNPROCESSABLE_ENTITY, "invalid", field.clone())
            }
            AppError::TooMany(_) => (StatusCode::TOO_MANY_REQUESTS, "too_many", None),
            AppError::Unavailable => (StatusCode::SERVICE_UNAVAILABLE, "unavailable", None),
            AppError::StoreUnavailable(_) | AppError::DiskUnavailable { .. } => {
                (StatusCode::SERVICE_UNAVAILABLE, "store_unavailable", None)
            }
            AppError::Busy(_) => (StatusCode::SERVICE_UNAVAILABLE, "busy", None),
            AppError::Internal(_) => (StatusCode::INTERNAL_SERVER_ERROR, "internal", None),
        }
    }
}

/// Requests this process answered 503 because the store (the database, a result file or a
/// scene upload's file) could not be written: `/metrics`' `raytile_store_failures_total`, so
/// that monitoring sees a full or read-only disk while `/healthz` still answers.
pub static STORE_FAILURES: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

impl IntoResponse for AppError {
    fn into_response(self) -> Response {
        let (status, code, field) = self.parts();
        match &self {
            AppError::Internal(e) => tracing::error!("internal error: {e:#}"),
            AppError::StoreUnavailable(e) => {
                STORE_FAILURES.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                tracing::error!("store write failed, answered 503: {e}")
            }
            AppError::DiskUnavailable { what, error } => {
                STORE_FAILURES.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                tracing::error!("writing {what} failed, answered 503: {error}")
            }
            _ => {}
        }
        let retryable = matches!(
            self,
            AppError::Unavailable
                | AppError::StoreUnavailable(_)
                | AppError::DiskUnavailable { .. }
                | AppError::Busy(_)
        );
        let mut message = self.to_string();
        if let Some(f) = &field {
            if !message.starts_with(f.as_str()) {
                message = format!("{f}: {message}");
            }
        }
        let body = ErrorBody {
            error: ErrorDetail {
                code: code.into(),
                message,
                field,
                retryable,
            },
        };
        let mut resp = (status, axum::Json(body)).into_response();
        let headers = resp.headers_mut();
        if let AppError::RangeNotSatisfiable(len) = self {
            if let Ok(v) = axum::http::HeaderValue::from_str(&format!("bytes */{len}")) {
                headers.insert(axum::http::header::CONTENT_RANGE, v);
            }
        }
        if status == StatusCode::UNAUTHORIZED {
            headers.insert(
                axum::http::header::WWW_AUTHENTICATE,
                axum::http::HeaderValue::from_static("Bearer"),
            );
        }
        if retryable {
            let secs = if matches!(self, AppError::Busy(_)) {
                "2"
            } else {
                "1"
            };
            headers.insert(
                axum::http::header::RETRY_AFTER,
                axum::http::HeaderValue::from_static(secs),
            );
        }
        resp
    }
}

/// JSON body extractor whose rejections use the app's error format. Every struct in the body
/// is read from a JSON object only ([`raytile_proto::json::Strict`]): an array of a struct's
/// fields is refused, as in scene files.
pub struct Json<T>(pub T);

impl<T, S> FromRequest<S> for Json<T>
where
    T: serde::de::DeserializeOwned,
    S: Send + Sync,
{
    type Rejection = AppError;

    async fn from_request(req: axum::extract::Request, state: &S) -> Result<Self, AppError> {
        let axum::Json(raytile_proto::json::Strict(v)) =
            axum::Json::<raytile_proto::json::Strict<T>>::from_request(req, state).await?;
        Ok(Json(v))
    }
}

impl<T: serde::Serialize> IntoResponse for Json<T> {
    fn into_response(self) -> Response {
        axum::Json(self.0).into_response()
    }
}

impl From<JsonRejection> for AppError {
    fn from(r: JsonRejection) -> Self {
        use axum::extract::rejection::JsonRejection as J;
        if r.status() == StatusCode::PAYLOAD_TOO_LARGE {
            return AppError::TooLarge(crate::api::JSON_BODY_LIMIT as u64);
        }
        match r {
            J::JsonDataError(e) => {
                // serde's own message (the rejection's source), without the preface the
                // rejection's text puts before it: "width: invalid type: ...", the JSON path of
                // the offending field first.
                let message = std::error::Error::source(&e)
                    .map_or_else(|| e.body_text(), ToString::to_string);
                let message = raytile_proto::json::plain_message(&message);
                let field = message
                    .split_once(": ")
                    .map(|(f, _)| f.to_string())
                    .filter(|f| {
                        f.starts_with(|c: char| c.is_ascii_alphabetic())
                            && f.chars()
                                .all(|c| c.is_ascii_alphanumeric() || "_.".contains(c))
                    });
                // A member missing from the body itself, or given twice, names that member.
                let missing = ["missing field `", "duplicate field `"]
                    .iter()
                    .find_map(|p| message.strip_prefix(p))
                    .and_then(|m| m.split_once('`'))
                    .map(|(f, _)| f.to_string());
                AppError::Invalid {
                    // A body of the wrong shape altogether (an array, a string) names the body.
                    field: field.or(missing).or_else(|| Some("body".into())),
                    message,
                }
            }
            // The JSON parser's message alone (the innermost source: where the text stops being
            // JSON), without the rejection's preface or the path of the field it was in.
            J::JsonSyntaxError(e) => {
                let mut inner: &dyn std::error::Error = &e;
                while let Some(next) = inner.source() {
                    inner = next;
                }
                let message =
                    match inner.downcast_ref::<serde_path_to_error::Error<serde_json::Error>>() {
                        Some(located) => located.inner().to_string(),
                        None => inner.to_string(),
                    };
                AppError::BadRequest {
                    field: Some("body".into()),
                    message: format!("not valid JSON: {message}"),
                }
            }
            J::MissingJsonContentType(_) => AppError::UnsupportedMediaType(
                "expected a JSON body with Content-Type: application/json".into(),
            ),
            r => AppError::BadRequest {
                field: Some("body".into()),
                message: r.body_text(),
            },
        }
    }
}

/// The first parameter of query string `q` whose value is not UTF-8 once percent-decoded (its
/// name), or whose name is not (`Err`).
fn not_utf8(q: &str) -> Option<Result<String, ()>> {
    fn decode(s: &str) -> Vec<u8> {
        let b = s.as_bytes();
        let mut out = Vec::with_capacity(b.len());
        let mut i = 0;
        while i < b.len() {
            let hex = |c: u8| (c as char).to_digit(16).map(|d| d as u8);
            match (
                b[i],
                b.get(i + 1).copied().and_then(hex),
                b.get(i + 2).copied().and_then(hex),
            ) {
                (b'%', Some(h), Some(l)) => {
                    out.push(h * 16 + l);
                    i += 3;
                }
                (b'+', ..) => {
                    out.push(b' ');
                    i += 1;
                }
                (c, ..) => {
                    out.push(c);
                    i += 1;
                }
            }
        }
        out
    }
    q.split('&').filter(|p| !p.is_empty()).find_map(|pair| {
        let (name, value) = pair.split_once('=').unwrap_or((pair, ""));
        match String::from_utf8(decode(name)) {
            Err(_) => Some(Err(())),
            Ok(n) => std::str::from_utf8(&decode(value))
                .is_err()
                .then_some(Ok(n)),
        }
    })
}

/// Query string extractor: a value of the wrong type (`?purge=x`), a parameter given twice
/// (`?format=a&format=b`) or bytes that are not UTF-8 are a 400 naming the parameter.
#[derive(Debug)]
pub struct Query<T>(pub T);

impl<T: serde::de::DeserializeOwned, S: Send + Sync> FromRequestParts<S> for Query<T> {
    type Rejection = AppError;

    async fn from_request_parts(parts: &mut Parts, _: &S) -> Result<Self, AppError> {
        let q = parts.uri.query().unwrap_or_default();
        // The parser replaces bytes that are not UTF-8 with U+FFFD: refuse them first.
        match not_utf8(q) {
            Some(Ok(name)) => {
                let message = format!(
                    "query string: the value of `{name}` is not UTF-8 once percent-decoded"
                );
                return Err(AppError::bad(name, message));
            }
            Some(Err(())) => {
                return Err(AppError::bad(
                    "query",
                    "query string: a parameter's name is not UTF-8 once percent-decoded",
                ))
            }
            None => {}
        }
        let de = serde_urlencoded::Deserializer::new(form_urlencoded::parse(q.as_bytes()));
        serde_path_to_error::deserialize(de).map(Query).map_err(
            |e: serde_path_to_error::Error<_>| {
                let inner = raytile_proto::json::plain_message(&e.inner().to_string());
                let path = e.path().to_string();
                // A duplicate names its field in the message, not in the path.
                let field = if path == "." {
                    inner.split('`').nth(1).unwrap_or("query").to_string()
                } else {
                    path
                };
                AppError::bad(field, format!("query string: {inner}"))
            },
        )
    }
}

/// Path parameter extractor: a parameter that does not parse (a task index that is not a
/// number, bytes that are not UTF-8) is a 400 naming the parameter.
#[derive(Debug)]
pub struct Path<T>(pub T);

impl<T, S> FromRequestParts<S> for Path<T>
where
    T: serde::de::DeserializeOwned + Send,
    S: Send + Sync,
{
    type Rejection = AppError;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, AppError> {
        match axum::extract::Path::<T>::from_request_parts(parts, state).await {
            Ok(axum::extract::Path(v)) => Ok(Path(v)),
            Err(r) => Err(path_rejection(r)),
        }
    }
}

fn path_rejection(r: PathRejection) -> AppError {
    use axum::extract::path::ErrorKind as K;
    let message = r.body_text();
    let field = match &r {
        PathRejection::FailedToDeserializePathParams(e) => match e.kind() {
            K::ParseErrorAtKey { key, .. }
            | K::InvalidUtf8InPathParam { key }
            | K::DeserializeError { key, .. } => Some(key.clone()),
            _ => None,
        },
        _ => None,
    };
    match field {
        Some(f) => AppError::bad(f, message),
        None => AppError::BadRequest {
            field: None,
            message,
        },
    }
}
