//! Stage 5: geometric classification of clusters into marking candidates.
//!
//! # Interface
//! `run(&PointCloud, &[Cluster], &Trajectory, &Params) -> Vec<Candidate>` with the trajectory
//! in the cloud's LOCAL coordinates (`Trajectory::to_local(cloud.origin)`). Each kept cluster
//! becomes a [`Candidate`]: its point indices, a class, a confidence, its robust rectangle
//! ([`Shape`]) and, for pieces running along the road, a centreline in the trajectory frame
//! ([`LineGeometry`]). The learned classifier (a later module) refines `Unknown` candidates
//! from `indices` and `shape` (local frame) without touching the rest. `assess` returns the
//! dropped clusters too, with the reason, for debugging and `export-clusters`.
//!
//! # Algorithm
//! 1. Per cluster (rayon): the robust principal-axis rectangle (length, width, fill ratio,
//!    angle to the trajectory) and, in the (mileage, offset) frame of the smoothed
//!    trajectory, a centreline test: per 0.5 m mileage slice the median offset; the piece is
//!    a *line* when the residuals about that centreline are as narrow as one painted line
//!    (≤ `line_max_width_m`), as wide along its whole length (fewer than a tenth of its
//!    slices wider than `line_max_width_ratio` × the median slice width, so a straight
//!    arrow's shaft and head is no line) and it runs within `line_max_angle_deg` of the
//!    trajectory.
//!    The line test works on curved pieces, where an MBR is a fat wrong rectangle.
//!    Long clusters that fail it are a line with something attached (gore chevrons, a second
//!    line): the lines are peeled off (`peel_lines`, up to six; the ragged edge of a peeled
//!    line, points ≤ 0.1 m beyond its width, goes with no piece, so the stripes of a hatched
//!    gore it chained come apart); pieces of a cluster no longer than
//!    [`MAX_OBJECT_LENGTH_M`] keep it in `Candidate::whole`, for the learned classifier to
//!    put back together when it is one object (a long arrow).
//! 2. Broken lines are re-joined (Pan 2019): line pieces and short narrow fragments whose
//!    ends are ≤ `join_gap_m` apart along the trajectory, at the same offset (prediction
//!    from the piece's slope) and of similar width are merged (mutual best match), so a
//!    sparse far line or a worn dash is one object. Line pieces read as sparse points
//!    (under [`SPARSE_LINE_POINTS_PER_M`]) are joined across up to `join_sparse_gap_m`.
//!    The pieces of one bar across the road (a zebra stripe across a side street, broken
//!    end to end by far scan rows) are joined the same way across the road
//!    (`rejoin_across`).
//! 3. Rules (first match wins):
//!    - tiny (few points or area) → dropped; compact blobs ≤ `blob_max_size_m` with aspect
//!      < 1.6 (manhole covers, ~0.6–0.8 m round) → dropped;
//!    - line: length ≥ `solid_min_length_m` and length/width ≥ `solid_min_ratio` (Yao 2019:
//!      a > 7 m, a/b > 20) → `solid_line`; `dash_min_length_m` ≤ length < solid → `dashed_line`
//!      (GB 6 m / 2 m, MUTCD 3 m, Italy 4.5 m); shorter line fragments → `unknown`;
//!    - filled bar across the trajectory (≥ 60°), 0.15–0.65 m wide, ≥ 1.5 m long →
//!      `stop_line`;
//!    - filled bar along the road (≤ 25°), 0.3–0.65 m wide, 1.5–10 m long, with a parallel
//!      neighbour stripe of similar size ≤ 2.5 m away → `crosswalk` (zebra stripes run
//!      along the road); a lone one that passed the line test is a wide dash;
//!    - filled bar diagonal (25–65°), 0.25–0.8 m wide, with a parallel neighbour ≤ 6 m away
//!      → `guideline` (chevron/hatch stripes);
//!    - a thin or filled elongated shape steeper than `noise_angle_deg` (Yao 2021: 45°) to
//!      the trajectory that matched none of the above → dropped as noise (sealant, cracks);
//!    - everything else → `unknown` (arrows, diamonds, text: the learned classifier's job).
//!    Kept `unknown` pieces up to 6 m long within 0.5 m of each other (a worn or sparsely
//!    scanned arrow or diamond in pieces) share their union as `Candidate::whole`, for the
//!    learned classifier to put back together (`group_fragments`); pieces of a line that
//!    runs on in line for more than 12 m (a lane line beside the object) are left out.
//!    Lane-line context (a "dash" inside a solid lane line is an occluded solid piece) is
//!    applied later by `vectorize`. Clusters dropped as too small that are still pieces of a
//!    line along the road ([`is_line_fragment`]: a far lane's dash seen as one scan row's
//!    few returns) are returned apart by [`run_with_fragments`]; `vectorize` keeps them only
//!    where they make a lane line on the drive's dash design.
//!
//! # Parameters
//! See [`Params`]; lengths in metres, angles in degrees.
//!
//! # Reference
//! Yao et al. 2019 §2.8.1 (MBR solid-line rule); Yao et al. 2021 §2.3 and §5 (45° noise
//! rule); Pan et al. 2019 §2.4–2.5 (bounding-box features, re-joining broken lines).
//!
//! # Complexity
//! O(n log n) over the cluster points (a trajectory-frame lookup per point), O(k log k) for
//! the re-joining and neighbour rules over k clusters.

use super::cluster::Cluster;
use super::geom::{self, BarShape};
use super::refline::RefLine;
use super::types::{MarkingClass, PointCloud, Trajectory};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Parameters of this stage (JSON object `classify` in the job parameters).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Params {
    /// Clusters with fewer points are dropped. Default 10.
    pub min_points: usize,
    /// Clusters with a smaller painted area (length × width × fill, m²) are dropped.
    /// Default 0.02.
    pub min_area_m2: f64,
    /// Compact blobs (both sides ≤ this, aspect < 1.6) are dropped: manhole covers and the
    /// like. Default 1.0 m.
    pub blob_max_size_m: f64,
    /// Widest single painted line (m). Default 0.55 (lane lines are 0.10–0.25 m; GB
    /// acceleration-lane dashes and wide edge lines are 0.45 m).
    pub line_max_width_m: f64,
    /// Filled cross-sections of a line piece wider than this many times its typical one
    /// (the median over its slices) — and more than [`LINE_WIDTH_SLACK_M`] wider — are wide;
    /// a piece with at least [`WIDE_SLICE_SHARE`] of them is no line: a painted line has
    /// one width along its length, a straight arrow (0.15–0.25 m shaft, 0.75 m head) does
    /// not (its head's 0.5 m slices measure 0.5–0.65 m). Default 1.6.
    pub line_max_width_ratio: f64,
    /// Largest angle between a line piece and the trajectory (deg). Default 20.
    pub line_max_angle_deg: f64,
    /// Solid-line piece: at least this long (m). Default 7 (Yao 2019: a > 7 m).
    pub solid_min_length_m: f64,
    /// Solid-line piece: at least this length/width ratio. Default 20 (Yao 2019: a/b > 20).
    pub solid_min_ratio: f64,
    /// Shortest dash (m). Default 0.8 (GB urban dashes are 2 m, worn ones shorter).
    pub dash_min_length_m: f64,
    /// Broken pieces of one line with ends at most this far apart are re-joined (m).
    /// Default 0.8 (real dash gaps are ≥ 1.5 m).
    pub join_gap_m: f64,
    /// Line pieces read as sparse points (fewer than [`SPARSE_LINE_POINTS_PER_M`] points per
    /// metre: a line at long range, or seen through traffic) are re-joined across gaps up to
    /// this (m). Default 2.5: below the shortest gap of a dashed lane line (3 m), above
    /// most gaps between the sparse pieces of one far line.
    pub join_sparse_gap_m: f64,
    /// Elongated leftovers steeper than this to the trajectory are noise (deg). Default 45.
    pub noise_angle_deg: f64,
    /// Stop line width range (m). Defaults 0.15–0.65 (GB 0.2–0.4, MUTCD 0.3–0.6).
    pub stop_min_width_m: f64,
    pub stop_max_width_m: f64,
    /// Crosswalk stripe width range (m). Defaults 0.3–0.65 (GB 0.40–0.45, MUTCD 0.3–0.6).
    /// The learned classifier names no wider candidate a stripe either.
    pub crosswalk_min_width_m: f64,
    pub crosswalk_max_width_m: f64,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            min_points: 10,
            min_area_m2: 0.02,
            blob_max_size_m: 1.0,
            line_max_width_m: 0.55,
            line_max_width_ratio: 1.6,
            line_max_angle_deg: 20.0,
            solid_min_length_m: 7.0,
            solid_min_ratio: 20.0,
            dash_min_length_m: 0.8,
            join_gap_m: 0.8,
            join_sparse_gap_m: 2.5,
            noise_angle_deg: 45.0,
            stop_min_width_m: 0.15,
            stop_max_width_m: 0.65,
            crosswalk_min_width_m: 0.3,
            crosswalk_max_width_m: 0.65,
        }
    }
}

impl Params {
    /// Check every field; the message names the offending parameter.
    pub fn validate(&self) -> Result<(), String> {
        let pos = [
            ("min_area_m2", self.min_area_m2, 0.0, 10.0),
            ("blob_max_size_m", self.blob_max_size_m, 0.0, 5.0),
            ("line_max_width_m", self.line_max_width_m, 0.01, 2.0),
            ("line_max_width_ratio", self.line_max_width_ratio, 1.0, 100.0),
            ("line_max_angle_deg", self.line_max_angle_deg, 0.0, 60.0),
            ("solid_min_length_m", self.solid_min_length_m, 0.1, 100.0),
            ("solid_min_ratio", self.solid_min_ratio, 1.0, 1000.0),
            ("dash_min_length_m", self.dash_min_length_m, 0.0, 50.0),
            ("join_gap_m", self.join_gap_m, 0.0, 10.0),
            ("join_sparse_gap_m", self.join_sparse_gap_m, 0.0, 10.0),
            ("noise_angle_deg", self.noise_angle_deg, 0.0, 90.0),
            ("stop_min_width_m", self.stop_min_width_m, 0.0, 5.0),
            ("stop_max_width_m", self.stop_max_width_m, 0.0, 5.0),
            ("crosswalk_min_width_m", self.crosswalk_min_width_m, 0.0, 5.0),
            ("crosswalk_max_width_m", self.crosswalk_max_width_m, 0.0, 5.0),
        ];
        for (name, v, lo, hi) in pos {
            if !(v >= lo && v <= hi) {
                return Err(format!("{name} must be in [{lo}, {hi}], got {v}"));
            }
        }
        if self.min_points == 0 {
            return Err("min_points must be at least 1".into());
        }
        if self.dash_min_length_m >= self.solid_min_length_m {
            return Err("dash_min_length_m must be below solid_min_length_m".into());
        }
        if self.stop_min_width_m > self.stop_max_width_m {
            return Err("stop_min_width_m must not exceed stop_max_width_m".into());
        }
        if self.crosswalk_min_width_m > self.crosswalk_max_width_m {
            return Err("crosswalk_min_width_m must not exceed crosswalk_max_width_m".into());
        }
        Ok(())
    }
}

/// Width differences a line piece may show between its cross-sections whatever
/// `line_max_width_ratio` says (m): sparse far lines, a few points per slice, measure
/// narrow slices.
pub const LINE_WIDTH_SLACK_M: f64 = 0.15;

/// Narrowest painted line (m; MUTCD 4 in): the outline width of a line is not taken
/// below this from the interquartile range of its points (see `LineGeometry::paint_width_m`).
pub const MIN_PAINT_WIDTH_M: f64 = 0.10;

/// Largest ratio of a line's outline width (twice the IQR of its residuals) to the trimmed
/// extent of the residuals (see `LineGeometry::paint_width_m`).
pub const PAINT_WIDTH_OVER_EXTENT: f64 = 1.15;

/// Share of a line piece's cross-sections that may be wider than its typical one (see
/// `line_max_width_ratio`) before the piece is no line.
pub const WIDE_SLICE_SHARE: f64 = 0.1;

/// Robust rectangle and shape features of a cluster (local coordinates).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Shape {
    /// Centre of the robust rectangle.
    pub center: [f64; 2],
    /// Unit long axis (canonical sign: x > 0).
    pub axis: [f64; 2],
    pub length_m: f64,
    pub width_m: f64,
    /// Mean slice width over the rectangle width: ~1 for bars, ~0.5 for triangles. Slices
    /// are no shorter than the spacing of the scan rows crossing the cluster
    /// ([`BarShape::of_rows`]): a far stripe crossed by rows 0.4 m apart is a filled bar.
    pub fill_ratio: f64,
    /// Acute angle between the long axis and the trajectory (deg, 0..=90).
    pub angle_to_trajectory_deg: f64,
    /// Station of the centre in the smoothed trajectory frame.
    pub mileage_m: f64,
    pub offset_m: f64,
    /// Unit driving direction at the centre's station.
    pub driving_direction: [f64; 2],
    /// Median nearest-neighbour point spacing (m).
    pub spacing_m: f64,
    pub point_count: usize,
    pub mean_intensity: f32,
}

impl Shape {
    /// The four rectangle corners (local coordinates).
    pub fn corners(&self) -> [[f64; 2]; 4] {
        let (a, c) = (self.axis, self.center);
        let (hl, hw) = (self.length_m / 2.0, self.width_m / 2.0);
        let f = |u: f64, v: f64| [c[0] + u * a[0] - v * a[1], c[1] + u * a[1] + v * a[0]];
        [f(-hl, -hw), f(hl, -hw), f(hl, hw), f(-hl, hw)]
    }
}

/// Centreline of a piece running along the road (local coordinates).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LineGeometry {
    /// Vertices ordered by increasing mileage, about 0.5 m apart.
    pub centerline: Vec<[f64; 2]>,
    /// (mileage, offset) of each vertex in the smoothed trajectory frame.
    pub stations: Vec<[f64; 2]>,
    /// Painted width (robust extent of the residuals about the centreline).
    pub width_m: f64,
    /// Width of the painted outline: twice the interquartile range of the residuals (paint
    /// points spread uniformly across a line, so the IQR is half its width whatever a few
    /// percent of strays beside it do to the trimmed extent, and the centreline's own
    /// noise does not shrink it), between [`MIN_PAINT_WIDTH_M`] and
    /// [`PAINT_WIDTH_OVER_EXTENT`] × `width_m`; `width_m` itself with fewer than 40 points.
    /// The rules judge by `width_m`; only the outline uses this.
    pub paint_width_m: f64,
    /// Length along the centreline.
    pub length_m: f64,
    /// Largest distance of the centreline from its chord: > a few cm means curved.
    pub sagitta_m: f64,
}

