//! Accuracy metrics of a result against a truth, as in the papers and more.
//!
//! **What.** [`evaluate`] scores a result [`Extraction`] against a truth one and returns a
//! [`Report`] (serde-serialisable; `roadmark evaluate --json` prints it, tests and the service
//! parse it). One file per metric family:
//! - [`pixel`]: pixel-level completeness / correctness / F-score of the painted area, and the
//!   length-based solid-line scores;
//! - [`objects`]: one-to-one IoU matching, per-class precision / recall / F1, macro-F1,
//!   confusion matrix;
//! - [`lanes`]: lane-line completeness / correctness within a buffer, RMSE, fragmentation,
//!   class agreement;
//! - [`corners`]: outline corner RMSE of matched rectangle-like markings;
//! - [`raster`]: the run-length polygon rasteriser behind the pixel metrics.
//!
//! **Algorithm.** Both sides are first brought into one metric CRS: a result in WGS84 lon/lat
//! (or any other CRS) is reprojected into the truth's projected CRS; a geographic truth is
//! reprojected into a projected result's CRS; when both are geographic, both go to the UTM
//! zone of the truth. An unknown CRS on one side is assumed to equal the other (noted in the
//! report). Coordinates are then made local (integer-metre origin at the lower-left of both
//! sides) so no metric works on large absolute values. Every value of the report is rounded
//! to 6 decimals (1 µm, 1e-6 of a ratio) so the JSON is stable; a ratio with an empty
//! denominator is `null` ("n/a" in the table) rather than a made-up 0 or 1. The truth scored
//! against itself is exactly 1 everywhere with 0 RMSE.
//!
//! **Parameters.** [`EvalOptions`]: `pixel_m` 0.05 m, `iou_min` 0.3, `lane_tol_m` 0.15 m,
//! `sample_m` 0.1 m, `solid_tol_m` 0.15 m.
//!
//! **Reference.** Yao et al. 2019/2021 (pixel level, solid-line length), Pan et al. 2019
//! (object level, corner RMSE), see `../shared/papers/README.md`.
//!
//! **Complexity.** Dominated by the rasterisation, O(C log C) in row crossings (≈ 1 s for a
//! 1 km drive at 0.05 m), and the polygon intersections of overlapping pairs.

pub mod corners;
pub mod lanes;
pub mod objects;
pub mod pixel;
pub mod raster;

use crate::pipeline::geojson::read_geojson;
use crate::pipeline::reproject::{EPSG_WGS84, Reprojector, crs_label, map_coords, reproject_extraction, utm_epsg_for};
use crate::pipeline::types::{Crs, Extraction};
use serde::{Deserialize, Serialize, de::DeserializeOwned};
use std::fmt::Write as _;
use std::path::Path;

/// Evaluation parameters (all lengths in metres).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EvalOptions {
    /// Pixel size of the pixel-level metrics.
    pub pixel_m: f64,
    /// Minimum IoU of a matched marking pair.
    pub iou_min: f64,
    /// Buffer of the lane-line completeness / correctness.
    pub lane_tol_m: f64,
    /// Sampling step along lane lines.
    pub sample_m: f64,
    /// Tolerance of the length-based solid-line scores.
    pub solid_tol_m: f64,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            pixel_m: 0.05,
            iou_min: 0.3,
            lane_tol_m: 0.15,
            sample_m: 0.1,
            solid_tol_m: 0.15,
        }
    }
}

impl EvalOptions {
    pub fn validate(&self) -> Result<(), String> {
        let pos = |v: f64, name: &str, max: f64| {
            if v.is_finite() && v > 0.0 && v <= max {
                Ok(())
            } else {
                Err(format!("{name} must be in (0, {max}], got {v}"))
            }
        };
        pos(self.pixel_m, "pixel_m", 1.0)?;
        pos(self.iou_min, "iou_min", 1.0)?;
        pos(self.lane_tol_m, "lane_tol_m", 10.0)?;
        pos(self.sample_m, "sample_m", 10.0)?;
        if !(self.solid_tol_m.is_finite() && (0.0..=10.0).contains(&self.solid_tol_m)) {
            return Err(format!("solid_tol_m must be in [0, 10], got {}", self.solid_tol_m));
        }
        Ok(())
    }
}

