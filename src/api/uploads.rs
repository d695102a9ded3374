//! `POST /v1/uploads`, `GET /v1/uploads/{id}`: files streamed to disk and validated as they land.
//!
//! The body is the file itself. It is streamed chunk by chunk to a temporary file (never held
//! whole in memory) while its SHA-256 and size are computed; the size limit is enforced on
//! the stream (and up front from `Content-Length`). The kind is recognised from the first bytes
//! ([`io::sniff`]), whatever the Content-Type; then LAS/LAZ headers are checked against the file
//! size ([`io::inspect_points`]) and trajectory tables parsed ([`io::inspect_trajectory`]) on the
//! blocking pool. Only a valid file is moved to its final, server-chosen name
//! (`uploads/<uuid>.<ext>`) and recorded; on any failure — including the client hanging up —
//! the partial file is removed. The client's `filename` is kept for display only.

use super::error::ApiError;
use super::{ApiPath, ApiQuery, AppState, ErrorBody};
use crate::jobs::clock::rfc3339;
use crate::jobs::queue::UploadRecord;
use crate::pipeline::PipelineError;
use crate::pipeline::io::{self, FileKind};
use crate::storage::Storage;
use axum::Json;
use axum::body::{Body, Bytes};
use axum::extract::State;
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use futures_util::{Stream, StreamExt};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::path::PathBuf;
use tokio::io::{AsyncWriteExt, BufWriter};
use utoipa::{IntoParams, ToSchema};

/// Bytes kept from the start of an upload for recognising its kind.
const HEAD_BYTES: usize = io::SNIFF_BYTES;

/// What the uploaded file is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum UploadKind {
    Las,
    Laz,
    Trajectory,
}

impl UploadKind {
    pub fn as_str(self) -> &'static str {
        match self {
            UploadKind::Las => "las",
            UploadKind::Laz => "laz",
            UploadKind::Trajectory => "trajectory",
        }
    }

    pub fn parse(s: &str) -> Option<UploadKind> {
        match s {
            "las" => Some(UploadKind::Las),
            "laz" => Some(UploadKind::Laz),
            "trajectory" => Some(UploadKind::Trajectory),
            _ => None,
        }
    }

    fn extension(self) -> &'static str {
        match self {
            UploadKind::Las => "las",
            UploadKind::Laz => "laz",
            UploadKind::Trajectory => "txt",
        }
    }

    pub fn is_points(self) -> bool {
        matches!(self, UploadKind::Las | UploadKind::Laz)
    }
}

/// A stored, validated upload.
#[derive(Clone, Debug, Serialize, ToSchema)]
pub struct Upload {
    /// Id to reference the file in `POST /v1/jobs`.
    pub id: String,
    pub kind: UploadKind,
    /// The client's name for the file (display only).
    pub filename: Option<String>,
    /// Size in bytes.
    pub size: u64,
    /// SHA-256 of the content, lowercase hex.
    pub sha256: String,
    /// RFC 3339 time of the upload.
    pub created_at: String,
    pub summary: UploadSummary,
}

/// What validation found in the file.
#[derive(Clone, Debug, Serialize, Deserialize, ToSchema)]
#[serde(untagged)]
pub enum UploadSummary {
    Points(PointsInfo),
    Trajectory(TrajectoryInfo),
}

/// Summary of a LAS/LAZ tile (from its header, checked against the file size).
#[derive(Clone, Debug, Serialize, Deserialize, ToSchema)]
pub struct PointsInfo {
    pub point_count: u64,
    /// `[[min_x, min_y, min_z], [max_x, max_y, max_z]]` in the file's CRS.
    #[schema(value_type = Vec<Vec<f64>>)]
    pub bounds: [[f64; 3]; 2],
    /// The CRS found in the file, if any.
    pub crs: Option<CrsInfo>,
    /// LAS version, e.g. `1.4`.
    pub version: String,
    pub point_format: u8,
    pub compressed: bool,
    pub has_gps_time: bool,
}

