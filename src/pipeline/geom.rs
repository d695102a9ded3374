//! Small planar geometry helpers shared by the cluster, classify and vectorize stages.
//!
//! - [`GridIndex`]: points bucketed in square cells, for radius connectivity (Euclidean
//!   clustering) and nearest-neighbour spacing without building a tree.
//! - [`components`]: exact connected components of the "distance ≤ r" graph in O(n) expected
//!   time (cells of side r/√2 are cliques, so only cell pairs need a point-pair test, and a
//!   pair already joined is never tested again).
//! - [`Pca`], [`robust_extent`], [`quantile_sorted`]: the robust principal-axis rectangle used
//!   for the minimum bounding rectangle (MBR) features of the papers. The extent estimator
//!   treats the coordinate as uniform over the painted bar, so a few stray points do not
//!   inflate it (unlike a raw min/max MBR).
//! - [`local_linear`]: Gaussian-weighted local linear regression (a moving least-squares
//!   smoother) used for centrelines and offsets.
//!
//! Everything here is deterministic for a given input order; callers that need results
//! independent of the point order sort their points canonically first (see `cluster`).

use std::collections::HashMap;

/// `v.floor() as i64` without the libm call: the default x86-64 target has no SSE 4.1
/// `roundsd`, so `f64::floor` is an out-of-line call, which showed up as 6 % of a
/// pipeline profile (grid indices of every point). Identical for every `f64`, NaN and
/// infinities included (saturating like `as`).
#[inline]
pub fn floor_i64(v: f64) -> i64 {
    let t = v as i64;
    if (t as f64) > v { t.saturating_sub(1) } else { t }
}

/// Points bucketed in square cells of side `cell` (sorted by cell, so each cell is a slice).
pub struct GridIndex {
    cell: f64,
    /// Point indices (into the caller's slice) ordered by cell.
    order: Vec<u32>,
    /// Cell key → range in `order`.
    cells: HashMap<(i64, i64), (u32, u32)>,
    /// Cell keys in sorted order (deterministic iteration).
    keys: Vec<(i64, i64)>,
}

impl GridIndex {
    pub fn new(xy: &[[f64; 2]], cell: f64) -> Self {
        // Keys computed once (not in the sort's comparisons), sorted with their index.
        let mut keyed: Vec<((i64, i64), u32)> = xy
            .iter()
            .enumerate()
            .map(|(i, p)| ((floor_i64(p[0] / cell), floor_i64(p[1] / cell)), i as u32))
            .collect();
        keyed.sort_unstable();
        let order: Vec<u32> = keyed.iter().map(|e| e.1).collect();
        let mut cells = HashMap::with_capacity(xy.len() / 4 + 1);
        let mut keys = Vec::new();
        let mut start = 0usize;
        while start < keyed.len() {
            let k = keyed[start].0;
            let mut end = start + 1;
            while end < keyed.len() && keyed[end].0 == k {
                end += 1;
            }
            cells.insert(k, (start as u32, end as u32));
            keys.push(k);
            start = end;
        }
        Self {
            cell,
            order,
            cells,
            keys,
        }
    }

    fn slice(&self, k: (i64, i64)) -> Option<&[u32]> {
        self.cells
            .get(&k)
            .map(|&(a, b)| &self.order[a as usize..b as usize])
    }

    /// Indices of the points in the cells within `rings` cells of the cell holding `p`
    /// (a (2·rings + 1)² block, column by column, each cell in index order).
    pub fn around(&self, p: [f64; 2], rings: i64) -> impl Iterator<Item = usize> + '_ {
        let (kx, ky) = (floor_i64(p[0] / self.cell), floor_i64(p[1] / self.cell));
        (-rings..=rings)
            .flat_map(move |dx| (-rings..=rings).map(move |dy| (kx + dx, ky + dy)))
            .filter_map(|k| self.slice(k))
            .flatten()
            .map(|&i| i as usize)
    }

    /// Distance to the nearest other point within `max_r` (None when there is none).
    pub fn nearest_other(&self, xy: &[[f64; 2]], i: usize, max_r: f64) -> Option<f64> {
        let p = xy[i];
        let (kx, ky) = (floor_i64(p[0] / self.cell), floor_i64(p[1] / self.cell));
        let rings = (max_r / self.cell).ceil() as i64;
        let mut best = f64::INFINITY;
        for ring in 0..=rings {
            // Once a candidate is closer than the inner edge of this ring, stop.
            if best <= (ring - 1).max(0) as f64 * self.cell {
                break;
            }
            for dx in -ring..=ring {
                for dy in -ring..=ring {
                    if dx.abs() != ring && dy.abs() != ring {
                        continue;
                    }
                    if let Some(s) = self.slice((kx + dx, ky + dy)) {
                        for &j in s {
                            if j as usize != i {
                                let q = xy[j as usize];
                                best = best.min((q[0] - p[0]).hypot(q[1] - p[1]));
                            }
                        }
                    }
                }
            }
        }
        (best <= max_r).then_some(best)
    }
}

/// Exact connected components of the graph joining points closer than or at `r`.
///
/// Returns groups of indices into `xy`, each sorted ascending, groups ordered by their first
/// index. Cells have side r/√2 (slightly less), so all points of one cell are connected and
/// the union-find runs over cells; a neighbouring cell pair is tested point by point only
/// while the two cells are not yet in the same component, with an early exit on the first
/// pair within `r`.
pub fn components(xy: &[[f64; 2]], r: f64) -> Vec<Vec<usize>> {
    if xy.is_empty() {
        return Vec::new();
    }
    let cell = r / std::f64::consts::SQRT_2 * 0.999;
    let grid = GridIndex::new(xy, cell);
    let ncell = grid.keys.len();
    let cell_id: HashMap<(i64, i64), usize> = grid.keys.iter().enumerate().map(|(i, &k)| (k, i)).collect();
    let mut parent: Vec<usize> = (0..ncell).collect();
    let r2 = r * r;
    let reach = (r / cell).ceil() as i64;
    for (ia, &ka) in grid.keys.iter().enumerate() {
        let sa = grid.slice(ka).expect("cell exists");
        for dx in 0..=reach {
            for dy in -reach..=reach {
                if dx == 0 && dy <= 0 {
                    continue; // each unordered pair once
                }
                let gx = (dx.abs() - 1).max(0) as f64 * cell;
                let gy = (dy.abs() - 1).max(0) as f64 * cell;
                if gx * gx + gy * gy > r2 {
                    continue;
                }
                let kb = (ka.0 + dx, ka.1 + dy);
                let Some(&ib) = cell_id.get(&kb) else { continue };
                let (ra, rb) = (find_root(&mut parent, ia), find_root(&mut parent, ib));
                if ra == rb {
                    continue;
                }
                let sb = grid.slice(kb).expect("cell exists");
                let joined = sa.iter().any(|&i| {
                    let p = xy[i as usize];
                    sb.iter().any(|&j| {
                        let q = xy[j as usize];
                        let (ex, ey) = (q[0] - p[0], q[1] - p[1]);
                        ex * ex + ey * ey <= r2
                    })
                });
                if joined {
                    parent[ra.max(rb)] = ra.min(rb);
                }
            }
        }
    }
    let members = grid
        .keys
        .iter()
        .map(|&k| grid.slice(k).expect("cell exists").iter().map(|&i| i as usize));
    merge_groups(&mut parent, members)
}

