//! Stage 1: pavement extraction guided by the trajectory.
//!
//! **What.** Keeps the points of the drivable road surface and drops curbs, sidewalks,
//! vehicles, vegetation and everything else, so the later stages see only asphalt and paint.
//!
//! **Algorithm** (`method: "slices"`, the default; Yao et al. 2019 § 2.1–2.4). Points are
//! located on the trajectory (mileage along it, signed lateral offset `u` from it) and cut
//! into slices of `slice_length_m` by mileage; each slice is its own cross-section
//! (`u` across, z up). Per slice:
//! 1. *Pseudo scan line*: the lowest point of every `pseudo_bin_m` interval of `u` (the
//!    paper's § 2.3), taken separately in sub-slices of 0.5 m so that the longitudinal
//!    grade can be fitted too.
//! 2. *RANSAC* (`ransac_iterations`, `ransac_tolerance_m`, seeded per slice from `seed` and
//!    the global slice index) fits the plane `z = a + b·u + c·s` to the pseudo points
//!    (the paper fits a line; the `c·s` grade term keeps a 2 m slice on a 5 % slope from
//!    looking 10 cm thick), refined by least squares on its inliers. Points whose height
//!    above that plane lies outside `[-buffer_below_m, buffer_above_m]` are dropped
//!    (the paper's road-surface buffer).
//! 3. *Moving-window cut* (§ 2.4): windows of `window_m` across the road, walked outward
//!    from the trajectory on both sides. A window's level is its 10 % height quantile and
//!    its thickness the 10–90 % range. A flat window (thickness ≤ the road thickness)
//!    becomes the new reference level and keeps its points near that level. A thick
//!    window (a "key window", eq. 7) is either an object on the road — the surface beyond
//!    it comes back to the reference level: keep its points at road level (eq. 9) — or the
//!    road edge: the points above the reference level mark the curb and everything from the
//!    innermost of them outward is cut (eq. 8), and with it an `edge_margin_m` strip in
//!    front of it (the face's foot: bright returns at road height); the walk stops. A window whose level steps
//!    by more than the road thickness (plus `max_cross_slope` times the distance) also ends
//!    the road, and so does a gap without points wider than `max_gap_m`. The road thickness
//!    is `road_thickness_m`, raised to 1.5 × the median window thickness of the slice when
//!    the scanner is noisier than that. A window's ground (the centre of its buffer) is the
//!    lowest band of its pseudo points holding a fifth of them, so a tree canopy or a car
//!    body over most of its bins does not lift it; and the foot of any face standing on
//!    the road (a parked car's side, a bollard) is cut within `edge_margin_m` like a curb's.
//!
//! Nothing depends on the order of the points, so interleaved scanner heads are fine.
//!
//! `method: "scan_lines"` is the scan-line method of Yao et al. 2021 (see
//! [`super::pavement_scanline`]) for single-head data in acquisition order;
//! `method: "none"` keeps every point (input already cut to the road).
//!
//! Where the asphalt ends at a verge instead of a curb, the verge's first strip survives
//! these tests (it is nearly flat and at road height); once the marking candidates are
//! known, [`super::pavement_verge`] (`verge` parameters) clears those that lie below the
//! asphalt beside them.
//!
//! **Parameters** ([`Params`], defaults): `slice_length_m` 2.0 (paper D), `pseudo_bin_m`
//! 0.05 (paper W), `ransac_iterations` 200, `ransac_tolerance_m` 0.04, `buffer_below_m`
//! 0.3, `buffer_above_m` 0.3, `window_m` 0.4 (paper), `road_thickness_m` 0.06,
//! `max_cross_slope` 0.1, `max_gap_m` 3.0, `max_offset_m` 30, `reenter` true,
//! `reentry_min_width_m` 3, `reentry_min_separation_m` 1, `reentry_max_step_m` 1,
//! `edge_margin_m` 0.05 (points this close to the face of a curb, barrier or object on the
//! road are cut with it),
//! `seed` 0; `verge` (nested, see [`super::pavement_verge`]).
//!
//! **Reference.** Yao L., Qin C., Chen Q., Wu H., Zhang S. (2019) Automatic extraction and
//! recognition of road markings based on vehicle laser point cloud, ISPRS Archives.
//!
//! **Complexity.** O(n log n) overall (quantiles per window), parallel over slices; RANSAC
//! stops adaptively once the inlier ratio makes a better plane unlikely.

use super::geom::floor_i64;
use super::{pavement_scanline, pavement_verge};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Which pavement method runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// Mileage slices + RANSAC + moving window (Yao 2019). Order-independent.
    #[default]
    Slices,
    /// Scan lines from acquisition order (Yao 2021). Single head, points in order.
    ScanLines,
    /// Keep every point.
    None,
}

/// Parameters of this stage (JSON object `pavement` in the job parameters).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Params {
    pub method: Method,
    /// Slice length along the trajectory (m). Paper D = 2.
    pub slice_length_m: f64,
    /// Interval of the pseudo scan line across the road (m). Paper W = 0.05.
    pub pseudo_bin_m: f64,
    /// Maximum RANSAC iterations per slice.
    pub ransac_iterations: u32,
    /// RANSAC inlier distance (m).
    pub ransac_tolerance_m: f64,
    /// Buffer below / above the fitted road plane (m).
    pub buffer_below_m: f64,
    pub buffer_above_m: f64,
    /// Moving-window width across the road (m). Paper: 0.4.
    pub window_m: f64,
    /// Height range above which a window holds more than road surface (m).
    pub road_thickness_m: f64,
    /// Allowed change of cross slope between windows (m per m).
    pub max_cross_slope: f64,
    /// Widest gap without points that the road may continue across (m).
    pub max_gap_m: f64,
    /// Points farther than this from the trajectory are never road (m).
    pub max_offset_m: f64,
    /// Look for a second carriageway beyond the road edge (a median, barrier or occlusion).
    pub reenter: bool,
    /// A flat strip at least this wide (m) (or 1.6 m when it continues the road's plane:
    /// the rest of a lane seen past a vehicle) …
    pub reentry_min_width_m: f64,
    /// … at least this far (m) beyond the edge, with no flat strip in between (a sidewalk;
    /// a flat strip more than 0.35 m above the road — a barrier top, a vehicle's roof — is
    /// none) …
    pub reentry_min_separation_m: f64,
    /// … and within this height (m) of the road is road again.
    pub reentry_max_step_m: f64,
    /// Where the road ends at a curb, barrier or wall, points closer than this (m) to the
    /// innermost point above the road are cut too: the foot of a vertical face scatters
    /// bright returns at road height within the scanner's noise of the face, and paint is
    /// never that close to it. 0 keeps everything up to the face.
    pub edge_margin_m: f64,
    /// Seed of the per-slice RANSAC generators.
    pub seed: u64,
    /// Parameters of the scan-line method (`method: "scan_lines"`).
    pub scan_lines: pavement_scanline::Params,
    /// Bright verge strips beyond the asphalt, cleared after thresholding (see
    /// [`super::pavement_verge`]).
    pub verge: pavement_verge::Params,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            method: Method::Slices,
            slice_length_m: 2.0,
            pseudo_bin_m: 0.05,
            ransac_iterations: 200,
            ransac_tolerance_m: 0.04,
            buffer_below_m: 0.3,
            buffer_above_m: 0.3,
            window_m: 0.4,
            road_thickness_m: 0.06,
            max_cross_slope: 0.1,
            max_gap_m: 3.0,
            max_offset_m: 30.0,
            reenter: true,
            reentry_min_width_m: 3.0,
            reentry_min_separation_m: 1.0,
            reentry_max_step_m: 1.0,
            edge_margin_m: 0.05,
            seed: 0,
            scan_lines: pavement_scanline::Params::default(),
            verge: pavement_verge::Params::default(),
        }
    }
}

