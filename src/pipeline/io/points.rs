//! LAS/LAZ point reader: validation, chunked streaming into column vectors, multi-tile loading.
//!
//! **What.** LAS 1.0–1.4 and LAZ, point formats 0–10, read through the `las` crate (LAZ with
//! `laz-parallel`) into a [`PointCloud`]: f64 coordinates relative to a local origin, raw
//! intensity as f32, GPS time when the format has it, a scanner-head id per point, the CRS.
//!
//! **Algorithm.**
//! 1. *Validate before reading* ([`inspect_points`], also run by [`PointReader::open`]): the
//!    signature (`LASF`), version, header size, offset to point data and record length are
//!    checked against the file length; for uncompressed files the point count × record length
//!    must fit in the file (a truncated file is reported with how many points it has room
//!    for, and no point is read); EVLRs must lie inside the file. For LAZ the laszip VLR must
//!    exist and describe the header's record length, and the chunk table must be present,
//!    hold enough chunks for the announced point count and not claim more compressed bytes
//!    than the file has — so a damaged file can never make the decoder allocate or read out
//!    of bounds.
//! 2. *Stream*: [`PointReader::next_chunk`] fills a reused `las::PointData` byte slab with
//!    `Reader::fill_points` and decodes it column by column straight into the cloud's
//!    vectors (`raw · scale + (offset − origin)` in f64; no `las::Point` structs, no
//!    per-point allocation). Chunks of ~64 K points keep the slab in cache while the columns
//!    are swept; LAZ requests whole multiples of the laszip chunk so `laz-parallel` can
//!    decode chunks on every core.
//! 3. *Scanner head* (the pipeline must not assume one head). A sample of the first 65 536
//!    points decides the source: formats 6–10 use the scanner channel when it takes ≥ 2
//!    values; otherwise (and for formats 0–5) `user_data`, then `point_source_id`, is used
//!    when it takes 2–4 distinct values, each on ≥ 5 % of the sample (heads interleave in
//!    acquisition order, so both show up early and in similar numbers; a field used for
//!    labels or flight lines fails the test). Values are numbered by rank in the sample
//!    (0, 1, …); values first seen later get the next numbers. Otherwise every point is
//!    head 0.
//! 4. *Tiles* ([`read_points`]): all headers are validated first; the origin is the first
//!    tile's header minimum floored to whole metres (its first point when the header bounds
//!    are unusable) and every tile is decoded relative to it; GPS time is kept only when
//!    every tile has it; tiles declaring different EPSG codes are an error.
//! 5. *Intensity*: [`read_points`] rejects a tile whose points all have intensity 0 ("has no
//!    intensity values"), because marking extraction needs intensity. The streaming reader
//!    does not judge; it counts non-zero intensities ([`PointReader::nonzero_intensity_count`]).
//!
//! **Parameters.** Chunk size (points per `next_chunk`), [`ReadOptions`].
//!
//! **Reference.** ASPRS LAS 1.4 R15 specification (record layouts, §2.6); LASzip chunk table
//! (laz-rs `laszip::chunk_table`).
//!
//! **Complexity.** O(n) time; memory O(chunk) for streaming, O(n) for [`read_points`].

use super::crs::crs_from_header;
use super::{FileKind, PointsSummary, open_file};
use crate::pipeline::error::PipelineError;
use crate::pipeline::types::{Crs, PointCloud};
use serde::Serialize;
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

/// Points sampled at open to choose the scanner-head source.
const SCANNER_SAMPLE: usize = 65_536;
/// Default chunk (points per `next_chunk`) for uncompressed files.
const LAS_CHUNK: usize = 16_384;
/// Records read from an uncompressed file at a time: the slab (≤ 16 K × record length, about
/// 0.5 MB) stays in L2 between the kernel's copy and the decode. Measured on a 10 M point
/// file: 4–16 K records decode at ~1.5× the raw read time, 64 K at 2.5×, 256 K at 7×.
const LAS_FETCH: usize = 16_384;
/// Records decoded per group of column passes (~120 KB of format-6 records).
const DECODE_BLOCK: usize = 4_096;
/// Size of the LAS 1.0–1.2 header; every version's header is at least this long.
const MIN_HEADER_SIZE: u64 = 227;

/// Where the scanner-head id of each point comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ScannerSource {
    /// The LAS 1.4 scanner channel (formats 6–10).
    Channel,
    /// The user_data byte (heuristic, see the module docs).
    UserData,
    /// The point_source_id field (heuristic, see the module docs).
    PointSourceId,
    /// Nothing tells heads apart: every point is head 0.
    Single,
}