/// Errors of an evaluation.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error("invalid evaluation options: {0}")]
    Options(String),
    /// The two sides cannot be put into one metric CRS.
    #[error("{0}")]
    Crs(String),
    /// A truth or result file could not be read (the message names it).
    #[error("{0}")]
    Input(String),
}

/// Precision / recall / F from counts.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Prf {
    pub tp: u64,
    pub fp: u64,
    #[serde(rename = "fn")]
    pub fn_: u64,
    pub precision: Option<f64>,
    pub recall: Option<f64>,
    pub f_score: Option<f64>,
}

impl Prf {
    /// F = 2·TP / (2·TP + FP + FN), equal to the harmonic mean of P and R when both exist.
    pub fn from_counts(tp: u64, fp: u64, fn_: u64) -> Self {
        Self {
            tp,
            fp,
            fn_,
            precision: ratio(tp as f64, (tp + fp) as f64),
            recall: ratio(tp as f64, (tp + fn_) as f64),
            f_score: ratio(2.0 * tp as f64, (2 * tp + fp + fn_) as f64),
        }
    }
}

/// `num / den`, or `None` when `den` is 0.
pub fn ratio(num: f64, den: f64) -> Option<f64> {
    (den > 0.0).then(|| num / den)
}

/// Harmonic mean of two rates; 0 when one is 0; `None` only when both are undefined.
pub fn harmonic(a: Option<f64>, b: Option<f64>) -> Option<f64> {
    match (a, b) {
        (Some(a), Some(b)) if a + b > 0.0 => Some(2.0 * a * b / (a + b)),
        (None, None) => None,
        _ => Some(0.0),
    }
}

/// Pixel-level scores of the marking layer (all classes together).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PixelScores {
    pub pixel_m: f64,
    pub truth_px: u64,
    pub result_px: u64,
    pub tp_px: u64,
    pub fp_px: u64,
    pub fn_px: u64,
    /// TP / (TP + FN): recall.
    pub completeness: Option<f64>,
    /// TP / (TP + FP): precision.
    pub correctness: Option<f64>,
    pub f_score: Option<f64>,
}

/// Length-based solid-line scores.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SolidLineScores {
    pub tolerance_m: f64,
    pub truth_pieces: usize,
    pub result_pieces: usize,
    /// Sum of `length_m` of the truth solid-line pieces.
    pub truth_length_m: f64,
    pub result_length_m: f64,
    /// recall × truth length.
    pub detected_length_m: Option<f64>,
    /// Fraction of the truth solid-line area within the tolerance of result solid lines.
    pub recall: Option<f64>,
    /// Fraction of the result solid-line area within the tolerance of truth solid lines.
    pub precision: Option<f64>,
    pub f_score: Option<f64>,
}

/// Scores of one marking class.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClassScores {
    pub class: String,
    /// Number of truth / result markings of the class.
    pub truth: usize,
    pub result: usize,
    /// Counts from the IoU matching.
    pub tp: u64,
    pub fp: u64,
    #[serde(rename = "fn")]
    pub fn_: u64,
    pub precision: Option<f64>,
    pub recall: Option<f64>,
    pub f1: Option<f64>,
    /// `iou` (from the counts) or `length` (solid lines, from [`SolidLineScores`]).
    pub method: String,
}

/// Confusion matrix over matched pairs: rows truth, columns result; the last label `none`
/// holds missed truth (column) and false results (row).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Confusion {
    pub labels: Vec<String>,
    pub counts: Vec<Vec<usize>>,
}

impl Confusion {
    /// The count of (truth label, result label), 0 when a label is absent.
    pub fn get(&self, truth: &str, result: &str) -> usize {
        let pos = |l: &str| self.labels.iter().position(|x| x == l);
        match (pos(truth), pos(result)) {
            (Some(i), Some(j)) => self.counts[i][j],
            _ => 0,
        }
    }
}