/// A classified cluster.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Candidate {
    /// Indices into the marking cloud (several clusters when re-joined), sorted.
    pub indices: Vec<usize>,
    pub class: MarkingClass,
    /// 0..1: how clearly the geometry matched the class's rule.
    pub confidence: f64,
    pub shape: Shape,
    /// Present for pieces running along the road (lane-line material).
    pub line: Option<LineGeometry>,
    /// For a piece peeled off a cluster no longer than [`MAX_OBJECT_LENGTH_M`] (see
    /// `peel_lines`): that cluster as it was, unclassified. A long arrow (GB 5768: 9 m at
    /// highway speeds) has a shaft the peeling takes for a line; the learned classifier
    /// (`learned::refine`) puts the cluster back together when it names it one painted object.
    #[serde(skip)]
    pub whole: Option<Arc<Candidate>>,
    /// For a piece of a group of nearby fragments that holds such a peeled cluster (see
    /// `group_fragments`): the union of the group, offered after `whole` (an arrow's turning
    /// branch that broke off at a worn spot lies beside its peeled shaft and head).
    #[serde(skip)]
    pub group: Option<Arc<Candidate>>,
    /// For a piece of a group of fragments that holds line pieces (see `group_fragments`):
    /// the group's union without one of those line pieces, one union per line piece left
    /// out. A lane line passing a far arrow's head within half a metre is grouped with it,
    /// and the union with the line is no painted object; offered beside `whole`, the most
    /// probable painted object of them wins.
    #[serde(skip)]
    pub alternatives: Vec<Arc<Candidate>>,
}

/// Longest single painted object (m): GB 5768 highway arrows are 9 m, MUTCD arrows ≤ 7.3 m.
pub const MAX_OBJECT_LENGTH_M: f64 = 12.0;

/// Why a cluster was dropped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DropReason {
    Tiny,
    Blob,
    SteepNoise,
}

/// Classify clusters; only kept candidates are returned, in a deterministic order (by
/// mileage, then offset).
pub fn run(cloud: &PointCloud, clusters: &[Cluster], traj: &Trajectory, params: &Params) -> Vec<Candidate> {
    assess(cloud, clusters, traj, params)
        .into_iter()
        .filter_map(|(c, d)| d.is_none().then_some(c))
        .collect()
}

/// Like [`run`], and also the line fragments among the dropped candidates (see
/// [`is_line_fragment`]), classed `dashed_line` with a low confidence.
pub fn run_with_fragments(
    cloud: &PointCloud,
    clusters: &[Cluster],
    traj: &Trajectory,
    params: &Params,
) -> (Vec<Candidate>, Vec<Candidate>) {
    let mut kept = Vec::new();
    let mut fragments = Vec::new();
    for (mut c, d) in assess(cloud, clusters, traj, params) {
        match d {
            None => kept.push(c),
            Some(DropReason::Tiny) if is_line_fragment(&c, params) => {
                c.class = MarkingClass::DashedLine;
                c.confidence = FRAGMENT_CONFIDENCE;
                fragments.push(c);
            }
            Some(_) => {}
        }
    }
    (kept, fragments)
}

/// Confidence of a line fragment that joins a lane line.
pub const FRAGMENT_CONFIDENCE: f64 = 0.3;

/// Whether a cluster dropped as too small ([`DropReason::Tiny`]) is still a piece of a line
/// along the road: at least 4 returns over at least 0.3 m, within `line_max_angle_deg` of
/// the trajectory and no wider than `line_max_width_m`. A far lane's 6 m dash is often seen
/// as one scan row's 5–9 returns; alone that is noise, in a row along a lane line it is
/// the line (`vectorize::assemble` keeps fragments only there).
pub fn is_line_fragment(c: &Candidate, p: &Params) -> bool {
    c.line.is_some()
        && c.shape.point_count >= 4
        && c.shape.length_m >= 0.3
        && c.shape.angle_to_trajectory_deg <= p.line_max_angle_deg
        && c.shape.width_m <= p.line_max_width_m
}

/// Like [`run`] but also returns the dropped candidates with the reason.
pub fn assess(
    cloud: &PointCloud,
    clusters: &[Cluster],
    traj: &Trajectory,
    params: &Params,
) -> Vec<(Candidate, Option<DropReason>)> {
    let refl = RefLine::new(traj);
    let xy: Vec<[f64; 2]> = cloud.x.iter().zip(&cloud.y).map(|(&x, &y)| [x, y]).collect();
    let groups: Vec<Vec<usize>> = clusters.iter().map(|c| c.indices.clone()).collect();
    let feats: Vec<Candidate> = groups
        .into_par_iter()
        .map(|g| describe(&xy, &cloud.intensity, g, &refl, params))
        .collect();
    // Long clusters that failed the line test: a line with something attached (gore
    // chevrons, an arrow, a second line of a double line). Peel the lines off.
    let feats: Vec<Candidate> = feats
        .into_par_iter()
        .flat_map_iter(|c| peel_lines(c, &xy, &cloud.intensity, &refl, params))
        .collect();
    let feats = rejoin(feats, &xy, &cloud.intensity, &refl, params);
    let feats = rejoin_across(feats, &xy, &cloud.intensity, &refl, params);
    let mut out: Vec<(Candidate, Option<DropReason>)> = feats.into_iter().map(|c| rule(c, params)).collect();
    confirm_groups(&mut out);
    group_fragments(&mut out, &xy, &cloud.intensity, &refl, params);
    out.sort_by(|a, b| {
        a.0.shape
            .mileage_m
            .total_cmp(&b.0.shape.mileage_m)
            .then(a.0.shape.offset_m.total_cmp(&b.0.shape.offset_m))
            .then(a.0.indices.first().cmp(&b.0.indices.first()))
    });
    out
}

/// Features of one group of points; class left `Unknown` (rules come later).
fn describe(
    xy: &[[f64; 2]],
    intensity: &[f32],
    mut idx: Vec<usize>,
    refl: &RefLine,
    p: &Params,
) -> Candidate {
    idx.sort_unstable();
    let pts: Vec<[f64; 2]> = idx.iter().map(|&i| xy[i]).collect();
    let bar = BarShape::of_rows(&pts);
    let center = bar.center();
    let [ms, mo] = refl.locate(center);
    let dir = refl.direction(ms);
    let spacing = geom::spacing(&pts, 1.0).unwrap_or(0.05);
    let mean_intensity = if idx.is_empty() {
        0.0
    } else {
        (idx.iter()
            .map(|&i| intensity.get(i).copied().unwrap_or(0.0) as f64)
            .sum::<f64>()
            / idx.len() as f64) as f32
    };
    let shape = Shape {
        center,
        axis: bar.pca.axis,
        length_m: bar.length(),
        width_m: bar.width(),
        fill_ratio: bar.fill,
        angle_to_trajectory_deg: geom::acute_angle_deg(bar.pca.axis, dir),
        mileage_m: ms,
        offset_m: mo,
        driving_direction: dir,
        spacing_m: spacing,
        point_count: idx.len(),
        mean_intensity,
    };
    let line = line_geometry(&pts, refl, p);
    Candidate {
        indices: idx,
        class: MarkingClass::Unknown,
        confidence: 0.0,
        shape,
        line,
        whole: None,
        group: None,
        alternatives: Vec::new(),
    }
}

/// The trajectory-frame centreline test (see the module docs).
fn line_geometry(pts: &[[f64; 2]], refl: &RefLine, p: &Params) -> Option<LineGeometry> {
    if pts.len() < 4 {
        return None;
    }
    let mut so: Vec<[f64; 2]> = pts.iter().map(|&q| refl.locate(q)).collect();
    so.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    let (s_lo, s_hi) = (so[0][0], so[so.len() - 1][0]);
    let ext = s_hi - s_lo;
    if ext < 0.3 {
        return None;
    }
    let ds = (ext / 4.0).clamp(0.1, 0.5);
    let ns = (ext / ds).ceil().max(1.0) as usize;
    let mut slices: Vec<Vec<f64>> = vec![Vec::new(); ns];
    let mut slice_s: Vec<f64> = vec![0.0; ns];
    for q in &so {
        let k = (((q[0] - s_lo) / ds) as usize).min(ns - 1);
        slices[k].push(q[1]);
        slice_s[k] += q[0];
    }
    let (mut ks, mut ko, mut kw) = (Vec::new(), Vec::new(), Vec::new());
    for k in 0..ns {
        let n = slices[k].len();
        if n >= 2 || (n == 1 && ns <= 4) {
            ks.push(slice_s[k] / n as f64);
            ko.push(geom::median(&mut slices[k]));
            kw.push(n as f64);
        }
    }
    if ks.len() < 2 {
        return None;
    }
    // Smooth offsets of the slice medians; the residuals of all points give the width.
    let h = (2.0 * ds).max(0.5);
    let fit = |s: f64| geom::local_linear(&ks, &ko, &kw, s, h, 2.0).unwrap_or((0.0, 0.0));
    let mut resid: Vec<f64> = Vec::with_capacity(so.len());
    let mut slope_sum = 0.0;
    for &k in &ks {
        slope_sum += fit(k).1;
    }
    let slope = slope_sum / ks.len() as f64;
    let cosang = 1.0 / (1.0 + slope * slope).sqrt();
    // Fitted offsets at the slice centres, interpolated for the residuals.
    let fo: Vec<f64> = ks.iter().map(|&s| fit(s).0).collect();
    for q in &so {
        resid.push(q[1] - geom::interp_clamped(&ks, &fo, q[0]));
    }
    resid.sort_unstable_by(f64::total_cmp);
    let (r0, r1) = geom::robust_extent(&resid);
    let mut width = (r1 - r0) * cosang;
    // A painted line has one width along its length; an arrow (narrow shaft, wide head)
    // whose overall width stays under `line_max_width_m` does not. Slices with few points
    // (sparse far lines) measure no width.
    // (width, filled) per slice: filled when no gap across it is over a quarter of its
    // width — an arrow head is filled, a double line whose one line is worn in places is
    // not.
    let mut slice_w: Vec<(f64, bool)> = Vec::new();
    for k in 0..ns {
        let n = slices[k].len();
        if n >= 6 {
            let f = geom::interp_clamped(&ks, &fo, slice_s[k] / n as f64);
            let mut r: Vec<f64> = slices[k].iter().map(|o| o - f).collect();
            r.sort_unstable_by(f64::total_cmp);
            let (a, b) = geom::robust_extent(&r);
            let gap = r.windows(2).map(|w| w[1] - w[0]).fold(0.0, f64::max);
            slice_w.push(((b - a) * cosang, gap <= 0.25 * (b - a)));
        }
    }
    if slice_w.len() >= 4 {
        let typical = geom::median(&mut slice_w.iter().map(|w| w.0).collect::<Vec<f64>>());
        let wide_from = (p.line_max_width_ratio * typical).max(typical + LINE_WIDTH_SLACK_M);
        // Positions of the wide (filled) slices.
        let wide_at: Vec<usize> = (0..slice_w.len())
            .filter(|&i| slice_w[i].1 && slice_w[i].0 > wide_from)
            .collect();
        let wide = wide_at.len();
        // A few wide slices are something touching the line's end (a stop line, a
        // crosswalk stripe); a tenth of its length is a part of its own shape.
        if width > wide_from && wide >= 2 && wide as f64 >= WIDE_SLICE_SHARE * slice_w.len() as f64 {
            return None;
        }
        // Fewer wide slices, all within the end sixths: a mark touching the line's end (an
        // arrow, a stop line) inflated the spread of the residuals; the line's own width
        // is the typical one.
        let n = slice_w.len();
        let at_ends = wide_at.iter().all(|&i| 6 * i < n || 6 * i >= 5 * n);
        if width > typical + LINE_WIDTH_SLACK_M && wide > 0 && at_ends {
            width = typical;
        }
    }
    if width > p.line_max_width_m || ext * cosang < 3.0 * width.max(0.05) {
        return None;
    }
    let angle = slope.abs().atan().to_degrees();
    // Local angles too: a piece bending across the road is not a lane line.
    if angle > p.line_max_angle_deg
        || ks
            .iter()
            .any(|&s| fit(s).1.abs().atan().to_degrees() > p.line_max_angle_deg + 10.0)
    {
        return None;
    }
    // Ends: the first/last points, ignoring a lone stray beyond a slice gap.
    let first = (0..ns).find(|&k| slices[k].len() >= 2).unwrap_or(0);
    let last = (0..ns).rev().find(|&k| slices[k].len() >= 2).unwrap_or(ns - 1);
    let s0 = so
        .iter()
        .map(|q| q[0])
        .find(|&s| s >= s_lo + first as f64 * ds)
        .unwrap_or(s_lo);
    let s1 = so
        .iter()
        .rev()
        .map(|q| q[0])
        .find(|&s| s <= s_lo + (last + 1) as f64 * ds)
        .unwrap_or(s_hi);
    let mut stations: Vec<[f64; 2]> = vec![[s0, fit(s0).0]];
    let nv = ((s1 - s0) / 0.5).ceil().max(1.0) as usize;
    for i in 1..nv {
        let s = s0 + (s1 - s0) * i as f64 / nv as f64;
        stations.push([s, fit(s).0]);
    }
    stations.push([s1, fit(s1).0]);
    let centerline: Vec<[f64; 2]> = stations.iter().map(|st| refl.point(st[0], st[1])).collect();
    let length = geom::polyline_length(&centerline);
    let (a, b) = (centerline[0], centerline[centerline.len() - 1]);
    let chord = (b[0] - a[0]).hypot(b[1] - a[1]).max(1e-9);
    let sagitta = centerline
        .iter()
        .map(|q| ((q[0] - a[0]) * (b[1] - a[1]) - (q[1] - a[1]) * (b[0] - a[0])).abs() / chord)
        .fold(0.0, f64::max);
    let paint_width = if resid.len() >= 40 {
        let iqr = geom::quantile_sorted(&resid, 0.75) - geom::quantile_sorted(&resid, 0.25);
        // The trimmed extent reads a dense line too narrow: the centreline follows the
        // slice medians, which lean towards each slice's own points, so the residuals'
        // tails shrink (a 0.20 m edge line 10 m out measured 0.178 m) while the IQR keeps
        // half the width. Strays beside the line widen the extent, never the IQR. Never
        // below the narrowest painted line (a far line crossed by two scan rows has an IQR
        // of about nothing) and at most `PAINT_WIDTH_OVER_EXTENT` × the extent (paint
        // points bunched at the line's two edges).
        (2.0 * iqr * cosang)
            .max(MIN_PAINT_WIDTH_M)
            .min(PAINT_WIDTH_OVER_EXTENT * width)
    } else {
        width
    };
    Some(LineGeometry {
        centerline,
        stations,
        width_m: width,
        paint_width_m: paint_width,
        length_m: length,
        sagitta_m: sagitta,
    })
}

