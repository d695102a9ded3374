//! Stage 4: group the marking points into clusters, one per painted object.
//!
//! # Interface
//! `run(&PointCloud, &Params) -> Vec<Cluster>`: the cloud holds the marking points left by
//! thresholding (local coordinates); each [`Cluster`] lists point indices into that cloud
//! plus cheap statistics. Clusters come out in a canonical order (by their lowest-x point)
//! and each cluster's indices are sorted by (x, y), so the result does not depend on the
//! order of the input points. Deterministic; parallel over components with rayon.
//!
//! # Algorithm
//! 1. **Euclidean clustering** (Yao 2019/2021 step 6) as exact connected components of the
//!    graph "distance ≤ `radius_m`", on a grid of r/√2 cells (see `geom::components`).
//!    The papers use r = 0.5 m; that joins a dash to a solid line 0.15–0.3 m beside it, and
//!    crosswalk stripes 0.6 m apart as soon as a little noise lies between them. The default
//!    0.25 m is ~8× the typical point spacing near the vehicle (0.03 m) and keeps gaps ≥ 0.25 m
//!    apart; sparse far lines that fragment at this radius are re-joined along their
//!    direction by `classify` (Pan 2019: broken lines re-joined by endpoint distance and
//!    direction), which a radius cannot do without also joining side-by-side lines.
//! 2. **Splitting merged objects** (improving on the papers, where dashes touching a solid
//!    line stayed merged into it). Each component is tested, recursively, by three rules:
//!    - *width profile*: in the principal frame, the cluster is cut in 0.25 m slices along its
//!      axis; when most slices have the width w₀ of one painted line and a run of slices is
//!      much wider, with line-width slices on both sides, the line's centre is interpolated
//!      through the wide run and the points off that line are split off — but only parts
//!      that are themselves filled bars parallel to the line (a dash), or, on a line at
//!      least 12 m long, filled bars at 20–70° to it (a gore area's chevrons, a hatched
//!      island's stripes), so an arrow head or a combined arrow's branch is never cut from
//!      its shaft; on a line at least 12 m long (longer than any arrow's shaft) also a part
//!      of any shape at least 0.5 m wide, 0.15 m² and at most 10 m long (an arrow whose head
//!      or branch reaches an edge line);
//!    - *lateral valley*: the offsets from a smoothed centre (so curved pairs work) form two
//!      modes separated by an almost empty valley (double lines, side-by-side dashes,
//!      crosswalk stripes bridged by noise) → split at the valley, unless the offsets are
//!      a comb of evenly spaced thin rows (one mark sampled by scan rows running along
//!      it); on short clusters the same test runs along the axis (two collinear dashes
//!      bridged by noise);
//!    - *crossing bar*: on short clusters, a Hough search over directions finds the densest
//!      straight bar (≤ `max_bar_width_m`); parts attached to it are split off when they are
//!      parallel filled bars, or perpendicular objects lying on one side of the bar with the
//!      bar overhanging both their ends (an arrow tip touching a stop line), or filled bars
//!      ≥ 2 m long meeting it square (≥ 75°) on one side (a lane line ending on a stop line:
//!      an L of two bars is no one painted object; a turning branch leaves at 45–65°).
//!
//!    Every part a rule returns is taken apart into its connected components (same radii
//!    as step 1) before it is tested again: a valley or a line taken out of a component can
//!    leave one part holding objects that only the line joined (two arrows 100 m apart whose
//!    branches touch one edge line). Without this, which objects shared a cluster depended
//!    on how far the streaming of the drive (`driver`) had grown the line.
//! 3. **Stacked scan rows** (`join_rows`): at far range the scanner samples the road in
//!    rows dense along them and 0.3–0.6 m apart across, so a crosswalk stripe becomes a
//!    stack of short parallel one-row fragments (one per row crossing it). Fragments that
//!    are single rows, at most 1 m long, parallel, side by side and at most `max_radius_m`
//!    apart across are joined (`geom::join_row_fragments`) — after step 2, whose valley rule
//!    would cut the stack apart again at the empty gaps between the rows. Collinear
//!    fragments (the next stripe along the same row) are never joined by this rule.
//!
//! # Parameters
//! See [`Params`]; all lengths in metres.
//!
//! # Reference
//! Yao et al. 2019 (ISPRS) §2.7 and Yao et al. 2021 (Remote Sens. 13:2612) §2.2.3 for the
//! Euclidean clustering; Pan et al. 2019 for connected components and re-joining.
//!
//! # Complexity
//! O(n) expected for the components (n points), O(m) per component for the profile and
//! valley tests and O(m · 100) for the bar search on short components (≤ 20 m).

use super::geom::{self, BarShape, Pca};
use super::types::PointCloud;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Parameters of this stage (JSON object `cluster` in the job parameters).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Params {
    /// Connectivity radius of the Euclidean clustering (m). Default 0.25 (papers: 0.5, which
    /// merges side-by-side markings). Must be in (0, 2].
    pub radius_m: f64,
    /// Largest radius for sparse points (m): a point with fewer than 2 neighbours within
    /// `radius_m` (far-range paint, 0.1–0.3 m apart) connects up to
    /// `min(max_radius_m, 2 × its 2nd-neighbour distance)` to other sparse points. Dense
    /// points keep `radius_m`. Default 0.6; set equal to `radius_m` to disable.
    pub max_radius_m: f64,
    /// Components with fewer points are dropped as noise. Default 5.
    pub min_points: usize,
    /// Join stacked far-range scan-row fragments of one painted bar (parallel one-row
    /// pieces side by side, at most `max_radius_m` apart across them; see
    /// `geom::join_row_fragments`). Default true.
    pub join_rows: bool,
    /// Split merged objects (dash touching a solid line, parallel lines, arrow touching a
    /// stop line). Default true.
    pub split: bool,
    /// Widest single painted line (m): the width profile test only runs when the cluster's
    /// typical width is at most this. Default 0.35 (lines are 0.10–0.25 m).
    pub max_line_width_m: f64,
    /// Widest bar the crossing-bar test looks for (m). Default 0.6 (stop lines ≤ 0.6 m).
    pub max_bar_width_m: f64,
    /// Smallest part (points) split off a merged cluster; smaller bumps stay attached.
    /// Default 8.
    pub min_split_points: usize,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            radius_m: 0.25,
            max_radius_m: 0.6,
            min_points: 5,
            join_rows: true,
            split: true,
            max_line_width_m: 0.35,
            max_bar_width_m: 0.6,
            min_split_points: 8,
        }
    }
}

impl Params {
    /// Check every field; the message names the offending parameter.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.radius_m > 0.0 && self.radius_m <= 2.0) {
            return Err(format!("radius_m must be in (0, 2], got {}", self.radius_m));
        }
        if !(self.max_radius_m >= self.radius_m && self.max_radius_m <= 3.0) {
            return Err(format!(
                "max_radius_m must be in [radius_m, 3], got {}",
                self.max_radius_m
            ));
        }
        if self.min_points == 0 {
            return Err("min_points must be at least 1".into());
        }
        if !(self.max_line_width_m > 0.0 && self.max_line_width_m <= 1.0) {
            return Err(format!(
                "max_line_width_m must be in (0, 1], got {}",
                self.max_line_width_m
            ));
        }
        if !(self.max_bar_width_m > 0.0 && self.max_bar_width_m <= 2.0) {
            return Err(format!(
                "max_bar_width_m must be in (0, 2], got {}",
                self.max_bar_width_m
            ));
        }
        if self.min_split_points < 2 {
            return Err("min_split_points must be at least 2".into());
        }
        Ok(())
    }
}