/// Options of [`read_points_with`].
#[derive(Clone, Debug)]
pub struct ReadOptions {
    /// Reject a tile whose intensities are all zero (default true).
    pub require_intensity: bool,
    /// Points per chunk; `None` uses [`PointReader::preferred_chunk`].
    pub chunk_points: Option<usize>,
}

impl Default for ReadOptions {
    fn default() -> Self {
        Self {
            require_intensity: true,
            chunk_points: None,
        }
    }
}

/// Byte offsets of the decoded fields inside one point record.
#[derive(Clone, Copy, Debug)]
struct RecordLayout {
    len: usize,
    gps: Option<usize>,
    user_data: usize,
    point_source_id: usize,
    extended: bool,
}

impl RecordLayout {
    /// LAS 1.4 R15 Tables 7–17: formats 0–5 share the 20-byte legacy core (GPS time at 20),
    /// formats 6–10 the 30-byte extended core (scanner channel in byte 15, GPS time at 22).
    fn new(format: &las::point::Format, len: usize) -> Self {
        if format.is_extended {
            RecordLayout {
                len,
                gps: Some(22),
                user_data: 17,
                point_source_id: 20,
                extended: true,
            }
        } else {
            RecordLayout {
                len,
                gps: format.has_gps_time.then_some(20),
                user_data: 17,
                point_source_id: 18,
                extended: false,
            }
        }
    }
}

/// Header fields checked before `las` parses the file.
struct Checked {
    file_len: u64,
    point_count: u64,
    offset_to_point_data: u64,
    compressed: bool,
}

fn err(path: &Path, message: impl Into<String>) -> PipelineError {
    PipelineError::input(path, message)
}

fn read_exact_at(file: &mut File, path: &Path, pos: u64, buf: &mut [u8]) -> Result<(), PipelineError> {
    file.seek(SeekFrom::Start(pos))
        .and_then(|_| file.read_exact(buf))
        .map_err(|e| PipelineError::Io {
            path: path.to_path_buf(),
            source: e,
        })
}

fn le_u16(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}

fn le_u32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"))
}

fn le_u64(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"))
}