/// Object-level scores.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ObjectScores {
    pub iou_threshold: f64,
    pub matched: usize,
    pub mean_iou: Option<f64>,
    /// Class-agnostic detection (solid-line fragments excluded, see [`objects`]).
    pub detection: Prf,
    /// Matched pairs with the same class / matched pairs.
    pub classification_accuracy: Option<f64>,
    /// Mean F1 over the classes present in the truth.
    pub macro_f1: Option<f64>,
    /// Classes present on either side, in contract order.
    pub per_class: Vec<ClassScores>,
    pub confusion: Confusion,
    /// Unmatched solid-line pieces covered by the other side: [truth, result].
    pub solid_line_fragments: [usize; 2],
}

impl ObjectScores {
    pub fn class(&self, name: &str) -> Option<&ClassScores> {
        self.per_class.iter().find(|c| c.class == name)
    }
}

/// Lane-line scores.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LaneScores {
    pub tolerance_m: f64,
    pub sample_m: f64,
    pub truth_lines: usize,
    pub result_lines: usize,
    pub truth_length_m: f64,
    pub result_length_m: f64,
    pub completeness: Option<f64>,
    pub correctness: Option<f64>,
    pub f_score: Option<f64>,
    pub rmse_m: Option<f64>,
    /// Result lane lines per matched truth lane line: mean and max.
    pub fragmentation_mean: Option<f64>,
    pub fragmentation_max: Option<usize>,
    pub unmatched_truth_lines: usize,
    /// Matched length whose class (solid/dashed) agrees / matched length.
    pub class_agreement: Option<f64>,
}

/// Corner RMSE of matched rectangle-like markings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CornerScores {
    pub classes: Vec<String>,
    pub pairs: usize,
    pub rmse_m: Option<f64>,
    pub max_m: Option<f64>,
}

/// What one side held.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SideSummary {
    /// CRS as read (`EPSG:N`, `WKT "name"`, `unknown`).
    pub crs: String,
    pub markings: usize,
    pub lane_lines: usize,
}

/// The full evaluation report (`roadmark evaluate --json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Report {
    pub truth: SideSummary,
    pub result: SideSummary,
    /// The metric CRS the scores were computed in.
    pub working_crs: String,
    /// Reprojections and assumptions made.
    pub notes: Vec<String>,
    pub options: EvalOptions,
    pub pixel: PixelScores,
    pub solid_line: SolidLineScores,
    pub objects: ObjectScores,
    pub lanes: LaneScores,
    pub corners: CornerScores,
}

fn is_geographic(crs: &Crs) -> bool {
    crs.epsg == Some(EPSG_WGS84) || Reprojector::new(crs).map(|r| r.is_geographic()).unwrap_or(false)
}

fn same_crs(a: &Crs, b: &Crs) -> bool {
    a == b || (a.epsg.is_some() && a.epsg == b.epsg)
}

fn centroid(ex: &Extraction) -> Option<(f64, f64)> {
    let pts: Vec<&[f64; 2]> = ex
        .markings
        .iter()
        .flat_map(|m| &m.outline)
        .chain(ex.lane_lines.iter().flat_map(|l| &l.line))
        .collect();
    let n = pts.len() as f64;
    (!pts.is_empty()).then(|| {
        (
            pts.iter().map(|p| p[0]).sum::<f64>() / n,
            pts.iter().map(|p| p[1]).sum::<f64>() / n,
        )
    })
}

