//! Pixel-level scores of the marking layer, and the length-based solid-line scores.
//!
//! **What.** (1) Completeness / correctness / F-score of the painted area, class-agnostic, as
//! in Yao 2019/2021: truth and result marking polygons are rasterised on one grid and counted
//! pixel by pixel. (2) For `solid_line`, the fraction of truth solid-line area (≈ length, the
//! width being constant) found by result solid lines and vice versa, within a tolerance.
//!
//! **Algorithm.** Both marking layers become [`SpanSet`]s at `pixel_m` (pixel-centre rule, one
//! grid anchored at the local origin, so a shift by whole pixels is exact). TP = |T ∩ R|,
//! FN = |T| − TP, FP = |R| − TP; completeness = TP/(TP+FN), correctness = TP/(TP+FP),
//! F = 2·TP/(2·TP+FP+FN). Solid lines: recall = |T_s ∩ dilate(R_s, tol)| / |T_s| and
//! precision = |R_s ∩ dilate(T_s, tol)| / |R_s| with a disk of radius `solid_tol_m`; a
//! result that follows the painted line a few centimetres off still counts as finding its
//! length, which pure overlap would not. Each solid-line piece also gets its own coverage,
//! for the fragment rule of [`super::objects`].
//!
//! **Parameters.** `pixel_m` (0.05 m), `solid_tol_m` (0.15 m).
//!
//! **Reference.** Yao et al. 2019 (ISPRS) and 2021 (Remote Sensing 13:2612), pixel-level
//! completeness/correctness/F-score; Yao 2019 reports solid-line detection as a length ratio.
//!
//! **Complexity.** O(C log C) in the number of row crossings, memory O(runs); the dilation
//! multiplies the runs by 2·tol/px + 1.

use super::raster::SpanSet;
use super::{PixelScores, SolidLineScores, harmonic, ratio};
use crate::pipeline::types::{Marking, MarkingClass};

/// Pixel-level completeness, correctness and F-score of all markings (any class).
pub fn pixel_scores(truth: &[Marking], result: &[Marking], pixel_m: f64) -> PixelScores {
    let t = SpanSet::from_polygons(truth.iter().map(|m| m.outline.as_slice()), pixel_m);
    let r = SpanSet::from_polygons(result.iter().map(|m| m.outline.as_slice()), pixel_m);
    let tp = t.intersection_count(&r);
    let (nt, nr) = (t.count(), r.count());
    let (fp, fn_) = (nr - tp, nt - tp);
    PixelScores {
        pixel_m,
        truth_px: nt,
        result_px: nr,
        tp_px: tp,
        fp_px: fp,
        fn_px: fn_,
        completeness: ratio(tp as f64, nt as f64),
        correctness: ratio(tp as f64, nr as f64),
        f_score: ratio(2.0 * tp as f64, (2 * tp + fp + fn_) as f64),
    }
}

/// Solid-line scores plus, per marking, whether it is a solid-line piece at least half covered
/// by the other side's solid lines (truth flags, result flags).
pub struct SolidLine {
    pub scores: SolidLineScores,
    pub truth_covered: Vec<bool>,
    pub result_covered: Vec<bool>,
}

fn solid_rings(ms: &[Marking]) -> impl Iterator<Item = &[[f64; 2]]> {
    ms.iter()
        .filter(|m| m.class == MarkingClass::SolidLine)
        .map(|m| m.outline.as_slice())
}

/// Whether each solid-line piece of `ms` is at least half inside `cover`.
fn covered_pieces(ms: &[Marking], cover: &SpanSet, pixel_m: f64) -> Vec<bool> {
    ms.iter()
        .map(|m| {
            if m.class != MarkingClass::SolidLine {
                return false;
            }
            let own = SpanSet::from_polygons([m.outline.as_slice()], pixel_m);
            let n = own.count();
            n > 0 && 2 * own.intersection_count(cover) >= n
        })
        .collect()
}

