//! Object-level scores: one-to-one IoU matching, per-class precision/recall/F1, confusion.
//!
//! **What.** Every truth marking is matched to at most one result marking and vice versa;
//! the matched pairs give per-class true positives, a confusion matrix and the mean IoU.
//!
//! **Algorithm.**
//! 1. Candidate pairs come from a uniform grid over the bounding boxes (cell 5 m); their IoU is
//!    the exact polygon intersection area (geo's `BooleanOps`, i_overlay) over the union area.
//!    Identical outlines short-cut to exactly 1.
//! 2. Matching is class-agnostic and greedy: pairs with IoU ≥ `iou_min` in descending IoU
//!    (ties by truth, then result index) are taken when both sides are still free. Above
//!    IoU 0.5 a one-to-one matching is unique anyway; below it greedy is the COCO practice.
//! 3. Per class c: TP = matched pairs with both sides of class c; FN = truth of class c not
//!    in such a pair; FP = results of class c not in such a pair. A misclassified match is
//!    therefore an FN of the truth class and an FP of the result class, and shows in the
//!    confusion matrix (rows truth, columns result, plus `none` for missed / false).
//! 4. **Solid lines.** The marking layer holds arbitrary *pieces* of solid line, so IoU of
//!    pieces says little: a 100 m truth line found as ten 10 m pieces matches nothing at
//!    IoU ≥ 0.3. For `solid_line` the per-class precision/recall/F1 are therefore the
//!    length-based values of [`super::pixel::solid_line`] (`method: "length"`), and an
//!    unmatched solid-line piece at least half covered by the other side's solid lines (within
//!    the solid-line tolerance) is a *fragment*: it is neither missed nor false in the
//!    detection counts or the confusion matrix. Solid pieces still take part in the matching,
//!    so a dashed truth matched by a solid result shows up in the confusion matrix.
//! 5. Macro-F1 is the mean F1 over the classes present in the truth.
//!
//! **Parameters.** `iou_min` (0.3 as in the issue).
//!
//! **Reference.** Per-class detection with IoU matching as in Everingham et al., *The PASCAL
//! VOC challenge* (2010), at the lower IoU usual for thin road markings.
//!
//! **Complexity.** O(n + m) grid work plus one polygon intersection per overlapping pair,
//! O(p log p) to sort the p candidate pairs.

use super::{ClassScores, Confusion, ObjectScores, Prf, ratio};
use crate::pipeline::outline::to_polygon as polygon;
use crate::pipeline::types::{Marking, MarkingClass};
use geo::{Area, BooleanOps, Polygon};
use std::collections::HashMap;

/// Grid cell for candidate pairs (m).
const CELL_M: f64 = 5.0;

/// Intersection over union of two outlines (rings not closed), in [0, 1].
pub fn iou(a: &[[f64; 2]], b: &[[f64; 2]]) -> f64 {
    if a == b && a.len() >= 3 {
        return 1.0;
    }
    let (pa, pb) = (polygon(a), polygon(b));
    iou_polygons(&pa, pa.unsigned_area(), &pb, pb.unsigned_area())
}

fn iou_polygons(a: &Polygon<f64>, area_a: f64, b: &Polygon<f64>, area_b: f64) -> f64 {
    let inter = a.intersection(b).unsigned_area();
    let union = area_a + area_b - inter;
    if union <= 0.0 || !inter.is_finite() {
        return 0.0;
    }
    (inter / union).clamp(0.0, 1.0)
}

fn bbox(ring: &[[f64; 2]]) -> [f64; 4] {
    ring.iter().fold(
        [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY],
        |b, p| [b[0].min(p[0]), b[1].min(p[1]), b[2].max(p[0]), b[3].max(p[1])],
    )
}

fn overlaps(a: &[f64; 4], b: &[f64; 4]) -> bool {
    a[0] <= b[2] && b[0] <= a[2] && a[1] <= b[3] && b[1] <= a[3]
}

fn cells(b: &[f64; 4]) -> impl Iterator<Item = (i64, i64)> {
    let (x0, y0) = ((b[0] / CELL_M).floor() as i64, (b[1] / CELL_M).floor() as i64);
    let (x1, y1) = ((b[2] / CELL_M).floor() as i64, (b[3] / CELL_M).floor() as i64);
    (x0..=x1).flat_map(move |x| (y0..=y1).map(move |y| (x, y)))
}

