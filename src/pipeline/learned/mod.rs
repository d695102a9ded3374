//! The learned marking classifier: a PointNet++-style network run by ONNX Runtime.
//!
//! # What
//! Gives every marking cluster a probability per contract class. The geometric rules of the
//! classify stage keep the decisive cases (long solid lines, stop lines, crosswalk stripes);
//! this classifier names the rest (dashes, guidelines, the five arrows, diamonds) and its
//! probability becomes the feature's `confidence`.
//!
//! # Algorithm
//! 1. Each cluster becomes `n` points in its trajectory-aligned local frame, in farthest-point
//!    order ([`features`]).
//! 2. Clusters are cut into batches of [`Classifier::batch_size`]; the batches run in parallel
//!    on the rayon pool. An ONNX Runtime `Session` needs `&mut self` to run, so sessions live
//!    in a pool: a worker takes one (or builds one the first time), runs its batch, and puts it
//!    back. Each session uses one intra-op thread: the parallelism is rayon's.
//! 3. The network (`training/model.py`) groups points around the first 64 and first 16 points
//!    of the input (the FPS prefixes) with k-nearest neighbours, two set-abstraction levels and
//!    a global one, and ends in a softmax over the classes named in the model's metadata.
//!    The shipped graph averages the probabilities of the cluster, the cluster turned by
//!    180° and both mirrored across the driving direction (left/right arrow classes swapped
//!    back), so its answer is exactly invariant under the road's symmetries (the features and
//!    their farthest-point order are equivariant under them). A prediction whose top probability is below the calibrated threshold
//!    (`roadmark.unknown_threshold` in the metadata) is `unknown`.
//!
//! # Model file contract (metadata keys of the ONNX model)
//! - `roadmark.classes`: comma-separated contract class names, in output order;
//! - `roadmark.points`: points per cluster `n`;
//! - `roadmark.features`: the feature recipe version, must equal [`features::FEATURE_VERSION`];
//! - `roadmark.unknown_threshold`: optional, default 0.5.
//!
//! Input `points` f32 `[batch, n, 4]`, output `probs` f32 `[batch, classes]`.
//!
//! # Runtime
//! ONNX Runtime is loaded at run time ([`runtime`]); a missing library is a
//! [`PipelineError::Model`] that says how to install it, never a panic.
//!
//! # Reference
//! Qi et al., PointNet++ (NeurIPS 2017); Yao et al. 2019 and 2021 classify marking clusters
//! with it (see `papers/README.md`). Training recipe and held-out scores: `models/README.md`.
//!
//! # Complexity
//! Per cluster O(m·n) feature preparation plus four network evaluations (≈ 0.3 M
//! multiply-adds per point each); memory O(batch · n) per worker plus one session per worker.

pub mod features;
pub mod refine;
pub mod runtime;

use std::path::Path;
use std::sync::Mutex;

use rayon::prelude::*;

pub use features::{ClusterPoints, FEATURES_PER_POINT};
pub use refine::{Params, RefineStats, refine};

use crate::pipeline::PipelineError;
use crate::pipeline::types::MarkingClass;

/// Number of contract classes; [`Prediction::probs`] is indexed by `MarkingClass as usize`.
pub const NCLASSES: usize = MarkingClass::ALL.len();

/// The model shipped with roadmark (trained by `training/train.py`, see `models/README.md`).
pub const BUILTIN_MODEL: &[u8] = include_bytes!("../../../models/marking_classifier.onnx");

/// The classifier's verdict on one cluster.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Prediction {
    /// Probability per contract class, indexed by `MarkingClass as usize` (classes the model
    /// does not know have 0).
    pub probs: [f32; NCLASSES],
    /// The most probable class, or `Unknown` when its probability is below the threshold.
    pub class: MarkingClass,
    /// Probability of `class` (for `Unknown` from a low top score: one minus that score).
    pub confidence: f32,
}

impl Prediction {
    /// Decide the class from the probabilities with the given unknown threshold.
    pub fn from_probs(probs: [f32; NCLASSES], unknown_threshold: f32) -> Self {
        let (best, p) =
            probs
                .iter()
                .enumerate()
                .fold((MarkingClass::Unknown as usize, f32::MIN), |acc, (i, &p)| {
                    if p > acc.1 { (i, p) } else { acc }
                });
        let class = MarkingClass::ALL[best];
        if p < unknown_threshold && class != MarkingClass::Unknown {
            let unknown = probs[MarkingClass::Unknown as usize].max(1.0 - p);
            Prediction {
                probs,
                class: MarkingClass::Unknown,
                confidence: unknown,
            }
        } else {
            Prediction {
                probs,
                class,
                confidence: p,
            }
        }
    }

    /// Probability of one class.
    pub fn prob(&self, class: MarkingClass) -> f32 {
        self.probs[class as usize]
    }
}

/// What the model file says about itself.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelInfo {
    /// Output order of the network.
    pub classes: Vec<MarkingClass>,
    /// Points per cluster `n`.
    pub points_per_cluster: usize,
    /// Below this top probability a prediction is `unknown`.
    pub unknown_threshold: f32,
}

