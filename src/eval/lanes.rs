//! Lane-line scores: completeness, correctness, RMSE, fragmentation, class agreement.
//!
//! **What.** How much of the truth lane-line length the result reproduces within a buffer,
//! how much of the result is true, how far off the matched parts are, into how many pieces
//! each truth lane line was broken, and whether solid/dashed agree.
//!
//! **Algorithm.** Every polyline is cut into pieces of at most `sample_m` per segment; each
//! piece is a sample at its midpoint weighted by its length (so weights sum to the exact
//! length). A sample is *matched* when the nearest segment of the other side (any class) is
//! within `tol_m`; nearest segments come from a uniform grid of segments (1 m cells, exact
//! point–segment distances, ties to the lower line index).
//! - completeness = matched truth length / truth length; correctness = matched result
//!   length / result length; F = their harmonic mean;
//! - RMSE = √(Σ w·d² / Σ w) over matched truth samples (d = distance to the nearest result);
//! - fragmentation of a truth line = number of result lines that are the nearest match over
//!   at least min(1 m, 20 % of the truth line) of it; mean and max over truth lines that are
//!   matched at all (unmatched ones are counted separately);
//! - class agreement = matched truth length whose nearest result line has the same class /
//!   matched truth length.
//!
//! **Parameters.** `tol_m` (0.15 m), `sample_m` (0.1 m).
//!
//! **Reference.** Buffer-based completeness/correctness of road centrelines: Wiedemann et
//! al., *Empirical evaluation of automatically extracted road axes* (1998); the 0.15 m buffer
//! follows the lane-marking literature (Yao 2021).
//!
//! **Complexity.** O(S · k) for S samples and k segments per grid neighbourhood.

use super::{LaneScores, harmonic, ratio};
use crate::pipeline::types::LaneLine;
use std::collections::HashMap;

const CELL_M: f64 = 1.0;

struct Sample {
    p: [f64; 2],
    w: f64,
    line: usize,
}

fn samples(lines: &[LaneLine], step: f64) -> Vec<Sample> {
    let mut out = Vec::new();
    for (k, l) in lines.iter().enumerate() {
        for seg in l.line.windows(2) {
            let (a, b) = (seg[0], seg[1]);
            let len = (b[0] - a[0]).hypot(b[1] - a[1]);
            if len == 0.0 {
                continue;
            }
            let n = (len / step).ceil().max(1.0) as usize;
            for i in 0..n {
                let f = (i as f64 + 0.5) / n as f64;
                out.push(Sample {
                    p: [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1])],
                    w: len / n as f64,
                    line: k,
                });
            }
        }
    }
    out
}

fn point_segment_distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let l2 = dx * dx + dy * dy;
    let t = if l2 > 0.0 {
        (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p[0] - a[0] - t * dx).hypot(p[1] - a[1] - t * dy)
}

/// Segments of a set of polylines in a uniform grid.
struct SegmentIndex {
    segs: Vec<([f64; 2], [f64; 2], usize)>,
    grid: HashMap<(i64, i64), Vec<u32>>,
}

fn cell(v: f64) -> i64 {
    (v / CELL_M).floor() as i64
}

impl SegmentIndex {
    fn new(lines: &[LaneLine]) -> Self {
        let mut segs = Vec::new();
        let mut grid: HashMap<(i64, i64), Vec<u32>> = HashMap::new();
        for (k, l) in lines.iter().enumerate() {
            for s in l.line.windows(2) {
                let id = segs.len() as u32;
                segs.push((s[0], s[1], k));
                for cx in cell(s[0][0].min(s[1][0]))..=cell(s[0][0].max(s[1][0])) {
                    for cy in cell(s[0][1].min(s[1][1]))..=cell(s[0][1].max(s[1][1])) {
                        grid.entry((cx, cy)).or_default().push(id);
                    }
                }
            }
        }
        Self { segs, grid }
    }

    /// Nearest (distance, line index) within `tol`.
    fn nearest(&self, p: [f64; 2], tol: f64) -> Option<(f64, usize)> {
        let mut best: Option<(f64, usize)> = None;
        for cx in cell(p[0] - tol)..=cell(p[0] + tol) {
            for cy in cell(p[1] - tol)..=cell(p[1] + tol) {
                for &id in self.grid.get(&(cx, cy)).map(Vec::as_slice).unwrap_or(&[]) {
                    let (a, b, line) = self.segs[id as usize];
                    let d = point_segment_distance(p, a, b);
                    if d <= tol && best.is_none_or(|(bd, bl)| (d, line) < (bd, bl)) {
                        best = Some((d, line));
                    }
                }
            }
        }
        best
    }
}

