//! Stop-line joining: the pieces of one stop line become one bar.
//!
//! **What.** A stop line is one straight bar across the lanes of an approach. What the
//! pipeline sees of it is often several marks: worn paint breaks it into pieces (the short
//! ones read as guideline stripes, dashes or unknown fragments), and lane lines ending on it
//! cut it apart. Given the marks of a drive, this module joins to every stop line the marks
//! lying on its centre line beyond its ends and returns one bar per stop line.
//!
//! **Algorithm** (on outlines in the plane; written here: no library does this).
//! 1. Stop lines, longest first. Frame: `a` along the bar (principal axis of its outline),
//!    `b` across; the bar's half-width `h` and extent `[lo, hi]` along `a`.
//!    Axis from the outline's area moments and width = area / length, centre line through
//!    the centroid (bits of lane lines left in a stop line's outline barely move these).
//! 2. Candidates: other marks (not lane lines' solid pieces longer than
//!    [`MAX_FRAGMENT_LENGTH_M`], not crosswalk stripes) whose centroid lies within
//!    `h + 0.1 m` of the centre line and every vertex within `h + 0.3 m`, and that are
//!    parallel to it (≤ 15°) or no longer than 1 m.
//! 3. Growing: repeatedly, a candidate whose extent starts at most [`MAX_JOIN_GAP_M`]
//!    beyond the current extent (on either end) is joined and the extent widened. Other
//!    stop lines join too (a stop line cut in two by a lane line's end).
//! 4. The bar: the joined extent along `a`; width and centre line the length-weighted
//!    medians over the joined parts.
//!
//! **Complexity.** O(s · m · j) for s stop lines, m marks and j joins (a few).

use super::crosswalks::{Mark, Stripe, frame_of};
use super::geom;
use super::types::MarkingClass;

/// Marks are joined across gaps up to this long (m) along the stop line.
pub const MAX_JOIN_GAP_M: f64 = 1.5;
/// Solid pieces longer than this (m) are lane lines, never pieces of a stop line.
pub const MAX_FRAGMENT_LENGTH_M: f64 = 3.0;
/// A joined piece's centroid lies within half the bar's width + this (m) of its centre
/// line, and every vertex within half the width + [`VERTEX_TOL_M`].
const CENTRE_TOL_M: f64 = 0.1;
const VERTEX_TOL_M: f64 = 0.3;
/// Most misalignment of a joined piece (deg).
const MAX_ANGLE_DEG: f64 = 15.0;

/// (key of the stop line, its joined bar, keys of the marks joined into it).
pub type Join = (usize, Stripe, Vec<usize>);

