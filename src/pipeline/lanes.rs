//! Lane lines: line-segment self-growth along the trajectory, improved.
//!
//! # Interface
//! `grow(&[LanePiece], &Trajectory, &Params) -> Lanes`. Pieces are marking centrelines
//! (dashes and solid-line pieces, any coordinates as long as the trajectory is in the same
//! ones — `vectorize` passes absolute ones) with a caller key; the result holds one
//! [`LaneResult`] per lane line (class, smooth centreline, confidence, the keys it joins)
//! and the corrected class of every joined piece (an occluded piece of a solid line that
//! looked like a dash becomes `solid_line`). Works on pieces, not points, so it runs once
//! over a whole drive and is continuous across tiles and processing chunks.
//!
//! # Algorithm
//! Yao 2021 §2.3 grows a line from a cluster to the nearest candidate within 20 m whose
//! direction differs < 5° and whose MBR size similarity is > 0.58. Here, in the
//! (mileage s, offset o) frame of the smoothed trajectory (`refline`), where a lane line is
//! a near-constant offset even on curves:
//! 1. Every piece is reduced to its sampled centreline (s, o) and end slopes do/ds.
//! 2. **Linking**: piece B may follow piece A when it starts after A ends (≤ 0.5 m overlap,
//!    gap ≤ `max_gap_m`, i.e. ~2 dash periods of occlusion), both predict the same offset
//!    in the middle of the gap (extrapolating each along its own slope, so lines that drift
//!    across the trajectory during a lane change are followed) within
//!    `lateral_tolerance_m + lateral_tolerance_per_m × gap`, their directions differ ≤
//!    `max_angle_deg` (plus, across gaps up to 3 m, the direction uncertainty of short
//!    pieces: atan(0.05 m / length) each, so a far line's 1 m fragments chain), and
//!    their widths are similar (≥ `min_width_similarity`, widths under the narrowest
//!    painted line, 0.10 m, counting as 0.10 m: a far fragment crossed by one scan row
//!    reads 3 cm; lengths are not compared, so dashes and solid pieces join). Links are
//!    made between mutual best matches (cost = offset mismatch / tolerance + gap /
//!    2·max_gap), so the result does not
//!    depend on a seed cluster and growth runs in both directions at once. Two rounds: the
//!    second links whole chains, with slopes estimated over their last 15 m (further back,
//!    up to 60 m, until the samples span 10 m: a sparse chain's last 15 m may hold one
//!    fragment), each direction as uncertain as the extent it was fitted over. Where the
//!    caller knows what the scanner saw (`super::observed`) and it saw no bare asphalt on
//!    a gap's course, the gap may be up to `max_unseen_gap_m`, the offsets may match
//!    without extrapolating the slopes, and short pieces' directions count with their
//!    full uncertainty: a far line crossed by drifting scan columns, or hidden by traffic.
//!    Stretches at least 20 m long also link across gaps up to `max_chain_gap_m` when
//!    their ends meet within the tolerance of a `max_gap_m` gap and `max_angle_deg`: on a
//!    long drive a far line's dashes can go unseen for a hundred metres. Two solid
//!    stretches (painted over 70 % of their length) never link so across bare asphalt seen
//!    on the gap's course: the line breaks there (a ramp's mouth, a lane drop).
//!    Last, fragments (`unknown` pieces and pieces read narrower than any painted line,
//!    whose own directions are off by up to 13°) that no established line took join the
//!    line whose course, extrapolated from its last ≥ 10 m, passes within the lateral
//!    tolerance of their centres, up to 6 m past its end, one at a time
//!    (`absorb_fragments`): a ramp's edge line diverging 13–17 m out. Fragments left
//!    within a solid line's span, within 0.18 m of its course, join it too.
//! 3. **Dashed or solid**, judged on the named pieces only: `unknown` line fragments
//!    (neutral pieces: a far line's dash seen in part, shorter than any dash, looks the
//!    same on a solid line) are linked like the others but join the stretch nearest to
//!    them afterwards, and a chain of them alone is no lane line. Pieces closer than
//!    `run_join_gap_m` form painted runs; runs up
//!    to `dash_max_run_m` are dash-like. At least `min_dashes` consecutive dash-like runs
//!    of regular length (≥ 60 % within ±35 % of the median) with paint ≤ 80 % of their span
//!    form a dashed stretch, and so do dash-like runs whose centres repeat with one period
//!    (≥ 75 % of the spacings within ±15 % of one period or twice it, the period being the
//!    median spacing or, where missing dashes make the median fall between single and
//!    double spacings, the repeated single spacing; dashes seen
//!    only in part have irregular lengths but keep the period), and, where most gaps were
//!    seen bare, dash-like runs whose centres lie on one period's grid with runs of dashes
//!    missing (≥ 75 % of the spacings within 0.6 m of 1–8 periods; a far line crossed by
//!    few scan rows); everything else is solid
//!    (occlusion breaks a solid line into irregular runs). Where the scanner's view is
//!    known, a dashed stretch also needs a third of its gaps (at least one) seen bare: the
//!    fragments of a far solid line can have the lengths and spacing of dashes, but their
//!    gaps never show asphalt on the line's course. A run more than
//!    `NOT_A_DASH_FACTOR` (4) times the median run of its group is no dash (the first
//!    metres of the solid line a dashed line turns into); the dashes beside such a run
//!    need twice `min_dashes`, since a sparse solid line shows the same long run among
//!    short fragments. With `split_on_class_change`, a
//!    chain that is solid for ≥ `min_length_m` and dashed elsewhere becomes two lane lines.
//! 4. **Smooth centreline**: offset(s) by Gaussian local linear regression over the pieces'
//!    samples, bandwidth `smoothing_m` (on a dashed line 1, 2, 4 or 8 × it, chosen by
//!    leave-one-dash-out cross-validation: a far line's dashes, each a few centimetres off,
//!    are averaged with their neighbours while a bending line keeps the narrow fit); across
//!    gaps wider than the bandwidth a cubic Hermite joins the fitted ends (values and
//!    slopes, fitted over a quarter of the gap, 2–10 m, never less than the bandwidth), so
//!    the line follows the road's curvature through occlusions; across gaps of at least
//!    8 m that another line within 25 m is painted along (`Guide`), the line follows that
//!    line's course instead, at a difference interpolated linearly (the vehicle's sway,
//!    which the trajectory frame carries, is the same for both). Sampled every
//!    `vertex_spacing_m`, mapped back through the reference frame and simplified
//!    (Douglas–Peucker, `simplify_tolerance_m`).
//! 5. Lane lines shorter than `min_length_m` (a dashed stretch split off a chain at least
//!    that long is held to the chain's length) or whose pieces cover less than
//!    `min_paint_share` of their length, single named pieces that are not solid, and
//!    solid lines of at most 3 named pieces with less paint than `scant_solid_paint_m` are
//!    dropped: isolated dashes or noise do not make lane lines.
//!
//! Confidence: the mean piece confidence × support (pieces and painted length) × fit
//! (residual RMS of the samples about the centreline).
//!
//! # Reference
//! Yao et al. 2021 (Remote Sens. 13:2612) §2.3; Pan et al. 2019 §2.5 (re-joining broken
//! boundary lines by endpoint distance and direction, curvature-adaptive sampling).
//!
//! # Complexity
//! O(p log p + p·k) for p pieces with k candidates within the gap window; O(v) output.

use super::classify::MIN_PAINT_WIDTH_M;
use super::geom;
use super::observed::{Gap, Lookup};
use super::refline::RefLine;
use super::types::{LaneLineClass, MarkingClass, Trajectory};
use serde::{Deserialize, Serialize};

/// Lane-line growth parameters (JSON object `vectorize.lane_lines`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Params {
    /// Largest gap bridged between consecutive pieces along the road (m). Default 40
    /// (Yao: 20 m centre to centre; 40 m end to end covers a GB 6/9 m line missing two
    /// dashes, or 20 m of occlusion anywhere in it).
    pub max_gap_m: f64,
    /// Largest gap bridged when the scanner did not see the gap's course (m; see
    /// [`super::observed`]): a far line crossed by too few scan rows, a long occlusion.
    /// Default 60.
    pub max_unseen_gap_m: f64,
    /// Largest gap bridged between two stretches of line each at least
    /// [`CHAIN_MIN_SPAN_M`] long whose ends agree in offset and direction as closely as
    /// across a `max_gap_m` gap (m): a far line whose dashes go unseen for a hundred metres
    /// on a long drive is still one line. Default 150.
    pub max_chain_gap_m: f64,
    /// Offset mismatch allowed at a gap (m), plus `lateral_tolerance_per_m` per metre of
    /// gap. Defaults 0.25 and 0.01: lane lines 3–3.75 m apart are never joined.
    pub lateral_tolerance_m: f64,
    pub lateral_tolerance_per_m: f64,
    /// Largest direction difference between joined pieces (deg). Default 5 (Yao).
    pub max_angle_deg: f64,
    /// Smallest width ratio of joined pieces. Default 0.5.
    pub min_width_similarity: f64,
    /// Shortest lane line kept (m). Default 15.
    pub min_length_m: f64,
    /// Smallest share of a lane line's length its pieces must cover. Default 0.1: a dashed
    /// line paints 25–40 % (MUTCD 3/9 m, GB 2/4 m, 6/9 m) and keeps a tenth through
    /// occlusions; two stray fragments 30 m apart do not make a lane line.
    pub min_paint_share: f64,
    /// Least paint (m) of a solid lane line of at most [`SCANT_SOLID_MAX_PIECES`] named
    /// pieces. Default 8, about one solid piece's worth (the rules' solid piece is at least
    /// 7 m): two or three 1 m pieces of 14–17 returns each, 15 m apart, are no solid line
    /// (on the highway drives such lines ran beside or across the far lines, correctness
    /// .10–.71, each a second piece of the line it touched). 4 m kept a few of them.
    pub scant_solid_paint_m: f64,
    /// Painted runs up to this long count as dashes (m). Default 10.
    pub dash_max_run_m: f64,
    /// Fewest dashes that make a dashed lane line (or dashed stretch). Default 3.
    pub min_dashes: usize,
    /// Pieces closer than this form one painted run (m). Default 1.0.
    pub run_join_gap_m: f64,
    /// Split a chain into a solid and a dashed lane line where the pattern changes.
    /// Default true.
    pub split_on_class_change: bool,
    /// Bandwidth of the offset smoothing (m). Default 2.
    pub smoothing_m: f64,
    /// Spacing of centreline vertices before simplification (m). Default 1.
    pub vertex_spacing_m: f64,
    /// Douglas–Peucker tolerance of the output centreline (m). Default 0.005.
    pub simplify_tolerance_m: f64,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            max_gap_m: 40.0,
            max_unseen_gap_m: 60.0,
            max_chain_gap_m: 150.0,
            lateral_tolerance_m: 0.25,
            lateral_tolerance_per_m: 0.01,
            max_angle_deg: 5.0,
            min_width_similarity: 0.5,
            min_length_m: 15.0,
            min_paint_share: 0.1,
            scant_solid_paint_m: 8.0,
            dash_max_run_m: 10.0,
            min_dashes: 3,
            run_join_gap_m: 1.0,
            split_on_class_change: true,
            smoothing_m: 2.0,
            vertex_spacing_m: 1.0,
            simplify_tolerance_m: 0.005,
        }
    }
}

impl Params {
    pub fn validate(&self) -> Result<(), String> {
        let checks = [
            ("max_gap_m", self.max_gap_m, 0.0, 500.0),
            ("max_unseen_gap_m", self.max_unseen_gap_m, 0.0, 500.0),
            ("max_chain_gap_m", self.max_chain_gap_m, 0.0, 2000.0),
            ("lateral_tolerance_m", self.lateral_tolerance_m, 0.0, 5.0),
            ("lateral_tolerance_per_m", self.lateral_tolerance_per_m, 0.0, 1.0),
            ("max_angle_deg", self.max_angle_deg, 0.0, 45.0),
            ("min_width_similarity", self.min_width_similarity, 0.0, 1.0),
            ("min_length_m", self.min_length_m, 0.0, 1000.0),
            ("min_paint_share", self.min_paint_share, 0.0, 1.0),
            ("scant_solid_paint_m", self.scant_solid_paint_m, 0.0, 100.0),
            ("dash_max_run_m", self.dash_max_run_m, 0.1, 100.0),
            ("run_join_gap_m", self.run_join_gap_m, 0.0, 10.0),
            ("smoothing_m", self.smoothing_m, 0.1, 50.0),
            ("vertex_spacing_m", self.vertex_spacing_m, 0.05, 50.0),
            ("simplify_tolerance_m", self.simplify_tolerance_m, 0.0, 1.0),
        ];
        for (name, v, lo, hi) in checks {
            if !(v >= lo && v <= hi) {
                return Err(format!("lane_lines.{name} must be in [{lo}, {hi}], got {v}"));
            }
        }
        if self.min_dashes < 2 {
            return Err("lane_lines.min_dashes must be at least 2".into());
        }
        Ok(())
    }
}

/// One marking offered to lane-line growth.
#[derive(Clone, Debug, PartialEq)]
pub struct LanePiece {
    /// Caller's key (returned in [`LaneResult::pieces`]).
    pub key: usize,
    /// `SolidLine` or `DashedLine`, or `Unknown` for a line fragment too short to tell
    /// (joined like the others, but not counted as a dash or as solid paint); other
    /// classes are ignored.
    pub class: MarkingClass,
    /// Centreline, at least 2 vertices.
    pub centerline: Vec<[f64; 2]>,
    pub width_m: f64,
    pub confidence: f64,
}

/// One lane line.
#[derive(Clone, Debug, PartialEq)]
pub struct LaneResult {
    pub class: LaneLineClass,
    /// Centreline, vertices in increasing mileage (driving order).
    pub line: Vec<[f64; 2]>,
    pub confidence: f64,
    pub length_m: f64,
    /// Keys of the joined pieces, in driving order.
    pub pieces: Vec<usize>,
    /// Station of the first vertex (for ordering).
    pub start: [f64; 2],
}

/// Lane lines and the corrected classes of the pieces they join.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Lanes {
    pub lines: Vec<LaneResult>,
    /// (key, class) for every joined piece.
    pub classes: Vec<(usize, MarkingClass)>,
}

/// A piece in the trajectory frame.
struct Item {
    /// Caller keys (several when overlapping duplicates were merged).
    keys: Vec<usize>,
    /// (s, o) samples sorted by s.
    so: Vec<[f64; 2]>,
    width: f64,
    conf: f64,
    /// An `unknown` line fragment: part of the chain, but no evidence of dashes or solid
    /// paint (see [`regimes`]).
    neutral: bool,
}

impl Item {
    /// First and last mileage of its samples.
    fn ends(&self) -> (f64, f64) {
        (self.so[0][0], self.so[self.so.len() - 1][0])
    }
}

/// A linkable segment: one piece or a chain of pieces.
struct Seg {
    members: Vec<usize>,
    s0: f64,
    s1: f64,
    o0: f64,
    o1: f64,
    slope0: f64,
    slope1: f64,
    /// Along-track extent of the samples `slope0` and `slope1` are fitted on (m, 0.1–15):
    /// how well the end directions are known. A long chain whose last 15 m hold one 1 m
    /// fragment knows its end direction as poorly as that fragment does.
    fit0: f64,
    fit1: f64,
    width: f64,
    /// Along-track length its members cover (m; overlaps counted twice).
    painted: f64,
}