/// A loaded model and its pool of ONNX Runtime sessions. Share one per process (it is `Sync`).
pub struct Classifier {
    model: Vec<u8>,
    info: ModelInfo,
    input_name: String,
    pool: Mutex<Vec<ort::session::Session>>,
    batch_size: usize,
    source: String,
}

impl std::fmt::Debug for Classifier {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Classifier")
            .field("source", &self.source)
            .field("info", &self.info)
            .field("batch_size", &self.batch_size)
            .finish()
    }
}

fn model_err(source: &str, what: impl std::fmt::Display) -> PipelineError {
    PipelineError::Model(format!("{source}: {what}"))
}

/// Clusters per network evaluation by default. A chunk shows the network 10-80 clusters;
/// in batches of 32 one of two threads got two batches and the other one or none (urban
/// s1: 79 clusters, 32 + 32 + 15). Batches of 8 share them out evenly: the same outputs,
/// urban s1 end to end 2.19 -> 2.07 s (the classifier's share of it 14 % -> 12 %); 4 gained
/// nothing more.
const DEFAULT_BATCH_SIZE: usize = 8;

impl Classifier {
    /// Load a model file (loading ONNX Runtime first if needed).
    pub fn load(path: &Path) -> Result<Self, PipelineError> {
        let bytes = std::fs::read(path)
            .map_err(|e| PipelineError::Model(format!("cannot read the model {}: {e}", path.display())))?;
        Self::from_bytes(bytes, path.display().to_string())
    }

    /// The model shipped inside the binary.
    pub fn builtin() -> Result<Self, PipelineError> {
        Self::from_bytes(BUILTIN_MODEL.to_vec(), "built-in marking_classifier.onnx".into())
    }

