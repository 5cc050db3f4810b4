//! The one error type of the HTTP API and its JSON body.

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
    /// 404: no such object.
    #[error("{0}")]
    NotFound(String),
    /// 409: the request conflicts with the object's state.
    #[error("{0}")]
    Conflict(String),
    /// 413: the body is over the limit.
    #[error("request body over the limit of {0} bytes")]
    TooLarge(u64),
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
    /// 503: shutting down.
    #[error("shutting down")]
    Unavailable,
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
            S::Store(e) => AppError::Internal(e.into()),
        }
    }
}

impl IntoResponse for AppError {
    fn into_response(self) -> Response {
        let (status, code, field) = match &self {
            AppError::BadRequest { field, .. } => {
                (StatusCode::BAD_REQUEST, "bad_request", field.clone())
            }
            AppError::Unauthorized => (StatusCode::UNAUTHORIZED, "unauthorized", None),
            AppError::NotFound(_) => (StatusCode::NOT_FOUND, "not_found", None),
            AppError::Conflict(_) => (StatusCode::CONFLICT, "conflict", None),
            AppError::TooLarge(_) => (StatusCode::PAYLOAD_TOO_LARGE, "too_large", None),
            AppError::Invalid { field, .. } => {
                (StatusCode::UNPROCESSABLE_ENTITY, "invalid", field.clone())
            }
            AppError::TooMany(_) => (StatusCode::TOO_MANY_REQUESTS, "too_many", None),
            AppError::Unavailable => (StatusCode::SERVICE_UNAVAILABLE, "unavailable", None),
            AppError::Busy(_) => (StatusCode::SERVICE_UNAVAILABLE, "busy", None),
            AppError::Internal(e) => {
                tracing::error!("internal error: {e:#}");
                (StatusCode::INTERNAL_SERVER_ERROR, "internal", None)
            }
        };
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
            },
        };
        let mut resp = (status, axum::Json(body)).into_response();
        if status == StatusCode::UNAUTHORIZED {
            resp.headers_mut().insert(
                axum::http::header::WWW_AUTHENTICATE,
                axum::http::HeaderValue::from_static("Bearer"),
            );
        }
        if code == "busy" {
            resp.headers_mut().insert(
                axum::http::header::RETRY_AFTER,
                axum::http::HeaderValue::from_static("2"),
            );
        }
        resp
    }
}

/// JSON body extractor whose rejections use the app's error format.
#[derive(axum::extract::FromRequest)]
#[from_request(via(axum::Json), rejection(AppError))]
pub struct Json<T>(pub T);

impl<T: serde::Serialize> IntoResponse for Json<T> {
    fn into_response(self) -> Response {
        axum::Json(self.0).into_response()
    }
}

impl From<axum::extract::rejection::JsonRejection> for AppError {
    fn from(r: axum::extract::rejection::JsonRejection) -> Self {
        use axum::extract::rejection::JsonRejection as J;
        let text = r.body_text();
        // serde's messages start with the JSON path of the offending field ("width: ...").
        let field = text
            .split_once(": ")
            .and_then(|(_, rest)| rest.split_once(": "))
            .map(|(f, _)| f.to_string())
            .filter(|f| !f.contains(' '));
        match r {
            J::JsonDataError(_) => AppError::Invalid {
                field,
                message: text,
            },
            _ => AppError::BadRequest {
                field: Some("body".into()),
                message: text,
            },
        }
    }
}