/// One group of marking points.
#[derive(Clone, Debug, PartialEq)]
pub struct Cluster {
    /// Indices into the input cloud, sorted by (x, y).
    pub indices: Vec<usize>,
    /// Mean position (local coordinates).
    pub centroid: [f64; 2],
    /// Axis-aligned bounds [[min x, min y], [max x, max y]] (local coordinates).
    pub bounds: [[f64; 2]; 2],
    /// Mean raw intensity.
    pub mean_intensity: f32,
    /// True when this cluster was split off (or left over) from a merged component.
    pub split: bool,
}

/// Cluster the marking points. See the module docs.
pub fn run(cloud: &PointCloud, params: &Params) -> Vec<Cluster> {
    let xy: Vec<[f64; 2]> = cloud.x.iter().zip(&cloud.y).map(|(&x, &y)| [x, y]).collect();
    let finite: Vec<usize> = (0..xy.len())
        .filter(|&i| xy[i][0].is_finite() && xy[i][1].is_finite())
        .collect();
    let fxy: Vec<[f64; 2]> = finite.iter().map(|&i| xy[i]).collect();
    let comps = geom::components_adaptive(&fxy, params.radius_m, params.max_radius_m, 2);
    let parts: Vec<(Vec<usize>, bool)> = comps
        .into_par_iter()
        .filter(|c| c.len() >= params.min_points || params.join_rows)
        .flat_map_iter(|c| {
            let mut idx: Vec<usize> = c.into_iter().map(|i| finite[i]).collect();
            canonical_sort(&xy, &mut idx);
            let parts = if params.split && idx.len() >= params.min_points {
                split(&xy, idx, params, 0)
            } else {
                vec![idx]
            };
            let was_split = parts.len() > 1;
            parts.into_iter().map(move |p| (p, was_split))
        })
        .collect();
    // Stacked scan-row fragments of one far bar are joined after the splitting, whose
    // lateral-valley rule would cut them apart again at the empty gaps between the rows.
    let mut groups: Vec<(Vec<usize>, bool)> = if params.join_rows {
        let (idx, was_split): (Vec<Vec<usize>>, Vec<bool>) = parts.into_iter().unzip();
        geom::join_row_fragments(&xy, &idx, params.max_radius_m)
            .into_iter()
            .map(|members| {
                let split = members.iter().any(|&c| was_split[c]);
                (
                    members.into_iter().flat_map(|c| idx[c].iter().copied()).collect(),
                    split,
                )
            })
            .collect()
    } else {
        parts
    };
    groups.retain(|(c, _)| c.len() >= params.min_points);
    for (g, _) in groups.iter_mut() {
        canonical_sort(&xy, g);
    }
    groups.sort_by(|a, b| {
        let (p, q) = (xy[a.0[0]], xy[b.0[0]]);
        p[0].total_cmp(&q[0])
            .then(p[1].total_cmp(&q[1]))
            .then(a.0.len().cmp(&b.0.len()))
    });
    groups
        .into_iter()
        .map(|(indices, split)| {
            let n = indices.len() as f64;
            let (mut sx, mut sy, mut si) = (0.0, 0.0, 0.0f64);
            let mut bounds = [[f64::INFINITY; 2], [f64::NEG_INFINITY; 2]];
            for &i in &indices {
                let p = xy[i];
                sx += p[0];
                sy += p[1];
                si += cloud.intensity.get(i).copied().unwrap_or(0.0) as f64;
                for k in 0..2 {
                    bounds[0][k] = bounds[0][k].min(p[k]);
                    bounds[1][k] = bounds[1][k].max(p[k]);
                }
            }
            Cluster {
                centroid: [sx / n, sy / n],
                bounds,
                mean_intensity: (si / n) as f32,
                split,
                indices,
            }
        })
        .collect()
}

/// Sort indices by (x, y, index): computations over a cluster then see the same sequence
/// whatever the input order (points with equal coordinates are interchangeable).
fn canonical_sort(xy: &[[f64; 2]], idx: &mut [usize]) {
    idx.sort_unstable_by(|&a, &b| {
        xy[a][0]
            .total_cmp(&xy[b][0])
            .then(xy[a][1].total_cmp(&xy[b][1]))
            .then(a.cmp(&b))
    });
}

/// Recursively split one component; returns groups of cloud indices.
fn split(xy: &[[f64; 2]], idx: Vec<usize>, p: &Params, depth: u32) -> Vec<Vec<usize>> {
    if idx.len() < 2 * p.min_split_points || depth >= 4 {
        return vec![idx];
    }
    let pts: Vec<[f64; 2]> = idx.iter().map(|&i| xy[i]).collect();
    let parts = profile_split(&pts, p)
        .or_else(|| valley_split(&pts, p))
        .or_else(|| bar_split(&pts, p));
    match parts {
        None => vec![idx],
        Some(parts) => parts
            .into_iter()
            .flat_map(|part| connected_parts(xy, part.into_iter().map(|k| idx[k]).collect(), p))
            .flat_map(|mut sub| {
                canonical_sort(xy, &mut sub);
                split(xy, sub, p, depth + 1)
            })
            .collect(),
    }
}

/// A part a rule split off, as the connected components it holds (with the radius of the
/// clustering): a lateral valley or a line taken out of a component can leave two objects
/// that only the line joined in one part (two arrows 100 m apart whose branches touch one
/// edge line), and a cluster is one painted object. Components of fewer than
/// `min_split_points` points stay with the largest (stray points of the part).
fn connected_parts(xy: &[[f64; 2]], part: Vec<usize>, p: &Params) -> Vec<Vec<usize>> {
    let pts: Vec<[f64; 2]> = part.iter().map(|&i| xy[i]).collect();
    let mut comps = geom::components_adaptive(&pts, p.radius_m, p.max_radius_m, 2);
    if comps.len() < 2 {
        return vec![part];
    }
    comps.sort_by_key(|c| std::cmp::Reverse(c.len()));
    let mut out: Vec<Vec<usize>> = Vec::new();
    let mut stray: Vec<usize> = Vec::new();
    for c in comps {
        let g: Vec<usize> = c.into_iter().map(|k| part[k]).collect();
        if out.is_empty() || g.len() >= p.min_split_points {
            out.push(g);
        } else {
            stray.extend(g);
        }
    }
    out[0].extend(stray);
    out
}

/// Frame coordinates of all points.
fn frame(pts: &[[f64; 2]], pca: &Pca) -> Vec<[f64; 2]> {
    pts.iter().map(|&q| pca.to_frame(q)).collect()
}

/// Is this shape a filled bar (a dash, a stripe)?
fn is_filled_bar(s: &BarShape) -> bool {
    s.length() >= 2.5 * s.width() && s.fill >= 0.7
}

