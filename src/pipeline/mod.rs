//! The extraction pipeline: pure, synchronous, deterministic; no axum/sqlx/tokio here.
//!
//! Data flows one way:
//! `io → pavement → rasterize → threshold → cluster → classify → vectorize → geojson`.
//! The service and the CLI call [`run`] once per job, on a rayon pool, and follow it
//! through a [`Progress`] callback.

/// Stage 5: geometric (and learned) classification of clusters.
pub mod classify;
/// Stage 4: Euclidean clustering of marking points.
pub mod cluster;
/// Errors of the pipeline, split into fatal input errors and retryable ones.
pub mod error;
/// GeoJSON output (and input, for truth files and evaluation).
pub mod geojson;
/// LAS/LAZ and trajectory readers, CRS detection.
pub mod io;
/// The learned marking classifier (PointNet++ through ONNX Runtime).
pub mod learned;
/// Every tunable parameter with its documented default, validated before any point is read.
pub mod params;
/// Stage 1: pavement extraction guided by the trajectory.
pub mod pavement;
/// Stage 2: IDW intensity rasterisation with range/incidence normalisation.
pub mod rasterize;
/// Reprojection between the input CRS and WGS84.
pub mod reproject;
/// Stage 3: adaptive (integral-image) thresholding and cleanup.
pub mod threshold;
/// Core types: point cloud, trajectory, markings, lane lines.
pub mod types;
/// Stage 6: outlines and lane-line self-growth.
pub mod vectorize;

pub use error::PipelineError;
pub use types::{
    Crs, Extraction, LaneLine, LaneLineClass, Marking, MarkingClass, PointCloud, Pose, Trajectory,
};

use std::path::PathBuf;

/// Progress and cancellation hooks; the pipeline calls them between (and within) stages.
pub trait Progress: Sync {
    /// `stage` is a stable stage name, `fraction` in 0..=1 of the whole job.
    fn report(&self, _stage: &str, _fraction: f64) {}
    /// Checked at stage boundaries: when true the pipeline stops with [`PipelineError::Cancelled`].
    fn is_cancelled(&self) -> bool {
        false
    }
}

/// A progress sink that ignores everything.
pub struct NoProgress;
impl Progress for NoProgress {}

/// The files of one job.
#[derive(Clone, Debug)]
pub struct Inputs {
    pub points: Vec<PathBuf>,
    pub trajectory: PathBuf,
}

/// Run the whole pipeline on the files of one job.
pub fn run(
    inputs: &Inputs,
    params: &params::ValidParams,
    progress: &dyn Progress,
) -> Result<Extraction, PipelineError> {
    let _ = (inputs, params, progress);
    Err(PipelineError::Internal(
        "the pipeline is not assembled yet".into(),
    ))
}
