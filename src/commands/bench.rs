//! `roadmark bench`: pipeline throughput per stage, end to end, and peak memory.
//!
//! Runs the whole pipeline once on a drive — the given `--points`/`--trajectory`, or a
//! simulated drive of `--length-m` metres written by `roadmark simulate` in a child
//! process (so the simulator's memory does not count) — and prints, per stage, the
//! wall-clock seconds and the points per second (points read for `read`, points the chunk
//! stages processed for the others), the end-to-end rate over the points read, and the
//! peak resident memory (`VmHWM` of /proc/self/status) of the pipeline, read as soon as it
//! returns: scoring against labels re-reads every tile, so its own peak is printed apart.
//! Numbers, not assertions: this is how the ≥ 5 M points/s and ≤ 2 GB targets are checked.

use super::extract::load_params;
use crate::pipeline::driver::{self, STAGES};
use crate::pipeline::{Inputs, NoProgress, PointCloud, io};
use anyhow::{Context, bail};
use std::collections::HashMap;
use std::path::PathBuf;
use std::process::Command;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Tiles of an existing drive (otherwise a drive is simulated).
    #[arg(long = "points", value_name = "TILE", requires = "trajectory")]
    pub points: Vec<PathBuf>,
    /// Trajectory of the existing drive.
    #[arg(long, value_name = "FILE")]
    pub trajectory: Option<PathBuf>,
    /// Scene of the simulated drive.
    #[arg(long, default_value = "highway")]
    pub scene: String,
    /// Length of the simulated drive (m).
    #[arg(long, default_value_t = 1000.0)]
    pub length_m: f64,
    /// Seed of the simulated drive.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Keep the simulated drive in this directory (reused when it already holds one).
    #[arg(long, value_name = "DIR")]
    pub keep: Option<PathBuf>,
    /// Pipeline parameters as JSON.
    #[arg(long, value_name = "PARAMS.json")]
    pub params: Option<PathBuf>,
    /// Per-point labels of the tiles (little-endian u32 per point, in file order; the
    /// simulator's `labels.bin`, or SemanticKITTI `.label` files): prints the precision and
    /// recall of the extracted marking points. A simulated drive uses its own labels.
    #[arg(long = "labels", value_name = "FILE")]
    pub labels: Vec<PathBuf>,
    /// With `--labels`: the label value of painted markings (lower 16 bits, e.g. 60 for
    /// SemanticKITTI); by default every label > 0 is paint.
    #[arg(long, value_name = "N")]
    pub label_class: Option<u32>,
    /// Also write the extracted markings here (GeoJSON, for `roadmark evaluate`).
    #[arg(long, value_name = "OUT.geojson")]
    pub output: Option<PathBuf>,
}

