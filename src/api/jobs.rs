//! `/v1/jobs`: create (JSON by upload ids, or multipart with the files inline), read, list,
//! cancel, and fetch the result.
//!
//! A job is checked completely before it is enqueued: every upload exists and has the right
//! kind, and the parameters parse (unknown fields rejected) and validate. The *resolved*
//! parameters — every default filled in — are stored with the job and shown by `GET`, so a
//! job's result can always be traced to the exact settings that produced it.
//!
//! Listing is keyset-paginated, newest first: `limit` (1–100, default 20) and the opaque
//! `cursor` returned as `next_cursor` by the previous page.

use super::error::{ApiError, ErrorDetail};
use super::uploads::{UploadKind, ingest};
use super::{ApiPath, ApiQuery, AppState, ErrorBody};
use crate::jobs::clock::rfc3339;
use crate::jobs::queue::{CancelOutcome, JobRecord, JobStatus, NewJob};
use crate::pipeline::Extraction;
use crate::pipeline::geojson::{self, CrsMode, GeoJsonError};
use crate::pipeline::params::Params;
use axum::Json;
use axum::extract::{FromRequest, Multipart, Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};

/// Largest JSON job request, bytes (the files travel separately).
const MAX_JSON_BYTES: usize = 1 << 20;
/// Largest `params` part of a multipart job request, bytes.
const MAX_PARAMS_BYTES: usize = 1 << 20;
/// Most tiles in one job.
const MAX_TILES: usize = 1000;

/// A job by upload ids.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct CreateJob {
    /// Upload ids of the LAS/LAZ tiles of one drive.
    pub points: Vec<String>,
    /// Upload id of the trajectory table.
    pub trajectory: String,
    /// Pipeline parameters: one object per stage, every field optional (defaults apply);
    /// unknown fields are rejected.
    #[schema(value_type = Option<Object>)]
    #[serde(default)]
    pub params: Option<serde_json::Value>,
}

/// Multipart form of a job: the files inline.
/// (Documentation of the multipart body; the handler reads the parts as a stream.)
#[derive(ToSchema)]
pub struct CreateJobMultipart {
    /// A LAS/LAZ tile (repeat the part for several tiles).
    #[schema(value_type = Vec<String>, format = Binary)]
    pub points: Vec<Vec<u8>>,
    /// The trajectory table.
    #[schema(value_type = String, format = Binary)]
    pub trajectory: Vec<u8>,
    /// Parameters as JSON text (optional).
    pub params: Option<String>,
}