/// Connected components with a radius that adapts to the local point density: points with
/// fewer than `k` neighbours within `r_min` (sparse far-range paint) get
/// `r_i = clamp(2 · d_k, r_min, r_max)`, `d_k` being their k-th neighbour distance, and two
/// points join when their distance is ≤ min(r_i, r_j). Dense points keep `r_min`, so dense
/// side-by-side markings stay apart while a sparse far line is not shattered. Symmetric,
/// hence independent of the point order. Output as [`components`].
pub fn components_adaptive(xy: &[[f64; 2]], r_min: f64, r_max: f64, k: usize) -> Vec<Vec<usize>> {
    let base = components(xy, r_min);
    // The adaptive radius only joins components: one (or none) stays as it is.
    if r_max <= r_min || base.len() < 2 {
        return base;
    }
    let mut label = vec![0usize; xy.len()];
    for (g, c) in base.iter().enumerate() {
        for &i in c {
            label[i] = g;
        }
    }
    let cell = r_min / 2.0;
    let grid = GridIndex::new(xy, cell);
    let reach = (r_max / 2.0 / cell).ceil() as i64;
    let radius: Vec<f64> = (0..xy.len())
        .map(|i| {
            let p = xy[i];
            let key = (floor_i64(p[0] / cell), floor_i64(p[1] / cell));
            // A full own cell means k neighbours within r_min: dense, the common case.
            if grid.slice(key).is_some_and(|s| s.len() > k) {
                return r_min;
            }
            let mut d: Vec<f64> = grid
                .around(p, reach)
                .filter(|&j| j != i)
                .map(|j| (xy[j][0] - p[0]).hypot(xy[j][1] - p[1]))
                .collect();
            if d.len() < k {
                return r_max;
            }
            d.select_nth_unstable_by(k - 1, f64::total_cmp);
            (2.0 * d[k - 1]).clamp(r_min, r_max)
        })
        .collect();
    let sparse: Vec<usize> = (0..xy.len()).filter(|&i| radius[i] > r_min).collect();
    if sparse.is_empty() {
        return base;
    }
    let sxy: Vec<[f64; 2]> = sparse.iter().map(|&i| xy[i]).collect();
    let sgrid = GridIndex::new(&sxy, r_max);
    let mut parent: Vec<usize> = (0..base.len()).collect();
    for (a, &i) in sparse.iter().enumerate() {
        let p = xy[i];
        for b in sgrid.around(p, 1).filter(|&b| b > a) {
            let j = sparse[b];
            let q = xy[j];
            if (q[0] - p[0]).hypot(q[1] - p[1]) <= radius[i].min(radius[j]) {
                union(&mut parent, label[i], label[j]);
            }
        }
    }
    merge_groups(&mut parent, base)
}

/// Largest spread (m, standard deviation) across a component that still counts as one scan
/// row: range noise plus a row's curvature over a fragment.
const ROW_MAX_SPREAD_M: f64 = 0.02;
/// ... or, for a fragment of two interleaved rows (two scanner heads), this share of its
/// length.
const ROW_MAX_RELATIVE_SPREAD: f64 = 0.25;
/// Longest row fragment considered (m): longer single rows are lines in their own right.
/// Fragments that are not rows take part when they are this short both ways.
const ROW_MAX_LENGTH_M: f64 = 1.0;
/// Stacked fragments overlap along the row by at least this share of their mean length
/// (projected on the row): rows that cross a bar obliquely (the ±35° planes of a butterfly
/// pair of heads) are shifted by row spacing × sin(angle).
const ROW_MIN_OVERLAP: f64 = 0.25;
/// Largest angle between stacked row fragments (deg): the rows of two scanner heads cross
/// a far bar at angles up to ~30° apart.
const ROW_MAX_ANGLE_DEG: f64 = 35.0;