/// Split `rest` (indices into `pts`) into components; parts with fewer than
/// `min_split_points` points are returned separately as "tiny".
fn rest_components(pts: &[[f64; 2]], rest: &[usize], p: &Params) -> (Vec<Vec<usize>>, Vec<usize>) {
    let rxy: Vec<[f64; 2]> = rest.iter().map(|&k| pts[k]).collect();
    let mut parts = Vec::new();
    let mut tiny = Vec::new();
    for c in geom::components(&rxy, p.radius_m) {
        let g: Vec<usize> = c.into_iter().map(|k| rest[k]).collect();
        if g.len() < p.min_split_points {
            tiny.extend(g);
        } else {
            parts.push(g);
        }
    }
    (parts, tiny)
}

/// Width-profile split: a line of width w₀ with a wider stretch where something touches it.
fn profile_split(pts: &[[f64; 2]], p: &Params) -> Option<Vec<Vec<usize>>> {
    let pca = Pca::of(pts);
    let uv = frame(pts, &pca);
    let (umin, umax) = uv.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |a, q| {
        (a.0.min(q[0]), a.1.max(q[0]))
    });
    let len = umax - umin;
    if len < 3.0 {
        return None;
    }
    const DS: f64 = 0.25;
    let ns = (len / DS).ceil() as usize + 1;
    let slice_of = |u: f64| (((u - umin) / DS).floor() as usize).min(ns - 1);
    let mut vs: Vec<Vec<f64>> = vec![Vec::new(); ns];
    for q in &uv {
        vs[slice_of(q[0])].push(q[1]);
    }
    // Robust width and median per slice.
    let mut width = vec![f64::NAN; ns];
    let mut mid = vec![f64::NAN; ns];
    for k in 0..ns {
        if vs[k].len() >= 3 {
            vs[k].sort_unstable_by(f64::total_cmp);
            let (a, b) = geom::robust_extent(&vs[k]);
            width[k] = b - a;
            mid[k] = geom::quantile_sorted(&vs[k], 0.5);
        }
    }
    let mut ws: Vec<f64> = width.iter().copied().filter(|w| w.is_finite()).collect();
    if ws.len() < 8 {
        return None;
    }
    ws.sort_unstable_by(f64::total_cmp);
    let w0 = geom::quantile_sorted(&ws, 0.3);
    if w0 > p.max_line_width_m {
        return None;
    }
    let clean_max = 1.25 * w0 + 0.03;
    let wide_min = (1.45 * w0 + 0.04).max(clean_max + 0.02);
    let clean: Vec<bool> = width.iter().map(|&w| w.is_finite() && w <= clean_max).collect();
    let wide: Vec<bool> = width.iter().map(|&w| w.is_finite() && w >= wide_min).collect();
    let nclean = clean.iter().filter(|&&c| c).count();
    if (nclean as f64) < 0.4 * ws.len() as f64 || !wide.iter().any(|&w| w) {
        return None;
    }
    // Wide runs must be framed by clean slices on both sides (≥ 2 slices = 0.5 m each side):
    // an arrow head at the end of its shaft is not.
    let first_clean = clean.iter().position(|&c| c)?;
    let last_clean = clean.iter().rposition(|&c| c)?;
    let framed = (0..ns).any(|k| wide[k] && k >= first_clean + 2 && k + 2 <= last_clean);
    if !framed {
        return None;
    }
    // Centre line: medians of clean slices, interpolated by local linear fits over wide ones.
    let cu: Vec<f64> = (0..ns)
        .filter(|&k| clean[k])
        .map(|k| umin + (k as f64 + 0.5) * DS)
        .collect();
    let cv: Vec<f64> = (0..ns).filter(|&k| clean[k]).map(|k| mid[k]).collect();
    let cw = vec![1.0; cu.len()];
    let centre: Vec<f64> = (0..ns)
        .map(|k| {
            let u = umin + (k as f64 + 0.5) * DS;
            if clean[k] {
                mid[k]
            } else {
                // Quadratic: follows a curve through a 6 m gap (sagitta 4.5 cm at R = 100 m).
                geom::local_quadratic(&cu, &cv, &cw, u, 2.0, 12.0).unwrap_or(0.0)
            }
        })
        .collect();
    // w₀ is already a robust full width (padded by half a point spacing each side); line
    // points beyond it are few and come back as tiny parts or slivers.
    // Only points of wide slices (and their neighbours) can leave the line: the line's own
    // stray points elsewhere must not chain a dash part along it.
    let near_wide: Vec<bool> = (0..ns)
        .map(|k| wide[k] || (k > 0 && wide[k - 1]) || (k + 1 < ns && wide[k + 1]))
        .collect();
    let tol = w0 / 2.0 + 0.01;
    let (mut line, mut rest) = (Vec::new(), Vec::new());
    for (i, q) in uv.iter().enumerate() {
        let f = ((q[0] - umin) / DS - 0.5).clamp(0.0, (ns - 1) as f64);
        let k = (f.floor() as usize).min(ns - 1);
        let k1 = (k + 1).min(ns - 1);
        let c = centre[k] + (f - k as f64) * (centre[k1] - centre[k]);
        if (q[1] - c).abs() <= tol || !near_wide[slice_of(q[0])] {
            line.push(i);
        } else {
            rest.push(i);
        }
    }
    let (parts, tiny) = rest_components(pts, &rest, p);
    line.extend(tiny);
    let mut out = Vec::new();
    // Points per m² of the line, to tell a dash from a sparse scatter of stray points.
    let density = pts.len() as f64 / (len * w0).max(1e-6);
    for part in parts {
        // A filled bar at least 1 m long, about as dense as the line (not a sparse scatter
        // of stray points), at this angle (deg) to the line.
        let shape = BarShape::of(&part.iter().map(|&k| pts[k]).collect::<Vec<_>>());
        let bar = (is_filled_bar(&shape)
            && shape.length() >= 1.0
            && part.len() as f64 >= 0.3 * density * shape.length() * shape.width())
        .then(|| (geom::acute_angle_deg(shape.pca.axis, pca.axis), shape.width()));
        // A dash: parallel and as wide as a painted line (not a sliver shaved off the line's
        // own edge).
        let parallel = bar.is_some_and(|(a, w)| a <= 12.0 && w >= (0.4 * w0).max(0.06));
        // A stripe touching a long line obliquely (a chevron of a gore area, a hatched
        // island's stripe), as wide as paint, on a line too long to be an arrow (whose head
        // and branches stay on its shaft).
        let oblique = len >= OBLIQUE_LINE_MIN_LENGTH_M
            && bar.is_some_and(|(a, w)| (OBLIQUE_MIN_DEG..=OBLIQUE_MAX_DEG).contains(&a) && w >= 0.1);
        // A mark that touches a long line with a part wider than paint lines (an arrow's
        // head or branch reaching an edge line): no arrow's shaft is that long, so what
        // sticks out is no part of the line.
        let area = shape.length() * shape.width() * shape.fill;
        let beside = len >= OBLIQUE_LINE_MIN_LENGTH_M
            && !is_filled_bar(&shape)
            && shape.length() <= BESIDE_MAX_LENGTH_M
            && shape.width() >= BESIDE_MIN_WIDTH_M
            && area >= BESIDE_MIN_AREA_M2
            && part.len() as f64 >= 0.3 * density * area;
        if parallel || oblique || beside {
            out.push(part);
        } else {
            line.extend(part);
        }
    }
    if out.is_empty() || line.len() < p.min_split_points {
        return None;
    }
    line.sort_unstable();
    out.insert(0, line);
    Some(out)
}

