//! One module per `roadmark` subcommand: each has an `Args` (clap) and a `run`.

/// `roadmark bench`: pipeline throughput per stage and peak memory.
pub mod bench;
/// `roadmark bench-read`: LAS/LAZ reading throughput.
pub mod bench_read;
/// `roadmark evaluate`: score a result against truth.
pub mod evaluate;
/// `roadmark export-clusters`: training set for the learned classifier.
pub mod export_clusters;
/// `roadmark extract`: the whole pipeline on local files.
pub mod extract;
/// `roadmark serve`: the HTTP API and its workers.
pub mod serve;
/// `roadmark simulate`: a synthetic survey.
pub mod simulate;