/// A solid lane line of at most this many named pieces needs `scant_solid_paint_m` of
/// paint (see [`Params`]).
pub const SCANT_SOLID_MAX_PIECES: usize = 3;

/// Lateral uncertainty (m) of a piece's end over the length its slope is fitted on: the
/// direction of a piece L metres long is known to about atan(SLOPE_NOISE_M / L) (3° for a
/// 1 m far-range fragment, 0.2° for 15 m), which is added to `max_angle_deg`.
const SLOPE_NOISE_M: f64 = 0.05;

/// Least along-track extent (m) of the samples a chain's end slope is fitted on, where
/// the chain has them within 4 × 15 m of its end (see `end_slope`).
const END_FIT_MIN_M: f64 = 10.0;

/// Half width (m) of the course whose cells tell whether a gap was seen (see
/// [`super::observed`]): the middle of a 0.15 m line, allowing a few centimetres of
/// error in the course.
const COURSE_HALF_WIDTH_M: f64 = 0.05;

/// Jitter (share of the period) of the centres of partly seen dashes in the period test.
const PERIOD_JITTER: f64 = 0.15;
/// ... where most of the gaps were seen bare (the fragments' gaps are real).
const BARE_PERIOD_JITTER: f64 = 0.25;

/// How far (m) a spacing of dash centres may lie from a whole number of periods in the
/// grid test ([`dash_grid`]). Absolute, not a share of the period: a spacing of k periods
/// is as precise as one of one period (the centres of the two dashes it spans are what
/// jitter), and a share of a long spacing would fit any spacing.
const GRID_TOLERANCE_M: f64 = 0.6;
/// Most whole periods one spacing of the grid test may span (dashes missing in a row).
const GRID_MAX_PERIODS: f64 = 8.0;

/// A painted run longer than this many times the median run of its group is no dash.
const NOT_A_DASH_FACTOR: f64 = 4.0;

/// Shortest stretch (m, along the track) that links across gaps up to `max_chain_gap_m`.
const CHAIN_MIN_SPAN_M: f64 = 20.0;

/// Share of its span a stretch's pieces cover above which it is a solid line for the
/// long links (dashed lines paint 25–40 %).
const SOLID_SHARE: f64 = 0.7;

/// Gaps (m) up to which the direction slack of short pieces applies in full; beyond, it
/// shrinks in proportion.
const SLACK_GAP_M: f64 = 3.0;

impl Seg {
    /// Along-track extent its start (`at_end` false) or end slope is fitted over (m): a
    /// short piece's direction is uncertain by about [`SLOPE_NOISE_M`] over it.
    fn fit(&self, at_end: bool) -> f64 {
        if at_end { self.fit1 } else { self.fit0 }
    }
}

/// Lateral uncertainty (m) of a segment's end direction over its span: [`SLOPE_NOISE_M`],
/// or half its width for a wide piece whose direction its outline hardly fixes.
fn slope_noise(s: &Seg) -> f64 {
    SLOPE_NOISE_M.max(0.5 * s.width)
}

/// Least-squares slope do/ds of samples (sorted by s) with s within `span` of the start
/// or end (further, see below), and the along-track extent of the samples it was fitted
/// on, clamped to 0.1–15 m (the length over which `SLOPE_NOISE_M` sets its uncertainty).
fn end_slope(so: &[[f64; 2]], at_end: bool, span: f64) -> (f64, f64) {
    let (slope, extent, _) = end_fit(so, at_end, span);
    (slope, extent)
}

/// [`end_slope`], and the centroid of the samples it was fitted on (the fitted line
/// passes through it).
fn end_fit(so: &[[f64; 2]], at_end: bool, span: f64) -> (f64, f64, [f64; 2]) {
    if so.len() < 2 {
        return (0.0, 0.1, so.first().copied().unwrap_or([0.0, 0.0]));
    }
    // The samples within `w` of the end: a suffix (prefix) of the sorted samples.
    let window = |w: f64| -> &[[f64; 2]] {
        if at_end {
            let lim = so[so.len() - 1][0] - w;
            &so[so.partition_point(|q| q[0] < lim)..]
        } else {
            let lim = so[0][0] + w;
            &so[..so.partition_point(|q| q[0] <= lim)]
        }
    };
    let ext = |p: &[[f64; 2]]| p[p.len() - 1][0] - p[0][0];
    let mut pick = window(span);
    // A sparse chain's last `span` metres may hold one short fragment: the window widens
    // (to at most 4 × `span`) until its samples extend over `END_FIT_MIN_M`.
    for k in 2..=4 {
        if ext(pick) >= END_FIT_MIN_M {
            break;
        }
        pick = window(span * k as f64);
    }
    let extent = ext(pick).clamp(0.1, 15.0);
    (
        geom::ls_slope(pick).map_or(0.0, |k| k.clamp(-0.5, 0.5)),
        extent,
        mean_of(pick),
    )
}

fn seg_of(items: &[Item], members: Vec<usize>) -> Seg {
    let so = samples_of(items, &members);
    let w = members.iter().map(|&m| items[m].width).sum::<f64>() / members.len() as f64;
    let ((slope0, fit0), (slope1, fit1)) = (end_slope(&so, false, 15.0), end_slope(&so, true, 15.0));
    Seg {
        s0: so[0][0],
        s1: so[so.len() - 1][0],
        o0: so[0][1],
        o1: so[so.len() - 1][1],
        slope0,
        slope1,
        fit0,
        fit1,
        width: w,
        painted: painted_of(items, &members),
        members,
    }
}

/// Mutual-best linking of segments; returns chains of segment indices in driving order.
fn link(
    segs: &[Seg],
    p: &Params,
    barriers: &[[f64; 4]],
    gap_at: &dyn Fn([f64; 2], [f64; 2]) -> Gap,
) -> Vec<Vec<usize>> {
    let n = segs.len();
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| segs[a].s0.total_cmp(&segs[b].s0).then(a.cmp(&b)));
    let mut cands: Vec<(f64, usize, usize)> = Vec::new();
    let max_tan = p.max_angle_deg.to_radians();
    for (oi, &a) in order.iter().enumerate() {
        let sa = &segs[a];
        // Candidates start at most 0.5 m before A's end... and ≤ max_gap after it. Since
        // `order` is by start, scan from the first start ≥ A.s1 − 0.5.
        let from = order.partition_point(|&x| segs[x].s0 < sa.s1 - 0.5).max(oi + 1);
        for &b in &order[from..] {
            let sb = &segs[b];
            if sb.s0 > sa.s1 + p.max_gap_m.max(p.max_unseen_gap_m).max(p.max_chain_gap_m) {
                break;
            }
            if b == a || sb.s1 <= sa.s1 {
                continue;
            }
            let g = (sb.s0 - sa.s1).max(0.0);
            let pa = sa.o1 + sa.slope1 * g / 2.0;
            let pb = sb.o0 - sb.slope0 * g / 2.0;
            let mut dev = (pa - pb).abs();
            let tol = p.lateral_tolerance_m + p.lateral_tolerance_per_m * g;
            // ... but only across short gaps: two short pieces far apart are weak evidence
            // of one line whatever their directions.
            let slack = ((SLOPE_NOISE_M / sa.fit(true)).atan() + (SLOPE_NOISE_M / sb.fit(false)).atan())
                * (SLACK_GAP_M / g.max(1e-6)).min(1.0);
            let turn = (sa.slope1.atan() - sb.slope0.atan()).abs();
            // Where the offsets only meet by extrapolating the slopes, the extrapolation must
            // be trustworthy: the slope of a piece L long and w wide is uncertain by about
            // max(SLOPE_NOISE_M, w/2) / L, so over half the gap each end may be off by that
            // times g/2. A short wide blob (both lines of a worn double line, an arrow's
            // head) does not steer a link metres sideways across a long gap.
            let flat = (sa.o1 - sb.o0).abs();
            let unsure = 0.5 * g * (slope_noise(sa) / sa.fit(true) + slope_noise(sb) / sb.fit(false));
            let extrapolated = flat > tol && unsure > tol;
            // What the scanner saw on the gap's course, looked up once and only if asked.
            let seen = std::cell::OnceCell::new();
            let gap = || *seen.get_or_init(|| gap_at([sa.s1, sa.o1], [sb.s0, sb.o0]));
            // Two long stretches across a longer gap: held to the offset tolerance of a
            // `max_gap_m` gap and to `max_angle_deg` without slack.
            let long_link = g > p.max_gap_m
                && g <= p.max_chain_gap_m
                && sa.s1 - sa.s0 >= CHAIN_MIN_SPAN_M
                && sb.s1 - sb.s0 >= CHAIN_MIN_SPAN_M
                && dev <= p.lateral_tolerance_m + p.lateral_tolerance_per_m * p.max_gap_m
                && turn <= max_tan
                // Two well-painted (solid) stretches do not link across bare asphalt seen
                // on the gap's course: the line breaks there (a ramp's mouth, a lane drop).
                && !(sa.painted >= SOLID_SHARE * (sa.s1 - sa.s0)
                    && sb.painted >= SOLID_SHARE * (sb.s1 - sb.s0)
                    && gap() == Gap::SeenBare);
            if dev > tol || turn > max_tan + slack || (g > p.max_gap_m && !long_link) || extrapolated {
                // Across a gap the scanner did not see, the pieces on either side are all
                // the evidence there is of the line: a short fragment's own slope (a 1 m
                // far-range piece's is off by several degrees) is not extrapolated, and its
                // direction counts with its full uncertainty however long the gap.
                let full_slack =
                    (SLOPE_NOISE_M / sa.fit(true)).atan() + (SLOPE_NOISE_M / sb.fit(false)).atan();
                if g > p.max_unseen_gap_m
                    || dev.min(flat) > tol
                    || turn > max_tan + full_slack
                    || gap() != Gap::Unseen
                {
                    continue;
                }
                dev = dev.min(flat);
            }
            // A barrier inside the gap (overlapping it by ≥ 0.1 m) at the line's offset.
            if barrier_across(barriers, sa.s1, sb.s0, 0.5 * (pa + pb)) {
                continue;
            }
            // Widths compared with 5 cm added: sparse far-range pieces under-read their
            // width by about a point spacing, which must not break a line. A width under
            // the narrowest painted line is a sparse piece's under-reading (a far line's
            // fragment crossed by one scan row reads 3 cm) and compares as that narrowest
            // line.
            let (wa, wb) = (sa.width.max(MIN_PAINT_WIDTH_M), sb.width.max(MIN_PAINT_WIDTH_M));
            if wa.min(wb) + 0.05 < p.min_width_similarity * (wa.max(wb) + 0.05) {
                continue;
            }
            // The mismatch that ranks candidates is the smaller of the extrapolated and the
            // flat one, for every candidate alike: otherwise a piece 30 m on across an
            // unseen gap (ranked by its flat offset) beats the next piece 12 m on (ranked
            // by extrapolating short pieces' noisy slopes) and the line is cut between them.
            let cost = dev.min(flat) / tol.max(1e-6) + 0.5 * g / p.max_gap_m.max(1e-6);
            cands.push((cost, a, b));
        }
    }
    // Mutual best matches, repeated among the ends still free: a piece whose best match
    // was taken by a better-placed one links to its next best when that one also prefers
    // it among the free ends (a far line's fragments otherwise leave gaps in the chain).
    let mut next: Vec<Option<usize>> = vec![None; n];
    let mut has_prev = vec![false; n];
    loop {
        let mut best_next: Vec<Option<(f64, usize)>> = vec![None; n];
        let mut best_prev: Vec<Option<(f64, usize)>> = vec![None; n];
        for &(cost, a, b) in &cands {
            if next[a].is_some() || has_prev[b] {
                continue;
            }
            if best_next[a].is_none_or(|(c, x)| cost < c || (cost == c && b < x)) {
                best_next[a] = Some((cost, b));
            }
            if best_prev[b].is_none_or(|(c, x)| cost < c || (cost == c && a < x)) {
                best_prev[b] = Some((cost, a));
            }
        }
        let mut linked = false;
        for (a, bn) in best_next.iter().enumerate() {
            if let Some((_, b)) = *bn
                && best_prev[b].map(|x| x.1) == Some(a)
            {
                next[a] = Some(b);
                has_prev[b] = true;
                linked = true;
            }
        }
        if !linked {
            break;
        }
    }
    let mut chains = Vec::new();
    for &a in &order {
        if has_prev[a] {
            continue;
        }
        let mut chain = vec![a];
        let mut cur = a;
        while let Some(b) = next[cur] {
            chain.push(b);
            cur = b;
        }
        chains.push(chain);
    }
    chains
}

/// Grow lane lines from pieces. See the module docs.
pub fn grow(pieces: &[LanePiece], traj: &Trajectory, p: &Params) -> Lanes {
    grow_with_barriers(pieces, traj, p, &[], None)
}

