//! The extraction pipeline: pure, synchronous, deterministic; no axum/sqlx/tokio here.
//!
//! Data flows one way:
//! `io → pavement → rasterize → threshold → cluster → classify → vectorize → geojson`.
//! The service and the CLI call [`run`] once per job, on a rayon pool, and follow it
//! through a [`Progress`] callback.

/// Chunking along the trajectory (bounded memory), with spill files.
pub mod chunk;
/// Stage 5: geometric (and learned) classification of clusters.
pub mod classify;
/// Stage 4: Euclidean clustering of marking points.
pub mod cluster;
/// Crosswalk regularisation: the stripes of one crossing share one design.
pub mod crosswalks;
pub mod dashes;
/// The driver behind [`run`]: chunk loop, streaming clusters, statistics.
pub mod driver;
/// Errors of the pipeline, split into fatal input errors and retryable ones.
pub mod error;
/// GeoJSON output (and input, for truth files and evaluation).
pub mod geojson;
/// Planar geometry helpers (grid components, robust rectangles, smoothing).
pub mod geom;
/// LAS/LAZ and trajectory readers, CRS detection.
pub mod io;
/// Lane-line growth (part of stage 6).
pub mod lanes;
/// The learned marking classifier (PointNet++ through ONNX Runtime).
pub mod learned;
/// Where the pavement was seen bare (dark points by cell), for lane-line growth.
pub mod observed;
/// Marking outlines: rectangles, buffered centrelines, alpha shapes (part of stage 6).
pub mod outline;
/// Every tunable parameter with its documented default, validated before any point is read.
pub mod params;
/// Stage 1: pavement extraction guided by the trajectory.
pub mod pavement;
/// Stage 1, alternative: the scan-line pavement method (Yao 2021).
pub mod pavement_scanline;
/// Stage 3, refinement: bright verge strips below the road's plane are not paint.
pub mod pavement_verge;
/// Stage 2: IDW intensity rasterisation with range/incidence normalisation.
pub mod rasterize;
/// The smoothed trajectory frame (mileage, offset) used by classify and vectorize.
pub mod refline;
/// Reprojection between the input CRS and WGS84.
pub mod reproject;
/// Stop-line joining: the pieces of one stop line become one bar.
pub mod stoplines;
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
///
/// Stages report progress under the stable names of [`driver::STAGES`] and the job can be
/// cancelled at every stage boundary. Memory stays bounded by a chunk of the drive
/// (`params.chunk`), see [`driver`] and [`chunk`].
pub fn run(
    inputs: &Inputs,
    params: &params::ValidParams,
    progress: &dyn Progress,
) -> Result<Extraction, PipelineError> {
    driver::run_with_stats(inputs, params, progress).map(|(ex, _)| ex)
}