/// Join stacked scan-row fragments: at far range a scanner samples the road in rows (one
/// pulse index over consecutive scan lines) that are dense along the row and 0.3–0.6 m
/// apart across it, so a painted bar crossed by several rows falls apart into thin
/// parallel fragments; with two scanner heads, rows of the two heads that cross inside
/// the bar also form small fragments that are not one row. A fragment that is one row
/// (spread across its axis ≤ [`ROW_MAX_SPREAD_M`] or [`ROW_MAX_RELATIVE_SPREAD`] of its
/// length, length ≤ [`ROW_MAX_LENGTH_M`]) is joined to a small fragment (at most
/// [`ROW_MAX_LENGTH_M`] both ways) that lies beside it: overlapping it along the row by at
/// least [`ROW_MIN_OVERLAP`] of their mean length and at most `max_across` from the row
/// across it (nearest points). Two rows parallel within [`ROW_MAX_ANGLE_DEG`] must each
/// lie beside the other; a "row" at a steeper angle is a stack of rows seen along the bar
/// and counts as a small fragment. Collinear fragments (the next
/// stripe along the same row, a dash after a gap) never overlap along the row and are never
/// joined by this rule. Returns groups of indices into `comps`, each sorted, ordered by
/// their first; symmetric and independent of the order of `comps`' members.
pub fn join_row_fragments(xy: &[[f64; 2]], comps: &[Vec<usize>], max_across: f64) -> Vec<Vec<usize>> {
    /// A small fragment: its principal frame centred on the middle of its extent.
    struct Frag {
        comp: usize,
        frame: Pca,
        half: f64,
        row: bool,
    }
    let frags: Vec<Frag> = comps
        .iter()
        .enumerate()
        .filter(|(_, c)| c.len() >= 3)
        .filter_map(|(k, c)| {
            let pts: Vec<[f64; 2]> = c.iter().map(|&i| xy[i]).collect();
            let pca = Pca::of(&pts);
            let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
            for &p in &pts {
                let f = pca.to_frame(p);
                for a in 0..2 {
                    lo[a] = lo[a].min(f[a]);
                    hi[a] = hi[a].max(f[a]);
                }
            }
            let (len, wide) = (hi[0] - lo[0], hi[1] - lo[1]);
            let row = pca.var[1].sqrt() <= ROW_MAX_SPREAD_M.max(ROW_MAX_RELATIVE_SPREAD * len);
            (len > 0.0 && len <= ROW_MAX_LENGTH_M && wide <= ROW_MAX_LENGTH_M).then(|| Frag {
                comp: k,
                frame: Pca {
                    center: pca.from_frame([0.5 * (lo[0] + hi[0]), 0.0]),
                    ..pca
                },
                half: 0.5 * len,
                row,
            })
        })
        .collect();
    let mut parent: Vec<usize> = (0..comps.len()).collect();
    let centers: Vec<[f64; 2]> = frags.iter().map(|r| r.frame.center).collect();
    let grid = GridIndex::new(&centers, max_across + ROW_MAX_LENGTH_M);
    // `o` lies beside the row `r`: overlapping it along the row, near it across.
    let beside = |r: &Frag, o: &Frag| {
        let (mut lo, mut hi, mut near) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY);
        for &i in &comps[o.comp] {
            let [along, across] = r.frame.to_frame(xy[i]);
            lo = lo.min(along);
            hi = hi.max(along);
            near = near.min(across.abs());
        }
        let overlap = hi.min(r.half) - lo.max(-r.half);
        overlap >= ROW_MIN_OVERLAP * (r.half + 0.5 * (hi - lo)) && near <= max_across
    };
    for (a, fa) in frags.iter().enumerate() {
        for b in grid.around(fa.frame.center, 1).filter(|&b| b > a) {
            let fb = &frags[b];
            // Two parallel rows must each lie beside the other; a row at a steep angle to
            // the other is a stack of rows read along the bar (its spread is a share of
            // its length) and counts as a small fragment, like one that is not a row.
            let parallel = acute_angle_deg(fa.frame.axis, fb.frame.axis) <= ROW_MAX_ANGLE_DEG;
            let joined = if fa.row && fb.row && parallel {
                beside(fa, fb) && beside(fb, fa)
            } else {
                (fa.row && beside(fa, fb)) || (fb.row && beside(fb, fa))
            };
            if joined {
                union(&mut parent, fa.comp, fb.comp);
            }
        }
    }
    merge_groups(&mut parent, (0..comps.len()).map(|c| [c]))
}

/// Root of `a` in the union-find forest `parent` (with path halving). The union-find here is
/// a few lines over plain index vectors, which no dependency of ours offers.
pub fn find_root(parent: &mut [usize], mut a: usize) -> usize {
    while parent[a] != a {
        parent[a] = parent[parent[a]];
        a = parent[a];
    }
    a
}

/// Join the sets of `a` and `b` (the smaller root index becomes the root, so the result does
/// not depend on the order of the unions); false when they were already one set.
pub fn union(parent: &mut [usize], a: usize, b: usize) -> bool {
    let (ra, rb) = (find_root(parent, a), find_root(parent, b));
    if ra == rb {
        return false;
    }
    parent[ra.max(rb)] = ra.min(rb);
    true
}

/// The members of union-find elements merged per set: `members[e]` belongs to element `e`.
/// Each group sorted; groups ordered by their first member.
pub fn merge_groups<I>(parent: &mut [usize], members: impl IntoIterator<Item = I>) -> Vec<Vec<usize>>
where
    I: IntoIterator<Item = usize>,
{
    let mut groups: HashMap<usize, Vec<usize>> = HashMap::new();
    for (e, m) in members.into_iter().enumerate() {
        groups.entry(find_root(parent, e)).or_default().extend(m);
    }
    let mut out: Vec<Vec<usize>> = groups
        .into_values()
        .map(|mut g| {
            g.sort_unstable();
            g
        })
        .collect();
    out.sort_unstable_by_key(|g| g[0]);
    out
}

/// Linear interpolation of the piecewise-linear function through (`xs[i]`, `ys[i]`) (`xs`
/// ascending, non-empty) at `x`, held constant beyond the ends.
pub fn interp_clamped(xs: &[f64], ys: &[f64], x: f64) -> f64 {
    let j = xs.partition_point(|&v| v < x);
    if j == 0 {
        ys[0]
    } else if j >= xs.len() {
        ys[xs.len() - 1]
    } else {
        let f = (x - xs[j - 1]) / (xs[j] - xs[j - 1]).max(1e-9);
        ys[j - 1] + f * (ys[j] - ys[j - 1])
    }
}

/// Least-squares slope dy/dx of the points; `None` with fewer than 2 points or no spread
/// in x (Σ(x − x̄)² < 1e-9).
pub fn ls_slope(pts: &[[f64; 2]]) -> Option<f64> {
    let n = pts.len() as f64;
    if n < 2.0 {
        return None;
    }
    let mx = pts.iter().map(|q| q[0]).sum::<f64>() / n;
    let my = pts.iter().map(|q| q[1]).sum::<f64>() / n;
    let (mut sxx, mut sxy) = (0.0, 0.0);
    for q in pts {
        sxx += (q[0] - mx) * (q[0] - mx);
        sxy += (q[0] - mx) * (q[1] - my);
    }
    (sxx >= 1e-9).then(|| sxy / sxx)
}

/// Least-squares slope of the polyline y(x) (`xs` ascending) over `[lo, hi]`, sampled
/// every metre (and at both ends) by [`interp_clamped`], so every stretch counts by its
/// length whatever its vertex density. `None` when the span is shorter than 1 m.
pub fn slope_in(xs: &[f64], ys: &[f64], lo: f64, hi: f64) -> Option<f64> {
    if xs.is_empty() || (hi - lo).is_nan() || hi - lo < 1.0 {
        return None;
    }
    let n = (hi - lo).ceil() as usize;
    let pts: Vec<[f64; 2]> = (0..=n)
        .map(|k| {
            let x = lo + (hi - lo) * k as f64 / n as f64;
            [x, interp_clamped(xs, ys, x)]
        })
        .collect();
    ls_slope(&pts)
}

