//! Synthetic mobile-mapping surveys: ray-cast scenes with exact truth, for tests, demos,
//! benchmarks and classifier training (`roadmark simulate`).
//!
//! **What.** A scene ([`scene`]) is a road of straights and arcs ([`road`]) with a
//! cross-section (crown or superelevation, curbs, sidewalks, verges, viaduct edges), road
//! markings of real dimensions ([`markings`]), objects that occlude the pavement
//! ([`objects`]: façades, trees with porous canopies, poles, barriers, parked and moving
//! cars), and pavement features that fool intensity thresholds ([`intensity`]: asphalt
//! texture and repairs, worn paint, manhole covers, crack sealant, concrete patches).
//! A vehicle ([`drive`]) carries one or two rotating-mirror profilers ([`scanner`]); every
//! pulse is cast against the ground ([`surface`]) and the objects.
//!
//! **Outputs** in the output directory:
//! - `points.las` (or `points_000.las`, `points_001.las`, ... with `tiles > 1`): LAS 1.4,
//!   point format 6, EPSG:32650 WKT, points in acquisition order ([`las_out`]).
//! - `trajectory.csv`: `time,x,y,z,heading,roll,pitch` at 100 Hz, same GPS time base,
//!   heading in degrees clockwise from north, roll positive right side down, pitch positive
//!   nose up; the position is the reference point 2.2 m above the ground between the heads.
//! - `truth.geojson`: the contract's FeatureCollection in the native CRS (EPSG:32650), every
//!   marking a polygon (`m1`, `m2`, ...) with its real dimensions and the number of
//!   simulated points on its paint, every lane line its painted centreline (`l1`, ...).
//!   A hollow shape (the diamond, the glyph "0") has its outer ring as outline.
//! - `labels.bin`: **one u32 little-endian per point, in file order** (all points of
//!   `points.las`, or of `points_000.las`, then `points_001.las`, ...): 0 = not paint,
//!   k = 1 + index of the marking in the order of the `marking` features of
//!   `truth.geojson` (`m{k}`). Where worn paint is completely gone the point is 0.
//! - `summary.json`: scene, seed, options, counts, origin.
//! - `preview.png` (with `preview`): top-down mean-intensity image ([`preview`]).
//!
//! **Determinism.** Everything derives from the seed; scan lines have their own generators
//! and are merged in a fixed order, so the files are byte-identical for any thread count.
//!
//! **Speed.** Lines are cast in parallel (rayon) in chunks of 64 lines and streamed to the
//! writer; memory is bounded by a chunk. About 2–3 M pulses/s per core.

pub mod drive;
pub mod intensity;
pub mod las_out;
pub mod markings;
pub mod objects;
pub mod preview;
pub mod road;
pub mod scanner;
pub mod scene;
pub mod surface;

use crate::pipeline::types::Crs;
use anyhow::{Context, Result};
use markings::{MarkingIndex, Standard};
use objects::ObjectIndex;
use rayon::prelude::*;
use scanner::{ScanConfig, SimPoint, World};
use std::path::Path;
use std::time::Instant;
use surface::Ground;

/// EPSG code of the simulated surveys (WGS 84 / UTM zone 50N).
pub const EPSG: u16 = 32650;

/// Options of one simulation.
#[derive(Clone, Debug)]
pub struct SimOptions {
    pub scene: String,
    pub seed: u64,
    pub length_m: Option<f64>,
    /// Number of tiles (1 = a single `points.las`).
    pub tiles: usize,
    pub heads: Option<usize>,
    pub standard: Standard,
    pub points_per_s: f64,
    pub lines_per_s: f64,
    pub max_range_m: f64,
    /// Write `preview.png` with this pixel size (m).
    pub preview_px_m: Option<f64>,
}

impl Default for SimOptions {
    fn default() -> Self {
        SimOptions {
            scene: "highway".into(),
            seed: 1,
            length_m: None,
            tiles: 1,
            heads: None,
            standard: Standard::GB,
            points_per_s: 500_000.0,
            lines_per_s: 200.0,
            max_range_m: 100.0,
            preview_px_m: None,
        }
    }
}

