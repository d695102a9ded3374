//! Crosswalk regularisation: the stripes of one zebra crossing share one design.
//!
//! **What.** A zebra crossing is painted as parallel stripes of one width, side by side at
//! one period, whose ends line up on two straight lines (the kerb-side edges of the
//! crossing). What the scanner sees of a stripe is often less: worn paint leaves pieces of
//! it (classified as dashes, guideline stripes or unknown fragments), and the stripe that
//! was seen is short or narrow. Given the marks of a drive, this module finds the groups of
//! crosswalk stripes, estimates each group's design from its most complete stripes, and
//! returns the edits that give every stripe the painted design: short stripes extended to
//! the group's edges, fragments lying on a stripe's position absorbed into it (or made the
//! stripe when none was seen there), and stripes missing between seen ones added.
//!
//! **Algorithm** (on rectangles in the plane; written here: no library does this).
//! 1. Stripes = marks classed `Crosswalk`. Their long axis and extents come from the
//!    principal axes of the outline's vertices. Two stripes belong to one group when they
//!    are parallel (≤ 10°), at most [`MAX_STRIPE_GAP_M`] apart across their axis, and
//!    overlap along it by ≥ 30 % of the shorter (union–find). Groups of ≥ 3 stripes only.
//! 2. Frame: `a` along the stripes, `b` across them. Width `W` = median width of the longer
//!    half of the stripes (worn ones are only ever narrower or shorter). Edges: the line
//!    through two stripes' ends (over all pairs) that leaves no stripe end beyond it by more
//!    than [`END_TOL_M`] and has the most ends on it, with a slope ≤ 1 (a crossing skewed
//!    by at most 45°); a single-stripe maximum when no pair fits. The two edges run
//!    parallel (the kerbs of the road crossed): when their slopes differ by more than
//!    [`MAX_EDGE_SLOPE_DIFF`], the edge with fewer ends on it (worn paint left its ends on
//!    a slant) takes the other's slope, through the end with the most ends near it and at
//!    most a fifth beyond it.
//! 3. Period `P` = median spacing of consecutive stripe centres divided by its whole
//!    multiple of the smallest spacing; the grid is regular when every spacing is within
//!    `max(0.15 m, 15 % P)` of a whole multiple.
//! 4. Fragments: any other mark whose outline lies within the band between the edges
//!    (± 0.3 m), parallel to the stripes (≤ 20°) or no longer than `2 W` (a stop line only
//!    when parallel: then it is a misread stripe), and whose centre is within
//!    `W/2 + 0.15 m` of a stripe's position: a seen stripe, a grid position between seen
//!    ones on a regular grid, or up to [`MAX_EDGE_SLOTS`] grid positions outward of them
//!    (each only if the positions nearer the crossing have fragments too, or at most
//!    `fill_max` consecutive ones are empty: those are then filled).
//! 5. Edits: each seen stripe gets the design rectangle at its own centre line and absorbs
//!    the fragments at its position; a grid position with fragments only becomes a stripe
//!    (the largest fragment, reclassified); on a regular grid, up to `fill_max` consecutive
//!    empty positions between seen stripes get a stripe (confidence halved, no points).
//!
//! **Complexity.** O(s² + s³) per group of s stripes (pair edges), O(f · g) for f fragment
//! candidates and g groups.

use super::geom::{self, Pca};
use super::types::MarkingClass;

/// Stripes further apart than this across their axis (m) are not neighbours in one group.
pub const MAX_STRIPE_GAP_M: f64 = 3.0;
/// Stripe ends may lie this far beyond a group edge (m).
pub const END_TOL_M: f64 = 0.15;
/// Most difference of slope (across the stripes per metre along the crossing) between a
/// crossing's two edges.
const MAX_EDGE_SLOPE_DIFF: f64 = 0.1;
/// Most parallel misalignment of two stripes of one group (deg).
const MAX_STRIPE_ANGLE_DEG: f64 = 10.0;
/// Most stripe positions beyond the outermost seen stripe that fragments can extend a
/// crossing by: the far half of a crossing, beyond the scanner's dense range or worn,
/// comes as unknown fragments (5 rather than 3 raised pixel F on 7 of the 20 simulated
/// drives and lowered it on none).
const MAX_EDGE_SLOTS: usize = 5;
/// Most misalignment of a fragment absorbed into a stripe (deg).
const MAX_FRAGMENT_ANGLE_DEG: f64 = 20.0;

