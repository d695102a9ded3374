//! The pipeline hook of the learned classifier: names the candidates the geometric rules
//! could not decide.
//!
//! # What
//! [`refine`] takes the classify stage's candidates and, for each one left `unknown`,
//! classified with a confidence below [`Params::decisive_confidence`], a dash, or a solid
//! piece no longer than a painted object, asks the network.
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
//!    - network below the threshold (or says `unknown`), or a crosswalk stripe wider than
//!      the rules allow a stripe (`classify.crosswalk_max_width_m`, see [`fits_stripe`]):
//!      the candidate keeps its geometric class; an `unknown`
//!      candidate gets confidence = the network's `unknown` confidence;
//!    - a confident dash or a solid piece no longer than a painted object (the rules' bar
//!      test cannot tell a dash from a straight arrow whose head is worn or too sparsely
//!      scanned, nor a line piece from a lone stop line along the road) keeps
//!      its class unless the network names another painted object — an arrow, a diamond, a
//!      guideline or stop line, never a line or a crosswalk stripe (the rules found no
//!      stripe beside it) — with probability ≥ `dash_overrule_confidence`.
//! 4. Clusters the classify stage peeled a line off and that are no longer than one painted
//!    object (`Candidate::whole`: a 9 m highway arrow's shaft passes the line test) are shown
//!    to the network whole as well; when it names one such painted object with probability
//!    ≥ `dash_overrule_confidence`, the pieces are replaced by the whole cluster. The same
//!    holds for groups of nearby fragments (`unknown` pieces, a dash-like shaft, head parts
//!    dropped as too small, round or steep), whose union the classify stage offers as their
//!    `whole` (a worn or sparsely scanned arrow or diamond in pieces). A group with line
//!    pieces is also offered without each of its longest few (`Candidate::alternatives`:
//!    a lane line passing a far arrow's head within half a metre joins its group); these
//!    compete with the whole, the most probable painted object wins, and an alternative
//!    needs probability ≥ `ALTERNATIVE_MIN_CONFIDENCE` (0.9). A group that holds
//!    a peeled cluster is offered as the pieces' `group`: when the network names it an
//!    arrow or a diamond with that probability, it replaces the peeled clusters in it (a
//!    straight arrow and the turning branch that wore off its shaft are one
//!    straight-and-turn arrow).
//!
//! # Parameters
//! [`Params`]: `mode` (`auto`: run when ONNX Runtime is installed, otherwise leave the
//! candidates unchanged with a warning; `on`: a missing runtime is an error; `off`),
//! `decisive_confidence` (default 0.5: below it a geometric class is re-examined),
//! `dash_overrule_confidence` (default 0.8), `glyph_min_confidence` (default 0.5: an
//! undecided candidate becomes an arrow or a diamond only at this probability).
//!
//! # Complexity
//! O(m·n) feature preparation per selected cluster of m points (n = 256), plus one network
//! evaluation per cluster (≈ 4 M multiply-adds); memory O(batch · n) per worker.

use serde::{Deserialize, Serialize};

use super::{Classifier, ClusterPoints};
use crate::pipeline::PipelineError;
use crate::pipeline::classify::{self, Candidate, MAX_OBJECT_LENGTH_M, shared_unions};
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
    /// Dashes are always shown to the network (a straight arrow whose head is worn or cut
    /// off, a lone stop line along the road and a wide dash are the same bar to the rules);
    /// the network overrules a dash with another painted-object class only at this
    /// probability or above (0..=1). Default 0.8.
    pub dash_overrule_confidence: f64,
    /// An undecided candidate becomes an arrow or a diamond (glyphs the network alone
    /// names) only at this probability or above (0..=1; never below the model's unknown
    /// threshold). Default 0.5: end to end, the network's glyphs below it were nearly all
    /// wrong (20 simulated scenes and the 1 km bench drive: 2 of 26 arrows right below 0.5,
    /// 129 of 154 above; 25 of 27 diamonds, all above 0.8), though the held-out clusters
    /// calibrate the unknown threshold at 0.3: the pipeline's odd pieces (scraps, a far
    /// arrow's few scan rows) are not the training set's clusters. Below it the candidate
    /// stays `unknown`.
    pub glyph_min_confidence: f64,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            mode: Mode::Auto,
            decisive_confidence: 0.5,
            dash_overrule_confidence: 0.8,
            glyph_min_confidence: 0.5,
        }
    }
}