/// Step 1 of the module docs, up to what can be checked from the raw header bytes.
fn check_raw_header(path: &Path, file: &mut File) -> Result<Checked, PipelineError> {
    let file_len = file
        .metadata()
        .map_err(|e| PipelineError::Io {
            path: path.to_path_buf(),
            source: e,
        })?
        .len();
    if file_len == 0 {
        return Err(err(path, "empty file (0 bytes): not a LAS/LAZ file"));
    }
    // The header is at most 65535 bytes (its size is a u16), usually 227–375.
    let mut head = vec![0u8; file_len.min(1 << 16) as usize];
    read_exact_at(file, path, 0, &mut head)?;
    if !head.starts_with(b"LASF") {
        let hint = match super::sniff(&head) {
            FileKind::Trajectory => " (it looks like a trajectory table)",
            _ if head
                .iter()
                .all(|b| b.is_ascii_graphic() || b.is_ascii_whitespace()) =>
            {
                " (it is a text file)"
            }
            _ => "",
        };
        return Err(err(
            path,
            format!("not a LAS/LAZ file: signature is not LASF{hint}"),
        ));
    }
    if file_len < MIN_HEADER_SIZE {
        return Err(err(
            path,
            format!("truncated file: {file_len} bytes, shorter than a LAS header ({MIN_HEADER_SIZE} bytes)"),
        ));
    }
    let raw = las::raw::Header::read_from(&head[..])
        .map_err(|e| err(path, format!("unreadable LAS header (truncated?): {e}")))?;
    let (major, minor) = (raw.version.major, raw.version.minor);
    if major != 1 || minor > 4 {
        return Err(err(
            path,
            format!("unsupported LAS version {major}.{minor} (versions 1.0 to 1.4 are supported)"),
        ));
    }
    let header_size = u64::from(raw.header_size);
    let expected_header = u64::from(raw.version.header_size());
    if header_size < expected_header {
        return Err(err(
            path,
            format!(
                "corrupt header: header size {header_size} is below the {expected_header} bytes LAS {major}.{minor} needs"
            ),
        ));
    }
    let offset_to_point_data = u64::from(raw.offset_to_point_data);
    if offset_to_point_data < header_size {
        return Err(err(
            path,
            format!(
                "corrupt header: point data offset {offset_to_point_data} lies inside the {header_size}-byte header"
            ),
        ));
    }
    if offset_to_point_data > file_len {
        return Err(err(
            path,
            format!(
                "truncated file: point data should start at byte {offset_to_point_data} but the file has only {file_len} bytes"
            ),
        ));
    }
    // Walk the VLR headers: the chain must end at or before the point data (a corrupt
    // count would otherwise make `las` parse point bytes as VLRs through the whole file).
    let mut pos = header_size;
    for i in 0..raw.number_of_variable_length_records {
        let mut vlr = [0u8; 54];
        if pos + 54 > offset_to_point_data {
            return Err(err(
                path,
                format!(
                    "corrupt header: {} VLRs announced but VLR {} would start inside the point data",
                    raw.number_of_variable_length_records,
                    i + 1
                ),
            ));
        }
        read_exact_at(file, path, pos, &mut vlr)?;
        pos += 54 + u64::from(le_u16(&vlr, 20));
    }
    if pos > offset_to_point_data {
        return Err(err(path, "corrupt header: the last VLR runs into the point data"));
    }
    let format = las::point::Format::new(raw.point_data_record_format).map_err(|_| {
        err(
            path,
            format!(
                "unsupported point format {} (formats 0 to 10 are supported)",
                raw.point_data_record_format & 0x3f
            ),
        )
    })?;
    let record_len = u64::from(raw.point_data_record_length);
    if record_len < u64::from(format.len()) {
        return Err(err(
            path,
            format!(
                "corrupt header: point record length {record_len} is shorter than format {} needs ({} bytes)",
                format.to_u8().unwrap_or(0),
                format.len()
            ),
        ));
    }
    // LAS 1.4: a non-zero legacy count wins over the 64-bit one (R15 §2.4, as `las` does).
    let legacy = u64::from(raw.number_of_point_records);
    let point_count = match raw.large_file {
        Some(lf) if legacy == 0 => lf.number_of_point_records,
        _ => legacy,
    };
    let point_bytes = point_count
        .checked_mul(record_len)
        .and_then(|b| b.checked_add(offset_to_point_data))
        .ok_or_else(|| {
            err(
                path,
                format!("corrupt header: implausible point count {point_count}"),
            )
        })?;
    if !format.is_compressed && point_bytes > file_len {
        let room = (file_len - offset_to_point_data) / record_len;
        return Err(err(
            path,
            format!(
                "truncated file: the header announces {point_count} points ({record_len} bytes each, {} bytes of \
                 point data) but the file has {file_len} bytes, room for {room} points",
                point_count * record_len
            ),
        ));
    }
    if let Some(evlr) = raw.evlr {
        let start = evlr.start_of_first_evlr;
        if !format.is_compressed && start < point_bytes {
            return Err(err(
                path,
                format!("corrupt header: the first EVLR (byte {start}) overlaps the point data"),
            ));
        }
        if start.checked_add(60).is_none_or(|end| end > file_len) {
            return Err(err(
                path,
                format!(
                    "truncated file: the first EVLR should start at byte {start} but the file has {file_len} bytes"
                ),
            ));
        }
        let mut evlr_head = [0u8; 60];
        read_exact_at(file, path, start, &mut evlr_head)?;
        let len = le_u64(&evlr_head, 20);
        if len > file_len - start - 60 {
            return Err(err(
                path,
                format!(
                    "truncated file: the EVLR at byte {start} announces {len} bytes past the end of the file"
                ),
            ));
        }
    }
    Ok(Checked {
        file_len,
        point_count,
        offset_to_point_data,
        compressed: format.is_compressed,
    })
}