impl SimOptions {
    pub fn validate(&self) -> Result<(), String> {
        if let Some(l) = self.length_m
            && !(5.0..=20_000.0).contains(&l)
        {
            return Err(format!("length must be within 5..20000 m, got {l}"));
        }
        if !(1..=999).contains(&self.tiles) {
            return Err(format!("tiles must be within 1..999, got {}", self.tiles));
        }
        if !(1_000.0..=5_000_000.0).contains(&self.points_per_s) {
            return Err(format!(
                "points per second must be within 1e3..5e6, got {}",
                self.points_per_s
            ));
        }
        if !(10.0..=1000.0).contains(&self.lines_per_s) || self.points_per_s / self.lines_per_s < 16.0 {
            return Err(format!(
                "lines per second must be within 10..1000 with at least 16 pulses per line, got {}",
                self.lines_per_s
            ));
        }
        if !(5.0..=1000.0).contains(&self.max_range_m) {
            return Err(format!(
                "max range must be within 5..1000 m, got {}",
                self.max_range_m
            ));
        }
        if let Some(px) = self.preview_px_m
            && !(0.01..=5.0).contains(&px)
        {
            return Err(format!("preview pixel must be within 0.01..5 m, got {px}"));
        }
        Ok(())
    }
}

/// What a simulation produced.
#[derive(Clone, Debug)]
pub struct Summary {
    pub points: u64,
    pub tiles: Vec<(String, u64)>,
    pub duration_s: f64,
    pub markings: usize,
    pub lane_lines: usize,
    pub paint_points: u64,
    pub elapsed_s: f64,
}

