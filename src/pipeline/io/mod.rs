//! Input: LAS/LAZ point clouds, trajectory tables, CRS detection, file-kind sniffing.
//!
//! **What.** Everything that turns files into the pipeline's types: [`read_points`] (several
//! tiles of one drive into one [`PointCloud`](crate::pipeline::PointCloud)),
//! [`PointReader`] (the same, streamed chunk by chunk for files larger than memory),
//! [`inspect_points`] (header validation and summary, no points read),
//! [`read_trajectory`]/[`parse_trajectory`] (the contract's table), and [`sniff`] (what an
//! uploaded file is, from its first bytes).
//!
//! **Algorithm.** See the submodules: [`points`] (validation, chunked column decoding,
//! scanner heads, tiles), [`trajectory`] (header and delimiter detection), [`crs`] (WKT and
//! GeoTIFF to EPSG). Sniffing: the `LASF` signature means LAS, or LAZ when the point format
//! byte has the compression bit (0x80, or 0x40 for old LASzip) or a laszip VLR follows the
//! header; printable text whose first non-comment line is a header with time, x and y
//! columns means a trajectory; anything else is unknown.
//!
//! **Parameters.** Chunk sizes and [`ReadOptions`]; no tuning constants otherwise.
//!
//! **Reference.** ASPRS LAS 1.4 R15; LASzip; `CONTRACT.md` (Inputs).
//!
//! **Complexity.** Linear in the input size; streaming uses memory in O(chunk).
//!
//! Every input problem is a [`PipelineError::Input`] naming the file and the problem; a
//! missing file is an input error too (retrying cannot make it appear), other I/O failures
//! are [`PipelineError::Io`] (retryable).

pub mod crs;
pub mod points;
pub mod trajectory;

pub use points::{PointReader, ReadOptions, ScannerSource, inspect_points, read_points, read_points_with};
pub use trajectory::{Delimiter, TrajectorySummary, inspect_trajectory, parse_trajectory, read_trajectory};

use super::error::PipelineError;
use super::types::Crs;
use serde::Serialize;
use std::fs::File;
use std::io::Read;
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

/// Bytes [`sniff`] wants to see (it copes with fewer).
pub const SNIFF_BYTES: usize = 4096;

/// Recognise a file from its first bytes (at least 512 bytes when available; a laszip VLR
/// is only found when its header lies within `head`).
pub fn sniff(head: &[u8]) -> FileKind {
    if head.starts_with(b"LASF") {
        if head.get(104).is_some_and(|f| f & 0xC0 != 0) || has_laszip_vlr(head) {
            FileKind::Laz
        } else {
            FileKind::Las
        }
    } else if trajectory::looks_like_trajectory(head) {
        FileKind::Trajectory
    } else {
        FileKind::Unknown
    }
}

/// Whether a VLR with user id "laszip encoded" and record id 22204 starts within `head`.
fn has_laszip_vlr(head: &[u8]) -> bool {
    if head.len() < 104 {
        return false;
    }
    let header_size = usize::from(u16::from_le_bytes([head[94], head[95]]));
    let count = u32::from_le_bytes([head[100], head[101], head[102], head[103]]);
    let mut pos = header_size;
    for _ in 0..count.min(1024) {
        let Some(vlr) = head.get(pos..pos + 54) else {
            return false;
        };
        if vlr[2..18].starts_with(b"laszip encoded") && u16::from_le_bytes([vlr[18], vlr[19]]) == 22204 {
            return true;
        }
        pos += 54 + usize::from(u16::from_le_bytes([vlr[20], vlr[21]]));
    }
    false
}

/// [`sniff`] on the first [`SNIFF_BYTES`] of a file.
pub fn sniff_file(path: &Path) -> Result<FileKind, PipelineError> {
    let file = open_file(path)?;
    let mut head = Vec::with_capacity(SNIFF_BYTES);
    file.take(SNIFF_BYTES as u64)
        .read_to_end(&mut head)
        .map_err(|e| PipelineError::Io {
            path: path.to_path_buf(),
            source: e,
        })?;
    Ok(sniff(&head))
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

/// Open a file for reading: a missing file or a directory is an input error, anything else
/// (permissions, disk) a retryable I/O error.
pub(crate) fn open_file(path: &Path) -> Result<File, PipelineError> {
    match File::open(path) {
        Ok(f) => {
            if f.metadata().is_ok_and(|m| m.is_dir()) {
                return Err(PipelineError::input(path, "is a directory, not a file"));
            }
            Ok(f)
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            Err(PipelineError::input(path, "file not found"))
        }
        Err(e) => Err(PipelineError::Io {
            path: path.to_path_buf(),
            source: e,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sniff_recognises_kinds() {
        let mut las = vec![0u8; 375];
        las[..4].copy_from_slice(b"LASF");
        las[104] = 6;
        assert_eq!(sniff(&las), FileKind::Las);
        las[104] = 6 | 0x80;
        assert_eq!(sniff(&las), FileKind::Laz);
        las[104] = 3 | 0x40;
        assert_eq!(sniff(&las), FileKind::Laz);
        assert_eq!(sniff(b"LASF"), FileKind::Las);
        assert_eq!(sniff(b"time,x,y\n1,2,3\n"), FileKind::Trajectory);
        assert_eq!(sniff(b"\x89PNG\r\n"), FileKind::Unknown);
        assert_eq!(sniff(b""), FileKind::Unknown);
    }

    #[test]
    fn sniff_finds_a_laszip_vlr() {
        let mut head = vec![0u8; 227 + 54 + 10 + 54];
        head[..4].copy_from_slice(b"LASF");
        head[94..96].copy_from_slice(&227u16.to_le_bytes());
        head[100..104].copy_from_slice(&2u32.to_le_bytes());
        head[104] = 3;
        // First VLR: 10 bytes of something else.
        head[227 + 2..227 + 11].copy_from_slice(b"LASF_Spec");
        head[227 + 20..227 + 22].copy_from_slice(&10u16.to_le_bytes());
        let second = 227 + 54 + 10;
        head[second + 2..second + 16].copy_from_slice(b"laszip encoded");
        head[second + 18..second + 20].copy_from_slice(&22204u16.to_le_bytes());
        assert_eq!(sniff(&head), FileKind::Laz);
        assert_eq!(sniff(&head[..second + 10]), FileKind::Las, "VLR not within head");
    }
}