/// Median nearest-neighbour distance of (a deterministic subsample of) the points; a proxy
/// for the point spacing. `None` with fewer than 2 points or no neighbour within `max_r`.
pub fn spacing(xy: &[[f64; 2]], max_r: f64) -> Option<f64> {
    if xy.len() < 2 {
        return None;
    }
    let grid = GridIndex::new(xy, (max_r / 4.0).max(0.01));
    let stride = (xy.len() / 256).max(1);
    let mut d: Vec<f64> = (0..xy.len())
        .step_by(stride)
        .filter_map(|i| grid.nearest_other(xy, i, max_r))
        .collect();
    if d.is_empty() {
        return None;
    }
    d.sort_unstable_by(f64::total_cmp);
    Some(quantile_sorted(&d, 0.5))
}

/// Quantile `q` in 0..=1 of sorted values, linearly interpolated. NaN when empty.
pub fn quantile_sorted(v: &[f64], q: f64) -> f64 {
    match v.len() {
        0 => f64::NAN,
        1 => v[0],
        n => {
            let pos = q.clamp(0.0, 1.0) * (n - 1) as f64;
            let i = pos.floor() as usize;
            let f = pos - i as f64;
            if i + 1 < n {
                v[i] * (1.0 - f) + v[i + 1] * f
            } else {
                v[n - 1]
            }
        }
    }
}

/// Deterministic jitter in [-0.5, 0.5) for hand-made test scenes (a 64-bit LCG; no
/// dependency on the rand API in unit tests).
#[cfg(test)]
pub(crate) fn test_jitter(seed: u64) -> impl FnMut() -> f64 {
    let mut k = seed;
    move || {
        k = k
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((k >> 33) as f64 / (1u64 << 31) as f64) - 0.5
    }
}

/// Median of the values (sorts them in place). NaN when empty.
pub fn median(v: &mut [f64]) -> f64 {
    v.sort_unstable_by(f64::total_cmp);
    quantile_sorted(v, 0.5)
}

/// Weighted median of (value, weight) pairs (sorts them by value): the first value at
/// which the running weight reaches half the total. NaN when empty.
pub fn weighted_median(v: &mut [(f64, f64)]) -> f64 {
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    let total: f64 = v.iter().map(|x| x.1).sum();
    let mut acc = 0.0;
    for x in v.iter() {
        acc += x.1;
        if acc >= total / 2.0 {
            return x.0;
        }
    }
    v.first().map_or(f64::NAN, |x| x.0)
}

/// Estimated extent (lo, hi) of the interval a sample was drawn from, treating the sample as
/// uniform over it: trimmed quantiles rescaled for large samples (robust to a few strays),
/// the range widened by one mean gap for small ones. `v` must be sorted and non-empty.
pub fn robust_extent(v: &[f64]) -> (f64, f64) {
    let n = v.len();
    let Some(p) = trim_fraction(n) else {
        let (lo, hi) = (v[0], v[n - 1]);
        let pad = if n > 1 {
            (hi - lo) / (n - 1) as f64 / 2.0
        } else {
            0.0
        };
        return (lo - pad, hi + pad);
    };
    let (a, b) = (quantile_sorted(v, p), quantile_sorted(v, 1.0 - p));
    let half = (b - a) / (1.0 - 2.0 * p) / 2.0;
    let c = (a + b) / 2.0;
    (c - half, c + half)
}

/// Share of a sample [`robust_extent`] trims at each end (`None`: too small to trim, it
/// takes the range widened by half a mean gap).
fn trim_fraction(n: usize) -> Option<f64> {
    match n {
        0..40 => None,
        40..100 => Some(0.01),
        _ => Some(0.02),
    }
}

/// Most that [`row_extent`] widens an end by (m): half the spacing of the scan rows near a
/// survey vehicle (200 lines/s at up to 70 km/h); wider "row gaps" are holes in the mark.
const ROW_EXTENT_MAX_PAD_M: f64 = 0.05;

/// [`robust_extent`] of a sample that may be taken in rows: scan rows crossing a bar put its
/// points on a few levels along the direction they step in, and the painted extent reaches
/// about half a row spacing beyond the first and last row (the trimmed quantiles, so a stray
/// point does not count), not a quantile's rescaling beyond them. The sample is taken as
/// rows when the gaps over 4 × the median gap make up at least 60 % of the range (a
/// continuous sample's exponential gaps put about 23 % there); the row spacing is then
/// their length-weighted median, and each end is widened by half of it (at most
/// [`ROW_EXTENT_MAX_PAD_M`]) where that is more than [`robust_extent`] does. `v` must be
/// sorted and non-empty.
pub fn row_extent(v: &[f64]) -> (f64, f64) {
    let (lo, hi) = robust_extent(v);
    let n = v.len();
    if n < 8 {
        return (lo, hi);
    }
    // The trimmed sample (as robust_extent trims): a stray point makes no row.
    let p = trim_fraction(n).unwrap_or(0.0);
    let (a, b) = (quantile_sorted(v, p), quantile_sorted(v, 1.0 - p));
    let inner: Vec<f64> = v.iter().copied().filter(|&x| x >= a && x <= b).collect();
    let mut gaps: Vec<f64> = inner.windows(2).map(|w| w[1] - w[0]).collect();
    if gaps.len() < 2 {
        return (lo, hi);
    }
    let mut sorted = gaps.clone();
    let tau = (4.0 * median(&mut sorted)).max(1e-4);
    gaps.retain(|&g| g > tau);
    let big: f64 = gaps.iter().sum();
    if gaps.len() < 2 || big < 0.6 * (b - a) {
        return (lo, hi);
    }
    // The gap size that carries half the range (length-weighted median): the rows'
    // spacing, not the many small gaps within rows that also exceed `tau`.
    let mut weighted: Vec<(f64, f64)> = gaps.iter().map(|&g| (g, g)).collect();
    let half = (weighted_median(&mut weighted) / 2.0).min(ROW_EXTENT_MAX_PAD_M);
    (lo.min(a - half), hi.max(b + half))
}