/// One mark as the regularisation sees it.
#[derive(Clone, Debug, PartialEq)]
pub struct Mark {
    /// Caller's key (index of the piece).
    pub key: usize,
    pub class: MarkingClass,
    pub ring: Vec<[f64; 2]>,
    pub confidence: f64,
    pub point_count: usize,
}

/// A stripe of the design: its rectangle and measures.
#[derive(Clone, Debug, PartialEq)]
pub struct Stripe {
    pub ring: [[f64; 2]; 4],
    pub length_m: f64,
    pub width_m: f64,
    /// Unit direction of the long axis.
    pub axis: [f64; 2],
}

/// What to change.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Plan {
    /// (key, new stripe, keys absorbed into it): the mark `key` becomes this crosswalk
    /// stripe (reclassified if it was a fragment) and the absorbed marks are removed.
    pub reshape: Vec<(usize, Stripe, Vec<usize>)>,
    /// (stripe, confidence) of missing stripes to add.
    pub fill: Vec<(Stripe, f64)>,
}

/// A mark in a group's frame.
#[derive(Clone, Copy, Debug)]
struct Seen {
    idx: usize,
    /// Centre across the stripes (b) and extent along them (a).
    c: f64,
    lo: f64,
    hi: f64,
    width: f64,
}

/// Principal axis of a ring's vertices and their (lo, hi) extents along and across it.
pub(crate) type Frame = (Pca, (f64, f64), (f64, f64));

/// The [`Frame`] of a ring.
pub(crate) fn frame_of(ring: &[[f64; 2]]) -> Frame {
    let pca = Pca::of(ring);
    let mut u = (f64::INFINITY, f64::NEG_INFINITY);
    let mut v = (f64::INFINITY, f64::NEG_INFINITY);
    for &p in ring {
        let q = pca.to_frame(p);
        u = (u.0.min(q[0]), u.1.max(q[0]));
        v = (v.0.min(q[1]), v.1.max(q[1]));
    }
    (pca, u, v)
}

/// An edge line `e(c) = alpha + beta·c` over stripe ends `(c, end)`: `upper` edges bound the
/// ends from above (hi ends), lower ones from below (lo ends, given negated).
fn edge(ends: &[(f64, f64)]) -> (f64, f64, usize) {
    let max_single = ends.iter().map(|e| e.1).fold(f64::NEG_INFINITY, f64::max);
    let mut best: (f64, f64) = (max_single, 0.0);
    let mut best_on = 1usize;
    for i in 0..ends.len() {
        for j in i + 1..ends.len() {
            let (ci, ei) = ends[i];
            let (cj, ej) = ends[j];
            if (cj - ci).abs() < 0.3 {
                continue;
            }
            let beta = (ej - ei) / (cj - ci);
            if beta.abs() > 1.0 {
                continue;
            }
            let alpha = ei - beta * ci;
            let beyond = ends.iter().any(|&(c, e)| e > alpha + beta * c + END_TOL_M);
            if beyond {
                continue;
            }
            let on = ends
                .iter()
                .filter(|&&(c, e)| e >= alpha + beta * c - END_TOL_M)
                .count();
            if on > best_on || (on == best_on && beta.abs() < best.1.abs()) {
                best = (alpha, beta);
                best_on = on;
            }
        }
    }
    (best.0, best.1, best_on)
}

/// The edge of slope `beta` over `ends` (see [`edge`]): through the end with the most
/// ends within [`END_TOL_M`] of it, at most a fifth of them beyond it (a stray at a
/// stripe's end); the farther of equals.
fn edge_with_slope(ends: &[(f64, f64)], beta: f64) -> f64 {
    let off: Vec<f64> = ends.iter().map(|&(c, e)| e - beta * c).collect();
    let mut best = (0usize, f64::NEG_INFINITY);
    for &a in &off {
        let beyond = off.iter().filter(|&&o| o > a + END_TOL_M).count();
        if 5 * beyond > off.len() {
            continue;
        }
        let on = off.iter().filter(|&&o| (o - a).abs() <= END_TOL_M).count();
        if on > best.0 || (on == best.0 && a > best.1) {
            best = (on, a);
        }
    }
    best.1
}