/// Run a simulation and write its files into `out` (created if missing).
pub fn simulate(opt: &SimOptions, out: &Path) -> Result<Summary> {
    opt.validate().map_err(anyhow::Error::msg)?;
    let started = Instant::now();
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let sc_opt = scene::SceneOptions {
        seed: opt.seed,
        length_m: opt.length_m,
        standard: opt.standard,
        heads: opt.heads,
    };
    let mut sc = scene::build(&opt.scene, &sc_opt).map_err(anyhow::Error::msg)?;
    let road = &sc.road;
    let (s_lo, s_hi) = sc.s_range;
    let objects = ObjectIndex::new(road, std::mem::take(&mut sc.objects), s_lo, s_hi);
    let mindex = MarkingIndex::new(road, &sc.marks.markings, s_lo, s_hi);
    let to_s = |x: f64, y: f64| road.to_sd(x, y).0;
    sc.refl.index(&to_s, s_lo, s_hi);
    let scan = ScanConfig {
        lines_per_s: opt.lines_per_s,
        points_per_s: opt.points_per_s,
        max_range_m: opt.max_range_m,
        ..ScanConfig::default()
    };
    let world = World {
        seed: opt.seed,
        road,
        ground: Ground {
            road,
            profile: sc.profile.as_ref(),
        },
        objects: &objects,
        moving: &sc.moving,
        markings: &sc.marks.markings,
        mindex: &mindex,
        refl: &sc.refl,
        radio: intensity::Radiometry::default(),
        drive: &sc.drive,
        scan,
        heads: &sc.heads,
    };
    let drive = &sc.drive;
    let duration = drive.duration();
    let n_lines = (duration * scan.lines_per_s).ceil() as u64;
    let tile_ends: Vec<f64> = (1..opt.tiles)
        .map(|k| drive.time_at(drive.s_start + drive.length_m * k as f64 / opt.tiles as f64))
        .collect();
    let mut sink = las_out::LasSink::new(out, sc.origin, drive.t0, tile_ends, EPSG)?;
    let mut preview = opt.preview_px_m.map(|px| {
        let mut b = [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY];
        let n = (drive.length_m / 2.0).ceil() as usize;
        for i in 0..=n {
            let s = drive.s_start - 15.0 + (drive.length_m + 30.0) * i as f64 / n as f64;
            for d in [-30.0, 30.0] {
                let p = road.to_xy(s, d);
                b = [b[0].min(p[0]), b[1].min(p[1]), b[2].max(p[0]), b[3].max(p[1])];
            }
        }
        preview::Preview::new(b, px)
    });
    let mut counts = vec![0u64; sc.marks.markings.len()];
    let nh = sc.heads.len();
    let chunk = 64u64;
    let mut carry: Vec<SimPoint> = Vec::new();
    let mut total = 0u64;
    let mut k0 = 0u64;
    while k0 < n_lines {
        let k1 = (k0 + chunk).min(n_lines);
        let jobs: Vec<(usize, u64)> = (k0..k1).flat_map(|k| (0..nh).map(move |h| (h, k))).collect();
        let lines: Vec<Vec<SimPoint>> = jobs.par_iter().map(|&(h, k)| world.scan_line(h, k)).collect();
        let mut pts: Vec<SimPoint> = std::mem::take(&mut carry);
        for l in lines {
            pts.extend(l);
        }
        if nh > 1 {
            pts.sort_by(|a, b| a.t.total_cmp(&b.t).then(a.head.cmp(&b.head)));
            if k1 < n_lines {
                let t_end = k1 as f64 / scan.lines_per_s;
                let cut = pts.partition_point(|p| p.t < t_end);
                carry = pts.split_off(cut);
            }
        }
        for p in &pts {
            if p.label > 0 {
                counts[p.label as usize - 1] += 1;
            }
        }
        if let Some(pv) = preview.as_mut() {
            pv.add(&pts);
        }
        total += pts.len() as u64;
        sink.push(&pts)?;
        k0 = k1;
    }
    let tiles = sink.finish()?;

    // Trajectory at 100 Hz.
    let n_rows = (duration * 100.0).ceil() as usize;
    let rows: Vec<las_out::TrajRow> = (0..=n_rows)
        .map(|i| {
            let t = (i as f64 * 0.01).min(duration);
            let stt = drive.state(t, road, &world.ground);
            las_out::TrajRow {
                t,
                pos: stt.pos,
                heading_deg: markings::compass_deg(stt.yaw),
                roll_deg: stt.roll.to_degrees(),
                pitch_deg: stt.pitch.to_degrees(),
            }
        })
        .collect();
    las_out::write_trajectory(&out.join("trajectory.csv"), &rows, sc.origin, drive.t0)?;

    // Truth: the markings the survey saw (at least one point on their paint), numbered in
    // order; the labels are renumbered to match.
    let (kept, kept_counts, lanes, map) =
        markings::keep_seen(&sc.marks.markings, &sc.marks.lane_lines, &counts);
    renumber_labels(&out.join("labels.bin"), &map)?;
    let crs = Crs {
        epsg: Some(u32::from(EPSG)),
        wkt: crs_definitions::from_code(EPSG).map(|d| d.wkt.to_string()),
    };
    let ex = markings::truth(road, &kept, &lanes, &kept_counts, sc.origin, crs);
    let gj = crate::pipeline::geojson::to_native(&ex);
    let truth_path = out.join("truth.geojson");
    std::fs::write(&truth_path, serde_json::to_vec(&gj)?)
        .with_context(|| format!("writing {}", truth_path.display()))?;
    if let Some(pv) = &preview {
        pv.write(&out.join("preview.png"))?;
    }
    let paint_points: u64 = kept_counts.iter().sum();
    let summary = Summary {
        points: total,
        tiles,
        duration_s: duration,
        markings: ex.markings.len(),
        lane_lines: ex.lane_lines.len(),
        paint_points,
        elapsed_s: started.elapsed().as_secs_f64(),
    };
    let meta = serde_json::json!({
        "scene": opt.scene, "seed": opt.seed, "standard": opt.standard.name,
        "length_m": drive.length_m, "heads": nh, "points_per_s_per_head": opt.points_per_s,
        "lines_per_s": opt.lines_per_s, "max_range_m": opt.max_range_m,
        "duration_s": duration, "gps_time_start": drive.t0, "epsg": EPSG,
        "points": total, "paint_points": paint_points,
        "tiles": summary.tiles.iter().map(|(n, c)| serde_json::json!({"file": n, "points": c})).collect::<Vec<_>>(),
        "markings": ex.markings.len(), "lane_lines": ex.lane_lines.len(),
        "labels": "labels.bin: u32 LE per point in file order (tiles in order); 0 = not paint, k = marking m{k}",
    });
    std::fs::write(out.join("summary.json"), serde_json::to_vec_pretty(&meta)?)?;
    Ok(summary)
}

/// Rewrite `labels.bin` with marking indices mapped through `map` (old → new, 0-based).
fn renumber_labels(path: &Path, map: &[Option<usize>]) -> Result<()> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let mut out = Vec::with_capacity(bytes.len());
    for c in bytes.chunks_exact(4) {
        let l = u32::from_le_bytes([c[0], c[1], c[2], c[3]]);
        let n = match l {
            0 => 0,
            k => map[k as usize - 1].map_or(0, |j| j as u32 + 1),
        };
        out.extend_from_slice(&n.to_le_bytes());
    }
    std::fs::write(path, out).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}