    /// The built-in model, loaded once per process and shared (the service reuses it per job).
    pub fn shared() -> Result<&'static Self, PipelineError> {
        static SHARED: std::sync::OnceLock<Classifier> = std::sync::OnceLock::new();
        static LOADING: Mutex<()> = Mutex::new(());
        if let Some(c) = SHARED.get() {
            return Ok(c);
        }
        let _guard = LOADING.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(c) = SHARED.get() {
            return Ok(c);
        }
        let c = Self::builtin()?;
        Ok(SHARED.get_or_init(|| c))
    }

    /// Load a model from its bytes; `source` names it in errors.
    pub fn from_bytes(model: Vec<u8>, source: String) -> Result<Self, PipelineError> {
        runtime::ensure_loaded()?;
        let session = Self::new_session(&model, &source)?;
        let meta = session.metadata().map_err(|e| model_err(&source, e))?;
        let get = |key: &str| {
            meta.custom(key)
                .ok_or_else(|| model_err(&source, format!("metadata `{key}` is missing")))
        };
        let classes = get("roadmark.classes")?
            .split(',')
            .map(|name| {
                MarkingClass::parse(name.trim())
                    .ok_or_else(|| model_err(&source, format!("unknown class `{name}` in metadata")))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let points_per_cluster: usize = get("roadmark.points")?
            .parse()
            .map_err(|e| model_err(&source, format!("metadata roadmark.points: {e}")))?;
        let version = get("roadmark.features")?;
        if version != features::FEATURE_VERSION {
            return Err(model_err(
                &source,
                format!(
                    "the model expects feature recipe {version}, this build prepares {}",
                    features::FEATURE_VERSION
                ),
            ));
        }
        let unknown_threshold = match meta.custom("roadmark.unknown_threshold") {
            Some(s) => s
                .parse()
                .map_err(|e| model_err(&source, format!("metadata roadmark.unknown_threshold: {e}")))?,
            None => 0.5,
        };
        drop(meta);
        if session.inputs().len() != 1 || session.outputs().len() != 1 {
            return Err(model_err(&source, "the model must have one input and one output"));
        }
        let input_name = session.inputs()[0].name().to_string();
        if classes.is_empty() || points_per_cluster == 0 {
            return Err(model_err(&source, "empty class list or zero points per cluster"));
        }
        let this = Self {
            model,
            info: ModelInfo {
                classes,
                points_per_cluster,
                unknown_threshold,
            },
            input_name,
            pool: Mutex::new(vec![session]),
            batch_size: DEFAULT_BATCH_SIZE,
            source,
        };
        // One dry run so a model with the wrong shapes fails here, not in the middle of a job.
        let zeros = vec![0.0; points_per_cluster * FEATURES_PER_POINT];
        this.run_features(&zeros, 1)?;
        Ok(this)
    }

    fn new_session(model: &[u8], source: &str) -> Result<ort::session::Session, PipelineError> {
        let env = runtime::env()?;
        let builder = ort::session::Session::builder(env).map_err(|e| model_err(source, e))?;
        let builder = builder.with_intra_threads(1).map_err(|e| model_err(source, e))?;
        let builder = builder.with_inter_threads(1).map_err(|e| model_err(source, e))?;
        let builder = builder
            .with_intra_op_spinning(false)
            .map_err(|e| model_err(source, e))?;
        let mut builder = builder
            .with_optimization_level(ort::session::builder::GraphOptimizationLevel::All)
            .map_err(|e| model_err(source, e))?;
        builder
            .commit_from_memory(model)
            .map_err(|e| model_err(source, e))
    }

    /// What the model file says about itself.
    pub fn info(&self) -> &ModelInfo {
        &self.info
    }

    /// Clusters per network evaluation.
    pub fn batch_size(&self) -> usize {
        self.batch_size
    }

    /// Change the number of clusters per network evaluation (at least 1).
    pub fn with_batch_size(mut self, batch_size: usize) -> Self {
        self.batch_size = batch_size.max(1);
        self
    }

    /// Classify clusters in parallel batches; one prediction per cluster, in order.
    pub fn classify(&self, clusters: &[ClusterPoints<'_>]) -> Result<Vec<Prediction>, PipelineError> {
        let n = self.info.points_per_cluster;
        let chunks: Vec<Vec<Prediction>> = clusters
            .par_chunks(self.batch_size)
            .map(|chunk| {
                let mut feats = vec![0.0f32; chunk.len() * n * FEATURES_PER_POINT];
                for (c, out) in chunk.iter().zip(feats.chunks_mut(n * FEATURES_PER_POINT)) {
                    features::prepare(c, n, out);
                }
                self.predict_features(&feats, chunk.len())
            })
            .collect::<Result<_, _>>()?;
        Ok(chunks.into_iter().flatten().collect())
    }

    /// Classify prepared features (`count × n × 4` values, see [`features::prepare`]) in
    /// parallel batches.
    pub fn classify_features(&self, feats: &[f32], count: usize) -> Result<Vec<Prediction>, PipelineError> {
        let per = self.info.points_per_cluster * FEATURES_PER_POINT;
        if feats.len() != count * per {
            return Err(model_err(
                &self.source,
                format!("{} feature values for {count} clusters of {per}", feats.len()),
            ));
        }
        let chunks: Vec<Vec<Prediction>> = feats
            .par_chunks(self.batch_size * per)
            .map(|chunk| self.predict_features(chunk, chunk.len() / per))
            .collect::<Result<_, _>>()?;
        Ok(chunks.into_iter().flatten().collect())
    }

    fn predict_features(&self, feats: &[f32], count: usize) -> Result<Vec<Prediction>, PipelineError> {
        let raw = self.run_features(feats, count)?;
        let k = self.info.classes.len();
        Ok(raw
            .chunks(k)
            .map(|row| {
                let mut probs = [0.0f32; NCLASSES];
                for (&class, &p) in self.info.classes.iter().zip(row) {
                    probs[class as usize] += p;
                }
                Prediction::from_probs(probs, self.info.unknown_threshold)
            })
            .collect())
    }

    /// One network evaluation of `count` clusters; returns `count × classes` probabilities.
    fn run_features(&self, feats: &[f32], count: usize) -> Result<Vec<f32>, PipelineError> {
        let n = self.info.points_per_cluster;
        let mut session = match self.pool.lock().unwrap_or_else(|e| e.into_inner()).pop() {
            Some(s) => s,
            None => Self::new_session(&self.model, &self.source)?,
        };
        let result = (|| {
            let input = ort::value::Tensor::from_array(([count, n, FEATURES_PER_POINT], feats.to_vec()))?;
            let outputs = session.run(ort::inputs![self.input_name.as_str() => input])?;
            let (shape, data) = outputs[0].try_extract_tensor::<f32>()?;
            Ok::<_, ort::Error>((shape.to_vec(), data.to_vec()))
        })();
        self.pool.lock().unwrap_or_else(|e| e.into_inner()).push(session);
        let (shape, data) = result.map_err(|e| model_err(&self.source, e))?;
        let k = self.info.classes.len();
        if shape != [count as i64, k as i64] {
            return Err(model_err(
                &self.source,
                format!("output shape {shape:?}, expected [{count}, {k}]"),
            ));
        }
        Ok(data)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn low_top_probability_becomes_unknown() {
        let mut probs = [0.0; NCLASSES];
        probs[MarkingClass::LeftArrow as usize] = 0.45;
        probs[MarkingClass::StraightLeftArrow as usize] = 0.40;
        probs[MarkingClass::Unknown as usize] = 0.15;
        let p = Prediction::from_probs(probs, 0.5);
        assert_eq!(p.class, MarkingClass::Unknown);
        assert!((p.confidence - 0.55).abs() < 1e-6);
        let p = Prediction::from_probs(probs, 0.4);
        assert_eq!(p.class, MarkingClass::LeftArrow);
        assert!((p.confidence - 0.45).abs() < 1e-6);
        assert_eq!(p.prob(MarkingClass::StraightLeftArrow), 0.40);
    }

    #[test]
    fn class_indices_follow_the_contract_order() {
        for (i, c) in MarkingClass::ALL.iter().enumerate() {
            assert_eq!(*c as usize, i);
        }
    }
}
