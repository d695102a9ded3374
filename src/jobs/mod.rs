//! The job queue (SQLite) and the workers that run the pipeline for it.
//!
//! - [`queue`]: every SQL statement of the service — uploads, enqueue, atomic claim, leases with
//!   fenced writes, retries, cancellation.
//! - [`worker`]: the claim → run → complete loop, heartbeat, throttled progress, graceful stop.
//! - [`runner`]: the [`runner::Runner`] trait between a worker and the pipeline.
//! - [`clock`]: the injectable clock the queue measures leases and delays with.

/// Injectable time source and RFC 3339 formatting.
pub mod clock;
/// All SQL: uploads and the job queue.
pub mod queue;
/// The pipeline behind a trait, so the queue can be tested in isolation.
pub mod runner;
/// Claim → run → complete, heartbeat, progress.
pub mod worker;

pub use clock::{Clock, ManualClock, SystemClock};
pub use queue::{JobRecord, JobStatus, Queue};
pub use runner::{PipelineRunner, Runner};