/// Greedy one-to-one matching: (truth index, result index, IoU), sorted by truth index.
pub fn match_markings(truth: &[Marking], result: &[Marking], iou_min: f64) -> Vec<(usize, usize, f64)> {
    let t_box: Vec<[f64; 4]> = truth.iter().map(|m| bbox(&m.outline)).collect();
    let r_box: Vec<[f64; 4]> = result.iter().map(|m| bbox(&m.outline)).collect();
    let mut grid: HashMap<(i64, i64), Vec<usize>> = HashMap::new();
    for (j, b) in r_box.iter().enumerate() {
        for c in cells(b) {
            grid.entry(c).or_default().push(j);
        }
    }
    let r_poly: Vec<(Polygon<f64>, f64)> = result
        .iter()
        .map(|m| {
            let p = polygon(&m.outline);
            let a = p.unsigned_area();
            (p, a)
        })
        .collect();
    let mut candidates: Vec<(f64, usize, usize)> = Vec::new();
    let mut near: Vec<usize> = Vec::new();
    for (i, t) in truth.iter().enumerate() {
        near.clear();
        for c in cells(&t_box[i]) {
            if let Some(js) = grid.get(&c) {
                near.extend_from_slice(js);
            }
        }
        near.sort_unstable();
        near.dedup();
        let tp = polygon(&t.outline);
        let ta = tp.unsigned_area();
        for &j in near.iter().filter(|&&j| overlaps(&t_box[i], &r_box[j])) {
            let v = if t.outline == result[j].outline {
                1.0
            } else {
                iou_polygons(&tp, ta, &r_poly[j].0, r_poly[j].1)
            };
            if v >= iou_min {
                candidates.push((v, i, j));
            }
        }
    }
    candidates.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let (mut t_used, mut r_used) = (vec![false; truth.len()], vec![false; result.len()]);
    let mut pairs = Vec::new();
    for (v, i, j) in candidates {
        if !t_used[i] && !r_used[j] {
            t_used[i] = true;
            r_used[j] = true;
            pairs.push((i, j, v));
        }
    }
    pairs.sort_by_key(|p| p.0);
    pairs
}

/// Length-based solid-line scores, used for the `solid_line` class row.
#[derive(Clone, Copy, Debug)]
pub struct SolidLength {
    pub precision: Option<f64>,
    pub recall: Option<f64>,
    pub f_score: Option<f64>,
}