/// Bring both sides into one metric CRS; returns them, the working CRS label and notes.
fn align(truth: &Extraction, result: &Extraction) -> Result<(Extraction, Extraction, String, Vec<String>), String> {
    let mut notes = Vec::new();
    let to = |ex: &Extraction, crs: &Crs, who: &str, notes: &mut Vec<String>| {
        let out = reproject_extraction(ex, crs).map_err(|e| format!("{who}: {e}"))?;
        notes.push(format!(
            "{who} reprojected from {} to {}",
            crs_label(ex.crs.as_ref()),
            crs_label(Some(crs))
        ));
        Ok::<_, String>(out)
    };
    match (&truth.crs, &result.crs) {
        (None, None) => Ok((
            truth.clone(),
            result.clone(),
            "unknown (coordinates taken as metres)".into(),
            notes,
        )),
        (Some(c), None) | (None, Some(c)) => {
            let (known, unknown) = if truth.crs.is_some() {
                ("truth", "result")
            } else {
                ("result", "truth")
            };
            if is_geographic(c) {
                return Err(format!(
                    "the {known} is in {} (longitude/latitude) but the {unknown}'s CRS is unknown: \
                     cannot bring them into one metric CRS",
                    crs_label(Some(c))
                ));
            }
            notes.push(format!("{unknown} CRS unknown: assumed to be {} like the {known}", crs_label(Some(c))));
            Ok((truth.clone(), result.clone(), crs_label(Some(c)), notes))
        }
        (Some(a), Some(b)) => {
            let (ga, gb) = (is_geographic(a), is_geographic(b));
            if !ga {
                let r = if same_crs(a, b) { result.clone() } else { to(result, a, "result", &mut notes)? };
                Ok((truth.clone(), r, crs_label(Some(a)), notes))
            } else if !gb {
                let t = to(truth, b, "truth", &mut notes)?;
                Ok((t, result.clone(), crs_label(Some(b)), notes))
            } else {
                // Both lon/lat: metres from the UTM zone of the truth (else of the result).
                let (lon, lat) = centroid(truth).or_else(|| centroid(result)).unwrap_or((0.0, 0.0));
                // A geographic CRS other than WGS84 is close enough to it to pick a zone.
                let utm = Crs::epsg(utm_epsg_for(lon, lat));
                let t = to(truth, &utm, "truth", &mut notes)?;
                let r = to(result, &utm, "result", &mut notes)?;
                Ok((t, r, crs_label(Some(&utm)), notes))
            }
        }
    }
}

/// Both sides relative to one integer-metre origin (lower-left of everything).
fn localise(truth: &Extraction, result: &Extraction) -> (Extraction, Extraction) {
    let all = [truth, result];
    let pts = all
        .iter()
        .flat_map(|ex| ex.markings.iter().flat_map(|m| &m.outline).chain(ex.lane_lines.iter().flat_map(|l| &l.line)));
    let (mx, my) = pts.fold((f64::INFINITY, f64::INFINITY), |(x, y), p| (x.min(p[0]), y.min(p[1])));
    let (ox, oy) = if mx.is_finite() { (mx.floor(), my.floor()) } else { (0.0, 0.0) };
    let shift = |ex: &Extraction| map_coords(ex, |x, y| Ok((x - ox, y - oy))).expect("translation cannot fail");
    (shift(truth), shift(result))
}

/// Round every float of a serialisable value to 6 decimals (stable JSON, exact self-scores).
fn rounded<T: Serialize + DeserializeOwned>(v: &T) -> T {
    fn walk(v: &mut serde_json::Value) {
        match v {
            serde_json::Value::Number(n) if n.is_f64() => {
                let x = n.as_f64().unwrap_or(0.0);
                *v = serde_json::json!((x * 1e6).round() / 1e6);
            }
            serde_json::Value::Array(a) => a.iter_mut().for_each(walk),
            serde_json::Value::Object(o) => o.values_mut().for_each(walk),
            _ => {}
        }
    }
    let mut value = serde_json::to_value(v).expect("report serialises");
    walk(&mut value);
    serde_json::from_value(value).expect("report deserialises")
}

