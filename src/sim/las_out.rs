//! Output files: LAS 1.4 point format 6 tiles, per-point labels, the trajectory table.
//!
//! **LAS.** Version 1.4, point format 6 (30-byte records: X/Y/Z i32, intensity u16, return
//! 1 of 1, scanner channel = head, classification 1 "unclassified", user data = head,
//! scan angle in 0.006° steps, point source id 1, GPS time f64), adjusted standard GPS time
//! (global encoding bit 0) and the OGC WKT of EPSG:32650 in a LASF_Projection 2112 VLR (WKT
//! bit set). Scale 0.001 m with per-axis offsets (231000, 3380000, 0): a northing of 3.38e6
//! at 1 mm does not fit an i32 without an offset. Records are encoded here and handed to
//! `las::Writer::write_points` in blocks, which keeps the header's bounds and counts.
//!
//! **Labels.** One u32 little-endian per point in file order (tiles in tile order).
//!
//! **Tiles.** Cut by driving distance: tile k holds the points acquired while the vehicle
//! drove from `k · L / n` to `(k + 1) · L / n`; the tiles overlap spatially where the
//! scanner looks ahead and behind, and markings cross their boundaries.

use super::scanner::SimPoint;
use anyhow::{Context, Result};
use las::point::Format;
use las::{Builder, GpsTimeType, PointDataBuilder, Transform, Vector, Version, Writer};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// Per-axis offsets of the written files.
pub const OFFSETS: [f64; 3] = [231_000.0, 3_380_000.0, 0.0];
pub const SCALE: f64 = 0.001;
const RECORD: usize = 30;

/// The LAS header used for every tile.
pub fn header(epsg: u16) -> Result<las::Header> {
    let mut b = Builder::from(Version::new(1, 4));
    b.point_format = Format::new(6)?;
    b.transforms = Vector {
        x: Transform {
            scale: SCALE,
            offset: OFFSETS[0],
        },
        y: Transform {
            scale: SCALE,
            offset: OFFSETS[1],
        },
        z: Transform {
            scale: SCALE,
            offset: OFFSETS[2],
        },
    };
    b.gps_time_type = GpsTimeType::Standard;
    b.generating_software = "roadmark simulate".into();
    b.system_identifier = "roadmark VUX-1-like MLS".into();
    b.file_source_id = 1;
    let mut h = b.into_header()?;
    let def = crs_definitions::from_code(epsg).with_context(|| format!("unknown EPSG code {epsg}"))?;
    h.set_wkt_crs(def.wkt.as_bytes().to_vec())?;
    Ok(h)
}

/// Streams points into one or several LAS tiles and the label file.
pub struct LasSink {
    dir: PathBuf,
    header: las::Header,
    origin: [f64; 3],
    gps_t0: f64,
    /// End time (s since start) of each tile; the last is +∞.
    tile_ends: Vec<f64>,
    names: Vec<String>,
    tile: usize,
    writer: Option<Writer<BufWriter<File>>>,
    buf: Vec<u8>,
    labels: BufWriter<File>,
    counts: Vec<u64>,
}

impl LasSink {
    /// `tile_ends` empty → a single `points.las`; else `points_000.las`, ... with
    /// `tile_ends.len() + 1` tiles.
    pub fn new(dir: &Path, origin: [f64; 3], gps_t0: f64, tile_ends: Vec<f64>, epsg: u16) -> Result<LasSink> {
        let n = tile_ends.len() + 1;
        let names = if n == 1 {
            vec!["points.las".to_string()]
        } else {
            (0..n).map(|k| format!("points_{k:03}.las")).collect()
        };
        let labels_path = dir.join("labels.bin");
        let labels = BufWriter::new(
            File::create(&labels_path).with_context(|| format!("creating {}", labels_path.display()))?,
        );
        let mut ends = tile_ends;
        ends.push(f64::INFINITY);
        let mut sink = LasSink {
            dir: dir.to_path_buf(),
            header: header(epsg)?,
            origin,
            gps_t0,
            tile_ends: ends,
            names,
            tile: 0,
            writer: None,
            buf: Vec::with_capacity(RECORD * 65536),
            labels,
            counts: vec![0; n],
        };
        sink.open(0)?;
        Ok(sink)
    }

