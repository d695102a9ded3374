//! Dash regularisation along a dashed lane line.
//!
//! **What.** The dashes of one dashed lane line are painted to one design: a dash length
//! `L`, a period `P` (dash + gap) and a width. What the scanner sees of a dash is often
//! less: worn paint, a car's shadow, or the sparse scan lines of a far lane leave only part
//! of it, and the outline drawn from those points is short (IoU with the painted dash well
//! under 0.5). A dash can also be missing altogether. Given the stations (distance along the
//! lane line) of the dashes that were seen, this module estimates the line's design from
//! its complete dashes and returns (a) the painted extent of every short dash that fits the
//! pattern and (b) the dashes missing from an otherwise regular run.
//!
//! **Algorithm** (1-D, on stations; written here: no library does this).
//! 1. `L` = median of the longer half of the dash lengths (worn or sparse dashes are only
//!    ever shorter than painted, so the upper half is the reliable one). Complete dashes
//!    are those within [0.85, 1.2] × `L`; at least 3 are needed.
//! 2. `P` from the spacing of consecutive complete dashes' centres: each spacing is divided
//!    by its multiple of the smallest spacing (a missing or short dash in between makes it
//!    a multiple), `P` is the median of these; at least 70 % of the spacings must lie within
//!    `max(0.25 m, 5 % P)` × multiple of a whole multiple of `P`, or the line is not regular
//!    and nothing is changed.
//! 3. A short dash is placed on the pattern of the nearest complete dash (at most 4 periods
//!    away): the painted dash whose centre is a whole number of periods from it must contain
//!    the short dash (within `max(0.3 m, 10 % L)` at both ends); it is then extended to that
//!    painted dash (and given the median width of the complete dashes, if it looked
//!    narrower).
//! 4. Between consecutive dashes `n` periods apart (2 ≤ n ≤ `fill_max` + 1, within the same
//!    tolerance), the `n - 1` missing dashes are added.
//!
//! **Complexity.** O(d log d) for d dashes.

use super::geom::median;

/// One dash as seen along its lane line.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Span {
    /// Caller's key (index of the piece).
    pub key: usize,
    /// Start and end station along the lane line (m), `a <= b`.
    pub a: f64,
    pub b: f64,
    pub width: f64,
    pub confidence: f64,
}

/// What to change.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Plan {
    /// (key, new start, new end, new width) of dashes to extend.
    pub extend: Vec<(usize, f64, f64, f64)>,
    /// (start, end, width, confidence) of missing dashes to add.
    pub fill: Vec<(f64, f64, f64, f64)>,
    /// The design found: dash length and period (m).
    pub dash_length: f64,
    pub period: f64,
}

