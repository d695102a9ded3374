//! The pipeline hook of the learned classifier: names the candidates the geometric rules
//! could not decide.
//!
//! # What
//! [`refine`] takes the classify stage's candidates and, for each one left `unknown` or
//! classified with a confidence below [`Params::decisive_confidence`], asks the network.
//! Decisive geometric results (long solid lines, stop lines, crosswalk stripes the rules are
//! sure of) are left alone: the rules are exact there and the network is not needed.
//!
//! # Algorithm
//! 1. Select the non-decisive candidates; build a [`ClusterPoints`] view of each (its point
//!    indices into the marking cloud and the driving direction at its centre, which the
//!    classify stage already computed).
//! 2. [`Classifier::classify`] prepares features and runs the network in batches on the rayon
//!    pool, each batch with its own ONNX Runtime session taken from the classifier's pool
//!    (sessions are never shared between threads).
//! 3. Per candidate, with `p` the top probability and the model's calibrated unknown threshold:
//!    - network says a class with `p` ≥ threshold: that class, confidence `p` (a geometric
//!      class with low confidence is overruled; when both agree the larger confidence stays);
//!    - network below the threshold (or says `unknown`): the candidate keeps its geometric
//!      class; an `unknown` candidate gets confidence = the network's `unknown` confidence.
//!
//! # Parameters
//! [`Params`]: `mode` (`auto`: run when ONNX Runtime is installed, otherwise leave the
//! candidates unchanged with a warning; `on`: a missing runtime is an error; `off`),
//! `decisive_confidence` (default 0.5: below it a geometric class is re-examined).
//!
//! # Complexity
//! O(m·n) feature preparation per selected cluster of m points (n = 256), plus one network
//! evaluation per cluster (≈ 4 M multiply-adds); memory O(batch · n) per worker.

use serde::{Deserialize, Serialize};

use super::{Classifier, ClusterPoints};
use crate::pipeline::PipelineError;
use crate::pipeline::classify::Candidate;
use crate::pipeline::types::{MarkingClass, PointCloud};

/// When the learned classifier runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    /// Run when ONNX Runtime can be loaded; otherwise warn and keep the geometric classes.
    #[default]
    Auto,
    /// Always run; a missing runtime or model is an error.
    On,
    /// Never run.
    Off,
}

/// Parameters of the learned refinement (JSON object `learned` in the job parameters).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Params {
    /// `auto` (default), `on` or `off`.
    pub mode: Mode,
    /// Candidates whose geometric confidence is below this are re-examined (0..=1).
    pub decisive_confidence: f64,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            mode: Mode::Auto,
            decisive_confidence: 0.5,
        }
    }
}

impl Params {
    pub fn validate(&self) -> Result<(), String> {
        crate::pipeline::pavement::check_range("decisive_confidence", self.decisive_confidence, 0.0, 1.0)
    }
}

/// What [`refine`] did (for logs and the bench).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RefineStats {
    /// Candidates sent to the network.
    pub examined: usize,
    /// Candidates whose class changed.
    pub reclassified: usize,
}

/// Reclassify the non-decisive candidates with the shared built-in model (see module docs).
pub fn refine(
    candidates: &mut [Candidate],
    cloud: &PointCloud,
    params: &Params,
) -> Result<RefineStats, PipelineError> {
    if params.mode == Mode::Off {
        return Ok(RefineStats::default());
    }
    let classifier = match Classifier::shared() {
        Ok(c) => c,
        Err(e) if params.mode == Mode::Auto => {
            warn_once(&e);
            return Ok(RefineStats::default());
        }
        Err(e) => return Err(e),
    };
    refine_with(classifier, candidates, cloud, params.decisive_confidence)
}

/// [`refine`] with an explicit classifier.
pub fn refine_with(
    classifier: &Classifier,
    candidates: &mut [Candidate],
    cloud: &PointCloud,
    decisive_confidence: f64,
) -> Result<RefineStats, PipelineError> {
    let selected: Vec<usize> = candidates
        .iter()
        .enumerate()
        .filter(|(_, c)| {
            !c.indices.is_empty() && (c.class == MarkingClass::Unknown || c.confidence < decisive_confidence)
        })
        .map(|(i, _)| i)
        .collect();
    if selected.is_empty() {
        return Ok(RefineStats::default());
    }
    let views: Vec<ClusterPoints<'_>> = selected
        .iter()
        .map(|&i| ClusterPoints {
            cloud,
            indices: &candidates[i].indices,
            direction: candidates[i].shape.driving_direction,
        })
        .collect();
    let preds = classifier.classify(&views)?;
    drop(views);
    let threshold = classifier.info().unknown_threshold;
    let mut stats = RefineStats {
        examined: selected.len(),
        reclassified: 0,
    };
    for (&i, pred) in selected.iter().zip(&preds) {
        let c = &mut candidates[i];
        let top = pred.prob(pred.class) as f64;
        if pred.class != MarkingClass::Unknown && top >= threshold as f64 {
            if pred.class == c.class {
                c.confidence = c.confidence.max(top);
            } else {
                c.class = pred.class;
                c.confidence = top;
                stats.reclassified += 1;
            }
        } else if c.class == MarkingClass::Unknown {
            c.confidence = pred.confidence as f64;
        }
    }
    Ok(stats)
}

fn warn_once(e: &PipelineError) {
    static WARNED: std::sync::Once = std::sync::Once::new();
    WARNED.call_once(|| {
        tracing::warn!("learned marking classifier skipped (geometric classes kept): {e}");
    });
}