/// Fragments closer than this (m, nearest points) belong to one group in
/// [`group_fragments`].
const FRAGMENT_GAP_M: f64 = 0.5;

/// Fewest points of a cluster dropped as tiny that [`group_fragments`] offers (a single
/// scan row across a far arrow's shaft holds 5–10).
const FRAGMENT_MIN_TINY_POINTS: usize = 5;

/// Fewest points of a cluster dropped as a blob or steep noise that [`group_fragments`]
/// offers.
const FRAGMENT_MIN_DROPPED_POINTS: usize = 10;
/// Fragments longer than this (m) are no part of one painted object's pieces.
const FRAGMENT_MAX_LENGTH_M: f64 = 6.0;

/// Widest mean cross-section (m) of a thin stroke ([`drop_thin_strokes`]).
const STROKE_MAX_MEAN_WIDTH_M: f64 = 0.2;
/// Least length over rectangle width of a thin stroke.
const STROKE_MIN_ASPECT: f64 = 3.0;

/// Crack sealant and glints: a bright stroke a few centimetres wide that wanders across
/// the road. Left `unknown` by the rules and the learned classifier, it is elongated
/// (length ≥ [`STROKE_MIN_ASPECT`] × its rectangle's width), thin (mean cross-section —
/// fill ratio × width — at most [`STROKE_MAX_MEAN_WIDTH_M`]) and runs at more than
/// `line_max_angle_deg` to the trajectory (painted lines along the road pass the line
/// test; stop lines, stripes and arrows are wider). Such candidates are dropped; on the 20
/// simulated scenes 41 of 134 `unknown` candidates on bare asphalt and 1 of 75 on paint
/// were. Runs after the learned classifier, which may still name a thin piece part of an
/// arrow. Returns the number dropped.
pub fn drop_thin_strokes(candidates: &mut Vec<Candidate>, p: &Params) -> usize {
    let before = candidates.len();
    candidates.retain(|c| {
        let s = &c.shape;
        !(c.class == MarkingClass::Unknown
            && s.length_m >= STROKE_MIN_ASPECT * s.width_m
            && s.fill_ratio * s.width_m <= STROKE_MAX_MEAN_WIDTH_M
            && s.angle_to_trajectory_deg > p.line_max_angle_deg)
    });
    before - candidates.len()
}

/// Worn or sparsely scanned arrows and diamonds fall apart into several pieces that no
/// single look can name: `unknown` pieces, a shaft that passes for a dash, and parts of the
/// head too small, too round or too steep to be kept on their own (a far arrow crossed by
/// three scan rows is a dash-like shaft and a 26-point blob). Pieces no longer than
/// [`FRAGMENT_MAX_LENGTH_M`] — kept `unknown` candidates and dashes, and clusters dropped
/// as tiny (≥ [`FRAGMENT_MIN_TINY_POINTS`] points), blobs or steep noise (≥
/// [`FRAGMENT_MIN_DROPPED_POINTS`]) — and the clusters `peel_lines` took apart (each one
/// unit: its whole, standing for all its pieces) that lie within [`FRAGMENT_GAP_M`] of each
/// other (single linkage on their nearest points) form a group. A group of two or more
/// units that holds an `unknown` or dropped piece or a peeled cluster, and a kept piece,
/// and whose union is no longer than [`MAX_OBJECT_LENGTH_M`], is given to each member as
/// its `whole`, for the learned classifier to put back together when the union is one
/// painted object — or, when the group holds a peeled cluster, to each member (of a peeled
/// cluster: to each of its pieces) as its `group`, offered when the peeled cluster alone is
/// no painted object (an arrow whose turning branch broke off its shaft at a worn spot is
/// a peeled shaft-and-head cluster and a branch beside it). Dashes alone never form a
/// group: a dashed line is no object; nor is a piece of a line longer than any painted
/// object offered ([`in_long_lines`]: a lane line passing a far arrow's head). A group of
/// fragments (no peeled cluster) that holds line pieces is also offered without each of
/// its [`MAX_ALTERNATIVES`] longest (`Candidate::alternatives`): the piece of a lane line
/// whose other pieces are too far apart to chain still joins the group of the arrow it
/// passes, and the learned classifier picks the union that is one painted object.
/// Line pieces that are part of a line longer than any painted object: kept line pieces
/// chained end to end (the next one starting within [`CONTINUATION_GAP_M`] beyond the end
/// of the last, at the same offset ± [`CONTINUATION_OFFSET_M`]) over more than
/// [`MAX_OBJECT_LENGTH_M`] along the track. Such a piece belongs to a lane line (a sparse
/// solid line comes in 1–5 m pieces), not to an object beside it: grouped with a far arrow
/// that the line passes within half a metre of, it made the union no object. An arrow's
/// shaft broken in two is a chain of a few metres; a dashed line's dashes are farther apart.
/// Hand-written (a union-find over the pieces in mileage order, like `rejoin`'s window):
/// O(k log k + links) for the k line pieces of a chunk.
fn in_long_lines(items: &[(Candidate, Option<DropReason>)], p: &Params) -> Vec<bool> {
    // Kept line pieces' ends in the trajectory frame, in order of their start.
    let ends: Vec<Option<End>> = items
        .iter()
        .map(|(c, d)| {
            let line = d.is_none()
                && c.line.is_some()
                && matches!(c.class, MarkingClass::SolidLine | MarkingClass::DashedLine);
            line.then(|| piece_end(c, p)).flatten()
        })
        .collect();
    let mut order: Vec<usize> = (0..items.len()).filter(|&k| ends[k].is_some()).collect();
    order.sort_by(|&a, &b| {
        let (ea, eb) = (ends[a].as_ref().expect("end"), ends[b].as_ref().expect("end"));
        ea.s0.total_cmp(&eb.s0).then(a.cmp(&b))
    });
    let mut parent: Vec<usize> = (0..items.len()).collect();
    for &a in &order {
        let ea = ends[a].as_ref().expect("end");
        // Successors start from 2 m before a's end to CONTINUATION_GAP_M after it.
        let from = order.partition_point(|&b| ends[b].as_ref().expect("end").s0 < ea.s1 - 2.0);
        for &b in &order[from..] {
            let eb = ends[b].as_ref().expect("end");
            if eb.s0 > ea.s1 + CONTINUATION_GAP_M {
                break;
            }
            if a != b && (eb.o0 - ea.o1).abs() <= CONTINUATION_OFFSET_M {
                geom::union(&mut parent, a, b);
            }
        }
    }
    // Extent along the track of each chain (at its root).
    let mut span = vec![(f64::INFINITY, f64::NEG_INFINITY); items.len()];
    for &k in &order {
        let (e, r) = (ends[k].as_ref().expect("end"), geom::find_root(&mut parent, k));
        span[r] = (span[r].0.min(e.s0), span[r].1.max(e.s1));
    }
    (0..items.len())
        .map(|k| {
            ends[k].is_some() && {
                let (lo, hi) = span[geom::find_root(&mut parent, k)];
                hi - lo > MAX_OBJECT_LENGTH_M
            }
        })
        .collect()
}

/// Largest gap (m, along the track) at which a line piece continues another (see
/// [`in_long_lines`]).
const CONTINUATION_GAP_M: f64 = 6.0;
/// Largest offset difference (m) at which a line piece continues another.
const CONTINUATION_OFFSET_M: f64 = 0.2;

fn group_fragments(
    items: &mut [(Candidate, Option<DropReason>)],
    xy: &[[f64; 2]],
    intensity: &[f32],
    refl: &RefLine,
    p: &Params,
) {
    // Units: a peeled cluster (its whole and its pieces) or one offered fragment.
    let mut units: Vec<(Option<Arc<Candidate>>, Vec<usize>)> =
        shared_unions(items, |(c, _)| c.whole.as_ref())
            .into_iter()
            .map(|(w, members)| (Some(w), members))
            .collect();
    let long_line = in_long_lines(items, p);
    for (k, (c, d)) in items.iter().enumerate() {
        let offered = match d {
            None => matches!(c.class, MarkingClass::Unknown | MarkingClass::DashedLine),
            Some(DropReason::Tiny) => c.shape.point_count >= FRAGMENT_MIN_TINY_POINTS,
            Some(DropReason::Blob | DropReason::SteepNoise) => {
                c.shape.point_count >= FRAGMENT_MIN_DROPPED_POINTS
            }
        };
        if c.whole.is_none() && offered && c.shape.length_m <= FRAGMENT_MAX_LENGTH_M && !long_line[k] {
            units.push((None, vec![k]));
        }
    }
    if units.len() < 2 {
        return;
    }
    let unit_points: Vec<&[usize]> = units
        .iter()
        .map(|(w, members)| match w {
            Some(w) => &w.indices[..],
            None => &items[members[0]].0.indices[..],
        })
        .collect();
    // Single linkage on the nearest points: components of the units' points at the gap;
    // a unit is one set with every unit that shares a component with it.
    let mut owner: Vec<usize> = Vec::new();
    let mut pts: Vec<[f64; 2]> = Vec::new();
    for (f, u) in unit_points.iter().enumerate() {
        for &i in u.iter() {
            owner.push(f);
            pts.push(xy[i]);
        }
    }
    let mut parent: Vec<usize> = (0..units.len()).collect();
    for comp in geom::components(&pts, FRAGMENT_GAP_M) {
        for w in comp.windows(2) {
            geom::union(&mut parent, owner[w[0]], owner[w[1]]);
        }
    }
    let mut groups: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
    for f in 0..units.len() {
        groups.entry(geom::find_root(&mut parent, f)).or_default().push(f);
    }
    // Dropped pieces are classed `unknown`; a group needs a kept piece to carry its whole.
    let mut wholes: Vec<(Vec<usize>, Candidate, bool)> = Vec::new();
    let mut alternatives: Vec<(Vec<usize>, Candidate)> = Vec::new();
    let union_of = |units: &[usize]| {
        let mut idx: Vec<usize> = units
            .iter()
            .flat_map(|&f| unit_points[f].iter().copied())
            .collect();
        idx.sort_unstable();
        idx.dedup();
        describe(xy, intensity, idx, refl, p)
    };
    for group in groups.into_values().filter(|g| g.len() >= 2) {
        let members: Vec<usize> = group.iter().flat_map(|&f| units[f].1.iter().copied()).collect();
        let peeled = group.iter().any(|&f| units[f].0.is_some());
        let suspect = peeled || members.iter().any(|&k| items[k].0.class == MarkingClass::Unknown);
        if !suspect || !members.iter().any(|&k| items[k].1.is_none()) {
            continue;
        }
        let union = union_of(&group);
        if union.shape.length_m <= MAX_OBJECT_LENGTH_M {
            wholes.push((members, union, peeled));
        }
        if peeled {
            continue;
        }
        // The group without one of its line pieces, for each of the longest few.
        let mut lines: Vec<usize> = group
            .iter()
            .copied()
            .filter(|&f| is_line_piece(&items[units[f].1[0]]))
            .collect();
        lines.sort_by(|&a, &b| {
            let len = |f: usize| items[units[f].1[0]].0.shape.length_m;
            len(b).total_cmp(&len(a)).then(a.cmp(&b))
        });
        for &out in lines.iter().take(MAX_ALTERNATIVES) {
            let rest: Vec<usize> = group.iter().copied().filter(|&f| f != out).collect();
            let members: Vec<usize> = rest.iter().map(|&f| units[f].1[0]).collect();
            if rest.len() < 2 || !members.iter().any(|&k| items[k].1.is_none()) {
                continue;
            }
            let union = union_of(&rest);
            if union.shape.length_m <= MAX_OBJECT_LENGTH_M {
                alternatives.push((members, union));
            }
        }
    }
    drop(unit_points);
    for (members, union, peeled) in wholes {
        let union = Some(Arc::new(union));
        for &k in &members {
            if peeled {
                items[k].0.group.clone_from(&union);
            } else {
                items[k].0.whole.clone_from(&union);
            }
        }
    }
    for (members, union) in alternatives {
        let union = Arc::new(union);
        for &k in &members {
            items[k].0.alternatives.push(Arc::clone(&union));
        }
    }
}

/// Most unions of a group without one of its line pieces (see [`group_fragments`]).
const MAX_ALTERNATIVES: usize = 3;
/// Shortest line piece (m) that [`group_fragments`] offers a group without.
const ALTERNATIVE_LINE_MIN_M: f64 = 1.5;

/// A kept piece of a line along the road at least [`ALTERNATIVE_LINE_MIN_M`] long: the
/// shaft of an arrow, or a piece of the lane line passing it.
fn is_line_piece((c, d): &(Candidate, Option<DropReason>)) -> bool {
    d.is_none()
        && c.line.is_some()
        && matches!(c.class, MarkingClass::DashedLine | MarkingClass::SolidLine)
        && c.shape.length_m >= ALTERNATIVE_LINE_MIN_M
}