/// Score `result` against `truth`.
pub fn evaluate(truth: &Extraction, result: &Extraction, opts: &EvalOptions) -> Result<Report, EvalError> {
    opts.validate().map_err(EvalError::Options)?;
    let (t, r, working_crs, notes) = align(truth, result).map_err(EvalError::Crs)?;
    let (t, r) = localise(&t, &r);

    let pixel = pixel::pixel_scores(&t.markings, &r.markings, opts.pixel_m);
    let solid = pixel::solid_line(&t.markings, &r.markings, opts.pixel_m, opts.solid_tol_m);
    let pairs = objects::match_markings(&t.markings, &r.markings, opts.iou_min);
    let objects = objects::score(
        &t.markings,
        &r.markings,
        &pairs,
        &solid.truth_covered,
        &solid.result_covered,
        objects::SolidLength {
            precision: solid.scores.precision,
            recall: solid.scores.recall,
            f_score: solid.scores.f_score,
        },
        opts.iou_min,
    );
    let lanes = lanes::lane_scores(&t.lane_lines, &r.lane_lines, opts.lane_tol_m, opts.sample_m);
    let corners = corners::corner_scores(&t.markings, &r.markings, &pairs);
    let side = |ex: &Extraction| SideSummary {
        crs: crs_label(ex.crs.as_ref()),
        markings: ex.markings.len(),
        lane_lines: ex.lane_lines.len(),
    };
    Ok(rounded(&Report {
        truth: side(truth),
        result: side(result),
        working_crs,
        notes,
        options: opts.clone(),
        pixel,
        solid_line: solid.scores,
        objects,
        lanes,
        corners,
    }))
}

/// Read two GeoJSON files and score the second against the first.
pub fn evaluate_files(truth: &Path, result: &Path, opts: &EvalOptions) -> Result<Report, EvalError> {
    let t = read_geojson(truth).map_err(|e| EvalError::Input(e.to_string()))?;
    let r = read_geojson(result).map_err(|e| EvalError::Input(e.to_string()))?;
    evaluate(&t, &r, opts)
}

fn f(v: Option<f64>) -> String {
    v.map_or_else(|| "n/a".into(), |x| format!("{x:.4}"))
}

fn m(v: Option<f64>) -> String {
    v.map_or_else(|| "n/a".into(), |x| format!("{x:.3} m"))
}