/// Scores from a matching. `t_fragment[i]` / `r_fragment[j]` mark solid-line pieces covered by
/// the other side (see the module docs); they are only consulted for unmatched markings.
pub fn score(
    truth: &[Marking],
    result: &[Marking],
    pairs: &[(usize, usize, f64)],
    t_fragment: &[bool],
    r_fragment: &[bool],
    solid: SolidLength,
    iou_min: f64,
) -> ObjectScores {
    let mut t_match = vec![None; truth.len()];
    let mut r_match = vec![None; result.len()];
    for &(i, j, _) in pairs {
        t_match[i] = Some(j);
        r_match[j] = Some(i);
    }
    let present: Vec<MarkingClass> = MarkingClass::ALL
        .into_iter()
        .filter(|c| truth.iter().chain(result).any(|m| m.class == *c))
        .collect();
    let idx = |c: MarkingClass| present.iter().position(|p| *p == c).expect("class is present");
    let none = present.len();
    let mut counts = vec![vec![0usize; none + 1]; none + 1];
    for (i, t) in truth.iter().enumerate() {
        match t_match[i] {
            Some(j) => counts[idx(t.class)][idx(result[j].class)] += 1,
            None if !t_fragment[i] => counts[idx(t.class)][none] += 1,
            None => {}
        }
    }
    for (j, r) in result.iter().enumerate() {
        if r_match[j].is_none() && !r_fragment[j] {
            counts[none][idx(r.class)] += 1;
        }
    }
    let missed: u64 = (0..none).map(|k| counts[k][none] as u64).sum();
    let false_: u64 = (0..none).map(|k| counts[none][k] as u64).sum();
    let detection = Prf::from_counts(pairs.len() as u64, false_, missed);
    let per_class: Vec<ClassScores> = present
        .iter()
        .enumerate()
        .map(|(k, &class)| {
            let tp = counts[k][k] as u64;
            let fn_ = (0..=none).filter(|&c| c != k).map(|c| counts[k][c] as u64).sum();
            let fp = (0..=none).filter(|&r| r != k).map(|r| counts[r][k] as u64).sum();
            let prf = Prf::from_counts(tp, fp, fn_);
            let (precision, recall, f1, method) = if class == MarkingClass::SolidLine {
                (solid.precision, solid.recall, solid.f_score, "length")
            } else {
                (prf.precision, prf.recall, prf.f_score, "iou")
            };
            ClassScores {
                class: class.as_str().to_string(),
                truth: truth.iter().filter(|m| m.class == class).count(),
                result: result.iter().filter(|m| m.class == class).count(),
                tp,
                fp,
                fn_,
                precision,
                recall,
                f1,
                method: method.to_string(),
            }
        })
        .collect();
    let in_truth: Vec<f64> = per_class
        .iter()
        .filter(|c| c.truth > 0)
        .map(|c| c.f1.unwrap_or(0.0))
        .collect();
    let same_class = pairs
        .iter()
        .filter(|&&(i, j, _)| truth[i].class == result[j].class)
        .count();
    let mut labels: Vec<String> = present.iter().map(|c| c.as_str().to_string()).collect();
    labels.push("none".into());
    ObjectScores {
        iou_threshold: iou_min,
        matched: pairs.len(),
        mean_iou: ratio(pairs.iter().map(|p| p.2).sum(), pairs.len() as f64),
        detection,
        classification_accuracy: ratio(same_class as f64, pairs.len() as f64),
        macro_f1: ratio(in_truth.iter().sum(), in_truth.len() as f64),
        per_class,
        confusion: Confusion { labels, counts },
        solid_line_fragments: [
            (0..truth.len())
                .filter(|&i| t_match[i].is_none() && t_fragment[i])
                .count(),
            (0..result.len())
                .filter(|&j| r_match[j].is_none() && r_fragment[j])
                .count(),
        ],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn mk(id: &str, class: MarkingClass, x0: f64, y0: f64, w: f64, h: f64) -> Marking {
        Marking {
            id: id.into(),
            class,
            outline: vec![[x0, y0], [x0 + w, y0], [x0 + w, y0 + h], [x0, y0 + h]],
            confidence: 1.0,
            length_m: h.max(w),
            width_m: h.min(w),
            heading_deg: 0.0,
            point_count: 0,
        }
    }

    const NO_SOLID: SolidLength = SolidLength {
        precision: None,
        recall: None,
        f_score: None,
    };

    #[test]
    fn iou_of_simple_cases() {
        let a = mk("a", MarkingClass::DashedLine, 0.0, 0.0, 1.0, 1.0).outline;
        let b = mk("b", MarkingClass::DashedLine, 0.5, 0.0, 1.0, 1.0).outline;
        let c = mk("c", MarkingClass::DashedLine, 5.0, 0.0, 1.0, 1.0).outline;
        assert_eq!(iou(&a, &a), 1.0);
        assert!((iou(&a, &b) - 1.0 / 3.0).abs() < 1e-12);
        assert_eq!(iou(&a, &c), 0.0);
        let mut rev = a.clone();
        rev.reverse();
        assert!((iou(&a, &rev) - 1.0).abs() < 1e-12, "orientation does not matter");
    }

    #[test]
    fn matching_is_one_to_one_and_prefers_higher_iou() {
        use MarkingClass::*;
        let truth = vec![mk("t0", DashedLine, 0.0, 0.0, 0.15, 6.0)];
        let result = vec![
            mk("r0", DashedLine, 0.0, 1.0, 0.15, 6.0), // IoU 5/7
            mk("r1", DashedLine, 0.0, 0.5, 0.15, 6.0), // IoU 5.5/6.5
        ];
        let pairs = match_markings(&truth, &result, 0.3);
        assert_eq!(pairs.len(), 1);
        assert_eq!(pairs[0].1, 1);
        let s = score(&truth, &result, &pairs, &[false], &[false, false], NO_SOLID, 0.3);
        assert_eq!((s.detection.tp, s.detection.fp, s.detection.fn_), (1, 1, 0));
    }

    #[test]
    fn wrong_class_missed_and_false_fill_the_confusion_matrix() {
        use MarkingClass::*;
        let truth = vec![
            mk("a", DashedLine, 0.0, 0.0, 0.15, 6.0),
            mk("b", StopLine, 10.0, 0.0, 4.0, 0.4),
            mk("c", StraightArrow, 20.0, 0.0, 1.0, 5.0),
        ];
        let result = vec![
            mk("x", DashedLine, 0.0, 0.0, 0.15, 6.0),
            mk("y", Crosswalk, 10.0, 0.0, 4.0, 0.4),
            mk("z", Diamond, 40.0, 0.0, 1.0, 1.0),
        ];
        let pairs = match_markings(&truth, &result, 0.3);
        let s = score(&truth, &result, &pairs, &[false; 3], &[false; 3], NO_SOLID, 0.3);
        assert_eq!(
            s.confusion.labels,
            [
                "dashed_line",
                "straight_arrow",
                "crosswalk",
                "diamond",
                "stop_line",
                "none"
            ]
        );
        let at = |t: &str, r: &str| {
            let l = &s.confusion.labels;
            s.confusion.counts[l.iter().position(|x| x == t).unwrap()][l.iter().position(|x| x == r).unwrap()]
        };
        assert_eq!(at("dashed_line", "dashed_line"), 1);
        assert_eq!(at("stop_line", "crosswalk"), 1);
        assert_eq!(at("straight_arrow", "none"), 1);
        assert_eq!(at("none", "diamond"), 1);
        assert_eq!((s.detection.tp, s.detection.fp, s.detection.fn_), (2, 1, 1));
        assert_eq!(s.classification_accuracy, Some(0.5));
        let class = |c: &str| s.per_class.iter().find(|x| x.class == c).unwrap();
        assert_eq!(class("dashed_line").f1, Some(1.0));
        assert_eq!((class("stop_line").tp, class("stop_line").fn_), (0, 1));
        assert_eq!((class("crosswalk").fp, class("crosswalk").recall), (1, None));
        assert_eq!(class("straight_arrow").recall, Some(0.0));
        // Macro-F1 over the truth classes: dashed 1, stop 0, arrow 0.
        assert!((s.macro_f1.unwrap() - 1.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn solid_line_fragments_are_not_errors() {
        use MarkingClass::*;
        let truth = vec![mk("t", SolidLine, 0.0, 0.0, 0.15, 100.0)];
        let result: Vec<Marking> = (0..10)
            .map(|k| mk(&format!("r{k}"), SolidLine, 0.0, 10.0 * k as f64, 0.15, 10.0))
            .collect();
        let pairs = match_markings(&truth, &result, 0.3);
        assert!(pairs.is_empty(), "10 m pieces do not reach IoU 0.3 with 100 m");
        let solid = SolidLength {
            precision: Some(1.0),
            recall: Some(1.0),
            f_score: Some(1.0),
        };
        let s = score(&truth, &result, &pairs, &[true], &[true; 10], solid, 0.3);
        assert_eq!((s.detection.fp, s.detection.fn_), (0, 0));
        assert_eq!(s.solid_line_fragments, [1, 10]);
        let row = &s.per_class[0];
        assert_eq!((row.method.as_str(), row.f1), ("length", Some(1.0)));
    }

    proptest! {
        #[test]
        fn iou_is_in_unit_interval_and_symmetric(
            pa in proptest::collection::vec((-5.0f64..5.0, -5.0f64..5.0), 3..7),
            pb in proptest::collection::vec((-5.0f64..5.0, -5.0f64..5.0), 3..7)) {
            // Convex hulls of random points: valid simple polygons.
            use geo::ConvexHull;
            let hull = |p: &Vec<(f64, f64)>| -> Vec<[f64; 2]> {
                let mp = geo::MultiPoint::from(p.clone());
                let h = mp.convex_hull();
                let mut r: Vec<[f64; 2]> = h.exterior().coords().map(|c| [c.x, c.y]).collect();
                r.pop();
                r
            };
            let (a, b) = (hull(&pa), hull(&pb));
            prop_assume!(a.len() >= 3 && b.len() >= 3);
            let v = iou(&a, &b);
            prop_assert!((0.0..=1.0).contains(&v));
            prop_assert!((v - iou(&b, &a)).abs() < 1e-9);
            prop_assert!((iou(&a, &a) - 1.0).abs() < 1e-12);
        }
    }
}