/// Principal axes of a planar point set.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pca {
    pub center: [f64; 2],
    /// Unit long axis, sign made canonical (x > 0, or y > 0 when x = 0).
    pub axis: [f64; 2],
    /// Variance along the long axis and across it.
    pub var: [f64; 2],
}

impl Pca {
    pub fn of(xy: &[[f64; 2]]) -> Pca {
        let n = xy.len().max(1) as f64;
        let (mut sx, mut sy) = (0.0, 0.0);
        for p in xy {
            sx += p[0];
            sy += p[1];
        }
        let c = [sx / n, sy / n];
        let (mut xx, mut xy_, mut yy) = (0.0, 0.0, 0.0);
        for p in xy {
            let (dx, dy) = (p[0] - c[0], p[1] - c[1]);
            xx += dx * dx;
            xy_ += dx * dy;
            yy += dy * dy;
        }
        let (xx, xy_, yy) = (xx / n, xy_ / n, yy / n);
        let theta = 0.5 * (2.0 * xy_).atan2(xx - yy);
        let axis = canonical([theta.cos(), theta.sin()]);
        let tr = xx + yy;
        let det = xx * yy - xy_ * xy_;
        let disc = (tr * tr / 4.0 - det).max(0.0).sqrt();
        Pca {
            center: c,
            axis,
            var: [tr / 2.0 + disc, (tr / 2.0 - disc).max(0.0)],
        }
    }

    /// (along, across) coordinates of `p` in this frame.
    pub fn to_frame(&self, p: [f64; 2]) -> [f64; 2] {
        let (dx, dy) = (p[0] - self.center[0], p[1] - self.center[1]);
        [
            dx * self.axis[0] + dy * self.axis[1],
            -dx * self.axis[1] + dy * self.axis[0],
        ]
    }

    pub fn from_frame(&self, uv: [f64; 2]) -> [f64; 2] {
        [
            self.center[0] + uv[0] * self.axis[0] - uv[1] * self.axis[1],
            self.center[1] + uv[0] * self.axis[1] + uv[1] * self.axis[0],
        ]
    }
}

/// A unit vector with a canonical sign (x > 0, or y > 0 when x = 0).
pub fn canonical(a: [f64; 2]) -> [f64; 2] {
    if a[0] < 0.0 || (a[0] == 0.0 && a[1] < 0.0) {
        [-a[0], -a[1]]
    } else {
        a
    }
}

/// Acute angle in degrees (0..=90) between two undirected unit directions.
pub fn acute_angle_deg(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] * b[0] + a[1] * b[1]).abs().min(1.0).acos().to_degrees()
}

/// Gaussian-weighted local linear regression of `y` on `x` at `x0` with bandwidth `h`,
/// widened until at least `min_w` total weight (about that many samples) is in reach.
/// `xs` must be sorted. Returns (value, slope); None when `xs` is empty.
pub fn local_linear(xs: &[f64], ys: &[f64], ws: &[f64], x0: f64, h: f64, min_w: f64) -> Option<(f64, f64)> {
    if xs.is_empty() {
        return None;
    }
    let mut h = h;
    for _ in 0..12 {
        let lo = xs.partition_point(|&x| x < x0 - 3.0 * h);
        let hi = xs.partition_point(|&x| x <= x0 + 3.0 * h);
        let (mut s0, mut s1, mut s2, mut t0, mut t1) = (0.0, 0.0, 0.0, 0.0, 0.0);
        let mut count = 0.0;
        for i in lo..hi {
            let d = xs[i] - x0;
            let w = ws[i] * (-0.5 * (d / h) * (d / h)).exp();
            s0 += w;
            s1 += w * d;
            s2 += w * d * d;
            t0 += w * ys[i];
            t1 += w * d * ys[i];
            count += ws[i];
        }
        if count >= min_w && s0 > 0.0 {
            let det = s0 * s2 - s1 * s1;
            // Degenerate spread (all samples at one x): fall back to the weighted mean.
            if det.abs() <= 1e-12 * s0 * s0 * h * h {
                return Some((t0 / s0, 0.0));
            }
            let b = (s0 * t1 - s1 * t0) / det;
            let a = (t0 - b * s1) / s0;
            return Some((a, b));
        }
        h *= 1.6;
    }
    // Still too few samples in reach: weighted mean of everything.
    let sw: f64 = ws.iter().sum();
    let sy: f64 = ws.iter().zip(ys).map(|(w, y)| w * y).sum();
    (sw > 0.0).then_some((sy / sw, 0.0))
}

/// Gaussian-weighted local quadratic regression of `y` on `x` at `x0` (bandwidth widened
/// like [`local_linear`] until `min_w` weight is in reach); falls back to the local linear
/// fit when the quadratic system is singular. `xs` must be sorted.
pub fn local_quadratic(xs: &[f64], ys: &[f64], ws: &[f64], x0: f64, h: f64, min_w: f64) -> Option<f64> {
    if xs.is_empty() {
        return None;
    }
    let mut h = h;
    for _ in 0..12 {
        let lo = xs.partition_point(|&x| x < x0 - 3.0 * h);
        let hi = xs.partition_point(|&x| x <= x0 + 3.0 * h);
        let count: f64 = ws[lo..hi].iter().sum();
        if count >= min_w {
            let mut m = [[0.0f64; 3]; 3];
            let mut r = [0.0f64; 3];
            for i in lo..hi {
                let d = (xs[i] - x0) / h;
                let w = ws[i] * (-0.5 * d * d).exp();
                let b = [1.0, d, d * d];
                for a in 0..3 {
                    r[a] += w * b[a] * ys[i];
                    for c in 0..3 {
                        m[a][c] += w * b[a] * b[c];
                    }
                }
            }
            let mat = nalgebra::Matrix3::from_fn(|a, c| m[a][c]);
            if let Some(inv) = mat.try_inverse() {
                let sol = inv * nalgebra::Vector3::new(r[0], r[1], r[2]);
                if sol[0].is_finite() && mat.determinant().abs() > 1e-9 * m[0][0].powi(3) {
                    return Some(sol[0]);
                }
            }
            return local_linear(xs, ys, ws, x0, h, min_w).map(|v| v.0);
        }
        h *= 1.6;
    }
    local_linear(xs, ys, ws, x0, h, min_w).map(|v| v.0)
}