/// Step 1 for LAZ: laszip VLR and chunk table, before any decoding.
fn check_laz(path: &Path, header: &las::Header, file: &mut File, c: &Checked) -> Result<(), PipelineError> {
    let vlr = header.laz_vlr().map_err(|e| {
        err(
            path,
            format!("unreadable LAZ data: the laszip VLR is missing or invalid ({e})"),
        )
    })?;
    let record_len = u64::from(header.point_format().len());
    if vlr.items_size() != record_len {
        return Err(err(
            path,
            format!(
                "unreadable LAZ data: the laszip VLR describes {}-byte points but the header says {record_len}",
                vlr.items_size()
            ),
        ));
    }
    let n = c.point_count;
    let data_start = c.offset_to_point_data;
    if data_start + 8 > c.file_len {
        return Err(err(
            path,
            "truncated file: no compressed point data after the header",
        ));
    }
    // The chunk table offset follows the header; writers that could not seek back leave it
    // invalid and repeat it in the last 8 bytes of the file (laz-rs `read_offset` does the same).
    let mut b8 = [0u8; 8];
    read_exact_at(file, path, data_start, &mut b8)?;
    let mut table_at = i64::from_le_bytes(b8);
    if table_at <= data_start as i64 {
        read_exact_at(file, path, c.file_len - 8, &mut b8)?;
        table_at = i64::from_le_bytes(b8);
        if table_at <= data_start as i64 {
            return Err(err(
                path,
                "unreadable LAZ data: the chunk table is missing (the file was not finished or is truncated)",
            ));
        }
    }
    let table_at = table_at as u64;
    if table_at.checked_add(8).is_none_or(|end| end > c.file_len) {
        return Err(err(
            path,
            format!(
                "truncated file: the LAZ chunk table should start at byte {table_at} but the file has only {} bytes",
                c.file_len
            ),
        ));
    }
    read_exact_at(file, path, table_at, &mut b8)?;
    let chunks = u64::from(le_u32(&b8, 4));
    let compressed_bytes = table_at - data_start - 8;
    let chunk_size = u64::from(vlr.chunk_size());
    let variable = vlr.uses_variable_size_chunks();
    if !variable {
        let needed = n.div_ceil(chunk_size.max(1));
        if chunks < needed {
            return Err(err(
                path,
                format!(
                    "truncated or incomplete LAZ file: the chunk table lists {chunks} chunks of {chunk_size} points \
                     but the header announces {n} points ({needed} chunks)"
                ),
            ));
        }
    }
    // Each chunk holds at least one byte: bounds the table before laz allocates it.
    if chunks > compressed_bytes {
        return Err(err(
            path,
            format!("unreadable LAZ data: corrupt chunk table ({chunks} chunks in {compressed_bytes} bytes)"),
        ));
    }
    file.seek(SeekFrom::Start(data_start))
        .map_err(|e| PipelineError::Io {
            path: path.to_path_buf(),
            source: e,
        })?;
    let table = laz::laszip::ChunkTable::read_from(&mut BufReader::new(&mut *file), &vlr)
        .map_err(|e| err(path, format!("unreadable LAZ data: corrupt chunk table ({e})")))?;
    let entries = table.as_ref();
    let total_bytes = entries.iter().fold(0u64, |a, e| a.saturating_add(e.byte_count));
    if total_bytes > compressed_bytes {
        return Err(err(
            path,
            format!(
                "truncated or corrupt LAZ file: the chunk table lists {total_bytes} bytes of chunks but only \
                 {compressed_bytes} bytes of compressed data precede it"
            ),
        ));
    }
    if variable {
        let total_points = entries.iter().fold(0u64, |a, e| a.saturating_add(e.point_count));
        if total_points < n || entries.iter().any(|e| e.point_count > n.max(1)) {
            return Err(err(
                path,
                format!(
                    "truncated or corrupt LAZ file: the chunk table lists {total_points} points, the header {n}"
                ),
            ));
        }
    }
    Ok(())
}

/// Validate a file completely (steps 1 of the module docs) and open the `las` reader on it.
fn open_checked(path: &Path) -> Result<(las::Reader, Checked), PipelineError> {
    let mut file = open_file(path)?;
    let checked = check_raw_header(path, &mut file)?;
    file.seek(SeekFrom::Start(0)).map_err(|e| PipelineError::Io {
        path: path.to_path_buf(),
        source: e,
    })?;
    // The header (and its VLRs) is parsed on its own first, so the LAZ checks run before
    // the decompressor is built (it reads the chunk table).
    let header = las::Header::new(BufReader::new(&mut file))
        .map_err(|e| err(path, format!("unreadable LAS header: {e}")))?;
    if checked.compressed {
        check_laz(path, &header, &mut file, &checked)?;
    }
    file.seek(SeekFrom::Start(0)).map_err(|e| PipelineError::Io {
        path: path.to_path_buf(),
        source: e,
    })?;
    let reader = las::Reader::new(BufReader::with_capacity(1 << 16, file)).map_err(|e| {
        err(
            path,
            if checked.compressed {
                format!("unreadable LAZ data: {e}")
            } else {
                format!("unreadable LAS file: {e}")
            },
        )
    })?;
    Ok((reader, checked))
}

fn summary_of(header: &las::Header, checked: &Checked) -> PointsSummary {
    let b = header.bounds();
    let v = header.version();
    let format = header.point_format();
    PointsSummary {
        point_count: checked.point_count,
        bounds: [[b.min.x, b.min.y, b.min.z], [b.max.x, b.max.y, b.max.z]],
        crs: crs_from_header(header),
        version: format!("{}.{}", v.major, v.minor),
        point_format: format.to_u8().unwrap_or(0),
        compressed: format.is_compressed,
        has_gps_time: format.has_gps_time,
    }
}