/// The distinct unions (`whole`, `group` or `alternatives`) that `of` finds on the items,
/// in order of first appearance, each with the indices of the items that point to it.
pub fn shared_unions<'a, T, I>(items: &'a [T], of: impl Fn(&'a T) -> I) -> Vec<(Arc<Candidate>, Vec<usize>)>
where
    I: IntoIterator<Item = &'a Arc<Candidate>>,
{
    let mut out: Vec<(Arc<Candidate>, Vec<usize>)> = Vec::new();
    for (i, item) in items.iter().enumerate() {
        for w in of(item) {
            match out.iter_mut().find(|(x, _)| Arc::ptr_eq(x, w)) {
                Some((_, members)) => members.push(i),
                None => out.push((Arc::clone(w), vec![i])),
            }
        }
    }
    out
}

/// Split painted lines off a long cluster that is not one line (see `assess`): in the
/// trajectory frame, per 0.5 m mileage slice, the offsets form runs (intervals without a
/// gap > 0.1 m or 1.5 point spacings); a dynamic programme over the slices finds the
/// longest track of line-wide runs (≤ `line_max_width_m`) with near-constant offset or
/// slope (the next run within 0.1 m + 0.02 m per skipped slice of the last one's offset,
/// or of where the track's smoothed slope leads: a ramp's line diverges from the drive;
/// up to 4 slices skipped where something crosses the line). A track at least
/// `solid_min_length_m` long takes every point within its half width (+3 cm) of the
/// track's centre; the rest is re-clustered
/// (0.25 m components) and peeled again, up to [`PEEL_ROUNDS`] lines; points just beyond a
/// peeled track ([`PEEL_EDGE_M`]) go with no piece. Every piece gets the cluster as its
/// `whole` (when no longer than a painted object), except where pieces are bars across the
/// road ([`bars_across`]: an expansion joint through an arrow): the cluster without them
/// falls into components, and each piece gets its component's whole (none for the bars, or
/// for a piece alone in its component). In a cluster longer than a painted object, the
/// pieces besides its long lines and bars are grouped at [`FRAGMENT_GAP_M`] and each group
/// is its pieces' whole ([`set_component_wholes`]: an arrow whose shaft a track took, beside the
/// edge line its branch touched). Cost: O(m log m) for m points.
fn peel_lines(
    c: Candidate,
    xy: &[[f64; 2]],
    intensity: &[f32],
    refl: &RefLine,
    p: &Params,
) -> Vec<Candidate> {
    if c.line.is_some() || c.indices.len() < 40 {
        return vec![c];
    }
    let whole = (c.shape.length_m <= MAX_OBJECT_LENGTH_M).then(|| Arc::new(c.clone()));
    let cluster = c.indices.clone();
    let mut out = Vec::new();
    // The points left and their (s, o), located once and carried through the rounds.
    let mut rest = c.indices;
    let mut so: Vec<[f64; 2]> = rest.iter().map(|&i| refl.locate(xy[i])).collect();
    // One round: the longest track of `tp` with (s, o) mapped by `frame` to (along,
    // across): the piece of the points on it, the indices (into `rest`) of the others, and
    // the track as a distance over (s, o).
    let peel = |tp: &Params, frame: fn([f64; 2]) -> [f64; 2], rest: &[usize], so: &[[f64; 2]]| {
        let fs: Vec<[f64; 2]> = so.iter().map(|&q| frame(q)).collect();
        let (lo, hi) = fs.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |a, q| {
            (a.0.min(q[0]), a.1.max(q[0]))
        });
        if hi - lo < tp.solid_min_length_m {
            return None;
        }
        let track = line_track(&fs, lo, hi, tp)?;
        let (on, off): (Vec<usize>, Vec<usize>) = (0..rest.len()).partition(|&k| track(fs[k]) <= 0.0);
        if on.len() < 20 {
            return None;
        }
        let cand = describe(xy, intensity, on.iter().map(|&k| rest[k]).collect(), refl, p);
        Some((cand, off, move |q: [f64; 2]| track(frame(q))))
    };
    let mut tracks = Vec::new();
    for _round in 0..PEEL_ROUNDS {
        let Some((cand, off, track)) = peel(p, |q| q, &rest, &so) else {
            break;
        };
        if cand.line.is_none() {
            // Not a clean line after all: keep the cluster as it was.
            break;
        }
        out.push(cand);
        (rest, so) = off.iter().map(|&k| (rest[k], so[k])).unzip();
        tracks.push(track);
    }
    if out.is_empty() {
        return vec![describe(xy, intensity, rest, refl, p)];
    }
    let lines_end = out.len();
    // Bars across the road that the lines passed through (an expansion joint through an
    // arrow and the lane lines): the same track search with mileage and offset swapped
    // finds a run of near-constant mileage across the offsets.
    let across = Params {
        solid_min_length_m: CROSS_BAR_MIN_LENGTH_M,
        line_max_width_m: p.stop_max_width_m,
        ..p.clone()
    };
    for _round in 0..BAR_ROUNDS {
        let Some((cand, off, track)) = peel(&across, |q| [q[1], q[0]], &rest, &so) else {
            break;
        };
        if !bar_shaped(&cand.shape, p) {
            break;
        }
        out.push(cand);
        (rest, so) = off.iter().map(|&k| (rest[k], so[k])).unzip();
        tracks.push(track);
    }
    // The ragged edge of a peeled line or bar (points just beyond its track's width) would
    // chain everything that touches the line (the stripes of a gore) into one component:
    // those points go with no piece.
    let rest: Vec<usize> = (0..rest.len())
        .filter(|&k| tracks.iter().all(|t| t(so[k]) > PEEL_EDGE_M))
        .map(|k| rest[k])
        .collect();
    let pts: Vec<[f64; 2]> = rest.iter().map(|&i| xy[i]).collect();
    let peeled = out.len();
    for comp in geom::components(&pts, 0.25) {
        let idx: Vec<usize> = comp.into_iter().map(|k| rest[k]).collect();
        out.push(describe(xy, intensity, idx, refl, p));
    }
    let bars = bars_across(&out, p);
    if bars.contains(&true) {
        // The cluster without its bars falls into the marks the bars joined. A bar cuts what
        // it crossed (an arrowhead) by its width and ragged edges: up to ~0.45 m apart, the
        // parts are rejoined through the ragged points, which stay.
        let mut in_bars: Vec<usize> = out
            .iter()
            .zip(&bars)
            .filter(|(_, b)| **b)
            .flat_map(|(piece, _)| piece.indices.iter().copied())
            .collect();
        in_bars.sort_unstable();
        let kept: Vec<usize> = cluster
            .into_iter()
            .filter(|i| in_bars.binary_search(i).is_err())
            .collect();
        set_component_wholes(&mut out, &bars, &kept, xy, intensity, refl, p);
    } else if whole.is_none() {
        // Too long to be one mark: the lines longer than a painted object and the bars are
        // no part of a mark's whole (a shorter line track can be an arrow's shaft), nor
        // their ragged points, which would chain everything along them.
        let apart: Vec<bool> = (0..out.len())
            .map(|k| {
                (k < lines_end && out[k].shape.length_m > MAX_OBJECT_LENGTH_M)
                    || (lines_end..peeled).contains(&k)
            })
            .collect();
        let kept: Vec<usize> = out
            .iter()
            .zip(&apart)
            .filter(|(_, a)| !**a)
            .flat_map(|(piece, _)| piece.indices.iter().copied())
            .collect();
        set_component_wholes(&mut out, &apart, &kept, xy, intensity, refl, p);
    } else {
        for piece in &mut out {
            piece.whole.clone_from(&whole);
        }
    }
    out
}

/// Wholes of the pieces of a peeled cluster by components: the points `kept` fall into
/// components at [`FRAGMENT_GAP_M`] (the grouping distance of `group_fragments`); each piece
/// not `apart` belongs to its first point's component, and a component holding two such
/// pieces or more that is no longer than a painted object is their whole. The others get
/// none.
fn set_component_wholes(
    out: &mut [Candidate],
    apart: &[bool],
    kept: &[usize],
    xy: &[[f64; 2]],
    intensity: &[f32],
    refl: &RefLine,
    p: &Params,
) {
    let pts: Vec<[f64; 2]> = kept.iter().map(|&i| xy[i]).collect();
    let comps = geom::components(&pts, FRAGMENT_GAP_M);
    let mut comp_of: std::collections::HashMap<usize, usize> =
        std::collections::HashMap::with_capacity(kept.len());
    for (ci, comp) in comps.iter().enumerate() {
        for &k in comp {
            comp_of.insert(kept[k], ci);
        }
    }
    let piece_comp: Vec<Option<usize>> = out
        .iter()
        .zip(apart)
        .map(|(piece, &apart)| {
            (!apart)
                .then(|| piece.indices.first().and_then(|i| comp_of.get(i).copied()))
                .flatten()
        })
        .collect();
    let wholes: Vec<Option<Arc<Candidate>>> = comps
        .iter()
        .enumerate()
        .map(|(ci, comp)| {
            if piece_comp.iter().filter(|&&pc| pc == Some(ci)).count() < 2 {
                return None;
            }
            let w = describe(xy, intensity, comp.iter().map(|&k| kept[k]).collect(), refl, p);
            (w.shape.length_m <= MAX_OBJECT_LENGTH_M).then(|| Arc::new(w))
        })
        .collect();
    for (piece, pc) in out.iter_mut().zip(piece_comp) {
        piece.whole = pc.and_then(|ci| wholes[ci].clone());
    }
}

/// A filled bar (fill ≥ 0.65, length ≥ 2.5 × width) of a stop line's width at ≥ 60° to
/// the trajectory: the rules' stop line, whatever its length.
fn stop_line_shaped(s: &Shape, p: &Params) -> bool {
    s.fill_ratio >= 0.65
        && s.length_m / s.width_m.max(1e-3) >= 2.5
        && s.angle_to_trajectory_deg >= 60.0
        && s.width_m >= p.stop_min_width_m
        && s.width_m <= p.stop_max_width_m
}

/// A bar across the road: shaped like a stop line, at least [`CROSS_BAR_MIN_LENGTH_M`] long.
fn bar_shaped(s: &Shape, p: &Params) -> bool {
    stop_line_shaped(s, p) && s.length_m >= CROSS_BAR_MIN_LENGTH_M
}

/// Bars across the road peeled off one cluster at most (after its lines).
const BAR_ROUNDS: usize = 2;

/// Least length (m) of a bar across the road that [`peel_lines`] takes out of the wholes
/// (see [`bars_across`]).
const CROSS_BAR_MIN_LENGTH_M: f64 = 2.0;

/// Which pieces of a peeled cluster are bars across the road that only touch the other
/// marks: filled straight bars of a stop line's width at ≥ 60° to the trajectory, at least
/// [`CROSS_BAR_MIN_LENGTH_M`] long and at least twice as long as the other pieces (bars
/// apart) reach along their axis. An expansion joint or a stop line running through an
/// arrow made the arrow's whole no arrow to the learned classifier (a straight arrow
/// crossed by a bridge joint read as a straight-and-turn arrow); a turning branch is
/// shorter, and the arrow it leaves reaches as far across.
fn bars_across(pieces: &[Candidate], p: &Params) -> Vec<bool> {
    let shaped: Vec<bool> = pieces.iter().map(|c| bar_shaped(&c.shape, p)).collect();
    (0..pieces.len())
        .map(|k| {
            let s = &pieces[k].shape;
            // The other pieces' reach along the bar's axis (their rectangles' corners).
            let (lo, hi) = pieces
                .iter()
                .zip(&shaped)
                .filter(|(_, bar)| !**bar)
                .flat_map(|(q, _)| q.shape.corners())
                .map(|c| (c[0] - s.center[0]) * s.axis[0] + (c[1] - s.center[1]) * s.axis[1])
                .fold((f64::INFINITY, f64::NEG_INFINITY), |a, u| {
                    (a.0.min(u), a.1.max(u))
                });
            shaped[k] && (hi < lo || s.length_m >= 2.0 * (hi - lo))
        })
        .collect()
}

/// Largest offset change per 0.5 m slice (m) a line track's slope is taken as (~17°).
const MAX_DRIFT_PER_SLICE: f64 = 0.15;

/// Lines peeled off one cluster at most (a gore: two edge lines, the lines they meet,
/// the lane lines beside them).
const PEEL_ROUNDS: usize = 6;

/// Points this far (m) beyond the width of a peeled line's track are its ragged edge.
const PEEL_EDGE_M: f64 = 0.1;