/// Douglas–Peucker simplification of an open polyline (keeps both ends).
pub fn simplify(line: &[[f64; 2]], tol: f64) -> Vec<[f64; 2]> {
    if line.len() <= 2 {
        return line.to_vec();
    }
    let mut keep = vec![false; line.len()];
    keep[0] = true;
    keep[line.len() - 1] = true;
    let mut stack = vec![(0usize, line.len() - 1)];
    while let Some((a, b)) = stack.pop() {
        let (p, q) = (line[a], line[b]);
        let (dx, dy) = (q[0] - p[0], q[1] - p[1]);
        let len = dx.hypot(dy);
        let mut best = (0.0, 0usize);
        for (i, r) in line.iter().enumerate().take(b).skip(a + 1) {
            let d = if len > 0.0 {
                ((r[0] - p[0]) * dy - (r[1] - p[1]) * dx).abs() / len
            } else {
                (r[0] - p[0]).hypot(r[1] - p[1])
            };
            if d > best.0 {
                best = (d, i);
            }
        }
        if best.0 > tol {
            keep[best.1] = true;
            stack.push((a, best.1));
            stack.push((best.1, b));
        }
    }
    line.iter()
        .zip(keep)
        .filter_map(|(p, k)| k.then_some(*p))
        .collect()
}

/// Length of an open polyline.
pub fn polyline_length(line: &[[f64; 2]]) -> f64 {
    line.windows(2)
        .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
        .sum()
}

/// Widest spacing of far-range scan rows taken for a bar's slices (m; the clustering's
/// largest radius joins nothing further apart).
const MAX_ROW_SPACING_M: f64 = 0.6;

/// Robust rectangle of a point set in its principal frame, with a fill ratio.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BarShape {
    pub pca: Pca,
    /// Estimated extent along the long axis and across it, in frame coordinates.
    pub u: (f64, f64),
    pub v: (f64, f64),
    /// Mean slice width over the full width (1 for a filled bar, ~0.5 for a triangle).
    pub fill: f64,
}

impl BarShape {
    pub fn of(xy: &[[f64; 2]]) -> BarShape {
        Self::sliced(xy, false)
    }

    /// [`BarShape::of`] with the fill measured in slices no shorter than the spacing of
    /// the scan rows crossing the bar (see the body).
    pub fn of_rows(xy: &[[f64; 2]]) -> BarShape {
        Self::sliced(xy, true)
    }

    fn sliced(xy: &[[f64; 2]], rows: bool) -> BarShape {
        let pca = Pca::of(xy);
        let mut uv: Vec<[f64; 2]> = xy.iter().map(|&p| pca.to_frame(p)).collect();
        let mut us: Vec<f64> = uv.iter().map(|p| p[0]).collect();
        let mut vs: Vec<f64> = uv.iter().map(|p| p[1]).collect();
        us.sort_unstable_by(f64::total_cmp);
        vs.sort_unstable_by(f64::total_cmp);
        if xy.is_empty() {
            return BarShape {
                pca,
                u: (0.0, 0.0),
                v: (0.0, 0.0),
                fill: 0.0,
            };
        }
        let u = robust_extent(&us);
        let v = robust_extent(&vs);
        let (len, wid) = (u.1 - u.0, v.1 - v.0);
        let fill = if wid > 0.0 && len > 0.0 && xy.len() >= 8 {
            uv.sort_unstable_by(|a, b| a[0].total_cmp(&b[0]));
            // Slices no shorter than the spacing of the scan rows crossing the bar: at far
            // range the rows are 0.3-0.6 m apart, and a slice between two rows is empty
            // because nothing was sampled there, not because the bar is not filled. The
            // second-largest gap along the axis stands for that spacing (a bar crossed by
            // rows has a gap at every row; one hole in a shape is ignored).
            let mut nsl = ((xy.len() / 6).clamp(2, 20)).min(((len / 0.05) as usize).max(2));
            if rows {
                let (mut g1, mut g2) = (0.0f64, 0.0f64);
                for w in uv.windows(2) {
                    let g = (w[1][0] - w[0][0]).min(MAX_ROW_SPACING_M);
                    if g > g1 {
                        (g1, g2) = (g, g1);
                    } else if g > g2 {
                        g2 = g;
                    }
                }
                nsl = nsl.min(((len / (1.01 * g2)) as usize).max(2));
            }
            let dl = len / nsl as f64;
            let mut total = 0.0;
            let mut cur: Vec<f64> = Vec::new();
            let mut k = 0usize;
            let flush = |cur: &mut Vec<f64>, total: &mut f64| {
                if cur.len() >= 2 {
                    cur.sort_unstable_by(f64::total_cmp);
                    let (a, b) = robust_extent(cur);
                    *total += (b - a).min(wid);
                }
                cur.clear();
            };
            for p in &uv {
                let kk = (((p[0] - u.0) / dl).floor().max(0.0) as usize).min(nsl - 1);
                if kk != k {
                    flush(&mut cur, &mut total);
                    k = kk;
                }
                cur.push(p[1]);
            }
            flush(&mut cur, &mut total);
            (total / nsl as f64 / wid).clamp(0.0, 1.0)
        } else {
            1.0
        };
        BarShape { pca, u, v, fill }
    }

    pub fn length(&self) -> f64 {
        self.u.1 - self.u.0
    }

    pub fn width(&self) -> f64 {
        self.v.1 - self.v.0
    }

    /// Centre of the robust rectangle (not the centroid).
    pub fn center(&self) -> [f64; 2] {
        self.pca
            .from_frame([(self.u.0 + self.u.1) / 2.0, (self.v.0 + self.v.1) / 2.0])
    }