/// Length-based solid-line recall/precision within `solid_tol_m`.
pub fn solid_line(truth: &[Marking], result: &[Marking], pixel_m: f64, solid_tol_m: f64) -> SolidLine {
    let t = SpanSet::from_polygons(solid_rings(truth), pixel_m);
    let r = SpanSet::from_polygons(solid_rings(result), pixel_m);
    let radius = (solid_tol_m / pixel_m).round() as i64;
    let (td, rd) = (t.dilate(radius), r.dilate(radius));
    let recall = ratio(t.intersection_count(&rd) as f64, t.count() as f64);
    let precision = ratio(r.intersection_count(&td) as f64, r.count() as f64);
    let length = |ms: &[Marking]| -> f64 {
        ms.iter()
            .filter(|m| m.class == MarkingClass::SolidLine)
            .map(|m| m.length_m)
            .sum()
    };
    let truth_length_m = length(truth);
    SolidLine {
        scores: SolidLineScores {
            tolerance_m: solid_tol_m,
            truth_pieces: solid_rings(truth).count(),
            result_pieces: solid_rings(result).count(),
            truth_length_m,
            result_length_m: length(result),
            detected_length_m: recall.map(|r| r * truth_length_m),
            recall,
            precision,
            f_score: harmonic(precision, recall),
        },
        truth_covered: covered_pieces(truth, &rd, pixel_m),
        result_covered: covered_pieces(result, &td, pixel_m),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn bar(class: MarkingClass, x0: f64, y0: f64, w: f64, h: f64) -> Marking {
        Marking {
            id: format!("{x0},{y0}"),
            class,
            outline: vec![[x0, y0], [x0 + w, y0], [x0 + w, y0 + h], [x0, y0 + h]],
            confidence: 1.0,
            length_m: h.max(w),
            width_m: h.min(w),
            heading_deg: 0.0,
            point_count: 0,
        }
    }

    #[test]
    fn empty_sides() {
        let none: Vec<Marking> = vec![];
        let s = pixel_scores(&none, &none, 0.05);
        assert_eq!((s.completeness, s.correctness, s.f_score), (None, None, None));
        let one = vec![bar(MarkingClass::DashedLine, 0.0, 0.0, 0.15, 6.0)];
        let s = pixel_scores(&one, &none, 0.05);
        assert_eq!((s.completeness, s.correctness, s.f_score), (Some(0.0), None, Some(0.0)));
    }

    #[test]
    fn lateral_shift_of_two_pixels_leaves_a_third() {
        // A 0.15 m wide dash shifted 0.10 m sideways: 1 of 3 pixel columns still overlaps.
        let t = vec![bar(MarkingClass::DashedLine, 10.0, 10.0, 0.15, 6.0)];
        let r = vec![bar(MarkingClass::DashedLine, 10.1, 10.0, 0.15, 6.0)];
        let s = pixel_scores(&t, &r, 0.05);
        assert_eq!((s.truth_px, s.tp_px, s.fp_px, s.fn_px), (360, 120, 240, 240));
        assert!((s.f_score.unwrap() - 1.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn solid_line_length_tolerates_a_small_offset() {
        use MarkingClass::SolidLine as S;
        let t = vec![bar(S, 0.0, 0.0, 0.15, 100.0)];
        // Found over 0..60 m, 0.05 m to the side, in three pieces; plus a false piece.
        let r = vec![
            bar(S, 0.05, 0.0, 0.15, 20.0),
            bar(S, 0.05, 20.0, 0.15, 20.0),
            bar(S, 0.05, 40.0, 0.15, 20.0),
            bar(S, 5.0, 0.0, 0.15, 20.0),
        ];
        let out = solid_line(&t, &r, 0.05, 0.15);
        // 60 m plus the 0.15 m tolerance past the end of the last piece.
        assert!((out.scores.recall.unwrap() - 0.6015).abs() < 1e-3, "{:?}", out.scores.recall);
        assert!((out.scores.precision.unwrap() - 0.75).abs() < 1e-3);
        assert!((out.scores.detected_length_m.unwrap() - 60.15).abs() < 0.1);
        assert_eq!(out.truth_covered, [true]);
        assert_eq!(out.result_covered, [true, true, true, false]);
        // Without tolerance, two thirds of the width overlap.
        let strict = solid_line(&t, &r, 0.05, 0.0);
        assert!((strict.scores.recall.unwrap() - 0.4).abs() < 1e-3);
    }

    proptest! {
        #[test]
        fn pixel_f_is_symmetric(a in proptest::collection::vec((0.0f64..20.0, 0.0f64..20.0, 0.1f64..3.0, 0.1f64..3.0), 0..6),
                                b in proptest::collection::vec((0.0f64..20.0, 0.0f64..20.0, 0.1f64..3.0, 0.1f64..3.0), 0..6)) {
            let ms = |v: &Vec<(f64, f64, f64, f64)>| -> Vec<Marking> {
                v.iter().map(|&(x, y, w, h)| bar(MarkingClass::Unknown, x, y, w, h)).collect()
            };
            let (ta, tb) = (ms(&a), ms(&b));
            let ab = pixel_scores(&ta, &tb, 0.05);
            let ba = pixel_scores(&tb, &ta, 0.05);
            prop_assert_eq!(ab.f_score, ba.f_score);
            prop_assert_eq!(ab.completeness, ba.correctness);
            if !ta.is_empty() {
                let me = pixel_scores(&ta, &ta, 0.05);
                prop_assert_eq!(me.f_score, Some(1.0));
            }
        }
    }
}
