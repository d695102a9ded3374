//! The HTTP API (axum), versioned under `/v1`, and the [`Application`] that serves it next to
//! its workers.
//!
//! - [`app`] builds the [`Router`] from an [`AppState`] without binding anything (tests and
//!   tools can drive it directly); [`openapi`] is the OpenAPI document generated from the same
//!   handler annotations (utoipa), served at `/openapi.json` and pinned in `openapi/openapi.json`
//!   by a snapshot test.
//! - [`uploads`]: streamed, validated uploads. [`jobs`]: create/read/list/cancel/result.
//! - [`error::ApiError`]: the single error type; every failure is
//!   `{"error": {"code", "message"}}` with a stable kebab-case code — including unknown routes,
//!   wrong methods and malformed query strings.
//!
//! Handlers are thin: parse at the edge into checked types, call the queue, render a view.

/// The single API error type and its JSON shape.
pub mod error;
/// `GET /healthz`.
pub mod health;
/// `/v1/jobs`: create (JSON or multipart), get, list, cancel, result.
pub mod jobs;
/// Start-up and graceful shutdown of HTTP server and workers.
pub mod server;
/// `/v1/uploads`: streamed, validated uploads.
pub mod uploads;

pub use error::{ApiError, ErrorBody};
pub use server::Application;

use crate::jobs::Queue;
use crate::storage::Storage;
use axum::Router;
use axum::extract::DefaultBodyLimit;
use axum::http::Uri;
use std::sync::Arc;
use tokio::sync::Notify;
use tower_http::trace::TraceLayer;
use utoipa::OpenApi;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

/// `Path` with the API's JSON error on rejection (axum's own answers in plain text).
#[derive(axum::extract::FromRequestParts)]
#[from_request(via(axum::extract::Path), rejection(ApiError))]
pub struct ApiPath<T>(pub T);

/// `Query` with the API's JSON error on rejection.
#[derive(axum::extract::FromRequestParts)]
#[from_request(via(axum::extract::Query), rejection(ApiError))]
pub struct ApiQuery<T>(pub T);

/// Limits and defaults the handlers apply.
#[derive(Clone, Debug)]
pub struct ApiSettings {
    pub max_upload_bytes: u64,
    pub max_attempts: u32,
}

/// Shared state of the handlers (cheap to clone).
#[derive(Clone)]
pub struct AppState {
    pub queue: Queue,
    pub storage: Storage,
    pub settings: ApiSettings,
    /// Wakes an idle worker when a job is enqueued.
    pub wake: Arc<Notify>,
}

#[derive(OpenApi)]
#[openapi(
    info(
        title = "roadmark",
        description = "Road markings from mobile laser scanning drives: upload LAS/LAZ tiles and a \
                       trajectory, run a job, fetch the marking GeoJSON.",
        license(name = "MIT OR Apache-2.0")
    ),
    tags(
        (name = "uploads", description = "Point cloud tiles and trajectory tables"),
        (name = "jobs", description = "Extraction jobs and their results"),
        (name = "service", description = "Health and API description"),
    )
)]
struct ApiDoc;

fn routers() -> OpenApiRouter<AppState> {
    OpenApiRouter::with_openapi(ApiDoc::openapi())
        .routes(routes!(uploads::create_upload))
        .routes(routes!(uploads::get_upload))
        .routes(routes!(jobs::create_job, jobs::list_jobs))
        .routes(routes!(jobs::get_job, jobs::cancel_job))
        .routes(routes!(jobs::get_result))
        .routes(routes!(health::healthz))
}

/// The OpenAPI document of this API (the same one `/openapi.json` serves).
pub fn openapi() -> utoipa::openapi::OpenApi {
    let mut doc = routers().into_openapi();
    // The document is the contract; the version field follows the crate.
    doc.info.version = env!("CARGO_PKG_VERSION").to_string();
    doc
}

/// The OpenAPI document as pretty JSON with a trailing newline (the form committed in
/// `openapi/openapi.json`).
pub fn openapi_json() -> String {
    let mut text = openapi()
        .to_pretty_json()
        .unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"));
    text.push('\n');
    text
}

/// The complete router: API routes, `/openapi.json`, JSON fallbacks, request tracing.
pub fn app(state: AppState) -> Router {
    let (router, _) = routers().split_for_parts();
    let document = openapi_json();
    router
        .route(
            "/openapi.json",
            axum::routing::get(move || {
                let document = document.clone();
                async move { ([(axum::http::header::CONTENT_TYPE, "application/json")], document) }
            }),
        )
        .fallback(|uri: Uri| async move { ApiError::NoRoute(uri.path().to_string()) })
        .method_not_allowed_fallback(|| async { ApiError::MethodNotAllowed })
        // Upload and job handlers stream their bodies and enforce their own limits
        // (--max-upload-bytes per file, 1 MiB for JSON); axum's blanket 2 MB cap would cut
        // multipart jobs short.
        .layer(DefaultBodyLimit::disable())
        .layer(TraceLayer::new_for_http())
        .with_state(state)
}