/// Lines at least this long (m) have oblique stripes touching them split off (see
/// [`profile_split`]); shorter clusters may be arrows, whose head and branches stay whole.
const OBLIQUE_LINE_MIN_LENGTH_M: f64 = 12.0;
/// Least width (m) and area (m²) of a part touching a long line that is split off it
/// whatever its shape (see [`profile_split`]).
const BESIDE_MIN_WIDTH_M: f64 = 0.5;
const BESIDE_MIN_AREA_M2: f64 = 0.15;
/// Longest such part (m): an arrow, not the stripes of a gore and the line they reach.
const BESIDE_MAX_LENGTH_M: f64 = 10.0;
/// Angles (deg) between such a stripe and the line: guideline stripes and chevrons, not
/// crosswalk stripes (along or across the road) nor stop lines.
const OBLIQUE_MIN_DEG: f64 = 20.0;
const OBLIQUE_MAX_DEG: f64 = 70.0;

/// Histogram valley split across (and, for short clusters, along) the principal axis.
fn valley_split(pts: &[[f64; 2]], p: &Params) -> Option<Vec<Vec<usize>>> {
    let pca = Pca::of(pts);
    let uv = frame(pts, &pca);
    let (umin, umax) = uv.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |a, q| {
        (a.0.min(q[0]), a.1.max(q[0]))
    });
    let len = umax - umin;
    // Across: residual from a smoothed centre (slice means), so curved pairs split too.
    const DS: f64 = 0.5;
    let ns = (len / DS).ceil() as usize + 1;
    let mut sum = vec![(0.0, 0.0); ns];
    for q in &uv {
        let k = (((q[0] - umin) / DS) as usize).min(ns - 1);
        sum[k].0 += q[1];
        sum[k].1 += 1.0;
    }
    let (mut su, mut sv, mut sw) = (Vec::new(), Vec::new(), Vec::new());
    for (k, &(s, c)) in sum.iter().enumerate() {
        if c > 0.0 {
            su.push(umin + (k as f64 + 0.5) * DS);
            sv.push(s / c);
            sw.push(c);
        }
    }
    // The bandwidth stays short on long clusters: a local linear fit over tens of metres
    // of a curved line is biased by decimetres (≈ h²/2R), which smears the residuals of ONE
    // line into two false modes.
    let h = (len / 10.0).clamp(2.0, 5.0);
    let centre: Vec<f64> = (0..ns)
        .map(|k| {
            let u = umin + (k as f64 + 0.5) * DS;
            geom::local_linear(&su, &sv, &sw, u, h, 1.0).map_or(0.0, |r| r.0)
        })
        .collect();
    let resid: Vec<f64> = uv
        .iter()
        .map(|q| {
            let f = ((q[0] - umin) / DS - 0.5).clamp(0.0, (ns - 1) as f64);
            let k = (f.floor() as usize).min(ns - 1);
            let k1 = (k + 1).min(ns - 1);
            q[1] - (centre[k] + (f - k as f64) * (centre[k1] - centre[k]))
        })
        .collect();
    // Modes ≥ 0.2 m apart: two painted lines side by side (centre to centre ≥ 0.25 m for
    // 0.1 m lines 0.15 m apart); closer modes are the scan pattern inside one line. A
    // mark sampled by scan rows running along it (a stripe across a side street, parallel
    // to the scan lines) is a comb of evenly spaced rows with empty gaps between them: one
    // object, not several.
    if sampled_rows(&resid) {
        return None;
    }
    if let Some(cut) = find_valley(&resid, 0.02, 0.2, p) {
        let (a, b): (Vec<usize>, Vec<usize>) = (0..pts.len()).partition(|&i| resid[i] < cut);
        return Some(vec![a, b]);
    }
    if len <= 20.0 {
        let along: Vec<f64> = uv.iter().map(|q| q[0]).collect();
        if let Some(cut) = find_valley(&along, 0.05, 0.5, p) {
            let (a, b): (Vec<usize>, Vec<usize>) = (0..pts.len()).partition(|&i| along[i] < cut);
            return Some(vec![a, b]);
        }
    }
    None
}

/// Largest spread (m) of one scan row's offsets across a mark it runs along (range noise
/// and the row's slight slant), and the largest step between two offsets of one row.
const ROW_MAX_WIDTH_M: f64 = 0.05;
const ROW_MAX_STEP_M: f64 = 0.03;
/// Most spacing (m) of the rows of one mark: farther apart they are separate marks.
const ROW_MAX_SPACING_M: f64 = 0.4;

/// Whether the offsets `vals` across a cluster are those of one mark sampled by scan rows
/// along it: at least three thin bands (each at most [`ROW_MAX_WIDTH_M`] wide, bands
/// separated by gaps wider than [`ROW_MAX_STEP_M`]) holding all but a few of the points,
/// evenly spaced (every centre-to-centre spacing within 30 % of their median, which is at
/// most [`ROW_MAX_SPACING_M`]). With the default row rate of the simulated scanners rows
/// are 5 cm apart and never leave an empty valley inside a mark; at 100 lines/s they are
/// 0.12-0.15 m apart, and `find_valley` cut each crosswalk stripe across a side street
/// into its rows, which the classifier then dropped as steep one-row strokes. Two lines
/// side by side (a double line, seen as one row each or as broad bands), and stripes
/// bridged by noise (bands with one wide gap) are no such comb. Hand-written.
fn sampled_rows(vals: &[f64]) -> bool {
    let mut s = vals.to_vec();
    s.sort_unstable_by(f64::total_cmp);
    // Bands: runs of sorted offsets with steps of at most ROW_MAX_STEP_M.
    let mut bands: Vec<(f64, f64, usize)> = Vec::new();
    for &v in &s {
        match bands.last_mut() {
            Some(b) if v - b.1 <= ROW_MAX_STEP_M => {
                b.1 = v;
                b.2 += 1;
            }
            _ => bands.push((v, v, 1)),
        }
    }
    // Stray points (noise beside the mark) are not rows; the rows hold the rest.
    let min_row = 3.max(s.len() / 50);
    let rows: Vec<&(f64, f64, usize)> = bands.iter().filter(|b| b.2 >= min_row).collect();
    let in_rows: usize = rows.iter().map(|b| b.2).sum();
    if rows.len() < 3 || in_rows * 20 < s.len() * 19 || rows.iter().any(|b| b.1 - b.0 > ROW_MAX_WIDTH_M) {
        return false;
    }
    let spacing: Vec<f64> = rows
        .windows(2)
        .map(|w| 0.5 * (w[1].0 + w[1].1) - 0.5 * (w[0].0 + w[0].1))
        .collect();
    let med = geom::median(&mut spacing.clone());
    med <= ROW_MAX_SPACING_M && spacing.iter().all(|d| (d - med).abs() <= 0.3 * med)
}