impl Report {
    /// The human-readable table printed by `roadmark evaluate`.
    pub fn to_text(&self) -> String {
        let mut s = String::new();
        let o = &self.options;
        let _ = writeln!(
            s,
            "truth:  {} markings, {} lane lines ({})",
            self.truth.markings, self.truth.lane_lines, self.truth.crs
        );
        let _ = writeln!(
            s,
            "result: {} markings, {} lane lines ({})",
            self.result.markings, self.result.lane_lines, self.result.crs
        );
        let _ = writeln!(s, "scored in {}", self.working_crs);
        for n in &self.notes {
            let _ = writeln!(s, "note: {n}");
        }
        let p = &self.pixel;
        let _ = writeln!(s, "\n{:<34}{:>14}{:>13}{:>10}", "", "completeness", "correctness", "F-score");
        let _ = writeln!(
            s,
            "{:<34}{:>14}{:>13}{:>10}",
            format!("pixels ({} m)", o.pixel_m),
            f(p.completeness),
            f(p.correctness),
            f(p.f_score)
        );
        let sl = &self.solid_line;
        let _ = writeln!(
            s,
            "{:<34}{:>14}{:>13}{:>10}",
            format!("solid-line length (±{} m)", sl.tolerance_m),
            f(sl.recall),
            f(sl.precision),
            f(sl.f_score)
        );
        let l = &self.lanes;
        let _ = writeln!(
            s,
            "{:<34}{:>14}{:>13}{:>10}",
            format!("lane lines (±{} m)", l.tolerance_m),
            f(l.completeness),
            f(l.correctness),
            f(l.f_score)
        );
        let _ = writeln!(
            s,
            "  truth {:.1} m, result {:.1} m, solid-line truth {:.1} m found {}",
            l.truth_length_m,
            l.result_length_m,
            sl.truth_length_m,
            m(sl.detected_length_m)
        );
        let _ = writeln!(
            s,
            "  lane RMSE {}, pieces per truth line mean {} max {}, unmatched truth lines {}, class agreement {}",
            m(l.rmse_m),
            f(l.fragmentation_mean),
            l.fragmentation_max.map_or("n/a".into(), |x| x.to_string()),
            l.unmatched_truth_lines,
            f(l.class_agreement)
        );
        let ob = &self.objects;
        let _ = writeln!(
            s,
            "\nobjects (IoU >= {}){:>12}{:>7}{:>6}{:>6}{:>6}{:>11}{:>9}{:>9}",
            ob.iou_threshold, "truth", "result", "TP", "FP", "FN", "precision", "recall", "F1"
        );
        for c in &ob.per_class {
            let name = if c.method == "length" {
                format!("{} (length)", c.class)
            } else {
                c.class.clone()
            };
            let _ = writeln!(
                s,
                "  {:<28}{:>7}{:>7}{:>6}{:>6}{:>6}{:>11}{:>9}{:>9}",
                name,
                c.truth,
                c.result,
                c.tp,
                c.fp,
                c.fn_,
                f(c.precision),
                f(c.recall),
                f(c.f1)
            );
        }
        let d = &ob.detection;
        let _ = writeln!(
            s,
            "  {:<28}{:>7}{:>7}{:>6}{:>6}{:>6}{:>11}{:>9}{:>9}",
            "all (detection)",
            self.truth.markings,
            self.result.markings,
            d.tp,
            d.fp,
            d.fn_,
            f(d.precision),
            f(d.recall),
            f(d.f_score)
        );
        let _ = writeln!(
            s,
            "  macro-F1 {}, classification accuracy {}, mean IoU {}, solid-line fragments {} truth / {} result",
            f(ob.macro_f1),
            f(ob.classification_accuracy),
            f(ob.mean_iou),
            ob.solid_line_fragments[0],
            ob.solid_line_fragments[1]
        );
        if ob.confusion.labels.len() > 1 {
            let short = |l: &str| l.chars().take(9).collect::<String>();
            let _ = write!(s, "\nconfusion (rows truth, columns result)\n  {:<22}", "");
            for l in &ob.confusion.labels {
                let _ = write!(s, "{:>10}", short(l));
            }
            let _ = writeln!(s);
            for (label, row) in ob.confusion.labels.iter().zip(&ob.confusion.counts) {
                let _ = write!(s, "  {label:<22}");
                for v in row {
                    let _ = write!(s, "{v:>10}");
                }
                let _ = writeln!(s);
            }
        }
        let c = &self.corners;
        let _ = writeln!(
            s,
            "\noutline corners ({}): {} pairs, RMSE {}, max {}",
            c.classes.join(", "),
            c.pairs,
            m(c.rmse_m),
            m(c.max_m)
        );
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn options_are_validated() {
        assert!(EvalOptions::default().validate().is_ok());
        let bad = EvalOptions {
            pixel_m: 0.0,
            ..Default::default()
        };
        assert!(bad.validate().unwrap_err().contains("pixel_m"));
        let bad = EvalOptions {
            iou_min: 1.5,
            ..Default::default()
        };
        assert!(bad.validate().unwrap_err().contains("iou_min"));
        let e = evaluate(&Extraction::default(), &Extraction::default(), &bad).unwrap_err();
        assert!(e.to_string().contains("invalid evaluation options"));
    }

    #[test]
    fn harmonic_and_ratio_edge_cases() {
        assert_eq!(ratio(1.0, 0.0), None);
        assert_eq!(harmonic(None, None), None);
        assert_eq!(harmonic(Some(0.0), None), Some(0.0));
        assert_eq!(harmonic(Some(1.0), Some(1.0)), Some(1.0));
        assert_eq!(Prf::from_counts(0, 0, 0).f_score, None);
        assert_eq!(Prf::from_counts(0, 2, 0).f_score, Some(0.0));
    }

    #[test]
    fn empty_against_empty_is_all_undefined() {
        let r = evaluate(&Extraction::default(), &Extraction::default(), &EvalOptions::default()).unwrap();
        assert_eq!(r.pixel.f_score, None);
        assert_eq!(r.lanes.completeness, None);
        assert_eq!(r.objects.macro_f1, None);
        assert!(r.to_text().contains("n/a"));
    }

    #[test]
    fn geographic_truth_and_unknown_result_cannot_be_compared() {
        let t = Extraction {
            crs: Some(Crs::epsg(4326)),
            ..Default::default()
        };
        let e = evaluate(&t, &Extraction::default(), &EvalOptions::default()).unwrap_err();
        assert!(e.to_string().contains("CRS is unknown"), "{e}");
    }
}