/// Peak resident set size in bytes (Linux), when known.
pub fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let params = load_params(args.params.as_deref())?;
    let mut _tmp_guard = None;
    let inputs = if let Some(traj) = &args.trajectory {
        Inputs {
            points: args.points.clone(),
            trajectory: traj.clone(),
        }
    } else {
        let dir = match &args.keep {
            Some(d) => d.clone(),
            None => {
                let d = std::env::temp_dir().join(format!("roadmark-bench-{}", std::process::id()));
                _tmp_guard = Some(RemoveOnDrop(d.clone()));
                d
            }
        };
        let (points, trajectory) = (dir.join("points.las"), dir.join("trajectory.csv"));
        if !(points.is_file() && trajectory.is_file()) {
            std::fs::create_dir_all(&dir).with_context(|| format!("{}: cannot create", dir.display()))?;
            eprintln!(
                "simulating a {} m '{}' drive into {} ...",
                args.length_m,
                args.scene,
                dir.display()
            );
            let exe = std::env::current_exe().context("cannot find the roadmark executable")?;
            let status = Command::new(exe)
                .args([
                    "simulate",
                    "--scene",
                    &args.scene,
                    "--seed",
                    &args.seed.to_string(),
                ])
                .args(["--length-m", &args.length_m.to_string()])
                .arg("--out")
                .arg(&dir)
                .status()
                .context("cannot run roadmark simulate")?;
            if !status.success() {
                bail!("roadmark simulate failed ({status})");
            }
        }
        Inputs {
            points: vec![points],
            trajectory,
        }
    };
    let mut label_files = args.labels.clone();
    if label_files.is_empty() && args.trajectory.is_none() {
        let sim = inputs.points[0].with_file_name("labels.bin");
        if sim.is_file() {
            label_files.push(sim);
        }
    }
    let bytes: u64 = inputs
        .points
        .iter()
        .map(|p| std::fs::metadata(p).map(|m| m.len()).unwrap_or(0))
        .sum();
    let (ex, stats, marks) = if label_files.is_empty() {
        let (ex, stats) = driver::run_with_stats(&inputs, &params, &NoProgress)?;
        (ex, stats, None)
    } else {
        let (ex, stats, m) = driver::run_collecting_with_stats(&inputs, &params, &NoProgress)?;
        (ex, stats, Some(m))
    };
    // The pipeline's own peak: read now, before `point_scores` re-reads every tile (that
    // evaluation would otherwise be what the figure reports).
    let pipeline_peak = peak_rss_bytes();
    let threads = rayon::current_num_threads();
    println!(
        "drive: {} points ({:.0} MB on disk), {} near the trajectory, {} chunks, {} spilled, {} rayon threads",
        stats.points_read,
        bytes as f64 / 1e6,
        stats.points_near_track,
        stats.chunks,
        stats.spilled_points,
        threads
    );
    println!(
        "{:<10} {:>9} {:>14} {:>12}",
        "stage", "seconds", "points", "M points/s"
    );
    for (i, name) in STAGES.iter().enumerate() {
        let pts = match i {
            0 => stats.points_read,
            1..=3 => stats.points_processed,
            _ => stats.marking_points,
        };
        let s = stats.stage_seconds[i];
        println!(
            "{:<10} {:>9.3} {:>14} {:>12.2}",
            name,
            s,
            pts,
            if s > 0.0 {
                pts as f64 / s / 1e6
            } else {
                f64::INFINITY
            }
        );
    }
    println!(
        "end-to-end {:>9.3} {:>14} {:>12.2}",
        stats.total_seconds,
        stats.points_read,
        stats.points_read as f64 / stats.total_seconds.max(1e-9) / 1e6
    );
    println!(
        "result: {} markings, {} lane lines; pavement {} points, marking {} points",
        ex.markings.len(),
        ex.lane_lines.len(),
        stats.pavement_points,
        stats.marking_points
    );
    if let Some(out) = &args.output {
        let mode = if ex.crs.is_some() {
            crate::pipeline::geojson::CrsMode::Wgs84
        } else {
            crate::pipeline::geojson::CrsMode::Native
        };
        super::extract::write_output(out, &ex, mode)
            .with_context(|| format!("{}: cannot write", out.display()))?;
    }
    if let Some(marks) = &marks {
        let (tp, extracted, labelled) = point_scores(&inputs.points, &label_files, args.label_class, marks)?;
        println!(
            "marking points: extracted {extracted}, labelled {labelled}, true {tp}: precision {:.4}, recall {:.4}",
            tp as f64 / extracted.max(1) as f64,
            tp as f64 / labelled.max(1) as f64
        );
    }
    match pipeline_peak {
        Some(b) => println!(
            "peak RSS: {:.1} MB (the pipeline's, before the marking points were scored)",
            b as f64 / 1048576.0
        ),
        None => println!("peak RSS: unknown (no /proc/self/status)"),
    }
    if marks.is_some()
        && let Some(b) = peak_rss_bytes()
    {
        println!("peak RSS with scoring: {:.1} MB", b as f64 / 1048576.0);
    }
    Ok(())
}

/// (true positives, extracted, labelled) of the marking points against per-point labels.
/// Points are matched by their absolute coordinates quantised to 0.1 mm.
fn point_scores(
    tiles: &[PathBuf],
    labels: &[PathBuf],
    class: Option<u32>,
    marks: &PointCloud,
) -> anyhow::Result<(usize, usize, usize)> {
    if labels.len() != tiles.len() {
        bail!(
            "give one --labels file per tile ({} tiles, {} label files)",
            tiles.len(),
            labels.len()
        );
    }
    let key = |x: f64, y: f64, z: f64| {
        let q = |v: f64| (v * 1e4).round() as i64;
        (q(x), q(y), q(z))
    };
    let is_paint = |l: u32| match class {
        Some(c) => l & 0xFFFF == c,
        None => l > 0,
    };
    // Per quantised position: (paint, not paint) counts (duplicates are possible).
    let mut at: HashMap<(i64, i64, i64), (u32, u32)> = HashMap::new();
    let mut labelled = 0;
    for (tile, lf) in tiles.iter().zip(labels) {
        let cloud = io::read_points(&[tile.as_path()])?;
        let bytes = std::fs::read(lf).with_context(|| format!("{}: cannot read", lf.display()))?;
        if bytes.len() != 4 * cloud.len() {
            bail!(
                "{}: {} labels for {} points in {}",
                lf.display(),
                bytes.len() / 4,
                cloud.len(),
                tile.display()
            );
        }
        let o = cloud.origin;
        for (i, b) in bytes.chunks_exact(4).enumerate() {
            let l = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
            let e = at
                .entry(key(cloud.x[i] + o[0], cloud.y[i] + o[1], cloud.z[i] + o[2]))
                .or_default();
            if is_paint(l) {
                labelled += 1;
                e.0 += 1;
            } else {
                e.1 += 1;
            }
        }
    }
    let o = marks.origin;
    let tp = (0..marks.len())
        .filter(|&i| {
            at.get(&key(marks.x[i] + o[0], marks.y[i] + o[1], marks.z[i] + o[2]))
                .is_some_and(|e| e.0 > 0)
        })
        .count();
    Ok((tp, marks.len(), labelled))
}

struct RemoveOnDrop(PathBuf);

impl Drop for RemoveOnDrop {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}