/// [`grow`], never bridging a gap across a barrier: markings that cross the road (stop
/// lines, crosswalks; outlines in the pieces' coordinates). A lane line does not run on
/// through a crosswalk or past a stop line into the junction, however well the lines on
/// both sides align.
pub fn grow_with_barriers(
    pieces: &[LanePiece],
    traj: &Trajectory,
    p: &Params,
    barriers: &[Vec<[f64; 2]>],
    seen: Option<&Lookup<'_>>,
) -> Lanes {
    let refl = RefLine::new(traj);
    // What the scanner saw on the course of a gap from (s, o) `a` to `b`.
    let gap_at = |a: [f64; 2], b: [f64; 2]| {
        let Some(seen) = seen else { return Gap::Unknown };
        if b[0] - a[0] < 0.5 {
            return Gap::Unknown;
        }
        let n = (b[0] - a[0]).ceil() as usize;
        let course: Vec<[f64; 2]> = (0..=n)
            .map(|k| {
                let t = k as f64 / n as f64;
                refl.point(a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]))
            })
            .collect();
        seen.gap(&course, COURSE_HALF_WIDTH_M)
    };
    let boxes = barrier_boxes(barriers, &refl);
    let mut items: Vec<Item> = pieces
        .iter()
        .filter(|q| {
            matches!(
                q.class,
                MarkingClass::SolidLine | MarkingClass::DashedLine | MarkingClass::Unknown
            ) && q.centerline.len() >= 2
        })
        .filter_map(|q| {
            let mut so: Vec<[f64; 2]> = q.centerline.iter().map(|&v| refl.locate(v)).collect();
            so.sort_by(|a, b| a[0].total_cmp(&b[0]));
            (so[so.len() - 1][0] - so[0][0] >= 0.3).then(|| Item {
                keys: vec![q.key],
                so,
                width: q.width_m.max(0.01),
                conf: q.confidence,
                neutral: q.class == MarkingClass::Unknown,
            })
        })
        .collect();
    items.sort_by(|a, b| a.so[0][0].total_cmp(&b.so[0][0]).then(a.keys.cmp(&b.keys)));
    let items = merge_overlaps(items);
    // Round 1: pieces; round 2: chains.
    let segs: Vec<Seg> = (0..items.len()).map(|i| seg_of(&items, vec![i])).collect();
    let chains1: Vec<Vec<usize>> = link(&segs, p, &boxes, &gap_at)
        .into_iter()
        .map(|c| c.into_iter().flat_map(|s| segs[s].members.clone()).collect())
        .collect();
    let segs2: Vec<Seg> = chains1.into_iter().map(|m| seg_of(&items, m)).collect();
    let chains: Vec<Vec<usize>> = link(&segs2, p, &boxes, &gap_at)
        .into_iter()
        .map(|c| c.into_iter().flat_map(|s| segs2[s].members.clone()).collect())
        .collect();
    let chains = merge_parallel_chains(&items, chains);
    let chains = absorb_fragments(&items, chains, p, &boxes);
    let mut out = Lanes::default();
    let mut accepted: Vec<(LaneLineClass, Vec<usize>, f64)> = Vec::new();
    for mut chain in chains {
        chain.sort_by(|&a, &b| items[a].so[0][0].total_cmp(&items[b].so[0][0]).then(a.cmp(&b)));
        let regs = regimes(&items, &chain, p, seen.map(|_| &gap_at as &dyn Fn(_, _) -> Gap));
        // A dashed stretch split off a longer line (the dashes a solid line turns into
        // after a junction) is held to the whole line's length: its dashes already passed
        // the dash tests, and cutting it off at `min_length_m` drops the short dashed
        // stretches that lines begin or end with.
        let chain_long =
            regs.len() > 1 && end_of(&items, &chain) - items[chain[0]].so[0][0] >= p.min_length_m;
        for (class, members) in regs {
            let s0 = items[members[0]].so[0][0];
            let s1 = end_of(&items, &members);
            let named = members.iter().filter(|&&m| !items[m].neutral).count();
            let long_enough = s1 - s0 >= p.min_length_m || (chain_long && class == LaneLineClass::DashedLine);
            if !long_enough || (named == 1 && class != LaneLineClass::SolidLine) {
                continue;
            }
            let painted = painted_of(&items, &members);
            let scant_solid = class == LaneLineClass::SolidLine
                && named <= SCANT_SOLID_MAX_PIECES
                && painted < p.scant_solid_paint_m;
            if painted < p.min_paint_share * (s1 - s0) || scant_solid {
                continue;
            }
            accepted.push((class, members, painted));
        }
    }
    // Every line's paint guides the others across their long gaps (see `Guide`).
    let guides: Vec<Guide> = accepted.iter().map(|(_, m, _)| Guide::new(&items, m)).collect();
    for (k, (class, members, painted)) in accepted.into_iter().enumerate() {
        let (line, rms) = centreline(
            &items,
            &members,
            &refl,
            p,
            class == LaneLineClass::DashedLine,
            (&guides, k),
        );
        if line.len() < 2 {
            continue;
        }
        let mean_conf = members.iter().map(|&m| items[m].conf).sum::<f64>() / members.len() as f64;
        let support = (members.len() as f64 / 4.0).max(painted / 20.0).min(1.0);
        let fit = (-(rms / 0.05).powi(2) / 2.0).exp();
        let piece_class = class.marking_class();
        out.classes.extend(
            members
                .iter()
                .flat_map(|&m| items[m].keys.iter().map(move |&k| (k, piece_class))),
        );
        let start = refl.locate(line[0]);
        out.lines.push(LaneResult {
            class,
            length_m: geom::polyline_length(&line),
            line,
            confidence: (mean_conf * (0.6 + 0.4 * support) * (0.5 + 0.5 * fit)).clamp(0.0, 1.0),
            pieces: members
                .iter()
                .flat_map(|&m| items[m].keys.iter().copied())
                .collect(),
            start,
        });
    }
    out.lines.sort_by(|a, b| {
        a.start[0]
            .total_cmp(&b.start[0])
            .then(a.start[1].total_cmp(&b.start[1]))
    });
    out.classes.sort_unstable_by_key(|c| c.0);
    out
}

/// Chains that run along the same painted line over a common stretch (fragments of a
/// sparse far line linked into two interleaved chains, where one chain's fragments may
/// fall in the other's gaps: its offset is interpolated there) are one lane line: same
/// test as `merge_overlaps`, on the chains' pooled samples.
fn merge_parallel_chains(items: &[Item], chains: Vec<Vec<usize>>) -> Vec<Vec<usize>> {
    let pooled: Vec<Item> = chains
        .iter()
        .map(|c| Item {
            keys: c.clone(),
            so: samples_of(items, c),
            width: c.iter().map(|&m| items[m].width).fold(0.0, f64::max),
            conf: 0.0,
            neutral: c.iter().all(|&m| items[m].neutral),
        })
        .collect();
    // `merge_overlaps` sorts by start and concatenates `keys`, here the item indices.
    let mut sorted = pooled;
    sorted.sort_by(|a, b| a.so[0][0].total_cmp(&b.so[0][0]).then(a.keys.cmp(&b.keys)));
    merge_overlaps(sorted).into_iter().map(|m| m.keys).collect()
}

/// Longest gap (m) from a line's end to a fragment that [`absorb_fragments`] joins to it:
/// the fragments of a far line lie 0.3–4 m apart, and one bare gap of a 6/9 m dashed line
/// is 9 m (a fragment beyond it is evidence of the next dash, not of the gap).
const FRAGMENT_MAX_GAP_M: f64 = 6.0;

/// Fragments (`unknown` pieces, and pieces read narrower than any painted line, 0.10 m)
/// just past the end of an established line that lie on its course join it, one at a time,
/// each extending the line and refitting its end.
///
/// The far line a ramp diverges along is crossed by a few scan rows every metre: its
/// fragments are 1 m long, 2–5 cm wide, and their own directions are off by up to 13°
/// (one crossing row decides them), so the pairwise links, which compare directions, stop
/// at the first one (highway drives: the ramp's edge line lost its last 25 m as eight to
/// ten `unknown` pieces). Here a fragment's direction is not used at all: only its centre,
/// against the course extrapolated from the line's last ≥ 10 m (`end_fit`), within the
/// lateral tolerance of the gap, no further than [`FRAGMENT_MAX_GAP_M`], and not across a
/// barrier. An established line is a chain at least [`CHAIN_MIN_SPAN_M`] long with at
/// least one piece that is no fragment; the fragments come from chains that are not (a
/// wrong chain of three fragments is no line). Where two line ends
/// claim one fragment, the nearer course takes it. Then the fragments left within the
/// span of a solid line, within [`MAX_MERGE_OFFSET_M`] of its course, join it (see below).
///
/// Written here: it is the self-growth step of Yao 2021 §2.3 on centres alone.
fn absorb_fragments(
    items: &[Item],
    mut chains: Vec<Vec<usize>>,
    p: &Params,
    barriers: &[[f64; 4]],
) -> Vec<Vec<usize>> {
    // A fragment: an `unknown` piece, or one read narrower than any painted line (a far
    // line crossed by one scan row), whose direction its outline does not fix.
    let fragment = |m: usize| items[m].neutral || items[m].width < MIN_PAINT_WIDTH_M;
    let anchor: Vec<bool> = chains
        .iter()
        .map(|c| end_of(items, c) - start_of(items, c) >= CHAIN_MIN_SPAN_M && c.iter().any(|&m| !fragment(m)))
        .collect();
    // Candidate fragments: the fragments of the other chains, with their centres.
    let mut free: Vec<(usize, [f64; 2])> = chains
        .iter()
        .zip(&anchor)
        .filter(|(_, a)| !**a)
        .flat_map(|(c, _)| c.iter().copied())
        .filter(|&m| fragment(m))
        .map(|m| (m, mean_of(&items[m].so)))
        .collect();
    if free.is_empty() {
        return chains;
    }
    free.sort_by(|a, b| a.1[0].total_cmp(&b.1[0]));
    // The anchors' pooled samples, kept up to date as they grow.
    let mut samples: Vec<Option<Vec<[f64; 2]>>> = chains
        .iter()
        .zip(&anchor)
        .map(|(c, &a)| a.then(|| samples_of(items, c)))
        .collect();
    let mut taken = vec![false; items.len()];
    loop {
        // Each anchor end's nearest fragment on its course: (dev / tol, chain, item).
        let mut claims: Vec<(f64, usize, usize)> = Vec::new();
        for (ci, so) in samples.iter().enumerate() {
            let Some(so) = so else { continue };
            for at_end in [false, true] {
                let (slope, _, cen) = end_fit(so, at_end, 15.0);
                let end = if at_end { so[so.len() - 1][0] } else { so[0][0] };
                // Centres up to 5 m beyond the farthest start or end (fragments up to 10 m).
                let (lo, hi) = if at_end {
                    (end - 0.5, end + FRAGMENT_MAX_GAP_M + 5.0)
                } else {
                    (end - FRAGMENT_MAX_GAP_M - 5.0, end + 0.5)
                };
                let from = free.partition_point(|f| f.1[0] < lo);
                let mut best: Option<(f64, f64, usize)> = None;
                for &(m, ctr) in free[from..].iter().take_while(|f| f.1[0] <= hi) {
                    if taken[m] {
                        continue;
                    }
                    let (f0, f1) = items[m].ends();
                    let beyond = if at_end { f1 > end } else { f0 < end };
                    let g = if at_end { f0 - end } else { end - f1 };
                    if !beyond || !(-0.5..=FRAGMENT_MAX_GAP_M).contains(&g) {
                        continue;
                    }
                    let pred = cen[1] + slope * (ctr[0] - cen[0]);
                    let tol = p.lateral_tolerance_m + p.lateral_tolerance_per_m * g.max(0.0);
                    let dev = (ctr[1] - pred).abs();
                    let (gs0, gs1) = if at_end { (end, f0) } else { (f1, end) };
                    if dev > tol || barrier_across(barriers, gs0, gs1, pred) {
                        continue;
                    }
                    if best.is_none_or(|(bg, _, _)| g < bg) {
                        best = Some((g, dev / tol, m));
                    }
                }
                if let Some((_, r, m)) = best {
                    claims.push((r, ci, m));
                }
            }
        }
        if claims.is_empty() {
            break;
        }
        claims.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
        // One fragment per line per round: its end is refitted before the next.
        let mut grew = vec![false; chains.len()];
        for (_, ci, m) in claims {
            if taken[m] || grew[ci] {
                continue;
            }
            taken[m] = true;
            grew[ci] = true;
            chains[ci].push(m);
            if let Some(so) = samples[ci].as_mut() {
                so.extend_from_slice(&items[m].so);
                so.sort_by(|a, b| a[0].total_cmp(&b[0]));
            }
        }
    }
    // Fragments within the span of a solid line (painted over SOLID_SHARE of it), on its
    // course (its samples' median offset there, interpolated across its gaps) within
    // MAX_MERGE_OFFSET_M, are its pieces: a fragment pointing off the course in a gap the
    // line bridged. Not on dashed lines: a fragment in a dash gap is no paint of the line,
    // and one beside a dash made the dash's outline worse (MUTCD urban: 2 dashes fewer).
    for (ci, c) in chains.iter().enumerate() {
        if painted_of(items, c) < SOLID_SHARE * (end_of(items, c) - start_of(items, c)) {
            samples[ci] = None;
        }
    }
    for &(m, ctr) in &free {
        if taken[m] {
            continue;
        }
        let (f0, f1) = items[m].ends();
        let best = samples
            .iter()
            .enumerate()
            .filter_map(|(ci, so)| {
                let so = so.as_ref()?;
                if so[0][0] > f0 || so[so.len() - 1][0] < f1 {
                    return None;
                }
                let dev = (median_offset_in(so, f0, f1)? - ctr[1]).abs();
                (dev <= MAX_MERGE_OFFSET_M).then_some((dev, ci))
            })
            .min_by(|a, b| a.0.total_cmp(&b.0));
        if let Some((_, ci)) = best {
            taken[m] = true;
            chains[ci].push(m);
        }
    }
    chains
        .into_iter()
        .zip(anchor)
        .filter_map(|(c, a)| {
            let c: Vec<usize> = if a {
                c
            } else {
                c.into_iter().filter(|&m| !taken[m]).collect()
            };
            (!c.is_empty()).then_some(c)
        })
        .collect()
}

/// Largest offset difference at which overlapping pieces or chains are one line (m): less
/// than the 0.2-0.3 m between the centres of a double line's two lines.
const MAX_MERGE_OFFSET_M: f64 = 0.18;

/// Longest gap between a chain's samples across which [`median_offset_in`] interpolates (m).
const INTERPOLATED_GAP_M: f64 = 20.0;

/// Median offset of the samples of `so` (sorted by s) with s in [a, b]; when none lies
/// there but `so` spans [a, b] (a chain's gap between two fragments, at most
/// [`INTERPOLATED_GAP_M`]), the offset interpolated at its middle between the samples on
/// either side.
fn median_offset_in(so: &[[f64; 2]], a: f64, b: f64) -> Option<f64> {
    // `merge_overlaps` asks this three times per overlapping pair: find the window by
    // binary search instead of scanning every sample.
    let (lo, hi) = (
        so.partition_point(|q| q[0] < a),
        so.partition_point(|q| q[0] <= b),
    );
    if lo < hi {
        let mut v: Vec<f64> = so[lo..hi].iter().map(|q| q[1]).collect();
        return Some(geom::median(&mut v));
    }
    let mid = 0.5 * (a + b);
    let k = so.partition_point(|q| q[0] < mid);
    (k > 0 && k < so.len() && so[k][0] - so[k - 1][0] <= INTERPOLATED_GAP_M).then(|| {
        let (p, q) = (so[k - 1], so[k]);
        let t = if q[0] > p[0] {
            (mid - p[0]) / (q[0] - p[0])
        } else {
            0.5
        };
        p[1] + t * (q[1] - p[1])
    })
}

