//! `roadmark bench`: pipeline throughput per stage, end to end, and peak memory.
//!
//! Runs the whole pipeline once on a drive — the given `--points`/`--trajectory`, or a
//! simulated drive of `--length-m` metres written by `roadmark simulate` in a child
//! process (so the simulator's memory does not count) — and prints, per stage, the
//! wall-clock seconds and the points per second (points read for `read`, points the chunk
//! stages processed for the others), the end-to-end rate over the points read, and the
//! peak resident memory (`VmHWM` of /proc/self/status). Numbers, not assertions: this is
//! how the ≥ 5 M points/s and ≤ 2 GB targets are checked.

use super::extract::load_params;
use crate::pipeline::driver::{self, STAGES};
use crate::pipeline::{Inputs, NoProgress};
use anyhow::{Context, bail};
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
    let bytes: u64 = inputs
        .points
        .iter()
        .map(|p| std::fs::metadata(p).map(|m| m.len()).unwrap_or(0))
        .sum();
    let (ex, stats) = driver::run_with_stats(&inputs, &params, &NoProgress)?;
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
    match peak_rss_bytes() {
        Some(b) => println!("peak RSS: {:.1} MB", b as f64 / 1048576.0),
        None => println!("peak RSS: unknown (no /proc/self/status)"),
    }
    Ok(())
}

struct RemoveOnDrop(PathBuf);

impl Drop for RemoveOnDrop {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}
