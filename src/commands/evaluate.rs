//! `roadmark evaluate --truth T --result R [--json]`: score a result GeoJSON against a truth.
//!
//! Prints the table of [`crate::eval::Report::to_text`], or with `--json` the report as JSON
//! (stable field names; see [`crate::eval::Report`]). Both files are read with
//! [`crate::pipeline::geojson::read_geojson`]; a result in WGS84 is reprojected into the
//! truth's CRS before scoring.

use crate::eval::{EvalOptions, evaluate_files};
use anyhow::Context;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Reference GeoJSON (for example the truth.geojson of `roadmark simulate`).
    #[arg(long)]
    pub truth: PathBuf,
    /// GeoJSON to score (for example the output of `roadmark extract`).
    #[arg(long)]
    pub result: PathBuf,
    /// Print the report as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Pixel size of the pixel-level scores (m).
    #[arg(long, default_value_t = EvalOptions::default().pixel_m)]
    pub pixel_m: f64,
    /// Minimum IoU of a matched marking pair.
    #[arg(long, default_value_t = EvalOptions::default().iou_min)]
    pub iou: f64,
    /// Lane-line buffer (m).
    #[arg(long, default_value_t = EvalOptions::default().lane_tol_m)]
    pub lane_tol_m: f64,
    /// Sampling step along lane lines (m).
    #[arg(long, default_value_t = EvalOptions::default().sample_m)]
    pub sample_m: f64,
    /// Tolerance of the length-based solid-line scores (m).
    #[arg(long, default_value_t = EvalOptions::default().solid_tol_m)]
    pub solid_tol_m: f64,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let opts = EvalOptions {
        pixel_m: args.pixel_m,
        iou_min: args.iou,
        lane_tol_m: args.lane_tol_m,
        sample_m: args.sample_m,
        solid_tol_m: args.solid_tol_m,
    };
    let report = evaluate_files(&args.truth, &args.result, &opts)?;
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&report).context("cannot serialise the report")?
        );
    } else {
        print!("{}", report.to_text());
    }
    Ok(())
}