/// The cut position of an almost empty valley between two well-populated modes of `vals`
/// (bin `bin` m, modes at least `min_sep` m apart), or None.
fn find_valley(vals: &[f64], bin: f64, min_sep: f64, p: &Params) -> Option<f64> {
    let (lo, hi) = vals
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    let nb = ((hi - lo) / bin).ceil() as usize + 1;
    if !(5..=20_000).contains(&nb) {
        return None;
    }
    let mut h = vec![0.0f64; nb];
    for &v in vals {
        h[(((v - lo) / bin) as usize).min(nb - 1)] += 1.0;
    }
    // Light smoothing so sparse sampling does not make spurious valleys.
    let sm: Vec<f64> = (0..nb)
        .map(|i| {
            let a = i.saturating_sub(1);
            let b = (i + 1).min(nb - 1);
            (a..=b).map(|j| h[j]).sum::<f64>() / (b - a + 1) as f64
        })
        .collect();
    let total = vals.len() as f64;
    let sep_bins = (min_sep / bin).ceil() as usize;
    // Best valley: the lowest bin whose left and right maxima are both high.
    let mut left_max = vec![0.0; nb];
    let mut acc = 0.0f64;
    for i in 0..nb {
        acc = acc.max(sm[i]);
        left_max[i] = acc;
    }
    let mut right_max = vec![0.0; nb];
    acc = 0.0;
    for i in (0..nb).rev() {
        acc = acc.max(sm[i]);
        right_max[i] = acc;
    }
    let mut best: Option<(f64, usize)> = None;
    for i in 1..nb - 1 {
        let peak = left_max[i].min(right_max[i]);
        if peak <= 0.0 || sm[i] > 0.1 * peak {
            continue;
        }
        let score = sm[i] / peak;
        if best.is_none_or(|(b, _)| score < b) {
            best = Some((score, i));
        }
    }
    let (_, i) = best?;
    let cut = lo + (i as f64 + 0.5) * bin;
    let below = vals.iter().filter(|&&v| v < cut).count();
    let min_part = p.min_split_points.max((0.05 * total) as usize);
    if below < min_part || vals.len() - below < min_part {
        return None;
    }
    // The modes must be separated: peaks on either side at least `min_sep` apart.
    let lpk = (0..i).max_by(|&a, &b| sm[a].total_cmp(&sm[b]))?;
    let rpk = (i + 1..nb).max_by(|&a, &b| sm[a].total_cmp(&sm[b]).then(b.cmp(&a)))?;
    (rpk - lpk >= sep_bins).then_some(cut)
}

/// Is this cluster one painted line, straight or curved: are the residuals about a smoothed
/// centre (local quadratic of 0.5 m slice means) as narrow as a line?
fn clean_line(pts: &[[f64; 2]], p: &Params) -> bool {
    let pca = Pca::of(pts);
    let uv = frame(pts, &pca);
    let mut us: Vec<(f64, f64)> = uv.iter().map(|q| (q[0], q[1])).collect();
    us.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (umin, umax) = (us[0].0, us[us.len() - 1].0);
    let len = umax - umin;
    const DS: f64 = 0.5;
    let ns = (len / DS).ceil() as usize + 1;
    let mut acc = vec![(0.0, 0.0, 0.0); ns];
    for &(u, v) in &us {
        let k = (((u - umin) / DS) as usize).min(ns - 1);
        acc[k].0 += u;
        acc[k].1 += v;
        acc[k].2 += 1.0;
    }
    let (mut su, mut sv, mut sw) = (Vec::new(), Vec::new(), Vec::new());
    for a in acc.iter().filter(|a| a.2 > 0.0) {
        su.push(a.0 / a.2);
        sv.push(a.1 / a.2);
        sw.push(a.2);
    }
    let h = (len / 10.0).max(2.0);
    let centre: Vec<f64> = su
        .iter()
        .map(|&u| geom::local_quadratic(&su, &sv, &sw, u, h, 1.0).unwrap_or(0.0))
        .collect();
    let mut resid: Vec<f64> = us
        .iter()
        .map(|&(u, v)| {
            let j = su.partition_point(|&x| x < u).min(su.len() - 1);
            v - centre[j]
        })
        .collect();
    resid.sort_unstable_by(f64::total_cmp);
    let (a, b) = geom::robust_extent(&resid);
    b - a <= 1.3 * p.max_line_width_m
}

/// Hough search for the densest straight bar; split off attached parallel bars and
/// perpendicular objects the bar overhangs. On long clusters (> 10 m from the centre) the
/// bar must be a long thin line (≥ 10 m, ≤ `max_line_width_m`), and everything attached to
/// it is split off: gore-area chevrons, wide dashes or arrows touching an edge line.
fn bar_split(pts: &[[f64; 2]], p: &Params) -> Option<Vec<Vec<usize>>> {
    let n = pts.len();
    if n < 30 {
        return None;
    }
    let pca = Pca::of(pts);
    let c = pca.center;
    let rel: Vec<[f64; 2]> = pts.iter().map(|q| [q[0] - c[0], q[1] - c[1]]).collect();
    let ext = rel.iter().fold(0.0f64, |a, q| a.max(q[0].hypot(q[1])));
    // Long clusters: only a long thin straight line (an edge or lane line with things
    // touching it) is looked for, and a clean (possibly curved) line is left alone.
    let long = ext > 10.0;
    if long && clean_line(pts, p) {
        return None;
    }
    // The direction search runs on at most ~20 000 points.
    let stride = (n / 20_000).max(1);
    let srel: Vec<[f64; 2]> = rel.iter().step_by(stride).copied().collect();
    const BIN: f64 = 0.05;
    let nb = (2.0 * ext / BIN).ceil() as usize + 3;
    // Score of a direction: points in the best window of `WIN` bins across it. A window as
    // wide as a stop line makes long wide bars win over an arrow's shaft crossing them.
    const WIN: usize = 8;
    let score_at = |theta: f64, h: &mut Vec<u32>| -> (u32, usize) {
        h.clear();
        h.resize(nb, 0);
        let (s, co) = theta.sin_cos();
        for q in &srel {
            let d = -s * q[0] + co * q[1];
            h[(((d + ext) / BIN) as usize + 1).min(nb - 1)] += 1;
        }
        let mut w: u32 = h[..WIN.min(nb)].iter().sum();
        let mut best = (w, 0);
        for i in 1..nb.saturating_sub(WIN - 1) {
            w = w + h[i + WIN - 1] - h[i - 1];
            if w > best.0 {
                best = (w, i);
            }
        }
        best
    };
    // Candidate directions: the local maxima of the coarse score (2° steps), best first.
    let mut h = Vec::new();
    let coarse: Vec<(u32, usize)> = (0..90)
        .map(|k| score_at((k as f64 * 2.0).to_radians(), &mut h))
        .collect();
    let top = coarse.iter().map(|c| c.0).max().unwrap_or(0);
    let mut peaks: Vec<usize> = (0..90)
        .filter(|&k| {
            let (l, r) = (coarse[(k + 89) % 90].0, coarse[(k + 1) % 90].0);
            coarse[k].0 >= l && coarse[k].0 > r && coarse[k].0 as f64 >= 0.3 * top as f64
        })
        .collect();
    peaks.sort_by(|&x, &y| coarse[y].0.cmp(&coarse[x].0).then(x.cmp(&y)));
    for &k in peaks.iter().take(3) {
        let mut best = (0u32, 0usize, 0.0f64);
        for j in -8..=8 {
            let th = (k as f64 * 2.0 + j as f64 * 0.25).to_radians();
            let (sc, i) = score_at(th, &mut h);
            if sc > best.0 {
                best = (sc, i, th);
            }
        }
        if let Some(parts) = bar_split_at(pts, &rel, ext, best.2, best.1, long, p, &score_at) {
            return Some(parts);
        }
    }
    None
}