/// Validate a LAS/LAZ file (header, point count vs file size, LAZ chunk table) and summarise
/// it, without reading points.
pub fn inspect_points(path: &Path) -> Result<PointsSummary, PipelineError> {
    let (reader, checked) = open_checked(path)?;
    Ok(summary_of(reader.header(), &checked))
}

/// Scanner-head mapping decided from the sample (step 3 of the module docs).
struct ScannerMap {
    source: ScannerSource,
    /// Raw value → head id; `UNSET` for values not seen yet.
    lut: Vec<u16>,
    next_id: u16,
}

const UNSET: u16 = u16::MAX;

impl ScannerMap {
    fn single() -> Self {
        ScannerMap {
            source: ScannerSource::Single,
            lut: Vec::new(),
            next_id: 0,
        }
    }

    fn decide(bytes: &[u8], layout: &RecordLayout) -> Self {
        let n = bytes.len() / layout.len;
        if n == 0 {
            return Self::single();
        }
        let recs = || bytes.chunks_exact(layout.len);
        if layout.extended {
            let mut counts = [0usize; 4];
            for r in recs() {
                counts[usize::from((r[15] >> 4) & 3)] += 1;
            }
            if counts.iter().filter(|&&c| c > 0).count() >= 2 {
                return ScannerMap {
                    source: ScannerSource::Channel,
                    lut: Vec::new(),
                    next_id: 0,
                };
            }
        }
        let ud = layout.user_data;
        let ps = layout.point_source_id;
        let value = |source: ScannerSource, r: &[u8]| match source {
            ScannerSource::UserData => usize::from(r[ud]),
            _ => usize::from(le_u16(r, ps)),
        };
        for source in [ScannerSource::UserData, ScannerSource::PointSourceId] {
            let mut counts = vec![0usize; 1 << 16];
            for r in recs() {
                counts[value(source, r)] += 1;
            }
            let distinct: Vec<usize> = (0..counts.len()).filter(|&v| counts[v] > 0).collect();
            let balanced = distinct.iter().all(|&v| counts[v] * 20 >= n);
            if (2..=4).contains(&distinct.len()) && balanced {
                let mut lut = vec![UNSET; 1 << 16];
                for (id, &v) in distinct.iter().enumerate() {
                    lut[v] = id as u16;
                }
                return ScannerMap {
                    source,
                    lut,
                    next_id: distinct.len() as u16,
                };
            }
        }
        Self::single()
    }

    #[inline]
    fn map(&mut self, raw: usize) -> u8 {
        let id = self.lut[raw];
        if id != UNSET {
            return id.min(255) as u8;
        }
        let id = self.next_id;
        self.lut[raw] = id;
        self.next_id = self.next_id.saturating_add(1).min(255);
        id.min(255) as u8
    }

    fn decode(&mut self, bytes: &[u8], layout: &RecordLayout, out: &mut Vec<u8>) {
        let recs = bytes.chunks_exact(layout.len);
        match self.source {
            ScannerSource::Single => out.resize(out.len() + recs.len(), 0),
            ScannerSource::Channel => out.extend(recs.map(|r| (r[15] >> 4) & 3)),
            ScannerSource::UserData => {
                let ud = layout.user_data;
                out.reserve(recs.len());
                for r in recs {
                    let id = self.map(usize::from(r[ud]));
                    out.push(id);
                }
            }
            ScannerSource::PointSourceId => {
                let ps = layout.point_source_id;
                out.reserve(recs.len());
                for r in recs {
                    let id = self.map(usize::from(le_u16(r, ps)));
                    out.push(id);
                }
            }
        }
    }
}

/// Streaming reader of one LAS/LAZ file into [`PointCloud`] chunks (see the module docs).
///
/// ```no_run
/// # use roadmark::pipeline::{io::PointReader, PointCloud};
/// let mut reader = PointReader::open("tile.laz".as_ref())?;
/// let mut chunk = PointCloud::default();
/// while reader.next_chunk(&mut chunk, reader.preferred_chunk())? > 0 {
///     // chunk.x / y / z are relative to chunk.origin (== reader.origin())
/// }
/// # Ok::<(), roadmark::pipeline::PipelineError>(())
/// ```
pub struct PointReader {
    path: PathBuf,
    reader: las::Reader,
    /// Reused byte slab of raw records.
    data: las::PointData,
    /// Records of `data` not decoded yet start here (the sample read at open is kept).
    pending_from: usize,
    summary: PointsSummary,
    layout: RecordLayout,
    scale: [f64; 3],
    offset: [f64; 3],
    origin: [f64; 3],
    scanner: ScannerMap,
    /// Points handed out so far.
    delivered: u64,
    /// Points fetched from the file so far.
    fetched: u64,
    nonzero_intensity: u64,
    laz_chunk: Option<usize>,
    /// Set when the decoder failed: later calls repeat the error instead of reading garbage.
    failed: Option<String>,
}