/// The longest line track through the (s, o) samples (see `peel_lines`), as a distance:
/// how far (m) a sample lies beyond the track's half width (≤ 0 inside; infinite beyond
/// its ends).
fn line_track(so: &[[f64; 2]], s_lo: f64, s_hi: f64, p: &Params) -> Option<impl Fn([f64; 2]) -> f64 + use<>> {
    const DS: f64 = 0.5;
    const MAX_SKIP: usize = 4;
    let ns = ((s_hi - s_lo) / DS).ceil() as usize + 1;
    let mut slices: Vec<Vec<f64>> = vec![Vec::new(); ns];
    for q in so {
        slices[(((q[0] - s_lo) / DS) as usize).min(ns - 1)].push(q[1]);
    }
    // Runs per slice: (lo, hi, count).
    let mut runs: Vec<Vec<(f64, f64, usize)>> = Vec::with_capacity(ns);
    for sl in &mut slices {
        sl.sort_unstable_by(f64::total_cmp);
        let mut r: Vec<(f64, f64, usize)> = Vec::new();
        // Gap threshold from the slice's own sampling: sparse lines stay one run.
        let n = sl.len();
        let gap = if n >= 2 {
            let mut d: Vec<f64> = sl.windows(2).map(|w| w[1] - w[0]).collect();
            (1.5 * geom::median(&mut d)).clamp(0.1, 0.2)
        } else {
            0.1
        };
        for &o in sl.iter() {
            match r.last_mut() {
                Some(l) if o - l.1 <= gap => {
                    l.1 = o;
                    l.2 += 1;
                }
                _ => r.push((o, o, 1)),
            }
        }
        r.retain(|q| q.1 - q.0 <= p.line_max_width_m);
        runs.push(r);
    }
    // DP: best[k][j] = (track length in slices, previous (k, j), offset change per slice).
    // A run continues a track when it lies at the track's offset or where the track's
    // slope leads (a ramp's line diverging from the drive drifts ~0.07 m per slice, and
    // across the 2-4 slices a gore's chevrons block that exceeds the plain tolerance).
    type Back = Option<(usize, usize)>;
    let mut best: Vec<Vec<(usize, Back, f64)>> = runs.iter().map(|r| vec![(1, None, 0.0); r.len()]).collect();
    for k in 0..ns {
        for j in 0..runs[k].len() {
            let c = 0.5 * (runs[k][j].0 + runs[k][j].1);
            let mut b = (1usize, None, 0.0);
            for back in 1..=MAX_SKIP + 1 {
                if back > k {
                    break;
                }
                let kk = k - back;
                let tol = 0.1 + 0.02 * (back - 1) as f64;
                for (jj, r) in runs[kk].iter().enumerate() {
                    let cc = 0.5 * (r.0 + r.1);
                    let (len, _, slope) = best[kk][jj];
                    let led = (c - (cc + slope * back as f64)).abs() <= tol;
                    if ((c - cc).abs() <= tol || led) && len + 1 > b.0 {
                        let step = ((c - cc) / back as f64).clamp(-MAX_DRIFT_PER_SLICE, MAX_DRIFT_PER_SLICE);
                        let slope = if len == 1 { step } else { 0.5 * (slope + step) };
                        b = (len + 1, Some((kk, jj)), slope);
                    }
                }
            }
            best[k][j] = b;
        }
    }
    let (mut k, mut j) = (0..ns)
        .flat_map(|k| (0..runs[k].len()).map(move |j| (k, j)))
        .max_by(|a, b| best[a.0][a.1].0.cmp(&best[b.0][b.1].0).then(b.cmp(a)))?;
    let mut path: Vec<(f64, f64, f64)> = Vec::new(); // (s centre, o centre, width)
    loop {
        let r = runs[k][j];
        path.push((s_lo + (k as f64 + 0.5) * DS, 0.5 * (r.0 + r.1), r.1 - r.0));
        match best[k][j].1 {
            Some((kk, jj)) => {
                k = kk;
                j = jj;
            }
            None => break,
        }
    }
    path.reverse();
    let (t0, t1) = (path[0].0 - DS / 2.0, path[path.len() - 1].0 + DS / 2.0);
    if t1 - t0 < p.solid_min_length_m {
        return None;
    }
    let mut ws: Vec<f64> = path.iter().map(|q| q.2).collect();
    let half = geom::median(&mut ws) / 2.0 + 0.03;
    let ps: Vec<f64> = path.iter().map(|q| q.0).collect();
    let po: Vec<f64> = path.iter().map(|q| q.1).collect();
    Some(move |q: [f64; 2]| {
        if q[0] < t0 || q[0] > t1 {
            return f64::INFINITY;
        }
        (q[1] - geom::interp_clamped(&ps, &po, q[0])).abs() - half
    })
}

/// Summary of a piece for re-joining: ends and offsets in the trajectory frame.
struct End {
    s0: f64,
    s1: f64,
    o0: f64,
    o1: f64,
    slope: f64,
    width: f64,
}

fn piece_end(c: &Candidate, p: &Params) -> Option<End> {
    if let Some(l) = &c.line {
        let (a, b) = (l.stations[0], l.stations[l.stations.len() - 1]);
        let slope = if b[0] - a[0] > 1e-6 {
            (b[1] - a[1]) / (b[0] - a[0])
        } else {
            0.0
        };
        return Some(End {
            s0: a[0],
            s1: b[0],
            o0: a[1],
            o1: b[1],
            slope,
            width: l.width_m,
        });
    }
    // A short narrow fragment (too short for the line test) may still belong to a line.
    let s = &c.shape;
    if s.length_m <= 1.5 && s.width_m <= p.line_max_width_m && s.point_count >= 3 {
        let half = s.length_m / 2.0 * (1.0 - s.angle_to_trajectory_deg.to_radians().sin()).max(0.3);
        return Some(End {
            s0: s.mileage_m - half,
            s1: s.mileage_m + half,
            o0: s.offset_m,
            o1: s.offset_m,
            slope: 0.0,
            width: s.width_m.min(s.length_m),
        });
    }
    None
}

/// Points per metre below which a line piece counts as sparse for the re-joining.
/// A lane line near the scanner holds hundreds per metre; one 25 m out, 5–20.
pub const SPARSE_LINE_POINTS_PER_M: f64 = 40.0;

/// Merge broken pieces of one line (mutual best successor within `join_gap_m`).
fn rejoin(
    feats: Vec<Candidate>,
    xy: &[[f64; 2]],
    intensity: &[f32],
    refl: &RefLine,
    p: &Params,
) -> Vec<Candidate> {
    if p.join_gap_m <= 0.0 {
        return feats;
    }
    let ends: Vec<Option<End>> = feats.iter().map(|c| piece_end(c, p)).collect();
    let mut order: Vec<usize> = (0..feats.len()).filter(|&i| ends[i].is_some()).collect();
    order.sort_by(|&a, &b| {
        let (ea, eb) = (ends[a].as_ref().expect("end"), ends[b].as_ref().expect("end"));
        ea.s0.total_cmp(&eb.s0).then(a.cmp(&b))
    });
    // Sparse line pieces may be joined across longer gaps (`join_sparse_gap_m`).
    let sparse: Vec<bool> = feats
        .iter()
        .map(|c| {
            c.line.as_ref().is_some_and(|l| {
                (c.shape.point_count as f64) < SPARSE_LINE_POINTS_PER_M * l.length_m.max(c.shape.length_m)
            })
        })
        .collect();
    let window = p.join_gap_m.max(p.join_sparse_gap_m);
    let cost = |a: usize, b: usize| -> Option<f64> {
        let (ea, eb) = (ends[a].as_ref()?, ends[b].as_ref()?);
        let gap = eb.s0 - ea.s1;
        let limit = if sparse[a] && sparse[b] {
            window
        } else {
            p.join_gap_m
        };
        if gap < -0.2 || gap > limit {
            return None;
        }
        let pred = ea.o1 + ea.slope * gap.max(0.0);
        let dev = (eb.o0 - pred).abs();
        let wmax = ea.width.max(eb.width).max(0.05);
        let tol = 0.5 * wmax + 0.03;
        if dev > tol
            || ea.width.min(eb.width) < 0.4 * wmax && feats[a].line.is_some() && feats[b].line.is_some()
        {
            return None;
        }
        Some(dev / tol + gap.max(0.0) / limit)
    };
    // Candidate successors are the next pieces in mileage order (window bounded by the gap).
    let mut links = Vec::new();
    for (oi, &a) in order.iter().enumerate() {
        let ea = ends[a].as_ref().expect("end");
        for &b in &order[oi + 1..] {
            let eb = ends[b].as_ref().expect("end");
            if eb.s0 > ea.s1 + window {
                break;
            }
            if let Some(c) = cost(a, b) {
                links.push((a, b, c));
            }
        }
    }
    let pairs = mutual_best(feats.len(), &links);
    merge_pairs(feats, &pairs, xy, intensity, refl, p)
}

/// The links `(a, b, cost)` (a before b) that are both a's cheapest link to a successor
/// and b's cheapest link to a predecessor (the first listed wins a tie).
fn mutual_best(n: usize, links: &[(usize, usize, f64)]) -> Vec<(usize, usize)> {
    let mut best_next: Vec<Option<(f64, usize)>> = vec![None; n];
    let mut best_prev: Vec<Option<(f64, usize)>> = vec![None; n];
    for &(a, b, c) in links {
        if best_next[a].is_none_or(|(bc, _)| c < bc) {
            best_next[a] = Some((c, b));
        }
        if best_prev[b].is_none_or(|(bc, _)| c < bc) {
            best_prev[b] = Some((c, a));
        }
    }
    (0..n)
        .filter_map(|a| best_next[a].map(|(_, b)| (a, b)))
        .filter(|&(a, b)| best_prev[b].map(|x| x.1) == Some(a))
        .collect()
}

/// Merge the candidates linked by `pairs` (transitively) into one each, described anew.
fn merge_pairs(
    feats: Vec<Candidate>,
    pairs: &[(usize, usize)],
    xy: &[[f64; 2]],
    intensity: &[f32],
    refl: &RefLine,
    p: &Params,
) -> Vec<Candidate> {
    if pairs.is_empty() {
        return feats;
    }
    let n = feats.len();
    let mut parent: Vec<usize> = (0..n).collect();
    for &(a, b) in pairs {
        geom::union(&mut parent, a, b);
    }
    let mut groups: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
    for i in 0..n {
        let r = geom::find_root(&mut parent, i);
        groups.entry(r).or_default().push(i);
    }
    let mut slots: Vec<Option<Candidate>> = feats.into_iter().map(Some).collect();
    let (single, multi): (Vec<Vec<usize>>, Vec<Vec<usize>>) =
        groups.into_values().partition(|g| g.len() == 1);
    let mut out: Vec<Candidate> = single
        .into_iter()
        .map(|g| slots[g[0]].take().expect("each candidate once"))
        .collect();
    let merged: Vec<Vec<usize>> = multi
        .into_iter()
        .map(|g| {
            g.into_iter()
                .flat_map(|i| slots[i].take().expect("each candidate once").indices)
                .collect()
        })
        .collect();
    let described: Vec<Candidate> = merged
        .into_par_iter()
        .map(|idx| describe(xy, intensity, idx, refl, p))
        .collect();
    out.extend(described);
    out
}

/// Smallest angle (deg) to the trajectory of a fragment of a bar across the road.
const ACROSS_MIN_ANGLE_DEG: f64 = 60.0;
/// Longest fragment (m) re-joined across the road: stripes are 2.5-6 m long.
const ACROSS_MAX_FRAGMENT_M: f64 = 3.0;

/// Merge the collinear pieces of one bar across the road (mutual best match). At long
/// range the scan rows run along a zebra stripe across a side street and break it into
/// 0.5-2 m pieces end to end; one by one they are blobs, noise or nothing, and the
/// crossing is never recognised. Pieces across the trajectory (≥ [`ACROSS_MIN_ANGLE_DEG`]),
/// no wider than a crosswalk stripe and at most [`ACROSS_MAX_FRAGMENT_M`] long, whose
/// centres lie at the same mileage (within half their width + 3 cm) and whose ends are at
/// most `join_gap_m` apart across the road, of similar width (ratio ≥ 0.6), are one bar.
/// Side-by-side stripes (about 1 m apart in mileage) and a stop line before the crossing
/// are never at the same mileage.
fn rejoin_across(
    feats: Vec<Candidate>,
    xy: &[[f64; 2]],
    intensity: &[f32],
    refl: &RefLine,
    p: &Params,
) -> Vec<Candidate> {
    if p.join_gap_m <= 0.0 {
        return feats;
    }
    // (mileage, offset from, offset to, width) of the across fragments.
    let ends: Vec<Option<[f64; 4]>> = feats
        .iter()
        .map(|c| {
            let s = &c.shape;
            (s.angle_to_trajectory_deg >= ACROSS_MIN_ANGLE_DEG
                && s.length_m <= ACROSS_MAX_FRAGMENT_M
                && s.width_m <= p.crosswalk_max_width_m
                && s.point_count >= 3)
                .then(|| {
                    let half = 0.5 * s.length_m * s.angle_to_trajectory_deg.to_radians().sin();
                    [s.mileage_m, s.offset_m - half, s.offset_m + half, s.width_m]
                })
        })
        .collect();
    let mut order: Vec<usize> = (0..feats.len()).filter(|&i| ends[i].is_some()).collect();
    order.sort_by(|&a, &b| {
        let (ea, eb) = (ends[a].expect("end"), ends[b].expect("end"));
        ea[0].total_cmp(&eb[0]).then(a.cmp(&b))
    });
    // Links from the inner piece to the outer one across the road: mutual best links
    // chain the pieces of one bar like beads.
    let mut links = Vec::new();
    for (oi, &a) in order.iter().enumerate() {
        let ea = ends[a].expect("end");
        for &b in &order[oi + 1..] {
            let eb = ends[b].expect("end");
            let tol = 0.5 * ea[3].max(eb[3]) + 0.03;
            let ds = eb[0] - ea[0];
            if ds > tol {
                break;
            }
            // Gap between the two offset ranges (negative: they overlap).
            let gap = (eb[1] - ea[2]).max(ea[1] - eb[2]);
            if gap < -0.2 || gap > p.join_gap_m || ea[3].min(eb[3]) < 0.6 * ea[3].max(eb[3]) {
                continue;
            }
            let cost = ds.abs() / tol + gap.max(0.0) / p.join_gap_m;
            let (inner, outer) = if ea[1] + ea[2] <= eb[1] + eb[2] {
                (a, b)
            } else {
                (b, a)
            };
            links.push((inner, outer, cost));
        }
    }
    let pairs = mutual_best(feats.len(), &links);
    merge_pairs(feats, &pairs, xy, intensity, refl, p)
}

/// Membership of `v` in [lo, hi] with soft shoulders: 1 well inside, falling to 0.5 at the
/// bounds.
fn inside(v: f64, lo: f64, hi: f64) -> f64 {
    let span = (hi - lo).max(1e-9);
    let m = ((v - lo).min(hi - v) / (0.25 * span)).clamp(0.0, 1.0);
    0.5 + 0.5 * m
}

