//! Polygon rasterisation into run-length pixel sets, for the pixel-level metrics.
//!
//! **What.** A [`SpanSet`] is a set of pixels of a grid of square cells (`px` metres, cell
//! (c, r) covering `[c·px, (c+1)·px) × [r·px, (r+1)·px)` in local coordinates), stored as
//! sorted, merged horizontal runs `[c0, c1)` per row. Union, intersection size and disk
//! dilation work on the runs, never on a full image.
//!
//! **Algorithm.** Scanline fill with the pixel-centre rule: a pixel belongs to a polygon when
//! its centre is inside (even–odd rule, half-open in y so shared edges are not counted
//! twice). Each edge contributes one crossing per row whose centre line it spans; crossings are
//! sorted by (row, x) and paired. Runs from many polygons are merged by one sort.
//!
//! **Parameters.** `px`: cell size in metres (0.05 m in the papers).
//!
//! **Reference.** Classic edge-list scan conversion (Foley et al., *Computer Graphics*, §3.6).
//!
//! **Complexity.** O(C log C) for C crossings (≈ rows spanned × edges crossing a row), memory
//! O(runs): a 1 km lane line at 0.05 m is 20 000 runs, not a 12 M pixel image.

/// One run of pixels: row, first column, one past the last column.
pub type Span = (i64, i64, i64);

/// A set of pixels as sorted, disjoint, non-adjacent runs.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SpanSet {
    spans: Vec<Span>,
}

/// Push the runs of one polygon ring (local coordinates, any orientation, not closed).
fn ring_spans(ring: &[[f64; 2]], px: f64, out: &mut Vec<Span>, crossings: &mut Vec<(i64, f64)>) {
    crossings.clear();
    let n = ring.len();
    for i in 0..n {
        let (a, b) = (ring[i], ring[(i + 1) % n]);
        if a[1] == b[1] {
            continue;
        }
        let (lo, hi) = if a[1] < b[1] { (a, b) } else { (b, a) };
        // Rows whose centre y = (r + 0.5)·px satisfies lo.y <= y < hi.y.
        let r0 = (lo[1] / px - 0.5).ceil() as i64;
        let r1 = (hi[1] / px - 0.5).ceil() as i64; // exclusive
        let slope = (hi[0] - lo[0]) / (hi[1] - lo[1]);
        for r in r0..r1 {
            let y = (r as f64 + 0.5) * px;
            crossings.push((r, lo[0] + (y - lo[1]) * slope));
        }
    }
    crossings.sort_by(|p, q| p.0.cmp(&q.0).then(p.1.total_cmp(&q.1)));
    for pair in crossings.chunks_exact(2) {
        let ((r, xa), (_, xb)) = (pair[0], pair[1]);
        // Columns whose centre x = (c + 0.5)·px satisfies xa <= x < xb.
        let c0 = (xa / px - 0.5).ceil() as i64;
        let c1 = (xb / px - 0.5).ceil() as i64;
        if c1 > c0 {
            out.push((r, c0, c1));
        }
    }
}

impl SpanSet {
    /// Sort and merge arbitrary (possibly overlapping) runs.
    pub fn from_spans(mut spans: Vec<Span>) -> Self {
        spans.sort_unstable();
        let mut merged: Vec<Span> = Vec::with_capacity(spans.len());
        for s in spans {
            match merged.last_mut() {
                Some(last) if last.0 == s.0 && s.1 <= last.2 => last.2 = last.2.max(s.2),
                _ => merged.push(s),
            }
        }
        Self { spans: merged }
    }