/// A job as the API shows it.
#[derive(Debug, Serialize, ToSchema)]
pub struct Job {
    pub id: String,
    pub status: JobStatus,
    pub progress: JobProgress,
    /// Attempts started so far (counted when a worker claims the job).
    pub attempts: i64,
    pub max_attempts: i64,
    /// `DELETE` was called while the job ran; it stops at its next stage boundary.
    pub cancel_requested: bool,
    pub created_at: String,
    pub updated_at: String,
    pub started_at: Option<String>,
    pub finished_at: Option<String>,
    /// Why the job failed (or, while queued for a retry, why the last attempt failed).
    pub error: Option<ErrorDetail>,
    pub inputs: JobInputs,
    /// The resolved parameters (every default filled in).
    #[schema(value_type = Object)]
    pub params: serde_json::Value,
    pub links: JobLinks,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct JobProgress {
    /// `queued`, `starting`, a pipeline stage name, `retry-wait`, `done` or `cancelled`.
    pub stage: String,
    /// Fraction of the whole job done, 0..1.
    pub fraction: f64,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct JobInputs {
    pub points: Vec<String>,
    pub trajectory: Option<String>,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct JobLinks {
    #[serde(rename = "self")]
    pub self_: String,
    /// Present once the job succeeded.
    pub result: Option<String>,
}

/// One page of jobs, newest first.
#[derive(Debug, Serialize, ToSchema)]
pub struct JobPage {
    pub jobs: Vec<Job>,
    /// Pass as `cursor` to get the next (older) page; absent on the last page.
    pub next_cursor: Option<String>,
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ListQuery {
    /// Page size, 1–100 (default 20).
    pub limit: Option<u32>,
    /// `next_cursor` of the previous page.
    pub cursor: Option<String>,
    /// Only jobs with this status.
    pub status: Option<JobStatus>,
}

/// Coordinates of the result.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum CrsParam {
    /// The input CRS (with a `crs` member when its EPSG code is known).
    Native,
    /// Longitude/latitude (RFC 7946).
    Wgs84,
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ResultQuery {
    /// Output coordinates; default `wgs84` when the input CRS is known, else `native`.
    pub crs: Option<CrsParam>,
}

/// Create a job from uploaded files (JSON) or with the files inline (multipart).
#[utoipa::path(
    post,
    path = "/v1/jobs",
    tag = "jobs",
    request_body(content(
        (CreateJob = "application/json"),
        (CreateJobMultipart = "multipart/form-data"),
    )),
    responses(
        (status = 201, description = "Queued", body = Job,
         headers(("Location" = String, description = "URL of the job"))),
        (status = 400, description = "Malformed request", body = ErrorBody),
        (status = 413, description = "An inline file exceeds the upload limit", body = ErrorBody),
        (status = 415, description = "Unsupported content type or file kind", body = ErrorBody),
        (status = 422, description = "Unknown upload, wrong file kind, broken file or invalid parameters", body = ErrorBody),
    )
)]
pub async fn create_job(State(state): State<AppState>, request: Request) -> Result<Response, ApiError> {
    let content_type = request
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("application/json")
        .to_ascii_lowercase();
    let job = if content_type.starts_with("multipart/form-data") {
        create_multipart(&state, request).await?
    } else if content_type.starts_with("application/json") {
        let bytes = axum::body::to_bytes(request.into_body(), MAX_JSON_BYTES)
            .await
            .map_err(|e| ApiError::BadRequest(format!("reading the body failed: {e}")))?;
        let body: CreateJob = serde_json::from_slice(&bytes).map_err(|e| match e.classify() {
            serde_json::error::Category::Data => ApiError::Unprocessable(format!("invalid job request: {e}")),
            _ => ApiError::BadRequest(format!("invalid JSON: {e}")),
        })?;
        let params = resolve_params(body.params)?;
        check_inputs(&state, &body.points, &body.trajectory).await?;
        enqueue(&state, body.points, body.trajectory, params).await?
    } else {
        return Err(ApiError::UnsupportedMediaType(format!(
            "{content_type}: send application/json or multipart/form-data"
        )));
    };
    let mut headers = HeaderMap::new();
    if let Ok(v) = HeaderValue::from_str(&job.links.self_) {
        headers.insert(header::LOCATION, v);
    }
    Ok((StatusCode::CREATED, headers, Json(job)).into_response())
}

/// Parse and validate parameters; the stored form is the resolved set.
fn resolve_params(value: Option<serde_json::Value>) -> Result<String, ApiError> {
    let params: Params = match value {
        None | Some(serde_json::Value::Null) => Params::default(),
        Some(v) => serde_json::from_value(v).map_err(|e| ApiError::InvalidParams(e.to_string()))?,
    };
    let valid = params.validate().map_err(ApiError::InvalidParams)?;
    serde_json::to_string(&valid).map_err(|e| ApiError::Internal(e.to_string()))
}

async fn check_inputs(state: &AppState, points: &[String], trajectory: &str) -> Result<(), ApiError> {
    if points.is_empty() {
        return Err(ApiError::Unprocessable(
            "`points` needs at least one LAS/LAZ upload".into(),
        ));
    }
    if points.len() > MAX_TILES {
        return Err(ApiError::Unprocessable(format!(
            "{} tiles in one job; at most {MAX_TILES}",
            points.len()
        )));
    }
    for (i, id) in points.iter().enumerate() {
        if points[..i].contains(id) {
            return Err(ApiError::Unprocessable(format!(
                "upload {id} is listed twice in `points`"
            )));
        }
        let upload = state
            .queue
            .get_upload(id)
            .await?
            .ok_or_else(|| ApiError::UnknownUpload(id.clone()))?;
        if !UploadKind::parse(&upload.kind).is_some_and(UploadKind::is_points) {
            return Err(ApiError::WrongUploadKind(format!(
                "upload {id} in `points` is a {}, not a LAS/LAZ file",
                upload.kind
            )));
        }
    }
    let upload = state
        .queue
        .get_upload(trajectory)
        .await?
        .ok_or_else(|| ApiError::UnknownUpload(trajectory.to_string()))?;
    if upload.kind != UploadKind::Trajectory.as_str() {
        return Err(ApiError::WrongUploadKind(format!(
            "upload {trajectory} given as `trajectory` is a {} file, not a trajectory table",
            upload.kind
        )));
    }
    Ok(())
}

async fn enqueue(
    state: &AppState,
    points: Vec<String>,
    trajectory: String,
    params: String,
) -> Result<Job, ApiError> {
    let record = state
        .queue
        .enqueue(&NewJob {
            points,
            trajectory,
            params,
            max_attempts: state.settings.max_attempts,
        })
        .await?;
    state.wake.notify_one();
    tracing::info!(job_id = %record.id, "job queued");
    job_view(state, record).await
}

/// Multipart: `points` parts (repeatable) and one `trajectory` part, each streamed through the
/// same ingestion as `POST /v1/uploads`, plus an optional `params` part (JSON text). If the
/// request fails, the uploads it created are removed again.
async fn create_multipart(state: &AppState, request: Request) -> Result<Job, ApiError> {
    let mut multipart = Multipart::from_request(request, state).await?;
    let mut created: Vec<String> = Vec::new();
    let result = async {
        let mut points = Vec::new();
        let mut trajectory: Option<String> = None;
        let mut params: Option<String> = None;
        while let Some(mut field) = multipart.next_field().await? {
            let name = field.name().unwrap_or_default().to_string();
            match name.as_str() {
                "points" | "trajectory" => {
                    if name == "trajectory" && trajectory.is_some() {
                        return Err(ApiError::BadRequest("more than one `trajectory` part".into()));
                    }
                    if name == "points" && points.len() >= MAX_TILES {
                        return Err(ApiError::Unprocessable(format!(
                            "at most {MAX_TILES} `points` parts"
                        )));
                    }
                    let filename = field.file_name().map(str::to_string);
                    let upload = ingest(state, field, filename).await?;
                    created.push(upload.id.clone());
                    let label = upload.filename.clone().unwrap_or_else(|| upload.id.clone());
                    if name == "points" {
                        if !upload.kind.is_points() {
                            return Err(ApiError::WrongUploadKind(format!(
                                "part `points` ({label}) is a {} file, not LAS/LAZ",
                                upload.kind.as_str()
                            )));
                        }
                        points.push(upload.id);
                    } else {
                        if upload.kind != UploadKind::Trajectory {
                            return Err(ApiError::WrongUploadKind(format!(
                                "part `trajectory` ({label}) is a {} file, not a trajectory table",
                                upload.kind.as_str()
                            )));
                        }
                        trajectory = Some(upload.id);
                    }
                }
                "params" => {
                    let mut text = Vec::new();
                    while let Some(chunk) = field.chunk().await? {
                        text.extend_from_slice(&chunk);
                        if text.len() > MAX_PARAMS_BYTES {
                            return Err(ApiError::BadRequest("the `params` part exceeds 1 MiB".into()));
                        }
                    }
                    let value: serde_json::Value = serde_json::from_slice(&text)
                        .map_err(|e| ApiError::InvalidParams(format!("`params` part is not JSON: {e}")))?;
                    // Validate as soon as it arrives: bad parameters fail before big files stream in.
                    params = Some(resolve_params(Some(value))?);
                }
                other => {
                    return Err(ApiError::BadRequest(format!(
                        "unexpected part `{other}` (expected `points`, `trajectory`, `params`)"
                    )));
                }
            }
        }
        let trajectory =
            trajectory.ok_or_else(|| ApiError::Unprocessable("missing the `trajectory` part".into()))?;
        if points.is_empty() {
            return Err(ApiError::Unprocessable("missing a `points` part".into()));
        }
        let params = match params {
            Some(p) => p,
            None => resolve_params(None)?,
        };
        enqueue(state, points, trajectory, params).await
    }
    .await;
    if result.is_err() {
        for id in &created {
            if let Ok(Some(u)) = state.queue.get_upload(id).await
                && state.queue.delete_unused_upload(id).await.unwrap_or(false)
            {
                let _ = state.storage.remove(&u.path);
            }
        }
    }
    result
}

/// Status, progress, timestamps, error and links of a job.
#[utoipa::path(
    get,
    path = "/v1/jobs/{id}",
    tag = "jobs",
    params(("id" = String, Path, description = "Job id")),
    responses(
        (status = 200, description = "The job", body = Job),
        (status = 404, description = "No such job", body = ErrorBody),
    )
)]
pub async fn get_job(
    State(state): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Json<Job>, ApiError> {
    let record = state
        .queue
        .get(&id)
        .await?
        .ok_or(ApiError::NotFound { what: "job", id })?;
    Ok(Json(job_view(&state, record).await?))
}

/// Jobs, newest first, keyset-paginated.
#[utoipa::path(
    get,
    path = "/v1/jobs",
    tag = "jobs",
    params(ListQuery),
    responses(
        (status = 200, description = "One page of jobs", body = JobPage),
        (status = 400, description = "Bad limit, cursor or status", body = ErrorBody),
    )
)]
pub async fn list_jobs(
    State(state): State<AppState>,
    ApiQuery(q): ApiQuery<ListQuery>,
) -> Result<Json<JobPage>, ApiError> {
    let limit = q.limit.unwrap_or(20);
    if !(1..=100).contains(&limit) {
        return Err(ApiError::BadRequest(format!(
            "limit must be 1..=100, got {limit}"
        )));
    }
    let before = match q.cursor.as_deref() {
        None | Some("") => None,
        Some(c) => Some(
            c.parse::<i64>()
                .map_err(|_| ApiError::BadRequest(format!("invalid cursor {c:?}")))?,
        ),
    };
    let records = state.queue.list(q.status, before, limit).await?;
    let next_cursor = (records.len() == limit as usize)
        .then(|| records.last().map(|r| r.seq.to_string()))
        .flatten();
    let mut jobs = Vec::with_capacity(records.len());
    for r in records {
        jobs.push(job_view(&state, r).await?);
    }
    Ok(Json(JobPage { jobs, next_cursor }))
}

