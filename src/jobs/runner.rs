//! What a worker runs for a claimed job: the pipeline, behind a trait.
//!
//! The shipped [`PipelineRunner`] calls [`crate::pipeline::run`]. The trait exists for the
//! integration tests of the queue: a runner that blocks until released (to test leases,
//! cancellation and crash recovery) or fails on demand isolates the queue from the pipeline's
//! accuracy and speed. End-to-end tests use the real runner on real files.
//!
//! `run` is synchronous and CPU-bound: the worker calls it on the rayon pool, never on the
//! async runtime.

use crate::pipeline::params::ValidParams;
use crate::pipeline::{Extraction, Inputs, PipelineError, Progress};

pub trait Runner: Send + Sync + 'static {
    /// Process one job. Must check `progress.is_cancelled()` at safe points (stage boundaries)
    /// and return [`PipelineError::Cancelled`] when it is set.
    fn run(
        &self,
        inputs: &Inputs,
        params: &ValidParams,
        progress: &dyn Progress,
    ) -> Result<Extraction, PipelineError>;
}

/// The real extraction pipeline.
#[derive(Clone, Copy, Debug, Default)]
pub struct PipelineRunner;

impl Runner for PipelineRunner {
    fn run(
        &self,
        inputs: &Inputs,
        params: &ValidParams,
        progress: &dyn Progress,
    ) -> Result<Extraction, PipelineError> {
        crate::pipeline::run(inputs, params, progress)
    }
}