/// Merge pieces that cover the same stretch of the same painted line (a line split
/// lengthwise into strips, duplicates from two scanner heads or overlapping chunks): they
/// overlap along the road by ≥ 0.5 m (or half the shorter one) and their median offsets
/// over the overlap — and over its first and last thirds, when those are ≥ 1 m — differ by
/// less than half the wider piece plus 5 cm (at most [`MAX_MERGE_OFFSET_M`]). Side-by-side
/// lines (≥ 0.25 m centre to centre) are never merged, not even through a third piece
/// close to both (merges go closest first and never join two side-by-side pieces). Input
/// sorted by start; output too.
fn merge_overlaps(items: Vec<Item>) -> Vec<Item> {
    let n = items.len();
    let mut parent: Vec<usize> = (0..n).collect();
    let ext = |it: &Item| (it.so[0][0], it.so[it.so.len() - 1][0]);
    // Pairs to merge (with their offset difference) and pairs side by side: two lines that
    // may never end up in one group, not even through a third piece (a worn double line's
    // piece that holds both lines lies within the tolerance of each).
    let mut merge: Vec<(f64, usize, usize)> = Vec::new();
    let mut apart: std::collections::HashSet<(usize, usize)> = std::collections::HashSet::new();
    for i in 0..n {
        let (a0, a1) = ext(&items[i]);
        for j in i + 1..n {
            let (b0, b1) = ext(&items[j]);
            if b0 >= a1 {
                break;
            }
            let (lo, hi) = (a0.max(b0), a1.min(b1));
            let ov = hi - lo;
            if ov < 0.5_f64.min(0.5 * (a1 - a0).min(b1 - b0)) {
                continue;
            }
            // Never as far as the other line of a double line (centres 0.2-0.3 m apart).
            let tol = (0.5 * items[i].width.max(items[j].width) + 0.05).min(MAX_MERGE_OFFSET_M);
            let (Some(oa), Some(ob)) = (
                median_offset_in(&items[i].so, lo, hi),
                median_offset_in(&items[j].so, lo, hi),
            ) else {
                continue;
            };
            // Over a long overlap the ends must agree too: a line diverging from another
            // (an exit ramp's edge line leaving the lane line it started on) agrees over
            // the first part of the common stretch, where the median is taken, and not
            // at its far end.
            let third = (hi - lo) / 3.0;
            let ends_agree = third < 1.0
                || [(lo, lo + third), (hi - third, hi)].iter().all(|&(a, b)| {
                    match (
                        median_offset_in(&items[i].so, a, b),
                        median_offset_in(&items[j].so, a, b),
                    ) {
                        (Some(x), Some(y)) => (x - y).abs() < tol,
                        _ => true,
                    }
                });
            let d = (oa - ob).abs();
            if d < tol && ends_agree {
                merge.push((d, i, j));
            } else if d >= MAX_MERGE_OFFSET_M {
                apart.insert((i, j));
            }
        }
    }
    let any = !merge.is_empty();
    // Closest pairs first; a merge that would put two side-by-side pieces in one group is
    // refused.
    merge.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let mut members: Vec<Vec<usize>> = (0..n).map(|i| vec![i]).collect();
    for (_, i, j) in merge {
        let (ri, rj) = (geom::find_root(&mut parent, i), geom::find_root(&mut parent, j));
        if ri == rj {
            continue;
        }
        let clash = members[ri]
            .iter()
            .any(|&a| members[rj].iter().any(|&b| apart.contains(&(a.min(b), a.max(b)))));
        if clash {
            continue;
        }
        // `union` makes the smaller root the root.
        geom::union(&mut parent, ri, rj);
        let moved = std::mem::take(&mut members[ri.max(rj)]);
        members[ri.min(rj)].extend(moved);
    }
    if !any {
        return items;
    }
    let mut slots: Vec<Option<Item>> = items.into_iter().map(Some).collect();
    let mut out: Vec<Item> = Vec::new();
    let mut at: Vec<Option<usize>> = vec![None; n];
    for (i, slot) in slots.iter_mut().enumerate() {
        let r = geom::find_root(&mut parent, i);
        let it = slot.take().expect("each item once");
        match at[r] {
            None => {
                at[r] = Some(out.len());
                out.push(it);
            }
            Some(k) => {
                let m = &mut out[k];
                m.so.extend(it.so);
                m.keys.extend(it.keys);
                m.width = m.width.max(it.width);
                m.conf = m.conf.max(it.conf);
                m.neutral &= it.neutral;
            }
        }
    }
    for m in &mut out {
        m.so.sort_by(|a, b| a[0].total_cmp(&b[0]));
        m.keys.sort_unstable();
    }
    out.sort_by(|a, b| a.so[0][0].total_cmp(&b.so[0][0]).then(a.keys.cmp(&b.keys)));
    out
}

/// Maximal spans `(first, last)` of consecutive `true` values.
/// The period of dash centres `spacings` apart, when at least three quarters of the
/// spacings are one or two periods within `jitter` × period: the median spacing, or where
/// missing dashes make as many double spacings as single ones (and the median falls
/// between), the median of the spacings that a single spacing (one seen at least twice
/// within the jitter) explains as single periods.
fn dash_period(spacings: &[f64], jitter: f64) -> Option<f64> {
    let on = |period: f64, x: f64| {
        let k = (x / period).round();
        (1.0..=2.0).contains(&k) && (x - k * period).abs() <= jitter * period
    };
    let fits = |period: f64| {
        spacings.iter().filter(|&&x| on(period, x)).count() as f64 >= 0.75 * spacings.len() as f64
    };
    let median = geom::median(&mut spacings.to_vec());
    if fits(median) {
        return Some(median);
    }
    period_candidates(spacings, |cand| jitter * cand)
        // Only to see through missing dashes: a double spacing must be among them (a
        // sparse solid line's fragments can show a loose single period, never this).
        .filter(|&period| {
            fits(period)
                && spacings
                    .iter()
                    .any(|&x| (x / period).round() == 2.0 && on(period, x))
        })
        .max_by(|a, b| a.total_cmp(b))
}

/// Candidate single periods: for each spacing, the median of the spacings within
/// `tolerance(spacing)` of it, where there are at least two.
fn period_candidates<'a>(
    spacings: &'a [f64],
    tolerance: impl Fn(f64) -> f64 + 'a,
) -> impl Iterator<Item = f64> + 'a {
    spacings.iter().filter_map(move |&cand| {
        let mut single: Vec<f64> = spacings
            .iter()
            .copied()
            .filter(|&x| (x - cand).abs() <= tolerance(cand))
            .collect();
        (single.len() >= 2).then(|| geom::median(&mut single))
    })
}

/// The period of dashes on a grid with many of them missing: a far line whose gaps were
/// seen bare but whose dashes go unseen several in a row (few scan rows cross it), so the
/// spacings of its dash centres are any whole number of periods (6, 24, 18, 6, 12 m on a
/// 2/4 m line), which [`dash_period`] (one or two periods) does not accept.
///
/// At least two spacings within [`GRID_TOLERANCE_M`] of each other are single periods
/// (the largest such candidate wins); the period is refitted by least squares over the
/// spacings on the grid, and at least 75 % of the spacings must lie within
/// [`GRID_TOLERANCE_M`] of 1 to [`GRID_MAX_PERIODS`] periods. The fragments of a worn solid
/// line have bare gaps too, but spacings with no common period: on the 20 simulated
/// drives' lines that fail the other dash tests, this one accepted only a far 2/4 m
/// dashed line (and no solid line below a tolerance of 1.0 m).
fn dash_grid(spacings: &[f64]) -> Option<f64> {
    let on_grid = |period: f64, x: f64| {
        let k = (x / period).round();
        (1.0..=GRID_MAX_PERIODS).contains(&k) && (x - k * period).abs() <= GRID_TOLERANCE_M
    };
    period_candidates(spacings, |_| GRID_TOLERANCE_M)
        .filter_map(|mut period| {
            // Least squares x ≈ k·period over the spacings on the grid (twice: the whole
            // numbers can change with the period).
            for _ in 0..2 {
                let (sxk, skk) =
                    spacings
                        .iter()
                        .filter(|&&x| on_grid(period, x))
                        .fold((0.0, 0.0), |(a, b), &x| {
                            let k = (x / period).round();
                            (a + x * k, b + k * k)
                        });
                if skk > 0.0 {
                    period = sxk / skk;
                }
            }
            let fit = spacings.iter().filter(|&&x| on_grid(period, x)).count();
            (fit as f64 >= 0.75 * spacings.len() as f64).then_some(period)
        })
        .max_by(|a, b| a.total_cmp(b))
}

fn true_spans(v: &[bool]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < v.len() {
        if !v[i] {
            i += 1;
            continue;
        }
        let mut j = i;
        while j + 1 < v.len() && v[j + 1] {
            j += 1;
        }
        out.push((i, j));
        i = j + 1;
    }
    out
}

/// Largest end mileage of the members.
fn end_of(items: &[Item], members: &[usize]) -> f64 {
    members
        .iter()
        .map(|&m| items[m].ends().1)
        .fold(f64::NEG_INFINITY, f64::max)
}

/// Smallest start mileage of the members.
fn start_of(items: &[Item], members: &[usize]) -> f64 {
    members
        .iter()
        .map(|&m| items[m].ends().0)
        .fold(f64::INFINITY, f64::min)
}

/// The members' (s, o) samples pooled and sorted by s.
fn samples_of(items: &[Item], members: &[usize]) -> Vec<[f64; 2]> {
    let mut so: Vec<[f64; 2]> = members
        .iter()
        .flat_map(|&m| items[m].so.iter().copied())
        .collect();
    so.sort_by(|a, b| a[0].total_cmp(&b[0]));
    so
}

/// Along-track length the members cover (m; overlaps counted twice).
fn painted_of(items: &[Item], members: &[usize]) -> f64 {
    members
        .iter()
        .map(|&m| {
            let (a, b) = items[m].ends();
            b - a
        })
        .sum()
}

/// Mean (s, o) of samples (at least one).
fn mean_of(so: &[[f64; 2]]) -> [f64; 2] {
    let n = so.len() as f64;
    [
        so.iter().map(|q| q[0]).sum::<f64>() / n,
        so.iter().map(|q| q[1]).sum::<f64>() / n,
    ]
}

/// Barrier outlines as (s, o) boxes [s0, s1, o0, o1], widened by 0.5 m across so the gaps
/// between zebra stripes count too (for [`barrier_across`]).
pub(crate) fn barrier_boxes(barriers: &[Vec<[f64; 2]>], refl: &RefLine) -> Vec<[f64; 4]> {
    barriers
        .iter()
        .filter(|r| !r.is_empty())
        .map(|r| {
            let b = refl.box_of(r);
            [b[0], b[1], b[2] - 0.5, b[3] + 0.5]
        })
        .collect()
}

/// Whether a barrier box (s0, s1, o0, o1) lies inside the gap from `s0` to `s1` (overlapping
/// it by at least 0.1 m) at offset `o`.
pub(crate) fn barrier_across(barriers: &[[f64; 4]], s0: f64, s1: f64, o: f64) -> bool {
    barriers
        .iter()
        .any(|b| b[0] < s1 - 0.1 && b[1] > s0 + 0.1 && o >= b[2] && o <= b[3])
}

/// Split a chain (pieces in driving order) into solid and dashed stretches, judged on its
/// named pieces; each neutral piece (an `unknown` fragment: a far line's dash seen in part
/// looks like a dash on a solid line too) joins the stretch nearest to it. A chain of
/// neutral pieces alone has none.
fn regimes(
    items: &[Item],
    chain: &[usize],
    p: &Params,
    gap_at: Option<&dyn Fn([f64; 2], [f64; 2]) -> Gap>,
) -> Vec<(LaneLineClass, Vec<usize>)> {
    let (neutral, named): (Vec<usize>, Vec<usize>) = chain.iter().partition(|&&m| items[m].neutral);
    if named.is_empty() {
        return Vec::new();
    }
    let mut regs = named_regimes(items, &named, p, gap_at);
    // The named stretches' extents; a neutral piece joins the one it lies nearest to.
    let spans: Vec<(f64, f64)> = regs
        .iter()
        .map(|r| (items[r.1[0]].ends().0, end_of(items, &r.1)))
        .collect();
    for m in neutral {
        let (a, b) = items[m].ends();
        let away = |k: usize| (spans[k].0 - b).max(a - spans[k].1).max(0.0);
        if let Some(k) = (0..regs.len()).min_by(|&x, &y| away(x).total_cmp(&away(y))) {
            regs[k].1.push(m);
        }
    }
    for r in &mut regs {
        r.1.sort_by(|&x, &y| items[x].ends().0.total_cmp(&items[y].ends().0).then(x.cmp(&y)));
    }
    regs
}

/// [`regimes`] of a chain of named pieces.
fn named_regimes(
    items: &[Item],
    chain: &[usize],
    p: &Params,
    gap_at: Option<&dyn Fn([f64; 2], [f64; 2]) -> Gap>,
) -> Vec<(LaneLineClass, Vec<usize>)> {
    // Painted runs: pieces closer than run_join_gap_m.
    let mut runs: Vec<(f64, f64, Vec<usize>)> = Vec::new();
    for &m in chain {
        let (a, b) = items[m].ends();
        match runs.last_mut() {
            Some(r) if a - r.1 < p.run_join_gap_m => {
                r.1 = r.1.max(b);
                r.2.push(m);
            }
            _ => runs.push((a, b, vec![m])),
        }
    }
    let mut short: Vec<bool> = runs.iter().map(|r| r.1 - r.0 <= p.dash_max_run_m).collect();
    // A run several times longer than the runs around it is no dash even when it is under
    // `dash_max_run_m`: the first 8 m of the solid line a dashed line turns into before a
    // junction, next to 2 m dashes. Left in, it would spoil the dash tests of the whole
    // group; out, the group ends there. A long run is also what a sparse solid line shows
    // between its short fragments, so a group beside such a run needs twice `min_dashes`.
    let mut demoted = vec![false; runs.len()];
    for (i, j) in true_spans(&short) {
        let mut lens: Vec<f64> = runs[i..=j].iter().map(|r| r.1 - r.0).collect();
        let med = geom::median(&mut lens);
        for k in i..=j {
            if runs[k].1 - runs[k].0 > NOT_A_DASH_FACTOR * med {
                short[k] = false;
                demoted[k] = true;
            }
        }
    }
    // Mark dashed stretches: maximal groups of consecutive short runs that look like dashes.
    let mut dashed = vec![false; runs.len()];
    for (i, j) in true_spans(&short) {
        let lens: Vec<f64> = runs[i..=j].iter().map(|r| r.1 - r.0).collect();
        // Regular dashes: most runs within ±35 % of the median length (dashes cut by an
        // occlusion at its ends do not spoil it; an irregularly broken solid line does).
        let mut sorted = lens.clone();
        let med = geom::median(&mut sorted);
        let regular =
            lens.iter().filter(|&&l| (l - med).abs() <= 0.35 * med).count() as f64 >= 0.6 * lens.len() as f64;
        let span = runs[j].1 - runs[i].0;
        let paint = lens.iter().sum::<f64>() / span.max(1e-9);
        // Painted dashes repeat with regular gaps too (every standard fixes the gap);
        // a solid line broken by parked cars or shadows has irregular gaps. Gaps much
        // longer than the median (a missing dash, an occlusion) are left out of the test.
        let gaps: Vec<f64> = (i..j).map(|k| runs[k + 1].0 - runs[k].1).collect();
        let regular_gaps = gaps.len() < 2 || {
            let mut g = gaps.clone();
            let mg = geom::median(&mut g);
            let usable: Vec<f64> = gaps.iter().copied().filter(|&x| x <= 1.8 * mg).collect();
            usable.iter().filter(|&&x| (x - mg).abs() <= 0.35 * mg).count() as f64
                >= 0.6 * usable.len() as f64
        };
        // Dashes seen only in part (sparse far scan rows, wear) measure 1–2 m of a 2 m dash:
        // their lengths and gaps vary, but their centres still repeat with the line's period
        // (jitter ≤ half a dash: a sixth of a GB 2/4 m period), or twice it where one dash is
        // missing; a run longer than most of a period is no dash. A solid line sampled in
        // fragments has no such period.
        let centres: Vec<f64> = runs[i..=j].iter().map(|r| 0.5 * (r.0 + r.1)).collect();
        let spacings: Vec<f64> = centres.windows(2).map(|w| w[1] - w[0]).collect();
        let dashes_fit = |period: f64| lens.iter().all(|&l| l <= 0.8 * period);
        let regular_period_within =
            |jitter: f64| lens.len() >= 3 && dash_period(&spacings, jitter).is_some_and(dashes_fit);
        let regular_period = regular_period_within(PERIOD_JITTER);
        // Dashes on a grid with runs of them missing, where their gaps were seen bare.
        let on_grid = || lens.len() >= 3 && dash_grid(&spacings).is_some_and(dashes_fit);
        let beside_demoted = (i > 0 && demoted[i - 1]) || (j + 1 < runs.len() && demoted[j + 1]);
        let min_dashes = if beside_demoted {
            2 * p.min_dashes
        } else {
            p.min_dashes
        };
        // Where the scanner's view is known, some dash gaps must have been seen bare: at
        // long range the scan columns drift on and off a line, and a solid line's
        // fragments have the lengths and spacing of dashes, but its gaps never show
        // asphalt on its course (their points, where there are any, are paint).
        // Looked up once, and only when the other tests pass (each gap is a course lookup).
        let bare_cache = std::cell::OnceCell::new();
        let bare_count = || {
            *bare_cache.get_or_init(|| {
                let gap_at = gap_at?;
                let end = |k: usize| {
                    let last = &items[runs[k].2[runs[k].2.len() - 1]].so;
                    last[last.len() - 1]
                };
                let bare = (i..j)
                    .filter(|&k| gap_at(end(k), items[runs[k + 1].2[0]].so[0]) == Gap::SeenBare)
                    .count();
                Some(bare)
            })
        };
        // At least a third of them seen bare, or the group is no dashed stretch. (Bare
        // gaps alone do not make dashes: worn solid lines have them too.)
        let bare_some = || bare_count().is_none_or(|b| b >= 1 && 3 * b >= j - i);
        // Where most gaps were seen bare, dashes seen in part (a 6 m dash read as 1-4 m at
        // long range) may shift their centres by up to a quarter period.
        let mostly_bare = || bare_count().is_some_and(|b| b >= 2 && 2 * b >= j - i);
        if lens.len() >= min_dashes
            && (regular && regular_gaps
                || regular_period
                || mostly_bare() && (regular_period_within(BARE_PERIOD_JITTER) || on_grid()))
            && paint <= 0.7
            && bare_some()
        {
            dashed[i..=j].iter_mut().for_each(|d| *d = true);
        }
    }
    // Regimes of consecutive runs with the same label.
    let mut regs: Vec<(bool, Vec<usize>)> = Vec::new();
    for (k, r) in runs.iter().enumerate() {
        match regs.last_mut() {
            Some(g) if g.0 == dashed[k] => g.1.extend(r.2.iter().copied()),
            _ => regs.push((dashed[k], r.2.clone())),
        }
    }
    let class_of = |d: bool| {
        if d {
            LaneLineClass::DashedLine
        } else {
            LaneLineClass::SolidLine
        }
    };
    let extent = |ms: &[usize]| end_of(items, ms) - items[ms[0]].ends().0;
    if regs.len() == 1 {
        let (d, ms) = regs.pop().expect("one regime");
        return vec![(class_of(d), ms)];
    }
    if !p.split_on_class_change {
        let dashed_len: f64 = regs.iter().filter(|g| g.0).map(|g| extent(&g.1)).sum();
        let solid_len: f64 = regs.iter().filter(|g| !g.0).map(|g| extent(&g.1)).sum();
        let all: Vec<usize> = regs.into_iter().flat_map(|g| g.1).collect();
        return vec![(class_of(dashed_len > solid_len), all)];
    }
    // Short solid stretches inside a dashed line (two dashes merged by noise, a long worn
    // patch) do not split it: absorb solid regimes shorter than min_length_m into a
    // neighbouring dashed one.
    let mut merged: Vec<(bool, Vec<usize>)> = Vec::new();
    for (d, ms) in regs {
        let absorb = !d && extent(&ms) < p.min_length_m;
        match merged.last_mut() {
            Some(g) if g.0 == d || (absorb && g.0) => g.1.extend(ms),
            _ if absorb => merged.push((true, ms)),
            _ => merged.push((d, ms)),
        }
    }
    // Merge neighbours that became equal.
    let mut out: Vec<(bool, Vec<usize>)> = Vec::new();
    for (d, ms) in merged {
        match out.last_mut() {
            Some(g) if g.0 == d => g.1.extend(ms),
            _ => out.push((d, ms)),
        }
    }
    out.into_iter().map(|(d, ms)| (class_of(d), ms)).collect()
}