    /// The four corners of the robust rectangle.
    pub fn corners(&self) -> [[f64; 2]; 4] {
        let f = |u, v| self.pca.from_frame([u, v]);
        [
            f(self.u.0, self.v.0),
            f(self.u.1, self.v.0),
            f(self.u.1, self.v.1),
            f(self.u.0, self.v.1),
        ]
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn floor_matches_the_library() {
        for v in [
            -2.5,
            -2.0,
            -1e-300,
            -0.0,
            0.0,
            0.3,
            1.0,
            7.999999,
            -7.000001,
            1e15,
            -1e15,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            1e300,
            -1e300,
        ] {
            assert_eq!(floor_i64(v), v.floor() as i64, "{v}");
        }
    }

    use super::*;

    #[test]
    fn slope_in_sees_through_a_wiggle() {
        // y = 0.01 x with a 0.2 m bump between x = 40 and 45, sampled unevenly.
        let xs = [0.0, 40.0, 42.5, 45.0, 100.0];
        let ys = [0.0, 0.4, 0.625, 0.45, 1.0];
        let k = slope_in(&xs, &ys, 0.0, 100.0).expect("span");
        assert!((k - 0.01).abs() < 0.001, "{k}");
        // Over [20, 42.5] the end values read 0.019 / m; the fit stays nearer the trend.
        let k = slope_in(&xs, &ys, 20.0, 42.5).expect("span");
        assert!(k < 0.015, "{k}");
        assert!(slope_in(&xs, &ys, 3.0, 3.5).is_none());
        assert!(slope_in(&[], &[], 0.0, 10.0).is_none());
    }

    /// A zebra stripe across a side street, 3.4 m x 0.45 m, seen at far range: scan rows
    /// 0.4 m apart cross it, each sampling its whole width every 0.03 m. Sliced finer than
    /// the rows, half the slices are empty and the stripe reads half filled; sliced by the
    /// rows it is a filled bar. A dense triangle stays a triangle either way.
    #[test]
    fn a_bar_crossed_by_sparse_rows_is_filled_when_sliced_by_the_rows() {
        let mut stripe = Vec::new();
        for r in 0..9 {
            for k in 0..16 {
                stripe.push([0.1 + 0.4 * r as f64 + 0.002 * k as f64, -0.225 + 0.03 * k as f64]);
            }
        }
        let fine = BarShape::of(&stripe);
        let rows = BarShape::of_rows(&stripe);
        assert!(fine.fill < 0.65, "fine slices: {}", fine.fill);
        assert!(rows.fill > 0.85, "row slices: {}", rows.fill);
        assert!((rows.length() - fine.length()).abs() < 1e-12 && (rows.width() - fine.width()).abs() < 1e-12);
        let mut tri = Vec::new();
        for i in 0..60 {
            for j in 0..=i {
                tri.push([0.05 * i as f64, 0.05 * j as f64 - 0.025 * i as f64]);
            }
        }
        let (a, b) = (BarShape::of(&tri).fill, BarShape::of_rows(&tri).fill);
        assert!((a - b).abs() < 1e-12 && a < 0.7, "{a} {b}");
    }

    /// One scan row crossing a bar: `n` points 0.05 m apart from `start` along `dir`.
    /// The fragments' points in one list, and each fragment's indices into it.
    fn pooled(frags: Vec<Vec<[f64; 2]>>) -> (Vec<[f64; 2]>, Vec<Vec<usize>>) {
        let mut xy = Vec::new();
        let mut comps = Vec::new();
        for pts in frags {
            comps.push((xy.len()..xy.len() + pts.len()).collect::<Vec<usize>>());
            xy.extend(pts);
        }
        (xy, comps)
    }

    fn row(start: [f64; 2], dir: [f64; 2], n: usize) -> Vec<[f64; 2]> {
        (0..n)
            .map(|k| {
                [
                    start[0] + 0.05 * k as f64 * dir[0],
                    start[1] + 0.05 * k as f64 * dir[1],
                ]
            })
            .collect()
    }

    /// Rows 0.45 m apart crossing two stripes (0.45 m wide, 1.05 m apart along the rows):
    /// each stripe's fragments join, the two stripes do not; a lone fragment at an angle
    /// and a long row (a line, not a fragment) join nothing.
    #[test]
    fn stacked_row_fragments_join_and_collinear_ones_do_not() {
        let mut frags = Vec::new();
        for r in 0..5 {
            let y = 0.45 * r as f64;
            frags.push(row([0.0, y], [1.0, 0.0], 9));
            frags.push(row([1.05, y], [1.0, 0.0], 9));
        }
        let d = [30f64.to_radians().cos(), 30f64.to_radians().sin()];
        frags.push(row([0.0, 2.7], d, 9));
        frags.push(row([-3.0, 1.0], [1.0, 0.0], 60));
        let (xy, comps) = pooled(frags);
        let n = comps.len();
        let joined: Vec<Vec<usize>> = join_row_fragments(&xy, &comps, 0.6)
            .into_iter()
            .map(|g| g.iter().flat_map(|&c| comps[c].iter().copied()).collect())
            .collect();
        assert_eq!(joined.len(), n - 8);
        let first = joined.iter().find(|g| g.contains(&0)).unwrap();
        assert_eq!(first.len(), 45, "five rows of the first stripe");
        let second = joined.iter().find(|g| g.contains(&9)).unwrap();
        assert_eq!(second.len(), 45);
        assert!(joined.iter().any(|g| g.len() == 60));
    }

    /// Two scanner heads: a far stripe (0.45 m along the rows, 3 m across) is crossed by rows
    /// tilted +15° and −12°, and where two rows cross they form one fragment that is not a
    /// row (or reads as a "row" along the stripe). All of them join into the stripe; the
    /// next stripe 1 m further along the rows stays apart.
    #[test]
    fn two_head_row_stacks_join_into_their_stripe() {
        let dir = |deg: f64| [deg.to_radians().cos(), deg.to_radians().sin()];
        let mut frags = Vec::new();
        for stripe in 0..2 {
            let x0 = stripe as f64 * 1.0;
            for (r, y) in [0.0, 0.45, 0.9, 1.8, 2.25, 2.7].into_iter().enumerate() {
                let deg = if r % 2 == 0 { 15.0 } else { -12.0 };
                frags.push(row([x0, y], dir(deg), 9));
            }
            // Two crossing rows at 1.3-1.45 m make one X-shaped fragment.
            let mut cross = row([x0, 1.3], dir(15.0), 9);
            cross.extend(row([x0, 1.45], dir(-15.0), 9));
            frags.push(cross);
        }
        let (xy, comps) = pooled(frags);
        let joined = join_row_fragments(&xy, &comps, 0.6);
        assert_eq!(joined.len(), 2, "{joined:?}");
        assert_eq!(joined[0], (0..7).collect::<Vec<_>>());
    }

    #[test]
    fn components_of_degenerate_inputs() {
        assert!(components(&[], 0.3).is_empty());
        assert_eq!(components(&[[1.0, 2.0]], 0.3), vec![vec![0]]);
        // Exactly at the radius is connected; just beyond is not.
        let c = components(&[[0.0, 0.0], [0.3, 0.0], [0.6000001, 0.0]], 0.3);
        assert_eq!(c, vec![vec![0, 1], vec![2]]);
        // Duplicates and collinear points.
        let pts: Vec<[f64; 2]> = (0..50)
            .map(|i| [i as f64 * 0.1, 0.0])
            .chain([[0.0, 0.0]])
            .collect();
        assert_eq!(components(&pts, 0.15).len(), 1);
    }

    #[test]
    fn components_match_brute_force() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let pts: Vec<[f64; 2]> = (0..400)
            .map(|_| [rng.random_range(0.0..10.0), rng.random_range(0.0..10.0)])
            .collect();
        let r = 0.4;
        // Brute force union-find.
        let mut lab: Vec<usize> = (0..pts.len()).collect();
        fn f(l: &mut [usize], mut a: usize) -> usize {
            while l[a] != a {
                a = l[a];
            }
            a
        }
        for i in 0..pts.len() {
            for j in 0..i {
                if (pts[i][0] - pts[j][0]).hypot(pts[i][1] - pts[j][1]) <= r {
                    let (a, b) = (f(&mut lab, i), f(&mut lab, j));
                    lab[a.max(b)] = a.min(b);
                }
            }
        }
        let mut groups: HashMap<usize, Vec<usize>> = HashMap::new();
        for i in 0..pts.len() {
            let root = f(&mut lab, i);
            groups.entry(root).or_default().push(i);
        }
        let mut want: Vec<Vec<usize>> = groups.into_values().collect();
        want.sort_unstable_by_key(|g| g[0]);
        assert_eq!(components(&pts, r), want);
    }

