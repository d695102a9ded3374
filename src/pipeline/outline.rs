//! Marking outlines: rectangles, buffered centrelines and alpha shapes.
//!
//! - Bar-like marks (dashes, stop lines, crosswalk and guideline stripes) get their robust
//!   principal-axis rectangle (see `geom::BarShape`): stray points do not inflate it.
//! - Long or curved line pieces get their centreline buffered by half the painted width, so
//!   a solid line on a curve is a thin curved band, not a fat rectangle.
//! - Irregular marks (arrows, diamonds, unknown) get an alpha shape (Edelsbrunner 1983, as
//!   in Yao 2021 for guidelines): Delaunay triangles (spade) with circumradius ≤ R are kept;
//!   boundary edges belong to exactly one kept triangle and are chained into rings; the ring
//!   of largest area of the largest connected piece is the outline. R starts at
//!   `max(0.15 m, 3 × point spacing)` and doubles (up to 3 times) while the outline holds
//!   < 80 % of the points; if none does, the largest R's outline holding ≥ 50 % (pieces
//!   farther apart than R: a far arrow's scan rows), and the convex hull only as the last
//!   resort. The ring is then grown by half the point spacing (geo's buffer): the painted
//!   edge lies that far beyond the outermost points on average.
//!
//! Complexity: O(n log n) for the alpha shape of n points; linear for the others.

use super::geom;
use spade::{DelaunayTriangulation, Point2, Triangulation};
use std::collections::HashMap;

/// Twice the signed area of a ring (counter-clockwise positive).
pub fn signed_area2(ring: &[[f64; 2]]) -> f64 {
    let n = ring.len();
    (0..n)
        .map(|i| {
            let (a, b) = (ring[i], ring[(i + 1) % n]);
            a[0] * b[1] - b[0] * a[1]
        })
        .sum()
}

/// Area of a ring.
pub fn area(ring: &[[f64; 2]]) -> f64 {
    signed_area2(ring).abs() / 2.0
}