/// Candidate bandwidths of a dashed line's centreline, as multiples of `smoothing_m`.
const DASHED_BANDWIDTH_FACTORS: [f64; 4] = [1.0, 2.0, 4.0, 8.0];

/// The smoothing bandwidth (m) of a dashed line's centreline, chosen by leave-one-dash-out
/// cross-validation (written here; the fit is [`geom::local_linear`]): each candidate
/// predicts every dash's median offset from the other dashes alone, and the one with the
/// least squared error (each error capped at 0.3 m) wins if it beats `h0` by 20 %. With
/// 2 m dashes every 6 m, `h0` = 2 m fits each dash to its own points; on a far line, where
/// a few returns at one edge of a dash put it centimetres off, the wider fit through its
/// neighbours is nearer the paint, while a line that bends (a lane change, a ramp)
/// keeps the narrow one.
fn dashed_bandwidth(
    items: &[Item],
    members: &[usize],
    xs: &[f64],
    ys: &[f64],
    owner: &[usize],
    h0: f64,
) -> f64 {
    if members.len() < 4 {
        return h0;
    }
    // Each dash's median station and offset.
    let targets: Vec<(usize, f64, f64)> = members
        .iter()
        .enumerate()
        .filter(|&(_, &m)| items[m].so.len() >= 2)
        .map(|(j, &m)| {
            let mut s: Vec<f64> = items[m].so.iter().map(|q| q[0]).collect();
            let mut o: Vec<f64> = items[m].so.iter().map(|q| q[1]).collect();
            (j, geom::median(&mut s), geom::median(&mut o))
        })
        .collect();
    let mut ws = vec![1.0; xs.len()];
    let mut score = [0.0f64; DASHED_BANDWIDTH_FACTORS.len()];
    for &(j, s, o) in &targets {
        for (w, &k) in ws.iter_mut().zip(owner) {
            *w = if k == j { 0.0 } else { 1.0 };
        }
        for (sc, f) in score.iter_mut().zip(DASHED_BANDWIDTH_FACTORS) {
            let e =
                geom::local_linear(xs, ys, &ws, s, f * h0, 3.0).map_or(0.3, |(a, _)| (a - o).abs().min(0.3));
            *sc += e * e;
        }
    }
    let best = (0..score.len())
        .min_by(|&a, &b| score[a].total_cmp(&score[b]))
        .unwrap_or(0);
    if score[best] < 0.8 * score[0] {
        DASHED_BANDWIDTH_FACTORS[best] * h0
    } else {
        h0
    }
}

/// Shortest gap (m) of a line that another line's paint guides across ([`Guide`]): shorter
/// gaps (a dash gap, a car) are bridged by the Hermite of the fitted ends.
const GUIDE_MIN_GAP_M: f64 = 8.0;
/// Farthest (m) a guide may lie from the line at the start of its gap (also for the lines
/// of fragments, `vectorize::fragment_lines`): the sway is the vehicle's, the same at any
/// offset; a far carriageway's lines lie 13–21 m from the near one's on the simulated
/// highways.
pub(crate) const GUIDE_MAX_DISTANCE_M: f64 = 25.0;
/// Longest unpainted stretch (m) of a guide within the gap it guides (a dash gap, GB 9 m,
/// MUTCD 30 ft, with a margin), and how far (m) short of the gap's ends its paint may stop.
const GUIDE_MAX_HOLE_M: f64 = 12.0;
const GUIDE_END_SLACK_M: f64 = 2.0;
/// Bandwidth (m) of a guide's offset fit, well under the sway of a vehicle in its lane
/// (tens of metres); across a dashed guide's gaps `geom::local_linear` widens it until it
/// holds enough samples.
const GUIDE_BANDWIDTH_M: f64 = 2.0;

/// The members' extents along s.
fn member_intervals(items: &[Item], members: &[usize]) -> Vec<(f64, f64)> {
    members
        .iter()
        .map(|&m| (items[m].so[0][0], items[m].so[items[m].so.len() - 1][0]))
        .collect()
}

/// Intervals sorted and merged where one starts at most `join` after the last ends.
pub(crate) fn merge_intervals(mut ivs: Vec<(f64, f64)>, join: f64) -> Vec<(f64, f64)> {
    ivs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut merged: Vec<(f64, f64)> = Vec::new();
    for iv in ivs {
        match merged.last_mut() {
            Some(l) if iv.0 <= l.1 + join => l.1 = l.1.max(iv.1),
            _ => merged.push(iv),
        }
    }
    merged
}

/// Share of [a, b] covered by the merged, ordered intervals `painted`.
pub(crate) fn painted_share(painted: &[(f64, f64)], a: f64, b: f64) -> f64 {
    if b <= a {
        return 0.0;
    }
    painted
        .iter()
        .map(|iv| (iv.1.min(b) - iv.0.max(a)).max(0.0))
        .sum::<f64>()
        / (b - a)
}

/// A lane line's paint as a guide for the others. In the trajectory frame a straight line
/// is not at a constant offset: the vehicle sways in its lane (on a simulated highway a far
/// line's offset rose by 0.24 m and fell back over 60 m), so a line interpolated across a
/// 40 m gap from its ends alone ran up to 0.29 m off (beyond the 0.15 m a lane line is held
/// to). Lines painted all along such a gap sway the same way: across a gap of at least
/// [`GUIDE_MIN_GAP_M`], of the lines within [`GUIDE_MAX_DISTANCE_M`] whose paint covers the
/// gap (holes ≤ [`GUIDE_MAX_HOLE_M`], ends within [`GUIDE_END_SLACK_M`]) the most painted
/// along it, then the nearest, carries the line: its offset plus the line's difference from
/// it at the gap's ends (fitted locally), interpolated linearly (two lines that converge, a
/// lane drop, converge linearly).
struct Guide {
    xs: Vec<f64>,
    ys: Vec<f64>,
    ws: Vec<f64>,
    /// Painted intervals along s, merged, in order.
    painted: Vec<(f64, f64)>,
}

impl Guide {
    fn new(items: &[Item], members: &[usize]) -> Self {
        let mut so = samples_of(items, members);
        so.sort_by(|a, b| a[0].total_cmp(&b[0]));
        let painted = merge_intervals(member_intervals(items, members), 0.0);
        Self {
            xs: so.iter().map(|q| q[0]).collect(),
            ys: so.iter().map(|q| q[1]).collect(),
            ws: vec![1.0; so.len()],
            painted,
        }
    }

    /// Whether the paint covers [a, b] up to holes of [`GUIDE_MAX_HOLE_M`].
    fn covers(&self, a: f64, b: f64) -> bool {
        // The intervals are merged, so ordered by both ends.
        let lo = self.painted.partition_point(|iv| iv.1 < a - GUIDE_END_SLACK_M);
        let hi = self.painted.partition_point(|iv| iv.0 <= b + GUIDE_END_SLACK_M);
        let inside = &self.painted[lo..hi.max(lo)];
        let (Some(first), Some(last)) = (inside.first(), inside.last()) else {
            return false;
        };
        first.0 <= a + GUIDE_END_SLACK_M
            && last.1 >= b - GUIDE_END_SLACK_M
            && inside.windows(2).all(|w| w[1].0 - w[0].1 <= GUIDE_MAX_HOLE_M)
    }

    fn offset(&self, s: f64) -> Option<f64> {
        geom::local_linear(&self.xs, &self.ys, &self.ws, s, GUIDE_BANDWIDTH_M, 3.0).map(|f| f.0)
    }
}