pub(crate) fn check_range(name: &str, v: f64, lo: f64, hi: f64) -> Result<(), String> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(format!("{name}: must be within {lo}..={hi}, got {v}"))
    }
}

impl Params {
    /// Check every field; the message names the offending parameter.
    pub fn validate(&self) -> Result<(), String> {
        check_range("slice_length_m", self.slice_length_m, 0.1, 50.0)?;
        check_range("pseudo_bin_m", self.pseudo_bin_m, 0.005, 1.0)?;
        if !(1..=100_000).contains(&self.ransac_iterations) {
            return Err(format!(
                "ransac_iterations: must be within 1..=100000, got {}",
                self.ransac_iterations
            ));
        }
        check_range("ransac_tolerance_m", self.ransac_tolerance_m, 0.001, 1.0)?;
        check_range("buffer_below_m", self.buffer_below_m, 0.0, 10.0)?;
        check_range("buffer_above_m", self.buffer_above_m, 0.0, 10.0)?;
        check_range("window_m", self.window_m, 0.05, 5.0)?;
        check_range("road_thickness_m", self.road_thickness_m, 0.001, 1.0)?;
        check_range("max_cross_slope", self.max_cross_slope, 0.0, 1.0)?;
        check_range("max_gap_m", self.max_gap_m, 0.0, 50.0)?;
        check_range("max_offset_m", self.max_offset_m, 1.0, 500.0)?;
        check_range("reentry_min_width_m", self.reentry_min_width_m, 0.1, 100.0)?;
        check_range(
            "reentry_min_separation_m",
            self.reentry_min_separation_m,
            0.0,
            100.0,
        )?;
        check_range("reentry_max_step_m", self.reentry_max_step_m, 0.0, 100.0)?;
        check_range("edge_margin_m", self.edge_margin_m, 0.0, 2.0)?;
        self.scan_lines
            .validate()
            .map_err(|e| format!("scan_lines.{e}"))?;
        self.verge.validate().map_err(|e| format!("verge.{e}"))
    }
}

/// Points of one chunk as the pavement stage sees them.
pub struct Input<'a> {
    pub x: &'a [f64],
    pub y: &'a [f64],
    pub z: &'a [f64],
    /// Mileage along the trajectory (m), and signed lateral offset (m, left positive).
    pub mileage: &'a [f64],
    pub offset: &'a [f64],
    /// GPS time, when known (the scan-line method orders by it).
    pub gps_time: Option<&'a [f64]>,
    pub scanner: &'a [u8],
}

/// Global slice index of a mileage.
#[inline]
pub fn slice_of(mileage: f64, slice_length_m: f64) -> i64 {
    floor_i64(mileage / slice_length_m)
}

/// Indices (ascending) of the pavement points.
pub fn run(input: &Input<'_>, p: &Params) -> Vec<usize> {
    match p.method {
        Method::None => (0..input.z.len()).collect(),
        Method::ScanLines => pavement_scanline::run(input, &p.scan_lines, p.max_offset_m),
        Method::Slices => run_slices(input, p),
    }
}

fn run_slices(input: &Input<'_>, p: &Params) -> Vec<usize> {
    let n = input.z.len();
    if n == 0 {
        return Vec::new();
    }
    // Counting sort of the point indices by slice.
    let slice: Vec<i64> = input
        .mileage
        .iter()
        .map(|&m| slice_of(m, p.slice_length_m))
        .collect();
    let s0 = *slice.iter().min().expect("non-empty");
    let s1 = *slice.iter().max().expect("non-empty");
    let ns = (s1 - s0 + 1) as usize;
    let mut start = vec![0usize; ns + 1];
    for &s in &slice {
        start[(s - s0) as usize + 1] += 1;
    }
    for k in 0..ns {
        start[k + 1] += start[k];
    }
    let mut fill = start.clone();
    let mut order = vec![0usize; n];
    for (i, &s) in slice.iter().enumerate() {
        let k = (s - s0) as usize;
        order[fill[k]] = i;
        fill[k] += 1;
    }
    let kept: Vec<Vec<usize>> = (0..ns)
        .into_par_iter()
        .map(|k| {
            let idx = &order[start[k]..start[k + 1]];
            let gs = s0 + k as i64;
            slice_pavement(idx, input, gs as f64 * p.slice_length_m, gs, p)
        })
        .collect();
    // Each point is in one slice, so the kept indices are distinct: a flag per point
    // puts them in ascending order in O(n) (instead of sorting them).
    let mut flag = vec![false; n];
    for &i in kept.iter().flatten() {
        debug_assert!(!flag[i], "point {i} kept twice");
        flag[i] = true;
    }
    (0..n).filter(|&i| flag[i]).collect()
}

/// Quantile of a scratch slice (reorders it).
fn quantile(v: &mut [f64], q: f64) -> f64 {
    let k = ((v.len() - 1) as f64 * q).round() as usize;
    *v.select_nth_unstable_by(k, f64::total_cmp).1
}

/// The ground of a window from its pseudo scan points (lowest points per bin): the median
/// of the lowest band `band` high that holds at least a fifth of them (and two). Where a
/// tree canopy, a wall's overhang or a car body hides most bins, their lowest points are up
/// there; the plain median would put the ground there too and end the road under a tree.
/// A lone low outlier (multipath) does not make a band. Reorders `v`.
fn lowest_level(v: &mut [f64], band: f64) -> f64 {
    v.sort_unstable_by(f64::total_cmp);
    let need = v.len().div_ceil(5).max(2).min(v.len());
    let mut hi = 0;
    for lo in 0..v.len() {
        while hi < v.len() && v[hi] <= v[lo] + band {
            hi += 1;
        }
        if hi - lo >= need {
            return v[lo + (hi - lo) / 2];
        }
    }
    v[v.len() / 2]
}

