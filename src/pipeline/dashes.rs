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
//! 1. `L` = the longest dash length that at least 3 dashes share (within [0.85, 1.2] × it),
//!    refined to the median of the dashes near it: worn or sparse dashes are only ever
//!    shorter than painted, and on a far line they can be most of the dashes. Complete
//!    dashes are those within [0.85, 1.2] × `L`; at least 3 are needed.
//! 2. `P` from the spacing of consecutive complete dashes' centres: each spacing is divided
//!    by its multiple of the smallest spacing (a missing or short dash in between makes it
//!    a multiple), `P` is the median of these; at least 70 % of the spacings must lie within
//!    `max(0.25 m, 5 % P)` × multiple of a whole multiple of `P`, or the line is not regular
//!    and nothing is changed.
//! 3. A short dash is placed on the pattern of the nearest anchor (a complete dash, or a
//!    short dash already placed; at most 4 periods away), nearest first, so the pattern
//!    carries along a run of short dashes: the painted dash whose centre is a whole number
//!    of periods from the anchor must contain the short dash (within `max(0.3 m, 10 % L)`
//!    at both ends); it is then extended to that painted dash (and given the median width
//!    of the complete dashes, if it looked narrower), unless that painted dash already has
//!    its piece (an anchor, or a short dash placed before): then it is a part of that dash
//!    and is removed, not drawn a second time.
//! 4. Between consecutive dashes `n` periods apart (2 ≤ n ≤ `fill_max` + 1, within the same
//!    tolerance), the `n - 1` missing dashes are added.
//!
//! **A line with too few complete dashes** (a far lane seen only in parts of each dash)
//! borrows the design of the drive's other dashed lines ([`plan_with_designs`]): each short
//! dash `[a, b]` admits the dash starts `[b − L, a]` (± the tolerance) modulo `P`; the
//! start shared by the most dashes is the line's phase if at least 3 dashes and 70 % of
//! the line's dashes share it and the dashes that share it pin it to within `L / 4` (dashes
//! seen at their two ends do; dashes all seen at the same end leave the phase open and the
//! line unchanged). The dashes sharing it are then the anchors of steps 3 and 4.
//!
//! **Complexity.** O(d²) for d dashes of a line (d is tens).

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

/// The painted design of a dashed line: dash length, period (dash + gap) and width (m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Design {
    pub dash_length: f64,
    pub period: f64,
    pub width: f64,
}

/// What to change.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Plan {
    /// (key, new start, new end, new width) of dashes to extend.
    pub extend: Vec<(usize, f64, f64, f64)>,
    /// (start, end, width, confidence) of missing dashes to add.
    pub fill: Vec<(f64, f64, f64, f64)>,
    /// Keys of short dashes that are parts of a painted dash another piece already stands
    /// for (a complete dash, or a short dash extended to it): to remove.
    pub absorb: Vec<usize>,
    /// The design found: dash length and period (m).
    pub dash_length: f64,
    pub period: f64,
    /// The median width of the complete dashes (m).
    pub width: f64,
}

impl Plan {
    /// The design this plan puts the dashes on (`None` when the line had none).
    pub fn design(&self) -> Option<Design> {
        (self.period > 0.0).then_some(Design {
            dash_length: self.dash_length,
            period: self.period,
            width: self.width,
        })
    }
}

fn centre(s: &Span) -> f64 {
    0.5 * (s.a + s.b)
}

/// The regularisation plan of one dashed lane line (see the module docs). `fill_max` is the
/// most consecutive missing dashes added (0: none).
pub fn plan(spans: &[Span], fill_max: usize) -> Plan {
    match own_design(spans) {
        Some((design, anchors)) => apply(spans, design, anchors, fill_max),
        None => Plan::default(),
    }
}

/// Like [`plan`], but a line whose own dashes give no design is put on the one of
/// `designs` (the drive's other dashed lines) its dashes fit best, if any fits (module
/// docs).
pub fn plan_with_designs(spans: &[Span], designs: &[Design], fill_max: usize) -> Plan {
    let own = plan(spans, fill_max);
    if own.period > 0.0 {
        return own;
    }
    plan_on_designs(spans, designs, fill_max)
}