/// Apply the rules to one described candidate.
fn rule(mut c: Candidate, p: &Params) -> (Candidate, Option<DropReason>) {
    let s = &c.shape;
    let area = s.length_m * s.width_m * s.fill_ratio;
    if s.point_count < p.min_points || area < p.min_area_m2 {
        return (c, Some(DropReason::Tiny));
    }
    let aspect = s.length_m / s.width_m.max(1e-3);
    if let Some(l) = &c.line {
        // Sparse far-range paint is sampled by one or two points per scan line, so the
        // measured extent of the residuals under-reads the painted width by about one point
        // spacing: a line is judged by extent + spacing (capped, so scattered noise is not
        // made wide).
        let eff_width = l.width_m + s.spacing_m.min(0.1);
        // Narrower than any painted line even so: a sliver or a single row of points.
        if eff_width < 0.05 {
            c.class = MarkingClass::Unknown;
            c.confidence = 0.2;
            return (c, None);
        }
        if l.width_m <= p.line_max_width_m {
            let ratio = l.length_m / eff_width.max(0.05);
            let wq = inside(eff_width.min(p.line_max_width_m), 0.06, p.line_max_width_m);
            let stripe = l.width_m >= p.crosswalk_min_width_m
                && l.width_m <= p.crosswalk_max_width_m
                && (1.5..=10.0).contains(&l.length_m);
            if stripe {
                // A wide dash or a zebra stripe: `confirm_groups` decides by its neighbours
                // (stripes side by side across the road, dashes one after the other).
                c.class = MarkingClass::Crosswalk;
                c.confidence = 0.8 * inside(l.width_m, p.crosswalk_min_width_m, p.crosswalk_max_width_m);
            } else if l.length_m >= p.solid_min_length_m && ratio >= p.solid_min_ratio {
                c.class = MarkingClass::SolidLine;
                c.confidence = (0.75 + 0.25 * (l.length_m / (2.0 * p.solid_min_length_m)).min(1.0)) * wq;
            } else if l.length_m >= p.dash_min_length_m {
                c.class = MarkingClass::DashedLine;
                c.confidence = 0.85 * wq * (0.7 + 0.3 * s.fill_ratio.min(1.0));
            } else {
                c.class = MarkingClass::Unknown;
                c.confidence = 0.3;
            }
            return (c, None);
        }
    }
    if s.length_m <= p.blob_max_size_m && aspect < 1.6 {
        return (c, Some(DropReason::Blob));
    }
    let bar = s.fill_ratio >= 0.65 && aspect >= 2.5;
    let ang = s.angle_to_trajectory_deg;
    if stop_line_shaped(s, p) && s.length_m >= 1.5 {
        c.class = MarkingClass::StopLine;
        c.confidence = 0.8 * inside(s.width_m, p.stop_min_width_m, p.stop_max_width_m);
        return (c, None);
    }
    if bar
        && ang <= 25.0
        && s.width_m >= p.crosswalk_min_width_m
        && s.width_m <= p.crosswalk_max_width_m
        && (1.5..=10.0).contains(&s.length_m)
    {
        // Confirmed by a neighbour stripe in `confirm_groups`; `Crosswalk` marks the candidate.
        c.class = MarkingClass::Crosswalk;
        c.confidence = 0.8 * inside(s.width_m, p.crosswalk_min_width_m, p.crosswalk_max_width_m);
        return (c, None);
    }
    if bar && ang > 25.0 && ang < 65.0 && (0.25..=0.8).contains(&s.width_m) && s.length_m >= 1.0 {
        c.class = MarkingClass::Guideline;
        c.confidence = 0.7;
        return (c, None);
    }
    if aspect >= 3.0 && ang > p.noise_angle_deg && (s.fill_ratio >= 0.5 || s.width_m < 0.12) {
        return (c, Some(DropReason::SteepNoise));
    }
    c.class = MarkingClass::Unknown;
    c.confidence = 0.4;
    (c, None)
}

/// Two stripes of one group: centres ≤ `max_d` apart, parallel, similar size, side by side
/// (not one after the other).
fn stripe_neighbours(a: &Shape, b: &Shape, max_d: f64) -> bool {
    similar_stripes(a, b, max_d)
        && ((b.center[0] - a.center[0]) * a.axis[0] + (b.center[1] - a.center[1]) * a.axis[1]).abs()
            <= 0.5 * a.length_m.max(b.length_m)
}

/// Two stripes of one group, wherever the one lies from the other: centres ≤ `max_d`
/// apart, parallel, similar size.
fn similar_stripes(a: &Shape, b: &Shape, max_d: f64) -> bool {
    (a.center[0] - b.center[0]).hypot(a.center[1] - b.center[1]) <= max_d
        && geom::acute_angle_deg(a.axis, b.axis) <= 10.0
        && a.width_m.min(b.width_m) >= 0.6 * a.width_m.max(b.width_m)
        && a.length_m.min(b.length_m) >= 0.5 * a.length_m.max(b.length_m)
}

/// Two guideline stripes of one hatched area: like [`stripe_neighbours`], but the next
/// stripe lies along the road (within [`CHEVRON_REPEAT_MAX_DEG`] of the driving direction)
/// rather than side by side. Chevrons at 45° to the road, 2.5 m apart along it, are each
/// shifted 1.8 m along their own axis from the next: more than half the length of those
/// near the gore's tip (1.6-2.8 m), which the side-by-side test then left alone.
fn chevron_neighbours(a: &Shape, b: &Shape, max_d: f64) -> bool {
    let v = [b.center[0] - a.center[0], b.center[1] - a.center[1]];
    let d = v[0].hypot(v[1]);
    d > 0.0
        && similar_stripes(a, b, max_d)
        && geom::acute_angle_deg([v[0] / d, v[1] / d], a.driving_direction) <= CHEVRON_REPEAT_MAX_DEG
}

/// Largest angle (deg) between the driving direction and the step from one guideline
/// stripe to the next ([`chevron_neighbours`]).
const CHEVRON_REPEAT_MAX_DEG: f64 = 30.0;