/// The joins over all marks of a drive (see the module docs). Only stop lines that gained
/// a piece are returned.
pub fn plan(marks: &[Mark]) -> Vec<Join> {
    let mut order: Vec<usize> = (0..marks.len())
        .filter(|&i| marks[i].class == MarkingClass::StopLine && marks[i].ring.len() >= 3)
        .collect();
    let frames: Vec<_> = marks.iter().map(|m| frame_of(&m.ring)).collect();
    let len = |i: usize| frames[i].1.1 - frames[i].1.0;
    order.sort_by(|&x, &y| len(y).total_cmp(&len(x)));
    let mut used = vec![false; marks.len()];
    let mut out = Vec::new();
    for &s in &order {
        if used[s] {
            continue;
        }
        used[s] = true;
        let pca = area_frame(&marks[s].ring).unwrap_or(frames[s].0);
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for &p in &marks[s].ring {
            let u = pca.to_frame(p)[0];
            lo = lo.min(u);
            hi = hi.max(u);
        }
        // Robust across the bar: bits of lane lines left in its outline widen its extent,
        // not much its area, so width = area / length and the centre line through the
        // centroid.
        let (vc, w0) = centre_and_width(&marks[s].ring, &pca);
        let half = w0 / 2.0;
        // Candidates in the stop line's frame: (index, lo, hi).
        let cands: Vec<(usize, f64, f64)> = (0..marks.len())
            .filter(|&i| !used[i] && marks[i].ring.len() >= 3)
            .filter(|&i| match marks[i].class {
                MarkingClass::Crosswalk => false,
                MarkingClass::SolidLine => len(i) <= MAX_FRAGMENT_LENGTH_M,
                _ => true,
            })
            .filter_map(|i| {
                let (mut ulo, mut uhi) = (f64::INFINITY, f64::NEG_INFINITY);
                for &p in &marks[i].ring {
                    let q = pca.to_frame(p);
                    if (q[1] - vc).abs() > half + VERTEX_TOL_M {
                        return None;
                    }
                    ulo = ulo.min(q[0]);
                    uhi = uhi.max(q[0]);
                }
                if (centre_and_width(&marks[i].ring, &pca).0 - vc).abs() > half + CENTRE_TOL_M {
                    return None;
                }
                let parallel = geom::acute_angle_deg(frames[i].0.axis, pca.axis) <= MAX_ANGLE_DEG;
                (parallel || len(i) <= 1.0).then_some((i, ulo, uhi))
            })
            .collect();
        let mut joined = Vec::new();
        let mut parts: Vec<usize> = vec![s];
        let mut grew = true;
        while grew {
            grew = false;
            for &(i, ulo, uhi) in &cands {
                if used[i] {
                    continue;
                }
                if ulo <= hi + MAX_JOIN_GAP_M && uhi >= lo - MAX_JOIN_GAP_M {
                    used[i] = true;
                    joined.push(marks[i].key);
                    parts.push(i);
                    lo = lo.min(ulo);
                    hi = hi.max(uhi);
                    grew = true;
                }
            }
        }
        if joined.is_empty() {
            continue;
        }
        // Width and centre line: length-weighted medians over the parts (a stop line cut
        // by lane lines' ends may hold bits of them, which widen its own outline).
        let mut widths: Vec<(f64, f64)> = Vec::new();
        let mut centres: Vec<(f64, f64)> = Vec::new();
        for &i in &parts {
            let (c, w) = centre_and_width(&marks[i].ring, &pca);
            let l = frames[i].1.1 - frames[i].1.0;
            widths.push((w, l));
            centres.push((c, l));
        }
        let (w, vc) = (
            geom::weighted_median(&mut widths),
            geom::weighted_median(&mut centres),
        );
        let half = w / 2.0;
        let f = |u: f64, v: f64| pca.from_frame([u, v]);
        let (b0, b1) = (vc - half, vc + half);
        out.push((
            marks[s].key,
            Stripe {
                ring: [f(lo, b0), f(hi, b0), f(hi, b1), f(lo, b1)],
                length_m: hi - lo,
                width_m: 2.0 * half,
                axis: pca.axis,
            },
            joined,
        ));
    }
    out
}

/// Principal axes of a polygon's area (not of its vertices: a few vertices of a bump
/// would turn those), from its second moments (Green's theorem).
fn area_frame(ring: &[[f64; 2]]) -> Option<geom::Pca> {
    let n = ring.len();
    let o = ring[0];
    let (mut a2, mut cx, mut cy, mut ixx, mut iyy, mut ixy) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for i in 0..n {
        let (p, q) = (ring[i], ring[(i + 1) % n]);
        let (x0, y0, x1, y1) = (p[0] - o[0], p[1] - o[1], q[0] - o[0], q[1] - o[1]);
        let c = x0 * y1 - x1 * y0;
        a2 += c;
        cx += (x0 + x1) * c;
        cy += (y0 + y1) * c;
        ixx += (x0 * x0 + x0 * x1 + x1 * x1) * c;
        iyy += (y0 * y0 + y0 * y1 + y1 * y1) * c;
        ixy += (x0 * y1 + 2.0 * x0 * y0 + 2.0 * x1 * y1 + x1 * y0) * c;
    }
    if a2.abs() < 1e-12 {
        return None;
    }
    let area = a2 / 2.0;
    let (cx, cy) = (cx / (3.0 * a2), cy / (3.0 * a2));
    // Central moments (∫x², ∫y², ∫xy about the centroid).
    let sxx = ixx / 12.0 - area * cx * cx;
    let syy = iyy / 12.0 - area * cy * cy;
    let sxy = ixy / 24.0 - area * cx * cy;
    let t = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    let mut axis = [t.cos(), t.sin()];
    if axis[0] < 0.0 || (axis[0] == 0.0 && axis[1] < 0.0) {
        axis = [-axis[0], -axis[1]];
    }
    let (c2, s2) = (axis[0], axis[1]);
    let along = (c2 * c2 * sxx + 2.0 * c2 * s2 * sxy + s2 * s2 * syy) / area;
    let across = (s2 * s2 * sxx - 2.0 * c2 * s2 * sxy + c2 * c2 * syy) / area;
    Some(geom::Pca {
        center: [cx + o[0], cy + o[1]],
        axis,
        var: [along.abs(), across.abs()],
    })
}