/// The regularisation plan over all marks of a drive (see the module docs). `fill_max` is
/// the most consecutive missing stripes added (0: none).
pub fn plan(marks: &[Mark], fill_max: usize) -> Plan {
    let mut out = Plan::default();
    let stripes: Vec<usize> = (0..marks.len())
        .filter(|&i| marks[i].class == MarkingClass::Crosswalk && marks[i].ring.len() >= 3)
        .collect();
    // Principal frames of every mark, once (groups and fragments use them).
    let frames: Vec<Frame> = marks.iter().map(|m| frame_of(&m.ring)).collect();
    // 1. Groups.
    let mut parent: Vec<usize> = (0..stripes.len()).collect();
    for i in 0..stripes.len() {
        for j in i + 1..stripes.len() {
            let (pi, ui, _) = &frames[stripes[i]];
            let (pj, _, _) = &frames[stripes[j]];
            if geom::acute_angle_deg(pi.axis, pj.axis) > MAX_STRIPE_ANGLE_DEG {
                continue;
            }
            let cj = pi.to_frame(pj.center);
            if cj[1].abs() > MAX_STRIPE_GAP_M {
                continue;
            }
            // Extent of j along i's axis.
            let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
            for &p in &marks[stripes[j]].ring {
                let q = pi.to_frame(p);
                lo = lo.min(q[0]);
                hi = hi.max(q[0]);
            }
            let overlap = ui.1.min(hi) - ui.0.max(lo);
            let shorter = (ui.1 - ui.0).min(hi - lo);
            if overlap >= 0.3 * shorter {
                geom::union(&mut parent, i, j);
            }
        }
    }
    let groups = geom::merge_groups(&mut parent, (0..stripes.len()).map(|i| [i]));
    // Stripes of a group are never another group's fragments.
    let mut taken = vec![false; marks.len()];
    for g in groups.iter().filter(|g| g.len() >= 3) {
        for &s in g {
            taken[stripes[s]] = true;
        }
    }
    for g in groups.iter().filter(|g| g.len() >= 3) {
        if let Some((reshape, fill)) = regularise_group(
            marks,
            &frames,
            g.iter().map(|&s| stripes[s]),
            &mut taken,
            fill_max,
        ) {
            out.reshape.extend(reshape);
            out.fill.extend(fill);
        }
    }
    out
}

type GroupEdits = (Vec<(usize, Stripe, Vec<usize>)>, Vec<(Stripe, f64)>);