/// Smooth centreline through the pieces; returns the polyline and the samples' RMS residual.
fn centreline(
    items: &[Item],
    members: &[usize],
    refl: &RefLine,
    p: &Params,
    dashed: bool,
    (guides, own): (&[Guide], usize),
) -> (Vec<[f64; 2]>, f64) {
    // (s, o, member) samples sorted by s.
    let mut tagged: Vec<(f64, f64, usize)> = members
        .iter()
        .enumerate()
        .flat_map(|(j, &m)| items[m].so.iter().map(move |q| (q[0], q[1], j)))
        .collect();
    tagged.sort_by(|a, b| a.0.total_cmp(&b.0));
    let so: Vec<[f64; 2]> = tagged.iter().map(|t| [t.0, t.1]).collect();
    let xs: Vec<f64> = so.iter().map(|q| q[0]).collect();
    let ys: Vec<f64> = so.iter().map(|q| q[1]).collect();
    let ws = vec![1.0; xs.len()];
    let owner: Vec<usize> = tagged.iter().map(|t| t.2).collect();
    let h = if dashed {
        dashed_bandwidth(items, members, &xs, &ys, &owner, p.smoothing_m)
    } else {
        p.smoothing_m
    };
    let fit = |s: f64| geom::local_linear(&xs, &ys, &ws, s, h, 3.0).unwrap_or((0.0, 0.0));
    // Painted intervals (merged), to find the gaps that need a Hermite bridge.
    let painted = merge_intervals(member_intervals(items, members), 2.0 * h);
    let (s0, s1) = (xs[0], xs[xs.len() - 1]);
    let nv = ((s1 - s0) / p.vertex_spacing_m).ceil().max(1.0) as usize;
    let mut stations: Vec<f64> = (0..=nv).map(|i| s0 + (s1 - s0) * i as f64 / nv as f64).collect();
    // Make sure painted ends are vertices (the line starts/stops exactly with the paint).
    for iv in &painted {
        stations.push(iv.0);
        stations.push(iv.1);
    }
    stations.sort_by(f64::total_cmp);
    stations.dedup_by(|a, b| (*a - *b).abs() < 1e-6);
    // Ends of each gap (value, slope), fitted over a quarter of the gap (at least the
    // smoothing bandwidth, at most 10 m): across a long gap the line follows the trend of
    // the paint on either side, not the slope of the last fragment (a 1 m far-range
    // fragment's is off by degrees, which puts the middle of a 40 m gap decimetres off).
    let gap_ends: Vec<((f64, f64), (f64, f64))> = painted
        .windows(2)
        .map(|w| {
            let (a, b) = (w[0].1, w[1].0);
            let hw = ((b - a) / 4.0).min(10.0).max(h);
            let wide = |s: f64| geom::local_linear(&xs, &ys, &ws, s, hw, 3.0).unwrap_or_else(|| fit(s));
            (wide(a), wide(b))
        })
        .collect();
    // The guide of each long gap: the nearest other line painted all along it.
    let gap_guides: Vec<Option<&Guide>> = painted
        .windows(2)
        .zip(&gap_ends)
        .map(|(w, &((oa, _), _))| {
            let (a, b) = (w[0].1, w[1].0);
            if b - a < GUIDE_MIN_GAP_M {
                return None;
            }
            guides
                .iter()
                .enumerate()
                .filter(|&(j, g)| j != own && g.covers(a, b))
                .filter_map(|(_, g)| Some((g, (g.offset(a)? - oa).abs())))
                .filter(|&(_, d)| d <= GUIDE_MAX_DISTANCE_M)
                .max_by(|x, y| {
                    painted_share(&x.0.painted, a, b)
                        .total_cmp(&painted_share(&y.0.painted, a, b))
                        .then(y.1.total_cmp(&x.1))
                })
                .map(|(g, _)| g)
        })
        .collect();
    let offset_at = |s: f64| -> f64 {
        let k = painted.partition_point(|iv| iv.1 < s);
        if k < painted.len() && s >= painted[k].0 {
            return fit(s).0;
        }
        if k == 0 || k >= painted.len() {
            return fit(s).0;
        }
        // In the gap between painted[k-1] and painted[k]: along the guide, the difference
        // from it interpolated linearly; without one, a cubic Hermite.
        let (a, b) = (painted[k - 1].1, painted[k].0);
        let ((oa, ta), (ob, tb)) = gap_ends[k - 1];
        let l = b - a;
        let t = ((s - a) / l).clamp(0.0, 1.0);
        if let Some(g) = gap_guides[k - 1]
            && let (Some(ga), Some(gb), Some(gs)) = (g.offset(a), g.offset(b), g.offset(s))
        {
            // The ends as fitted locally: the guide, not a wide fit, carries the shape.
            let (fa, fb) = (fit(a).0, fit(b).0);
            return gs + (fa - ga) + t * ((fb - gb) - (fa - ga));
        }
        let (t2, t3) = (t * t, t * t * t);
        (2.0 * t3 - 3.0 * t2 + 1.0) * oa
            + (t3 - 2.0 * t2 + t) * l * ta
            + (-2.0 * t3 + 3.0 * t2) * ob
            + (t3 - t2) * l * tb
    };
    let line: Vec<[f64; 2]> = stations.iter().map(|&s| refl.point(s, offset_at(s))).collect();
    let rms = (so.iter().map(|q| (q[1] - fit(q[0]).0).powi(2)).sum::<f64>() / so.len() as f64).sqrt();
    (geom::simplify(&line, p.simplify_tolerance_m), rms)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::observed::test_seen_except;
    use crate::pipeline::types::test_straight_trajectory;

    fn traj() -> Trajectory {
        test_straight_trajectory(100, -20.0)
    }

    /// A segment from s0 to s1 starting at offset o0 with one slope at both ends.
    fn seg(s0: f64, s1: f64, o0: f64, slope: f64, width: f64) -> Seg {
        Seg {
            members: vec![],
            s0,
            s1,
            o0,
            o1: o0 + slope * (s1 - s0),
            slope0: slope,
            slope1: slope,
            fit0: (s1 - s0).clamp(0.1, 15.0),
            fit1: (s1 - s0).clamp(0.1, 15.0),
            width,
            painted: s1 - s0,
        }
    }

    /// Dash-class pieces on the spans `(x0, x1)`, keyed by position.
    fn dash_pieces(spans: &[(f64, f64)]) -> Vec<LanePiece> {
        spans
            .iter()
            .enumerate()
            .map(|(i, &(a, b))| piece(i, a, b, MarkingClass::DashedLine))
            .collect()
    }

    fn piece(key: usize, x0: f64, x1: f64, class: MarkingClass) -> LanePiece {
        LanePiece {
            key,
            class,
            centerline: vec![[x0, 3.5], [x1, 3.5]],
            width_m: 0.15,
            confidence: 0.9,
        }
    }

    /// In the trajectory frame lane lines sway with the vehicle (here 0.3 m over a 30 m
    /// wavelength). A line with a 30 m gap beside a line painted all along follows that
    /// line's sway through the gap (within 3 cm); alone, the Hermite of its ends does not
    /// (0.42 m off).
    #[test]
    fn a_long_gap_follows_the_sway_of_a_line_painted_beside_it() {
        let sway = |x: f64| 0.3 * (2.0 * std::f64::consts::PI * x / 30.0).sin();
        let swaying = |key: usize, x0: f64, x1: f64, y: f64| LanePiece {
            key,
            class: MarkingClass::SolidLine,
            centerline: (0..=((x1 - x0) * 2.0) as usize)
                .map(|i| {
                    let x = x0 + 0.5 * i as f64;
                    [x, y + sway(x)]
                })
                .collect(),
            width_m: 0.15,
            confidence: 0.9,
        };
        let gapped = vec![swaying(0, 0.0, 30.0, 2.0), swaying(1, 60.0, 90.0, 2.0)];
        let guide = swaying(2, 0.0, 90.0, -1.5);
        let worst_in_gap = |pieces: &[LanePiece]| {
            let lanes = grow(pieces, &traj(), &Params::default());
            let line = lanes
                .lines
                .iter()
                .find(|l| l.pieces.contains(&0))
                .expect("the gapped line");
            assert!(line.pieces.contains(&1), "one line across the gap");
            line.line
                .windows(2)
                .flat_map(|w| {
                    (0..10).map(move |k| {
                        let t = k as f64 / 10.0;
                        [
                            w[0][0] + t * (w[1][0] - w[0][0]),
                            w[0][1] + t * (w[1][1] - w[0][1]),
                        ]
                    })
                })
                .filter(|q| q[0] > 31.0 && q[0] < 59.0)
                .map(|q| (q[1] - 2.0 - sway(q[0])).abs())
                .fold(0.0, f64::max)
        };
        let guided = worst_in_gap(&[gapped.clone(), vec![guide]].concat());
        assert!(guided < 0.05, "{guided}");
        let alone = worst_in_gap(&gapped);
        assert!(alone > 0.1, "{alone}");
    }

    /// Two 1 m solid pieces 16 m apart make no lane line (2 m of paint); three pieces of
    /// irregular length and spacing (6, 1 and 2.5 m: no dashes) over the same 17 m do
    /// (9.5 m).
    #[test]
    fn a_solid_line_of_few_pieces_needs_eight_metres_of_paint() {
        let p = Params::default();
        let two = vec![
            piece(0, 0.0, 1.0, MarkingClass::SolidLine),
            piece(1, 16.0, 17.0, MarkingClass::SolidLine),
        ];
        assert!(grow(&two, &traj(), &p).lines.is_empty());
        let three = vec![
            piece(0, 0.0, 6.0, MarkingClass::SolidLine),
            piece(1, 7.0, 8.0, MarkingClass::SolidLine),
            piece(2, 14.5, 17.0, MarkingClass::SolidLine),
        ];
        let lanes = grow(&three, &traj(), &p);
        assert_eq!(lanes.lines.len(), 1, "{:?}", lanes.lines);
        assert_eq!(lanes.lines[0].class, LaneLineClass::SolidLine);
    }

    /// `unknown` fragments (1 m every 6 m, the period of a dashed line) between two stretches
    /// of a solid line join it without making it dashed there: one solid lane line, the
    /// fragments made `solid_line`. Named dashes so placed make a dashed stretch, and
    /// fragments alone make no lane line.
    #[test]
    fn neutral_fragments_join_a_line_without_deciding_its_class() {
        let p = Params::default();
        let pieces = |middle: MarkingClass| {
            let mut v = vec![piece(0, 0.0, 30.0, MarkingClass::SolidLine)];
            v.extend((0..8).map(|k| piece(1 + k, 33.0 + 6.0 * k as f64, 34.0 + 6.0 * k as f64, middle)));
            v.push(piece(9, 82.0, 110.0, MarkingClass::SolidLine));
            v
        };
        let lanes = grow(&pieces(MarkingClass::Unknown), &traj(), &p);
        assert_eq!(lanes.lines.len(), 1, "{:?}", lanes.lines);
        assert_eq!(lanes.lines[0].class, LaneLineClass::SolidLine);
        assert_eq!(lanes.lines[0].pieces.len(), 10);
        assert!(lanes.classes.iter().all(|&(_, c)| c == MarkingClass::SolidLine));
        let dashed = grow(&pieces(MarkingClass::DashedLine), &traj(), &p);
        assert!(
            dashed.lines.iter().any(|l| l.class == LaneLineClass::DashedLine),
            "{:?}",
            dashed.lines
        );
        let alone: Vec<LanePiece> = pieces(MarkingClass::Unknown)[1..9].to_vec();
        assert!(grow(&alone, &traj(), &p).lines.is_empty());
    }

    /// Two 30 m stretches of one line 90 m apart (a far line whose dashes went unseen) are
    /// linked; 0.8 m apart across the road they are not, nor are 10 m pieces, nor
    /// stretches beyond `max_chain_gap_m`.
    #[test]
    fn long_stretches_link_across_long_gaps_short_pieces_do_not() {
        let p = Params::default();
        let none = |_: [f64; 2], _: [f64; 2]| Gap::Unknown;
        let pair = |len: f64, gap: f64, d: f64| {
            [
                seg(0.0, len, 5.0, 0.0, 0.15),
                seg(len + gap, 2.0 * len + gap, 5.0 + d, 0.0, 0.15),
            ]
        };
        assert_eq!(link(&pair(30.0, 90.0, 0.1), &p, &[], &none), vec![vec![0, 1]]);
        assert_eq!(
            link(&pair(30.0, 90.0, 0.8), &p, &[], &none),
            vec![vec![0], vec![1]]
        );
        assert_eq!(
            link(&pair(10.0, 90.0, 0.0), &p, &[], &none),
            vec![vec![0], vec![1]]
        );
        assert_eq!(
            link(&pair(30.0, 160.0, 0.0), &p, &[], &none),
            vec![vec![0], vec![1]]
        );
        let off = Params {
            max_chain_gap_m: 0.0,
            ..Params::default()
        };
        assert_eq!(
            link(&pair(30.0, 90.0, 0.0), &off, &[], &none),
            vec![vec![0], vec![1]]
        );
    }

    /// Offsets that only meet by extrapolating slopes: two 15 m pieces of a line drifting
    /// across the trajectory (2.7°, 1.75 m over the 37 m gap) are linked; a 2 m blob 0.47 m
    /// wide with the same slope, whose direction its outline hardly fixes, is not linked to
    /// a piece 1.75 m beside it 37 m on. At the same offset the blob still links.
    #[test]
    fn short_wide_blobs_do_not_steer_links_sideways() {
        let p = Params::default();
        let none = |_: [f64; 2], _: [f64; 2]| Gap::Unknown;
        let k = 0.047;
        let long = [
            seg(0.0, 15.0, 5.36 - 15.0 * k, k, 0.15),
            seg(52.0, 67.0, 7.11, k, 0.15),
        ];
        assert_eq!(link(&long, &p, &[], &none), vec![vec![0, 1]]);
        let blob = [
            seg(0.0, 2.0, 5.36 - 2.0 * k, k, 0.47),
            seg(39.0, 41.8, 7.11, k, 0.25),
        ];
        assert_eq!(link(&blob, &p, &[], &none), vec![vec![0], vec![1]]);
        let level = [seg(0.0, 2.0, 5.36, 0.0, 0.47), seg(39.0, 41.8, 5.4, 0.0, 0.25)];
        assert_eq!(link(&level, &p, &[], &none), vec![vec![0, 1]]);
    }

    /// Mutual best matches repeat among the ends left free: C is the best next piece of
    /// both A and D and takes D (a better fit); A then links to its next best, B, which
    /// has no better free predecessor. (One round of mutual best matches left A and B
    /// apart.)
    #[test]
    fn ends_left_free_link_to_their_next_best_match() {
        let level = |s0: f64, s1: f64, o: f64| seg(s0, s1, o, 0.0, 0.15);
        let p = Params::default();
        let none = |_: [f64; 2], _: [f64; 2]| Gap::Unknown;
        let segs = [
            level(0.0, 10.0, 3.6),
            level(5.0, 13.5, 3.52),
            level(14.0, 30.0, 3.5),
            level(20.0, 30.0, 3.8),
        ];
        let mut chains = link(&segs, &p, &[], &none);
        chains.sort();
        assert_eq!(chains, vec![vec![0, 3], vec![1, 2]]);
        // A far line's pieces, 26 m from the trajectory, across gaps the scanner did not
        // see: the 12 m gap to the next piece is linked although a fragment 32 m on
        // matches the first piece's offset better. (Ends at the same offset, slopes apart.)
        let far = |s0: f64, s1: f64, o: f64, slope: f64, width: f64| Seg {
            o1: o,
            ..seg(s0, s1, o, slope, width)
        };
        let segs = [
            far(118.5, 198.4, 26.58, 0.0112, 0.15),
            far(210.4, 214.6, 26.43, 0.0103, 0.18),
            far(230.7, 231.9, 26.40, 0.0603, 0.09),
        ];
        let unseen = |_: [f64; 2], _: [f64; 2]| Gap::Unseen;
        assert_eq!(link(&segs, &p, &[], &unseen), vec![vec![0, 1, 2]]);
    }

    /// Two 1 m solid fragments 30 m apart cover 6 % of the line they would span: no lane
    /// line (unless `min_paint_share` and `scant_solid_paint_m` are 0); a 2/4 m dashed
    /// line (33 % painted) is one.
    #[test]
    fn stray_fragments_make_no_lane_line_and_dashes_do() {
        let t = traj();
        let p = Params::default();
        let stray = [
            piece(0, 0.0, 1.0, MarkingClass::SolidLine),
            piece(1, 31.0, 32.0, MarkingClass::SolidLine),
        ];
        assert!(grow(&stray, &t, &p).lines.is_empty());
        let lenient = Params {
            min_paint_share: 0.0,
            scant_solid_paint_m: 0.0,
            ..Params::default()
        };
        assert_eq!(grow(&stray, &t, &lenient).lines.len(), 1);
        let dashes: Vec<LanePiece> = (0..8)
            .map(|i| piece(i, 6.0 * i as f64, 6.0 * i as f64 + 2.0, MarkingClass::DashedLine))
            .collect();
        let lanes = grow(&dashes, &t, &p);
        assert_eq!(lanes.lines.len(), 1);
        assert_eq!(lanes.lines[0].class, LaneLineClass::DashedLine);
        assert_eq!(lanes.lines[0].pieces.len(), 8);
    }

    /// A far-range line reads as 1 m fragments whose own directions scatter by ±4°
    /// (a few points across): over short gaps they are one lane line although the
    /// fragments differ by 8°, more than `max_angle_deg`. Two such fragments 12 m apart
    /// with the same disagreement are not joined: the slack is for short gaps only.
    #[test]
    fn short_fragments_with_noisy_directions_link_across_short_gaps_only() {
        let t = traj();
        let p = Params::default();
        let tilt = 4f64.to_radians().tan() / 2.0;
        let frag = |key: usize, x0: f64, sign: f64| LanePiece {
            key,
            class: MarkingClass::SolidLine,
            centerline: vec![[x0, 3.5 + sign * tilt], [x0 + 1.0, 3.5 - sign * tilt]],
            width_m: 0.12,
            confidence: 0.8,
        };
        let line: Vec<LanePiece> = (0..12)
            .map(|i| frag(i, 2.5 * i as f64, if i % 2 == 0 { 1.0 } else { -1.0 }))
            .collect();
        let lanes = grow(&line, &t, &p);
        assert_eq!(
            lanes.lines.len(),
            1,
            "{:?}",
            lanes.lines.iter().map(|l| &l.pieces).collect::<Vec<_>>()
        );
        assert_eq!(lanes.lines[0].pieces.len(), 12);
        let lenient = Params {
            min_paint_share: 0.0,
            min_length_m: 0.0,
            scant_solid_paint_m: 0.0,
            ..Params::default()
        };
        let apart = [frag(0, 0.0, 1.0), frag(1, 13.0, -1.0)];
        assert!(
            grow(&apart, &t, &lenient)
                .lines
                .iter()
                .all(|l| l.pieces.len() == 1)
        );
        let aligned = [frag(0, 0.0, 0.0), frag(1, 13.0, 0.0)];
        assert_eq!(grow(&aligned, &t, &lenient).lines[0].pieces.len(), 2);
    }

    /// An exit ramp's edge line leaving a lane line, and the chain of wide dashes that
    /// carries on along the lane line beside it: over their 60 m common stretch the median
    /// offsets differ by 0.15 m (less than half a 0.45 m dash plus 5 cm), but at the far
    /// end by 0.4 m. They stay two lines; the same chain along a line that keeps its offset
    /// (a duplicate from a second scanner head) is merged.
    #[test]
    fn a_diverging_line_is_not_merged_with_the_dashes_beside_it() {
        let item = |key: usize, so: Vec<[f64; 2]>, width: f64| Item {
            keys: vec![key],
            so,
            width,
            conf: 0.9,
            neutral: false,
        };
        let ramp = |k: f64| {
            item(
                0,
                (0..=120)
                    .map(|i| [0.5 * i as f64, 3.5 + k * (0.5 * i as f64).powi(2)])
                    .collect(),
                0.2,
            )
        };
        let dashes = || {
            item(
                1,
                (0..=120)
                    .map(|i| 0.5 * i as f64)
                    .filter(|x| x % 6.0 < 3.0)
                    .map(|x| [x, 3.5])
                    .collect(),
                0.45,
            )
        };
        let diverging = merge_overlaps(vec![ramp(1.67e-4), dashes()]);
        assert_eq!(diverging.len(), 2);
        let parallel = merge_overlaps(vec![ramp(0.0), dashes()]);
        assert_eq!(parallel.len(), 1);
        assert_eq!(parallel[0].keys, vec![0, 1]);
    }

    /// A sparse far line linked into two interleaved chains: one holds fragments at 0–2 m
    /// and 18–22 m, the other one at 8–10 m, inside the first one's gap. They share no
    /// sampled stretch, so the first chain's offset is interpolated across its gap: at the
    /// same offset they are one line, 0.5 m beside it they are not, and across a gap longer
    /// than `INTERPOLATED_GAP_M` nothing is interpolated.
    #[test]
    fn interleaved_chains_of_one_line_are_merged_across_their_gaps() {
        let frags = |key: usize, spans: &[(f64, f64)], o: f64| Item {
            keys: vec![key],
            so: spans
                .iter()
                .flat_map(|&(a, b)| (0..=((b - a) / 0.25) as usize).map(move |i| [a + 0.25 * i as f64, o]))
                .collect(),
            width: 0.12,
            conf: 0.8,
            neutral: false,
        };
        let outer = || frags(0, &[(0.0, 2.0), (18.0, 22.0)], 16.4);
        assert_eq!(
            merge_overlaps(vec![outer(), frags(1, &[(8.0, 10.0)], 16.43)]).len(),
            1
        );
        assert_eq!(
            merge_overlaps(vec![outer(), frags(1, &[(8.0, 10.0)], 16.9)]).len(),
            2
        );
        let far_apart = frags(0, &[(0.0, 2.0), (28.0, 30.0)], 16.4);
        assert_eq!(
            merge_overlaps(vec![far_apart, frags(1, &[(12.0, 14.0)], 16.4)]).len(),
            2
        );
    }

    /// A worn double line (centres 0.3 m apart): the two lines stay apart even where a
    /// piece holds both of them (0.5 m wide, centred between them) and overlaps each; a
    /// piece of the same line split lengthwise (0.1 m apart) is merged.
    #[test]
    fn a_double_line_is_never_merged_into_one() {
        let line = |key: usize, a: f64, b: f64, o: f64, width: f64| Item {
            keys: vec![key],
            so: (0..=((b - a) / 0.25) as usize)
                .map(|i| [a + 0.25 * i as f64, o])
                .collect(),
            width,
            conf: 0.8,
            neutral: false,
        };
        let lower = || line(0, 0.0, 10.0, 5.4, 0.15);
        let upper = || line(1, 0.0, 10.0, 5.7, 0.15);
        assert_eq!(merge_overlaps(vec![lower(), upper()]).len(), 2);
        // With the wide piece the three may not become one line (they would with a
        // tolerance of half the widest piece: 0.3 m).
        let with_both = merge_overlaps(vec![lower(), upper(), line(2, 2.0, 8.0, 5.55, 0.5)]);
        assert!(
            with_both.len() >= 2,
            "{:?}",
            with_both.iter().map(|i| &i.keys).collect::<Vec<_>>()
        );
        assert_eq!(
            merge_overlaps(vec![lower(), line(3, 1.0, 9.0, 5.5, 0.15)]).len(),
            1
        );
    }

    /// A 2/4 m dashed line seen in part (each dash read as 1–2 m, so lengths and gaps
    /// vary, one dash missing) keeps its 6 m period and is dashed; a solid line read as
    /// fragments with the same lengths at irregular spacings is solid.
    /// A worn 2/4 m dashed line (some dashes seen only in part) turns solid before a
    /// junction; the solid line's first 8 m is seen as one run before a gap. That run is no
    /// dash: the dashes before it are one dashed lane line and the rest one solid lane
    /// line. Without the rule the 8 m run spoils the dash tests and all of it is solid.
    /// A sparse solid line with one long run among five short fragments stays solid.
    #[test]
    fn a_long_run_after_dashes_starts_the_solid_line() {
        let t = test_straight_trajectory(140, -20.0);
        let p = Params::default();
        let runs = [
            (-0.6, 0.2),
            (4.2, 5.7),
            (10.2, 12.1),
            (16.2, 17.4),
            (22.5, 23.3),
            (29.4, 30.0),
            (34.0, 36.0),
            (40.3, 42.2),
            (46.5, 47.4),
            (52.1, 54.1),
            (58.1, 66.3),
            (68.3, 69.1),
            (70.8, 81.9),
            (82.9, 84.5),
        ];
        let lanes = grow(&dash_pieces(&runs), &t, &p);
        let mut classes: Vec<(LaneLineClass, f64)> =
            lanes.lines.iter().map(|l| (l.class, l.length_m)).collect();
        classes.sort_by(|a, b| a.1.total_cmp(&b.1));
        assert_eq!(classes.len(), 2, "{classes:?}");
        assert!(
            classes
                .iter()
                .any(|&(c, l)| c == LaneLineClass::DashedLine && (50.0..60.0).contains(&l)),
            "{classes:?}"
        );
        assert!(
            classes
                .iter()
                .any(|&(c, l)| c == LaneLineClass::SolidLine && (20.0..30.0).contains(&l)),
            "{classes:?}"
        );
        // A far solid line: a 7 m run, then five 1 m fragments on a loose 5-6 m rhythm.
        let sparse = [
            (0.0, 6.9),
            (10.2, 11.0),
            (15.9, 16.9),
            (21.5, 22.6),
            (27.4, 28.2),
            (32.6, 33.9),
        ];
        let lanes = grow(&dash_pieces(&sparse), &t, &p);
        assert_eq!(lanes.lines.len(), 1);
        assert_eq!(lanes.lines[0].class, LaneLineClass::SolidLine);
    }

    /// A solid line 30 m long turns into three 2 m dashes (a 14 m dashed stretch after a
    /// junction, shorter than `min_length_m` alone): the dashes are a dashed lane line of
    /// their own. Three dashes alone are no lane line.
    #[test]
    fn a_short_dashed_stretch_after_a_solid_line_is_kept() {
        let t = test_straight_trajectory(100, -20.0);
        let p = Params::default();
        let mut pieces = vec![piece(0, 0.0, 30.0, MarkingClass::SolidLine)];
        pieces.extend(
            [(35.0, 37.0), (41.0, 43.0), (47.0, 49.0)]
                .iter()
                .enumerate()
                .map(|(i, &(a, b))| piece(i + 1, a, b, MarkingClass::DashedLine)),
        );
        let lanes = grow(&pieces, &t, &p);
        let mut got: Vec<(LaneLineClass, f64)> = lanes.lines.iter().map(|l| (l.class, l.length_m)).collect();
        got.sort_by(|a, b| a.1.total_cmp(&b.1));
        assert_eq!(got.len(), 2, "{got:?}");
        assert_eq!(got[0].0, LaneLineClass::DashedLine);
        assert!((got[0].1 - 14.0).abs() < 0.5, "{got:?}");
        assert_eq!(got[1].0, LaneLineClass::SolidLine);
        let dashed = lanes
            .classes
            .iter()
            .filter(|c| c.1 == MarkingClass::DashedLine)
            .count();
        assert_eq!(dashed, 3);
        let alone = grow(&pieces[1..], &t, &p);
        assert!(alone.lines.is_empty(), "{:?}", alone.lines.len());
    }

    /// The period of dash centres: the median spacing where it fits; where missing
    /// dashes make as many double spacings as single ones, the repeated single spacing;
    /// none for irregular spacings.
    #[test]
    fn dash_period_sees_through_missing_dashes() {
        let near = |a: Option<f64>, b: f64| a.is_some_and(|a| (a - b).abs() < 0.2);
        assert!(near(dash_period(&[15.0, 15.2, 14.9], 0.15), 15.0));
        // Median 22.8 lies between the single and double spacings.
        assert!(near(dash_period(&[30.0, 15.2, 15.3, 30.6], 0.15), 15.25));
        assert_eq!(dash_period(&[5.0, 11.0, 23.0, 8.0], 0.15), None);
        // A loose single period with no double spacing is left to the median test.
        assert_eq!(dash_period(&[14.95, 18.45, 14.1, 12.2], 0.15), None);
        // One single spacing among doubles is no evidence of the period.
        assert_eq!(dash_period(&[30.0, 15.2, 31.0, 44.0], 0.15), None);
    }

    /// A 2/6 m dashed line missing every other dash at both ends (gaps seen bare), then
    /// 6 m on a 22 m solid line: as many double spacings as single ones put the median
    /// between the two, yet the line is dashed, and split from the solid one.
    #[test]
    fn dashes_with_missing_ones_before_a_solid_line_stay_dashed() {
        let t = traj();
        let p = Params::default();
        let mut pieces = dash_pieces(&[(0.0, 2.0), (16.0, 18.0), (24.0, 26.0), (32.0, 34.0), (48.0, 50.0)]);
        pieces.push(piece(9, 56.0, 78.0, MarkingClass::SolidLine));
        let seen = crate::pipeline::observed::test_seen_except(&t, 3.5, |_| false);
        let lanes = grow_with_barriers(&pieces, &t, &p, &[], Some(&seen.lookup()));
        let classes: Vec<LaneLineClass> = lanes.lines.iter().map(|l| l.class).collect();
        assert_eq!(lanes.lines.len(), 2, "{classes:?}");
        assert!(classes.contains(&LaneLineClass::DashedLine) && classes.contains(&LaneLineClass::SolidLine));
    }

    /// A chain's end direction comes from at least 10 m of its samples: a straight line
    /// sampled to 40 m and then one 1 m fragment 16 m on, tilted 6°, ends straight (the
    /// fragment alone set it before, and the chain was taken to know it over 15 m).
    #[test]
    fn a_sparse_chain_end_slope_spans_ten_metres() {
        let mut so: Vec<[f64; 2]> = (0..=40).map(|s| [s as f64, 26.5]).collect();
        so.extend([[56.0, 26.5], [56.5, 26.45], [57.0, 26.4]]);
        let (slope, fit) = end_slope(&so, true, 15.0);
        assert!(slope.abs() < 0.01 && fit >= 10.0, "{slope} {fit}");
        // Dense samples: the last 15 m as before.
        let dense: Vec<[f64; 2]> = (0..=60).map(|s| [s as f64, 0.01 * s as f64]).collect();
        let (slope, fit) = end_slope(&dense, true, 15.0);
        assert!(
            (slope - 0.01).abs() < 1e-9 && (fit - 15.0).abs() < 1e-9,
            "{slope} {fit}"
        );
    }

    /// A far line whose every other piece was crossed by one scan row and reads 3 cm wide
    /// is one lane line: a width under the narrowest painted line compares as that line
    /// (0.03 against 0.15 m failed the width similarity, and the 0.15 m pieces, 41 m apart,
    /// are too far apart to link past the narrow ones).
    #[test]
    fn under_read_far_pieces_join_their_line() {
        let t = traj();
        let p = Params::default();
        let pieces: Vec<LanePiece> = (0..5)
            .map(|i| {
                let s0 = 22.0 * i as f64;
                LanePiece {
                    width_m: if i % 2 == 0 { 0.15 } else { 0.03 },
                    ..piece(i, s0, s0 + 3.0, MarkingClass::DashedLine)
                }
            })
            .collect();
        let lanes = grow(&pieces, &t, &p);
        let pieces_per_line: Vec<usize> = lanes.lines.iter().map(|l| l.pieces.len()).collect();
        assert_eq!(pieces_per_line, vec![5]);
    }

    /// Course of a ramp's edge line diverging at 8.5° (do/ds −0.15).
    fn ramp_course(x: f64) -> f64 {
        3.5 - 0.15 * x
    }

    /// The ramp's edge line as one solid piece over 0-30 m, and a record of the pavement
    /// seen everywhere but along its course beyond 30 m.
    fn ramp() -> (LanePiece, crate::pipeline::observed::Observed) {
        let line = LanePiece {
            centerline: vec![[0.0, ramp_course(0.0)], [30.0, ramp_course(30.0)]],
            ..piece(0, 0.0, 30.0, MarkingClass::SolidLine)
        };
        let seen = crate::pipeline::observed::test_seen_where(&traj(), |x, y| {
            x > 30.0 && (y - ramp_course(x)).abs() < 0.3
        });
        (line, seen)
    }

    /// A ramp's edge line diverging at 8.5° (do/ds −0.15), its last 20 m seen as 1 m
    /// fragments 3 cm wide every 2 m, the asphalt between them unseen (highway drives,
    /// 13–17 m out), each pointing 8.5–13° off the line's course (flat or do/ds +0.09): all
    /// of them join the line, by their centres, and none joins across a crosswalk ahead or
    /// from 0.4 m off course.
    #[test]
    fn a_diverging_line_takes_its_fragments_whatever_their_direction() {
        let p = Params::default();
        let course = ramp_course;
        let (line, seen) = ramp();
        let grow = |pieces: &[LanePiece], barriers: &[Vec<[f64; 2]>]| {
            grow_with_barriers(pieces, &traj(), &p, barriers, Some(&seen.lookup()))
        };
        let mut pieces = vec![line];
        for k in 0..10 {
            let c = 31.5 + 2.0 * k as f64;
            let slope = if k % 2 == 0 { 0.0 } else { 0.09 };
            let class = if k % 3 == 0 {
                MarkingClass::Unknown
            } else {
                MarkingClass::DashedLine
            };
            pieces.push(LanePiece {
                centerline: vec![
                    [c - 0.5, course(c) - 0.5 * slope],
                    [c + 0.5, course(c) + 0.5 * slope],
                ],
                width_m: 0.03,
                ..piece(1 + k, c - 0.5, c + 0.5, class)
            });
        }
        let lanes = grow(&pieces, &[]);
        assert_eq!(lanes.lines.len(), 1, "{:?}", lanes.lines);
        let line = &lanes.lines[0];
        assert_eq!(line.pieces, (0..11).collect::<Vec<_>>());
        assert_eq!(line.class, LaneLineClass::SolidLine);
        let end = line.line[line.line.len() - 1];
        assert!(end[0] > 49.5 && (end[1] - course(end[0])).abs() < 0.1, "{end:?}");
        // A fragment 0.4 m off the course stays out.
        let mut off = pieces.clone();
        off[10].centerline.iter_mut().for_each(|v| v[1] += 0.4);
        let lanes = grow(&off, &[]);
        assert_eq!(lanes.lines[0].pieces, (0..10).collect::<Vec<_>>());
        // A crosswalk across the course at x 36-39 stops the growth there.
        let zebra = vec![vec![[36.0, -10.0], [39.0, -10.0], [39.0, 10.0], [36.0, 10.0]]];
        let lanes = grow(&pieces, &zebra);
        assert_eq!(lanes.lines[0].pieces, (0..4).collect::<Vec<_>>());
    }

    /// A diverging line's fragments, a 1 m one beside a 3 m one, 0.1 m apart across (too far
    /// for the two to be one piece): growing the line's end takes the 3 m one, and the other,
    /// now behind the end, joins as a piece within the line's span (highway s1001: five
    /// fragments of the ramp's edge line). 0.3 m off the course it does not.
    #[test]
    fn a_fragment_beside_one_the_line_took_joins_it_too() {
        let p = Params::default();
        let (line, seen) = ramp();
        let frag = |key: usize, x0: f64, x1: f64, off: f64| {
            let c = 0.5 * (x0 + x1);
            LanePiece {
                centerline: vec![[x0, ramp_course(c) + off], [x1, ramp_course(c) + off]],
                width_m: 0.03,
                ..piece(key, x0, x1, MarkingClass::Unknown)
            }
        };
        let pieces = |off: f64| {
            let mut v = vec![line.clone()];
            v.extend([
                frag(1, 31.0, 34.0, 0.0),
                frag(2, 31.8, 32.8, off),
                frag(3, 35.0, 36.0, 0.0),
                frag(4, 37.0, 38.0, 0.0),
            ]);
            v
        };
        let keys = |off: f64| -> Vec<Vec<usize>> {
            grow_with_barriers(&pieces(off), &traj(), &p, &[], Some(&seen.lookup()))
                .lines
                .iter()
                .map(|l| l.pieces.clone())
                .collect()
        };
        assert_eq!(keys(0.1), vec![vec![0, 1, 2, 3, 4]]);
        assert_eq!(keys(0.3), vec![vec![0, 1, 3, 4]]);
    }

    /// A far 2/4 m dashed line (urban drive s2, offset 12.8 m) seen as one dash in 1–4,
    /// its gaps seen bare: the centres' spacings are 1, 4, 3, 1, 2, 1 and 2 periods. The
    /// fragments of a worn solid line (urban drive s1001, offset 16.2 m), gaps seen bare
    /// too, have no common period and stay solid.
    #[test]
    fn far_dashes_missing_in_runs_are_dashed_on_their_grid() {
        let t = traj();
        let p = Params::default();
        let seen = crate::pipeline::observed::test_seen_except(&t, 3.5, |_| false);
        let class_of = |centres: &[f64], lens: &[f64]| {
            let spans: Vec<(f64, f64)> = centres
                .iter()
                .zip(lens)
                .map(|(&c, &l)| (c - l / 2.0, c + l / 2.0))
                .collect();
            let lanes = grow_with_barriers(&dash_pieces(&spans), &t, &p, &[], Some(&seen.lookup()));
            let classes: Vec<LaneLineClass> = lanes.lines.iter().map(|l| l.class).collect();
            assert_eq!(classes.len(), 1, "{classes:?}");
            classes[0]
        };
        let far = [0.2, 6.5, 30.1, 48.3, 54.2, 66.2, 72.3, 84.1];
        let far_lens = [1.7, 0.6, 2.0, 1.9, 1.8, 1.9, 1.7, 1.9];
        assert_eq!(class_of(&far, &far_lens), LaneLineClass::DashedLine);
        let worn = [4.1, 7.1, 14.9, 18.3, 24.7, 28.1, 41.2, 45.7, 50.0];
        let worn_lens = [1.1, 1.8, 3.1, 1.1, 1.2, 2.7, 1.8, 1.3, 1.1];
        assert_eq!(class_of(&worn, &worn_lens), LaneLineClass::SolidLine);
        assert_eq!(
            dash_grid(&[6.3, 23.6, 18.2, 5.9, 12.0, 6.1, 11.8]).map(|p| (p * 10.0).round()),
            Some(60.0)
        );
        // One single spacing gives no period.
        assert_eq!(dash_grid(&[6.3, 23.6, 18.2, 12.0]), None);
    }

    #[test]
    fn partly_seen_dashes_are_dashed_by_their_period() {
        let t = traj();
        let p = Params::default();
        // (start, length) of the seen part of each dash; the dash at 36 m is missing.
        let seen = [
            (0.5, 1.0),
            (6.05, 1.9),
            (12.5, 1.1),
            (18.0, 2.0),
            (24.05, 1.9),
            (30.6, 0.8),
            (42.2, 1.3),
        ];
        let dashes: Vec<LanePiece> = seen
            .iter()
            .enumerate()
            .map(|(i, &(a, l))| piece(i, a, a + l, MarkingClass::DashedLine))
            .collect();
        let lanes = grow(&dashes, &t, &p);
        assert_eq!(lanes.lines.len(), 1);
        assert_eq!(lanes.lines[0].class, LaneLineClass::DashedLine);
        // The same fragments where a solid line was occluded irregularly.
        let starts = [0.0, 3.2, 11.0, 14.5, 22.8, 33.0, 36.1];
        let fragments: Vec<LanePiece> = starts
            .iter()
            .zip(&seen)
            .enumerate()
            .map(|(i, (&a, &(_, l)))| piece(i, a, a + l, MarkingClass::DashedLine))
            .collect();
        let lanes = grow(&fragments, &t, &p);
        assert_eq!(lanes.lines.len(), 1);
        assert_eq!(lanes.lines[0].class, LaneLineClass::SolidLine);
    }

    /// Two solid stretches 25 m long, 80 m apart on one course: one lane line where the
    /// scanner did not see the gap or cannot tell, two where it saw bare asphalt there (a
    /// ramp's mouth). Dashed stretches link across bare gaps: their gaps are bare anyway.
    #[test]
    fn solid_stretches_do_not_link_across_seen_bare_asphalt() {
        let t = test_straight_trajectory(200, -20.0);
        let p = Params::default();
        let solid = [
            piece(0, 0.0, 25.0, MarkingClass::SolidLine),
            piece(1, 105.0, 130.0, MarkingClass::SolidLine),
        ];
        let unseen = test_seen_except(&t, 3.5, |x| (25.0..105.0).contains(&x));
        let bare = test_seen_except(&t, 3.5, |_| false);
        let lines = |pieces: &[LanePiece], seen: &crate::pipeline::observed::Observed| {
            grow_with_barriers(pieces, &t, &p, &[], Some(&seen.lookup()))
                .lines
                .len()
        };
        assert_eq!(grow(&solid, &t, &p).lines.len(), 1);
        assert_eq!(lines(&solid, &unseen), 1);
        assert_eq!(lines(&solid, &bare), 2);
        let dashes: Vec<LanePiece> = [0.0, 9.0, 18.0, 105.0, 114.0, 123.0]
            .iter()
            .enumerate()
            .map(|(i, &a)| piece(i, a, a + 3.0, MarkingClass::DashedLine))
            .collect();
        assert_eq!(lines(&dashes, &bare), 1);
    }

    /// Two solid pieces 45 m apart (more than `max_gap_m`): one lane line when the scanner
    /// did not see the gap's course (no dark point on it), two when it saw bare asphalt.
    #[test]
    fn lines_link_across_long_gaps_the_scanner_did_not_see() {
        let t = traj();
        let p = Params::default();
        let pieces = [
            piece(0, 0.0, 15.0, MarkingClass::SolidLine),
            piece(1, 60.0, 78.0, MarkingClass::SolidLine),
        ];
        let unseen = test_seen_except(&t, 3.5, |x| (15.0..60.0).contains(&x));
        let lanes = grow_with_barriers(&pieces, &t, &p, &[], Some(&unseen.lookup()));
        assert_eq!(lanes.lines.len(), 1);
        assert_eq!(lanes.lines[0].pieces, [0, 1]);
        let bare = test_seen_except(&t, 3.5, |_| false);
        let lanes = grow_with_barriers(&pieces, &t, &p, &[], Some(&bare.lookup()));
        assert_eq!(lanes.lines.len(), 2);
        // Beyond `max_unseen_gap_m`: two lines whatever was seen.
        let short = Params {
            max_unseen_gap_m: 30.0,
            ..Params::default()
        };
        assert_eq!(
            grow_with_barriers(&pieces, &t, &short, &[], Some(&unseen.lookup()))
                .lines
                .len(),
            2
        );
    }

    /// The class of the one lane line grown from `pieces` along [`traj`] with default
    /// parameters: with no record of what the scanner saw (`None`), or with the line's
    /// course (offset 3.5 m) seen everywhere, its gaps bare (`Some(true)`) or holding no
    /// dark point (`Some(false)`).
    fn one_line_class(pieces: &[LanePiece], bare: Option<bool>) -> LaneLineClass {
        let t = traj();
        let seen = bare.map(|b| test_seen_except(&t, 3.5, move |_| !b));
        let lanes = grow_with_barriers(
            pieces,
            &t,
            &Params::default(),
            &[],
            seen.as_ref().map(|s| s.lookup()).as_ref(),
        );
        assert_eq!(lanes.lines.len(), 1);
        lanes.lines[0].class
    }

    /// 1.5 m fragments every 6 m (a far line's scan columns drifting on and off it): a
    /// dashed line when its gaps show bare asphalt, a solid line when their course holds
    /// no dark point (the points there are paint), and dashed without any record.
    #[test]
    fn fragments_without_bare_gaps_are_no_dashes() {
        let spans: Vec<(f64, f64)> = (0..12).map(|i| (6.0 * i as f64, 6.0 * i as f64 + 1.5)).collect();
        let pieces = dash_pieces(&spans);
        assert_eq!(one_line_class(&pieces, None), LaneLineClass::DashedLine);
        assert_eq!(one_line_class(&pieces, Some(true)), LaneLineClass::DashedLine);
        assert_eq!(one_line_class(&pieces, Some(false)), LaneLineClass::SolidLine);
    }

    /// A far GB 6/9 m dashed line read in part (0.8-3.8 m of each dash, so the centres
    /// jitter by up to a quarter of the 15 m period): dashed where its gaps were seen bare,
    /// solid without that evidence (the same fragments of a sparse solid line).
    #[test]
    fn partly_seen_dashes_with_bare_gaps_keep_their_period() {
        let pieces = dash_pieces(&[
            (12.4, 16.0),
            (28.5, 29.8),
            (47.2, 48.0),
            (59.8, 63.6),
            (72.7, 75.1),
        ]);
        assert_eq!(one_line_class(&pieces, None), LaneLineClass::SolidLine);
        assert_eq!(one_line_class(&pieces, Some(true)), LaneLineClass::DashedLine);
    }

    /// Across a 23 m gap the centreline follows the trend of the paint on either side, not
    /// the slope of the 1 m fragment (tilted 0.1) that ends the paint before it.
    #[test]
    fn long_gaps_follow_the_trend_not_the_last_fragment() {
        let t = traj();
        let p = Params::default();
        // Centrelines sampled every metre, as outlines give them.
        let dense = |key: usize, x0: f64, x1: f64| LanePiece {
            centerline: (0..=(x1 - x0) as usize).map(|i| [x0 + i as f64, 3.5]).collect(),
            ..piece(key, x0, x1, MarkingClass::SolidLine)
        };
        let pieces = [
            dense(0, 0.0, 20.0),
            LanePiece {
                centerline: vec![[20.5, 3.5], [21.5, 3.6]],
                ..piece(1, 0.0, 0.0, MarkingClass::SolidLine)
            },
            dense(2, 45.0, 78.0),
        ];
        let lanes = grow(&pieces, &t, &p);
        assert_eq!(lanes.lines.len(), 1);
        let worst = lanes.lines[0]
            .line
            .iter()
            .filter(|q| (25.0..40.0).contains(&q[0]))
            .map(|q| (q[1] - 3.5).abs())
            .fold(0.0, f64::max);
        assert!(worst < 0.05, "{worst}");
    }

    /// y of a polyline at x (linear between vertices; the line runs along x).
    fn y_at(line: &[[f64; 2]], x: f64) -> f64 {
        let k = line.partition_point(|q| q[0] < x).clamp(1, line.len() - 1);
        let (a, b) = (line[k - 1], line[k]);
        a[1] + (b[1] - a[1]) * (x - a[0]) / (b[0] - a[0])
    }

    /// A far dashed line whose dashes' points put each dash a few centimetres off the
    /// paint is drawn through its neighbours (the cross-validated bandwidth widens), so it
    /// lies nearer the paint than the dashes; a line that bends (a 1 m lane shift over
    /// ~25 m) with exact dashes keeps the narrow fit and follows the bend.
    #[test]
    fn a_noisy_dashed_line_is_smoothed_through_its_neighbours_and_a_bend_is_kept() {
        let p = Params::default();
        let noise = [
            0.05, -0.06, 0.04, -0.05, 0.06, -0.04, 0.05, -0.06, 0.03, -0.05, 0.06, -0.04, 0.05,
        ];
        let dashes = |y: &dyn Fn(f64) -> f64, noise: &[f64]| -> Vec<LanePiece> {
            (0..13)
                .map(|i| {
                    let x0 = 6.0 * i as f64;
                    let n = noise.get(i).copied().unwrap_or(0.0);
                    LanePiece {
                        key: i,
                        class: MarkingClass::DashedLine,
                        centerline: (0..=4)
                            .map(|j| {
                                let x = x0 + 0.5 * j as f64;
                                [x, y(x) + n]
                            })
                            .collect(),
                        width_m: 0.15,
                        confidence: 0.9,
                    }
                })
                .collect()
        };
        let flat = |_: f64| 3.5;
        let lanes = grow(&dashes(&flat, &noise), &traj(), &p);
        assert_eq!(lanes.lines.len(), 1, "{:?}", lanes.lines);
        let line = &lanes.lines[0].line;
        let err: Vec<f64> = (1..12)
            .map(|i| (y_at(line, 6.0 * i as f64 + 1.0) - 3.5).abs())
            .collect();
        let mean = err.iter().sum::<f64>() / err.len() as f64;
        assert!(
            mean < 0.02,
            "mean error {mean} (dashes are 0.05 off on average): {err:?}"
        );

        let bend = |x: f64| 3.5 + 1.0 / (1.0 + (-(x - 36.0) / 6.0).exp());
        let lanes = grow(&dashes(&bend, &[]), &traj(), &p);
        assert_eq!(lanes.lines.len(), 1, "{:?}", lanes.lines);
        let line = &lanes.lines[0].line;
        for i in 0..13 {
            let x = 6.0 * i as f64 + 1.0;
            assert!(
                (y_at(line, x) - bend(x)).abs() < 0.02,
                "at {x}: {} vs {}",
                y_at(line, x),
                bend(x)
            );
        }
    }

    /// A bandwidth wider than the 10 m cap of a gap's end fits (`smoothing_m` up to 50, or
    /// a far dashed line's cross-validated 16 m) bridges the gap with that bandwidth
    /// instead of panicking on an inverted clamp.
    #[test]
    fn a_bandwidth_above_the_gap_fit_cap_bridges_gaps() {
        let p = Params {
            smoothing_m: 12.0,
            ..Params::default()
        };
        // Two solid pieces 34 m apart: a gap wider than twice the bandwidth.
        let pieces = [
            piece(0, 0.0, 26.0, MarkingClass::SolidLine),
            piece(1, 60.0, 78.0, MarkingClass::SolidLine),
        ];
        let lanes = grow(&pieces, &traj(), &p);
        assert_eq!(lanes.lines.len(), 1, "{:?}", lanes.lines);
        let line = &lanes.lines[0].line;
        assert!((y_at(line, 45.0) - 3.5).abs() < 0.01, "{line:?}");
    }
}
