//! LAS/LAZ and trajectory readers (to be written). The signatures below are the agreed API.

use super::error::PipelineError;
use super::types::{Crs, PointCloud, Trajectory};
use serde::Serialize;
use std::path::Path;

/// What an uploaded file is, recognised from its first bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FileKind {
    Las,
    Laz,
    Trajectory,
    Unknown,
}

/// Recognise a file from its first bytes (at least 512 bytes when available).
pub fn sniff(_head: &[u8]) -> FileKind {
    FileKind::Unknown
}

/// Header-level summary of a LAS/LAZ file, after validating it.
#[derive(Clone, Debug, Serialize)]
pub struct PointsSummary {
    pub point_count: u64,
    /// [[min_x, min_y, min_z], [max_x, max_y, max_z]] in the file's CRS.
    pub bounds: [[f64; 3]; 2],
    pub crs: Option<Crs>,
    pub version: String,
    pub point_format: u8,
    pub compressed: bool,
    pub has_gps_time: bool,
}

/// Validate a LAS/LAZ file (header, point count vs file size) and summarise it.
pub fn inspect_points(path: &Path) -> Result<PointsSummary, PipelineError> {
    Err(PipelineError::input(path, "reader not written yet"))
}

/// Read several tiles of one drive into one cloud (local origin chosen from the first tile).
pub fn read_points(paths: &[&Path]) -> Result<PointCloud, PipelineError> {
    Err(PipelineError::input(
        paths.first().copied().unwrap_or(Path::new("")),
        "reader not written yet",
    ))
}

/// Read a trajectory table (contract format).
pub fn read_trajectory(path: &Path) -> Result<Trajectory, PipelineError> {
    Err(PipelineError::input(path, "reader not written yet"))
}