impl Params {
    pub fn validate(&self) -> Result<(), String> {
        crate::pipeline::pavement::check_range("decisive_confidence", self.decisive_confidence, 0.0, 1.0)?;
        crate::pipeline::pavement::check_range(
            "dash_overrule_confidence",
            self.dash_overrule_confidence,
            0.0,
            1.0,
        )?;
        crate::pipeline::pavement::check_range("glyph_min_confidence", self.glyph_min_confidence, 0.0, 1.0)
    }
}

/// What [`refine`] did (for logs and the bench).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RefineStats {
    /// Candidates sent to the network.
    pub examined: usize,
    /// Candidates whose class changed.
    pub reclassified: usize,
    /// Clusters put back together from the pieces the classify stage had peeled apart.
    pub reassembled: usize,
}

/// Reclassify the non-decisive candidates with the shared built-in model (see module docs).
pub fn refine(
    candidates: &mut Vec<Candidate>,
    cloud: &PointCloud,
    params: &Params,
    rules: &classify::Params,
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
    refine_with(classifier, candidates, cloud, params, rules)
}

/// [`refine`] with an explicit classifier.
pub fn refine_with(
    classifier: &Classifier,
    candidates: &mut Vec<Candidate>,
    cloud: &PointCloud,
    params: &Params,
    rules: &classify::Params,
) -> Result<RefineStats, PipelineError> {
    // A confident dash is still shown to the network, which may only turn it into another
    // painted object, and only when sure (`dash_overrule_confidence`).
    // So is a solid piece no longer than a painted object: a lone stop line along the road
    // (across a side street's mouth) is a solid piece to the rules.
    let short_solid =
        |c: &Candidate| c.class == MarkingClass::SolidLine && c.shape.length_m <= MAX_OBJECT_LENGTH_M;
    let confident_bar = |c: &Candidate| {
        (c.class == MarkingClass::DashedLine || short_solid(c)) && c.confidence >= params.decisive_confidence
    };
    let selected: Vec<usize> = candidates
        .iter()
        .enumerate()
        .filter(|(_, c)| {
            !c.indices.is_empty()
                && (c.class == MarkingClass::Unknown
                    || c.class == MarkingClass::DashedLine
                    || short_solid(c)
                    || c.confidence < params.decisive_confidence)
        })
        .map(|(i, _)| i)
        .collect();
    // The short clusters the classify stage peeled lines off, each once, with the
    // candidates (pieces) peeled off it; the groups' unions without one of their line
    // pieces, which compete with them; then the groups of fragments that hold such a
    // cluster, likewise.
    let mut unions = shared_unions(candidates, |c| c.whole.as_ref());
    let n_plain = unions.len();
    unions.extend(shared_unions(candidates, |c| &c.alternatives));
    let n_wholes = unions.len();
    unions.extend(shared_unions(candidates, |c| c.group.as_ref()));
    if selected.is_empty() && unions.is_empty() {
        return Ok(RefineStats::default());
    }
    let views: Vec<ClusterPoints<'_>> = selected
        .iter()
        .map(|&i| &candidates[i])
        .chain(unions.iter().map(|(w, _)| w.as_ref()))
        .map(|c| ClusterPoints {
            cloud,
            indices: &c.indices,
            direction: c.shape.driving_direction,
        })
        .collect();
    let preds = classifier.classify(&views)?;
    drop(views);
    let (preds, union_preds) = preds.split_at(selected.len());
    let threshold = classifier.info().unknown_threshold as f64;
    let overrule = params.dash_overrule_confidence.max(threshold);
    let glyph_min = params.glyph_min_confidence.max(threshold);
    let mut stats = RefineStats {
        examined: selected.len() + unions.len(),
        ..RefineStats::default()
    };
    for (&i, pred) in selected.iter().zip(preds) {
        let c = &mut candidates[i];
        let top = pred.prob(pred.class) as f64;
        let accepted = if confident_bar(c) {
            pred.class == c.class || (painted_object(pred.class) && top >= overrule)
        } else {
            pred.class != MarkingClass::Unknown
                && top >= if glyph(pred.class) { glyph_min } else { threshold }
                && (pred.class != MarkingClass::Crosswalk || fits_stripe(c, rules))
        };
        if accepted {
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
    // A peeled cluster the network names one painted object is put back together: its
    // first piece becomes the whole cluster, the other pieces go. A group of fragments
    // that holds peeled clusters is put together instead when the network names it an
    // arrow or a diamond (what falls apart into such pieces; a union of a stop line and
    // an arrow beside it is no stop line): a straight arrow beside a lone turning branch
    // is a straight-and-turn arrow.
    let mut chosen: Vec<usize> = Vec::new();
    for (u, ((_, pieces), pred)) in unions.iter().zip(union_preds).enumerate() {
        // An alternative is one hypothesis of several about the same pieces: it needs more
        // certainty.
        let need = if (n_plain..n_wholes).contains(&u) {
            overrule.max(ALTERNATIVE_MIN_CONFIDENCE)
        } else {
            overrule
        };
        if !painted_object(pred.class) || (pred.prob(pred.class) as f64) < need {
            continue;
        }
        let shares = |v: usize| unions[v].1.iter().any(|i| pieces.contains(i));
        if u >= n_wholes {
            if !glyph(pred.class) {
                continue;
            }
            chosen.retain(|&v| !shares(v));
        } else {
            // A group's union and its unions without one line piece share pieces: the
            // most probable painted object of them stays.
            let p = pred.prob(pred.class);
            let prob_of = |v: usize| union_preds[v].prob(union_preds[v].class);
            if chosen.iter().any(|&v| shares(v) && prob_of(v) >= p) {
                continue;
            }
            chosen.retain(|&v| !shares(v));
        }
        chosen.push(u);
    }
    let mut keep = vec![true; candidates.len()];
    for u in chosen {
        let ((w, pieces), pred) = (&unions[u], &union_preds[u]);
        candidates[pieces[0]] = Candidate {
            class: pred.class,
            confidence: pred.prob(pred.class) as f64,
            whole: None,
            group: None,
            alternatives: Vec::new(),
            ..Candidate::clone(w)
        };
        pieces[1..].iter().for_each(|&i| keep[i] = false);
        stats.reassembled += 1;
    }
    let mut keep = keep.into_iter();
    candidates.retain(|_| keep.next().unwrap_or(true));
    Ok(stats)
}

/// The network names a candidate a crosswalk stripe only when its rectangle is no wider
/// than the rules allow a stripe (`classify.crosswalk_max_width_m`, default 0.65 m). Sparse
/// far clusters 1–3 m wide, ten to forty points of road noise in a far carriageway
/// scanned at 100 lines/s, read as stripes at p = 0.33–0.93; on 29 simulated drives
/// (200 and 100–250 lines/s) every stripe the pipeline got right was at most 0.61 m
/// wide, and 47 of its 59 wrong stripes were wider than 0.7 m. A wider candidate the
/// network calls a stripe keeps its geometric class.
fn fits_stripe(c: &Candidate, rules: &classify::Params) -> bool {
    c.shape.width_m <= rules.crosswalk_max_width_m
}

/// Least probability at which the network's name for a group's union without one of its
/// line pieces (`Candidate::alternatives`) is taken. Up to three such unions are shown per
/// group besides its whole, so a chance match is likelier than for one whole: a crack
/// sealant streak's two pieces, without the dash they touched, read as a left arrow at
/// p = 0.80 on a simulated MUTCD highway, where the far arrows put back together this way
/// read at 0.96–0.98.
const ALTERNATIVE_MIN_CONFIDENCE: f64 = 0.9;

/// Arrows and diamonds: glyphs the network alone names. An `unknown` candidate becomes one
/// only at `glyph_min_confidence` (see [`Params`]).
fn glyph(class: MarkingClass) -> bool {
    class.is_arrow() || class == MarkingClass::Diamond
}

/// A painted object other than a line or a crosswalk stripe: what the network may make of
/// a confident dash (the rules saw no stripe beside it, and they are sure of lines) or of a
/// cluster the classify stage peeled a line off.
fn painted_object(class: MarkingClass) -> bool {
    !matches!(
        class,
        MarkingClass::DashedLine | MarkingClass::SolidLine | MarkingClass::Crosswalk | MarkingClass::Unknown
    )
}

fn warn_once(e: &PipelineError) {
    static WARNED: std::sync::Once = std::sync::Once::new();
    WARNED.call_once(|| {
        tracing::warn!("learned marking classifier skipped (geometric classes kept): {e}");
    });
}