    fn open(&mut self, k: usize) -> Result<()> {
        let path = self.dir.join(&self.names[k]);
        let w = Writer::from_path(&path, self.header.clone())
            .with_context(|| format!("creating {}", path.display()))?;
        self.writer = Some(w);
        self.tile = k;
        Ok(())
    }

    fn flush_block(&mut self) -> Result<()> {
        if self.buf.is_empty() {
            return Ok(());
        }
        let w = self.writer.as_mut().expect("open writer");
        let bytes = std::mem::replace(&mut self.buf, Vec::with_capacity(RECORD * 65536));
        let pd = PointDataBuilder::new()
            .for_header(w.header())
            .build_from_bytes(bytes)?;
        w.write_points(&pd)?;
        Ok(())
    }

    fn close_current(&mut self) -> Result<()> {
        self.flush_block()?;
        if let Some(mut w) = self.writer.take() {
            w.close()?;
        }
        Ok(())
    }

    /// Append points (already in acquisition order).
    pub fn push(&mut self, pts: &[SimPoint]) -> Result<()> {
        for p in pts {
            while p.t >= self.tile_ends[self.tile] {
                self.close_current()?;
                let k = self.tile + 1;
                self.open(k)?;
            }
            self.encode(p)?;
            self.labels.write_all(&p.label.to_le_bytes())?;
            self.counts[self.tile] += 1;
            if self.buf.len() >= RECORD * 65536 {
                self.flush_block()?;
            }
        }
        Ok(())
    }

    fn encode(&mut self, p: &SimPoint) -> Result<()> {
        let q = |v: f64, axis: usize| -> Result<i32> {
            let r = ((v + self.origin[axis] - OFFSETS[axis]) / SCALE).round();
            if r.abs() > i32::MAX as f64 {
                anyhow::bail!("coordinate {v} does not fit the LAS scale/offset");
            }
            Ok(r as i32)
        };
        let (x, y, z) = (q(p.x, 0)?, q(p.y, 1)?, q(p.z, 2)?);
        let b = &mut self.buf;
        b.extend_from_slice(&x.to_le_bytes());
        b.extend_from_slice(&y.to_le_bytes());
        b.extend_from_slice(&z.to_le_bytes());
        b.extend_from_slice(&p.intensity.to_le_bytes());
        b.push(0x11); // return 1 of 1
        b.push((p.head & 0x3) << 4); // classification flags 0, scanner channel, no edge/dir
        b.push(1); // unclassified
        b.push(p.head); // user data
        let angle = (f64::from(p.scan_angle_deg) / 0.006)
            .round()
            .clamp(-30000.0, 30000.0) as i16;
        b.extend_from_slice(&angle.to_le_bytes());
        b.extend_from_slice(&1u16.to_le_bytes());
        b.extend_from_slice(&(p.t + self.gps_t0).to_le_bytes());
        Ok(())
    }

    /// Close every file; returns (file name, point count) per tile.
    pub fn finish(mut self) -> Result<Vec<(String, u64)>> {
        self.close_current()?;
        // Tiles the drive never reached are still written (empty), so names are contiguous.
        for k in self.tile + 1..self.names.len() {
            self.open(k)?;
            self.close_current()?;
        }
        self.labels.flush()?;
        Ok(self.names.into_iter().zip(self.counts).collect())
    }
}

/// One trajectory row.
pub struct TrajRow {
    pub t: f64,
    pub pos: [f64; 3],
    pub heading_deg: f64,
    pub roll_deg: f64,
    pub pitch_deg: f64,
}

/// Write `trajectory.csv` (absolute coordinates, GPS time).
pub fn write_trajectory(path: &Path, rows: &[TrajRow], origin: [f64; 3], gps_t0: f64) -> Result<()> {
    let f = File::create(path).with_context(|| format!("creating {}", path.display()))?;
    let mut w = BufWriter::new(f);
    writeln!(w, "time,x,y,z,heading,roll,pitch")?;
    for r in rows {
        writeln!(
            w,
            "{:.6},{:.4},{:.4},{:.4},{:.5},{:.5},{:.5}",
            r.t + gps_t0,
            r.pos[0] + origin[0],
            r.pos[1] + origin[1],
            r.pos[2] + origin[2],
            r.heading_deg,
            r.roll_deg,
            r.pitch_deg
        )?;
    }
    w.flush()?;
    Ok(())
}