/// The plan of a line on the one of `designs` its dashes fit best (module docs), ignoring
/// any design of its own; an empty plan (period 0) when none fits.
pub fn plan_on_designs(spans: &[Span], designs: &[Design], fill_max: usize) -> Plan {
    // The design most dashes share a phase on (then the tightest phase).
    let mut best: Option<(Design, PhaseFit)> = None;
    for &d in designs {
        if let Some(fit) = phase_fit(spans, d) {
            let better = match &best {
                None => true,
                Some((_, b)) => {
                    fit.sharing > b.sharing || (fit.sharing == b.sharing && fit.spread < b.spread)
                }
            };
            if better {
                best = Some((d, fit));
            }
        }
    }
    match best {
        Some((d, fit)) => apply(spans, d, fit.anchors, fill_max),
        None => Plan::default(),
    }
}

/// Steps 1 and 2: the line's own design and its complete dashes' (centre, confidence).
fn own_design(spans: &[Span]) -> Option<(Design, Vec<Anchor>)> {
    if spans.len() < 4 {
        return None;
    }
    // 1. Dash length: the longest length shared by 3 dashes.
    let l = dash_length(spans)?;
    let is_full = |s: &Span| {
        let len = s.b - s.a;
        len >= 0.85 * l && len <= 1.2 * l
    };
    let mut full: Vec<&Span> = spans.iter().filter(|s| is_full(s)).collect();
    if full.len() < 3 {
        return None;
    }
    full.sort_by(|x, y| centre(x).total_cmp(&centre(y)));
    // 2. Period.
    let diffs: Vec<f64> = full.windows(2).map(|w| centre(w[1]) - centre(w[0])).collect();
    let d_min = diffs
        .iter()
        .copied()
        .filter(|&d| d > 1.05 * l)
        .min_by(f64::total_cmp)?;
    let mut units: Vec<f64> = diffs
        .iter()
        .filter(|&&d| d > 1.05 * l)
        .map(|&d| d / (d / d_min).round().max(1.0))
        .collect();
    if units.is_empty() {
        return None;
    }
    let period = median(&mut units);
    let tol_p = period_tolerance(period);
    // A spacing of many periods proves nothing once its tolerance nears a quarter period.
    let regular = diffs
        .iter()
        .filter(|&&d| {
            let n = (d / period).round();
            n >= 1.0 && tol_p * n < 0.25 * period && (d - n * period).abs() <= tol_p * n
        })
        .count();
    if (regular as f64) < 0.7 * diffs.len() as f64 {
        return None;
    }
    let mut widths: Vec<f64> = full.iter().map(|s| s.width).collect();
    let design = Design {
        dash_length: l,
        period,
        width: median(&mut widths),
    };
    let anchors = full
        .iter()
        .map(|s| Anchor {
            centre: centre(s),
            confidence: s.confidence,
            placed: true,
        })
        .collect();
    Some((design, anchors))
}

/// Step 1: the longest length `Lc` that at least 3 dashes have (within [0.85, 1.2] × `Lc`),
/// refined to the median of the dashes within [0.85, 1.2] × their median. Worn, shadowed
/// or sparsely scanned dashes are only ever shorter than painted, and on a far line they
/// can be most of the dashes, so the complete ones are the longest group, not the middle.
fn dash_length(spans: &[Span]) -> Option<f64> {
    let mut lens: Vec<f64> = spans
        .iter()
        .map(|s| s.b - s.a)
        .filter(|l| l.is_finite())
        .collect();
    lens.sort_by(|x, y| y.total_cmp(x));
    let near = |c: f64| -> Vec<f64> {
        lens.iter()
            .copied()
            .filter(|&v| v >= 0.85 * c && v <= 1.2 * c)
            .collect()
    };
    let group = lens.iter().map(|&c| near(c)).find(|g| g.len() >= 3)?;
    let l = median(&mut near(median(&mut group.clone())));
    (l > 0.1).then_some(l)
}

/// How far (m, per period) a spacing may be from a whole number of periods.
fn period_tolerance(period: f64) -> f64 {
    (0.05 * period).max(0.25)
}