impl std::fmt::Debug for PointReader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PointReader")
            .field("path", &self.path)
            .field("summary", &self.summary)
            .field("origin", &self.origin)
            .field("scanner_source", &self.scanner.source)
            .field("delivered", &self.delivered)
            .finish()
    }
}

impl PointReader {
    /// Validate the file (like [`inspect_points`]) and prepare to stream it.
    pub fn open(path: &Path) -> Result<Self, PipelineError> {
        let (reader, checked) = open_checked(path)?;
        let header = reader.header();
        let summary = summary_of(header, &checked);
        let format = *header.point_format();
        let layout = RecordLayout::new(&format, usize::from(format.len()));
        let t = *header.transforms();
        let laz_chunk = if format.is_compressed {
            header.laz_vlr().ok().map(|v| {
                let c = v.chunk_size();
                if v.uses_variable_size_chunks() || c == 0 {
                    LAS_CHUNK
                } else {
                    c as usize
                }
            })
        } else {
            None
        };
        let data = las::PointDataBuilder::new().for_header(header).build();
        let mut me = PointReader {
            path: path.to_path_buf(),
            reader,
            data,
            pending_from: 0,
            layout,
            scale: [t.x.scale, t.y.scale, t.z.scale],
            offset: [t.x.offset, t.y.offset, t.z.offset],
            origin: [0.0; 3],
            scanner: ScannerMap::single(),
            delivered: 0,
            fetched: 0,
            nonzero_intensity: 0,
            laz_chunk,
            failed: None,
            summary,
        };
        // The sample stays in the slab and is decoded by the first `next_chunk` calls.
        let sample = me.summary.point_count.min(SCANNER_SAMPLE as u64) as usize;
        me.fetch(sample)?;
        me.scanner = ScannerMap::decide(me.data.raw_bytes(), &me.layout);
        me.origin = me.default_origin();
        Ok(me)
    }

    /// Header minimum floored to whole metres; the first point when the bounds are unusable.
    fn default_origin(&self) -> [f64; 3] {
        let [min, max] = self.summary.bounds;
        let usable = (0..3).all(|i| min[i].is_finite() && max[i].is_finite() && min[i] <= max[i])
            && min.iter().chain(&max).all(|v| v.abs() < 1e9)
            && min.iter().chain(&max).any(|&v| v != 0.0);
        let base = if usable {
            min
        } else if let Some(r) = self.data.raw_bytes().get(..12) {
            let mut p = [0.0; 3];
            for (i, v) in p.iter_mut().enumerate() {
                let raw = i32::from_le_bytes(r[4 * i..4 * i + 4].try_into().expect("4 bytes"));
                *v = f64::from(raw) * self.scale[i] + self.offset[i];
            }
            p
        } else {
            [0.0; 3]
        };
        base.map(|v| if v.is_finite() { v.floor() } else { 0.0 })
    }