/// Centroid offset across the bar (in `pca`'s frame) and area / length along it of a ring.
fn centre_and_width(ring: &[[f64; 2]], pca: &geom::Pca) -> (f64, f64) {
    let uv: Vec<[f64; 2]> = ring.iter().map(|&p| pca.to_frame(p)).collect();
    let n = uv.len();
    let (mut a2, mut cv) = (0.0, 0.0);
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for i in 0..n {
        let (p, q) = (uv[i], uv[(i + 1) % n]);
        let cross = p[0] * q[1] - q[0] * p[1];
        a2 += cross;
        cv += (p[1] + q[1]) * cross;
        lo = lo.min(p[0]);
        hi = hi.max(p[0]);
    }
    if a2.abs() < 1e-12 || hi <= lo {
        let v = uv.iter().map(|p| p[1]).sum::<f64>() / n.max(1) as f64;
        return (v, 0.0);
    }
    (cv / (3.0 * a2), (a2.abs() / 2.0) / (hi - lo))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::crosswalks::tests::rect;

    #[test]
    fn pieces_on_the_line_are_joined_and_others_are_not() {
        let marks = vec![
            rect(0, MarkingClass::StopLine, 2.0, 6.0, 0.0, 0.3),
            // Worn pieces on its line, one beyond the other.
            rect(1, MarkingClass::Guideline, 6.8, 8.0, 0.02, 0.28),
            rect(2, MarkingClass::Unknown, 9.0, 9.6, 0.05, 0.3),
            // Cut off by a lane line's end: another stop line.
            rect(3, MarkingClass::StopLine, 0.0, 1.5, 0.0, 0.3),
            // A lane line ending on it, a dash across it, a piece too far along, a crosswalk.
            rect(4, MarkingClass::SolidLine, 3.0, 3.15, 0.3, 30.0),
            rect(5, MarkingClass::DashedLine, 4.9, 5.05, -1.0, 1.0),
            rect(6, MarkingClass::Unknown, 12.0, 12.5, 0.0, 0.3),
            rect(7, MarkingClass::Crosswalk, 10.0, 10.0 + 0.45, -5.0, 0.0),
        ];
        let j = plan(&marks);
        assert_eq!(j.len(), 1);
        let (k, bar, joined) = &j[0];
        assert_eq!(*k, 0);
        let mut joined = joined.clone();
        joined.sort();
        assert_eq!(joined, vec![1, 2, 3]);
        assert!((bar.length_m - 9.6).abs() < 1e-9, "{}", bar.length_m);
        assert!((bar.width_m - 0.3).abs() < 1e-9);
    }

    #[test]
    fn a_stop_line_widened_by_lane_line_bits_gets_its_pieces_width() {
        // The stop line's cluster kept 2 m of two lane lines' ends: 1.3 m wide outline.
        let mut stub = rect(0, MarkingClass::StopLine, 0.0, 6.0, 0.0, 0.3);
        stub.ring = vec![
            [0.0, 0.0],
            [6.0, 0.0],
            [6.0, 0.3],
            [4.1, 0.3],
            [4.1, 1.3],
            [3.9, 1.3],
            [3.9, 0.3],
            [0.0, 0.3],
        ];
        let marks = vec![
            stub,
            rect(1, MarkingClass::Guideline, 6.5, 8.0, 0.0, 0.3),
            rect(2, MarkingClass::Guideline, 8.5, 10.0, 0.0, 0.3),
        ];
        let f = area_frame(&marks[0].ring).unwrap();
        assert!(
            f.axis[1].abs() < 0.03,
            "the bump turns the axis little: {:?}",
            f.axis
        );
        let j = plan(&marks);
        assert_eq!(j.len(), 1);
        assert!((j[0].1.width_m - 0.3).abs() < 0.05, "{}", j[0].1.width_m);
        assert!((j[0].1.length_m - 10.0).abs() < 0.05, "{}", j[0].1.length_m);
    }

    #[test]
    fn a_lone_stop_line_is_not_changed() {
        let marks = vec![rect(0, MarkingClass::StopLine, 0.0, 6.0, 0.0, 0.3)];
        assert!(plan(&marks).is_empty());
    }
}