/// Crosswalk and guideline stripes need a parallel neighbour of similar size; lone ones
/// become `unknown` (or noise when steep).
fn confirm_groups(items: &mut [(Candidate, Option<DropReason>)]) {
    // Zebra stripes across a side street run across the trajectory and look like stop
    // lines one by one; a stop line never has a parallel bar of its size beside it.
    let stops: Vec<usize> = (0..items.len())
        .filter(|&i| items[i].1.is_none() && items[i].0.class == MarkingClass::StopLine)
        .collect();
    let zebra: Vec<usize> = stops
        .iter()
        .copied()
        .filter(|&i| {
            stops
                .iter()
                .any(|&j| j != i && stripe_neighbours(&items[i].0.shape, &items[j].0.shape, 2.5))
        })
        .collect();
    for i in zebra {
        items[i].0.class = MarkingClass::Crosswalk;
        items[i].0.confidence = 0.75;
    }
    let kinds = [MarkingClass::Crosswalk, MarkingClass::Guideline];
    let mut verdict: Vec<Option<bool>> = vec![None; items.len()];
    for kind in kinds {
        let idx: Vec<usize> = (0..items.len())
            .filter(|&i| items[i].1.is_none() && items[i].0.class == kind)
            .collect();
        let max_d = if kind == MarkingClass::Crosswalk { 2.5 } else { 6.0 };
        for &i in &idx {
            let a = &items[i].0.shape;
            let ok = idx.iter().any(|&j| {
                let b = &items[j].0.shape;
                j != i
                    && (stripe_neighbours(a, b, max_d)
                        || (kind == MarkingClass::Guideline && chevron_neighbours(a, b, max_d)))
            });
            verdict[i] = Some(ok);
        }
    }
    for (i, v) in verdict.into_iter().enumerate() {
        if v == Some(false) {
            let (c, d) = &mut items[i];
            if c.class == MarkingClass::Guideline && c.shape.angle_to_trajectory_deg > 45.0 {
                *d = Some(DropReason::SteepNoise);
            }
            if c.class == MarkingClass::Crosswalk && c.line.is_some() {
                // A lone wide stripe along the road is a wide dash.
                c.class = MarkingClass::DashedLine;
                c.confidence = 0.7;
            } else {
                c.class = MarkingClass::Unknown;
                c.confidence = 0.4;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::types::test_straight_trajectory;

    /// A straight trajectory along +x.
    fn refl() -> RefLine {
        RefLine::new(&test_straight_trajectory(60, -10.0))
    }

    /// Points on a 3 cm grid where `inside(x, y)`, for x in 0..len, |y - 2| < 0.5.
    fn paint(len: f64, inside: impl Fn(f64, f64) -> bool) -> Vec<[f64; 2]> {
        let mut v = Vec::new();
        for i in 0..=(len / 0.03) as usize {
            for j in 0..=33 {
                let (x, y) = (i as f64 * 0.03, j as f64 * 0.03 - 0.5);
                if inside(x, y) {
                    v.push([x, 2.0 + y]);
                }
            }
        }
        v
    }

    /// Appends points on a 3 cm grid over [x0, x1] × [y0, y1] to `xy`; their indices.
    fn block(xy: &mut Vec<[f64; 2]>, x0: f64, x1: f64, y0: f64, y1: f64) -> Vec<usize> {
        let start = xy.len();
        let mut x = x0;
        while x <= x1 {
            let mut y = y0;
            while y <= y1 {
                xy.push([x, y]);
                y += 0.03;
            }
            x += 0.03;
        }
        (start..xy.len()).collect()
    }

    /// Points every 3 cm filling a bar `len` long and `width` wide from `from` along the
    /// unit vector `axis` (centred on that line); their indices.
    fn bar_along(xy: &mut Vec<[f64; 2]>, from: [f64; 2], axis: [f64; 2], len: f64, width: f64) -> Vec<usize> {
        let start = xy.len();
        let n = [-axis[1], axis[0]];
        let mut a = 0.0;
        while a <= len {
            let mut q = -width / 2.0;
            while q <= width / 2.0 {
                xy.push([from[0] + a * axis[0] + q * n[0], from[1] + a * axis[1] + q * n[1]]);
                q += 0.03;
            }
            a += 0.03;
        }
        (start..xy.len()).collect()
    }

    /// A crack-sealant streak (5 cm wide, wandering ±0.3 m about a line at 35° to the
    /// drive) left `unknown` is dropped; a filled stripe at the same angle, the same
    /// streak run along the drive, and a streak classed a dash are kept.
    #[test]
    fn thin_strokes_across_the_road_are_dropped() {
        let (r, p) = (refl(), Params::default());
        let mut xy: Vec<[f64; 2]> = Vec::new();
        let (sa, ca) = 35f64.to_radians().sin_cos();
        let mut stroke = |along: bool| -> Vec<usize> {
            let start = xy.len();
            for i in 0..=200 {
                let t = i as f64 * 0.03;
                let wander = 0.3 * (t * 1.3).sin();
                for k in 0..3 {
                    let (u, v) = (t, wander + (k as f64 - 1.0) * 0.025);
                    xy.push(if along {
                        [u + 20.0, v + 5.0]
                    } else {
                        [u * ca - v * sa, u * sa + v * ca]
                    });
                }
            }
            (start..xy.len()).collect()
        };
        let streak = stroke(false);
        let along = stroke(true);
        let stripe_at = xy.len();
        for i in 0..=100 {
            for j in 0..=13 {
                let (u, v) = (i as f64 * 0.03, j as f64 * 0.03);
                xy.push([10.0 + u * ca - v * sa, u * sa + v * ca]);
            }
        }
        let stripe: Vec<usize> = (stripe_at..xy.len()).collect();
        let intensity = vec![100.0f32; xy.len()];
        let mut cands: Vec<Candidate> = [&streak, &along, &stripe, &streak]
            .iter()
            .map(|g| describe(&xy, &intensity, (*g).clone(), &r, &p))
            .collect();
        cands[3].class = MarkingClass::DashedLine;
        assert!(
            cands[0].shape.angle_to_trajectory_deg > 30.0,
            "{:?}",
            cands[0].shape
        );
        assert_eq!(drop_thin_strokes(&mut cands, &p), 1);
        assert_eq!(cands.len(), 3);
        assert_eq!(cands[0].indices, along);
        assert_eq!(cands[1].indices, stripe);
        assert_eq!(cands[2].class, MarkingClass::DashedLine);
    }

    /// Each group of points described as a kept candidate (no drop reason).
    fn kept(
        xy: &[[f64; 2]],
        intensity: &[f32],
        groups: &[Vec<usize>],
        r: &RefLine,
        p: &Params,
    ) -> Vec<(Candidate, Option<DropReason>)> {
        groups
            .iter()
            .map(|g| (describe(xy, intensity, g.clone(), r, p), None))
            .collect()
    }

    /// Two worn pieces of one mark 0.3 m apart and a dropped fragment 0.3 m from them share
    /// one `whole` (their union); a piece 2 m away gets none.
    #[test]
    fn nearby_unknown_fragments_are_offered_whole() {
        let (r, p) = (refl(), Params::default());
        let mut xy: Vec<[f64; 2]> = Vec::new();
        let mut block = |x0, x1, y0, y1| block(&mut xy, x0, x1, y0, y1);
        let groups = [
            block(10.0, 11.0, 1.0, 1.5),
            block(11.3, 12.0, 1.2, 1.8),
            block(14.0, 14.6, 1.0, 1.4),
            block(12.3, 12.6, 1.0, 1.3),
        ];
        let intensity = vec![100.0f32; xy.len()];
        let mut items = kept(&xy, &intensity, &groups, &r, &p);
        items[3].1 = Some(DropReason::Tiny);
        group_fragments(&mut items, &xy, &intensity, &r, &p);
        let (a, b) = (
            items[0].0.whole.as_ref().expect("grouped"),
            items[1].0.whole.as_ref().expect("grouped"),
        );
        assert!(Arc::ptr_eq(a, b));
        assert!(Arc::ptr_eq(a, items[3].0.whole.as_ref().expect("grouped")));
        assert_eq!(
            a.indices.len(),
            groups[0].len() + groups[1].len() + groups[3].len()
        );
        assert!(items[2].0.whole.is_none());
    }

    /// A sparsely scanned arrow: its shaft passed for a dash and its head was dropped as a
    /// blob; 0.3 m apart they are offered whole. Two dashes 0.3 m apart are not (no
    /// unknown piece among them), nor a dropped blob beside a dropped tiny fragment (no
    /// kept piece to carry the whole).
    #[test]
    fn a_dash_like_shaft_and_a_dropped_head_are_offered_whole() {
        let (r, p) = (refl(), Params::default());
        let mut xy: Vec<[f64; 2]> = Vec::new();
        let mut block = |x0, x1, y0, y1| block(&mut xy, x0, x1, y0, y1);
        let groups = [
            block(10.0, 12.0, 1.0, 1.15), // shaft
            block(12.3, 12.9, 0.8, 1.4),  // head
            block(20.0, 22.0, 1.0, 1.15), // dash
            block(22.3, 24.3, 1.0, 1.15), // dash
            block(30.0, 30.6, 1.0, 1.6),  // blob
            block(30.9, 31.2, 1.0, 1.1),  // tiny
        ];
        let intensity = vec![100.0f32; xy.len()];
        let mut items = kept(&xy, &intensity, &groups, &r, &p);
        for k in [0, 2, 3] {
            items[k].0.class = MarkingClass::DashedLine;
        }
        items[1].1 = Some(DropReason::Blob);
        items[4].1 = Some(DropReason::Blob);
        items[5].1 = Some(DropReason::Tiny);
        group_fragments(&mut items, &xy, &intensity, &r, &p);
        let shaft = items[0].0.whole.as_ref().expect("shaft grouped");
        assert!(Arc::ptr_eq(
            shaft,
            items[1].0.whole.as_ref().expect("head grouped")
        ));
        assert_eq!(shaft.indices.len(), groups[0].len() + groups[1].len());
        assert!(items[2..].iter().all(|(c, _)| c.whole.is_none()));
    }

    /// A 9 m arrow's shaft (0.3 m wide, along the road over x 10..18) and head (0.8 m
    /// wide at its base, 18..19.5).
    fn shaft_and_head(xy: &mut Vec<[f64; 2]>) -> (Vec<usize>, Vec<usize>) {
        (
            block(xy, 10.0, 18.0, 1.0, 1.3),
            block(xy, 18.03, 19.5, 0.75, 1.55),
        )
    }

    /// A 10 m bar across the road (0.25 m wide from `x0`, an expansion joint), without its
    /// points where it crosses the marks at y in `on_marks`.
    fn bar_across(xy: &mut Vec<[f64; 2]>, x0: f64, on_marks: std::ops::RangeInclusive<f64>) -> Vec<usize> {
        let bar = block(xy, x0, x0 + 0.25, -4.0, 6.0);
        bar.into_iter()
            .filter(|&i| !on_marks.contains(&xy[i][1]))
            .collect()
    }

    /// [`peel_lines`] on the cluster of `parts`, and its pieces' point counts, lengths and
    /// their wholes' point counts (for failure messages).
    fn peel_parts(xy: &[[f64; 2]], parts: &[&[usize]]) -> (Vec<Candidate>, String) {
        let (r, p) = (refl(), Params::default());
        let intensity = vec![100.0f32; xy.len()];
        let whole = describe(xy, &intensity, parts.concat(), &r, &p);
        assert!(whole.line.is_none());
        let out = peel_lines(whole, xy, &intensity, &r, &p);
        let summary: Vec<_> = out
            .iter()
            .map(|c| {
                (
                    c.indices.len(),
                    c.shape.length_m,
                    c.whole.as_ref().map(|w| w.indices.len()),
                )
            })
            .collect();
        (out, format!("{summary:?}"))
    }

    /// A 9 m arrow crossed by a bar across the road (an expansion joint, 10 m long), with a
    /// 1.3 m turning branch leaving the shaft square to it: the shaft is peeled, and the
    /// arrow's pieces (shaft, head, branch) share a whole without the bar's pieces; the
    /// bar's pieces have none. Before, the whole held the bar too and the network read it
    /// as a turn arrow.
    #[test]
    fn a_bar_across_an_arrow_is_no_part_of_its_whole() {
        let mut xy: Vec<[f64; 2]> = Vec::new();
        let (shaft, head) = shaft_and_head(&mut xy);
        let branch = block(&mut xy, 12.0, 12.25, 1.33, 2.6);
        let bar = bar_across(&mut xy, 14.0, 0.99..=1.31);
        let (out, summary) = peel_parts(&xy, &[&shaft, &head, &branch, &bar]);
        let on_bar = |c: &Candidate| c.indices.iter().all(|i| bar.contains(i));
        let bar_pieces: Vec<&Candidate> = out.iter().filter(|c| on_bar(c)).collect();
        assert!(
            !bar_pieces.is_empty() && bar_pieces.iter().all(|c| c.whole.is_none()),
            "{summary}"
        );
        let arrow: Vec<&Candidate> = out.iter().filter(|c| !on_bar(c)).collect();
        assert!(arrow.len() >= 3, "shaft, head and branch: {summary}");
        let w = arrow[0].whole.as_ref().expect("the arrow has a whole");
        assert!(
            arrow
                .iter()
                .all(|c| c.whole.as_ref().is_some_and(|v| Arc::ptr_eq(v, w)))
        );
        // Of the bar, only the ragged edge beside the peeled shaft (in no piece) is left.
        let left: Vec<f64> = w
            .indices
            .iter()
            .filter(|i| bar.contains(i))
            .map(|&i| xy[i][1])
            .collect();
        assert!(
            left.iter().all(|y| (y - 1.15).abs() <= 0.3),
            "bar points in the whole: {left:?}"
        );
        for part in [&shaft, &head, &branch] {
            assert!(part.iter().all(|i| w.indices.contains(i)), "{summary}");
        }
    }

    /// The same arrow in one cluster with a 40 m edge line (an arrow whose branch touched the
    /// line): the line and the shaft are peeled as line tracks, the head is left. The
    /// cluster is too long to be the arrow's whole, yet shaft and head share one, without
    /// the line; the line has none. Before, neither piece had a whole, and the shaft alone
    /// went to the learned classifier.
    #[test]
    fn an_arrow_in_a_long_lines_cluster_keeps_a_whole() {
        let mut xy: Vec<[f64; 2]> = Vec::new();
        let (shaft, head) = shaft_and_head(&mut xy);
        let line = block(&mut xy, 0.0, 40.0, -2.0, -1.85);
        let (out, summary) = peel_parts(&xy, &[&shaft, &head, &line]);
        let piece_of = |i: usize| out.iter().find(|c| c.indices.contains(&i)).expect("in a piece");
        assert!(piece_of(line[0]).whole.is_none(), "{summary}");
        let w = piece_of(shaft[0]).whole.as_ref().expect("the shaft has a whole");
        let h = piece_of(head[head.len() / 2])
            .whole
            .as_ref()
            .expect("the head has a whole");
        assert!(Arc::ptr_eq(w, h), "{summary}");
        assert!(w.indices.iter().all(|i| !line.contains(i)), "{summary}");
        assert!(
            w.indices.len() * 10 >= (shaft.len() + head.len()) * 9,
            "{summary}"
        );
    }

    /// The same arrow without a branch, the 10 m bar crossing its head instead of its
    /// shaft: head and bar are one component of what is left once the shaft is peeled, so
    /// the bar is peeled too (a run of near-constant mileage across the offsets), and the
    /// whole of shaft and head (both its parts, 0.45 m apart across the bar) holds none of
    /// it.
    #[test]
    fn a_bar_through_an_arrowhead_is_peeled_off_it() {
        let mut xy: Vec<[f64; 2]> = Vec::new();
        let (shaft, head) = shaft_and_head(&mut xy);
        let bar = bar_across(&mut xy, 18.6, 0.74..=1.56);
        let (out, summary) = peel_parts(&xy, &[&shaft, &head, &bar]);
        let on_bar =
            |c: &Candidate| c.indices.iter().filter(|i| bar.contains(i)).count() * 2 > c.indices.len();
        let bar_pieces: Vec<&Candidate> = out.iter().filter(|c| on_bar(c)).collect();
        assert!(
            !bar_pieces.is_empty() && bar_pieces.iter().all(|c| c.whole.is_none()),
            "{summary}"
        );
        let w = out
            .iter()
            .find(|c| c.indices.contains(&shaft[0]))
            .and_then(|c| c.whole.as_ref())
            .expect("the shaft has a whole");
        // The head on both sides of the bar (under it and its ragged edges, in no piece).
        for side in [18.0..18.45, 19.0..19.5] {
            let part: Vec<usize> = head
                .iter()
                .copied()
                .filter(|&i| side.contains(&xy[i][0]))
                .collect();
            assert!(part.iter().all(|i| w.indices.contains(i)), "{summary}");
        }
        let left = w.indices.iter().filter(|i| bar.contains(i)).count();
        assert!(
            left * 20 < bar.len(),
            "{left} of the bar's {} points in the whole",
            bar.len()
        );
    }

    /// The same sparse arrow with a lane line passing 0.35 m from its head, the line in
    /// 2–4 m pieces 1 m apart over 12.5 m: the line's pieces are no part of the arrow's
    /// group (their union with it would be no object), the shaft and head still are. A
    /// shaft broken in two (two pieces in line over 4 m) is no lane line.
    #[test]
    fn pieces_of_a_long_line_are_not_grouped_with_an_arrow_beside_it() {
        let mut xy: Vec<[f64; 2]> = Vec::new();
        // Shaft and head, then the line's pieces.
        let mut groups = vec![
            block(&mut xy, 10.0, 12.0, 1.0, 1.15),
            block(&mut xy, 12.3, 12.9, 0.8, 1.4),
        ];
        for (x0, x1) in [(6.0, 10.5), (11.5, 13.5), (14.5, 18.5)] {
            groups.push(block(&mut xy, x0, x1, 1.75, 1.9));
        }
        let intensity = vec![100.0f32; xy.len()];
        let (r, p) = (refl(), Params::default());
        let mut items = kept(&xy, &intensity, &groups, &r, &p);
        for k in [0, 2, 3, 4] {
            items[k].0.class = MarkingClass::DashedLine;
            assert!(items[k].0.line.is_some(), "piece {k} is a line piece");
        }
        items[1].1 = Some(DropReason::Blob);
        assert_eq!(in_long_lines(&items, &p), [false, false, true, true, true]);
        group_fragments(&mut items, &xy, &intensity, &r, &p);
        let shaft = items[0].0.whole.as_ref().expect("shaft grouped");
        assert_eq!(shaft.indices.len(), groups[0].len() + groups[1].len());
        assert!(items[2..].iter().all(|(c, _)| c.whole.is_none()));
        // Two pieces in line over 4 m: too short for a lane line.
        let mut two = kept(&xy, &intensity, &[groups[3].clone(), groups[4].clone()], &r, &p);
        two.iter_mut()
            .for_each(|(c, _)| c.class = MarkingClass::DashedLine);
        assert_eq!(in_long_lines(&two, &p), [false, false]);
    }

    /// The sparse arrow with a lane line's 4.5 m piece passing 0.35 m from its head, the
    /// line's other pieces too far away to chain (no long line): the group's whole holds the
    /// line piece, and the group without it (shaft and head) and without the shaft (head and
    /// line piece) are offered as alternatives, to the head and to the other remaining
    /// pieces; the left-out piece is given neither.
    #[test]
    fn a_group_is_also_offered_without_each_of_its_line_pieces() {
        let mut xy: Vec<[f64; 2]> = Vec::new();
        let groups = vec![
            block(&mut xy, 10.0, 12.0, 1.0, 1.15), // shaft
            block(&mut xy, 12.3, 12.9, 0.8, 1.4),  // head
            block(&mut xy, 9.5, 14.0, 1.75, 1.9),  // the lane line's piece
        ];
        let intensity = vec![100.0f32; xy.len()];
        let (r, p) = (refl(), Params::default());
        let mut items = kept(&xy, &intensity, &groups, &r, &p);
        for k in [0, 2] {
            items[k].0.class = MarkingClass::DashedLine;
            assert!(items[k].0.line.is_some(), "piece {k} is a line piece");
        }
        items[1].0.class = MarkingClass::Unknown;
        group_fragments(&mut items, &xy, &intensity, &r, &p);
        let whole = items[1].0.whole.as_ref().expect("grouped");
        assert_eq!(whole.indices.len(), xy.len());
        let sizes =
            |k: usize| -> Vec<usize> { items[k].0.alternatives.iter().map(|a| a.indices.len()).collect() };
        let (shaft, head, line) = (groups[0].len(), groups[1].len(), groups[2].len());
        // The longest line piece is left out first.
        assert_eq!(sizes(1), [shaft + head, head + line]);
        assert_eq!(sizes(0), [shaft + head]);
        assert_eq!(sizes(2), [head + line]);
        let (a, b) = (&items[0].0.alternatives[0], &items[1].0.alternatives[0]);
        assert!(Arc::ptr_eq(a, b), "one union shared by its pieces");
        // With no line piece in the group there is no alternative.
        let mut two = kept(
            &xy,
            &intensity,
            &groups[1..2]
                .iter()
                .chain(&groups[..1])
                .cloned()
                .collect::<Vec<_>>(),
            &r,
            &p,
        );
        two[1].0.class = MarkingClass::Unknown;
        two[0].0.class = MarkingClass::Unknown;
        group_fragments(&mut two, &xy, &intensity, &r, &p);
        assert!(two.iter().all(|(c, _)| c.alternatives.is_empty()));
    }

    /// A hatched area: four lines 2 m apart (more than the first three rounds peel) with
    /// 45° stripes between each pair, every line with stray points at its edges. All four
    /// lines are peeled and every stripe is a piece of its own.
    #[test]
    fn hatched_lines_are_all_peeled_and_their_stripes_come_apart() {
        let (r, p) = (refl(), Params::default());
        let mut xy: Vec<[f64; 2]> = Vec::new();
        let lines = [0.0, 2.0, 4.0, 6.0];
        for &o in &lines {
            for i in 0..=(40.0 / 0.03) as usize {
                let x = i as f64 * 0.03;
                for j in 0..=5 {
                    xy.push([x, o - 0.075 + j as f64 * 0.03]);
                }
                if i % 7 == 0 {
                    xy.push([x, o + 0.16]);
                    xy.push([x, o - 0.16]);
                }
            }
        }
        let mut stripes = 0;
        for pair in lines.windows(2) {
            for x0 in [6.0, 16.0, 26.0] {
                stripes += 1;
                let mut o = pair[0] + 0.1;
                while o < pair[1] - 0.1 {
                    let mut x = x0 + (o - pair[0]) - 0.3;
                    while x <= x0 + (o - pair[0]) + 0.3 {
                        xy.push([x, o]);
                        x += 0.03;
                    }
                    o += 0.03;
                }
            }
        }
        let intensity = vec![100.0f32; xy.len()];
        let whole = describe(&xy, &intensity, (0..xy.len()).collect(), &r, &p);
        assert!(whole.line.is_none());
        let out = peel_lines(whole, &xy, &intensity, &r, &p);
        let peeled: Vec<&Candidate> = out.iter().filter(|c| c.shape.length_m > 30.0).collect();
        assert_eq!(peeled.len(), lines.len(), "every line peeled");
        assert!(peeled.iter().all(|c| c.line.is_some() && c.shape.width_m < 0.4));
        let rest: Vec<&Candidate> = out.iter().filter(|c| c.shape.length_m <= 30.0).collect();
        let big: Vec<&Candidate> = rest.iter().copied().filter(|c| c.indices.len() > 100).collect();
        assert_eq!(big.len(), stripes, "one piece per stripe");
        assert!(
            big.iter()
                .all(|c| c.shape.length_m < 3.5 && c.shape.angle_to_trajectory_deg > 30.0)
        );
    }

    /// Two stripes leaving a line 3 m apart, chained along it by stray points just beyond
    /// the line's width (too short a run to be a line of their own): once the line is
    /// peeled, the strays go with no piece and the stripes are two pieces.
    #[test]
    fn the_ragged_edge_of_a_peeled_line_chains_nothing() {
        let (r, p) = (refl(), Params::default());
        let mut xy: Vec<[f64; 2]> = Vec::new();
        for i in 0..=(20.0 / 0.03) as usize {
            for j in 0..=5 {
                xy.push([i as f64 * 0.03, -0.075 + j as f64 * 0.03]);
            }
        }
        let mut x = 5.0;
        while x <= 11.0 {
            xy.push([x, 0.2]);
            x += 0.2;
        }
        for x0 in [6.0, 9.0] {
            let mut o = 0.1;
            while o < 2.0 {
                let mut x = x0 + o - 0.3;
                while x <= x0 + o + 0.3 {
                    xy.push([x, o]);
                    x += 0.03;
                }
                o += 0.03;
            }
        }
        let intensity = vec![100.0f32; xy.len()];
        let whole = describe(&xy, &intensity, (0..xy.len()).collect(), &r, &p);
        let out = peel_lines(whole, &xy, &intensity, &r, &p);
        let stripes = out
            .iter()
            .filter(|c| c.line.is_none() && c.indices.len() > 100)
            .count();
        assert_eq!(
            stripes,
            2,
            "{:?}",
            out.iter().map(|c| c.indices.len()).collect::<Vec<_>>()
        );
    }

    /// A gore's edge line diverging from the drive (offset +0.13 m per m, 7.4°) with 0.45 m
    /// chevrons leaving it at 75° every 2.2 m: the chevrons block 2-3 slices at a time,
    /// across which the line's offset drifts beyond the plain tolerance. Its slope leads
    /// the track on: the line is peeled and the ten chevrons come apart.
    #[test]
    fn a_diverging_line_with_chevrons_is_peeled() {
        let (r, p) = (refl(), Params::default());
        let mut xy: Vec<[f64; 2]> = Vec::new();
        let norm = 1.0f64.hypot(0.13);
        let u = [1.0 / norm, 0.13 / norm];
        bar_along(&mut xy, [0.0, 0.0], u, 24.0, 0.15);
        let (c75, s75) = (75f64.to_radians().cos(), 75f64.to_radians().sin());
        let w = [c75 * u[0] - s75 * u[1], s75 * u[0] + c75 * u[1]];
        for k in 0..10 {
            let b = [(1.0 + 2.2 * k as f64) * u[0], (1.0 + 2.2 * k as f64) * u[1]];
            bar_along(&mut xy, b, w, 2.5, 0.45);
        }
        let intensity = vec![100.0f32; xy.len()];
        let whole = describe(&xy, &intensity, (0..xy.len()).collect(), &r, &p);
        assert!(whole.line.is_none());
        let out = peel_lines(whole, &xy, &intensity, &r, &p);
        let summary: Vec<_> = out.iter().map(|c| (c.line.is_some(), c.indices.len())).collect();
        let lines: Vec<&Candidate> = out.iter().filter(|c| c.line.is_some()).collect();
        assert_eq!(lines.len(), 1, "{summary:?}");
        assert!(lines[0].shape.length_m > 20.0, "{:?}", lines[0].shape);
        let stripes = out
            .iter()
            .filter(|c| c.line.is_none() && c.indices.len() > 300)
            .count();
        assert_eq!(stripes, 10, "{summary:?}");
    }

    /// Chevrons at 45° to the road, 2.5 m apart along it and growing from 1.6 to 3.4 m
    /// long (a gore's tip): each is shifted 1.8 m along its own axis from the next, more
    /// than half the length of the short ones, yet all are confirmed as guideline stripes.
    /// A lone stripe is not.
    #[test]
    fn chevrons_repeated_along_the_road_confirm_each_other() {
        let (r, p) = (refl(), Params::default());
        let mut xy: Vec<[f64; 2]> = Vec::new();
        let c45 = std::f64::consts::FRAC_1_SQRT_2;
        // Lower ends on the line o = 1 at x = 10 + 2.5 k; then a lone stripe 30 m on.
        let mut groups: Vec<Vec<usize>> = [1.6, 2.0, 2.4, 2.8, 3.4]
            .into_iter()
            .enumerate()
            .map(|(k, len)| bar_along(&mut xy, [10.0 + 2.5 * k as f64, 1.0], [c45, c45], len, 0.4))
            .collect();
        groups.push(bar_along(&mut xy, [45.0, 1.0], [c45, c45], 1.8, 0.4));
        let intensity = vec![100.0f32; xy.len()];
        let mut items: Vec<(Candidate, Option<DropReason>)> = groups
            .into_iter()
            .map(|g| rule(describe(&xy, &intensity, g, &r, &p), &p))
            .collect();
        assert!(
            items
                .iter()
                .all(|(c, d)| d.is_none() && c.class == MarkingClass::Guideline)
        );
        confirm_groups(&mut items);
        let classes: Vec<_> = items.iter().map(|(c, d)| (c.class, *d)).collect();
        assert!(
            items[..5]
                .iter()
                .all(|(c, d)| d.is_none() && c.class == MarkingClass::Guideline),
            "{classes:?}"
        );
        assert_ne!(items[5].0.class, MarkingClass::Guideline, "{classes:?}");
    }

    /// A zebra stripe across a side street (0.45 m wide along the trajectory, across it
    /// from offset 2 to 6 m) read as three pieces end to end, 0.4-0.5 m apart: one bar
    /// after `rejoin_across`. A second stripe 1 m further along stays its own bar, and the
    /// pieces of one stripe are never joined to the other's.
    #[test]
    fn pieces_of_a_stripe_across_the_road_rejoin_and_stripes_stay_apart() {
        let (r, p) = (refl(), Params::default());
        let mut xy = Vec::new();
        let mut groups: Vec<Vec<usize>> = Vec::new();
        for x0 in [5.0, 6.0] {
            for (o0, o1) in [(2.0, 3.3), (3.7, 4.4), (4.9, 6.0)] {
                let start = xy.len();
                let mut o = o0;
                while o <= o1 {
                    let mut x = x0;
                    while x <= x0 + 0.45 {
                        xy.push([x, o]);
                        x += 0.03;
                    }
                    o += 0.03;
                }
                groups.push((start..xy.len()).collect());
            }
        }
        let intensity = vec![100.0f32; xy.len()];
        let feats = |p: &Params| -> Vec<Candidate> {
            groups
                .iter()
                .map(|g| describe(&xy, &intensity, g.clone(), &r, p))
                .collect()
        };
        let out = rejoin_across(feats(&p), &xy, &intensity, &r, &p);
        assert_eq!(out.len(), 2, "two stripes");
        for c in &out {
            assert!(
                (c.shape.length_m - 4.0).abs() < 0.1,
                "stripe length {}",
                c.shape.length_m
            );
            assert!(c.shape.angle_to_trajectory_deg > 80.0);
        }
        // Gaps wider than `join_gap_m`: six pieces.
        let off = Params {
            join_gap_m: 0.3,
            ..Params::default()
        };
        assert_eq!(rejoin_across(feats(&off), &xy, &intensity, &r, &off).len(), 6);
    }

    /// Pieces of one line 1.8 m apart: re-joined when they are read as sparse points (a
    /// far line, 5 points per metre), kept apart when dense (near dashes of a short-gap
    /// pattern are no occlusion); sparse pieces 3.5 m apart (a dash gap) stay apart too.
    #[test]
    fn sparse_pieces_of_a_line_rejoin_across_longer_gaps() {
        let (r, p) = (refl(), Params::default());
        let pieces = |starts: &[f64], dense: bool| -> (Vec<[f64; 2]>, Vec<Vec<usize>>) {
            let (mut xy, mut groups) = (Vec::new(), Vec::new());
            for &x0 in starts {
                let pts: Vec<[f64; 2]> = if dense {
                    paint(2.0, |_, y| y.abs() <= 0.075)
                        .into_iter()
                        .map(|q| [q[0] + x0, q[1]])
                        .collect()
                } else {
                    (0..=10)
                        .map(|k| [x0 + 0.2 * k as f64, 2.0 + 0.05 * ((k * 7 % 5) as f64 / 4.0 - 0.5)])
                        .collect()
                };
                groups.push((xy.len()..xy.len() + pts.len()).collect());
                xy.extend(pts);
            }
            (xy, groups)
        };
        let joined = |starts: &[f64], dense: bool| {
            let (xy, groups) = pieces(starts, dense);
            let intensity = vec![100.0f32; xy.len()];
            let feats: Vec<Candidate> = groups
                .into_iter()
                .map(|g| describe(&xy, &intensity, g, &r, &p))
                .collect();
            assert!(
                feats.iter().all(|c| c.line.is_some()),
                "every piece is a line piece"
            );
            rejoin(feats, &xy, &intensity, &r, &p).len()
        };
        assert_eq!(joined(&[2.0, 5.8, 9.6], false), 1, "sparse, 1.8 m gaps");
        assert_eq!(joined(&[2.0, 5.8, 9.6], true), 3, "dense, 1.8 m gaps");
        assert_eq!(joined(&[2.0, 7.5, 13.0], false), 3, "sparse, 3.5 m gaps");
    }

    /// A straight arrow (4 m shaft 0.25 m wide, 2 m head 0.75 m wide at its base) is no
    /// line even though its overall width (≈ 0.5 m) is under `line_max_width_m`; a
    /// uniform line, and a double line worn away on one side in stretches, are lines.
    #[test]
    fn arrows_are_no_lines_uniform_and_worn_double_lines_are() {
        let (r, p) = (refl(), Params::default());
        let arrow = paint(6.0, |x, y| {
            if x < 4.0 {
                y.abs() <= 0.125
            } else {
                y.abs() <= 0.375 * (6.0 - x) / 2.0
            }
        });
        assert!(line_geometry(&arrow, &r, &p).is_none());
        let line = paint(6.0, |_, y| y.abs() <= 0.075);
        let g = line_geometry(&line, &r, &p).expect("a uniform line is a line");
        assert!((g.width_m - 0.15).abs() < 0.04, "width {}", g.width_m);
        // Two 0.15 m lines 0.15 m apart; the upper one worn away over 1 m of every 2 m.
        let double = paint(8.0, |x, y| {
            let lower = (-0.225..=-0.075).contains(&y);
            let upper = (0.075..=0.225).contains(&y) && (x % 2.0) < 1.0;
            lower || upper
        });
        assert!(line_geometry(&double, &r, &p).is_some());
    }

    /// A 20 m edge line 0.15 m wide with a 1 m square mark touching its end (an arrow's
    /// head, a stop line) is still a line, of its own width, not a 1 m wide "line".
    #[test]
    fn a_mark_touching_a_lines_end_does_not_widen_it() {
        let (r, p) = (refl(), Params::default());
        let line = paint(20.0, |x, y| y.abs() <= 0.075 || x >= 19.0);
        let g = line_geometry(&line, &r, &p).expect("a line with a mark at its end is a line");
        assert!((g.width_m - 0.15).abs() < 0.04, "width {}", g.width_m);
        // The same mark in the middle of the line is no end: not a line.
        let middle = paint(20.0, |x, y| y.abs() <= 0.075 || (9.5..10.5).contains(&x));
        assert!(line_geometry(&middle, &r, &p).is_none_or(|g| g.width_m > 0.5));
    }

    /// A 30 m line 0.15 m wide with 5 % of its points strewn up to 0.25 m beside it
    /// (grit, the blurred edge of a worn patch): the rules see the trimmed extent, the
    /// outline gets twice the interquartile range, the paint's own width.
    #[test]
    fn strays_beside_a_line_do_not_widen_its_outline() {
        let (r, p) = (refl(), Params::default());
        let mut line = paint(30.0, |_, y| y.abs() <= 0.075);
        let n = line.len();
        for k in 0..n / 20 {
            let x = 30.0 * k as f64 / (n / 20) as f64;
            let side = if k % 2 == 0 { 1.0 } else { -1.0 };
            line.push([x, 2.0 + side * (0.1 + 0.15 * ((k * 7 % 11) as f64 / 10.0))]);
        }
        let g = line_geometry(&line, &r, &p).expect("still a line");
        assert!(g.width_m > 0.2, "trimmed extent {}", g.width_m);
        assert!(
            (g.paint_width_m - 0.15).abs() < 0.03,
            "outline width {}",
            g.paint_width_m
        );
        // Without strays both agree.
        let clean = paint(30.0, |_, y| y.abs() <= 0.075);
        let g = line_geometry(&clean, &r, &p).expect("a line");
        assert!((g.paint_width_m - g.width_m).abs() < 0.02);
    }

    /// A 0.20 m line sampled at random (about 12 points per 0.5 m) gets its painted width
    /// as outline width. When the points bunch at the line's two edges (two narrow lines
    /// read as one), twice the IQR overstates it: the outline is capped at
    /// `PAINT_WIDTH_OVER_EXTENT` × the trimmed extent.
    #[test]
    fn the_outline_width_is_twice_the_iqr_within_bounds() {
        let (r, p) = (refl(), Params::default());
        let mut jit = geom::test_jitter(11);
        let line: Vec<[f64; 2]> = (0..1200)
            .map(|_| [50.0 * (jit() + 0.5), 2.0 + 0.2 * jit()])
            .collect();
        let g = line_geometry(&line, &r, &p).expect("a line");
        assert!(
            (g.paint_width_m - 0.2).abs() < 0.012,
            "outline width {}",
            g.paint_width_m
        );
        let edges: Vec<[f64; 2]> = (0..1200)
            .map(|i| {
                let side = if i % 2 == 0 { 1.0 } else { -1.0 };
                [50.0 * (jit() + 0.5), 2.0 + side * (0.09 + 0.02 * jit())]
            })
            .collect();
        let g = line_geometry(&edges, &r, &p).expect("a line");
        assert!(
            g.paint_width_m <= PAINT_WIDTH_OVER_EXTENT * g.width_m + 1e-9,
            "outline {} extent {}",
            g.paint_width_m,
            g.width_m
        );
    }
}