/// Shortest arm of an L of two filled bars that [`bar_split_at`] takes apart (m), and the
/// least angle between the arms (deg): a lane line meets a stop line square, an arrow's
/// turning branch leaves its shaft at 45–65°.
const L_ARM_MIN_M: f64 = 2.0;
const L_ARM_MIN_ANGLE_DEG: f64 = 75.0;

/// One bar candidate of [`bar_split`]: direction `theta`, densest window starting at bin `w0`.
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn bar_split_at(
    pts: &[[f64; 2]],
    rel: &[[f64; 2]],
    ext: f64,
    theta: f64,
    w0: usize,
    long: bool,
    p: &Params,
    score_at: &dyn Fn(f64, &mut Vec<u32>) -> (u32, usize),
) -> Option<Vec<Vec<usize>>> {
    const BIN: f64 = 0.05;
    const WIN: usize = 8;
    let n = pts.len();
    let mut h = Vec::new();
    score_at(theta, &mut h);
    let nb = h.len();
    // Band: the window trimmed to its dense bins, then grown while neighbours stay dense.
    let wend = (w0 + WIN - 1).min(nb - 1);
    let peak = (w0..=wend).map(|i| h[i]).max().unwrap_or(0) as f64;
    let (mut a, mut b) = (w0, wend);
    while a < b && (h[a] as f64) < 0.3 * peak {
        a += 1;
    }
    while b > a && (h[b] as f64) < 0.3 * peak {
        b -= 1;
    }
    let max_bins = (p.max_bar_width_m / BIN).round() as usize;
    while b - a + 1 < max_bins {
        let (ca, cb) = (
            if a > 0 { h[a - 1] as f64 } else { 0.0 },
            if b + 1 < nb { h[b + 1] as f64 } else { 0.0 },
        );
        if ca.max(cb) < 0.3 * peak {
            break;
        }
        if ca >= cb {
            a -= 1;
        } else {
            b += 1;
        }
    }
    let (s, co) = theta.sin_cos();
    let dir = [co, s];
    let nlo = (a as f64 - 1.0) * BIN - ext;
    let nhi = (b as f64) * BIN - ext;
    let normal = |q: &[f64; 2]| -s * q[0] + co * q[1];
    let along = |q: &[f64; 2]| q[0] * dir[0] + q[1] * dir[1];
    // Strip points, then the longest connected run of them along the bar.
    let mut strip: Vec<usize> = (0..n)
        .filter(|&i| {
            let d = normal(&rel[i]);
            d >= nlo && d < nhi
        })
        .collect();
    strip.sort_by(|&x, &y| along(&rel[x]).total_cmp(&along(&rel[y])));
    let mut runs: Vec<Vec<usize>> = Vec::new();
    let run_gap = if long { p.max_radius_m } else { p.radius_m };
    for &i in &strip {
        match runs.last_mut() {
            Some(r) if along(&rel[i]) - along(&rel[*r.last().expect("non-empty")]) <= run_gap => r.push(i),
            _ => runs.push(vec![i]),
        }
    }
    let mut bar = runs.into_iter().max_by_key(|r| r.len())?;
    let (ba, bb) = (along(&rel[bar[0]]), along(&rel[*bar.last()?]));
    if bb - ba < 2.0 || bar.len() as f64 >= 0.85 * n as f64 {
        return None;
    }
    if long && (bb - ba < 10.0 || nhi - nlo > p.max_line_width_m + 0.05) {
        return None;
    }
    let mut in_bar = vec![false; n];
    for &i in &bar {
        in_bar[i] = true;
    }
    let rest: Vec<usize> = (0..n).filter(|&i| !in_bar[i]).collect();
    let (parts, tiny) = rest_components(pts, &rest, p);
    bar.extend(tiny);
    let mut out = Vec::new();
    let ncen = (nlo + nhi) / 2.0;
    for part in parts {
        let pxy: Vec<[f64; 2]> = part.iter().map(|&k| pts[k]).collect();
        let shape = BarShape::of(&pxy);
        let filled = is_filled_bar(&shape);
        let phi = geom::acute_angle_deg(shape.pca.axis, geom::canonical(dir));
        let band_w = nhi - nlo;
        let parallel =
            phi <= 12.0 && filled && shape.length() >= 1.0 && shape.width() >= (0.3 * band_w).max(0.06);
        let (mut pa, mut pb) = (f64::INFINITY, f64::NEG_INFINITY);
        let mut same_side = 0usize;
        let side = (normal(&rel[part[0]]) - ncen).signum();
        for &k in &part {
            let t = along(&rel[k]);
            pa = pa.min(t);
            pb = pb.max(t);
            if (normal(&rel[k]) - ncen).signum() == side {
                same_side += 1;
            }
        }
        let one_side = same_side as f64 >= 0.95 * part.len() as f64;
        let perpendicular =
            phi >= 60.0 && pa - ba >= 0.3 && bb - pb >= 0.3 && (bb - ba) >= 2.5 * (pb - pa) && one_side;
        // A filled stripe touching the bar at an angle (chevrons on an edge line).
        let diagonal = phi > 20.0 && phi < 70.0 && one_side && shape.length() >= 1.0 && filled;
        // A filled bar at least 2 m long meeting the bar square, on one side of it (a lane
        // line ending on a stop line): an L of two such bars is no one painted object.
        let l_arm = phi >= L_ARM_MIN_ANGLE_DEG && one_side && shape.length() >= L_ARM_MIN_M && filled;
        // A long line takes nothing with it: whatever touches it is another object.
        if long || parallel || perpendicular || diagonal || l_arm {
            out.push(part);
        } else {
            bar.extend(part);
        }
    }
    if out.is_empty() {
        return None;
    }
    bar.sort_unstable();
    out.insert(0, bar);
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud(pts: &[[f64; 2]]) -> PointCloud {
        let mut c = PointCloud::default();
        for p in pts {
            c.push_local(p[0], p[1], 0.0, 30000.0, None, 0);
        }
        c
    }

    /// Points on a jittered grid filling a rectangle (centre, along-axis angle in degrees).
    fn rect(cx: f64, cy: f64, len: f64, wid: f64, deg: f64, step: f64, seed: u64) -> Vec<[f64; 2]> {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let (s, c) = deg.to_radians().sin_cos();
        let mut out = Vec::new();
        let nu = (len / step).round() as i64;
        let nv = (wid / step).round().max(1.0) as i64;
        for i in 0..=nu {
            for j in 0..=nv {
                let u = -len / 2.0 + len * i as f64 / nu as f64 + rng.random_range(-0.3..0.3) * step;
                let v = -wid / 2.0 + wid * j as f64 / nv as f64 + rng.random_range(-0.3..0.3) * step;
                out.push([cx + u * c - v * s, cy + u * s + v * c]);
            }
        }
        out
    }

    fn sizes(cs: &[Cluster]) -> Vec<usize> {
        let mut v: Vec<usize> = cs.iter().map(|c| c.indices.len()).collect();
        v.sort_unstable();
        v
    }

    #[test]
    fn degenerate_inputs() {
        let p = Params::default();
        assert!(run(&PointCloud::default(), &p).is_empty());
        assert!(
            run(&cloud(&[[0.0, 0.0]]), &p).is_empty(),
            "one point is below min_points"
        );
        let one = Params {
            min_points: 1,
            ..Params::default()
        };
        assert_eq!(run(&cloud(&[[0.0, 0.0]]), &one).len(), 1);
        let line: Vec<[f64; 2]> = (0..100).map(|i| [i as f64 * 0.05, 0.0]).collect();
        let c = run(&cloud(&line), &p);
        assert_eq!(c.len(), 1, "collinear points stay one cluster");
        let mut nan = cloud(&line);
        nan.x[3] = f64::NAN;
        assert_eq!(
            run(&nan, &p)[0].indices.len(),
            99,
            "non-finite points are ignored"
        );
    }

    /// Three far crosswalk stripes (0.45 m wide, 3 m long, 1.05 m apart) seen by scan
    /// rows 0.45 m apart: one cluster per stripe, although each stripe's rows are 0.45 m
    /// apart (beyond `radius_m`) and the empty gaps between them are lateral valleys;
    /// with `join_rows` off each row piece is a cluster of its own.
    #[test]
    fn far_stripes_crossed_by_rows_are_one_cluster_each() {
        let mut pts = Vec::new();
        for stripe in 0..3 {
            for r in 0..7 {
                for k in 0..9 {
                    pts.push([1.05 * stripe as f64 + 0.05 * k as f64, 0.45 * r as f64]);
                }
            }
        }
        let c = run(&cloud(&pts), &Params::default());
        assert_eq!(sizes(&c), vec![63, 63, 63]);
        let off = Params {
            join_rows: false,
            ..Params::default()
        };
        assert_eq!(run(&cloud(&pts), &off).len(), 21);
    }

    /// A crosswalk stripe across a side street (4 m long, 0.45 m wide) lies along the scan
    /// rows: at 100 lines/s it holds four rows 0.13 m apart, points every 5 cm along each
    /// (with a little noise across). It stays one cluster; two such stripes 1.05 m apart
    /// joined by a few noise points are still cut apart, and so is a double line (two 0.1 m
    /// lines 0.2 m apart, one row each).
    #[test]
    fn a_stripe_sampled_by_rows_along_it_is_one_cluster() {
        let mut jit = geom::test_jitter(3);
        let stripe = |pts: &mut Vec<[f64; 2]>, y0: f64, rows: usize, jit: &mut dyn FnMut() -> f64| {
            for r in 0..rows {
                for k in 0..80 {
                    pts.push([0.05 * k as f64, y0 + 0.13 * r as f64 + 0.005 * jit()]);
                }
            }
        };
        let mut one = Vec::new();
        stripe(&mut one, 0.0, 4, &mut jit);
        assert_eq!(sizes(&run(&cloud(&one), &Params::default())), vec![320]);
        let mut two = one.clone();
        stripe(&mut two, 1.05, 4, &mut jit);
        two.extend((0..12).map(|k| [2.0, 0.45 + 0.05 * k as f64]));
        let c = run(&cloud(&two), &Params::default());
        assert!(c.len() >= 2, "{:?}", sizes(&c));
        assert!(c.iter().all(|c| c.indices.len() <= 332), "{:?}", sizes(&c));
        let mut double = Vec::new();
        stripe(&mut double, 0.0, 1, &mut jit);
        stripe(&mut double, 0.2, 1, &mut jit);
        assert_eq!(sizes(&run(&cloud(&double), &Params::default())), vec![80, 80]);
    }

    #[test]
    fn separate_markings_stay_separate() {
        let mut pts = rect(0.0, 0.0, 6.0, 0.15, 0.0, 0.03, 1);
        pts.extend(rect(15.0, 0.0, 6.0, 0.15, 0.0, 0.03, 2));
        pts.extend(rect(0.0, 3.5, 30.0, 0.15, 0.0, 0.03, 3));
        let c = run(&cloud(&pts), &Params::default());
        assert_eq!(c.len(), 3);
        assert!(c.iter().all(|c| !c.split));
    }

    #[test]
    fn dash_touching_a_solid_line_is_split() {
        // Solid line 30 m × 0.15 m; a 6 m dash right beside it (touching, 0 gap).
        let mut pts = rect(0.0, 0.0, 30.0, 0.15, 0.0, 0.03, 1);
        let nsolid = pts.len();
        pts.extend(rect(2.0, 0.16, 6.0, 0.15, 0.0, 0.03, 2));
        let c = run(&cloud(&pts), &Params::default());
        assert_eq!(c.len(), 2, "{:?}", sizes(&c));
        let solid = c.iter().max_by_key(|c| c.indices.len()).unwrap();
        // Touching: only the dash's boundary row (1 of 6) is ambiguous.
        let wrong = solid.indices.iter().filter(|&&i| i >= nsolid).count();
        let ndash = pts.len() - nsolid;
        assert!(
            wrong * 5 < ndash,
            "dash points left in the solid: {wrong} of {ndash}"
        );
        assert!(c.iter().all(|c| c.split));
    }

    /// A gore area's edge line (30 m × 0.2 m) with four chevrons (2 m × 0.4 m at 35°)
    /// touching it: the chevrons are split off, each one cluster.
    #[test]
    fn oblique_stripes_touching_a_long_line_are_split_off() {
        let mut pts = rect(0.0, 0.0, 30.0, 0.2, 0.0, 0.03, 1);
        let nline = pts.len();
        for (k, x) in [-9.0, -3.0, 3.0, 9.0].into_iter().enumerate() {
            // Centre 1 m from the stripe's end on the line's upper edge.
            let (s, c) = 35f64.to_radians().sin_cos();
            pts.extend(rect(x + c, 0.1 + s, 2.0, 0.4, 35.0, 0.03, 10 + k as u64));
        }
        let c = run(&cloud(&pts), &Params::default());
        assert_eq!(c.len(), 5, "{:?}", sizes(&c));
        let line = c.iter().max_by_key(|c| c.indices.len()).unwrap();
        let wrong = line.indices.iter().filter(|&&i| i >= nline).count();
        assert!(
            wrong * 4 < pts.len() - nline,
            "stripe points left on the line: {wrong}"
        );
    }

    #[test]
    fn dash_beside_a_curved_solid_line_is_split() {
        // R = 100 m arc, 40 m long; a 6 m dash 0.2 m (centre to centre 0.3) outside it.
        let mut pts = Vec::new();
        let mut dash = Vec::new();
        let mut k = 0u64;
        for i in 0..1333 {
            let a = i as f64 * 0.03 / 100.0;
            for j in 0..6 {
                k += 1;
                let r = 100.0 - 0.075 + j as f64 * 0.03 + (k % 7) as f64 * 0.001;
                pts.push([r * a.sin(), 100.0 - r * a.cos()]);
                if (15.0..21.0).contains(&(a * 100.0)) {
                    let r2 = r - 0.3;
                    dash.push([r2 * a.sin(), 100.0 - r2 * a.cos()]);
                }
            }
        }
        pts.extend(dash);
        let c = run(&cloud(&pts), &Params::default());
        assert_eq!(c.len(), 2, "{:?}", sizes(&c));
    }

    #[test]
    fn parallel_lines_bridged_by_noise_are_split() {
        // Double line: two 20 m lines 0.15 wide, 0.1 m gap, a few noise points between.
        let mut pts = rect(0.0, 0.0, 20.0, 0.15, 3.0, 0.03, 1);
        let off = [-0.25 * 3f64.to_radians().sin(), 0.25 * 3f64.to_radians().cos()];
        pts.extend(rect(off[0], off[1], 20.0, 0.15, 3.0, 0.03, 2));
        let c = run(&cloud(&pts), &Params::default());
        assert_eq!(c.len(), 2, "{:?}", sizes(&c));
        // Crosswalk: three stripes 0.45 wide, 0.6 apart, bridged by a streak of points.
        let mut pts = Vec::new();
        for k in 0..3 {
            pts.extend(rect(0.0, k as f64 * 1.05, 5.0, 0.45, 0.0, 0.04, k as u64));
        }
        pts.extend((0..30).map(|i| [0.3, i as f64 * 0.07]));
        let c = run(&cloud(&pts), &Params::default());
        let big: Vec<&Cluster> = c.iter().filter(|c| c.indices.len() > 100).collect();
        assert_eq!(big.len(), 3, "{:?}", sizes(&c));
    }

    #[test]
    fn arrow_touching_a_stop_line_is_split_but_an_arrow_alone_is_not() {
        // Straight arrow: shaft 0.2 × 3 m + triangular head 0.9 wide, 1.5 long, along +x.
        let mut arrow = rect(-1.5, 0.0, 3.0, 0.2, 0.0, 0.03, 5);
        for i in 0..50 {
            let u = i as f64 * 0.03;
            let half = 0.45 * (1.0 - u / 1.5);
            let m = (half / 0.03).round() as i64;
            for j in -m..=m {
                arrow.push([u, j as f64 * 0.03]);
            }
        }
        let c = run(&cloud(&arrow), &Params::default());
        assert_eq!(c.len(), 1, "an arrow is one object: {:?}", sizes(&c));
        // Stop line across, 0.4 m wide, 3.5 m long, touching the arrow tip.
        let mut pts = arrow.clone();
        pts.extend(rect(1.65, 0.3, 3.5, 0.4, 90.0, 0.03, 6));
        let c = run(&cloud(&pts), &Params::default());
        assert_eq!(c.len(), 2, "{:?}", sizes(&c));
    }

    #[test]
    fn a_lane_line_ending_on_a_stop_line_is_split() {
        // Stop line 0.45 × 4 m across (along y), a 0.15 m lane line 3.5 m long ending on
        // it at one end (an L: the stop line's other half went with another cluster).
        let mut pts = rect(0.0, 2.0, 4.0, 0.45, 90.0, 0.03, 7);
        pts.extend(rect(-1.97, 0.1, 3.5, 0.15, 0.0, 0.03, 8));
        let c = run(&cloud(&pts), &Params::default());
        assert_eq!(c.len(), 2, "{:?}", sizes(&c));
    }

    /// Two turn arrows 40 m apart whose branches touch one edge line (a shaft 4 m × 0.2 m
    /// 1.2 m beside the line, a branch 1.6 m × 0.3 m at 45° down to it): taking the line out
    /// leaves both arrows on one side of it, and each must still be a cluster of its own.
    #[test]
    fn objects_split_off_one_line_far_apart_are_separate_clusters() {
        let mut pts = rect(0.0, 0.0, 60.0, 0.15, 0.0, 0.03, 1);
        let nline = pts.len();
        let mut arrow_of = vec![None; nline];
        for (k, x) in [-20.0, 20.0].into_iter().enumerate() {
            let arrow = [
                rect(x, 1.2, 4.0, 0.2, 0.0, 0.03, 20 + k as u64),
                rect(x + 2.0 + 0.5, 0.6, 1.6, 0.3, -45.0, 0.03, 30 + k as u64),
            ]
            .concat();
            arrow_of.extend(std::iter::repeat_n(Some(k), arrow.len()));
            pts.extend(arrow);
        }
        let c = run(&cloud(&pts), &Params::default());
        // Per cluster: its points of the line, of the first arrow and of the second.
        let counts: Vec<[usize; 3]> = c
            .iter()
            .map(|cl| {
                let mut n = [0; 3];
                for &i in &cl.indices {
                    n[arrow_of[i].map_or(0, |k| k + 1)] += 1;
                }
                n
            })
            .collect();
        // The line may keep the branches' tips; no other cluster holds both arrows.
        assert!(
            counts.iter().all(|n| n[0] > nline / 2 || n[1].min(n[2]) == 0),
            "{counts:?}"
        );
        let whole = |k: usize| counts.iter().map(|n| n[k]).max().unwrap_or(0);
        let per_arrow = (pts.len() - nline) / 2;
        assert!(whole(1) * 2 > per_arrow && whole(2) * 2 > per_arrow, "{counts:?}");
    }

    /// A right-turn arrow whose head touches a 150 m edge line (shaft 4 m × 0.2 m, 1.2 m
    /// beside the line; its branch 1.6 m × 0.3 m at 45° down to the line; a 0.7 m head on
    /// the branch's end): the arrow is no part of the line, though no rule for bars fits it
    /// and its branch fills the lateral valley between it and the line.
    #[test]
    fn an_arrow_touching_a_long_line_is_split_off() {
        let mut pts = rect(0.0, 0.0, 150.0, 0.15, 0.0, 0.03, 1);
        let nline = pts.len();
        pts.extend(rect(0.0, 1.2, 4.0, 0.2, 0.0, 0.03, 2));
        pts.extend(rect(2.56, 0.6, 1.6, 0.3, -45.0, 0.03, 3));
        pts.extend(rect(3.12, 0.35, 0.7, 0.7, -45.0, 0.03, 4));
        let c = run(&cloud(&pts), &Params::default());
        let line = c.iter().max_by_key(|c| c.indices.len()).expect("clusters");
        let kept = line.indices.iter().filter(|&&i| i >= nline).count();
        assert!(
            kept * 5 < pts.len() - nline,
            "{kept} of the arrow's {} points left on the line: {:?}",
            pts.len() - nline,
            sizes(&c)
        );
    }

    #[test]
    fn result_does_not_depend_on_point_order() {
        use rand::SeedableRng;
        use rand::seq::SliceRandom;
        let mut pts = rect(0.0, 0.0, 30.0, 0.15, 10.0, 0.04, 1);
        pts.extend(rect(3.0, 0.7, 6.0, 0.15, 10.0, 0.04, 2));
        pts.extend(rect(0.0, 5.0, 5.0, 0.45, 100.0, 0.04, 3));
        let a = run(&cloud(&pts), &Params::default());
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut perm: Vec<usize> = (0..pts.len()).collect();
        perm.shuffle(&mut rng);
        let shuffled: Vec<[f64; 2]> = perm.iter().map(|&i| pts[i]).collect();
        let b = run(&cloud(&shuffled), &Params::default());
        let as_coords = |cs: &[Cluster], p: &[[f64; 2]]| -> Vec<Vec<[u64; 2]>> {
            cs.iter()
                .map(|c| {
                    c.indices
                        .iter()
                        .map(|&i| [p[i][0].to_bits(), p[i][1].to_bits()])
                        .collect()
                })
                .collect()
        };
        assert_eq!(as_coords(&a, &pts), as_coords(&b, &shuffled));
    }

    #[test]
    fn params_are_validated() {
        assert!(Params::default().validate().is_ok());
        let bad = Params {
            radius_m: 0.0,
            ..Params::default()
        };
        assert!(bad.validate().unwrap_err().contains("radius_m"));
        let p: Params = serde_json::from_str(r#"{"radius_m": 0.3}"#).unwrap();
        assert_eq!(p.min_points, 5);
        assert!(serde_json::from_str::<Params>(r#"{"radius": 0.3}"#).is_err());
    }
}