#[derive(Clone, Debug, Serialize, Deserialize, ToSchema)]
pub struct CrsInfo {
    pub epsg: Option<u32>,
    pub wkt: Option<String>,
}

/// Summary of a trajectory table.
#[derive(Clone, Debug, Serialize, Deserialize, ToSchema)]
pub struct TrajectoryInfo {
    /// Data rows in the table.
    pub rows: u64,
    /// Poses kept after sorting and merging repeated positions.
    pub poses: u64,
    /// Column names as found (lower case).
    pub columns: Vec<String>,
    /// `comma`, `semicolon`, `tab` or `whitespace`.
    pub delimiter: String,
    /// First and last time stamp.
    pub time_range: [f64; 2],
    /// Length of the track, metres.
    pub length_m: f64,
    pub has_z: bool,
    pub has_heading: bool,
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct UploadQuery {
    /// Name of the file on the client (display only; never used as a path).
    pub filename: Option<String>,
}

/// Upload a LAS/LAZ tile or a trajectory table (the body is the file).
#[utoipa::path(
    post,
    path = "/v1/uploads",
    tag = "uploads",
    params(UploadQuery),
    request_body(
        content = Vec<u8>,
        description = "The file itself: LAS, LAZ or a trajectory table. The kind is recognised from the content.",
        content_type = "application/octet-stream"
    ),
    responses(
        (status = 201, description = "Stored and validated", body = Upload,
         headers(("Location" = String, description = "URL of the upload"))),
        (status = 400, description = "Empty or unreadable body", body = ErrorBody),
        (status = 413, description = "Larger than the configured limit", body = ErrorBody),
        (status = 415, description = "Neither LAS/LAZ nor a trajectory table", body = ErrorBody),
        (status = 422, description = "Recognised but broken (truncated LAS, malformed trajectory)", body = ErrorBody),
    )
)]
pub async fn create_upload(
    State(state): State<AppState>,
    ApiQuery(query): ApiQuery<UploadQuery>,
    headers: HeaderMap,
    body: Body,
) -> Result<(StatusCode, HeaderMap, Json<Upload>), ApiError> {
    // A form upload (`curl -F`) would store the multipart envelope, not the file.
    let content_type = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("");
    if content_type.to_ascii_lowercase().starts_with("multipart/") {
        return Err(ApiError::UnsupportedMediaType(format!(
            "{content_type}: send the file itself as the body (curl --data-binary @FILE), \
             or send multipart forms to POST /v1/jobs"
        )));
    }
    let limit = state.settings.max_upload_bytes;
    // Refuse at once what announces itself as too large (the stream check covers the rest).
    let announced = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    if announced.is_some_and(|n| n > limit) {
        return Err(ApiError::PayloadTooLarge { limit });
    }
    let upload = ingest(&state, body.into_data_stream(), query.filename).await?;
    let mut out = HeaderMap::new();
    if let Ok(v) = HeaderValue::from_str(&format!("/v1/uploads/{}", upload.id)) {
        out.insert(header::LOCATION, v);
    }
    Ok((StatusCode::CREATED, out, Json(upload)))
}