/// Cancel a job: a queued job at once (200), a running one at its next stage boundary (202).
#[utoipa::path(
    delete,
    path = "/v1/jobs/{id}",
    tag = "jobs",
    params(("id" = String, Path, description = "Job id")),
    responses(
        (status = 200, description = "Cancelled (or already cancelled)", body = Job),
        (status = 202, description = "Running: asked to stop at the next stage boundary", body = Job),
        (status = 404, description = "No such job", body = ErrorBody),
        (status = 409, description = "Already succeeded or failed", body = ErrorBody),
    )
)]
pub async fn cancel_job(
    State(state): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Response, ApiError> {
    let (status, record) = match state.queue.cancel(&id).await? {
        CancelOutcome::Cancelled(r) => (StatusCode::OK, r),
        CancelOutcome::Requested(r) => (StatusCode::ACCEPTED, r),
        CancelOutcome::AlreadyFinished(r) if r.status == JobStatus::Cancelled => (StatusCode::OK, r),
        CancelOutcome::AlreadyFinished(r) => {
            return Err(ApiError::AlreadyFinished {
                id,
                status: r.status.as_str().into(),
            });
        }
        CancelOutcome::NotFound => return Err(ApiError::NotFound { what: "job", id }),
    };
    tracing::info!(job_id = %record.id, status = record.status.as_str(), "cancel requested");
    Ok((status, Json(job_view(&state, record).await?)).into_response())
}

/// The marking GeoJSON of a finished job.
#[utoipa::path(
    get,
    path = "/v1/jobs/{id}/result",
    tag = "jobs",
    params(("id" = String, Path, description = "Job id"), ResultQuery),
    responses(
        (status = 200, description = "FeatureCollection with layers `marking` and `lane_line`",
         content_type = "application/geo+json", body = Object),
        (status = 404, description = "No such job", body = ErrorBody),
        (status = 409, description = "The job has not succeeded (yet)", body = ErrorBody),
        (status = 422, description = "`crs=wgs84` but the input CRS is unknown", body = ErrorBody),
    )
)]
pub async fn get_result(
    State(state): State<AppState>,
    ApiPath(id): ApiPath<String>,
    ApiQuery(q): ApiQuery<ResultQuery>,
) -> Result<Response, ApiError> {
    let record = state.queue.get(&id).await?.ok_or_else(|| ApiError::NotFound {
        what: "job",
        id: id.clone(),
    })?;
    let hint = match record.status {
        JobStatus::Succeeded => "",
        JobStatus::Queued | JobStatus::Running => "poll the job until it has succeeded",
        JobStatus::Failed => "it has no result; the job's `error` says why",
        JobStatus::Cancelled => "it was cancelled and has no result",
    };
    let Some(rel) = record
        .result_path
        .filter(|_| record.status == JobStatus::Succeeded)
    else {
        return Err(ApiError::NotFinished {
            id,
            status: record.status.as_str().into(),
            hint,
        });
    };
    let bytes = tokio::fs::read(state.storage.resolve(&rel)).await?;
    let body = tokio::task::spawn_blocking(move || -> Result<Vec<u8>, ApiError> {
        let extraction: Extraction =
            serde_json::from_slice(&bytes).map_err(|e| ApiError::Internal(format!("stored result: {e}")))?;
        let known = extraction
            .crs
            .as_ref()
            .is_some_and(|c| c.epsg.is_some() || c.wkt.is_some());
        let mode = match q.crs {
            Some(CrsParam::Native) => CrsMode::Native,
            Some(CrsParam::Wgs84) if !known => {
                return Err(ApiError::CrsUnavailable(
                    "the input CRS is unknown, so the result cannot be given in WGS84; use crs=native".into(),
                ));
            }
            Some(CrsParam::Wgs84) => CrsMode::Wgs84,
            None if known => CrsMode::Wgs84,
            None => CrsMode::Native,
        };
        let fc = render(&extraction, mode)?;
        serde_json::to_vec(&fc).map_err(|e| ApiError::Internal(e.to_string()))
    })
    .await
    .map_err(|e| ApiError::Internal(e.to_string()))??;
    Ok(([(header::CONTENT_TYPE, "application/geo+json")], body).into_response())
}