/// How far (m) a short dash may reach past the painted dash it is placed in.
fn end_tolerance(dash_length: f64) -> f64 {
    (0.1 * dash_length).max(0.3)
}

/// A line's phase on a borrowed design.
struct PhaseFit {
    /// Dashes that fit it.
    sharing: usize,
    /// How far (m) those dashes leave the phase open.
    spread: f64,
    /// The painted dash of each of them (none has its piece yet: all are short).
    anchors: Vec<Anchor>,
}

/// The phase of a line on a borrowed design, or `None` when it is not pinned (module docs).
fn phase_fit(spans: &[Span], d: Design) -> Option<PhaseFit> {
    let (l, p) = (d.dash_length, d.period);
    if !(l > 0.1 && p > l) || spans.len() < 3 {
        return None;
    }
    let tol = end_tolerance(l);
    // Each dash no longer than a painted one admits dash starts [b - L - tol, a + tol].
    let fits: Vec<&Span> = spans
        .iter()
        .filter(|s| s.b - s.a <= 1.2 * l && s.width <= 1.5 * d.width.max(0.05))
        .collect();
    // Candidate phases: every interval's ends, modulo P; count the intervals holding each.
    let wrap = |x: f64| x.rem_euclid(p);
    let holds = |s: &Span, phi: f64| {
        // The start closest to the dash's admissible range.
        let lo = s.b - l - tol;
        let k = ((lo - phi) / p).ceil();
        phi + k * p <= s.a + tol
    };
    let mut best: Option<(usize, f64)> = None;
    for s in &fits {
        for phi in [wrap(s.b - l - tol), wrap(s.a + tol)] {
            let n = fits.iter().filter(|t| holds(t, phi)).count();
            if best.is_none_or(|(bn, _)| n > bn) {
                best = Some((n, phi));
            }
        }
    }
    let (n, phi) = best?;
    if n < 3 || (n as f64) < 0.7 * spans.len() as f64 {
        return None;
    }
    // The dashes sharing the phase pin it to [max(b - L), min(a)] (unwrapped near phi).
    let sharing: Vec<&Span> = fits.iter().copied().filter(|t| holds(t, phi)).collect();
    let start_of = |s: &Span| {
        let k = ((s.b - l - tol - phi) / p).ceil();
        phi + k * p
    };
    let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
    for s in &sharing {
        let st = start_of(s);
        lo = lo.max(s.b - l - st);
        hi = hi.min(s.a - st);
    }
    let spread = (hi - lo).max(0.0);
    if spread > 0.25 * l {
        return None;
    }
    let shift = 0.5 * (lo + hi);
    let anchors = sharing
        .iter()
        .map(|s| Anchor {
            centre: start_of(s) + shift + 0.5 * l,
            confidence: s.confidence,
            placed: false,
        })
        .collect();
    Some(PhaseFit {
        sharing: n,
        spread,
        anchors,
    })
}

/// A painted dash the pattern is pinned to.
#[derive(Clone, Copy, Debug)]
struct Anchor {
    centre: f64,
    confidence: f64,
    /// Whether a piece stands for it: a complete dash, or a short dash extended to it.
    placed: bool,
}

