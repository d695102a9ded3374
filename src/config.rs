//! Service configuration: every setting is a `roadmark serve` flag and an environment variable.
//!
//! The defaults run a complete service from a fresh checkout: SQLite database and files under
//! `./data`, HTTP on `127.0.0.1:8080`, two concurrent jobs. Durations carry their unit in the
//! name (`lease_ms`). [`Config::validate`] rejects inconsistent combinations (a heartbeat slower
//! than the lease it must keep alive) before anything starts; [`Config::for_tests`] is a small,
//! fast configuration on port 0 for the integration tests.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Log output format.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum LogFormat {
    /// Human-readable lines.
    Text,
    /// One JSON object per line (for log collectors).
    Json,
}

#[derive(Clone, Debug, clap::Args)]
pub struct Config {
    /// Address and port of the HTTP API.
    #[arg(long, env = "ROADMARK_BIND", default_value = "127.0.0.1:8080")]
    pub bind: SocketAddr,

    /// Directory holding the SQLite database, the uploads and the results (created if missing).
    #[arg(long, env = "ROADMARK_DATA_DIR", default_value = "./data")]
    pub data_dir: PathBuf,

    /// Jobs processed concurrently.
    #[arg(long, env = "ROADMARK_WORKERS", default_value_t = 2)]
    pub workers: usize,

    /// Threads of the pipeline's rayon pool (0: one per core; never fewer than --workers).
    #[arg(long, env = "ROADMARK_THREADS", default_value_t = 0)]
    pub threads: usize,

    /// Largest accepted upload, in bytes (larger bodies get 413).
    #[arg(long, env = "ROADMARK_MAX_UPLOAD_BYTES", default_value_t = 8 << 30)]
    pub max_upload_bytes: u64,

    /// How long a claimed job stays leased without a heartbeat before another worker may take it.
    #[arg(long, env = "ROADMARK_LEASE_MS", default_value_t = 30_000)]
    pub lease_ms: u64,

    /// Interval between lease extensions of a running job (well below --lease-ms).
    #[arg(long, env = "ROADMARK_HEARTBEAT_MS", default_value_t = 10_000)]
    pub heartbeat_ms: u64,

    /// Smallest interval between two progress writes of one job (throttling).
    #[arg(long, env = "ROADMARK_PROGRESS_MS", default_value_t = 500)]
    pub progress_ms: u64,

    /// How often an idle worker looks for due jobs (new jobs wake a worker at once).
    #[arg(long, env = "ROADMARK_POLL_MS", default_value_t = 1_000)]
    pub poll_ms: u64,

    /// Attempts per job, counting the first; only transient (I/O) failures are retried.
    #[arg(long, env = "ROADMARK_MAX_ATTEMPTS", default_value_t = 3)]
    pub max_attempts: u32,

    /// Delay before the first retry; doubled for every further attempt.
    #[arg(long, env = "ROADMARK_RETRY_BASE_MS", default_value_t = 5_000)]
    pub retry_base_ms: u64,

    /// Upper bound of the retry delay.
    #[arg(long, env = "ROADMARK_RETRY_MAX_MS", default_value_t = 600_000)]
    pub retry_max_ms: u64,

    /// On SIGINT/SIGTERM, how long running jobs get to reach a stage boundary and be released.
    #[arg(long, env = "ROADMARK_SHUTDOWN_GRACE_MS", default_value_t = 30_000)]
    pub shutdown_grace_ms: u64,

    /// Log format (the level comes from RUST_LOG, default `info`).
    #[arg(long, env = "ROADMARK_LOG_FORMAT", value_enum, default_value = "text")]
    pub log_format: LogFormat,
}

impl Config {
    /// A fast configuration for tests: port 0, the given data directory, short timings.
    pub fn for_tests(data_dir: &Path) -> Config {
        Config {
            bind: SocketAddr::from(([127, 0, 0, 1], 0)),
            data_dir: data_dir.to_path_buf(),
            workers: 2,
            threads: 2,
            max_upload_bytes: 64 << 20,
            lease_ms: 10_000,
            heartbeat_ms: 100,
            progress_ms: 20,
            poll_ms: 50,
            max_attempts: 3,
            retry_base_ms: 10,
            retry_max_ms: 100,
            shutdown_grace_ms: 5_000,
            log_format: LogFormat::Text,
        }
    }

    /// Reject settings that cannot work together.
    pub fn validate(&self) -> Result<(), String> {
        if self.workers == 0 {
            return Err("--workers must be at least 1".into());
        }
        if self.max_attempts == 0 {
            return Err("--max-attempts must be at least 1".into());
        }
        if self.max_upload_bytes == 0 {
            return Err("--max-upload-bytes must be positive".into());
        }
        if self.lease_ms == 0 || self.heartbeat_ms == 0 || self.progress_ms == 0 || self.poll_ms == 0 {
            return Err("--lease-ms, --heartbeat-ms, --progress-ms and --poll-ms must be positive".into());
        }
        // A heartbeat must land at least twice per lease, or a slow database write loses the job.
        if self.heartbeat_ms * 2 > self.lease_ms {
            return Err(format!(
                "--heartbeat-ms ({}) must be at most half of --lease-ms ({})",
                self.heartbeat_ms, self.lease_ms
            ));
        }
        if self.retry_base_ms > self.retry_max_ms {
            return Err("--retry-base-ms must not exceed --retry-max-ms".into());
        }
        Ok(())
    }

    /// Threads of the rayon pool: the configured count (or one per core), at least one per worker
    /// so that every claimed job runs at once instead of waiting inside the pool.
    pub fn pool_threads(&self) -> usize {
        let base = if self.threads == 0 {
            std::thread::available_parallelism().map_or(1, |n| n.get())
        } else {
            self.threads
        };
        base.max(self.workers)
    }

    pub fn lease(&self) -> Duration {
        Duration::from_millis(self.lease_ms)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        config: Config,
    }

    #[test]
    fn defaults_match_the_contract() {
        let cli = Cli::try_parse_from(["roadmark"]).unwrap();
        assert_eq!(cli.config.bind, "127.0.0.1:8080".parse().unwrap());
        assert_eq!(cli.config.data_dir, PathBuf::from("./data"));
        cli.config.validate().unwrap();
        Config::for_tests(Path::new("/tmp")).validate().unwrap();
    }

    #[test]
    fn flags_override_defaults_and_bad_combinations_are_rejected() {
        let cli = Cli::try_parse_from(["roadmark", "--bind", "0.0.0.0:9000", "--lease-ms", "1000"]).unwrap();
        assert_eq!(cli.config.bind.port(), 9000);
        let err = cli.config.validate().unwrap_err();
        assert!(err.contains("heartbeat"), "{err}");
        assert!(Cli::try_parse_from(["roadmark", "--bind", "not-an-address"]).is_err());
    }
}