/// Metadata and summary of an upload.
#[utoipa::path(
    get,
    path = "/v1/uploads/{id}",
    tag = "uploads",
    params(("id" = String, Path, description = "Upload id")),
    responses(
        (status = 200, description = "The upload", body = Upload),
        (status = 404, description = "No such upload", body = ErrorBody),
    )
)]
pub async fn get_upload(
    State(state): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Json<Upload>, ApiError> {
    let record = state
        .queue
        .get_upload(&id)
        .await?
        .ok_or(ApiError::NotFound { what: "upload", id })?;
    Ok(Json(upload_view(&record)?))
}

pub(crate) fn upload_view(r: &UploadRecord) -> Result<Upload, ApiError> {
    let kind =
        UploadKind::parse(&r.kind).ok_or_else(|| ApiError::Internal(format!("stored kind {}", r.kind)))?;
    let summary: UploadSummary =
        serde_json::from_str(&r.summary).map_err(|e| ApiError::Internal(format!("stored summary: {e}")))?;
    Ok(Upload {
        id: r.id.clone(),
        kind,
        filename: r.filename.clone(),
        size: u64::try_from(r.size).unwrap_or(0),
        sha256: r.sha256.clone(),
        created_at: rfc3339(r.created_at),
        summary,
    })
}

/// Removes a temporary file when dropped, unless it was committed: cleans up after errors and
/// after a client that hangs up mid-upload (the handler future is dropped then).
struct TempFile {
    path: PathBuf,
    armed: bool,
}

impl Drop for TempFile {
    fn drop(&mut self) {
        if self.armed {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

/// Keep only a plain, printable file name: the last path component, at most 255 characters.
fn clean_filename(name: Option<String>) -> Option<String> {
    let name = name?;
    let last = name.rsplit(['/', '\\']).next().unwrap_or("");
    let cleaned: String = last.chars().filter(|c| !c.is_control()).take(255).collect();
    let cleaned = cleaned.trim().to_string();
    (!cleaned.is_empty()).then_some(cleaned)
}

/// Stream `body` to storage, validate it and record it. Used by `POST /v1/uploads` and by the
/// file parts of a multipart `POST /v1/jobs`.
pub(crate) async fn ingest<S, E>(
    state: &AppState,
    body: S,
    filename: Option<String>,
) -> Result<Upload, ApiError>
where
    S: Stream<Item = Result<Bytes, E>>,
    E: std::fmt::Display,
{
    let limit = state.settings.max_upload_bytes;
    let filename = clean_filename(filename);
    let label = filename.clone().unwrap_or_else(|| "upload".to_string());
    let mut temp = TempFile {
        path: state.storage.temp_upload_path(),
        armed: true,
    };

    let mut body = std::pin::pin!(body);
    let file = tokio::fs::File::create(&temp.path).await?;
    let mut out = BufWriter::with_capacity(1 << 20, file);
    let mut hasher = Sha256::new();
    let mut head: Vec<u8> = Vec::with_capacity(HEAD_BYTES);
    let mut size: u64 = 0;
    while let Some(chunk) = body.next().await {
        let chunk =
            chunk.map_err(|e| ApiError::BadRequest(format!("{label}: reading the upload failed: {e}")))?;
        size += chunk.len() as u64;
        if size > limit {
            return Err(ApiError::PayloadTooLarge { limit });
        }
        hasher.update(&chunk);
        if head.len() < HEAD_BYTES {
            let take = (HEAD_BYTES - head.len()).min(chunk.len());
            head.extend_from_slice(&chunk[..take]);
        }
        out.write_all(&chunk).await?;
    }
    out.flush().await?;
    out.get_ref().sync_all().await?;
    drop(out);
    if size == 0 {
        return Err(ApiError::EmptyBody);
    }

    let kind = match io::sniff(&head) {
        FileKind::Las => UploadKind::Las,
        FileKind::Laz => UploadKind::Laz,
        FileKind::Trajectory => UploadKind::Trajectory,
        FileKind::Unknown => {
            return Err(ApiError::UnsupportedFile(format!(
                "{label}: not a LAS/LAZ file nor a trajectory table (first bytes: {})",
                describe_head(&head)
            )));
        }
    };
    let summary = validate(kind, temp.path.clone(), &label).await?;

    let id = uuid::Uuid::new_v4().to_string();
    let rel = Storage::upload_rel(&id, kind.extension());
    let storage = state.storage.clone();
    let (from, rel_c) = (temp.path.clone(), rel.clone());
    tokio::task::spawn_blocking(move || storage.commit_upload(&from, &rel_c))
        .await
        .map_err(|e| ApiError::Internal(e.to_string()))??;
    temp.armed = false;

    let record = UploadRecord {
        id,
        kind: kind.as_str().to_string(),
        filename,
        size: i64::try_from(size).unwrap_or(i64::MAX),
        sha256: hex::encode(hasher.finalize()),
        path: rel.clone(),
        summary: serde_json::to_string(&summary).map_err(|e| ApiError::Internal(e.to_string()))?,
        created_at: state.queue.now_ms(),
    };
    if let Err(e) = state.queue.insert_upload(&record).await {
        let _ = state.storage.remove(&rel);
        return Err(e.into());
    }
    tracing::info!(upload_id = %record.id, kind = kind.as_str(), size, "upload stored");
    upload_view(&record)
}

/// Parse/check the file on the blocking pool; broken files become 422 naming the problem.
async fn validate(kind: UploadKind, path: PathBuf, label: &str) -> Result<UploadSummary, ApiError> {
    let result = tokio::task::spawn_blocking(move || -> Result<UploadSummary, PipelineError> {
        if kind.is_points() {
            let s = io::inspect_points(&path)?;
            Ok(UploadSummary::Points(PointsInfo {
                point_count: s.point_count,
                bounds: s.bounds,
                crs: s.crs.map(|c| CrsInfo {
                    epsg: c.epsg,
                    wkt: c.wkt,
                }),
                version: s.version,
                point_format: s.point_format,
                compressed: s.compressed,
                has_gps_time: s.has_gps_time,
            }))
        } else {
            let t = io::inspect_trajectory(&path)?;
            let delimiter = serde_json::to_value(t.delimiter)
                .ok()
                .and_then(|v| v.as_str().map(str::to_string))
                .unwrap_or_default();
            Ok(UploadSummary::Trajectory(TrajectoryInfo {
                rows: t.row_count as u64,
                poses: t.pose_count as u64,
                columns: t.columns,
                delimiter,
                time_range: t.time_range,
                length_m: t.length_m,
                has_z: t.has_z,
                has_heading: t.has_heading,
            }))
        }
    })
    .await
    .map_err(|e| ApiError::Internal(format!("validation task: {e}")))?;
    result.map_err(|e| match e {
        PipelineError::Input { message, .. } => ApiError::InvalidFile(format!("{label}: {message}")),
        // A short read while parsing is the file's fault (truncated), not the server's.
        PipelineError::Io { source, .. }
            if matches!(
                source.kind(),
                std::io::ErrorKind::UnexpectedEof | std::io::ErrorKind::InvalidData
            ) =>
        {
            ApiError::InvalidFile(format!("{label}: {source}"))
        }
        PipelineError::Io { source, .. } => ApiError::Io(source),
        other => ApiError::InvalidFile(format!("{label}: {other}")),
    })
}

/// The first bytes of a rejected file, printable, for the error message.
fn describe_head(head: &[u8]) -> String {
    let n = head.len().min(8);
    let hex: Vec<String> = head[..n].iter().map(|b| format!("{b:02x}")).collect();
    hex.join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn filenames_are_display_only() {
        assert_eq!(
            clean_filename(Some("../../etc/passwd".into())).as_deref(),
            Some("passwd")
        );
        assert_eq!(
            clean_filename(Some("C:\\x\\tile.las".into())).as_deref(),
            Some("tile.las")
        );
        assert_eq!(clean_filename(Some("a\nb.las".into())).as_deref(), Some("ab.las"));
        assert_eq!(clean_filename(Some("dir/".into())), None);
        assert_eq!(clean_filename(None), None);
    }

    #[test]
    fn summaries_round_trip_through_the_database_json() {
        let t = UploadSummary::Trajectory(TrajectoryInfo {
            rows: 3,
            poses: 3,
            columns: vec!["time".into(), "x".into(), "y".into()],
            delimiter: "comma".into(),
            time_range: [1.0, 2.0],
            length_m: 10.0,
            has_z: false,
            has_heading: false,
        });
        let back: UploadSummary = serde_json::from_str(&serde_json::to_string(&t).unwrap()).unwrap();
        assert!(matches!(
            back,
            UploadSummary::Trajectory(TrajectoryInfo { rows: 3, .. })
        ));
    }
}