fn regularise_group(
    marks: &[Mark],
    frames: &[Frame],
    members: impl Iterator<Item = usize>,
    taken: &mut [bool],
    fill_max: usize,
) -> Option<GroupEdits> {
    let members: Vec<usize> = members.collect();
    // 2. Frame: mean axis (sign-aligned), origin at the first stripe's centre.
    let first = frames[members[0]].0;
    let mut ax = [0.0, 0.0];
    for &m in &members {
        // Weighted by length²: a long stripe's axis is the better determined.
        let (p, u, _) = frames[m];
        let wt = (u.1 - u.0).powi(2);
        let s = if p.axis[0] * first.axis[0] + p.axis[1] * first.axis[1] < 0.0 {
            -wt
        } else {
            wt
        };
        ax = [ax[0] + s * p.axis[0], ax[1] + s * p.axis[1]];
    }
    let n = ax[0].hypot(ax[1]);
    if n <= 0.0 {
        return None;
    }
    let a = [ax[0] / n, ax[1] / n];
    let b = [-a[1], a[0]];
    let o = first.center;
    let to = |p: [f64; 2]| {
        let d = [p[0] - o[0], p[1] - o[1]];
        (d[0] * a[0] + d[1] * a[1], d[0] * b[0] + d[1] * b[1])
    };
    let from = |u: f64, v: f64| [o[0] + u * a[0] + v * b[0], o[1] + u * a[1] + v * b[1]];
    let seen_of = |i: usize| -> Seen {
        let (mut lo, mut hi, mut vlo, mut vhi) =
            (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
        for &p in &marks[i].ring {
            let (u, v) = to(p);
            lo = lo.min(u);
            hi = hi.max(u);
            vlo = vlo.min(v);
            vhi = vhi.max(v);
        }
        // Width in the mark's own frame: a stripe turned slightly off the group's axis
        // spans more across it than its painted width.
        let own = frames[i].2;
        Seen {
            idx: i,
            c: (vlo + vhi) / 2.0,
            lo,
            hi,
            width: (own.1 - own.0).min(vhi - vlo),
        }
    };
    let mut seen: Vec<Seen> = members.iter().map(|&m| seen_of(m)).collect();
    seen.sort_by(|x, y| x.c.total_cmp(&y.c));
    // Width: median of the longer half.
    let mut by_len = seen.clone();
    by_len.sort_by(|x, y| (y.hi - y.lo).total_cmp(&(x.hi - x.lo)));
    let mut widths: Vec<f64> = by_len[..by_len.len().div_ceil(2)]
        .iter()
        .map(|s| s.width)
        .collect();
    let w = geom::median(&mut widths);
    if !(w > 0.05 && w < 1.5) {
        return None;
    }
    // Edges.
    let hi_ends: Vec<(f64, f64)> = seen.iter().map(|s| (s.c, s.hi)).collect();
    let lo_ends: Vec<(f64, f64)> = seen.iter().map(|s| (s.c, -s.lo)).collect();
    let (mut ha, mut hb, h_on) = edge(&hi_ends);
    let (mut la, mut lb, l_on) = edge(&lo_ends);
    // Parallel edges (see the module docs; the lower edge's slope is negated).
    if (hb + lb).abs() > MAX_EDGE_SLOPE_DIFF {
        if h_on > l_on || (h_on == l_on && hb.abs() < lb.abs()) {
            lb = -hb;
            la = edge_with_slope(&lo_ends, lb);
        } else {
            hb = -lb;
            ha = edge_with_slope(&hi_ends, hb);
        }
    }
    let hi_at = |c: f64| ha + hb * c;
    let lo_at = |c: f64| -(la + lb * c);
    if seen.iter().any(|s| hi_at(s.c) - lo_at(s.c) < 0.5) {
        return None;
    }
    // 3. Period and grid.
    let gaps: Vec<f64> = seen.windows(2).map(|p| p[1].c - p[0].c).collect();
    let smallest = gaps.iter().copied().fold(f64::INFINITY, f64::min);
    let mut grid: Option<f64> = None;
    if smallest > w * 1.05 {
        let mut unit: Vec<f64> = gaps.iter().map(|g| g / (g / smallest).round().max(1.0)).collect();
        let p = geom::median(&mut unit);
        let tol = (0.15f64).max(0.15 * p);
        if gaps
            .iter()
            .all(|g| (g - (g / p).round() * p).abs() <= tol * (g / p).round().max(1.0))
        {
            grid = Some(p);
        }
    }
    // Positions: seen stripes, plus the empty grid positions between them.
    struct Slot {
        c: f64,
        stripe: Option<usize>,
        frags: Vec<usize>,
        /// 0 within the seen stripes, j for the j-th position outward of them.
        edge: usize,
    }
    let mut slots: Vec<Slot> = Vec::new();
    for (k, s) in seen.iter().enumerate() {
        if k > 0
            && let Some(p) = grid
        {
            let prev = seen[k - 1].c;
            let m = ((s.c - prev) / p).round() as usize;
            for j in 1..m {
                slots.push(Slot {
                    c: prev + j as f64 * (s.c - prev) / m as f64,
                    stripe: None,
                    frags: Vec::new(),
                    edge: 0,
                });
            }
        }
        slots.push(Slot {
            c: s.c,
            stripe: Some(s.idx),
            frags: Vec::new(),
            edge: 0,
        });
    }
    let (c_min, c_max) = (seen[0].c, seen[seen.len() - 1].c);
    // On a regular grid, stripes worn down to fragments may also continue the crossing
    // outward, position after position (see below).
    let reach = grid.map_or(0.0, |p| MAX_EDGE_SLOTS as f64 * p);
    if let Some(p) = grid {
        for j in 1..=MAX_EDGE_SLOTS {
            for c in [c_min - j as f64 * p, c_max + j as f64 * p] {
                slots.push(Slot {
                    c,
                    stripe: None,
                    frags: Vec::new(),
                    edge: j,
                });
            }
        }
    }
    // 4. Fragments.
    for (i, mk) in marks.iter().enumerate() {
        if taken[i] || mk.ring.len() < 3 {
            continue;
        }
        let f = seen_of(i);
        if f.c < c_min - reach - w || f.c > c_max + reach + w {
            continue;
        }
        if f.lo < lo_at(f.c) - 0.3 || f.hi > hi_at(f.c) + 0.3 {
            continue;
        }
        let pca = frames[i].0;
        let long = (f.hi - f.lo).max(f.width);
        let parallel = geom::acute_angle_deg(pca.axis, a) <= MAX_FRAGMENT_ANGLE_DEG;
        // A "stop line" parallel to the stripes is a stripe; one across them is not.
        if !parallel && (long > 2.0 * w || mk.class == MarkingClass::StopLine) {
            continue;
        }
        let near = slots
            .iter_mut()
            .map(|s| ((s.c - f.c).abs(), s))
            .filter(|(d, _)| *d <= w / 2.0 + 0.15)
            .min_by(|x, y| x.0.total_cmp(&y.0));
        if let Some((_, slot)) = near {
            slot.frags.push(i);
            taken[i] = true;
        }
    }
    // Outward positions count while the crossing continues: each one nearer the crossing
    // has fragments too, or at most `fill_max` consecutive ones are empty (a stripe worn
    // away entirely between two that left fragments); those empty ones then lie inside
    // the crossing and are filled like the gaps between seen stripes.
    slots.sort_by(|x, y| x.c.total_cmp(&y.c));
    for side in [-1.0, 1.0] {
        let mut open = true;
        let mut empty: Vec<usize> = Vec::new();
        for j in 1..=MAX_EDGE_SLOTS {
            let Some(k) = slots
                .iter()
                .position(|s| s.edge == j && if side < 0.0 { s.c < c_min } else { s.c > c_max })
            else {
                continue;
            };
            if !open {
                for &i in &slots[k].frags {
                    taken[i] = false;
                }
                slots[k].frags.clear();
            } else if slots[k].frags.is_empty() {
                empty.push(k);
                open = empty.len() <= fill_max;
            } else {
                for e in empty.drain(..) {
                    slots[e].edge = 0;
                }
            }
        }
    }
    // 5. Edits.
    let design = |c: f64| -> Stripe {
        let (lo, hi) = (lo_at(c), hi_at(c));
        let (v0, v1) = (c - w / 2.0, c + w / 2.0);
        Stripe {
            ring: [from(lo, v0), from(hi, v0), from(hi, v1), from(lo, v1)],
            length_m: hi - lo,
            width_m: w,
            axis: a,
        }
    };
    let mut confs: Vec<f64> = seen.iter().map(|s| marks[s.idx].confidence).collect();
    let conf = geom::median(&mut confs);
    let mut reshape = Vec::new();
    let mut fill = Vec::new();
    let mut empty_run: Vec<f64> = Vec::new();
    let flush = |run: &mut Vec<f64>, fill: &mut Vec<(Stripe, f64)>| {
        if run.len() <= fill_max {
            fill.extend(run.iter().map(|&c| (design(c), 0.5 * conf)));
        }
        run.clear();
    };
    for s in &slots {
        let absorbed: Vec<usize> = s.frags.iter().map(|&i| marks[i].key).collect();
        match s.stripe {
            Some(i) => {
                flush(&mut empty_run, &mut fill);
                reshape.push((marks[i].key, design(s.c), absorbed));
            }
            None if !s.frags.is_empty() => {
                flush(&mut empty_run, &mut fill);
                // The fragments' own centre (worn paint leaves the stripe's position).
                let big = *s
                    .frags
                    .iter()
                    .max_by_key(|&&i| marks[i].point_count)
                    .expect("non-empty");
                let rest: Vec<usize> = s
                    .frags
                    .iter()
                    .filter(|&&i| i != big)
                    .map(|&i| marks[i].key)
                    .collect();
                reshape.push((marks[big].key, design(s.c), rest));
            }
            None if s.edge > 0 => {}
            None => empty_run.push(s.c),
        }
    }
    Some((reshape, fill))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// An axis-aligned rectangular mark (also used by the `stoplines` tests).
    pub(crate) fn rect(key: usize, class: MarkingClass, x0: f64, x1: f64, y0: f64, y1: f64) -> Mark {
        Mark {
            key,
            class,
            ring: vec![[x0, y0], [x1, y0], [x1, y1], [x0, y1]],
            confidence: 0.8,
            point_count: ((x1 - x0) * (y1 - y0) * 1000.0) as usize,
        }
    }

    /// Stripes along x (5 m long, 0.45 m wide) at y = k · 1 m.
    fn zebra(worn: &[(usize, f64, f64)], missing: &[usize]) -> Vec<Mark> {
        (0..8)
            .filter(|k| !missing.contains(k))
            .map(|k| {
                let y = k as f64;
                let (x0, x1) = worn.iter().find(|w| w.0 == k).map_or((0.0, 5.0), |w| (w.1, w.2));
                rect(k, MarkingClass::Crosswalk, x0, x1, y - 0.225, y + 0.225)
            })
            .collect()
    }

    #[test]
    fn worn_stripes_get_the_design_and_a_missing_one_is_filled() {
        let marks = zebra(&[(2, 1.0, 3.5), (5, 0.0, 2.0)], &[4]);
        let p = plan(&marks, 1);
        assert_eq!(p.reshape.len(), 7);
        for (_, s, absorbed) in &p.reshape {
            assert!((s.length_m - 5.0).abs() < 1e-6, "{}", s.length_m);
            assert!((s.width_m - 0.45).abs() < 1e-6);
            assert!(absorbed.is_empty());
        }
        assert_eq!(p.fill.len(), 1);
        let c = p.fill[0].0.ring.iter().fold(0.0, |a, q| a + q[1] / 4.0);
        assert!((c - 4.0).abs() < 1e-6, "filled at y = 4, got {c}");
        assert!((p.fill[0].1 - 0.4).abs() < 1e-9);
        // No fill allowed: nothing added.
        assert!(plan(&marks, 0).fill.is_empty());
    }

    #[test]
    fn fragments_on_a_stripe_are_absorbed_and_a_stripe_of_fragments_is_made() {
        let mut marks = zebra(&[], &[3]);
        // Fragments of stripe 3 (worn away but for two dash-like pieces) and of stripe 6.
        marks.push(rect(100, MarkingClass::DashedLine, 0.5, 2.3, 2.9, 3.05));
        marks.push(rect(101, MarkingClass::Unknown, 3.5, 4.2, 2.85, 3.1));
        marks.push(rect(102, MarkingClass::Guideline, 1.0, 2.0, 5.8, 6.1));
        // A lane dash beside the crossing (outside the band) and a stop line: untouched.
        marks.push(rect(103, MarkingClass::DashedLine, 7.0, 9.0, 3.0, 3.15));
        marks.push(rect(104, MarkingClass::StopLine, -1.0, -0.6, -0.5, 7.5));
        // Worn stripe one position beyond the last (read as a stop line parallel to the
        // stripes), and a fragment three positions beyond with nothing in between.
        marks.push(rect(105, MarkingClass::StopLine, 0.5, 3.0, 7.8, 8.2));
        marks.push(rect(106, MarkingClass::DashedLine, 1.0, 2.5, 9.95, 10.1));
        // With one missing stripe allowed, the fragment at 10 continues the crossing and
        // the worn-away stripe at 9 is filled.
        let one = plan(&marks, 1);
        assert!(one.reshape.iter().any(|r| r.0 == 106));
        assert_eq!(one.fill.len(), 1);
        let c = one.fill[0].0.ring.iter().fold(0.0, |a, q| a + q[1] / 4.0);
        assert!((c - 9.0).abs() < 1e-6, "filled at y = 9, got {c}");
        let p = plan(&marks, 0);
        let beyond = p
            .reshape
            .iter()
            .find(|r| r.0 == 105)
            .expect("stripe 8 from its remains");
        assert!((beyond.1.length_m - 5.0).abs() < 1e-6);
        assert!(p.reshape.iter().all(|r| r.0 != 106 && !r.2.contains(&106)));
        let of = |k: usize| p.reshape.iter().find(|r| r.0 == k);
        let made = of(100).expect("the biggest fragment becomes stripe 3");
        assert_eq!(made.2, vec![101]);
        assert!((made.1.length_m - 5.0).abs() < 1e-6);
        assert_eq!(of(6).expect("stripe 6").2, vec![102]);
        assert!(of(103).is_none() && of(104).is_none());
        assert!(
            p.reshape
                .iter()
                .all(|r| !r.2.contains(&103) && !r.2.contains(&104))
        );
        assert!(p.fill.is_empty(), "no empty position left");
    }

    /// Worn paint at one side of a crossing leaves its stripes' ends on a slant (stripe k
    /// seen to 1.8 + 0.5·k m, five of them); the complete stripes end at 5 m like the
    /// far edge of all. The slant holds the most ends, but the crossing's edges run
    /// parallel: every stripe gets 5 m, none more (not even the one whose end a stray
    /// lengthens to 5.8 m).
    #[test]
    fn an_edge_along_worn_ends_takes_the_other_edges_slope() {
        let mut seen: Vec<(usize, f64, f64)> = (0..5).map(|k| (k, 0.0, 1.8 + 0.5 * k as f64)).collect();
        // A stray at the end of one complete stripe does not move the edge.
        seen.push((7, 0.0, 5.8));
        let marks = zebra(&seen, &[]);
        let p = plan(&marks, 1);
        assert_eq!(p.reshape.len(), 8);
        for (k, s, _) in &p.reshape {
            assert!((s.length_m - 5.0).abs() < 0.05, "stripe {k}: {}", s.length_m);
        }
    }

    /// Half a crossing worn down to fragments (far from the scanner, each stripe a few
    /// scan rows' pieces) continues it position after position, five of them.
    #[test]
    fn a_crossing_continues_over_five_positions_of_fragments() {
        let mut marks = zebra(&[], &[]);
        for k in 0..5 {
            let y = 8.0 + k as f64;
            marks.push(rect(200 + k, MarkingClass::Unknown, 1.0, 2.5, y - 0.1, y + 0.1));
        }
        let p = plan(&marks, 0);
        for k in 0..5 {
            let made = p.reshape.iter().find(|r| r.0 == 200 + k);
            let made = made.unwrap_or_else(|| panic!("stripe {} from its fragment", 8 + k));
            assert!((made.1.length_m - 5.0).abs() < 1e-6);
        }
    }

    #[test]
    fn skewed_crossing_edges_follow_the_stripe_ends() {
        // Ends on x = 0.5·y and x = 5 + 0.5·y (a crossing skewed by 26.6°).
        let marks: Vec<Mark> = (0..6)
            .map(|k| {
                let y = k as f64;
                let (x0, x1) = if k == 2 {
                    (1.5, 4.0)
                } else {
                    (0.5 * y, 5.0 + 0.5 * y)
                };
                rect(k, MarkingClass::Crosswalk, x0, x1, y - 0.2, y + 0.2)
            })
            .collect();
        let p = plan(&marks, 1);
        let s = &p.reshape.iter().find(|r| r.0 == 2).expect("stripe 2").1;
        let xs: Vec<f64> = s.ring.iter().map(|q| q[0]).collect();
        let (lo, hi) = (
            xs.iter().copied().fold(f64::INFINITY, f64::min),
            xs.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        );
        assert!((lo - 0.9).abs() < 0.15 && (hi - 6.1).abs() < 0.15, "{lo} {hi}");
    }

    #[test]
    fn two_stripes_or_unrelated_bars_are_left_alone() {
        let two: Vec<Mark> = zebra(&[(1, 1.0, 2.0)], &[2, 3, 4, 5, 6, 7]);
        assert_eq!(plan(&two, 1), Plan::default());
        // Three stripes, far apart across: three groups of one.
        let far = vec![
            rect(0, MarkingClass::Crosswalk, 0.0, 5.0, 0.0, 0.45),
            rect(1, MarkingClass::Crosswalk, 0.0, 5.0, 10.0, 10.45),
            rect(2, MarkingClass::Crosswalk, 0.0, 5.0, 20.0, 20.45),
        ];
        assert_eq!(plan(&far, 1), Plan::default());
    }
}