/// GeoJSON in the requested coordinates.
fn render(extraction: &Extraction, mode: CrsMode) -> Result<serde_json::Value, ApiError> {
    geojson::to_geojson(extraction, mode).map_err(|e| match e {
        GeoJsonError::Reproject(m) => ApiError::CrsUnavailable(format!(
            "the result cannot be reprojected to WGS84 ({m}); use crs=native"
        )),
        other => ApiError::Internal(format!("rendering the result: {other}")),
    })
}

pub(crate) async fn job_view(state: &AppState, r: JobRecord) -> Result<Job, ApiError> {
    let inputs = state.queue.inputs(&r.id).await?;
    let mut points = Vec::new();
    let mut trajectory = None;
    for i in inputs {
        if i.role == "trajectory" {
            trajectory = Some(i.upload_id);
        } else {
            points.push(i.upload_id);
        }
    }
    let params = serde_json::from_str(&r.params).unwrap_or(serde_json::Value::Null);
    let self_ = format!("/v1/jobs/{}", r.id);
    let result = (r.status == JobStatus::Succeeded).then(|| format!("{self_}/result"));
    let error = match (r.error_code, r.error_message) {
        (Some(code), Some(message)) => Some(ErrorDetail { code, message }),
        (None, Some(message)) => Some(ErrorDetail {
            code: "error".into(),
            message,
        }),
        _ => None,
    };
    Ok(Job {
        id: r.id,
        status: r.status,
        progress: JobProgress {
            stage: r.progress_stage.unwrap_or_else(|| r.status.as_str().to_string()),
            fraction: r.progress_fraction.unwrap_or(0.0),
        },
        attempts: r.attempts,
        max_attempts: r.max_attempts,
        cancel_requested: r.cancel_requested,
        created_at: rfc3339(r.created_at),
        updated_at: rfc3339(r.updated_at),
        started_at: r.started_at.map(rfc3339),
        finished_at: r.finished_at.map(rfc3339),
        error,
        inputs: JobInputs { points, trajectory },
        params,
        links: JobLinks { self_, result },
    })
}