/// The regularisation plan of one dashed lane line (see the module docs). `fill_max` is the
/// most consecutive missing dashes added (0: none).
pub fn plan(spans: &[Span], fill_max: usize) -> Plan {
    let mut out = Plan::default();
    if spans.len() < 4 {
        return out;
    }
    // 1. Dash length from the longer half.
    let mut lens: Vec<f64> = spans.iter().map(|s| s.b - s.a).collect();
    lens.sort_by(|x, y| y.total_cmp(x));
    let half = lens.len().div_ceil(2);
    let l = median(&mut lens[..half]);
    if l.is_nan() || l <= 0.1 {
        return out;
    }
    let centre = |s: &Span| 0.5 * (s.a + s.b);
    let is_full = |s: &Span| {
        let len = s.b - s.a;
        len >= 0.85 * l && len <= 1.2 * l
    };
    let mut full: Vec<&Span> = spans.iter().filter(|s| is_full(s)).collect();
    if full.len() < 3 {
        return out;
    }
    full.sort_by(|x, y| centre(x).total_cmp(&centre(y)));
    // 2. Period.
    let diffs: Vec<f64> = full.windows(2).map(|w| centre(w[1]) - centre(w[0])).collect();
    let Some(d_min) = diffs
        .iter()
        .copied()
        .filter(|&d| d > 1.05 * l)
        .min_by(f64::total_cmp)
    else {
        return out;
    };
    let mut units: Vec<f64> = diffs
        .iter()
        .filter(|&&d| d > 1.05 * l)
        .map(|&d| d / (d / d_min).round().max(1.0))
        .collect();
    if units.is_empty() {
        return out;
    }
    let period = median(&mut units);
    let tol_p = (0.05 * period).max(0.25);
    let regular = diffs
        .iter()
        .filter(|&&d| {
            let n = (d / period).round();
            n >= 1.0 && (d - n * period).abs() <= tol_p * n
        })
        .count();
    if (regular as f64) < 0.7 * diffs.len() as f64 {
        return out;
    }
    out.dash_length = l;
    out.period = period;
    let mut widths: Vec<f64> = full.iter().map(|s| s.width).collect();
    let width = median(&mut widths);
    // 3. Extend short dashes that sit on the pattern.
    let tol = (0.1 * l).max(0.3);
    let mut centres: Vec<(f64, f64)> = full.iter().map(|s| (centre(s), s.confidence)).collect();
    for s in spans.iter().filter(|s| s.b - s.a < 0.85 * l) {
        let c = centre(s);
        let Some(anchor) = full
            .iter()
            .map(|f| centre(f))
            .min_by(|x, y| (x - c).abs().total_cmp(&(y - c).abs()))
        else {
            continue;
        };
        if (anchor - c).abs() > 4.0 * period {
            continue;
        }
        let k = ((c - anchor) / period).round();
        let cp = anchor + k * period;
        let (a, b) = (cp - 0.5 * l, cp + 0.5 * l);
        if s.a >= a - tol && s.b <= b + tol && s.width <= 1.5 * width {
            out.extend.push((s.key, a, b, s.width.max(width)));
            centres.push((cp, s.confidence));
        }
    }
    // 4. Missing dashes in a regular run.
    if fill_max > 0 {
        centres.sort_by(|x, y| x.0.total_cmp(&y.0));
        for w in centres.windows(2) {
            let ((c1, q1), (c2, q2)) = (w[0], w[1]);
            let n = ((c2 - c1) / period).round();
            if n >= 2.0 && n <= fill_max as f64 + 1.0 && (c2 - c1 - n * period).abs() <= tol_p * n {
                let step = (c2 - c1) / n;
                for j in 1..n as usize {
                    let cp = c1 + j as f64 * step;
                    out.fill
                        .push((cp - 0.5 * l, cp + 0.5 * l, width, 0.5 * q1.min(q2)));
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn span(key: usize, a: f64, b: f64) -> Span {
        Span {
            key,
            a,
            b,
            width: 0.15,
            confidence: 0.9,
        }
    }

    /// 2 m dashes every 6 m; dash 3 worn to its last 0.8 m, dash 5 missing, dash 7 seen
    /// only in its first 1.1 m and narrower.
    #[test]
    fn short_dashes_are_extended_and_a_missing_one_is_added() {
        let mut s = Vec::new();
        for i in 0..10 {
            let a = 1.0 + 6.0 * i as f64;
            match i {
                3 => s.push(span(i, a + 1.2, a + 2.0)),
                5 => {}
                7 => s.push(Span {
                    width: 0.09,
                    ..span(i, a, a + 1.1)
                }),
                _ => s.push(span(i, a + 0.02, a + 2.01)),
            }
        }
        let p = plan(&s, 1);
        assert!((p.dash_length - 1.99).abs() < 0.03, "L {}", p.dash_length);
        assert!((p.period - 6.0).abs() < 0.05, "P {}", p.period);
        assert_eq!(p.extend.len(), 2, "{:?}", p.extend);
        for &(key, a, b, w) in &p.extend {
            let want = 1.0 + 6.0 * key as f64;
            assert!(
                (a - want).abs() < 0.06 && (b - want - 2.0).abs() < 0.06,
                "{key}: {a}..{b}"
            );
            assert!(w >= 0.15 - 1e-9, "width {w}");
        }
        assert_eq!(p.fill.len(), 1, "{:?}", p.fill);
        let (a, b, _, conf) = p.fill[0];
        assert!((a - 31.0).abs() < 0.06 && (b - 33.0).abs() < 0.06, "{a}..{b}");
        assert!(conf < 0.9);
        // Nothing added without the fill.
        assert!(plan(&s, 0).fill.is_empty());
    }

    /// A piece that does not sit on the pattern (it straddles a gap) is left alone, and so
    /// is a line without a regular period.
    #[test]
    fn off_pattern_pieces_and_irregular_lines_are_left_alone() {
        let mut s: Vec<Span> = (0..8)
            .map(|i| span(i, 6.0 * i as f64, 6.0 * i as f64 + 2.0))
            .collect();
        s[4] = span(4, 24.0 + 2.5, 24.0 + 3.5); // in the gap after where dash 4 should be
        let p = plan(&s, 1);
        assert!(p.extend.is_empty(), "{:?}", p.extend);
        let irregular: Vec<Span> = [0.0, 5.0, 13.0, 16.5, 27.0, 31.0, 40.0]
            .iter()
            .enumerate()
            .map(|(i, &a)| span(i, a, a + 2.0))
            .collect();
        let p = plan(&irregular, 1);
        assert_eq!(p.period, 0.0);
        assert!(p.extend.is_empty() && p.fill.is_empty());
    }
}