/// A fitted road plane z = a + b·u + c·s.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    pub a: f64,
    pub b: f64,
    pub c: f64,
}

impl Plane {
    #[inline]
    pub fn at(&self, u: f64, s: f64) -> f64 {
        self.a + self.b * u + self.c * s
    }
}

/// Least-squares plane through points (u, s, z); `None` when degenerate. The grade term
/// is dropped (c = 0) when the points do not spread along s.
pub(crate) fn lsq_plane(pts: &[[f64; 3]]) -> Option<Plane> {
    let n = pts.len() as f64;
    if pts.len() < 2 {
        return None;
    }
    let (mu, ms, mz) = pts
        .iter()
        .fold((0.0, 0.0, 0.0), |a, p| (a.0 + p[0], a.1 + p[1], a.2 + p[2]));
    let (mu, ms, mz) = (mu / n, ms / n, mz / n);
    let (mut suu, mut sss, mut sus, mut suz, mut ssz) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for p in pts {
        let (du, ds, dz) = (p[0] - mu, p[1] - ms, p[2] - mz);
        suu += du * du;
        sss += ds * ds;
        sus += du * ds;
        suz += du * dz;
        ssz += ds * dz;
    }
    let det = suu * sss - sus * sus;
    let (b, c) = if sss > 1e-6 * n && det.abs() > 1e-9 * (suu * sss).max(1e-12) {
        ((suz * sss - ssz * sus) / det, (ssz * suu - suz * sus) / det)
    } else if suu > 1e-12 {
        (suz / suu, 0.0)
    } else {
        return None;
    };
    Some(Plane {
        a: mz - b * mu - c * ms,
        b,
        c,
    })
}

/// Plane through three points; `None` when they are (nearly) collinear in (u, s).
fn plane3(p: &[f64; 3], q: &[f64; 3], r: &[f64; 3]) -> Option<Plane> {
    let (u1, s1, z1) = (q[0] - p[0], q[1] - p[1], q[2] - p[2]);
    let (u2, s2, z2) = (r[0] - p[0], r[1] - p[1], r[2] - p[2]);
    let det = u1 * s2 - u2 * s1;
    if det.abs() < 1e-4 {
        return None;
    }
    let b = (z1 * s2 - z2 * s1) / det;
    let c = (u1 * z2 - u2 * z1) / det;
    Some(Plane {
        a: p[2] - b * p[0] - c * p[1],
        b,
        c,
    })
}

