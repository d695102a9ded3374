//! `GET /healthz`: the service answers and its database is reachable.

use super::AppState;
use super::error::ErrorBody;
use crate::jobs::JobStatus;
use axum::Json;
use axum::extract::State;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde::Serialize;
use utoipa::ToSchema;

#[derive(Debug, Serialize, ToSchema)]
pub struct Health {
    /// `ok`.
    pub status: String,
    pub version: String,
    pub jobs: JobCounts,
}

/// Number of jobs per status.
#[derive(Debug, Default, Serialize, ToSchema)]
pub struct JobCounts {
    pub queued: i64,
    pub running: i64,
    pub succeeded: i64,
    pub failed: i64,
    pub cancelled: i64,
}

/// Liveness and readiness: 200 when the database answers, 503 otherwise.
#[utoipa::path(
    get,
    path = "/healthz",
    tag = "service",
    responses(
        (status = 200, description = "Healthy", body = Health),
        (status = 503, description = "The database does not answer", body = ErrorBody),
    )
)]
pub async fn healthz(State(state): State<AppState>) -> Response {
    match state.queue.counts().await {
        Ok(counts) => {
            let mut jobs = JobCounts::default();
            for (status, n) in counts {
                match status {
                    JobStatus::Queued => jobs.queued = n,
                    JobStatus::Running => jobs.running = n,
                    JobStatus::Succeeded => jobs.succeeded = n,
                    JobStatus::Failed => jobs.failed = n,
                    JobStatus::Cancelled => jobs.cancelled = n,
                }
            }
            Json(Health {
                status: "ok".into(),
                version: env!("CARGO_PKG_VERSION").into(),
                jobs,
            })
            .into_response()
        }
        Err(e) => {
            tracing::error!(error = %e, "health check: database unavailable");
            let body = serde_json::json!({"error": {"code": "unavailable", "message": "the database does not answer"}});
            (StatusCode::SERVICE_UNAVAILABLE, Json(body)).into_response()
        }
    }
}
