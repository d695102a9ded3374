//! The `roadmark` binary: parse the command line, start telemetry, run the chosen command.

use clap::{Parser, Subcommand};
use roadmark::commands;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "roadmark",
    version,
    about = "Road markings from mobile laser scanning drives"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the whole pipeline on local files and write GeoJSON.
    Extract(commands::extract::Args),
    /// Start the HTTP API and its workers.
    Serve(commands::serve::Args),
    /// Write a synthetic survey (points.las, trajectory.csv, truth.geojson).
    Simulate(commands::simulate::Args),
    /// Score a result GeoJSON against a truth GeoJSON.
    Evaluate(commands::evaluate::Args),
    /// Measure LAS/LAZ reading throughput.
    BenchRead(commands::bench_read::Args),
    /// Measure pipeline throughput per stage and peak memory.
    Bench(commands::bench::Args),
    /// Export marking clusters from simulated surveys as a classifier training set.
    ExportClusters(commands::export_clusters::Args),
}

fn main() -> ExitCode {
    // Before any thread starts: the pipeline's per-chunk columns reuse freed memory.
    roadmark::memory::tune_allocator();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Extract(a) => commands::extract::run(a),
        Command::Serve(a) => commands::serve::run(a),
        Command::Simulate(a) => commands::simulate::run(a),
        Command::Evaluate(a) => commands::evaluate::run(a),
        Command::BenchRead(a) => commands::bench_read::run(a),
        Command::Bench(a) => commands::bench::run(a),
        Command::ExportClusters(a) => commands::export_clusters::run(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("roadmark: {e:#}");
            ExitCode::FAILURE
        }
    }
}
