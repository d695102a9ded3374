//! Outline corner RMSE of matched rectangle-like markings.
//!
//! **What.** For every matched pair (see [`super::objects`]) whose truth and result are both
//! rectangle-like (`dashed_line`, `stop_line`, `crosswalk`), the distances between the
//! corresponding corners of their minimum rotated rectangles; reported as one RMSE over all
//! corners, plus the largest corner error.
//!
//! **Algorithm.** geo's `MinimumRotatedRect` (rotating calipers on the convex hull) gives four
//! corners per outline. Corners are paired one-to-one by the cyclic correspondence (4 starting
//! corners × 2 directions) with the least sum of squared distances: this is the nearest-corner
//! pairing made one-to-one, so two result corners never claim the same truth corner.
//!
//! **Parameters.** None (the matching's IoU threshold decides which pairs exist).
//!
//! **Reference.** Pan et al. 2019 (ISPRS) report the corner-point RMSE of the vectorised
//! markings.
//!
//! **Complexity.** O(v log v) per marking of v vertices, O(1) per pair.

use super::{CornerScores, ratio};
use crate::pipeline::types::{Marking, MarkingClass};
use geo::MinimumRotatedRect;

/// Classes whose outline is a rectangle.
pub const RECTANGLE_CLASSES: [MarkingClass; 3] =
    [MarkingClass::DashedLine, MarkingClass::StopLine, MarkingClass::Crosswalk];

/// The four corners of the minimum rotated rectangle of an outline.
pub fn rectangle_corners(outline: &[[f64; 2]]) -> Option<[[f64; 2]; 4]> {
    let mp: geo::MultiPoint<f64> = outline.iter().map(|p| geo::Point::new(p[0], p[1])).collect();
    let rect = mp.minimum_rotated_rect()?;
    let c = &rect.exterior().0;
    if c.len() < 4 {
        return None;
    }
    Some([0, 1, 2, 3].map(|k| [c[k].x, c[k].y]))
}

/// Squared corner distances under the best one-to-one cyclic pairing.
pub fn paired_corner_sq(a: &[[f64; 2]; 4], b: &[[f64; 2]; 4]) -> [f64; 4] {
    let d2 = |p: [f64; 2], q: [f64; 2]| (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2);
    let mut best = [f64::INFINITY; 4];
    let mut best_sum = f64::INFINITY;
    for start in 0..4 {
        for dir in [1usize, 3] {
            let e: [f64; 4] = [0, 1, 2, 3].map(|k| d2(a[k], b[(start + dir * k) % 4]));
            let sum: f64 = e.iter().sum();
            if sum < best_sum {
                best_sum = sum;
                best = e;
            }
        }
    }
    best
}

/// Corner RMSE over matched rectangle-like pairs.
pub fn corner_scores(truth: &[Marking], result: &[Marking], pairs: &[(usize, usize, f64)]) -> CornerScores {
    let (mut n_pairs, mut sq, mut max2) = (0usize, 0.0, 0.0f64);
    for &(i, j, _) in pairs {
        let (t, r) = (&truth[i], &result[j]);
        if !(RECTANGLE_CLASSES.contains(&t.class) && RECTANGLE_CLASSES.contains(&r.class)) {
            continue;
        }
        let (Some(a), Some(b)) = (rectangle_corners(&t.outline), rectangle_corners(&r.outline)) else {
            continue;
        };
        let e = paired_corner_sq(&a, &b);
        n_pairs += 1;
        sq += e.iter().sum::<f64>();
        max2 = e.iter().copied().fold(max2, f64::max);
    }
    CornerScores {
        classes: RECTANGLE_CLASSES.iter().map(|c| c.as_str().to_string()).collect(),
        pairs: n_pairs,
        rmse_m: ratio(sq, 4.0 * n_pairs as f64).map(f64::sqrt),
        max_m: (n_pairs > 0).then(|| max2.sqrt()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mk(class: MarkingClass, ring: &[[f64; 2]]) -> Marking {
        Marking {
            id: "m".into(),
            class,
            outline: ring.to_vec(),
            confidence: 1.0,
            length_m: 0.0,
            width_m: 0.0,
            heading_deg: 0.0,
            point_count: 0,
        }
    }

    #[test]
    fn identical_outlines_have_zero_error() {
        let r = [[0.0, 0.0], [0.15, 0.0], [0.15, 6.0], [0.0, 6.0]];
        let t = vec![mk(MarkingClass::DashedLine, &r)];
        let s = corner_scores(&t, &t, &[(0, 0, 1.0)]);
        assert_eq!((s.pairs, s.rmse_m, s.max_m), (1, Some(0.0), Some(0.0)));
    }

    #[test]
    fn shifted_and_reordered_rectangle() {
        let t = vec![mk(MarkingClass::StopLine, &[[0.0, 0.0], [4.0, 0.0], [4.0, 0.4], [0.0, 0.4]])];
        // Same rectangle 3 cm east, listed clockwise from another corner, with an extra
        // vertex on one side (the MRR removes it).
        let r = vec![mk(
            MarkingClass::StopLine,
            &[[4.03, 0.4], [4.03, 0.0], [2.0, 0.0], [0.03, 0.0], [0.03, 0.4]],
        )];
        let s = corner_scores(&t, &r, &[(0, 0, 0.9)]);
        assert!((s.rmse_m.unwrap() - 0.03).abs() < 1e-9, "{:?}", s.rmse_m);
        // Pairs of other classes are not rectangles.
        let arrows = vec![mk(MarkingClass::StraightArrow, &t[0].outline)];
        assert_eq!(corner_scores(&arrows, &arrows, &[(0, 0, 1.0)]).rmse_m, None);
    }

    #[test]
    fn pairing_is_one_to_one() {
        let a = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
        let b = [[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]];
        assert_eq!(paired_corner_sq(&a, &b), [0.0; 4]);
    }
}
