//! The one error type of the HTTP API.
//!
//! Every failure leaves as `{"error": {"code": "...", "message": "..."}}` with a fitting status.
//! Codes are stable kebab-case strings clients may match on; messages are for humans. Database
//! and I/O errors are logged in full and answered with a generic 500: their details (SQL, server
//! paths) never reach the client.

use axum::Json;
use axum::extract::multipart::{MultipartError, MultipartRejection};
use axum::extract::rejection::{PathRejection, QueryRejection};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde::Serialize;
use utoipa::ToSchema;

#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    /// The URL names a job or upload that does not exist.
    #[error("{what} {id} not found")]
    NotFound { what: &'static str, id: String },
    /// No route at this path.
    #[error("no such endpoint: {0}")]
    NoRoute(String),
    #[error("method not allowed")]
    MethodNotAllowed,
    /// The request is malformed (syntax, missing part, bad query).
    #[error("{0}")]
    BadRequest(String),
    #[error("the request body is empty")]
    EmptyBody,
    #[error("the upload exceeds the limit of {limit} bytes")]
    PayloadTooLarge { limit: u64 },
    /// The request's Content-Type is not accepted here.
    #[error("unsupported content type {0}")]
    UnsupportedMediaType(String),
    /// The content is neither LAS/LAZ nor a trajectory table.
    #[error("{0}")]
    UnsupportedFile(String),
    /// The file was recognised but is broken (truncated LAS, malformed trajectory...).
    #[error("{0}")]
    InvalidFile(String),
    /// Pipeline parameters failed parsing or validation.
    #[error("invalid parameters: {0}")]
    InvalidParams(String),
    /// The job names an upload that does not exist.
    #[error("unknown upload id {0}")]
    UnknownUpload(String),
    /// The job uses an upload in the wrong role (a trajectory as points...).
    #[error("{0}")]
    WrongUploadKind(String),
    /// The request is well-formed but semantically wrong (no points, too many tiles...).
    #[error("{0}")]
    Unprocessable(String),
    /// The job has no result yet (or never will).
    #[error("job {id} is {status}: {hint}")]
    NotFinished {
        id: String,
        status: String,
        hint: &'static str,
    },
    #[error("job {id} already ended ({status})")]
    AlreadyFinished { id: String, status: String },
    /// WGS84 output asked for a result whose CRS is unknown.
    #[error("{0}")]
    CrsUnavailable(String),
    #[error("database error")]
    Database(#[from] sqlx::Error),
    #[error("storage error")]
    Io(#[from] std::io::Error),
    #[error("internal error")]
    Internal(String),
}

/// Body of every error response.
#[derive(Debug, Serialize, ToSchema)]
pub struct ErrorBody {
    pub error: ErrorDetail,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct ErrorDetail {
    /// Stable kebab-case code, e.g. `invalid-file`, `payload-too-large`, `job-not-finished`.
    pub code: String,
    /// Human-readable explanation naming the problem.
    pub message: String,
}

impl ApiError {
    pub fn status(&self) -> StatusCode {
        match self {
            ApiError::NotFound { .. } | ApiError::NoRoute(_) => StatusCode::NOT_FOUND,
            ApiError::MethodNotAllowed => StatusCode::METHOD_NOT_ALLOWED,
            ApiError::BadRequest(_) | ApiError::EmptyBody => StatusCode::BAD_REQUEST,
            ApiError::PayloadTooLarge { .. } => StatusCode::PAYLOAD_TOO_LARGE,
            ApiError::UnsupportedFile(_) | ApiError::UnsupportedMediaType(_) => {
                StatusCode::UNSUPPORTED_MEDIA_TYPE
            }
            ApiError::InvalidFile(_)
            | ApiError::InvalidParams(_)
            | ApiError::UnknownUpload(_)
            | ApiError::WrongUploadKind(_)
            | ApiError::Unprocessable(_)
            | ApiError::CrsUnavailable(_) => StatusCode::UNPROCESSABLE_ENTITY,
            ApiError::NotFinished { .. } | ApiError::AlreadyFinished { .. } => StatusCode::CONFLICT,
            ApiError::Database(_) | ApiError::Io(_) | ApiError::Internal(_) => {
                StatusCode::INTERNAL_SERVER_ERROR
            }
        }
    }

    pub fn code(&self) -> &'static str {
        match self {
            ApiError::NotFound { what: "job", .. } => "job-not-found",
            ApiError::NotFound { what: "upload", .. } => "upload-not-found",
            ApiError::NotFound { .. } | ApiError::NoRoute(_) => "not-found",
            ApiError::MethodNotAllowed => "method-not-allowed",
            ApiError::BadRequest(_) => "bad-request",
            ApiError::EmptyBody => "empty-body",
            ApiError::PayloadTooLarge { .. } => "payload-too-large",
            ApiError::UnsupportedFile(_) => "unsupported-file",
            ApiError::UnsupportedMediaType(_) => "unsupported-media-type",
            ApiError::InvalidFile(_) => "invalid-file",
            ApiError::InvalidParams(_) => "invalid-params",
            ApiError::UnknownUpload(_) => "unknown-upload",
            ApiError::WrongUploadKind(_) => "wrong-upload-kind",
            ApiError::Unprocessable(_) => "unprocessable",
            ApiError::NotFinished { .. } => "job-not-finished",
            ApiError::AlreadyFinished { .. } => "job-already-finished",
            ApiError::CrsUnavailable(_) => "crs-unknown",
            ApiError::Database(_) | ApiError::Io(_) | ApiError::Internal(_) => "internal-error",
        }
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let status = self.status();
        match &self {
            ApiError::Database(e) => tracing::error!(error = %e, "database error"),
            ApiError::Io(e) => tracing::error!(error = %e, "storage error"),
            ApiError::Internal(e) => tracing::error!(error = %e, "internal error"),
            _ => tracing::debug!(status = status.as_u16(), error = %self, "request rejected"),
        }
        let body = ErrorBody {
            error: ErrorDetail {
                code: self.code().to_string(),
                message: self.to_string(),
            },
        };
        (status, Json(body)).into_response()
    }
}

// axum's own rejections answer in plain text; these turn them into the JSON error shape.

impl From<QueryRejection> for ApiError {
    fn from(r: QueryRejection) -> Self {
        ApiError::BadRequest(format!("invalid query string: {}", r.body_text()))
    }
}

impl From<PathRejection> for ApiError {
    fn from(r: PathRejection) -> Self {
        ApiError::BadRequest(format!("invalid path: {}", r.body_text()))
    }
}

impl From<MultipartRejection> for ApiError {
    fn from(r: MultipartRejection) -> Self {
        ApiError::BadRequest(format!("invalid multipart body: {}", r.body_text()))
    }
}

impl From<MultipartError> for ApiError {
    fn from(e: MultipartError) -> Self {
        if e.status() == StatusCode::PAYLOAD_TOO_LARGE {
            return ApiError::BadRequest(format!("multipart body too large: {}", e.body_text()));
        }
        ApiError::BadRequest(format!("reading the multipart body failed: {}", e.body_text()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn database_details_never_leak() {
        let e = ApiError::from(sqlx::Error::Protocol("SELECT secret FROM jobs".into()));
        let r = e.into_response();
        assert_eq!(r.status(), StatusCode::INTERNAL_SERVER_ERROR);
        let body = axum::body::to_bytes(r.into_body(), 1 << 20).await.unwrap();
        let text = String::from_utf8(body.to_vec()).unwrap();
        assert!(!text.contains("secret"), "{text}");
        assert!(text.contains("\"internal-error\""), "{text}");
    }
}