/// Lane-line scores of `result` against `truth` (local metric coordinates).
pub fn lane_scores(truth: &[LaneLine], result: &[LaneLine], tol_m: f64, sample_m: f64) -> LaneScores {
    let (ts, rs) = (samples(truth, sample_m), samples(result, sample_m));
    let (t_index, r_index) = (SegmentIndex::new(truth), SegmentIndex::new(result));
    let truth_len: f64 = ts.iter().map(|s| s.w).sum();
    let result_len: f64 = rs.iter().map(|s| s.w).sum();

    let (mut matched, mut sq, mut same_class) = (0.0, 0.0, 0.0);
    // Per truth line: matched length per result line.
    let mut pieces: Vec<HashMap<usize, f64>> = vec![HashMap::new(); truth.len()];
    for s in &ts {
        if let Some((d, r)) = r_index.nearest(s.p, tol_m) {
            matched += s.w;
            sq += s.w * d * d;
            if truth[s.line].class == result[r].class {
                same_class += s.w;
            }
            *pieces[s.line].entry(r).or_default() += s.w;
        }
    }
    let r_matched: f64 = rs
        .iter()
        .filter(|s| t_index.nearest(s.p, tol_m).is_some())
        .map(|s| s.w)
        .sum();
    let counts: Vec<usize> = pieces
        .iter()
        .zip(truth)
        .map(|(m, t)| {
            let min_m = (0.2 * t.length_m.max(0.0)).min(1.0);
            m.values().filter(|&&len| len >= min_m).count()
        })
        .collect();
    let found: Vec<usize> = counts.iter().copied().filter(|&c| c > 0).collect();
    let completeness = ratio(matched, truth_len);
    let correctness = ratio(r_matched, result_len);
    LaneScores {
        tolerance_m: tol_m,
        sample_m,
        truth_lines: truth.len(),
        result_lines: result.len(),
        truth_length_m: truth_len,
        result_length_m: result_len,
        completeness,
        correctness,
        f_score: harmonic(correctness, completeness),
        rmse_m: ratio(sq, matched).map(f64::sqrt),
        fragmentation_mean: ratio(found.iter().sum::<usize>() as f64, found.len() as f64),
        fragmentation_max: found.iter().copied().max(),
        unmatched_truth_lines: counts.len() - found.len(),
        class_agreement: ratio(same_class, matched),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::types::LaneLineClass;

    fn line(id: &str, class: LaneLineClass, pts: &[[f64; 2]]) -> LaneLine {
        LaneLine {
            id: id.into(),
            class,
            line: pts.to_vec(),
            confidence: 1.0,
            length_m: pts.windows(2).map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1])).sum(),
            marking_ids: vec![],
        }
    }
    use LaneLineClass::{DashedLine as D, SolidLine as S};

    #[test]
    fn self_is_perfect_and_empty_is_none() {
        let t = vec![line("a", S, &[[0.0, 0.0], [30.0, 0.3], [60.0, 2.0]]), line("b", D, &[[0.0, 3.5], [60.0, 3.5]])];
        let s = lane_scores(&t, &t, 0.15, 0.1);
        assert_eq!((s.completeness, s.correctness, s.f_score), (Some(1.0), Some(1.0), Some(1.0)));
        assert!(s.rmse_m.unwrap() < 1e-12);
        assert_eq!((s.fragmentation_mean, s.fragmentation_max), (Some(1.0), Some(1)));
        assert_eq!(s.class_agreement, Some(1.0));
        let e = lane_scores(&[], &[], 0.15, 0.1);
        assert_eq!((e.completeness, e.correctness, e.rmse_m), (None, None, None));
        let miss = lane_scores(&t, &[], 0.15, 0.1);
        assert_eq!((miss.completeness, miss.f_score, miss.unmatched_truth_lines), (Some(0.0), Some(0.0), 2));
    }

    #[test]
    fn shift_inside_and_outside_the_tolerance() {
        let t = vec![line("a", S, &[[0.0, 0.0], [50.0, 0.0]])];
        let r = vec![line("x", S, &[[0.0, 0.1], [50.0, 0.1]])];
        let s = lane_scores(&t, &r, 0.15, 0.1);
        assert_eq!(s.completeness, Some(1.0));
        assert!((s.rmse_m.unwrap() - 0.1).abs() < 1e-9);
        let far = vec![line("x", S, &[[0.0, 0.2], [50.0, 0.2]])];
        assert_eq!(lane_scores(&t, &far, 0.15, 0.1).completeness, Some(0.0));
    }

    #[test]
    fn split_line_has_fragmentation_two_and_wrong_class_disagrees() {
        let t = vec![line("a", D, &[[0.0, 0.0], [100.0, 0.0]])];
        let r = vec![
            line("x", D, &[[0.0, 0.0], [50.0, 0.0]]),
            line("y", S, &[[50.0, 0.0], [80.0, 0.0]]),
        ];
        let s = lane_scores(&t, &r, 0.15, 0.1);
        assert_eq!((s.fragmentation_mean, s.fragmentation_max), (Some(2.0), Some(2)));
        // 80 m plus the buffer past the end of the last piece.
        assert!((s.completeness.unwrap() - 0.8).abs() < 0.003);
        assert_eq!(s.correctness, Some(1.0));
        assert!((s.class_agreement.unwrap() - 50.0 / 80.0).abs() < 0.003);
    }

    #[test]
    fn a_crossing_line_is_not_a_fragment() {
        let t = vec![line("a", S, &[[0.0, 0.0], [100.0, 0.0]])];
        let r = vec![
            line("x", S, &[[0.0, 0.0], [100.0, 0.0]]),
            line("y", S, &[[50.0, -5.0], [50.0, 5.0]]),
        ];
        assert_eq!(lane_scores(&t, &r, 0.15, 0.1).fragmentation_max, Some(1));
    }
}