    #[test]
    fn adaptive_components_join_sparse_lines_only() {
        // A sparse line (0.4 m spacing) and, beside it, two dense bars 0.3 m apart.
        let mut pts: Vec<[f64; 2]> = (0..20).map(|i| [i as f64 * 0.4, 5.0]).collect();
        for i in 0..200 {
            for j in 0..5 {
                pts.push([i as f64 * 0.02, j as f64 * 0.03]);
                pts.push([i as f64 * 0.02, 0.42 + j as f64 * 0.03]);
            }
        }
        assert_eq!(components(&pts, 0.25).len(), 22);
        let c = components_adaptive(&pts, 0.25, 0.9, 2);
        assert_eq!(c.len(), 3, "sparse line joined, dense bars kept apart");
        assert_eq!(components_adaptive(&pts, 0.25, 0.25, 2), components(&pts, 0.25));
    }

    #[test]
    fn weighted_median_follows_the_weights() {
        assert_eq!(weighted_median(&mut [(0.3, 1.5), (0.5, 6.0), (0.2, 1.5)]), 0.5);
        assert_eq!(weighted_median(&mut [(0.3, 1.0), (0.1, 1.0), (0.2, 1.0)]), 0.2);
        assert_eq!(weighted_median(&mut [(0.4, 0.0)]), 0.4);
        assert!(weighted_median(&mut []).is_nan());
    }

    #[test]
    fn row_extent_reaches_half_a_row_beyond_the_outer_rows() {
        // A 0.45 m bar sampled by rows 0.075 m apart (first row 0.03 m in): 6 rows of 30
        // points each, jittered 2 mm, plus one stray far out.
        let mut jit = test_jitter(7);
        let mut v: Vec<f64> = (0..6)
            .flat_map(|r| (0..30).map(move |_| 0.03 + 0.075 * r as f64))
            .map(|x| x + 0.002 * jit())
            .collect();
        v.push(1.5);
        v.sort_unstable_by(f64::total_cmp);
        let (lo, hi) = row_extent(&v);
        let (rlo, rhi) = robust_extent(&v);
        assert!((hi - lo - 0.45).abs() < 0.012, "row extent {lo:.3}..{hi:.3}");
        assert!(
            hi - lo > rhi - rlo + 0.03,
            "no wider than the trimmed extent {rlo:.3}..{rhi:.3}"
        );
        // A continuous sample is left as robust_extent reads it.
        let mut jit = test_jitter(3);
        let mut c: Vec<f64> = (0..200).map(|_| 0.225 + 0.225 * jit()).collect();
        c.sort_unstable_by(f64::total_cmp);
        assert_eq!(row_extent(&c), robust_extent(&c));
    }

    #[test]
    fn robust_extent_ignores_a_stray_point() {
        let mut v: Vec<f64> = (0..=1000).map(|i| i as f64 * 0.006).collect(); // 0..6 m
        v.push(9.0);
        v.sort_unstable_by(f64::total_cmp);
        let (lo, hi) = robust_extent(&v);
        assert!((hi - lo - 6.0).abs() < 0.15, "{lo} {hi}");
        let (lo, hi) = robust_extent(&[1.0, 2.0, 3.0]);
        assert!((lo - 0.5).abs() < 1e-12 && (hi - 3.5).abs() < 1e-12);
    }

    #[test]
    fn pca_and_local_linear() {
        let pts: Vec<[f64; 2]> = (0..100)
            .map(|i| [i as f64 * 0.1 * 0.6, -(i as f64) * 0.1 * 0.8])
            .collect();
        let p = Pca::of(&pts);
        assert!((p.axis[0] - 0.6).abs() < 1e-9 && (p.axis[1] + 0.8).abs() < 1e-9);
        let uv = p.to_frame(pts[10]);
        let back = p.from_frame(uv);
        assert!((back[0] - pts[10][0]).abs() < 1e-12);
        let xs: Vec<f64> = (0..20).map(|i| i as f64).collect();
        let ys: Vec<f64> = xs.iter().map(|x| 2.0 + 0.5 * x).collect();
        let ws = vec![1.0; 20];
        let (a, b) = local_linear(&xs, &ys, &ws, 7.3, 1.0, 3.0).unwrap();
        assert!((a - (2.0 + 0.5 * 7.3)).abs() < 1e-9 && (b - 0.5).abs() < 1e-9);
        // Far outside the samples the bandwidth widens instead of failing.
        assert!(local_linear(&xs, &ys, &ws, 100.0, 1.0, 3.0).is_some());
    }

    #[test]
    fn simplify_keeps_corners() {
        let l = vec![[0.0, 0.0], [1.0, 0.001], [2.0, 0.0], [2.0, 1.0]];
        assert_eq!(simplify(&l, 0.01), vec![[0.0, 0.0], [2.0, 0.0], [2.0, 1.0]]);
        assert!((polyline_length(&l) - 3.0).abs() < 1e-3);
    }
}
