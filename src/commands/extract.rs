//! `roadmark extract`: the whole pipeline on local files, GeoJSON out.
//!
//! Parameters are read and validated before any point is read; inputs are checked (headers,
//! trajectory) before the heavy work starts. On a terminal a progress bar follows the
//! stages; at the end one summary line goes to stdout. Errors become one line on stderr
//! naming the file and the problem (see `main.rs`), with a non-zero exit status.

use crate::pipeline::driver::{self, RunStats};
use crate::pipeline::geojson::{self, CrsMode};
use crate::pipeline::learned::Classifier;
use crate::pipeline::learned::refine::Mode;
use crate::pipeline::params::{Params, ValidParams};
use crate::pipeline::{Extraction, Inputs, MarkingClass, Progress};
use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// Output coordinates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum CrsArg {
    /// The input CRS.
    Native,
    /// Longitude/latitude (RFC 7946); the default whenever the input CRS is known.
    Wgs84,
}

#[derive(Debug, clap::Args)]
pub struct Args {
    /// A LAS/LAZ tile of the drive (repeat for several tiles).
    #[arg(long = "points", required = true, value_name = "TILE")]
    pub points: Vec<PathBuf>,
    /// The trajectory table (time, x, y[, z, heading, …]).
    #[arg(long, value_name = "FILE")]
    pub trajectory: PathBuf,
    /// Where to write the marking GeoJSON.
    #[arg(long, value_name = "OUT.geojson")]
    pub output: PathBuf,
    /// Output coordinates (default: wgs84 when the input CRS is known, else native).
    #[arg(long, value_enum)]
    pub crs: Option<CrsArg>,
    /// Pipeline parameters as JSON (one object per stage; every field optional).
    #[arg(long, value_name = "PARAMS.json")]
    pub params: Option<PathBuf>,
}

/// Read and validate a parameter file; the error names the file and the parameter.
pub fn load_params(path: Option<&Path>) -> anyhow::Result<ValidParams> {
    let Some(path) = path else {
        return Params::default().validate().map_err(anyhow::Error::msg);
    };
    let text =
        std::fs::read_to_string(path).map_err(|e| anyhow::anyhow!("{}: cannot read: {e}", path.display()))?;
    let parsed = Params::from_json(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    parsed
        .validate()
        .map_err(|e| anyhow::anyhow!("{}: invalid parameter {e}", path.display()))
}

/// A progress bar on stderr when it is a terminal; nothing otherwise.
pub struct Bar {
    bar: ProgressBar,
    stage: Mutex<String>,
}

impl Bar {
    pub fn new() -> Self {
        let bar = if std::io::stderr().is_terminal() {
            let b = ProgressBar::with_draw_target(Some(1000), ProgressDrawTarget::stderr());
            b.set_style(
                ProgressStyle::with_template("{spinner} {msg:10} [{bar:40}] {percent:>3}% {elapsed}")
                    .expect("static template")
                    .progress_chars("=> "),
            );
            b
        } else {
            ProgressBar::hidden()
        };
        Self {
            bar,
            stage: Mutex::new(String::new()),
        }
    }

    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

impl Default for Bar {
    fn default() -> Self {
        Self::new()
    }
}

impl Progress for Bar {
    fn report(&self, stage: &str, fraction: f64) {
        let mut s = self.stage.lock().unwrap_or_else(|e| e.into_inner());
        if *s != stage {
            *s = stage.to_string();
            self.bar.set_message(stage.to_string());
        }
        self.bar.set_position((fraction.clamp(0.0, 1.0) * 1000.0) as u64);
    }
}

/// One line: markings per class, lane lines, points, seconds, points/s.
pub fn summary_line(ex: &Extraction, stats: &RunStats, output: &Path) -> String {
    let mut per_class: Vec<String> = MarkingClass::ALL
        .iter()
        .filter_map(|c| {
            let n = ex.markings.iter().filter(|m| m.class == *c).count();
            (n > 0).then(|| format!("{n} {}", c.as_str()))
        })
        .collect();
    if per_class.is_empty() {
        per_class.push("none".into());
    }
    let rate = stats.points_read as f64 / stats.total_seconds.max(1e-9);
    format!(
        "{} markings ({}), {} lane lines, {} points in {:.1} s ({:.2} M points/s) -> {}",
        ex.markings.len(),
        per_class.join(", "),
        ex.lane_lines.len(),
        stats.points_read,
        stats.total_seconds,
        rate / 1e6,
        output.display()
    )
}

pub fn run(args: Args) -> anyhow::Result<()> {
    // Parameters first: a typo must not cost a pipeline run.
    let params = load_params(args.params.as_deref())?;
    check_classifier(&params)?;
    if let Some(dir) = args.output.parent().filter(|d| !d.as_os_str().is_empty())
        && !dir.is_dir()
    {
        bail!("{}: the output directory does not exist", dir.display());
    }
    let inputs = Inputs {
        points: args.points.clone(),
        trajectory: args.trajectory.clone(),
    };
    let bar = Bar::new();
    let result = driver::run_with_stats(&inputs, &params, &bar);
    bar.finish();
    let (ex, stats) = result?;
    let mode = match args.crs {
        Some(CrsArg::Native) => CrsMode::Native,
        Some(CrsArg::Wgs84) => CrsMode::Wgs84,
        None if ex.crs.is_some() => CrsMode::Wgs84,
        None => CrsMode::Native,
    };
    write_output(&args.output, &ex, mode)
        .with_context(|| format!("{}: cannot write", args.output.display()))?;
    println!("{}", summary_line(&ex, &stats, &args.output));
    Ok(())
}

/// The learned classifier, loaded before any point is read: with `learned.mode` `on` a
/// missing ONNX Runtime (or a model it cannot run) is an error; with `auto` the run goes on
/// with the geometric classes alone (no arrows, no diamonds), and says so on stderr with
/// the install hint, instead of only in a log nobody reads from the command line.
fn check_classifier(params: &ValidParams) -> anyhow::Result<()> {
    let mode = params.learned.mode;
    if mode == Mode::Off {
        return Ok(());
    }
    match Classifier::shared() {
        Ok(_) => Ok(()),
        Err(e) if mode == Mode::On => Err(e).context("learned.mode is \"on\""),
        Err(e) => {
            eprintln!(
                "roadmark: warning: the learned marking classifier is off for this run, so \
                 arrows and diamonds stay `unknown` ({e}); set learned.mode to \"off\" to \
                 silence this or to \"on\" to make it an error"
            );
            Ok(())
        }
    }
}

pub(crate) fn write_output(path: &Path, ex: &Extraction, mode: CrsMode) -> anyhow::Result<()> {
    geojson::write_geojson(path, ex, mode)?;
    Ok(())
}