    /// Read up to `n` more records from the file into the slab (replacing it).
    fn fetch(&mut self, n: usize) -> Result<usize, PipelineError> {
        if let Some(m) = &self.failed {
            return Err(err(&self.path, m.clone()));
        }
        let left = self.summary.point_count - self.fetched;
        let n = (n as u64).min(left);
        self.pending_from = 0;
        if n == 0 {
            self.data.resize_for(0);
            return Ok(0);
        }
        // laz-rs is not documented as panic-free on corrupt data: a panic in the decoder
        // becomes an input error instead of taking the service down.
        let reader = &mut self.reader;
        let data = &mut self.data;
        let res = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| reader.fill_points(n, data)));
        let what = if self.summary.compressed {
            "unreadable LAZ data"
        } else {
            "unreadable point data"
        };
        let got = match res {
            Ok(Ok(got)) => got,
            Ok(Err(e)) => {
                let m = format!("{what} near point {}: {e}", self.fetched);
                self.failed = Some(m.clone());
                return Err(err(&self.path, m));
            }
            Err(_) => {
                let m = format!(
                    "{what} near point {}: the decoder failed on corrupt data",
                    self.fetched
                );
                self.failed = Some(m.clone());
                return Err(err(&self.path, m));
            }
        };
        self.fetched += got;
        Ok(got as usize)
    }

    /// Header summary (point count, bounds, CRS, format).
    pub fn summary(&self) -> &PointsSummary {
        &self.summary
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The local origin the coordinates are expressed relative to.
    pub fn origin(&self) -> [f64; 3] {
        self.origin
    }

    /// Use another local origin (e.g. the first tile's, when reading several tiles).
    pub fn set_origin(&mut self, origin: [f64; 3]) {
        self.origin = origin;
    }

    pub fn crs(&self) -> Option<&Crs> {
        self.summary.crs.as_ref()
    }

    pub fn has_gps_time(&self) -> bool {
        self.layout.gps.is_some()
    }

    /// Where the scanner-head ids come from.
    pub fn scanner_source(&self) -> ScannerSource {
        self.scanner.source
    }

    /// Points not yet delivered.
    pub fn remaining(&self) -> u64 {
        self.summary.point_count - self.delivered
    }

    /// Points delivered so far with a non-zero intensity.
    pub fn nonzero_intensity_count(&self) -> u64 {
        self.nonzero_intensity
    }

    /// A good chunk size: ~64 K points for LAS; for LAZ whole laszip chunks, enough of them
    /// to keep every rayon thread decoding.
    pub fn preferred_chunk(&self) -> usize {
        match self.laz_chunk {
            Some(c) => c * (2 * rayon::current_num_threads()).max(4),
            None => LAS_CHUNK,
        }
    }

    /// Replace `out` with the next at most `max_points` points (buffers are reused). Returns
    /// the number of points read; 0 at the end of the file.
    pub fn next_chunk(&mut self, out: &mut PointCloud, max_points: usize) -> Result<usize, PipelineError> {
        out.x.clear();
        out.y.clear();
        out.z.clear();
        out.intensity.clear();
        out.scanner.clear();
        out.origin = self.origin;
        out.crs = self.summary.crs.clone();
        match (&mut out.gps_time, self.layout.gps) {
            (Some(t), Some(_)) => t.clear(),
            (g, Some(_)) => *g = Some(Vec::new()),
            (g, None) => *g = None,
        }
        self.append_chunk(out, max_points)
    }

    /// Append the next at most `max_points` points to `out`, relative to `out.origin`.
    /// GPS time: when the file has none, `out.gps_time` becomes `None`; when `out` is empty
    /// and the file has it, it becomes `Some`. Returns 0 at the end of the file.
    pub fn append_chunk(&mut self, out: &mut PointCloud, max_points: usize) -> Result<usize, PipelineError> {
        let max_points = max_points.max(1);
        let len = self.layout.len;
        if out.is_empty() && out.gps_time.is_none() && self.layout.gps.is_some() {
            out.gps_time = Some(Vec::new());
        }
        let shift = [0, 1, 2].map(|i| self.offset[i] - out.origin[i]);
        let mut done = 0;
        while done < max_points {
            if self.pending_from * len >= self.data.raw_bytes().len() {
                // LAS: small slabs stay in L2 between the kernel copy and the decode.
                // LAZ: large requests let laz-parallel decode chunks on every core.
                let want = match self.laz_chunk {
                    Some(_) => self.preferred_chunk(),
                    None => (max_points - done).min(LAS_FETCH),
                };
                if self.fetch(want)? == 0 {
                    break;
                }
            }
            let bytes = self.data.raw_bytes();
            let avail = bytes.len() / len - self.pending_from;
            let n = avail.min(max_points - done).min(DECODE_BLOCK);
            let block = &bytes[self.pending_from * len..(self.pending_from + n) * len];
            decode_block(block, &self.layout, self.scale, shift, out);
            let base = out.intensity.len() - n;
            self.nonzero_intensity += out.intensity[base..].iter().filter(|&&v| v != 0.0).count() as u64;
            self.scanner.decode(block, &self.layout, &mut out.scanner);
            self.pending_from += n;
            done += n;
        }
        if out.crs.is_none() {
            out.crs = self.summary.crs.clone();
        }
        self.delivered += done as u64;
        Ok(done)
    }
}