/// RANSAC plane through pseudo scan points, refined on its inliers.
pub fn ransac_plane(pts: &[[f64; 3]], iterations: u32, tol: f64, seed: u64) -> Option<Plane> {
    if pts.len() < 3 {
        return lsq_plane(pts);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let count = |pl: &Plane| {
        pts.iter()
            .filter(|p| (p[2] - pl.at(p[0], p[1])).abs() <= tol)
            .count()
    };
    let mut best: Option<(usize, Plane)> = None;
    let mut needed = iterations as f64;
    let mut it = 0u32;
    while (it as f64) < needed && it < iterations {
        it += 1;
        let i = rng.random_range(0..pts.len());
        let j = rng.random_range(0..pts.len());
        let k = rng.random_range(0..pts.len());
        // A line in u is a valid road model when the slice has no spread along s.
        let cand = plane3(&pts[i], &pts[j], &pts[k]).or_else(|| {
            let (p, q) = (&pts[i], &pts[j]);
            let du = q[0] - p[0];
            (du.abs() > 1e-3).then(|| {
                let b = (q[2] - p[2]) / du;
                Plane {
                    a: p[2] - b * p[0],
                    b,
                    c: 0.0,
                }
            })
        });
        let Some(pl) = cand else { continue };
        // A road plane is never steeper than 45°: skip walls and trees.
        if pl.b.abs() > 1.0 || pl.c.abs() > 1.0 {
            continue;
        }
        let c = count(&pl);
        if best.as_ref().is_none_or(|(bc, _)| c > *bc) {
            best = Some((c, pl));
            // Adaptive termination: iterations for 99 % confidence at this inlier ratio.
            let w = c as f64 / pts.len() as f64;
            let miss = 1.0 - w * w * w;
            if miss <= 1e-12 {
                needed = 0.0;
            } else {
                needed = ((0.01f64).ln() / miss.ln()).ceil().max(10.0);
            }
        }
    }
    let (_, pl) = best?;
    let inliers: Vec<[f64; 3]> = pts
        .iter()
        .filter(|p| (p[2] - pl.at(p[0], p[1])).abs() <= tol)
        .copied()
        .collect();
    lsq_plane(&inliers).or(Some(pl))
}

/// Per-window summary of the buffered points.
#[derive(Clone, Debug)]
struct Window {
    /// Indices (into the slice's buffered points) of the window's points.
    members: Vec<usize>,
    level: f64,
    thick: f64,
}

/// A flat strip beyond the road edge is a sidewalk or verge — beyond which no second
/// carriageway is sought — only when at most this far (m) above the road (curbs are
/// 0.1–0.3 m high; any strip below the road, a ditch or an embankment, counts too).
/// Higher flat strips are the tops of median barriers (0.8–1.1 m) or the hood and roof of
/// a vehicle beside the scanner, and the road goes on beyond them.
const SIDEWALK_MAX_STEP_M: f64 = 0.35;

/// Narrowest flat strip beyond the edge that counts as a sidewalk or verge (m).
const SIDEWALK_MIN_WIDTH_M: f64 = 0.8;

/// Whether a flat strip `width` m wide at `level`, beside road at `road_level`, is a
/// sidewalk or verge (see [`SIDEWALK_MAX_STEP_M`]).
fn sidewalk(width: f64, level: f64, road_level: f64) -> bool {
    width >= SIDEWALK_MIN_WIDTH_M && level - road_level <= SIDEWALK_MAX_STEP_M
}

/// Beyond an occlusion, a flat strip narrower than `reentry_min_width_m` but at least this
/// wide (m) is road again when its level continues the road's plane within the road
/// thickness plus [`NARROW_REENTRY_SLOPE`] × its distance from the road edge: the rest of
/// a lane seen past a vehicle, between the vehicle's shadow and a curb.
const NARROW_REENTRY_MIN_WIDTH_M: f64 = 1.6;
/// Cross-slope change (m per m) allowed between the road and such a strip.
const NARROW_REENTRY_SLOPE: f64 = 0.02;

fn slice_pavement(idx: &[usize], input: &Input<'_>, s_start: f64, slice_id: i64, p: &Params) -> Vec<usize> {
    // Cross-section coordinates: u across, s along (from the slice start), z up.
    let pts: Vec<(usize, f64, f64, f64)> = idx
        .iter()
        .filter(|&&i| input.offset[i].abs() <= p.max_offset_m)
        .map(|&i| (i, input.offset[i], input.mileage[i] - s_start, input.z[i]))
        .collect();
    if pts.len() < 3 {
        return Vec::new();
    }
    // 1. Pseudo scan points: lowest per (u interval, 0.5 m sub-slice).
    let sub = (p.slice_length_m / 0.5).round().max(1.0);
    let sub_len = p.slice_length_m / sub;
    let ub = |u: f64| floor_i64(u / p.pseudo_bin_m);
    let u_lo = pts.iter().map(|t| ub(t.1)).min().expect("non-empty");
    let u_hi = pts.iter().map(|t| ub(t.1)).max().expect("non-empty");
    let nu = (u_hi - u_lo + 1) as usize;
    let nsub = sub as usize;
    let mut lowest: Vec<Option<[f64; 3]>> = vec![None; nu * nsub];
    for &(_, u, s, z) in &pts {
        let k = (floor_i64(s / sub_len).clamp(0, nsub as i64 - 1) as usize) * nu + (ub(u) - u_lo) as usize;
        if lowest[k].is_none_or(|l| z < l[2]) {
            lowest[k] = Some([u, s, z]);
        }
    }
    let pseudo: Vec<[f64; 3]> = lowest.into_iter().flatten().collect();
    // 2. RANSAC plane: heights become residuals above the road plane (grade and cross
    //    slope removed).
    let seed = p.seed ^ (slice_id as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    let Some(plane) = ransac_plane(&pseudo, p.ransac_iterations, p.ransac_tolerance_m, seed) else {
        return Vec::new();
    };
    let res: Vec<(usize, f64, f64)> = pts
        .iter()
        .map(|&(i, u, s, z)| (i, u, z - plane.at(u, s)))
        .collect();
    // 3. Moving windows, centred on the trajectory (window 0 holds u ∈ [-w/2, w/2)).
    let wi = |u: f64| floor_i64(u / p.window_m + 0.5);
    let w_lo = res.iter().map(|t| wi(t.1)).min().expect("non-empty");
    let w_hi = res.iter().map(|t| wi(t.1)).max().expect("non-empty");
    let nw = (w_hi - w_lo + 1) as usize;
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); nw];
    for (k, t) in res.iter().enumerate() {
        members[(wi(t.1) - w_lo) as usize].push(k);
    }
    let mut ground_of: Vec<Vec<f64>> = vec![Vec::new(); nw];
    for q in &pseudo {
        ground_of[(wi(q[0]) - w_lo) as usize].push(q[2] - plane.at(q[0], q[1]));
    }
    // Per window: the ground is the lowest band of its lowest points (`lowest_level`); the buffer keeps the points
    // from `buffer_below_m` under to `buffer_above_m` over it (the paper's buffer, made
    // local so that a far carriageway at another height is not cut away).
    let mut windows: Vec<Window> = Vec::with_capacity(nw);
    let mut scratch = Vec::new();
    let mut thicknesses = Vec::new();
    for (w, mem) in members.iter().enumerate() {
        let mut win = Window {
            members: Vec::new(),
            level: 0.0,
            thick: 0.0,
        };
        if !ground_of[w].is_empty() {
            let ground = lowest_level(&mut ground_of[w], p.buffer_above_m);
            win.members = mem
                .iter()
                .copied()
                .filter(|&k| res[k].2 >= ground - p.buffer_below_m && res[k].2 <= ground + p.buffer_above_m)
                .collect();
        }
        if !win.members.is_empty() {
            scratch.clear();
            scratch.extend(win.members.iter().map(|&k| res[k].2));
            let lo = quantile(&mut scratch, 0.1);
            let hi = quantile(&mut scratch, 0.9);
            win.level = lo;
            win.thick = hi - lo;
            thicknesses.push(win.thick);
        }
        windows.push(win);
    }
    let thickness = if thicknesses.is_empty() {
        p.road_thickness_m
    } else {
        p.road_thickness_m.max(1.5 * quantile(&mut thicknesses, 0.5))
    };

    let mut keep: Vec<usize> = Vec::new();
    let get = |w: i64| -> Option<&Window> {
        (w >= w_lo && w <= w_hi)
            .then(|| &windows[(w - w_lo) as usize])
            .filter(|x| !x.members.is_empty())
    };
    let max_w = (p.max_offset_m / p.window_m).ceil() as i64 + 1;
    let in_range = |k: i64| k.abs() <= max_w && k >= w_lo - 1 && k <= w_hi + 1;
    let flat = |w: &Window| w.thick <= thickness;
    let near = |r: f64, lvl: f64| (r - lvl).abs() <= thickness;
    // `keep` holds indices into `res`; `taken[w]` the level window `w` was taken at.
    let mut taken = vec![f64::NAN; nw];
    let take = |k: i64, lvl: f64, keep: &mut Vec<usize>, taken: &mut [f64]| {
        let w = (k - w_lo) as usize;
        taken[w] = lvl;
        keep.extend(
            windows[w]
                .members
                .iter()
                .copied()
                .filter(|&m| near(res[m].2, lvl)),
        );
    };
    // Reference level: the window under the vehicle when it is flat, else the plane.
    let base = get(0).filter(|w| flat(w)).map(|w| w.level).unwrap_or(0.0);
    for dir in [1i64, -1] {
        let mut prev = base;
        let mut gap = 0.0;
        let mut k: i64 = if dir == 1 { 0 } else { -1 };
        let mut on_road = true;
        // Off the road: the last road window, the current flat run, and whether a flat
        // strip was already crossed (a sidewalk: then no second carriageway is sought).
        let mut last_road = 0i64;
        let mut run: Vec<i64> = Vec::new();
        let mut run_prev = 0.0;
        let mut run_gap = 0.0;
        let mut crossed_flat = false;
        while in_range(k) {
            let here = get(k);
            if !on_road {
                match here {
                    Some(w) if flat(w) => {
                        let allow = thickness + p.max_cross_slope * (run_gap + p.window_m);
                        if run.is_empty() || (w.level - run_prev).abs() > allow {
                            run.clear();
                        }
                        run.push(k);
                        run_prev = w.level;
                        run_gap = 0.0;
                        let width = ((k - run[0]).abs() + 1) as f64 * p.window_m;
                        let separation = ((run[0] - last_road).abs() - 1) as f64 * p.window_m;
                        // A narrower strip is road too when it continues the road's own
                        // plane (the lane beyond a vehicle, up to the next curb).
                        let in_plane = (w.level - prev).abs()
                            <= thickness + NARROW_REENTRY_SLOPE * (k - last_road).abs() as f64 * p.window_m;
                        let wide_enough =
                            width >= p.reentry_min_width_m || width >= NARROW_REENTRY_MIN_WIDTH_M && in_plane;
                        if wide_enough
                            && separation >= p.reentry_min_separation_m
                            && !crossed_flat
                            && (w.level - prev).abs() <= p.reentry_max_step_m
                        {
                            // A second carriageway beyond a median: road again.
                            for &j in &run {
                                let wj = get(j).expect("run windows are non-empty");
                                take(j, wj.level, &mut keep, &mut taken);
                            }
                            run.clear();
                            on_road = true;
                            prev = w.level;
                            gap = 0.0;
                        } else if separation < p.reentry_min_separation_m && sidewalk(width, w.level, prev) {
                            crossed_flat = true;
                        }
                    }
                    Some(_) => {
                        if sidewalk(run.len() as f64 * p.window_m, run_prev, prev) {
                            crossed_flat = true;
                        }
                        run.clear();
                    }
                    None => {
                        run_gap += p.window_m;
                        if run_gap > p.max_gap_m {
                            run.clear();
                        }
                    }
                }
                if !p.reenter {
                    break;
                }
                k += dir;
                continue;
            }
            let Some(w) = here else {
                gap += p.window_m;
                if gap > p.max_gap_m {
                    on_road = false;
                    last_road = k;
                }
                k += dir;
                continue;
            };
            let allowance = thickness + p.max_cross_slope * (gap + p.window_m);
            if (w.level - prev).abs() > allowance {
                // The surface steps up (sidewalk) or down (ditch): end of this road.
                on_road = false;
                last_road = k - dir;
                continue; // re-examine this window off the road
            }
            if flat(w) {
                take(k, w.level, &mut keep, &mut taken);
                prev = w.level;
                gap = 0.0;
                k += dir;
                continue;
            }
            // Key window: interior obstacle or road edge? Look for the next flat window.
            let mut j = k + dir;
            let mut look_gap = 0.0;
            let mut returns = false;
            while look_gap <= p.max_gap_m && in_range(j) {
                match get(j) {
                    Some(x) if flat(x) => {
                        let allow =
                            thickness + p.max_cross_slope * (look_gap + p.window_m * (j - k).abs() as f64);
                        returns = (x.level - prev).abs() <= allow;
                        break;
                    }
                    _ => look_gap += p.window_m,
                }
                j += dir;
            }
            if returns {
                take(k, prev, &mut keep, &mut taken);
                gap = 0.0;
                k += dir;
                continue;
            }
            // Edge: cut at the innermost point clearly above the road (eq. 8).
            let high = w
                .members
                .iter()
                .filter(|&&m| res[m].2 > prev + thickness)
                .map(|&m| res[m].1);
            let cut = if dir == 1 {
                high.fold(f64::INFINITY, f64::min)
            } else {
                high.fold(f64::NEG_INFINITY, f64::max)
            };
            keep.extend(w.members.iter().filter(|&&m| {
                let (_, u, r) = res[m];
                near(r, prev)
                    && if dir == 1 {
                        u < cut - p.edge_margin_m
                    } else {
                        u > cut + p.edge_margin_m
                    }
            }));
            taken[(k - w_lo) as usize] = prev;
            on_road = false;
            last_road = k;
            k += dir;
        }
    }
    if p.edge_margin_m > 0.0 {
        drop_feet(
            &mut keep,
            &windows,
            &taken,
            &res,
            &pts,
            thickness,
            p.edge_margin_m,
        );
    }
    keep.into_iter().map(|m| res[m].0).collect()
}