    /// The union of the pixels of several polygons (rings in local coordinates).
    pub fn from_polygons<'a>(rings: impl IntoIterator<Item = &'a [[f64; 2]]>, px: f64) -> Self {
        let mut spans = Vec::new();
        let mut crossings = Vec::new();
        for ring in rings {
            ring_spans(ring, px, &mut spans, &mut crossings);
        }
        Self::from_spans(spans)
    }

    pub fn spans(&self) -> &[Span] {
        &self.spans
    }

    pub fn is_empty(&self) -> bool {
        self.spans.is_empty()
    }

    /// Number of pixels.
    pub fn count(&self) -> u64 {
        self.spans.iter().map(|s| (s.2 - s.1) as u64).sum()
    }

    /// Number of pixels in both sets (one merge walk).
    pub fn intersection_count(&self, other: &SpanSet) -> u64 {
        let (a, b) = (&self.spans, &other.spans);
        let (mut i, mut j, mut n) = (0, 0, 0u64);
        while i < a.len() && j < b.len() {
            let (s, t) = (a[i], b[j]);
            if s.0 < t.0 || (s.0 == t.0 && s.2 <= t.1) {
                i += 1;
                continue;
            }
            if t.0 < s.0 || t.2 <= s.1 {
                j += 1;
                continue;
            }
            // Same row, overlapping runs.
            n += (s.2.min(t.2) - s.1.max(t.1)) as u64;
            if s.2 <= t.2 {
                i += 1;
            } else {
                j += 1;
            }
        }
        n
    }

    /// All pixels whose centre is within `r` pixels of a pixel centre of the set (a disk).
    pub fn dilate(&self, r: i64) -> SpanSet {
        if r <= 0 {
            return self.clone();
        }
        let half: Vec<i64> = (-r..=r)
            .map(|dy| (((r * r - dy * dy) as f64).sqrt() + 1e-9).floor() as i64)
            .collect();
        let mut out = Vec::with_capacity(self.spans.len() * half.len());
        for &(row, c0, c1) in &self.spans {
            for (k, w) in half.iter().enumerate() {
                out.push((row + k as i64 - r, c0 - w, c1 + w));
            }
        }
        SpanSet::from_spans(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn rect(x0: f64, y0: f64, x1: f64, y1: f64) -> Vec<[f64; 2]> {
        vec![[x0, y0], [x1, y0], [x1, y1], [x0, y1]]
    }

    #[test]
    fn aligned_rectangle_counts_exactly() {
        // 0.15 m x 6 m at 0.05 m: 3 x 120 pixels.
        let r = rect(1.0, 2.0, 1.15, 8.0);
        let s = SpanSet::from_polygons([r.as_slice()], 0.05);
        assert_eq!(s.count(), 360);
        assert_eq!(s.spans().len(), 120);
        // Orientation does not matter.
        let mut rev = r.clone();
        rev.reverse();
        assert_eq!(SpanSet::from_polygons([rev.as_slice()], 0.05), s);
    }

    #[test]
    fn degenerate_inputs() {
        let empty: [&[[f64; 2]]; 0] = [];
        assert!(SpanSet::from_polygons(empty, 0.05).is_empty());
        let line = vec![[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]];
        assert_eq!(SpanSet::from_polygons([line.as_slice()], 0.05).count(), 0);
        let tiny = rect(0.0, 0.0, 0.01, 0.01);
        assert_eq!(SpanSet::from_polygons([tiny.as_slice()], 0.05).count(), 0);
    }

    #[test]
    fn union_and_intersection() {
        let a = rect(0.0, 0.0, 1.0, 1.0);
        let b = rect(0.5, 0.0, 1.5, 1.0);
        let sa = SpanSet::from_polygons([a.as_slice()], 0.1);
        let sb = SpanSet::from_polygons([b.as_slice()], 0.1);
        let u = SpanSet::from_polygons([a.as_slice(), b.as_slice()], 0.1);
        assert_eq!(sa.count(), 100);
        assert_eq!(u.count(), 150);
        assert_eq!(sa.intersection_count(&sb), 50);
        assert_eq!(sb.intersection_count(&sa), 50);
        assert_eq!(sa.intersection_count(&sa), 100);
        assert_eq!(sa.intersection_count(&SpanSet::default()), 0);
    }

    #[test]
    fn concave_polygon_has_two_runs_per_row() {
        // A U shape: two 0.2 m legs, 0.6 m apart, joined at the bottom.
        let u = vec![
            [0.0, 0.0],
            [1.0, 0.0],
            [1.0, 1.0],
            [0.8, 1.0],
            [0.8, 0.2],
            [0.2, 0.2],
            [0.2, 1.0],
            [0.0, 1.0],
        ];
        let s = SpanSet::from_polygons([u.as_slice()], 0.1);
        assert_eq!(s.count(), 20 + 2 * 2 * 8);
        assert_eq!(s.spans().iter().filter(|sp| sp.0 == 5).count(), 2);
    }

    #[test]
    fn dilation_is_a_disk() {
        let one = SpanSet::from_spans(vec![(0, 0, 1)]);
        // Radius 1: the 4-neighbourhood plus the centre; radius 2: 13 pixels.
        assert_eq!(one.dilate(1).count(), 5);
        assert_eq!(one.dilate(2).count(), 13);
        assert_eq!(one.dilate(0), one);
    }

    proptest! {
        #[test]
        fn count_approximates_area(x0 in -50.0f64..50.0, y0 in -50.0f64..50.0,
                                   w in 0.1f64..5.0, h in 0.1f64..5.0, a in 0.0f64..3.2) {
            // A rotated rectangle: pixel count within one perimeter band of its area.
            let (c, s) = (a.cos(), a.sin());
            let ring: Vec<[f64; 2]> = [[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]]
                .iter().map(|p| [x0 + p[0] * c - p[1] * s, y0 + p[0] * s + p[1] * c]).collect();
            let px = 0.05;
            let area = SpanSet::from_polygons([ring.as_slice()], px).count() as f64 * px * px;
            prop_assert!((area - w * h).abs() <= 2.0 * (w + h) * px, "{} vs {}", area, w * h);
        }

        #[test]
        fn intersection_is_symmetric_and_bounded(
            a in proptest::collection::vec((0i64..20, -30i64..30, 1i64..10), 0..30),
            b in proptest::collection::vec((0i64..20, -30i64..30, 1i64..10), 0..30)) {
            let sa = SpanSet::from_spans(a.iter().map(|&(r, c, w)| (r, c, c + w)).collect());
            let sb = SpanSet::from_spans(b.iter().map(|&(r, c, w)| (r, c, c + w)).collect());
            let i = sa.intersection_count(&sb);
            prop_assert_eq!(i, sb.intersection_count(&sa));
            prop_assert!(i <= sa.count().min(sb.count()));
            // Brute force on the small grid.
            let cells = |s: &SpanSet| {
                let mut set = std::collections::HashSet::new();
                for &(r, c0, c1) in s.spans() { for c in c0..c1 { set.insert((r, c)); } }
                set
            };
            prop_assert_eq!(i as usize, cells(&sa).intersection(&cells(&sb)).count());
        }
    }
}