/// Steps 3 and 4 on a design and its anchors.
fn apply(spans: &[Span], design: Design, anchors: Vec<Anchor>, fill_max: usize) -> Plan {
    let Design {
        dash_length: l,
        period,
        width,
    } = design;
    let mut out = Plan {
        dash_length: l,
        period,
        width,
        ..Plan::default()
    };
    let tol_p = period_tolerance(period);
    // 3. Extend short dashes that sit on the pattern, nearest to an anchor first.
    let tol = end_tolerance(l);
    let mut centres = anchors;
    let mut short: Vec<&Span> = spans.iter().filter(|s| s.b - s.a < 0.85 * l).collect();
    loop {
        // The short dash nearest to an anchor, and that anchor.
        let near = short
            .iter()
            .enumerate()
            .filter_map(|(i, s)| {
                let c = centre(s);
                centres
                    .iter()
                    .map(|a| a.centre)
                    .min_by(|x, y| (x - c).abs().total_cmp(&(y - c).abs()))
                    .map(|a| (i, a, (a - c).abs()))
            })
            .min_by(|x, y| x.2.total_cmp(&y.2));
        let Some((i, anchor, dist)) = near else {
            break;
        };
        if dist > 4.0 * period {
            break;
        }
        let s = short.swap_remove(i);
        let k = ((centre(s) - anchor) / period).round();
        let cp = anchor + k * period;
        let (a, b) = (cp - 0.5 * l, cp + 0.5 * l);
        if s.a >= a - tol && s.b <= b + tol && s.width <= 1.5 * width {
            let at = |c: &Anchor| (c.centre - cp).abs() < 0.5 * l;
            if centres.iter().any(|c| c.placed && at(c)) {
                // That painted dash already has its piece: this one is a part of it.
                out.absorb.push(s.key);
            } else {
                out.extend.push((s.key, a, b, s.width.max(width)));
                match centres.iter_mut().find(|c| at(c)) {
                    Some(anchor) => anchor.placed = true,
                    None => centres.push(Anchor {
                        centre: cp,
                        confidence: s.confidence,
                        placed: true,
                    }),
                }
            }
        }
    }
    // 4. Missing dashes in a regular run.
    if fill_max > 0 {
        centres.sort_by(|x, y| x.centre.total_cmp(&y.centre));
        for w in centres.windows(2) {
            let (c1, c2) = (w[0].centre, w[1].centre);
            let n = ((c2 - c1) / period).round();
            if n >= 2.0 && n <= fill_max as f64 + 1.0 && (c2 - c1 - n * period).abs() <= tol_p * n {
                let step = (c2 - c1) / n;
                for j in 1..n as usize {
                    let cp = c1 + j as f64 * step;
                    out.fill.push((
                        cp - 0.5 * l,
                        cp + 0.5 * l,
                        width,
                        0.5 * w[0].confidence.min(w[1].confidence),
                    ));
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

    /// Parts of one painted dash are one dash: a part beside a complete dash, and the second
    /// of two parts of a worn dash, are absorbed, not drawn again on the same paint.
    #[test]
    fn parts_of_a_painted_dash_are_absorbed_not_drawn_twice() {
        let mut s: Vec<Span> = (0..8)
            .map(|i| span(i, 1.0 + 6.0 * i as f64, 3.0 + 6.0 * i as f64))
            .collect();
        s.push(span(8, 13.5, 14.5)); // inside complete dash 2 (13..15)
        s[5] = span(5, 31.0, 31.8); // dash 5 worn into two parts
        s.push(span(9, 32.1, 33.0));
        let p = plan(&s, 1);
        assert!((p.period - 6.0).abs() < 0.05, "P {}", p.period);
        assert_eq!(p.extend.len(), 1, "{:?}", p.extend);
        assert!((p.extend[0].1 - 31.0).abs() < 0.06 && (p.extend[0].2 - 33.0).abs() < 0.06);
        let mut absorbed = p.absorb.clone();
        absorbed.sort_unstable();
        let other_part = if p.extend[0].0 == 5 { 9 } else { 5 };
        let mut want = vec![8, other_part];
        want.sort_unstable();
        assert_eq!(absorbed, want);
        assert!(p.fill.is_empty(), "{:?}", p.fill);
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

    /// A far line seen mostly in parts of its dashes (2 m every 6 m): only 3 dashes are
    /// complete, so the length comes from the longest group, not the median of the longer
    /// half (1.69 m here), and the pattern carries from placed dash to placed dash along
    /// the run beyond 4 periods of the last complete one; the missing dash is added.
    #[test]
    fn mostly_short_dashes_keep_the_painted_length_and_the_pattern_carries() {
        let seen = [
            (5.1, 1.96),
            (11.9, 1.13),
            (17.1, 1.94),
            (23.1, 1.96),
            (29.6, 0.86),
            (36.2, 0.87),
            (47.9, 1.10),
            (53.6, 1.44),
            (59.7, 1.33),
            (66.5, 0.58),
        ];
        let s: Vec<Span> = seen
            .iter()
            .enumerate()
            .map(|(i, &(a, l))| span(i, a, a + l))
            .collect();
        let p = plan(&s, 1);
        assert!((p.dash_length - 1.96).abs() < 0.02, "L {}", p.dash_length);
        assert!((p.period - 6.0).abs() < 0.05, "P {}", p.period);
        let keys: Vec<usize> = p.extend.iter().map(|e| e.0).collect();
        for k in [1, 4, 5, 6, 7, 8, 9] {
            assert!(keys.contains(&k), "dash {k} not placed: {keys:?}");
        }
        for &(key, a, b, _) in &p.extend {
            // The painted dashes start at 5.1 + 6 n.
            let n = ((a - 5.1) / 6.0).round();
            assert!((a - 5.1 - 6.0 * n).abs() < 0.15, "{key}: {a}..{b}");
            assert!((b - a - 1.96).abs() < 0.02, "{key}: {a}..{b}");
        }
        assert_eq!(p.fill.len(), 1, "{:?}", p.fill);
        assert!((p.fill[0].0 - 41.1).abs() < 0.2, "{:?}", p.fill);
    }

    /// A line with no complete dash of its own is put on a design from the drive's other
    /// lines when its parts pin the phase (seen at different ends of their dashes); parts
    /// all seen at the same end leave the phase open and the line alone; and a design whose
    /// period the parts do not follow is not taken.
    #[test]
    fn a_line_without_complete_dashes_borrows_the_drive_design() {
        let design = Design {
            dash_length: 2.0,
            period: 6.0,
            width: 0.15,
        };
        // Painted dashes at 3 + 6 n; seen: the first 0.7 m, the last 0.8 m, a middle part.
        let parts = [(3.0, 3.7), (10.2, 11.0), (15.5, 16.3), (22.1, 22.9), (27.4, 28.0)];
        let s: Vec<Span> = parts
            .iter()
            .enumerate()
            .map(|(i, &(a, b))| span(i, a, b))
            .collect();
        assert_eq!(plan(&s, 1).period, 0.0, "no design of its own");
        let other = Design {
            dash_length: 3.0,
            period: 12.0,
            width: 0.15,
        };
        let p = plan_with_designs(&s, &[other, design], 1);
        assert_eq!(p.period, 6.0);
        assert_eq!(p.extend.len(), 5, "{:?}", p.extend);
        for &(key, a, b, _) in &p.extend {
            let n = ((a - 3.0) / 6.0).round();
            assert!(
                (a - 3.0 - 6.0 * n).abs() < 0.1 && (b - a - 2.0).abs() < 1e-9,
                "{key}: {a}..{b}"
            );
        }
        // Every part at the start of its dash: the dashes could begin up to 1.3 m earlier.
        let same_end: Vec<Span> = (0..5)
            .map(|i| span(i, 3.0 + 6.0 * i as f64, 3.7 + 6.0 * i as f64))
            .collect();
        assert!(plan_with_designs(&same_end, &[design], 1).extend.is_empty());
        // Parts every 7.5 m follow neither design.
        let other_period: Vec<Span> = (0..6)
            .map(|i| span(i, 7.5 * i as f64, 7.5 * i as f64 + 0.8))
            .collect();
        let p = plan_with_designs(&other_period, &[design, other], 1);
        assert!(p.extend.is_empty() && p.fill.is_empty(), "{p:?}");
    }

    /// Fragments 1 m apart among ones ~15 m apart make no 1 m "period": a spacing of many
    /// periods proves nothing once its tolerance nears a quarter period.
    #[test]
    fn a_tiny_spacing_is_no_period_for_far_apart_dashes() {
        let s: Vec<Span> = [0.0, 1.0, 15.3, 29.1, 46.0, 61.2]
            .iter()
            .enumerate()
            .map(|(i, &a)| span(i, a, a + 0.6))
            .collect();
        let p = plan(&s, 1);
        assert_eq!(p.period, 0.0, "{p:?}");
        assert!(p.extend.is_empty() && p.fill.is_empty());
    }
}