/// Most cells across the faces' span in [`drop_feet`] (bounds its lookup table).
const MAX_FACE_CELLS: usize = 1 << 16;

/// The foot of any vertical face standing on the road (a parked car's side, a bollard, a
/// trunk, the end of a barrier), not only of the face that ends the walk: points within
/// `margin` (in the road plane) of a point clearly above the level its window was taken
/// at (or a taken neighbour's) are cut. They scatter at road height within the scanner's
/// noise of the face and are as bright as the face, not paint. `keep` indexes `res`/`pts`.
fn drop_feet(
    keep: &mut Vec<usize>,
    windows: &[Window],
    taken: &[f64],
    res: &[(usize, f64, f64)],
    pts: &[(usize, f64, f64, f64)],
    thickness: f64,
    margin: f64,
) {
    let level = |w: usize| {
        let own = taken[w];
        if !own.is_nan() {
            return Some(own);
        }
        [w.wrapping_sub(1), w + 1]
            .into_iter()
            .filter_map(|j| taken.get(j).copied())
            .find(|l| !l.is_nan())
    };
    // (u cell, s, u) of the face points, ordered by cell then s: a query looks at the
    // cells of u - margin ..= u + margin only, each by binary search on s (a face beside
    // the road holds thousands of points per slice, all at the same s as the road).
    let mut high: Vec<(i64, f64, f64)> = Vec::new();
    for (w, win) in windows.iter().enumerate() {
        let Some(lvl) = level(w) else { continue };
        high.extend(
            win.members
                .iter()
                .filter(|&&m| res[m].2 > lvl + thickness)
                .map(|&m| (0, pts[m].2, res[m].1)),
        );
    }
    if high.is_empty() {
        return;
    }
    // Cells at least `margin` wide (the three around a point's cover its reach), and no
    // more than MAX_FACE_CELLS across the faces' span whatever the margin.
    let (u_lo, u_hi) = high.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), h| {
        (a.min(h.2), b.max(h.2))
    });
    let width = margin.max((u_hi - u_lo) / MAX_FACE_CELLS as f64);
    let cell = |u: f64| ((u - u_lo) / width).floor() as i64;
    for h in high.iter_mut() {
        h.0 = cell(h.2);
    }
    high.sort_unstable_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
    // start[k]: the first face point in a cell >= k (cell k spans start[k]..start[k + 1]).
    // A table, so a road point far from every face, the common case, is passed over by
    // three lookups instead of three binary searches over all the faces' points (pavement
    // stage -25 % on a 1 km simulated drive).
    let c_hi = high[high.len() - 1].0;
    let mut start = vec![high.len(); (c_hi + 2) as usize];
    let mut next = 0;
    for (i, h) in high.iter().enumerate() {
        while next <= h.0 as usize {
            start[next] = i;
            next += 1;
        }
    }
    let cell_range = |b: i64| {
        if b < 0 || b > c_hi {
            return &high[0..0];
        }
        &high[start[b as usize]..start[b as usize + 1]]
    };
    let m2 = margin * margin;
    keep.retain(|&m| {
        let (s, u) = (pts[m].2, res[m].1);
        let c = cell(u);
        !(c - 1..=c + 1).any(|b| {
            let faces = cell_range(b);
            let from = faces.partition_point(|h| h.1 < s - margin);
            faces[from..]
                .iter()
                .take_while(|h| h.1 <= s + margin)
                .any(|h| (h.1 - s).powi(2) + (h.2 - u).powi(2) <= m2)
        })
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The cell-bucketed search drops exactly the points a scan of every face point
    /// would: random faces and road points, windows with and without a level.
    #[test]
    fn drop_feet_equals_the_exhaustive_search() {
        let mut jit = crate::pipeline::geom::test_jitter(7);
        let n = 3000;
        // pts: (_, _, s, _); res: (_, u, r)
        let pts: Vec<(usize, f64, f64, f64)> = (0..n).map(|i| (i, 0.0, 1.0 + jit(), 0.0)).collect();
        let res: Vec<(usize, f64, f64)> = (0..n)
            .map(|i| {
                (
                    i,
                    3.0 * jit(),
                    if i % 7 == 0 {
                        0.5 + jit().abs()
                    } else {
                        0.01 * jit()
                    },
                )
            })
            .collect();
        let windows: Vec<Window> = (0..6)
            .map(|w| Window {
                members: (0..n).filter(|i| i % 6 == w).collect(),
                level: 0.0,
                thick: 0.0,
            })
            .collect();
        let taken = [0.0, f64::NAN, 0.0, 0.02, f64::NAN, f64::NAN];
        // 5e-5 m: more cells across the faces than MAX_FACE_CELLS, so they are widened.
        for margin in [0.05, 5e-5] {
            check_drop_feet(&pts, &res, &windows, &taken, margin);
        }
    }

    fn check_drop_feet(
        pts: &[(usize, f64, f64, f64)],
        res: &[(usize, f64, f64)],
        windows: &[Window],
        taken: &[f64],
        margin: f64,
    ) {
        let n = pts.len();
        let thickness = 0.1;
        let mut keep: Vec<usize> = (0..n).filter(|i| i % 7 != 0).collect();
        let before = keep.clone();
        drop_feet(&mut keep, windows, taken, res, pts, thickness, margin);
        // Exhaustive: the face points are those above their window's level (own, else a
        // neighbour's), as drop_feet defines them.
        let level = |w: usize| {
            [w, w.wrapping_sub(1), w + 1]
                .into_iter()
                .filter_map(|j| taken.get(j).copied())
                .find(|l| !l.is_nan())
        };
        let high: Vec<usize> = (0..6)
            .filter_map(|w| level(w).map(|l| (w, l)))
            .flat_map(|(w, l)| {
                let res = &res;
                windows[w]
                    .members
                    .iter()
                    .copied()
                    .filter(move |&m| res[m].2 > l + thickness)
            })
            .collect();
        let expect: Vec<usize> = before
            .into_iter()
            .filter(|&m| {
                !high.iter().any(|&h| {
                    (pts[h].2 - pts[m].2).powi(2) + (res[h].1 - res[m].1).powi(2) <= margin * margin
                })
            })
            .collect();
        assert!(expect.len() > 100);
        if margin > 0.01 {
            assert!(expect.len() < n * 6 / 7, "some road points must be feet");
        }
        assert_eq!(keep, expect, "margin {margin}");
    }

    /// A 10 m stretch of road (u ∈ [-3, 4)) with a 2 % cross slope and a 3 % grade; a
    /// 0.15 m curb at u = 4 with sidewalk beyond; a 0.2 m high box on the road; a 0.2 m
    /// barrier at u ∈ [-3.2, -3.0] with an embankment 0.25 m lower behind it and a wall at
    /// u < -5. Points on a jittered 2.5 cm grid, deterministic.
    fn scene() -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<bool>) {
        let (mut m, mut u, mut z, mut road) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let mut jit = crate::pipeline::geom::test_jitter(0);
        for i in 0..400 {
            for j in 0..500 {
                let mm = i as f64 * 0.025 + 0.01 * jit();
                let uu = -5.5 + j as f64 * 0.025 + 0.01 * jit();
                let ground = 0.02 * uu + 0.03 * mm + 0.005 * jit();
                let (zz, is_road) = if uu < -5.0 {
                    (ground + 1.0 + 2.0 * jit().abs(), false)
                } else if uu < -3.2 {
                    (ground - 0.25, false)
                } else if uu < -3.0 || ((-2.2..-1.8).contains(&uu) && (4.0..5.0).contains(&mm)) {
                    // The curb, and an object on the road.
                    (ground + 0.2, false)
                } else if uu < 4.0 {
                    (ground, true)
                } else {
                    (ground + 0.15, false)
                };
                m.push(mm);
                u.push(uu);
                z.push(zz);
                road.push(is_road);
            }
        }
        (m, u, z, road)
    }

    fn run_on(m: &[f64], u: &[f64], z: &[f64], p: &Params) -> Vec<usize> {
        let zeros = vec![0.0; m.len()];
        let heads = vec![0u8; m.len()];
        run(
            &Input {
                x: &zeros,
                y: &zeros,
                z,
                mileage: m,
                offset: u,
                gps_time: None,
                scanner: &heads,
            },
            p,
        )
    }

    /// A flat road (u ∈ [-2, 3)) ending at a vertical wall at u = 3 whose face scatters
    /// returns ±1.5 cm across it from road height up to 1 m: the face's foot is at road
    /// level and must go with the wall, the road in front of it must stay.
    #[test]
    fn the_foot_of_a_wall_is_cut_with_it() {
        let (mut m, mut u, mut z) = (Vec::new(), Vec::new(), Vec::new());
        let mut jit = crate::pipeline::geom::test_jitter(7);
        for i in 0..200 {
            let mm = i as f64 * 0.05;
            for j in 0..200 {
                m.push(mm + 0.01 * jit());
                u.push(-2.0 + j as f64 * 0.025 + 0.005 * jit());
                z.push(0.004 * jit());
            }
            for h in 0..40 {
                m.push(mm + 0.01 * jit());
                u.push(3.0 + 0.03 * jit());
                z.push(h as f64 * 0.025 + 0.004 * jit());
            }
        }
        let count = |p: &Params| {
            let kept = run_on(&m, &u, &z, p);
            let foot = kept.iter().filter(|&&i| u[i] > 2.97).count();
            let road = kept.iter().filter(|&&i| u[i] < 2.9).count();
            (foot, road)
        };
        let road_total = u.iter().filter(|&&v| v < 2.9).count();
        let (foot, road) = count(&Params::default());
        assert_eq!(foot, 0, "points of the wall's foot kept as road");
        assert!(
            road as f64 > 0.99 * road_total as f64,
            "road kept: {road} of {road_total}"
        );
        // Without the margin the foot comes through: the test sees the difference.
        let (foot0, _) = count(&Params {
            edge_margin_m: 0.0,
            ..Params::default()
        });
        assert!(foot0 > 0, "the scene has no foot points to cut");
    }

    /// A flat road (u ∈ [-2, 8)) under a tree canopy 5 m up over u ∈ [4, 7] that hides the
    /// ground of most pseudo-scan bins there (one ground return in six canopy returns): the
    /// road under and beyond the canopy is still road, the canopy is not.
    #[test]
    fn the_road_under_a_tree_canopy_is_kept() {
        let (mut m, mut u, mut z) = (Vec::new(), Vec::new(), Vec::new());
        let mut jit = crate::pipeline::geom::test_jitter(11);
        for i in 0..200 {
            let mm = i as f64 * 0.05;
            for j in 0..400 {
                let uu = -2.0 + j as f64 * 0.025 + 0.005 * jit();
                let under = (4.0..7.0).contains(&uu);
                if under && j % 6 != 0 {
                    m.push(mm + 0.01 * jit());
                    u.push(uu);
                    z.push(5.0 + 0.3 * jit().abs());
                    continue;
                }
                m.push(mm + 0.01 * jit());
                u.push(uu);
                z.push(0.004 * jit());
            }
        }
        let kept = run_on(&m, &u, &z, &Params::default());
        let canopy = kept.iter().filter(|&&i| z[i] > 1.0).count();
        let beyond = kept.iter().filter(|&&i| u[i] > 7.2 && z[i] < 1.0).count();
        let under = kept
            .iter()
            .filter(|&&i| (4.0..7.0).contains(&u[i]) && z[i] < 1.0)
            .count();
        let total =
            |r: std::ops::Range<f64>| (0..u.len()).filter(|&i| r.contains(&u[i]) && z[i] < 1.0).count();
        assert_eq!(canopy, 0, "canopy points kept as road");
        assert!(
            under as f64 > 0.95 * total(4.0..7.0) as f64,
            "under the canopy: {under}"
        );
        assert!(
            beyond as f64 > 0.95 * total(7.2..9.0) as f64,
            "beyond the canopy: {beyond}"
        );
    }

    /// A box 1.5 m high (a parked car) standing on the road at u ∈ [3, 4.8] over the middle
    /// 4 m of a 10 m stretch, its faces scattering returns from road height up: the road
    /// beside it and beyond it stays, the bright foot of its faces goes with it.
    #[test]
    fn the_foot_of_an_object_on_the_road_is_cut() {
        let (mut m, mut u, mut z) = (Vec::new(), Vec::new(), Vec::new());
        let mut jit = crate::pipeline::geom::test_jitter(13);
        let on_box = |mm: f64, uu: f64| (3.0..4.8).contains(&uu) && (3.0..7.0).contains(&mm);
        for i in 0..200 {
            let mm = i as f64 * 0.05;
            for j in 0..320 {
                let uu = -2.0 + j as f64 * 0.025 + 0.005 * jit();
                if !on_box(mm, uu) {
                    m.push(mm + 0.01 * jit());
                    u.push(uu);
                    z.push(0.004 * jit());
                }
            }
            if (3.0..7.0).contains(&mm) {
                // The near face, and the roof.
                for h in 0..60 {
                    m.push(mm + 0.01 * jit());
                    u.push(3.0 + 0.02 * jit());
                    z.push(h as f64 * 0.025 + 0.004 * jit());
                }
                for j in 0..72 {
                    m.push(mm);
                    u.push(3.0 + j as f64 * 0.025);
                    z.push(1.5);
                }
            }
        }
        let kept = run_on(&m, &u, &z, &Params::default());
        let face_foot = kept
            .iter()
            .filter(|&&i| (2.98..3.05).contains(&u[i]) && (3.05..6.95).contains(&m[i]))
            .count();
        let beside = kept.iter().filter(|&&i| u[i] < 2.9 && z[i] < 0.1).count();
        let beside_total = (0..u.len()).filter(|&i| u[i] < 2.9 && z[i] < 0.1).count();
        // Beyond it, where the box covers only part of a slice (in the slice it covers
        // whole, the 1.2 m of road beyond it is too narrow to be taken for a carriageway).
        let part = |i: usize| u[i] > 5.0 && !(4.0..6.0).contains(&m[i]);
        let beyond = kept.iter().filter(|&&i| part(i)).count();
        let beyond_total = (0..u.len()).filter(|&i| part(i)).count();
        assert_eq!(face_foot, 0, "the object's foot kept as road");
        assert!(kept.iter().all(|&i| z[i] < 0.1), "object points kept as road");
        assert!(
            beside as f64 > 0.97 * beside_total as f64,
            "beside: {beside} of {beside_total}"
        );
        assert!(
            beyond as f64 > 0.95 * beyond_total as f64,
            "beyond: {beyond} of {beyond_total}"
        );
    }

    #[test]
    fn defaults_validate_and_absurd_values_are_named() {
        Params::default().validate().unwrap();
        let p = Params {
            slice_length_m: 0.0,
            ..Params::default()
        };
        assert!(p.validate().unwrap_err().starts_with("slice_length_m"));
        let p = Params {
            window_m: f64::NAN,
            ..Params::default()
        };
        assert!(p.validate().unwrap_err().starts_with("window_m"));
    }

    #[test]
    fn ransac_finds_the_road_plane_among_outliers() {
        let mut pts = Vec::new();
        for i in 0..200 {
            let u = -5.0 + i as f64 * 0.05;
            let s = (i % 4) as f64 * 0.5;
            pts.push([u, s, 0.5 + 0.02 * u - 0.04 * s]);
        }
        for i in 0..60 {
            pts.push([i as f64 * 0.05, 0.3, 3.0 + i as f64 * 0.1]);
        }
        let pl = ransac_plane(&pts, 200, 0.01, 7).unwrap();
        assert!(
            (pl.a - 0.5).abs() < 1e-6 && (pl.b - 0.02).abs() < 1e-6 && (pl.c + 0.04).abs() < 1e-6,
            "{pl:?}"
        );
    }

    #[test]
    fn flat_road_with_curb_box_and_barrier() {
        let (m, u, z, road) = scene();
        let kept = run_on(&m, &u, &z, &Params::default());
        let mut is_kept = vec![false; m.len()];
        for &i in &kept {
            is_kept[i] = true;
        }
        let (mut tp, mut fp, mut fneg) = (0, 0, 0);
        for i in 0..m.len() {
            match (is_kept[i], road[i]) {
                (true, true) => tp += 1,
                (true, false) => fp += 1,
                (false, true) => fneg += 1,
                _ => {}
            }
        }
        let fp_rate = fp as f64 / (tp + fp) as f64;
        let miss = fneg as f64 / (tp + fneg) as f64;
        assert!(fp_rate < 0.005, "false pavement {fp} of {}", tp + fp);
        assert!(miss < 0.03, "missed pavement {fneg} of {}", tp + fneg);
        // Nothing on the sidewalk (u > 4.05) and nothing of the box.
        for &i in &kept {
            assert!(u[i] < 4.05, "sidewalk point kept at u = {}", u[i]);
            assert!(z[i] < 0.02 * u[i] + 0.03 * m[i] + 0.1, "raised point kept");
        }
    }

    /// A 4 m stretch of cross-sections from u = -3: the surface height at `u`
    /// (`None`: no return there, a shadow) every 2.5 cm, and vertical faces
    /// `(u, from z, to z)`; all jittered deterministically by `seed`.
    fn cross_section(
        u_max: f64,
        surface: impl Fn(f64) -> Option<f64>,
        faces: &[(f64, f64, f64)],
        seed: u64,
    ) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        let (mut m, mut u, mut z) = (Vec::new(), Vec::new(), Vec::new());
        let mut jit = crate::pipeline::geom::test_jitter(seed);
        for i in 0..80 {
            let mm = i as f64 * 0.05;
            for j in 0..((u_max + 3.0) / 0.025) as usize {
                let uu = -3.0 + j as f64 * 0.025;
                let Some(zz) = surface(uu) else { continue };
                m.push(mm + 0.01 * jit());
                u.push(uu + 0.005 * jit());
                z.push(zz + 0.004 * jit());
            }
            for &(face, from, to) in faces {
                for h in 0..((to - from) / 0.025) as usize {
                    m.push(mm + 0.01 * jit());
                    u.push(face + 0.01 * jit());
                    z.push(from + h as f64 * 0.025);
                }
            }
        }
        (m, u, z)
    }

    /// A van beside the scanner: its sides rise at u = 3 and 4.6, its 1.6 m wide roof is flat
    /// at 0.9 m and shadows the road from u = 4.6 to 8; the road goes on from 8 to 14. A flat
    /// strip that high is no sidewalk, so the road beyond the shadow is found again. The
    /// same strip at curb height (+0.15 m, a sidewalk) still ends the search.
    #[test]
    fn the_road_beyond_a_vehicle_beside_the_scanner_is_found_again() {
        let beyond = |top: f64| {
            let surface = |u: f64| match u {
                u if (3.0..4.6).contains(&u) => Some(top),
                u if (4.6..8.0).contains(&u) => None, // shadow: no points
                _ => Some(0.0),
            };
            let (m, u, z) = cross_section(14.0, surface, &[(3.0, 0.0, top), (4.6, 0.0, top)], 3);
            let kept = run_on(&m, &u, &z, &Params::default());
            let near = kept.iter().filter(|&&i| u[i] < 2.9).count();
            let far = kept.iter().filter(|&&i| u[i] > 8.5).count();
            let on_top = kept.iter().filter(|&&i| (3.05..4.55).contains(&u[i])).count();
            (near, far, on_top)
        };
        let (near, far, on_top) = beyond(0.9);
        assert!(near > 10_000, "road beside the scanner: {near}");
        assert!(far > 7_000, "road beyond the van: {far}");
        assert_eq!(on_top, 0, "the van's roof is no road");
        let (_, far, _) = beyond(0.15);
        assert_eq!(far, 0, "beyond a sidewalk the search stops");
    }

    /// Past a bus (roof 1.6 m, shadow from u = 4.6 to 10) only 2 m of the next lane are seen
    /// before a 0.15 m curb and a sidewalk: narrower than `reentry_min_width_m`, but in the
    /// road's plane, so it is road; the sidewalk beyond the curb is not. The same 2 m strip
    /// 0.6 m below the road (a ditch) is not road.
    #[test]
    fn a_narrow_strip_of_road_past_a_vehicle_is_road_when_it_continues_the_plane() {
        let build = |strip_z: f64| {
            let surface = |u: f64| match u {
                u if (3.0..4.6).contains(&u) => Some(1.6),
                u if (4.6..10.0).contains(&u) => None, // the bus's shadow
                u if (10.0..12.0).contains(&u) => Some(strip_z),
                u if u >= 12.0 => Some(strip_z + 0.15), // curb and sidewalk
                _ => Some(0.0),
            };
            let faces = [(3.0, 0.0, 1.6), (4.6, 0.0, 1.6), (12.0, strip_z, strip_z + 0.15)];
            let (m, u, z) = cross_section(15.0, surface, &faces, 5);
            let kept = run_on(&m, &u, &z, &Params::default());
            let strip = kept.iter().filter(|&&i| (10.1..11.9).contains(&u[i])).count();
            let sidewalk = kept.iter().filter(|&&i| u[i] > 12.1).count();
            (strip, sidewalk)
        };
        let (strip, sidewalk) = build(0.0);
        assert!(strip > 4_000, "the lane past the bus: {strip}");
        assert_eq!(sidewalk, 0, "the sidewalk beyond the curb");
        let (strip, _) = build(-0.6);
        assert_eq!(strip, 0, "a narrow strip below the road is no road");
    }

    #[test]
    fn result_does_not_depend_on_point_order() {
        let (m, u, z, _) = scene();
        let a = run_on(&m, &u, &z, &Params::default());
        // Reverse the order (as a second scanner head interleaving would permute it).
        let rev = |v: &[f64]| v.iter().rev().copied().collect::<Vec<_>>();
        let b = run_on(&rev(&m), &rev(&u), &rev(&z), &Params::default());
        let n = m.len();
        let mut b: Vec<usize> = b.into_iter().map(|i| n - 1 - i).collect();
        b.sort_unstable();
        assert_eq!(a, b);
    }

    #[test]
    fn method_none_keeps_everything_and_empty_input_is_empty() {
        let p = Params {
            method: Method::None,
            ..Params::default()
        };
        assert_eq!(run_on(&[0.0, 1.0], &[0.0, 0.0], &[0.0, 5.0], &p), vec![0, 1]);
        assert!(run_on(&[], &[], &[], &Params::default()).is_empty());
    }
}