/// Decode coordinates, intensity and GPS time of `block` and append them to `out`.
///
/// One pass per column over a block small enough to stay in L1/L2 ([`DECODE_BLOCK`]
/// records): each pass is a tight `extend` over an exact-size iterator, which writes the
/// destination without capacity checks.
fn decode_block(block: &[u8], layout: &RecordLayout, scale: [f64; 3], shift: [f64; 3], out: &mut PointCloud) {
    let recs = block.chunks_exact(layout.len);
    let coord = |r: &[u8], at: usize| i32::from_le_bytes(r[at..at + 4].try_into().expect("4 bytes"));
    let (sx, sy, sz) = (scale[0], scale[1], scale[2]);
    let (ox, oy, oz) = (shift[0], shift[1], shift[2]);
    out.x
        .extend(recs.clone().map(|r| f64::from(coord(r, 0)) * sx + ox));
    out.y
        .extend(recs.clone().map(|r| f64::from(coord(r, 4)) * sy + oy));
    out.z
        .extend(recs.clone().map(|r| f64::from(coord(r, 8)) * sz + oz));
    out.intensity
        .extend(recs.clone().map(|r| f32::from(le_u16(r, 12))));
    match (layout.gps, &mut out.gps_time) {
        (Some(g), Some(t)) => {
            t.extend(recs.map(|r| f64::from_le_bytes(r[g..g + 8].try_into().expect("8 bytes"))))
        }
        (None, t) => *t = None,
        (Some(_), None) => {}
    }
}

/// Read several tiles of one drive into one cloud (see the module docs, step 4), rejecting
/// tiles without intensity.
pub fn read_points(paths: &[&Path]) -> Result<PointCloud, PipelineError> {
    read_points_with(paths, &ReadOptions::default())
}

/// [`read_points`] with options.
pub fn read_points_with(paths: &[&Path], options: &ReadOptions) -> Result<PointCloud, PipelineError> {
    let Some(first) = paths.first() else {
        return Err(err(Path::new(""), "no point cloud files given"));
    };
    // Validate every header before reading any point: a broken last tile fails fast.
    let summaries = paths
        .iter()
        .map(|p| inspect_points(p))
        .collect::<Result<Vec<_>, _>>()?;
    let mut crs: Option<(Crs, &Path)> = None;
    for (s, p) in summaries.iter().zip(paths) {
        match (&crs, &s.crs) {
            (None, Some(c)) => crs = Some((c.clone(), p)),
            (Some((known, from)), Some(c)) => {
                if let (Some(a), Some(b)) = (known.epsg, c.epsg)
                    && a != b
                {
                    return Err(err(
                        p,
                        format!(
                            "CRS EPSG:{b} differs from EPSG:{a} of {} (all tiles of a drive must share one CRS)",
                            from.display()
                        ),
                    ));
                }
            }
            _ => {}
        }
    }
    // Reserve the announced total up front (no reallocation copies). A LAZ header could
    // announce more points than its bytes can plausibly hold: reserve at most 8 points per
    // compressed byte (~200× compression) and let the vectors grow beyond that if real.
    let mut total = 0u64;
    for (s, p) in summaries.iter().zip(paths) {
        let plausible = if s.compressed {
            let bytes = std::fs::metadata(p).map(|m| m.len()).unwrap_or(0);
            s.point_count.min(bytes.saturating_mul(8))
        } else {
            s.point_count
        };
        total = total.saturating_add(plausible);
    }
    let total = usize::try_from(total).unwrap_or(usize::MAX);
    let all_gps = summaries.iter().all(|s| s.has_gps_time);
    let mut cloud = PointCloud::default();
    let no_memory = |_| {
        err(
            first,
            format!("not enough memory for the {total} points announced by the tiles' headers"),
        )
    };
    cloud.x.try_reserve_exact(total).map_err(no_memory)?;
    cloud.y.try_reserve_exact(total).map_err(no_memory)?;
    cloud.z.try_reserve_exact(total).map_err(no_memory)?;
    cloud.intensity.try_reserve_exact(total).map_err(no_memory)?;
    cloud.scanner.try_reserve_exact(total).map_err(no_memory)?;
    if all_gps {
        let mut t = Vec::new();
        t.try_reserve_exact(total).map_err(no_memory)?;
        cloud.gps_time = Some(t);
    }
    cloud.crs = crs.map(|(c, _)| c);
    for (i, path) in paths.iter().enumerate() {
        let mut reader = PointReader::open(path)?;
        if i == 0 {
            cloud.origin = reader.origin();
        }
        reader.set_origin(cloud.origin);
        let chunk = options.chunk_points.unwrap_or_else(|| reader.preferred_chunk());
        let before = cloud.len();
        while reader.append_chunk(&mut cloud, chunk)? > 0 {}
        let got = cloud.len() - before;
        if options.require_intensity && got > 0 && reader.nonzero_intensity_count() == 0 {
            return Err(err(
                path,
                "has no intensity values (all zero); marking extraction needs intensity",
            ));
        }
    }
    if cloud.gps_time.as_ref().is_some_and(|t| t.len() != cloud.len()) {
        cloud.gps_time = None;
    }
    Ok(cloud)
}
