//! `roadmark simulate`: write a synthetic mobile-mapping survey (see [`crate::sim`]).

use crate::sim::{self, SimOptions, markings::Standard, scene::SCENES};
use anyhow::Context;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Scene: highway, urban_intersection, curved_ramp, dual_head or worn.
    #[arg(long)]
    pub scene: String,
    /// Output directory (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Random seed: the same seed gives byte-identical files.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Drive length in metres (scene default 160–250 m).
    #[arg(long)]
    pub length_m: Option<f64>,
    /// Number of LAS tiles cut by driving distance (1 = a single points.las).
    #[arg(long, default_value_t = 1)]
    pub tiles: usize,
    /// Scanner heads: 1 (cross-section profiler) or 2 (butterfly); default per scene.
    #[arg(long)]
    pub heads: Option<usize>,
    /// Marking standard: gb (China GB 5768) or mutcd (US).
    #[arg(long, default_value = "gb")]
    pub standard: String,
    /// Pulses per second per head.
    #[arg(long, default_value_t = 500_000.0)]
    pub points_per_second: f64,
    /// Scan lines (mirror turns) per second.
    #[arg(long, default_value_t = 200.0)]
    pub lines_per_second: f64,
    /// Maximum range of a return (m).
    #[arg(long, default_value_t = 100.0)]
    pub max_range_m: f64,
    /// Also write preview.png (top-down mean intensity).
    #[arg(long)]
    pub preview: bool,
    /// Pixel size of the preview (m).
    #[arg(long, default_value_t = 0.1)]
    pub preview_px_m: f64,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if !SCENES.contains(&args.scene.as_str()) {
        anyhow::bail!("unknown scene '{}' (known: {})", args.scene, SCENES.join(", "));
    }
    let standard = Standard::parse(&args.standard)
        .with_context(|| format!("unknown standard '{}' (known: gb, mutcd)", args.standard))?;
    let opt = SimOptions {
        scene: args.scene,
        seed: args.seed,
        length_m: args.length_m,
        tiles: args.tiles,
        heads: args.heads,
        standard,
        points_per_s: args.points_per_second,
        lines_per_s: args.lines_per_second,
        max_range_m: args.max_range_m,
        preview_px_m: args.preview.then_some(args.preview_px_m),
    };
    let s = sim::simulate(&opt, &args.out)?;
    println!(
        "{}: {} points ({} on paint) in {} file(s), {:.1} s of driving, {} markings, {} lane lines, {:.1} s",
        args.out.display(),
        s.points,
        s.paint_points,
        s.tiles.len(),
        s.duration_s,
        s.markings,
        s.lane_lines,
        s.elapsed_s
    );
    Ok(())
}