/// Is `p` inside the ring or within `tol` of its boundary?
pub fn contains(ring: &[[f64; 2]], p: [f64; 2], tol: f64) -> bool {
    let n = ring.len();
    if n < 3 {
        return false;
    }
    let mut inside = false;
    let mut near = false;
    for i in 0..n {
        let (a, b) = (ring[i], ring[(i + 1) % n]);
        if (a[1] > p[1]) != (b[1] > p[1]) {
            let x = a[0] + (p[1] - a[1]) / (b[1] - a[1]) * (b[0] - a[0]);
            if p[0] < x {
                inside = !inside;
            }
        }
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        let l2 = dx * dx + dy * dy;
        let t = if l2 > 0.0 {
            (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / l2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let (qx, qy) = (a[0] + t * dx, a[1] + t * dy);
        if (p[0] - qx).hypot(p[1] - qy) <= tol {
            near = true;
        }
    }
    inside || near
}

/// Counter-clockwise convex hull (Andrew's monotone chain); degenerate inputs give fewer
/// than 3 vertices.
pub fn convex_hull(pts: &[[f64; 2]]) -> Vec<[f64; 2]> {
    let mut p: Vec<[f64; 2]> = pts.to_vec();
    p.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    p.dedup();
    if p.len() < 3 {
        return p;
    }
    let cross =
        |o: [f64; 2], a: [f64; 2], b: [f64; 2]| (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]);
    let mut hull: Vec<[f64; 2]> = Vec::with_capacity(2 * p.len());
    for &q in &p {
        while hull.len() >= 2 && cross(hull[hull.len() - 2], hull[hull.len() - 1], q) <= 0.0 {
            hull.pop();
        }
        hull.push(q);
    }
    let lower = hull.len() + 1;
    for &q in p.iter().rev().skip(1) {
        while hull.len() >= lower && cross(hull[hull.len() - 2], hull[hull.len() - 1], q) <= 0.0 {
            hull.pop();
        }
        hull.push(q);
    }
    hull.pop();
    hull
}

/// The alpha shape with circumradius bound `radius`: the outer ring (counter-clockwise) of
/// its largest connected piece, and the fraction of the (distinct) input points that are
/// vertices of that piece. None when no triangle survives (too few or collinear points, or
/// R too small).
pub fn alpha_shape(pts: &[[f64; 2]], radius: f64) -> Option<(Vec<[f64; 2]>, f64)> {
    let mut uniq: Vec<[f64; 2]> = pts
        .iter()
        .copied()
        .filter(|p| p[0].is_finite() && p[1].is_finite())
        .collect();
    uniq.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    uniq.dedup();
    if uniq.len() < 3 {
        return None;
    }
    let verts: Vec<Point2<f64>> = uniq.iter().map(|p| Point2::new(p[0], p[1])).collect();
    let tri: DelaunayTriangulation<Point2<f64>> = DelaunayTriangulation::bulk_load_stable(verts).ok()?;
    let r2 = radius * radius;
    let nf = tri.num_all_faces();
    let mut kept = vec![false; nf];
    let mut any = false;
    for f in tri.inner_faces() {
        let (_, rr) = f.circumcircle();
        if rr <= r2 {
            kept[f.fix().index()] = true;
            any = true;
        }
    }
    if !any {
        return None;
    }
    // Connected pieces of kept triangles (through shared edges).
    let mut parent: Vec<usize> = (0..nf).collect();
    for f in tri.inner_faces() {
        let fi = f.fix().index();
        if !kept[fi] {
            continue;
        }
        for e in f.adjacent_edges() {
            if let Some(o) = e.rev().face().as_inner() {
                let oi = o.fix().index();
                if kept[oi] {
                    geom::union(&mut parent, fi, oi);
                }
            }
        }
    }
    let mut piece_area: HashMap<usize, f64> = HashMap::new();
    for f in tri.inner_faces() {
        let fi = f.fix().index();
        if kept[fi] {
            let [a, b, c] = f.positions();
            let area = ((b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x)).abs() / 2.0;
            *piece_area.entry(geom::find_root(&mut parent, fi)).or_default() += area;
        }
    }
    let best = piece_area
        .iter()
        .max_by(|a, b| a.1.total_cmp(b.1).then(b.0.cmp(a.0)))
        .map(|(&k, _)| k)?;
    // Boundary edges of that piece, directed counter-clockwise; covered vertices.
    let mut next: HashMap<usize, Vec<usize>> = HashMap::new();
    let mut covered = vec![false; tri.num_vertices()];
    let mut nedges = 0usize;
    for f in tri.inner_faces() {
        let fi = f.fix().index();
        if !kept[fi] || geom::find_root(&mut parent, fi) != best {
            continue;
        }
        for v in f.vertices() {
            covered[v.fix().index()] = true;
        }
        for e in f.adjacent_edges() {
            let other_kept = e.rev().face().as_inner().is_some_and(|o| kept[o.fix().index()]);
            if !other_kept {
                next.entry(e.from().fix().index())
                    .or_default()
                    .push(e.to().fix().index());
                nedges += 1;
            }
        }
    }
    for v in next.values_mut() {
        v.sort_unstable();
    }
    let positions: Vec<[f64; 2]> = tri
        .vertices()
        .map(|v| {
            let p = v.position();
            [p.x, p.y]
        })
        .collect();
    // Chain edges into rings (a vertex touching two rings has two outgoing edges).
    let mut rings: Vec<Vec<[f64; 2]>> = Vec::new();
    let mut starts: Vec<usize> = next.keys().copied().collect();
    starts.sort_unstable();
    for s in starts {
        while next.get(&s).is_some_and(|v| !v.is_empty()) {
            let mut ring = vec![positions[s]];
            let mut cur = s;
            while let Some(list) = next.get_mut(&cur) {
                let Some(nx) = list.pop() else { break };
                if nx == s {
                    break;
                }
                ring.push(positions[nx]);
                cur = nx;
                if ring.len() > nedges + 1 {
                    break;
                }
            }
            if ring.len() >= 3 {
                rings.push(ring);
            }
        }
    }
    let frac = covered.iter().filter(|&&c| c).count() as f64 / covered.len() as f64;
    rings
        .into_iter()
        .filter(|r| signed_area2(r) > 0.0)
        .max_by(|a, b| signed_area2(a).total_cmp(&signed_area2(b)))
        .map(|r| (r, frac))
}

/// Share of its points an irregular outline must hold before the alpha radius stops
/// growing. Each doubling bridges wider gaps: where a sparsely scanned arrow's points fall
/// into pieces a scan row apart, insisting on 95 % made its outline nearly convex (3.2 m²
/// for a 1.45 m² arrow); 80 % keeps the concave shape and still takes in worn-off parts.
const ALPHA_MIN_INSIDE: f64 = 0.8;
/// Share of its points the largest alpha shape tried must hold to be the outline when none
/// holds [`ALPHA_MIN_INSIDE`]; below it the convex hull is the last resort. Such a cluster
/// is pieces farther apart than the largest radius (a far arrow seen as a few scan rows,
/// strays beside a line piece): their hull covered 2–3 times a far arrow's painted area and
/// 29 m² for a 35 m solid-line piece on a simulated urban drive.
const ALPHA_FALLBACK_INSIDE: f64 = 0.5;

/// Alpha-shape outline holding at least [`ALPHA_MIN_INSIDE`] of the points (radius grown as
/// needed), else the largest radius' shape if it holds [`ALPHA_FALLBACK_INSIDE`], else the
/// convex hull; grown outward by half the point spacing. `spacing` is the typical
/// point spacing.
///
/// The alpha shape runs through the outermost points, but each point samples the paint
/// around it: the painted edge lies on average half a spacing beyond them (a 0.45 m wide
/// arrow shaft sampled every 5 cm reads 0.40 m between its outer points), so the ring is
/// grown by that much.
pub fn irregular(pts: &[[f64; 2]], spacing: f64) -> Vec<[f64; 2]> {
    let mut r = (3.0 * spacing).max(0.15);
    let mut last = None;
    for _ in 0..4 {
        last = alpha_shape(pts, r);
        if let Some((ring, frac)) = &last
            && *frac >= ALPHA_MIN_INSIDE
        {
            return grown(ring, 0.5 * spacing);
        }
        r *= 2.0;
    }
    match last {
        Some((ring, frac)) if frac >= ALPHA_FALLBACK_INSIDE => grown(&ring, 0.5 * spacing),
        _ => grown(&convex_hull(pts), 0.5 * spacing),
    }
}

/// The ring grown outward by `d` (mitred corners); the ring itself when `d` <= 0 or the
/// buffer fails.
pub fn grown(ring: &[[f64; 2]], d: f64) -> Vec<[f64; 2]> {
    use geo::Buffer;
    use geo::algorithm::buffer::{BufferStyle, LineJoin};
    if d <= 0.0 || ring.len() < 3 {
        return ring.to_vec();
    }
    let mp = to_polygon(ring).buffer_with_style(BufferStyle::new(d).line_join(LineJoin::Miter(2.0)));
    match largest_exterior(&mp) {
        Some(out) if out.len() >= 3 => out,
        _ => ring.to_vec(),
    }
}

/// A ring (not closed) as a geo polygon without holes.
pub fn to_polygon(ring: &[[f64; 2]]) -> geo::Polygon<f64> {
    geo::Polygon::new(
        ring.iter().map(|p| geo::coord! {x: p[0], y: p[1]}).collect(),
        vec![],
    )
}

/// The exterior ring (not closed) of the largest polygon of `mp`; `None` when it is empty.
fn largest_exterior(mp: &geo::MultiPolygon<f64>) -> Option<Vec<[f64; 2]>> {
    use geo::Area;
    let best =
        mp.0.iter()
            .max_by(|a, b| a.unsigned_area().total_cmp(&b.unsigned_area()))?;
    let mut out: Vec<[f64; 2]> = best.exterior().coords().map(|c| [c.x, c.y]).collect();
    if out.len() > 1 && out[0] == out[out.len() - 1] {
        out.pop();
    }
    Some(out)
}

/// A polygon around an open centreline at `half_width` on both sides (mitred joins,
/// counter-clockwise).
pub fn buffered_line(line: &[[f64; 2]], half_width: f64) -> Vec<[f64; 2]> {
    let n = line.len();
    if n < 2 {
        return Vec::new();
    }
    let seg_normal = |i: usize| {
        let (a, b) = (line[i], line[i + 1]);
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        let l = dx.hypot(dy).max(1e-12);
        [-dy / l, dx / l]
    };
    let normals: Vec<[f64; 2]> = (0..n)
        .map(|i| {
            let a = seg_normal(i.min(n - 2));
            let b = seg_normal(i.saturating_sub(1).min(n - 2));
            let (x, y) = (a[0] + b[0], a[1] + b[1]);
            let l = x.hypot(y);
            if l < 1e-9 {
                return a;
            }
            let m = [x / l, y / l];
            // Mitre length 1/cos(half turn), capped for sharp turns.
            let c = (m[0] * a[0] + m[1] * a[1]).max(0.5);
            [m[0] / c, m[1] / c]
        })
        .collect();
    let mut ring: Vec<[f64; 2]> = Vec::with_capacity(2 * n);
    for i in 0..n {
        ring.push([
            line[i][0] - normals[i][0] * half_width,
            line[i][1] - normals[i][1] * half_width,
        ]);
    }
    for i in (0..n).rev() {
        ring.push([
            line[i][0] + normals[i][0] * half_width,
            line[i][1] + normals[i][1] * half_width,
        ]);
    }
    ring
}

/// The outline of a centreline buffered by `half_width` (flat ends, mitred joins) that is
/// always a valid simple polygon: [`buffered_line`] when its ring is simple, otherwise the
/// union of the buffered segments (geo's buffer, which resolves the fold of a centreline
/// that bends back on itself) — never a convex hull, which for a long bent line would
/// cover metres of bare asphalt. The largest part's exterior is returned; empty when the
/// line is degenerate.
pub fn buffered_line_simple(line: &[[f64; 2]], half_width: f64) -> Vec<[f64; 2]> {
    use geo::Buffer;
    use geo::algorithm::buffer::{BufferStyle, LineCap, LineJoin};
    let ring = buffered_line(line, half_width);
    if ring.len() >= 3 && is_simple(&ring) {
        return ring;
    }
    let ls: geo::LineString<f64> = line.iter().map(|p| geo::coord! {x: p[0], y: p[1]}).collect();
    let style = BufferStyle::new(half_width)
        .line_cap(LineCap::Butt)
        .line_join(LineJoin::Miter(2.0));
    largest_exterior(&ls.buffer_with_style(style)).unwrap_or_default()
}

/// Radius (m) of the largest circle inside the ring: the distance from its pole of
/// inaccessibility (the `polylabel` crate, to 5 mm) to the ring. 0 for a degenerate ring.
pub fn inscribed_radius(ring: &[[f64; 2]]) -> f64 {
    if ring.len() < 3 {
        return 0.0;
    }
    use geo::{Distance, Euclidean};
    let poly = to_polygon(ring);
    let Ok(pole) = polylabel::polylabel(&poly, &0.005) else {
        return 0.0;
    };
    Euclidean.distance(&pole, poly.exterior())
}

/// True when the closed ring (not repeated first vertex) has no two non-adjacent edges
/// that touch or cross: a valid simple polygon boundary. O(n²) over the n edges (outlines
/// have tens to a few hundred vertices).
pub fn is_simple(ring: &[[f64; 2]]) -> bool {
    let n = ring.len();
    if n < 3 {
        return false;
    }
    let orient =
        |a: [f64; 2], b: [f64; 2], c: [f64; 2]| (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
    let on_seg = |a: [f64; 2], b: [f64; 2], c: [f64; 2]| {
        c[0] >= a[0].min(b[0]) && c[0] <= a[0].max(b[0]) && c[1] >= a[1].min(b[1]) && c[1] <= a[1].max(b[1])
    };
    let cross = |p1: [f64; 2], p2: [f64; 2], q1: [f64; 2], q2: [f64; 2]| {
        let (d1, d2) = (orient(q1, q2, p1), orient(q1, q2, p2));
        let (d3, d4) = (orient(p1, p2, q1), orient(p1, p2, q2));
        if ((d1 > 0.0 && d2 < 0.0) || (d1 < 0.0 && d2 > 0.0))
            && ((d3 > 0.0 && d4 < 0.0) || (d3 < 0.0 && d4 > 0.0))
        {
            return true;
        }
        (d1 == 0.0 && on_seg(q1, q2, p1))
            || (d2 == 0.0 && on_seg(q1, q2, p2))
            || (d3 == 0.0 && on_seg(p1, p2, q1))
            || (d4 == 0.0 && on_seg(p1, p2, q2))
    };
    for i in 0..n {
        let (a, b) = (ring[i], ring[(i + 1) % n]);
        for j in i + 2..n {
            if i == 0 && j == n - 1 {
                continue; // adjacent through the closing edge
            }
            if cross(a, b, ring[j], ring[(j + 1) % n]) {
                return false;
            }
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inscribed_radius_of_a_bar_a_triangle_and_a_stroke() {
        let bar = [[0.0, 0.0], [2.0, 0.0], [2.0, 0.3], [0.0, 0.3]];
        assert!((inscribed_radius(&bar) - 0.15).abs() < 0.006);
        // Right triangle with legs 3 and 4: inradius (3 + 4 - 5) / 2 = 1.
        let tri = [[0.0, 0.0], [4.0, 0.0], [0.0, 3.0]];
        assert!((inscribed_radius(&tri) - 1.0).abs() < 0.006);
        // An L of 0.1 m strokes: the widest circle sits in its corner, touching both outer
        // edges and the inner corner: r = 0.1 √2 / (1 + √2) = 0.059.
        let l = [
            [0.0, 0.0],
            [2.0, 0.0],
            [2.0, 0.1],
            [0.1, 0.1],
            [0.1, 2.0],
            [0.0, 2.0],
        ];
        assert!((inscribed_radius(&l) - 0.1 * 2f64.sqrt() / (1.0 + 2f64.sqrt())).abs() < 0.006);
        assert_eq!(inscribed_radius(&[[0.0, 0.0], [1.0, 0.0]]), 0.0);
    }

    #[test]
    fn simple_rings_are_told_from_self_intersecting_ones() {
        assert!(is_simple(&[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]));
        // Bow tie.
        assert!(!is_simple(&[[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0]]));
        // Touching itself at a vertex.
        assert!(!is_simple(&[[0.0, 0.0], [2.0, 0.0], [1.0, 0.0], [1.0, 1.0]]));
        assert!(!is_simple(&[[0.0, 0.0], [1.0, 0.0]]));
    }

    #[test]
    fn degenerate_inputs() {
        assert!(alpha_shape(&[], 1.0).is_none());
        assert!(alpha_shape(&[[0.0, 0.0], [1.0, 0.0]], 1.0).is_none());
        assert!(alpha_shape(&[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]], 1.0).is_none());
        assert_eq!(convex_hull(&[[0.0, 0.0], [0.0, 0.0]]).len(), 1);
        // Collinear points fall back to a degenerate hull without panicking.
        let line: Vec<[f64; 2]> = (0..10).map(|i| [i as f64, 0.0]).collect();
        assert!(irregular(&line, 0.05).len() < 3);
        assert!(buffered_line(&[[0.0, 0.0]], 0.1).is_empty());
    }

    /// A 1 × 1 m block of paint and a small piece 0.6 m off (a tenth of the points, as a
    /// sparse arrow's tip a scan row away): the outline is the block, not a hull bridging the
    /// gap.
    #[test]
    fn a_detached_tenth_of_the_points_does_not_bridge_the_outline() {
        let mut pts = Vec::new();
        for i in 0..=20 {
            for j in 0..=20 {
                pts.push([i as f64 * 0.05, j as f64 * 0.05]);
            }
        }
        for i in 0..=6 {
            for j in 0..=6 {
                pts.push([1.6 + i as f64 * 0.05, 1.6 + j as f64 * 0.05]);
            }
        }
        let a = area(&irregular(&pts, 0.05));
        assert!((a - 1.1).abs() < 0.05, "area {a}");
    }

    /// The block with a third of the points in a second block 3 m off (beyond any alpha
    /// radius tried): no alpha shape holds 80 % of the points, and the outline is the larger
    /// block's, not the convex hull of both (a far arrow seen as a few scan rows, and a 35 m
    /// solid-line piece with strays, had 3–29 m² hulls). Below half the points the hull
    /// stays the last resort.
    #[test]
    fn without_a_shape_holding_most_points_the_largest_piece_beats_the_hull() {
        let grid = |x0: f64, n: usize| -> Vec<[f64; 2]> {
            (0..=n)
                .flat_map(|i| (0..=n).map(move |j| [x0 + i as f64 * 0.05, j as f64 * 0.05]))
                .collect()
        };
        let mut pts = grid(0.0, 20);
        pts.extend(grid(4.0, 14));
        let (big, small) = (21.0 * 21.0, 15.0 * 15.0);
        assert!(big / (big + small) < ALPHA_MIN_INSIDE && big / (big + small) >= ALPHA_FALLBACK_INSIDE);
        let ring = irregular(&pts, 0.05);
        let a = area(&ring);
        assert!((a - 1.1).abs() < 0.05, "area {a}");
        assert!(!contains(&ring, [4.3, 0.3], 0.0));
        // Three equal blocks: none holds half the points; the hull spans them all.
        let mut three = grid(0.0, 10);
        three.extend(grid(4.0, 10));
        three.extend(grid(8.0, 10));
        let hull = irregular(&three, 0.05);
        assert!(contains(&hull, [4.25, 0.25], 0.0) && contains(&hull, [0.25, 0.25], 0.0));
    }

    #[test]
    fn alpha_shape_of_an_l_is_concave() {
        let mut pts = Vec::new();
        for i in 0..=40 {
            for j in 0..=40 {
                let (x, y) = (i as f64 * 0.05, j as f64 * 0.05);
                if x <= 0.5 || y <= 0.5 {
                    pts.push([x, y]);
                }
            }
        }
        let ring = irregular(&pts, 0.05);
        let a = area(&ring);
        // Each point stands for its 5 cm cell: 41 × 11 × 2 − 11 × 11 = 781 cells, 1.9525 m²
        // (the outermost points alone enclose 1.75 m²; the convex hull would be ~3.4 m²).
        assert!((a - 1.9525).abs() < 0.03, "area {a}");
        assert!(!contains(&ring, [1.5, 1.5], 0.0));
        let inside = pts.iter().filter(|&&p| contains(&ring, p, 1e-6)).count();
        assert_eq!(inside, pts.len());
    }

    #[test]
    fn buffered_line_follows_an_arc() {
        let line: Vec<[f64; 2]> = (0..=20)
            .map(|i| {
                let a = (i as f64 * 0.5f64).to_radians();
                [100.0 * a.sin(), 100.0 - 100.0 * a.cos()]
            })
            .collect();
        let ring = buffered_line(&line, 0.075);
        assert_eq!(ring.len(), 42);
        assert!(signed_area2(&ring) > 0.0);
        for q in &ring {
            let r = q[0].hypot(q[1] - 100.0);
            assert!((r - 100.0).abs() < 0.0751 && (r - 100.0).abs() > 0.0749, "{r}");
        }
    }

    #[test]
    fn a_folded_centreline_gets_a_thin_valid_outline_not_a_hull() {
        // A 10 m line that turns back on itself 0.05 m beside its start (a zigzag cluster).
        let line = vec![
            [0.0, 0.0],
            [10.0, 0.0],
            [10.0, 0.05],
            [0.0, 0.05],
            [0.0, 0.1],
            [10.0, 0.1],
        ];
        let ring = buffered_line(&line, 0.075);
        assert!(!is_simple(&ring), "the plain ring folds");
        let ok = buffered_line_simple(&line, 0.075);
        assert!(is_simple(&ok));
        let a = area(&ok);
        // Union of the three overlapping strips: 10 m × (0.1 + 0.15) m, far below a hull
        // of the bent ring would be for a longer fold, and above one strip alone.
        assert!(a > 1.5 && a < 2.8, "{a}");
        // A simple ring comes back unchanged.
        let straight = vec![[0.0, 0.0], [5.0, 0.0]];
        assert_eq!(
            buffered_line_simple(&straight, 0.1),
            buffered_line(&straight, 0.1)
        );
    }
}
