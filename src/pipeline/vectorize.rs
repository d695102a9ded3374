//! Stage 6: vectorisation — marking outlines, lane lines, ids.
//!
//! # Interface
//! - `outlines(&PointCloud, &[Candidate], &Params) -> Vec<Piece>`: one [`Piece`] per
//!   candidate: a [`Marking`] in ABSOLUTE coordinates (origin added; `id` still empty) and,
//!   for pieces along the road, the absolute centreline (also for `unknown` pieces that
//!   passed the line test no wider than a painted line, for lane growth to join as neutral
//!   pieces). Per chunk (the candidates already
//!   carry their trajectory frame).
//! - `assemble(Vec<Piece>, &Trajectory(absolute), &Params) -> (Vec<Marking>, Vec<LaneLine>)`:
//!   lane-line growth over all pieces (run it once per drive, so lane lines are continuous
//!   across tiles and chunks), class corrections from the lane context, then stable ids
//!   `m1, m2, …` and `l1, l2, …` in driving order (mileage, then offset from the left).
//! - `run(...)` = `outlines` + `assemble` for a single chunk.
//!
//! # Algorithm
//! Outlines (see `outline`): rectangles from the robust principal-axis rectangle for bars
//! (dashes, stop lines, crosswalk and guideline stripes); the centreline buffered by half the
//! painted width for solid pieces and curved dashes (sagitta > `curved_min_sagitta_m`);
//! alpha shapes for irregular marks (arrows, diamonds, unknown; a diamond worn open gets the
//! convex hull of its alpha shape; an arrow whose outline holds no arrowhead, no circle of
//! `ARROW_MIN_INRADIUS_M`, is a thin stroke and dropped). Heading: long axis, pointing
//! along the driving direction (stop lines: pointing to the right of it), degrees clockwise
//! from north. Lane lines: see `lanes` (improved line-segment self-growth of Yao 2021).
//!
//! `assemble`, in order: crosswalk stripes put on their crossing's design (`crosswalks`:
//! common width and edges, worn fragments absorbed, missing stripes filled); stop lines
//! that are not clearly paint (median contrast below `stop_line_min_contrast`) made
//! `unknown`; "stop lines" along the road at the offset of a line piece they continue made
//! line pieces (a far line's sparse pieces read as bars); stop lines joined with the marks
//! on their centre line (`stoplines`); "stop lines" across the road that a lane line runs
//! on through made `unknown` and dropped at the end (no paint: expansion joints, seams;
//! checked again after the join); lane-line growth with crosswalks and stop lines as
//! barriers; bars across the road wholly beyond the outermost lane line on their side (a
//! side street's centre line, dashes, crossing stripes) made `unknown`; marks named arrows
//! on a lane line's course (arrows are painted mid-lane) given the line's class; lane lines
//! of line fragments alone (pieces flagged [`Piece::fragment`], too small for markings: a
//! far lane's dashes seen as one scan row each) where they fall on the drive's dash design
//! (`fragment_lines`), other fragments dropped; line pieces whose width the points do not
//! resolve widened to their lane line's width and drawn along its course; gaps of solid
//! lane lines bridged (short ones always, long ones between longer pieces, and up to
//! `lane_lines.max_unseen_gap_m` where the scanner saw no bare asphalt on the gap's
//! course); dashes put on their line's design (`dashes`); solid lane lines that end where
//! the scanner stopped seeing their course run on to the stop line or crossing ahead
//! (`extend_to_bars`: cars queued beside the survey vehicle at a junction hide the lines'
//! last metres); `unknown` markings that are not clearly paint (median contrast over the
//! asphalt below `unknown_min_contrast`) dropped, and guideline stripes with no other
//! within 3 m (hatching comes in groups; a lone stripe is a streak); ids in driving order.
//!
//! # Parameters
//! See [`Params`] (and `lanes::Params` under `lane_lines`).
//!
//! # Reference
//! Yao et al. 2021 §2.3 (self-growth, alpha shapes); Pan et al. 2019 §2.5 (vectorisation).
//!
//! # Complexity
//! O(n log n) for the alpha shapes of n points; see `lanes` for the growth.

use super::classify::{Candidate, Shape};
use super::crosswalks;
use super::dashes;
use super::geom;
use super::lanes::{self, LanePiece};
use super::observed::{Gap, Lookup};
use super::outline;
use super::pavement::check_range;
use super::refline::RefLine;
use super::stoplines;
use super::types::{LaneLine, LaneLineClass, Marking, MarkingClass, PointCloud, Trajectory};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Parameters of this stage (JSON object `vectorize` in the job parameters).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Params {
    /// Line pieces bending more than this from their chord get a curved outline (m).
    /// Default 0.03.
    pub curved_min_sagitta_m: f64,
    /// Douglas–Peucker tolerance for curved and alpha-shape outlines (m). Default 0.01.
    pub outline_simplify_m: f64,
    /// Bar-like classes (lines, stripes, stop lines) wider than this (m) are outlined by
    /// their alpha shape, not their rectangle: no painted bar is that wide, so the cluster
    /// holds more than one mark. Default 0.8.
    pub max_bar_width_m: f64,
    /// Gaps (m) up to this long between consecutive solid pieces of a solid lane line are
    /// bridged by an inferred solid piece (confidence halved, no points); 0 turns it off.
    /// Default 8: a car or van in the next lane hides 4–8 m of a far line, and worn paint
    /// fades out over as much; a solid line's designed breaks (junction mouths, the start
    /// of a dashed stretch) are longer, or change the lane line's class.
    pub bridge_solid_gap_m: f64,
    /// Longer gaps, up to this (m), are bridged too when both solid pieces beside the gap
    /// are at least as long as it: a line painted solid on both sides of a gap shorter than
    /// either side was worn or hidden there, not broken (a real break, at a junction or
    /// where the line turns dashed, has short or no solid pieces on one side); and between
    /// any two far-range pieces whose width the points do not resolve (sparse scan rows
    /// break such a line into short pieces). 0 turns it off. Default 12.
    pub bridge_long_gap_m: f64,
    /// Dashes of a regular dashed lane line seen only in part (worn, shadowed, sparse far
    /// scan lines) get the painted extent of the line's design: its dash length, period and
    /// width, estimated from its complete dashes (see `dashes`). Default true.
    pub regularize_dashes: bool,
    /// With `regularize_dashes`: at most this many consecutive missing dashes of a regular
    /// run are added (confidence halved, no points); 0 adds none. Default 1.
    pub fill_missing_dashes: u32,
    /// Line pieces whose width the points do not resolve (fewer than about two points
    /// across: sparse far-range scan lines) get the width of their lane line's resolved
    /// pieces, or measured width + one point spacing (at most 0.1 m more) when their lane
    /// line has none (see [`widen_undersampled`]), and are drawn along their lane line's
    /// course (see [`recentre_undersampled`]). Default true.
    pub widen_undersampled: bool,
    /// An `unknown` marking whose points are not clearly paint — the median of their
    /// intensity over the asphalt background below this — is dropped (see
    /// [`faint`]). Default 1.5 (the pixel threshold's floor is 1.25); 0 keeps every
    /// `unknown` marking.
    pub unknown_min_contrast: f64,
    /// A stop line whose points are not clearly paint — the median of their intensity over
    /// the asphalt background below this — becomes `unknown` (see [`faint`]): a
    /// stop line is painted thick and bright, worn ones included, while the bright edge of a
    /// resurfaced strip or a joint across the road is barely above the asphalt. Default 1.6
    /// (between `unknown_min_contrast` and the faintest worn stop line, about 1.8); 0 keeps
    /// every stop line.
    pub stop_line_min_contrast: f64,
    /// The stripes of a zebra crossing (≥ 3 crosswalk stripes side by side) get the
    /// crossing's design: the common stripe width and the two edges their ends line up on;
    /// worn fragments lying on a stripe's position are absorbed into it (see `crosswalks`).
    /// Default true.
    pub regularize_crosswalks: bool,
    /// With `regularize_crosswalks`: at most this many consecutive missing stripes of a
    /// regular crossing are added (confidence halved, no points); 0 adds none. Default 1.
    pub fill_missing_stripes: u32,
    /// Marks lying on a stop line's centre line beyond its ends (worn pieces, a stop line
    /// cut by a lane line's end) are joined into it, across gaps up to 1.5 m (see
    /// `stoplines`). Default true.
    pub join_stop_lines: bool,
    /// A dash that belongs to no lane line becomes `unknown`: a dashed line is a row of
    /// dashes, and a lone bar along the road with the size of a dash is as often a piece of
    /// something else (a fragment of a solid line or an arrow, a sealant streak) as a dash
    /// whose neighbours were not seen. Default true.
    pub isolated_dashes_unknown: bool,
    /// Lane-line growth.
    pub lane_lines: lanes::Params,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            curved_min_sagitta_m: 0.03,
            outline_simplify_m: 0.01,
            max_bar_width_m: 0.8,
            bridge_solid_gap_m: 8.0,
            bridge_long_gap_m: 12.0,
            regularize_dashes: true,
            fill_missing_dashes: 1,
            widen_undersampled: true,
            unknown_min_contrast: 1.5,
            stop_line_min_contrast: 1.6,
            regularize_crosswalks: true,
            fill_missing_stripes: 1,
            join_stop_lines: true,
            isolated_dashes_unknown: true,
            lane_lines: lanes::Params::default(),
        }
    }
}

impl Params {
    /// Check every field; the message names the offending parameter.
    pub fn validate(&self) -> Result<(), String> {
        check_range("curved_min_sagitta_m", self.curved_min_sagitta_m, 0.0, 1.0)?;
        check_range("outline_simplify_m", self.outline_simplify_m, 0.0, 0.5)?;
        check_range("max_bar_width_m", self.max_bar_width_m, 0.1, 20.0)?;
        check_range("bridge_solid_gap_m", self.bridge_solid_gap_m, 0.0, 50.0)?;
        check_range("bridge_long_gap_m", self.bridge_long_gap_m, 0.0, 50.0)?;
        check_range("fill_missing_dashes", self.fill_missing_dashes as f64, 0.0, 10.0)?;
        check_range("unknown_min_contrast", self.unknown_min_contrast, 0.0, 100.0)?;
        check_range("stop_line_min_contrast", self.stop_line_min_contrast, 0.0, 100.0)?;
        check_range(
            "fill_missing_stripes",
            self.fill_missing_stripes as f64,
            0.0,
            10.0,
        )?;
        self.lane_lines.validate()
    }
}

/// A vectorised marking before ids are assigned (absolute coordinates).
#[derive(Clone, Debug, PartialEq)]
pub struct Piece {
    pub marking: Marking,
    /// Centreline of pieces along the road (dashes, solid pieces), driving order.
    pub centerline: Option<Vec<[f64; 2]>>,
    /// `Some(point spacing)` (m) when the painted width of this line piece is not resolved
    /// by its points: fewer than about two points across it (far-range scan lines cross a
    /// 0.15 m line with one return), so the measured width under-reads the paint. See
    /// [`widen_undersampled`].
    pub undersampled: Option<f64>,
    /// A line fragment too small to stand as a marking (a far line's dash seen as a few
    /// returns of one scan row): it only counts where it joins a lane line, and is dropped
    /// otherwise (see [`assemble`]).
    pub fragment: bool,
    /// Known to be no painted marking (a bar across lanes whose lines run on through it, see
    /// [`stop_lines_crossed_by_lines`]): it stays, as `unknown`, while the lane lines grow
    /// (as the `unknown` it was before it was known), and is dropped with the fragments at
    /// the end of [`assemble`].
    pub not_paint: bool,
    /// Median contrast of its points (intensity over the asphalt background,
    /// [`PointCloud::contrast`]) when known; `None` for inferred pieces (bridges, filled
    /// dashes and stripes) and input thresholded upstream.
    pub contrast: Option<f64>,
}

/// Heading in degrees clockwise from north of direction `d` (x east, y north), in [0, 360).
pub fn heading_deg(d: [f64; 2]) -> f64 {
    let h = d[0].atan2(d[1]).to_degrees();
    if h < 0.0 {
        h + 360.0
    } else if h >= 360.0 {
        h - 360.0
    } else {
        h
    }
}

/// Outline every candidate (see the module docs).
pub fn outlines(cloud: &PointCloud, candidates: &[Candidate], params: &Params) -> Vec<Piece> {
    let o = cloud.origin;
    let abs = |p: [f64; 2]| [p[0] + o[0], p[1] + o[1]];
    let points_of =
        |c: &Candidate| -> Vec<[f64; 2]> { c.indices.iter().map(|&i| [cloud.x[i], cloud.y[i]]).collect() };
    candidates
        .par_iter()
        .filter_map(|c| {
            let s = &c.shape;
            let drive = s.driving_direction;
            let along = if s.axis[0] * drive[0] + s.axis[1] * drive[1] < 0.0 {
                [-s.axis[0], -s.axis[1]]
            } else {
                s.axis
            };
            // Fewer than about two points across the line: the width is not resolved.
            let undersampled = c
                .line
                .as_ref()
                .filter(|l| {
                    matches!(c.class, MarkingClass::SolidLine | MarkingClass::DashedLine)
                        && l.width_m < UNRESOLVED_POINTS_ACROSS * s.spacing_m
                })
                .map(|_| s.spacing_m);
            let (ring, length, width, heading, centerline) = match c.class {
                MarkingClass::SolidLine | MarkingClass::DashedLine if c.line.is_some() => {
                    let l = c.line.as_ref().expect("checked");
                    let (a, b) = (l.centerline[0], l.centerline[l.centerline.len() - 1]);
                    let chord = [b[0] - a[0], b[1] - a[1]];
                    let cl: Vec<[f64; 2]> = l.centerline.iter().map(|&p| abs(p)).collect();
                    if c.class == MarkingClass::SolidLine || l.sagitta_m > params.curved_min_sagitta_m {
                        let simple = geom::simplify(&l.centerline, params.outline_simplify_m / 2.0);
                        let ring = outline::buffered_line_simple(&simple, l.paint_width_m / 2.0);
                        (ring, l.length_m, l.paint_width_m, heading_deg(chord), Some(cl))
                    } else {
                        // A densely scanned dash is as wide as its line geometry's painted
                        // width (twice the interquartile range across it, like solid and
                        // curved pieces): a crack-sealant streak or a glint crossing the dash
                        // widens the rectangle's trimmed extent, not the IQR. A sparse one
                        // (a few points per scan row across it) keeps the extent: there the
                        // IQR of a handful of discrete offsets reads it too narrow.
                        let dense = c.indices.len() as f64 >= DASH_IQR_MIN_DENSITY * s.length_m * s.width_m;
                        let mut rect = s.clone();
                        if dense {
                            rect.width_m = l.paint_width_m;
                        }
                        (
                            rect.corners().to_vec(),
                            s.length_m,
                            rect.width_m,
                            heading_deg(along),
                            Some(cl),
                        )
                    }
                }
                // A "bar" wider than any painted bar is a merged cluster (a gore area, a
                // line touching stripes): its rectangle would cover bare asphalt, so it is
                // outlined like an irregular mark below.
                MarkingClass::StopLine
                | MarkingClass::Crosswalk
                | MarkingClass::Guideline
                | MarkingClass::DashedLine
                | MarkingClass::SolidLine
                    if s.width_m > params.max_bar_width_m =>
                {
                    let pts = points_of(c);
                    (
                        irregular_ring(&pts, s, params),
                        s.length_m,
                        s.width_m,
                        heading_deg(along),
                        None,
                    )
                }
                MarkingClass::StopLine | MarkingClass::Crosswalk => {
                    // A stop line heads to the right of the driving direction.
                    let right = [drive[1], -drive[0]];
                    let d = if c.class == MarkingClass::Crosswalk {
                        along
                    } else if s.axis[0] * right[0] + s.axis[1] * right[1] < 0.0 {
                        [-s.axis[0], -s.axis[1]]
                    } else {
                        s.axis
                    };
                    let r = row_rect(cloud, &c.indices, s);
                    (r.corners().to_vec(), r.length_m, r.width_m, heading_deg(d), None)
                }
                MarkingClass::Guideline | MarkingClass::DashedLine | MarkingClass::SolidLine => (
                    s.corners().to_vec(),
                    s.length_m,
                    s.width_m,
                    heading_deg(along),
                    None,
                ),
                MarkingClass::Diamond => {
                    // A diamond is a rhombus painted as an outline (GB 5768, MUTCD): the
                    // marking is the whole rhombus, not the band of paint around its hole
                    // (which the alpha shape of a worn one follows, a U or a C). Where the
                    // alpha shape is that open band, the convex hull of it closes it; an
                    // intact diamond's alpha shape is already the rhombus (its hull would
                    // only add the mitred corners), and a hull holding over
                    // [`DIAMOND_MAX_HULL_RATIO`] times the paint is no rim of a diamond.
                    let pts = points_of(c);
                    let alpha = irregular_ring(&pts, s, params);
                    let hull = outline::convex_hull(&alpha);
                    let (a, h) = (outline::area(&alpha), outline::area(&hull));
                    let open_band = a < DIAMOND_OPEN_RATIO * h && h <= DIAMOND_MAX_HULL_RATIO * a;
                    let ring = if open_band && hull.len() >= 3 { hull } else { alpha };
                    (ring, s.length_m, s.width_m, heading_deg(along), None)
                }
                _ => {
                    let pts = points_of(c);
                    // An `unknown` piece that passed the line test as narrow as a painted
                    // line (a far line's dash seen in part, shorter than a dash) keeps its
                    // centreline: lane growth may join it (see `assemble`).
                    let centerline = c
                        .line
                        .as_ref()
                        .filter(|l| {
                            c.class == MarkingClass::Unknown && l.paint_width_m <= LINE_FRAGMENT_MAX_WIDTH_M
                        })
                        .map(|l| l.centerline.iter().map(|&p| abs(p)).collect());
                    (
                        irregular_ring(&pts, s, params),
                        s.length_m,
                        s.width_m,
                        heading_deg(along),
                        centerline,
                    )
                }
            };
            // A self-intersecting ring (a buffered centreline folding on a tight bend, an
            // alpha shape pinched at a vertex) is no valid polygon: the convex hull of its
            // vertices stands in.
            let mut ring = ring;
            ring.dedup();
            if ring.len() > 1 && ring[0] == ring[ring.len() - 1] {
                ring.pop();
            }
            if !outline::is_simple(&ring) {
                ring = outline::convex_hull(&ring);
            }
            // A degenerate outline (a cluster collapsed to a line or a point) is no painted
            // object: it would be an invalid GeoJSON polygon, so it is dropped here.
            let mut distinct = ring.clone();
            distinct.dedup();
            if distinct.len() < 3 || outline::area(&ring) < MIN_OUTLINE_AREA_M2 {
                return None;
            }
            if c.class.is_arrow() && outline::inscribed_radius(&ring) < ARROW_MIN_INRADIUS_M {
                return None;
            }
            Some(Piece {
                marking: Marking {
                    id: String::new(),
                    class: c.class,
                    outline: ring.into_iter().map(abs).collect(),
                    confidence: c.confidence.clamp(0.0, 1.0),
                    length_m: length,
                    width_m: width,
                    heading_deg: heading,
                    point_count: c.indices.len(),
                },
                undersampled: undersampled.filter(|_| centerline.is_some()),
                centerline,
                fragment: false,
                not_paint: false,
                contrast: cloud
                    .contrast
                    .as_ref()
                    .filter(|_| !c.indices.is_empty())
                    .map(|v| {
                        let mut m: Vec<f64> = c.indices.iter().map(|&i| v[i] as f64).collect();
                        geom::median(&mut m)
                    }),
            })
        })
        .collect()
}

/// The rectangle of a stop line or crosswalk stripe with its extents read as sampled in
/// scan rows ([`geom::row_extent`]): a stop line, and a stripe of a crossing over a side
/// street, lie along the scan rows, so their width is sampled by a few rows 5-10 cm apart
/// and the trimmed extent of [`Shape`] stops at the outer rows (on the simulated urban
/// drives such stripes came out 2-5 cm narrow). Same axis as `s`; extents that are not
/// row-sampled come out as in `s`. The classification keeps `s`.
fn row_rect(cloud: &PointCloud, indices: &[usize], s: &Shape) -> Shape {
    if indices.len() < 8 {
        return s.clone();
    }
    let frame = geom::Pca {
        center: s.center,
        axis: s.axis,
        var: [0.0, 0.0],
    };
    let (mut us, mut vs): (Vec<f64>, Vec<f64>) = indices
        .iter()
        .map(|&i| {
            let q = frame.to_frame([cloud.x[i], cloud.y[i]]);
            (q[0], q[1])
        })
        .unzip();
    us.sort_unstable_by(f64::total_cmp);
    vs.sort_unstable_by(f64::total_cmp);
    let (u, v) = (geom::row_extent(&us), geom::row_extent(&vs));
    let mut r = s.clone();
    r.center = frame.from_frame([(u.0 + u.1) / 2.0, (v.0 + v.1) / 2.0]);
    r.length_m = u.1 - u.0;
    r.width_m = v.1 - v.0;
    r
}

/// Widest painted line (m) an `unknown` line fragment may be for lane growth: lane lines
/// are 0.10–0.30 m wide (GB 5768, MUTCD wide lines).
const LINE_FRAGMENT_MAX_WIDTH_M: f64 = 0.3;

/// A line piece narrower than this many point spacings is not resolved across.
const UNRESOLVED_POINTS_ACROSS: f64 = 2.0;

/// Points per m² of its rectangle from which a straight dash's outline takes the painted
/// width of its line geometry (2 × IQR) instead of the rectangle's trimmed extent: about
/// one point per 5 cm × 5 cm, three or more across a 0.15 m dash on every scan row. Far
/// dashes of the simulated drives hold 100–150 per m², near ones 1000–3000.
const DASH_IQR_MIN_DENSITY: f64 = 400.0;

/// At most this much (m) is added to an unresolved width when no lane-line reference exists
/// (as in `classify`'s judgement of sparse lines: scattered noise is not made wide).
const MAX_UNRESOLVED_PAD_M: f64 = 0.1;

/// Widen the line pieces whose painted width their points do not resolve (see
/// [`Piece::undersampled`]) to the width of their lane line: the length-weighted median
/// width of the line's resolved solid and dashed pieces (a lane line is painted with one
/// width), or, on a lane line without resolved pieces or on none, to the measured width +
/// one point spacing (a return stands for a patch of about one spacing, half of it beyond
/// the outermost return on each side), at most [`MAX_UNRESOLVED_PAD_M`] more. Pieces are
/// never narrowed. Rectangles widen about their long axis, other outlines are re-buffered
/// from the centreline.
fn widen_undersampled(pieces: &mut [Piece], lines: &[lanes::LaneResult], simplify_m: f64) {
    let mut reference: Vec<Option<f64>> = vec![None; pieces.len()];
    for l in lines {
        let mut ws: Vec<(f64, f64)> = l
            .pieces
            .iter()
            .map(|&k| &pieces[k])
            .filter(|p| {
                p.undersampled.is_none()
                    && matches!(
                        p.marking.class,
                        MarkingClass::SolidLine | MarkingClass::DashedLine
                    )
                    && p.marking.point_count > 0
            })
            .map(|p| (p.marking.width_m, p.marking.length_m.max(0.0)))
            .collect();
        let total: f64 = ws.iter().map(|w| w.1).sum();
        if total < MIN_REFERENCE_LENGTH_M {
            continue;
        }
        let median = geom::weighted_median(&mut ws);
        for &k in &l.pieces {
            reference[k] = Some(median);
        }
    }
    for (k, p) in pieces.iter_mut().enumerate() {
        let Some(spacing) = p.undersampled else {
            continue;
        };
        let w = p.marking.width_m;
        let target = reference[k].unwrap_or(w + spacing.min(MAX_UNRESOLVED_PAD_M));
        if target > w {
            widen(p, target, simplify_m);
        }
    }
}

/// Line pieces whose width the points do not resolve ([`Piece::undersampled`]: far range,
/// fewer than about two returns across) are drawn along their lane line's course, over the
/// stretch of it they span, at their (widened) width. Their own centreline comes from a
/// few returns per scan row, each some centimetres off the paint's axis (measured on the
/// simulated scenes beyond 12 m: 2.3–4.0 cm median error against 1.7–2.1 cm for the lane
/// line, which pools every piece of the line); near pieces are resolved and keep their
/// own. A piece further than [`RECENTRE_MAX_OFFSET_M`] from the course anywhere is not on
/// it (a branch, a piece the growth joined across) and is left alone.
fn recentre_undersampled(pieces: &mut [Piece], lines: &[lanes::LaneResult]) {
    for l in lines.iter().filter(|l| l.line.len() >= 2) {
        for &k in &l.pieces {
            let p = &mut pieces[k];
            let line_piece = matches!(
                p.marking.class,
                MarkingClass::SolidLine | MarkingClass::DashedLine
            );
            let (Some(cl), true, true) = (p.centerline.as_ref(), line_piece, p.undersampled.is_some()) else {
                continue;
            };
            let (lo, hi, off) = station_span(&l.line, cl);
            if off > RECENTRE_MAX_OFFSET_M || hi - lo <= 0.1 {
                continue;
            }
            let line = sub_line(&l.line, lo, hi);
            let ring = outline::buffered_line_simple(&line, p.marking.width_m / 2.0);
            if line.len() >= 2 && ring.len() >= 3 && outline::is_simple(&ring) {
                p.marking.outline = ring;
                p.centerline = Some(line);
            }
        }
    }
}

/// How far (m) an undersampled piece may lie from its lane line's course to be redrawn on it.
const RECENTRE_MAX_OFFSET_M: f64 = 0.15;

/// Whether `p` is a `class` marking whose points are not clearly paint: their median
/// contrast (intensity over the asphalt background) below `min_contrast`. Pieces without a
/// contrast (inferred, or input thresholded upstream) are never faint.
/// - `unknown`: a shape that no rule, network or lane context could name must at least be
///   as bright as paint to be reported (dropped below [`Params::unknown_min_contrast`]): on
///   the simulated drives, `unknown` markings under 1.5 were 212 sealant streaks, polished
///   patches and wheel-track glints against 29 pieces of paint; between 1.5 and 2, 53
///   against 68.
/// - stop lines below [`Params::stop_line_min_contrast`] become `unknown` before lane-line
///   growth, so they stop no lane line as a barrier (and are dropped when fainter still):
///   every true stop line of the simulated drives, worn ones included, measured ≥ 1.83;
///   resurfaced-strip edges and joints across the road 1.26–1.57.
fn faint(p: &Piece, class: MarkingClass, min_contrast: f64) -> bool {
    p.marking.class == class && p.contrast.is_some_and(|c| c < min_contrast)
}

/// Resolved pieces of a lane line must cover this much (m) to give it a reference width.
const MIN_REFERENCE_LENGTH_M: f64 = 2.0;

/// Set a line piece's painted width to `width`: a rectangle moves its long sides outward
/// (about its axis), any other outline is its centreline buffered anew.
fn widen(p: &mut Piece, width: f64, simplify_m: f64) {
    let ring = &p.marking.outline;
    let d = |a: [f64; 2], b: [f64; 2]| (b[0] - a[0]).hypot(b[1] - a[1]);
    let new_ring = if ring.len() == 4 {
        // Corners c0 c1 c2 c3: the shorter of edges c0-c1 and c1-c2 runs across.
        let (e01, e12) = (d(ring[0], ring[1]), d(ring[1], ring[2]));
        let (across_from, across_len) = if e01 <= e12 { (0, e01) } else { (1, e12) };
        let (a, b) = (ring[across_from], ring[across_from + 1]);
        if across_len <= 0.0 {
            return;
        }
        let n = [(b[0] - a[0]) / across_len, (b[1] - a[1]) / across_len];
        let e = (width - across_len) / 2.0;
        // Corners at the start of an across edge move back along n, at its end forward.
        let mut out = ring.clone();
        for (i, q) in out.iter_mut().enumerate() {
            // With across edges (0,1) and (2,3): 0 and 3 are on one long side, 1 and 2 on the
            // other; with across edges (1,2) and (3,0): 1 and 0 on one, 2 and 3 on the other.
            let forward = if across_from == 0 {
                i == 1 || i == 2
            } else {
                i == 2 || i == 3
            };
            let sgn = if forward { e } else { -e };
            *q = [q[0] + sgn * n[0], q[1] + sgn * n[1]];
        }
        out
    } else if let Some(cl) = &p.centerline {
        let simple = geom::simplify(cl, simplify_m / 2.0);
        outline::buffered_line_simple(&simple, width / 2.0)
    } else {
        return;
    };
    if new_ring.len() >= 3 && outline::is_simple(&new_ring) {
        p.marking.outline = new_ring;
        p.marking.width_m = width;
    }
}

/// Alpha-shape outline of an irregular mark, simplified; the rectangle when degenerate.
fn irregular_ring(pts: &[[f64; 2]], s: &super::classify::Shape, params: &Params) -> Vec<[f64; 2]> {
    let mut ring = outline::irregular(pts, s.spacing_m);
    if ring.len() >= 4 {
        let mut closed = ring.clone();
        closed.push(ring[0]);
        let mut simple = geom::simplify(&closed, params.outline_simplify_m);
        simple.pop();
        if simple.len() >= 3 {
            ring = simple;
        }
    }
    if ring.len() < 3 {
        ring = s.corners().to_vec();
    }
    ring
}

/// A solid piece filling the gap between solid pieces `a` and `b` of one lane line, along
/// the lane line's polyline, when the gap is longer than a pixel-scale joint (0.1 m) and at
/// most `max_gap` (m). Its confidence is half the weaker neighbour's, its point count 0
/// (no paint was seen there).
fn bridge(a: &Piece, b: &Piece, lane: &[[f64; 2]], max_gap: f64) -> Option<Piece> {
    let (ca, cb) = (a.centerline.as_ref()?, b.centerline.as_ref()?);
    let d = |p: [f64; 2], q: [f64; 2]| (p[0] - q[0]).hypot(p[1] - q[1]);
    // Closest pair of ends (centrelines may run either way).
    let ends = |c: &Vec<[f64; 2]>| [c[0], c[c.len() - 1]];
    let (mut pa, mut pb, mut gap) = ([0.0; 2], [0.0; 2], f64::INFINITY);
    for p in ends(ca) {
        for q in ends(cb) {
            if d(p, q) < gap {
                (pa, pb, gap) = (p, q, d(p, q));
            }
        }
    }
    if !(gap > 0.1 && gap <= max_gap) || lane.len() < 2 {
        return None;
    }
    // The lane-line vertices between the two ends (by station along the lane line).
    let (sa, sb) = (station_on(lane, pa), station_on(lane, pb));
    let (lo, hi) = (sa.min(sb), sa.max(sb));
    let mut line = vec![if sa <= sb { pa } else { pb }];
    let mut s0 = 0.0;
    for (i, v) in lane.iter().enumerate() {
        if i > 0 {
            s0 += d(lane[i - 1], *v);
        }
        if s0 > lo + 0.01 && s0 < hi - 0.01 {
            line.push(*v);
        }
    }
    line.push(if sa <= sb { pb } else { pa });
    let width = 0.5 * (a.marking.width_m + b.marking.width_m);
    unseen_solid(line, width, 0.5 * a.marking.confidence.min(b.marking.confidence))
}

/// A solid piece where no paint was seen (point count 0): the centreline `line` (driving
/// order) buffered by half `width`. `None` when the line is degenerate.
fn unseen_solid(line: Vec<[f64; 2]>, width: f64, confidence: f64) -> Option<Piece> {
    let ring = outline::buffered_line_simple(&line, width / 2.0);
    if ring.len() < 3 {
        return None;
    }
    let chord = [
        line[line.len() - 1][0] - line[0][0],
        line[line.len() - 1][1] - line[0][1],
    ];
    Some(Piece {
        marking: Marking {
            id: String::new(),
            class: MarkingClass::SolidLine,
            outline: ring,
            confidence,
            length_m: geom::polyline_length(&line),
            width_m: width,
            heading_deg: heading_deg(chord),
            point_count: 0,
        },
        centerline: Some(line),
        undersampled: None,
        fragment: false,
        not_paint: false,
        contrast: None,
    })
}

/// The gaps of lane line `l` that none of its pieces covers, as (piece ending before the
/// gap, piece starting after it), in driving order. A piece's extent is the station span of
/// its centreline (outline when it has none) on the lane line; pieces running beside one
/// another (a short piece alongside a long one, a split cluster) overlap in station, and
/// taking the line's pieces pairwise in order would "bridge" along paint already there.
fn uncovered_gaps(l: &lanes::LaneResult, pieces: &[Piece]) -> Vec<(usize, usize)> {
    let mut spans: Vec<(f64, f64, usize)> = l
        .pieces
        .iter()
        .map(|&k| {
            let p = &pieces[k];
            let (lo, hi, _) = station_span(&l.line, p.centerline.as_deref().unwrap_or(&p.marking.outline));
            (lo, hi, k)
        })
        .filter(|s| s.0.is_finite())
        .collect();
    spans.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.2.cmp(&b.2)));
    let mut gaps = Vec::new();
    let mut cover: Option<(f64, usize)> = None;
    for (lo, hi, k) in spans {
        match cover {
            Some((end, ka)) if lo > end => {
                gaps.push((ka, k));
                cover = Some((hi, k));
            }
            Some((end, _)) if hi <= end => {}
            _ => cover = Some((hi, k)),
        }
    }
    gaps
}

/// The longest gap bridged between solid pieces `la` and `lb` m long: any gap up to
/// `bridge_solid_gap_m`, and one up to `bridge_long_gap_m` no longer than either piece.
fn bridge_limit(la: f64, lb: f64, params: &Params) -> f64 {
    params
        .bridge_solid_gap_m
        .max(params.bridge_long_gap_m.min(la.min(lb)))
}

/// The longest gap bridged between solid pieces `a` and `b` of one solid lane line:
/// [`bridge_limit`] of their lengths, or `bridge_long_gap_m` whatever their lengths when
/// both are undersampled (far range, fewer than about two points across): there the scan
/// rows drift on and off a 0.15 m line and break it into short pieces, so short pieces
/// say nothing about a real break.
fn gap_limit(a: &Piece, b: &Piece, params: &Params) -> f64 {
    if a.undersampled.is_some() && b.undersampled.is_some() {
        params.bridge_solid_gap_m.max(params.bridge_long_gap_m)
    } else {
        bridge_limit(a.marking.length_m, b.marking.length_m, params)
    }
}

/// Station (distance along `lane` from its first vertex) of the point of `lane` nearest `p`.
fn station_on(lane: &[[f64; 2]], p: [f64; 2]) -> f64 {
    locate_on(lane, p).1
}

/// Distance (m) from `p` to the polyline `lane` and the station of the nearest point.
fn locate_on(lane: &[[f64; 2]], p: [f64; 2]) -> (f64, f64) {
    let d = |p: [f64; 2], q: [f64; 2]| (p[0] - q[0]).hypot(p[1] - q[1]);
    let mut best = (f64::INFINITY, 0.0);
    let mut s0 = 0.0;
    for seg in lane.windows(2) {
        let (u, v) = (seg[0], seg[1]);
        let len = d(u, v);
        let t = if len > 0.0 {
            (((p[0] - u[0]) * (v[0] - u[0]) + (p[1] - u[1]) * (v[1] - u[1])) / (len * len)).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let q = [u[0] + t * (v[0] - u[0]), u[1] + t * (v[1] - u[1])];
        if d(p, q) < best.0 {
            best = (d(p, q), s0 + t * len);
        }
        s0 += len;
    }
    best
}

/// The stretch of polyline `lane` that the points `pts` span (smallest and largest station
/// of their nearest points) and the largest distance of a point from it; `(inf, -inf, 0)`
/// for no points.
fn station_span(lane: &[[f64; 2]], pts: &[[f64; 2]]) -> (f64, f64, f64) {
    pts.iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY, 0.0f64), |(lo, hi, off), &q| {
            let (d, s) = locate_on(lane, q);
            (lo.min(s), hi.max(s), off.max(d))
        })
}

/// Whether the piece's centreline (ends and middle) lies within `tol` of a lane line, within
/// the line's extent.
fn on_a_lane_line(lines: &[lanes::LaneResult], cl: &[[f64; 2]], tol: f64) -> bool {
    let probes = [cl[0], cl[cl.len() / 2], cl[cl.len() - 1]];
    lines.iter().any(|l| {
        probes.iter().all(|&q| {
            let (d, st) = locate_on(&l.line, q);
            d <= tol && st > 0.0 && st < l.length_m
        })
    })
}

/// The part of `lane` between stations `a < b` (clamped to the line): the point at `a`, the
/// vertices in between, the point at `b`.
fn sub_line(lane: &[[f64; 2]], a: f64, b: f64) -> Vec<[f64; 2]> {
    let d = |p: [f64; 2], q: [f64; 2]| (p[0] - q[0]).hypot(p[1] - q[1]);
    let at = |seg: &[[f64; 2]], t: f64| {
        [
            seg[0][0] + t * (seg[1][0] - seg[0][0]),
            seg[0][1] + t * (seg[1][1] - seg[0][1]),
        ]
    };
    let mut out = Vec::new();
    let mut s0 = 0.0;
    for seg in lane.windows(2) {
        let len = d(seg[0], seg[1]);
        let s1 = s0 + len;
        if len > 0.0 && s1 > a && s0 < b {
            if out.is_empty() {
                out.push(at(seg, ((a - s0) / len).clamp(0.0, 1.0)));
            }
            if s1 < b {
                out.push(seg[1]);
            } else {
                out.push(at(seg, ((b - s0) / len).clamp(0.0, 1.0)));
            }
        }
        s0 = s1;
    }
    out
}

/// The dashes of a lane line as spans along it.
fn dash_spans(l: &lanes::LaneResult, pieces: &[Piece]) -> Vec<dashes::Span> {
    l.pieces
        .iter()
        .filter(|&&k| pieces[k].marking.class == MarkingClass::DashedLine)
        .filter_map(|&k| {
            let (a, b, _) = station_span(&l.line, pieces[k].centerline.as_ref()?);
            Some(dashes::Span {
                key: k,
                a,
                b,
                width: pieces[k].marking.width_m,
                confidence: pieces[k].marking.confidence,
            })
        })
        .collect()
}

/// Lane lines of line fragments alone (written here: the lane-line growth extrapolates each
/// piece's direction, which a few returns of one scan row do not fix). The fragments and
/// the dashes on no lane line and not within `FRAGMENT_EXCLUSION_M` of one are chained in
/// the trajectory frame (see [`fragment_chains`]: at least `FRAGMENT_LINE_MIN` pieces). A
/// chain over at least `FRAGMENT_LINE_MIN_LENGTH_M` becomes a lane line: its pieces' offsets
/// smoothed over `FRAGMENT_LINE_SMOOTHING_M` (where a painted lane line runs beside it, the
/// guide: that line's course plus the smoothed difference from it), refitted without
/// pieces off it by more than `FRAGMENT_TOLERANCE_M`, and dropped if it drifts across the
/// road by more than `FRAGMENT_PARALLEL_M` relative to the lane line beside it (whose
/// drift is its least-squares slope over the overlap: a bridged gap may wiggle). It is
/// kept, dashed, only where its pieces fall on one phase of
/// a lane-line dash design of the drive's other dashed lines (dashes at most
/// `FRAGMENT_DESIGN_MAX_WIDTH_M` wide, the design of the most lane-line length tried
/// first; see [`dashes::plan_on_designs`]), at least `FRAGMENT_ON_DASH_SHARE` of them
/// are placed on painted dashes and the line spans at least 5 periods. A far lane's dashes
/// seen as one scan row each make such a line; scattered bright returns (a verge, sealant)
/// and a far solid line's fragments fall on no phase and make none.
fn fragment_lines(
    lanes: &mut lanes::Lanes,
    pieces: &mut [Piece],
    first: usize,
    designs: &[dashes::Design],
    refl: &RefLine,
    simplify_m: f64,
) {
    let mut joined = vec![false; pieces.len()];
    for l in &lanes.lines {
        for &k in &l.pieces {
            joined[k] = true;
        }
    }
    // (s, o) of the middle of each free piece: on no lane line, and not beside one (the
    // fragments of a far solid line whose pieces made a lane line are that line's).
    let mut free: Vec<(f64, f64, usize)> = (0..pieces.len())
        .filter(|&k| !joined[k] && (k >= first || pieces[k].marking.class == MarkingClass::DashedLine))
        .filter_map(|k| {
            let cl = pieces[k].centerline.as_ref().filter(|c| c.len() >= 2)?;
            if on_a_lane_line(&lanes.lines, cl, FRAGMENT_EXCLUSION_M) {
                return None;
            }
            let so = refl.locate(cl[cl.len() / 2]);
            Some((so[0], so[1], k))
        })
        .collect();
    if free.len() < FRAGMENT_LINE_MIN {
        return;
    }
    // A far lane repeats the road's lane-line design, not a wide transition line's.
    let designs: Vec<dashes::Design> = designs
        .iter()
        .copied()
        .filter(|d| d.width <= FRAGMENT_DESIGN_MAX_WIDTH_M)
        .collect();
    if designs.is_empty() {
        return;
    }
    // The lane lines' vertices in the trajectory frame: (mileages, offsets) by mileage.
    let ref_so: Vec<(Vec<f64>, Vec<f64>)> = lanes
        .lines
        .iter()
        .map(|l| {
            let mut so: Vec<[f64; 2]> = l.line.iter().map(|&q| refl.locate(q)).collect();
            so.sort_by(|a, b| a[0].total_cmp(&b[0]));
            so.into_iter().map(|q| (q[0], q[1])).unzip()
        })
        .collect();
    // The lane lines' painted intervals along the trajectory (their pieces' extents).
    let ref_paint: Vec<Vec<(f64, f64)>> = lanes
        .lines
        .iter()
        .map(|l| {
            let ivs = l.pieces.iter().filter_map(|&k| {
                let cl = pieces[k].centerline.as_ref().filter(|c| c.len() >= 2)?;
                let (u, v) = (refl.locate(cl[0])[0], refl.locate(cl[cl.len() - 1])[0]);
                Some((u.min(v), u.max(v)))
            });
            lanes::merge_intervals(ivs.collect(), 0.0)
        })
        .collect();
    free.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.2.cmp(&b.2)));
    for chain in fragment_chains(&free) {
        let (s0, s1) = (free[chain[0]].0, free[chain[chain.len() - 1]].0);
        if s1 - s0 < FRAGMENT_LINE_MIN_LENGTH_M {
            continue;
        }
        // The line: the members' centreline vertices smoothed over FRAGMENT_LINE_SMOOTHING_M,
        // refitted without the members whose median residual exceeds FRAGMENT_TOLERANCE_M
        // (a chain can pick up a stray fragment); a vertex every metre.
        let mut keys: Vec<usize> = chain.iter().map(|&i| free[i].2).collect();
        let samples = |keys: &[usize]| -> (Vec<f64>, Vec<f64>, Vec<usize>) {
            let mut v: Vec<(f64, f64, usize)> = keys
                .iter()
                .flat_map(|&k| {
                    let cl = pieces[k].centerline.as_deref().unwrap_or(&[]);
                    cl.iter().map(move |&q| {
                        let so = refl.locate(q);
                        (so[0], so[1], k)
                    })
                })
                .collect();
            v.sort_by(|a, b| a.0.total_cmp(&b.0));
            (
                v.iter().map(|t| t.0).collect(),
                v.iter().map(|t| t.1).collect(),
                v.iter().map(|t| t.2).collect(),
            )
        };
        let (xs, ys, owner) = samples(&keys);
        let ws = vec![1.0; xs.len()];
        let fit = |xs: &[f64], ys: &[f64], ws: &[f64], st: f64| {
            geom::local_linear(xs, ys, ws, st, FRAGMENT_LINE_SMOOTHING_M, 3.0).map_or(ys[0], |f| f.0)
        };
        // The guide: of the lane lines spanning at least 90 % of the chain within
        // `GUIDE_MAX_DISTANCE_M`, the most painted along it (at least
        // FRAGMENT_GUIDE_MIN_PAINT), then the nearest. The line is the guide's course plus
        // the smoothed difference from it (see `lanes::Guide`: the vehicle's sway, which the
        // 25 m smoothing of the fragments' own offsets flattens), and the fragments off it
        // are judged by their difference from it.
        let (a, b) = (xs[0] - 3.0, xs[xs.len() - 1] + 3.0);
        let mid = 0.5 * (xs[0] + xs[xs.len() - 1]);
        let o_first = fit(&xs, &ys, &ws, mid);
        let guide = ref_so
            .iter()
            .zip(&ref_paint)
            .filter(|((ms, _), _)| match (ms.first(), ms.last()) {
                (Some(&u), Some(&v)) => v.min(b) - u.max(a) >= 0.9 * (b - a),
                _ => false,
            })
            .map(|((ms, os), pt)| {
                (
                    ms,
                    os,
                    (geom::interp_clamped(ms, os, mid) - o_first).abs(),
                    lanes::painted_share(pt, a, b),
                )
            })
            .filter(|g| g.2 <= lanes::GUIDE_MAX_DISTANCE_M && g.3 >= FRAGMENT_GUIDE_MIN_PAINT)
            .max_by(|x, y| x.3.total_cmp(&y.3).then(y.2.total_cmp(&x.2)));
        let g_at = |st: f64| guide.map_or(0.0, |(ms, os, _, _)| geom::interp_clamped(ms, os, st));
        let rel_of =
            |xs: &[f64], ys: &[f64]| -> Vec<f64> { xs.iter().zip(ys).map(|(&x, &y)| y - g_at(x)).collect() };
        let rel = rel_of(&xs, &ys);
        keys.retain(|&k| {
            let mut r: Vec<f64> = (0..xs.len())
                .filter(|&i| owner[i] == k)
                .map(|i| (rel[i] - fit(&xs, &rel, &ws, xs[i])).abs())
                .collect();
            !r.is_empty() && geom::median(&mut r) <= FRAGMENT_TOLERANCE_M
        });
        if keys.len() < FRAGMENT_LINE_MIN {
            continue;
        }
        let (xs, ys, _) = samples(&keys);
        let ws = vec![1.0; xs.len()];
        // Lane lines run side by side: along the overlap with the nearest lane line beside
        // it (overlapping at least half of it), its offset may change by at most
        // FRAGMENT_PARALLEL_M more than that line's (a chain that slants across its
        // neighbour's course picked up the wrong fragments).
        let (c0, c1) = (xs[0], xs[xs.len() - 1]);
        let o_mid = fit(&xs, &ys, &ws, 0.5 * (c0 + c1));
        let beside = ref_so
            .iter()
            .filter_map(|(ms, os)| {
                let (lo, hi) = (ms.first()?.max(c0), ms.last()?.min(c1));
                (hi - lo >= 0.5 * (c1 - c0))
                    .then(|| (lo, hi, geom::interp_clamped(ms, os, 0.5 * (lo + hi)), ms, os))
            })
            .min_by(|x, y| (x.2 - o_mid).abs().total_cmp(&(y.2 - o_mid).abs()));
        if let Some((lo, hi, _, ms, os)) = beside {
            // The neighbour's drift from its least-squares slope over the overlap, not from
            // its two end values: where it bridges a gap it may wiggle by a decimetre or two.
            let drift = geom::slope_in(ms, os, lo, hi).map_or_else(
                || geom::interp_clamped(ms, os, hi) - geom::interp_clamped(ms, os, lo),
                |k| k * (hi - lo),
            );
            let own = fit(&xs, &ys, &ws, hi) - fit(&xs, &ys, &ws, lo);
            if (own - drift).abs() > FRAGMENT_PARALLEL_M {
                continue;
            }
        }
        let (a, b) = (xs[0] - 3.0, xs[xs.len() - 1] + 3.0);
        let rel = rel_of(&xs, &ys);
        let nv = (b - a).ceil().max(1.0) as usize;
        let line: Vec<[f64; 2]> = (0..=nv)
            .map(|v| {
                let st = a + (b - a) * v as f64 / nv as f64;
                refl.point(st, g_at(st) + fit(&xs, &rel, &ws, st))
            })
            .collect();
        let mut l = lanes::LaneResult {
            class: LaneLineClass::DashedLine,
            length_m: geom::polyline_length(&line),
            start: refl.locate(line[0]),
            line,
            confidence: FRAGMENT_CONFIDENCE_LINE,
            pieces: keys,
        };
        for &k in &l.pieces {
            pieces[k].marking.class = MarkingClass::DashedLine;
        }
        if fragment_plan(&dash_spans(&l, pieces), &designs, l.length_m).is_none() {
            continue;
        }
        l.line = geom::simplify(&l.line, simplify_m);
        lanes
            .classes
            .extend(l.pieces.iter().map(|&k| (k, MarkingClass::DashedLine)));
        lanes.lines.push(l);
    }
    lanes.classes.sort_unstable_by_key(|c| c.0);
}

/// The chains of free pieces `(mileage, offset, key)` sorted by mileage, best first: the
/// path through the most pieces, each within `FRAGMENT_LINE_MAX_GAP_M` ahead of the one
/// before and off the path's course (its offsets' running mean, the newest weighing a
/// third) by at most `FRAGMENT_CHAIN_TOLERANCE_M` plus 0.5 % of the gap. It is found as a
/// longest path in their directed acyclic graph; each step costs its share of the tolerance
/// and of the longest gap, halved, so the straighter and shorter of two equally long paths
/// wins. Its pieces removed, the next, while a path holds `FRAGMENT_LINE_MIN` pieces.
/// A far line's fragments scatter a few decimetres about its axis, so a greedy choice of
/// each piece's nearest next one (in offset and mileage) often skips the next along the
/// line and splits it into chains too short to count (the far dashed line of the s2
/// highway drive: five chains, none of eight pieces). Cost: O(w) per piece and path, for
/// the w pieces within the longest gap behind it (a drive's free pieces are a few hundred).
fn fragment_chains(free: &[(f64, f64, usize)]) -> Vec<Vec<usize>> {
    let n = free.len();
    let tol = |gap: f64| FRAGMENT_CHAIN_TOLERANCE_M + 0.005 * gap;
    let mut taken = vec![false; n];
    let mut chains = Vec::new();
    loop {
        // score[j]: the best path ending at j; from[j] its previous piece.
        let mut score = vec![f64::NEG_INFINITY; n];
        let mut from: Vec<Option<usize>> = vec![None; n];
        // The path's course: its offsets' running mean (the last piece weighs a third).
        let mut course = vec![0.0; n];
        for j in (0..n).filter(|&j| !taken[j]) {
            score[j] = 1.0;
            let (sj, oj, _) = free[j];
            course[j] = oj;
            for i in (0..j).rev().filter(|&i| !taken[i]) {
                let gap = sj - free[i].0;
                if gap > FRAGMENT_LINE_MAX_GAP_M {
                    break;
                }
                let d = (oj - course[i]).abs();
                if gap <= 0.3 || d > tol(gap) {
                    continue;
                }
                let v = score[i] + 1.0 - 0.5 * (d / tol(gap) + gap / FRAGMENT_LINE_MAX_GAP_M);
                if v > score[j] {
                    score[j] = v;
                    from[j] = Some(i);
                    course[j] = course[i] + (oj - course[i]) / 3.0;
                }
            }
        }
        let Some(end) = (0..n)
            .filter(|&j| !taken[j])
            .max_by(|&a, &b| score[a].total_cmp(&score[b]).then(b.cmp(&a)))
        else {
            break;
        };
        let mut chain = vec![end];
        while let Some(i) = from[chain[chain.len() - 1]] {
            chain.push(i);
        }
        if chain.len() < FRAGMENT_LINE_MIN {
            break;
        }
        chain.reverse();
        for &i in &chain {
            taken[i] = true;
        }
        chains.push(chain);
    }
    chains
}

/// The plan of a line of fragments: on the first of `designs` (the most lane-line length
/// first) its pieces fit with at least `FRAGMENT_ON_DASH_SHARE` of them placed on painted
/// dashes, over a line at least 5 periods long; no dashes are filled (where none was seen,
/// a line of fragments does not know its course to a dash's width). `None` when no design
/// fits.
fn fragment_plan(spans: &[dashes::Span], designs: &[dashes::Design], length_m: f64) -> Option<dashes::Plan> {
    designs
        .iter()
        .map(|d| dashes::plan_on_designs(spans, std::slice::from_ref(d), 0))
        .find(|p| {
            p.period > 0.0
                && (p.extend.len() + p.absorb.len()) as f64 >= FRAGMENT_ON_DASH_SHARE * spans.len() as f64
                && length_m >= 5.0 * p.period
        })
}

/// The dash designs of the drive's dashed lane lines (see [`dashes::plan`]), alike ones
/// (period within 5 %, dash within 10 %) merged, the design of the most lane-line length
/// first.
fn drive_designs(lines: &[lanes::LaneResult], pieces: &[Piece]) -> Vec<dashes::Design> {
    let mut weighted: Vec<(dashes::Design, f64)> = Vec::new();
    for l in lines
        .iter()
        .filter(|l| l.class == LaneLineClass::DashedLine && l.line.len() >= 2)
    {
        let Some(d) = dashes::plan(&dash_spans(l, pieces), 0).design() else {
            continue;
        };
        let alike = |w: &dashes::Design| {
            (w.period - d.period).abs() <= 0.05 * w.period
                && (w.dash_length - d.dash_length).abs() <= 0.1 * w.dash_length
        };
        match weighted.iter_mut().find(|(w, _)| alike(w)) {
            Some(w) => w.1 += l.length_m,
            None => weighted.push((d, l.length_m)),
        }
    }
    weighted.sort_by(|a, b| b.1.total_cmp(&a.1));
    weighted.into_iter().map(|(d, _)| d).collect()
}

/// How close (m) a fragment's samples must stay to its line's fit (median residual).
const FRAGMENT_TOLERANCE_M: f64 = 0.15;
/// Pieces this close (m) to a lane line are that line's, never part of a line of fragments.
const FRAGMENT_EXCLUSION_M: f64 = 0.3;
/// How much more (m) a line of fragments may drift across the road than the lane line
/// beside it, along their overlap.
const FRAGMENT_PARALLEL_M: f64 = 0.5;
/// Bandwidth (m) of a line of fragments' offset fit: a far fragment is a few returns of
/// one scan row, centimetres off the paint's axis, so the line averages several.
const FRAGMENT_LINE_SMOOTHING_M: f64 = 25.0;
/// Least share of a line of fragments' extent a lane line guiding it must be painted over
/// (MUTCD dashes: 10 ft every 40 ft).
const FRAGMENT_GUIDE_MIN_PAINT: f64 = 0.25;
/// Confidence of a lane line of fragments.
const FRAGMENT_CONFIDENCE_LINE: f64 = 0.4;
/// Longest gap (m) between consecutive pieces of a line of fragments: three 15 m periods of
/// a highway dashed line with two dashes unseen (highway s1001: 44 m between the fragments
/// of the far line's 60 m start and the rest, which at 40 m lost that start).
const FRAGMENT_LINE_MAX_GAP_M: f64 = 50.0;
/// Widest dashes (m) of a design a line of fragments may take.
const FRAGMENT_DESIGN_MAX_WIDTH_M: f64 = 0.3;
/// Offset difference (m) allowed between consecutive pieces of a line of fragments, plus
/// 0.5 % of their gap: a far fragment's middle is a few returns of one row, centimetres to
/// a decimetre off the paint's axis.
const FRAGMENT_CHAIN_TOLERANCE_M: f64 = 0.3;

/// Share of a line of fragments' pieces its dash design must place on painted dashes:
/// the pieces of a far dashed line nearly all fall on its dashes (86-100 % on the highway
/// drives), a row of strays picked up along a verge on about as many as chance (70 %).
const FRAGMENT_ON_DASH_SHARE: f64 = 0.8;

/// Fragments a line of fragments alone needs, and its least length (m).
const FRAGMENT_LINE_MIN: usize = 8;
const FRAGMENT_LINE_MIN_LENGTH_M: f64 = 40.0;

/// Dashes of the dashed lane lines put on their line's design (see [`super::dashes`]):
/// short dashes that fit the pattern get their painted extent, and up to
/// `fill_missing_dashes` missing dashes in a row are added (confidence halved, no points).
/// A line with too few complete dashes for a design of its own is tried on the designs of
/// the drive's other dashed lines. Returns the added pieces and the keys of the pieces
/// that are parts of a painted dash another piece stands for (to remove).
fn regularise_dashes(
    pieces: &mut [Piece],
    lines: &[lanes::LaneResult],
    designs: &[dashes::Design],
    params: &Params,
) -> (Vec<Piece>, Vec<usize>) {
    let fill_max = params.fill_missing_dashes as usize;
    let dashed: Vec<&lanes::LaneResult> = lines
        .iter()
        .filter(|l| l.class == LaneLineClass::DashedLine && l.line.len() >= 2)
        .collect();
    let all_spans: Vec<Vec<dashes::Span>> = dashed.iter().map(|l| dash_spans(l, pieces)).collect();
    let own: Vec<dashes::Plan> = all_spans.iter().map(|sp| dashes::plan(sp, fill_max)).collect();
    let (mut added, mut absorbed) = (Vec::new(), Vec::new());
    for ((l, spans), own) in dashed.into_iter().zip(&all_spans).zip(own) {
        let total = geom::polyline_length(&l.line);
        // A line of fragments is put on the design it was accepted on (`fragment_lines`).
        let of_fragments = l.pieces.iter().any(|&k| pieces[k].fragment);
        let plan = if own.period > 0.0 {
            own
        } else if of_fragments {
            fragment_plan(spans, designs, l.length_m).unwrap_or_default()
        } else {
            dashes::plan_with_designs(spans, designs, fill_max)
        };
        // (centreline, outline) of a dash from station a to b.
        type Drawn = (Vec<[f64; 2]>, Vec<[f64; 2]>);
        let make = |a: f64, b: f64, width: f64| -> Option<Drawn> {
            // Only where the lane line runs: a dash reaching past its ends is not placed.
            if a < -0.05 || b > total + 0.05 {
                return None;
            }
            let line = sub_line(&l.line, a.max(0.0), b.min(total));
            let ring = outline::buffered_line_simple(&line, width / 2.0);
            (line.len() >= 2 && ring.len() >= 3).then_some((line, ring))
        };
        for &(k, a, b, width) in &plan.extend {
            let Some((line, ring)) = make(a, b, width) else {
                continue;
            };
            pieces[k].fragment = false;
            let m = &mut pieces[k].marking;
            m.outline = ring;
            m.length_m = geom::polyline_length(&line);
            m.width_m = width;
            pieces[k].centerline = Some(line);
        }
        absorbed.extend_from_slice(&plan.absorb);
        for &(a, b, width, confidence) in &plan.fill {
            let Some((line, ring)) = make(a, b, width) else {
                continue;
            };
            let chord = [
                line[line.len() - 1][0] - line[0][0],
                line[line.len() - 1][1] - line[0][1],
            ];
            added.push(Piece {
                marking: Marking {
                    id: String::new(),
                    class: MarkingClass::DashedLine,
                    outline: ring,
                    confidence,
                    length_m: geom::polyline_length(&line),
                    width_m: width,
                    heading_deg: heading_deg(chord),
                    point_count: 0,
                },
                centerline: Some(line),
                undersampled: None,
                fragment: false,
                not_paint: false,
                contrast: None,
            });
        }
    }
    (added, absorbed)
}

/// Crosswalk stripes put on their crossing's design (see [`super::crosswalks`]); absorbed
/// fragments are removed, missing stripes added. Runs before the lane-line growth, so
/// fragments of a stripe never join a lane line.
fn regularise_crosswalks(mut pieces: Vec<Piece>, refl: &RefLine, fill_max: usize) -> Vec<Piece> {
    let plan = crosswalks::plan(&marks_of(&pieces), fill_max);
    // Heading of a stripe: its axis pointing along the driving direction.
    let heading_of = |st: &crosswalks::Stripe| {
        let n = st.ring.len() as f64;
        let c = st
            .ring
            .iter()
            .fold([0.0, 0.0], |a, q| [a[0] + q[0] / n, a[1] + q[1] / n]);
        let dir = refl.direction(refl.locate(c)[0]);
        let a = st.axis;
        heading_deg(if a[0] * dir[0] + a[1] * dir[1] < 0.0 {
            [-a[0], -a[1]]
        } else {
            a
        })
    };
    let mut removed = vec![false; pieces.len()];
    for (k, st, absorbed) in &plan.reshape {
        let extra: usize = absorbed.iter().map(|&j| pieces[j].marking.point_count).sum();
        let p = &mut pieces[*k];
        p.marking.class = MarkingClass::Crosswalk;
        p.marking.outline = st.ring.to_vec();
        p.marking.length_m = st.length_m;
        p.marking.width_m = st.width_m;
        p.marking.heading_deg = heading_of(st);
        p.marking.point_count += extra;
        p.centerline = None;
        p.undersampled = None;
        for &j in absorbed {
            removed[j] = true;
        }
    }
    for (st, confidence) in &plan.fill {
        pieces.push(Piece {
            marking: Marking {
                id: String::new(),
                class: MarkingClass::Crosswalk,
                outline: st.ring.to_vec(),
                confidence: *confidence,
                length_m: st.length_m,
                width_m: st.width_m,
                heading_deg: heading_of(st),
                point_count: 0,
            },
            centerline: None,
            undersampled: None,
            fragment: false,
            not_paint: false,
            contrast: None,
        });
    }
    without(pieces, removed)
}

/// The marks of [`crosswalks`] and [`stoplines`] plans.
fn marks_of(pieces: &[Piece]) -> Vec<crosswalks::Mark> {
    pieces
        .iter()
        .enumerate()
        .map(|(k, p)| crosswalks::Mark {
            key: k,
            class: p.marking.class,
            ring: p.marking.outline.clone(),
            confidence: p.marking.confidence,
            point_count: p.marking.point_count,
        })
        .collect()
}

/// Pieces without the removed ones.
fn without(pieces: Vec<Piece>, mut removed: Vec<bool>) -> Vec<Piece> {
    removed.resize(pieces.len(), false);
    pieces
        .into_iter()
        .zip(removed)
        .filter(|(_, r)| !r)
        .map(|(p, _)| p)
        .collect()
}

/// Stop lines joined with the marks on their centre line (see [`super::stoplines`]); the
/// joined marks are removed. Runs before the lane-line growth.
fn join_stop_lines(mut pieces: Vec<Piece>, refl: &RefLine) -> Vec<Piece> {
    let joins = stoplines::plan(&marks_of(&pieces));
    let mut removed = vec![false; pieces.len()];
    for (k, bar, joined) in &joins {
        let extra: usize = joined.iter().map(|&j| pieces[j].marking.point_count).sum();
        let n = bar.ring.len() as f64;
        let c = bar
            .ring
            .iter()
            .fold([0.0, 0.0], |a, q| [a[0] + q[0] / n, a[1] + q[1] / n]);
        let dir = refl.direction(refl.locate(c)[0]);
        // Stop lines point to the right of the driving direction (as in `outlines`).
        let right = [dir[1], -dir[0]];
        let a = bar.axis;
        let d = if a[0] * right[0] + a[1] * right[1] < 0.0 {
            [-a[0], -a[1]]
        } else {
            a
        };
        let p = &mut pieces[*k];
        p.marking.outline = bar.ring.to_vec();
        p.marking.length_m = bar.length_m;
        p.marking.width_m = bar.width_m;
        p.marking.heading_deg = heading_deg(d);
        p.marking.point_count += extra;
        for &j in joined {
            removed[j] = true;
        }
    }
    without(pieces, removed)
}

/// (s, o) samples of the solid and dashed pieces' centrelines, sorted by s, with the
/// pieces' indices.
fn line_samples(pieces: &[Piece], refl: &RefLine) -> Vec<(usize, Vec<[f64; 2]>)> {
    pieces
        .iter()
        .enumerate()
        .filter(|(_, p)| {
            matches!(
                p.marking.class,
                MarkingClass::SolidLine | MarkingClass::DashedLine
            )
        })
        .filter_map(|(k, p)| {
            let mut so: Vec<[f64; 2]> = p.centerline.as_ref()?.iter().map(|&v| refl.locate(v)).collect();
            so.sort_by(|a, b| a[0].total_cmp(&b[0]));
            (so.len() >= 2).then_some((k, so))
        })
        .collect()
}

/// The (s, o) box of a stop line that lies across the road (at least twice as long across
/// as along): what both stop-line context rules judge.
fn stop_line_across(p: &Piece, refl: &RefLine) -> Option<[f64; 4]> {
    if p.marking.class != MarkingClass::StopLine || p.marking.outline.len() < 4 {
        return None;
    }
    let b = refl.box_of(&p.marking.outline);
    (b[3] - b[2] >= 2.0 * (b[1] - b[0])).then_some(b)
}

/// Longest gap (m) on either side of a bar across the road between it and the pieces of a
/// line that runs on through it, for [`stop_lines_crossed_by_lines`]: a dash gap (GB 9 m,
/// MUTCD 30 ft) plus a metre.
const CROSSED_BAR_GAP_M: f64 = 10.0;
/// Largest offset difference (m) between the pieces before and after the bar.
const CROSSED_BAR_OFFSET_M: f64 = 0.2;
/// The line must cross the bar this far (m) inside its ends: a stop line ends at the
/// centre line or edge line that continues beside it.
const CROSSED_BAR_INSET_M: f64 = 0.3;

/// How far (m) a line piece must reach beyond a bar's side to run on past it.
const CROSSED_BAR_REACH_M: f64 = 0.3;
/// How far (m) beyond a bar's end the centre of a line running past that end may lie:
/// the bar's points stop at the line's edge (or were peeled off with it).
const CROSSED_BAR_END_OUT_M: f64 = 0.4;

/// A "stop line" across the road that a lane line runs on through is no stop line: lanes
/// end at a stop line, they do not continue through it. An expansion joint, a cable trench
/// or a bright seam across a ramp looks like a stop line and would otherwise cut the lane
/// lines it crosses (stop lines are barriers to lane-line growth). A line runs on through
/// a bar where a solid or dashed piece reaches at most [`CROSSED_BAR_GAP_M`] before it and
/// one (the same or another) at most as far after it, at the same offset (±
/// [`CROSSED_BAR_OFFSET_M`]) at the bar. Such a bar — across the road, crossed by a line
/// inside its ends by [`CROSSED_BAR_INSET_M`], or with lines running on past both of its
/// ends (a joint across one lane, between two lines that go on), with no crosswalk stripe
/// within that distance — becomes `unknown` and is flagged [`Piece::not_paint`]: no
/// painted marking runs across lanes whose lines go on through it (transverse markings end
/// at the lines), so it is not reported, as `unknown` or otherwise. On the 20 simulated
/// drives these were the expansion joints across the curved ramps (5–10 m long, 2 000–2 800
/// points each); reported as `unknown` they cost those drives .011–.015 of pixel F-score.
/// A stop line has a line running on past one end at most (the centre line to the
/// crossing; the lane lines end at it).
fn stop_lines_crossed_by_lines(pieces: &mut [Piece], refl: &RefLine) {
    // Each line piece's samples as (mileages, offsets).
    let lines: Vec<(Vec<f64>, Vec<f64>)> = line_samples(pieces, refl)
        .into_iter()
        .map(|(_, so)| so.iter().map(|q| (q[0], q[1])).unzip())
        .collect();
    let crossings: Vec<[f64; 4]> = pieces
        .iter()
        .filter(|p| p.marking.class == MarkingClass::Crosswalk)
        .map(|p| refl.box_of(&p.marking.outline))
        .collect();
    for p in pieces.iter_mut() {
        let Some([s0, s1, o0, o1]) = stop_line_across(p, refl) else {
            continue;
        };
        // A crosswalk next to it: a stop line where it belongs, and the stripes beyond it
        // (or their worn pieces read as dashes) are no line running on.
        let near_crossing = crossings.iter().any(|c| {
            c[0] <= s1 + CROSSED_BAR_GAP_M && c[1] >= s0 - CROSSED_BAR_GAP_M && c[2] <= o1 && c[3] >= o0
        });
        if near_crossing {
            continue;
        }
        // Whether a line runs on through the bar at an offset (at the bar) in [lo, hi].
        let runs_on = |lo: f64, hi: f64| {
            lines.iter().any(|(sa, oa)| {
                let before = sa[0] <= s0 - CROSSED_BAR_REACH_M && sa[sa.len() - 1] >= s0 - CROSSED_BAR_GAP_M;
                let at = geom::interp_clamped(sa, oa, s0);
                before
                    && (lo..=hi).contains(&at)
                    && lines.iter().any(|(sb, ob)| {
                        sb[sb.len() - 1] >= s1 + CROSSED_BAR_REACH_M
                            && sb[0] <= s1 + CROSSED_BAR_GAP_M
                            && (geom::interp_clamped(sb, ob, s1) - at).abs() <= CROSSED_BAR_OFFSET_M
                    })
            })
        };
        let crossed = runs_on(o0 + CROSSED_BAR_INSET_M, o1 - CROSSED_BAR_INSET_M)
            || (runs_on(o0 - CROSSED_BAR_END_OUT_M, o0 + CROSSED_BAR_INSET_M)
                && runs_on(o1 - CROSSED_BAR_INSET_M, o1 + CROSSED_BAR_END_OUT_M));
        if crossed {
            p.marking.class = MarkingClass::Unknown;
            p.not_paint = true;
        }
    }
}

/// Arrows are painted in the middle of their lane, half a lane from its lines: the arrows
/// found on the simulated drives lie 0.8-3.6 m (all but one under 1.9 m) from the nearest
/// lane line (centre of their outline). A mark "named an arrow" whose centre lies within
/// this distance (m) of a lane line is a piece of that line: a dash the learned classifier
/// read as a left arrow (its end frayed by a crossing scan row), a solid line's end with
/// the stub of the stop line it meets read as a straight arrow.
const ARROW_MIN_LANE_DISTANCE_M: f64 = 0.5;

/// Pieces named arrows on a lane line's course (within [`ARROW_MIN_LANE_DISTANCE_M`]) take
/// the line's class (see there). They do not join the line: the line was grown without
/// them, and a dash read as an arrow overlaps the dash that took its place in the line (an
/// isolated dash then becomes `unknown` with `isolated_dashes_unknown`).
fn arrows_on_lane_lines(pieces: &mut [Piece], lines: &[lanes::LaneResult]) {
    use geo::Centroid;
    for p in pieces.iter_mut().filter(|p| p.marking.class.is_arrow()) {
        let Some(c) = outline::to_polygon(&p.marking.outline).centroid() else {
            continue;
        };
        // A line without a segment is infinitely far (`locate_on`).
        let on = lines
            .iter()
            .find(|l| locate_on(&l.line, [c.x(), c.y()]).0 <= ARROW_MIN_LANE_DISTANCE_M);
        if let Some(l) = on {
            p.marking.class = l.class.marking_class();
        }
    }
}

/// How far along the road (m) the lane lines beside a bar across it are looked for, and how
/// far (m) beyond the outermost of them the bar must begin, for [`stop_lines_beyond_edges`].
const EDGE_WINDOW_M: f64 = 40.0;
const BEYOND_EDGE_M: f64 = 1.0;

/// A "stop line" across the road that lies wholly beyond the outermost lane line on its
/// side (within [`EDGE_WINDOW_M`] along the road, by more than [`BEYOND_EDGE_M`]) is no stop
/// line of this road: a stop line runs across the lanes the vehicle drives, between their
/// lines. Beyond the edge line, bars across the trajectory are the markings of a side street,
/// which runs across it: its centre line, dashes and crossing stripes. Such a bar becomes
/// `unknown`. Without lane lines beside it nothing is known of the edge and the bar stays.
fn stop_lines_beyond_edges(pieces: &mut [Piece], lines: &[lanes::LaneResult], refl: &RefLine) {
    let samples: Vec<[f64; 2]> = lines
        .iter()
        .flat_map(|l| l.line.iter().map(|&v| refl.locate(v)))
        .collect();
    for p in pieces.iter_mut() {
        let Some([s0, s1, o0, o1]) = stop_line_across(p, refl) else {
            continue;
        };
        // Offsets mirrored to the bar's side: its inner end and the outermost line there.
        let (side, inner) = match (o0 >= 0.0, o1 <= 0.0) {
            (true, _) => (1.0, o0),
            (_, true) => (-1.0, -o1),
            _ => continue,
        };
        let edge = samples
            .iter()
            .filter(|q| q[0] >= s0 - EDGE_WINDOW_M && q[0] <= s1 + EDGE_WINDOW_M)
            .map(|q| side * q[1])
            .fold(f64::NEG_INFINITY, f64::max);
        if edge.is_finite() && inner > edge + BEYOND_EDGE_M {
            p.marking.class = MarkingClass::Unknown;
        }
    }
}

/// Narrowest stop line (m): GB 5768 paints them 0.2–0.4 m wide, MUTCD 12–24 in, European
/// standards 0.25–0.5 m. A narrower "stop line" is a piece of a lane line (0.10–0.20 m): on
/// the 1 km highway drive (no stop line at all) the network named five 0.14–0.19 m far
/// edge-line fragments so, each a barrier that cut the edge line; every true stop line of
/// the 20 simulated drives, worn ones included, measures 0.26 m or more. It becomes
/// `unknown`, a neutral piece lane-line growth may join. Held to the joined bar's width
/// here, not in the rules' `classify::Params::stop_min_width_m` (0.15: a candidate's
/// width, which under-reads sparse and worn bars) nor on the network's verdict: checked
/// on the candidates there, it also lost two true stop lines (20 drives: stop lines
/// 28 → 26 TP, macro −.0010) and the 1 km drive's edge line was cut again (lane
/// completeness −.0074).
const STOP_LINE_MIN_WIDTH_M: f64 = 0.2;

/// Largest offset difference (m) between a bar along the road and the line piece it
/// continues, and the largest gap (m) between them, for [`lines_not_stop_lines`].
const ALONG_BAR_OFFSET_M: f64 = 0.2;
const ALONG_BAR_GAP_M: f64 = 15.0;

/// A "stop line" that runs along the road (within about 20° of it) and continues a line
/// piece at its offset (≤ [`ALONG_BAR_OFFSET_M`] across, ≤ [`ALONG_BAR_GAP_M`] along, either
/// side) is a piece of that lane line: at long range a sparse solid line's 4–6 m pieces read
/// as 0.3 m bars, which is what a side street's stop line looks like from the main road.
/// A real stop line across a side street is set back from the main road's edge line, so it
/// is not at that line's offset. Such bars become solid pieces with their axis as
/// centreline, so lane-line growth links across them instead of stopping at a barrier.
fn lines_not_stop_lines(pieces: &mut [Piece], refl: &RefLine) {
    let lines = line_samples(pieces, refl);
    // Mean offset of the samples within 3 m of one end.
    let end_offset = |so: &[[f64; 2]], at_end: bool| {
        let (lo, hi) = if at_end {
            (so[so.len() - 1][0] - 3.0, f64::INFINITY)
        } else {
            (f64::NEG_INFINITY, so[0][0] + 3.0)
        };
        let v: Vec<f64> = so
            .iter()
            .filter(|q| q[0] >= lo && q[0] <= hi)
            .map(|q| q[1])
            .collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    };
    let mut turned = Vec::new();
    for (k, p) in pieces.iter().enumerate() {
        if p.marking.class != MarkingClass::StopLine || p.marking.outline.len() < 4 {
            continue;
        }
        let [s0, s1, o0, o1] = refl.box_of(&p.marking.outline);
        // Along the road: its extent along is ≥ 3× its extent across (≲ 20°).
        if s1 - s0 < 3.0 * (o1 - o0) {
            continue;
        }
        let o = 0.5 * (o0 + o1);
        let continues = lines.iter().any(|(_, l)| {
            let (ls0, ls1) = (l[0][0], l[l.len() - 1][0]);
            let before = (-0.5..=ALONG_BAR_GAP_M).contains(&(s0 - ls1))
                && (end_offset(l, true) - o).abs() <= ALONG_BAR_OFFSET_M;
            let after = (-0.5..=ALONG_BAR_GAP_M).contains(&(ls0 - s1))
                && (end_offset(l, false) - o).abs() <= ALONG_BAR_OFFSET_M;
            before || after
        });
        if continues {
            turned.push(k);
        }
    }
    for k in turned {
        let p = &mut pieces[k];
        let r = &p.marking.outline;
        // Axis: the midpoints of the rectangle's two short sides, in driving order.
        let mid = |a: [f64; 2], b: [f64; 2]| [0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1])];
        let d = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).hypot(a[1] - b[1]);
        let (e0, e1) = if d(r[0], r[1]) < d(r[1], r[2]) {
            (mid(r[0], r[1]), mid(r[2], r[3]))
        } else {
            (mid(r[1], r[2]), mid(r[3], r[0]))
        };
        let axis = if refl.locate(e0)[0] <= refl.locate(e1)[0] {
            vec![e0, e1]
        } else {
            vec![e1, e0]
        };
        p.marking.class = MarkingClass::SolidLine;
        p.marking.heading_deg = heading_deg([axis[1][0] - axis[0][0], axis[1][1] - axis[0][1]]);
        p.centerline = Some(axis);
    }
}

/// A diamond's alpha shape covering less than this share of its convex hull is an open
/// band of paint (a worn rim), closed by the hull (see `outlines`).
const DIAMOND_OPEN_RATIO: f64 = 0.8;

/// Largest convex hull of a diamond's alpha shape, in multiples of the alpha shape's area,
/// taken as its outline: the rim of a rhombus 0.2 m wide holds about half its area when
/// intact and a fifth when half of it is worn away.
const DIAMOND_MAX_HULL_RATIO: f64 = 5.0;

/// Largest gap between the outlines of two guideline stripes of one hatched area (m): gore
/// and diversion hatching repeats every 1-3 m (the outlines 0.5-2.5 m apart).
const GUIDELINE_GROUP_M: f64 = 3.0;

/// Guideline stripes come in groups (the hatching of a gore or diversion area): the
/// indices of the stripes with no other within [`GUIDELINE_GROUP_M`], which are dropped.
/// Such a lone stripe is a bright streak on bare asphalt or a piece of something else
/// shaped like one (on the 20 simulated scenes and the 1 km drive, 22 of 30 false
/// guidelines were lone and 6 of 92 true ones).
fn lone_guidelines(pieces: &[Piece]) -> Vec<usize> {
    use geo::Distance;
    let stripes: Vec<(usize, geo::Polygon<f64>)> = pieces
        .iter()
        .enumerate()
        .filter(|(_, p)| p.marking.class == MarkingClass::Guideline && p.marking.outline.len() >= 3)
        .map(|(k, p)| (k, outline::to_polygon(&p.marking.outline)))
        .collect();
    stripes
        .iter()
        .filter(|(k, a)| {
            !stripes
                .iter()
                .any(|(j, b)| j != k && geo::Euclidean.distance(a, b) <= GUIDELINE_GROUP_M)
        })
        .map(|(k, _)| *k)
        .collect()
}

/// Smallest outline area kept (m²): far below any real marking (a 0.1 m x 0.01 m sliver).
const MIN_OUTLINE_AREA_M2: f64 = 1e-3;

/// An arrow's outline holds a circle at least this wide in radius (m), in its head: the
/// head of the smallest arrow found on the simulated drives (a worn 3.7 m MUTCD left
/// arrow) holds one of 0.14 m. An outline without one is a thin stroke the learned
/// classifier took for an arrow (the bend of a crack-sealant streak read as a right
/// arrow's branch: 0.07-0.10 m on three drives) and is dropped.
const ARROW_MIN_INRADIUS_M: f64 = 0.12;

/// Lane lines over all pieces, lane-context class corrections, stable ids.
///
/// `seen` (when the points were kept track of, see [`super::observed`]) tells where the
/// scanner saw bare asphalt: lane lines link, and solid ones are bridged, across longer gaps
/// it did not see.
pub fn assemble(
    pieces: Vec<Piece>,
    traj_abs: &Trajectory,
    params: &Params,
    seen: Option<&Lookup<'_>>,
) -> (Vec<Marking>, Vec<LaneLine>) {
    let refl = RefLine::new(traj_abs);
    // Line fragments only take part in the lane lines (module docs).
    let (fragments, pieces): (Vec<Piece>, Vec<Piece>) = pieces.into_iter().partition(|p| p.fragment);
    let pieces = if params.regularize_crosswalks {
        regularise_crosswalks(pieces, &refl, params.fill_missing_stripes as usize)
    } else {
        pieces
    };
    let mut pieces = pieces;
    for p in pieces.iter_mut() {
        if faint(p, MarkingClass::StopLine, params.stop_line_min_contrast) {
            p.marking.class = MarkingClass::Unknown;
        }
    }
    lines_not_stop_lines(&mut pieces, &refl);
    stop_lines_crossed_by_lines(&mut pieces, &refl);
    for p in pieces.iter_mut() {
        if p.marking.class == MarkingClass::StopLine && p.marking.width_m < STOP_LINE_MIN_WIDTH_M {
            p.marking.class = MarkingClass::Unknown;
        }
    }
    let mut pieces = if params.join_stop_lines {
        join_stop_lines(pieces, &refl)
    } else {
        pieces
    };
    // Again for the bars the join made: pieces of a joint across the road, each between
    // two lines, are one bar across lanes whose lines run on through it once joined (a
    // bridge joint across a ramp seen by scan rows along it, 15 m long).
    stop_lines_crossed_by_lines(&mut pieces, &refl);
    let lane_pieces: Vec<LanePiece> = pieces
        .iter()
        .enumerate()
        .filter_map(|(k, p)| {
            let cl = p.centerline.as_ref()?;
            // A short `unknown` line fragment is joined like the others (as a neutral
            // piece, see `lanes::LanePiece::class`): joined to a lane line it takes the
            // line's class, alone it stays `unknown`.
            Some(LanePiece {
                key: k,
                class: p.marking.class,
                centerline: cl.clone(),
                width_m: p.marking.width_m,
                confidence: p.marking.confidence,
            })
        })
        .collect();
    let mut barriers: Vec<Vec<[f64; 2]>> = pieces
        .iter()
        .filter(|p| matches!(p.marking.class, MarkingClass::StopLine | MarkingClass::Crosswalk))
        .map(|p| p.marking.outline.clone())
        .collect();
    barriers.extend(side_crossing_mouths(&pieces, &refl));
    let mut lanes = lanes::grow_with_barriers(&lane_pieces, traj_abs, &params.lane_lines, &barriers, seen);
    let first_fragment = pieces.len();
    pieces.extend(fragments);
    // The drive's dash designs, from the lane lines as grown (lines of fragments have none).
    let designs = drive_designs(&lanes.lines, &pieces);
    fragment_lines(
        &mut lanes,
        &mut pieces,
        first_fragment,
        &designs,
        &refl,
        params.lane_lines.simplify_tolerance_m,
    );
    for &(k, class) in &lanes.classes {
        pieces[k].marking.class = class;
    }
    stop_lines_beyond_edges(&mut pieces, &lanes.lines, &refl);
    arrows_on_lane_lines(&mut pieces, &lanes.lines);
    if params.isolated_dashes_unknown {
        let mut in_lane = vec![false; pieces.len()];
        for &(k, _) in &lanes.classes {
            in_lane[k] = true;
        }
        for (p, _) in pieces
            .iter_mut()
            .zip(in_lane)
            .filter(|(p, inl)| !inl && p.marking.class == MarkingClass::DashedLine)
        {
            p.marking.class = MarkingClass::Unknown;
        }
    }
    if params.widen_undersampled {
        widen_undersampled(&mut pieces, &lanes.lines, params.outline_simplify_m);
        recentre_undersampled(&mut pieces, &lanes.lines);
    }
    // Solid lane lines: short gaps between consecutive solid pieces (worn paint, a car
    // hiding the line) are bridged by a solid piece along the lane line.
    if params.bridge_solid_gap_m > 0.0 || params.bridge_long_gap_m > 0.0 {
        let mut bridges = Vec::new();
        for l in lanes.lines.iter().filter(|l| l.class == LaneLineClass::SolidLine) {
            for (ka, kb) in uncovered_gaps(l, &pieces) {
                let (a, b) = (&pieces[ka], &pieces[kb]);
                if a.marking.class != MarkingClass::SolidLine || b.marking.class != MarkingClass::SolidLine {
                    continue;
                }
                let max_gap = gap_limit(a, b, params);
                // Longer gaps the scanner did not see (its course holds no bare asphalt).
                let unseen = || {
                    let seen = seen?;
                    let br = bridge(a, b, &l.line, params.lane_lines.max_unseen_gap_m)?;
                    let course = br.centerline.as_deref()?;
                    (seen.gap(course, 0.05) == Gap::Unseen).then_some(br)
                };
                if let Some(bridge) = bridge(a, b, &l.line, max_gap).or_else(unseen) {
                    bridges.push(bridge);
                }
            }
        }
        pieces.extend(bridges);
    }
    let (added, absorbed) = if params.regularize_dashes {
        regularise_dashes(&mut pieces, &lanes.lines, &designs, params)
    } else {
        Default::default()
    };
    pieces.extend(added);
    if let Some(seen) = seen {
        let runs = extend_to_bars(
            &mut lanes.lines,
            &pieces,
            &refl,
            seen,
            params.lane_lines.max_gap_m,
        );
        pieces.extend(runs);
    }
    // After the dashes were put on each line's design (a line of fragments has its own).
    join_dashed_lines(&mut lanes.lines, &barriers, &refl);
    // A fragment not placed on a painted dash (`regularise_dashes` clears the flag of those
    // it places) is dropped: off the lane lines it is noise, on one it says where the line
    // runs, not where its paint is. So is a part of a painted dash another piece stands
    // for, a piece known to be no paint, and an `unknown` marking that is not clearly
    // paint. At the end (after the lane context had its say on classes), so keys stay put.
    let mut dropped: Vec<bool> = pieces
        .iter()
        .map(|p| p.fragment || p.not_paint || faint(p, MarkingClass::Unknown, params.unknown_min_contrast))
        .collect();
    for k in absorbed.into_iter().chain(lone_guidelines(&pieces)) {
        dropped[k] = true;
    }
    // Driving order: station of the outline's vertex mean on the absolute reference line.
    let mut order: Vec<(f64, f64, usize)> = pieces
        .iter()
        .enumerate()
        .filter(|&(k, _)| !dropped[k])
        .map(|(k, p)| {
            let n = p.marking.outline.len().max(1) as f64;
            let c = p
                .marking
                .outline
                .iter()
                .fold([0.0, 0.0], |a, q| [a[0] + q[0] / n, a[1] + q[1] / n]);
            let so = refl.locate(c);
            // Millimetre keys: ids do not flip on floating-point noise.
            ((so[0] * 1000.0).round(), (-so[1] * 1000.0).round(), k)
        })
        .collect();
    order.sort_by(|a, b| {
        a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)).then_with(|| {
            let (p, q) = (&pieces[a.2].marking.outline, &pieces[b.2].marking.outline);
            let (p0, q0) = (
                p.first().copied().unwrap_or([0.0; 2]),
                q.first().copied().unwrap_or([0.0; 2]),
            );
            p0[0].total_cmp(&q0[0]).then(p0[1].total_cmp(&q0[1]))
        })
    });
    let mut id_of = vec![String::new(); pieces.len()];
    for (rank, &(_, _, k)) in order.iter().enumerate() {
        id_of[k] = format!("m{}", rank + 1);
    }
    let lane_lines: Vec<LaneLine> = lanes
        .lines
        .into_iter()
        .enumerate()
        .map(|(i, l)| LaneLine {
            id: format!("l{}", i + 1),
            class: l.class,
            line: l.line,
            confidence: l.confidence,
            length_m: l.length_m,
            marking_ids: l
                .pieces
                .iter()
                .filter(|&&k| !dropped[k])
                .map(|&k| id_of[k].clone())
                .collect(),
        })
        .collect();
    let mut slots: Vec<Option<Piece>> = pieces.into_iter().map(Some).collect();
    let markings: Vec<Marking> = order
        .iter()
        .map(|&(_, _, k)| {
            let mut m = slots[k].take().expect("each piece once").marking;
            m.id = id_of[k].clone();
            m
        })
        .collect();
    (markings, lane_lines)
}

/// How far (m) toward the road a side street's crossing is widened into the barrier of
/// its mouth ([`side_crossing_mouths`]): crossings of a side street are set back from the
/// main road's edge line by a metre or two (1.3–1.4 m on the simulated junctions); a lane
/// line of the main road is a lane width (≥ 2.75 m) inside its edge line.
const SIDE_CROSSING_REACH_M: f64 = 2.5;
/// Least number of stripes of a side street's crossing, and the largest gap (m) along the
/// road between neighbouring stripes of one crossing.
const SIDE_CROSSING_MIN_STRIPES: usize = 3;
const SIDE_CROSSING_MAX_GAP_M: f64 = 1.5;

/// Longest gap (m) between two dashed lane lines [`join_dashed_lines`] joins (a dash gap,
/// GB 9 m, MUTCD 30 ft, plus a metre), their longest overlap (m), and the largest offset
/// difference (m) where they meet.
const JOIN_DASHED_MAX_GAP_M: f64 = 10.5;
const JOIN_DASHED_MAX_OVERLAP_M: f64 = 3.0;
const JOIN_DASHED_MAX_OFFSET_M: f64 = 0.15;

/// Dashed lane lines that continue one another are one line: one that starts within
/// [`JOIN_DASHED_MAX_GAP_M`] after another ends (or overlaps its end by at most
/// [`JOIN_DASHED_MAX_OVERLAP_M`]), at the same offset (within
/// [`JOIN_DASHED_MAX_OFFSET_M`] where they meet), with no barrier between them, is appended
/// to it. A far line grown partly from whole dashes and partly from fragments
/// ([`fragment_lines`]) came as several lines end to end (the 1 km drive's far dashed line
/// in four). The joined line keeps both lines' pieces and the length-weighted mean
/// confidence.
fn join_dashed_lines(lines: &mut Vec<lanes::LaneResult>, barriers: &[Vec<[f64; 2]>], refl: &RefLine) {
    let boxes = lanes::barrier_boxes(barriers, refl);
    // The dashed lines' vertices in the trajectory frame as (mileages, offsets).
    let mut so: Vec<Option<(Vec<f64>, Vec<f64>)>> = lines
        .iter()
        .map(|l| {
            (l.class == LaneLineClass::DashedLine && l.line.len() >= 2).then(|| {
                l.line
                    .iter()
                    .map(|&v| refl.locate(v))
                    .map(|q| (q[0], q[1]))
                    .unzip()
            })
        })
        .collect();
    let mut by_start: Vec<(f64, usize)> = so
        .iter()
        .enumerate()
        .filter_map(|(k, q)| Some((q.as_ref()?.0[0], k)))
        .collect();
    by_start.sort_by(|x, y| x.0.total_cmp(&y.0));
    let mut gone = vec![false; lines.len()];
    for &(_, a) in &by_start {
        // Line `a` takes on its best continuation for as long as it has one.
        while let Some((sa, oa)) = so[a].as_ref() {
            let end = [sa[sa.len() - 1], oa[oa.len() - 1]];
            let lo = by_start.partition_point(|x| x.0 < end[0] - JOIN_DASHED_MAX_OVERLAP_M);
            let hi = by_start.partition_point(|x| x.0 <= end[0] + JOIN_DASHED_MAX_GAP_M);
            let best = by_start[lo..hi]
                .iter()
                .filter(|&&(_, b)| b != a && !gone[b])
                .filter_map(|&(_, b)| {
                    let (sb, ob) = so[b].as_ref()?;
                    let start = [sb[0], ob[0]];
                    if sb[sb.len() - 1] <= end[0] || sa[0] >= start[0] {
                        return None;
                    }
                    // Offsets where they meet: each line's at the middle of the joint.
                    let at = 0.5 * (end[0] + start[0]);
                    let dev = (geom::interp_clamped(sa, oa, at) - geom::interp_clamped(sb, ob, at)).abs();
                    let (s0, s1) = (start[0].min(end[0]), start[0].max(end[0]));
                    let blocked = lanes::barrier_across(&boxes, s0, s1, 0.5 * (end[1] + start[1]));
                    (dev <= JOIN_DASHED_MAX_OFFSET_M && !blocked).then_some((b, dev))
                })
                .min_by(|x, y| x.1.total_cmp(&y.1));
            let Some((b, _)) = best else { break };
            let start_b = so[b].as_ref().map_or(f64::INFINITY, |q| q.0[0]);
            let kept = sa.partition_point(|&v| v < start_b);
            let (sb, ob) = so[b].take().expect("a candidate has vertices");
            let (mut sa, mut oa) = so[a].take().expect("line a has vertices");
            let lb = &lines[b];
            let (line_b, len_b, conf_b, pieces_b) =
                (lb.line.clone(), lb.length_m, lb.confidence, lb.pieces.clone());
            let la = &mut lines[a];
            la.line.truncate(kept);
            la.line.extend(line_b);
            let len_a = la.length_m;
            la.length_m = geom::polyline_length(&la.line);
            la.confidence = (la.confidence * len_a + conf_b * len_b) / (len_a + len_b).max(1e-9);
            la.pieces.extend(pieces_b);
            sa.truncate(kept);
            oa.truncate(kept);
            sa.extend(sb);
            oa.extend(ob);
            so[a] = Some((sa, oa));
            gone[b] = true;
        }
    }
    let mut gone = gone.into_iter();
    lines.retain(|_| !gone.next().unwrap_or(false));
}

/// The mouths of side streets, as barriers to lane-line growth (outlines): a crossing of a
/// side street is a row of crosswalk stripes that lie across the road (each at least twice
/// as long across as along it), all on one side of the trajectory, each within
/// [`SIDE_CROSSING_MAX_GAP_M`] along the road of the next; at least
/// [`SIDE_CROSSING_MIN_STRIPES`] of them. Its box in the trajectory frame, widened by
/// [`SIDE_CROSSING_REACH_M`] toward the road, is the mouth: the main road's edge line ends
/// there and starts again beyond the side street, so it is not joined across it, however
/// well its pieces on both sides align (on the simulated junctions the edge line ran 30 m
/// across the mouth, a metre from the ends of the crossing's stripes). The crossings of the
/// road itself lie along it and are barriers as they are.
fn side_crossing_mouths(pieces: &[Piece], refl: &RefLine) -> Vec<Vec<[f64; 2]>> {
    let across = crosswalk_boxes(pieces, refl, |b| b[3] - b[2] >= 2.0 * (b[1] - b[0]));
    let mut mouths = Vec::new();
    for side in [1.0, -1.0] {
        let on_side: Vec<[f64; 4]> = across
            .iter()
            .copied()
            .filter(|b| side * b[2] > 0.0 && side * b[3] > 0.0)
            .collect();
        for ([s0, s1, o0, o1], n) in stripe_rows(&on_side, SIDE_CROSSING_MAX_GAP_M) {
            if n < SIDE_CROSSING_MIN_STRIPES {
                continue;
            }
            // Widened toward the road.
            let (o0, o1) = if side > 0.0 {
                (o0 - SIDE_CROSSING_REACH_M, o1)
            } else {
                (o0, o1 + SIDE_CROSSING_REACH_M)
            };
            mouths.push(vec![
                refl.point(s0, o0),
                refl.point(s1, o0),
                refl.point(s1, o1),
                refl.point(s0, o1),
            ]);
        }
    }
    mouths
}

/// The (s, o) boxes of the crosswalk stripes whose box passes `keep`, ordered by s.
fn crosswalk_boxes(pieces: &[Piece], refl: &RefLine, keep: impl Fn(&[f64; 4]) -> bool) -> Vec<[f64; 4]> {
    let mut boxes: Vec<[f64; 4]> = pieces
        .iter()
        .filter(|p| p.marking.class == MarkingClass::Crosswalk && p.marking.outline.len() >= 3)
        .map(|p| refl.box_of(&p.marking.outline))
        .filter(|b| keep(b))
        .collect();
    boxes.sort_by(|a, b| a[0].total_cmp(&b[0]));
    boxes
}

/// Rows of stripe boxes ordered by s: each box joins the row before it when it starts at
/// most `max_gap` (m) after the row's end; each row's union box and number of stripes.
fn stripe_rows(boxes: &[[f64; 4]], max_gap: f64) -> Vec<([f64; 4], usize)> {
    let mut rows: Vec<([f64; 4], usize)> = Vec::new();
    for b in boxes {
        match rows.last_mut() {
            Some((r, n)) if b[0] <= r[1] + max_gap => {
                *r = [r[0], r[1].max(b[1]), r[2].min(b[2]), r[3].max(b[3])];
                *n += 1;
            }
            _ => rows.push((*b, 1)),
        }
    }
    rows
}

/// The bars across the road, in the trajectory frame [s0, s1, o0, o1]: stop lines lying
/// across it, and crossings (the union of the boxes of crosswalk stripes that overlap
/// along the road).
fn bars_across(pieces: &[Piece], refl: &RefLine) -> Vec<[f64; 4]> {
    let mut bars: Vec<[f64; 4]> = pieces.iter().filter_map(|p| stop_line_across(p, refl)).collect();
    // Stripes along the road (a crossing of it; those across it cross a side street).
    let along = crosswalk_boxes(pieces, refl, |b| b[1] - b[0] >= 2.0 * (b[3] - b[2]));
    bars.extend(stripe_rows(&along, 0.0).into_iter().map(|(b, _)| b));
    bars.retain(|b| b[3] - b[2] >= BAR_MIN_ACROSS_M);
    bars
}

/// Shortest extent across the road (m) of a bar a lane line may run on to.
const BAR_MIN_ACROSS_M: f64 = 2.0;
/// How far beside a bar's seen extent across the road (m) a lane line may meet it: a car
/// beside the survey vehicle hides the bar's other end as well as the line's last metres.
const BAR_REACH_M: f64 = 10.0;
/// Length (m) over which a lane line's end direction is taken.
const END_FIT_M: f64 = 10.0;
/// Largest end slope (offset per mileage) of a lane line carried on: one that bends away
/// (a ramp's line leaving the road) is not.
const END_MAX_SLOPE: f64 = 0.03;
/// Confidence of a lane line's extension and of the solid piece along it.
const EXTENSION_CONFIDENCE: f64 = 0.3;

/// Lane lines that end where the scanner stopped seeing their course run on to the bar
/// across the road ahead (a stop line, a crossing) at most `max_m` beyond their end: a
/// queue of cars beside the survey vehicle at a junction hides the last metres of the lines
/// (and of the bar), and a lane line runs to the bar. A line is carried on along its end
/// direction (fitted over [`END_FIT_M`], slope at most [`END_MAX_SLOPE`]) to the nearest bar
/// ahead whose extent across the road, widened by [`BAR_REACH_M`], holds that course, when
/// no bare asphalt was seen on the course (`Gap::Unseen`: bare asphalt there means the line
/// really ends). Both ends of a line are tried. Returns the solid pieces along the
/// extensions of solid lines (no points seen, confidence [`EXTENSION_CONFIDENCE`]).
fn extend_to_bars(
    lines: &mut [lanes::LaneResult],
    pieces: &[Piece],
    refl: &RefLine,
    seen: &Lookup<'_>,
    max_m: f64,
) -> Vec<Piece> {
    let bars = bars_across(pieces, refl);
    let mut out = Vec::new();
    if bars.is_empty() {
        return out;
    }
    for l in lines.iter_mut().filter(|l| l.class == LaneLineClass::SolidLine) {
        // The line's vertices run in increasing mileage (see `lanes::LaneResult::line`).
        let so: Vec<[f64; 2]> = l.line.iter().map(|&q| refl.locate(q)).collect();
        if so.len() < 2 {
            continue;
        }
        let width = {
            let mut w: Vec<f64> = l.pieces.iter().map(|&k| pieces[k].marking.width_m).collect();
            if w.is_empty() {
                continue;
            }
            geom::median(&mut w)
        };
        // The extensions before the first vertex and after the last, in mileage order and
        // without the line's own end vertex.
        let (mut before, mut after) = (Vec::new(), Vec::new());
        for (end, dir) in [(so.len() - 1, 1.0), (0, -1.0)] {
            let (s_e, o_e) = (so[end][0], so[end][1]);
            let near: Vec<[f64; 2]> = so
                .iter()
                .copied()
                .filter(|q| (q[0] - s_e).abs() <= END_FIT_M)
                .collect();
            let slope = geom::ls_slope(&near).unwrap_or(0.0);
            if slope.abs() > END_MAX_SLOPE {
                continue;
            }
            let course_at = |s: f64| o_e + slope * (s - s_e);
            // The nearest bar ahead that the course meets.
            let hit = bars
                .iter()
                .filter_map(|b| {
                    let s_b = if dir > 0.0 { b[0] } else { b[1] };
                    let d = dir * (s_b - s_e);
                    let o = course_at(s_b);
                    (d > 0.5 && d <= max_m && o >= b[2] - BAR_REACH_M && o <= b[3] + BAR_REACH_M)
                        .then_some((d, s_b))
                })
                .min_by(|a, b| a.0.total_cmp(&b.0));
            let Some((d, s_b)) = hit else { continue };
            // From the bar's side or the line's end, whichever comes first along the road.
            let (from, to) = if dir > 0.0 { (s_e, s_b) } else { (s_b, s_e) };
            let n = d.ceil() as usize;
            let run: Vec<[f64; 2]> = (0..=n)
                .map(|k| {
                    let s = from + (to - from) * k as f64 / n as f64;
                    refl.point(s, course_at(s))
                })
                .collect();
            if seen.gap(&run, 0.05) != Gap::Unseen {
                continue;
            }
            if dir > 0.0 {
                after = run[1..].to_vec();
            } else {
                before = run[..n].to_vec();
            }
            out.extend(unseen_solid(run, width, EXTENSION_CONFIDENCE));
        }
        if before.is_empty() && after.is_empty() {
            continue;
        }
        before.append(&mut l.line);
        before.append(&mut after);
        l.length_m = geom::polyline_length(&before);
        l.line = before;
        l.confidence = l.confidence.min(l.confidence * 0.5 + EXTENSION_CONFIDENCE * 0.5);
    }
    out
}

/// Outlines, lane lines and ids for one cloud (the whole drive in one chunk).
pub fn run(
    cloud: &PointCloud,
    candidates: &[Candidate],
    traj_local: &Trajectory,
    params: &Params,
) -> (Vec<Marking>, Vec<LaneLine>) {
    let pieces = outlines(cloud, candidates, params);
    let o = cloud.origin;
    let traj_abs = traj_local.to_local([-o[0], -o[1], -o[2]]);
    assemble(pieces, &traj_abs, params, None)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Stations and sub-lines along a bent lane line (10 m east, then 10 m north).
    #[test]
    fn stations_and_sub_lines_follow_the_lane_line() {
        let lane = [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]];
        assert!((station_on(&lane, [4.0, 0.3]) - 4.0).abs() < 1e-9);
        assert!((station_on(&lane, [10.2, 6.0]) - 16.0).abs() < 1e-9);
        let sub = sub_line(&lane, 8.0, 13.0);
        assert_eq!(sub.len(), 3, "{sub:?}");
        let near = |p: [f64; 2], q: [f64; 2]| (p[0] - q[0]).hypot(p[1] - q[1]) < 1e-9;
        assert!(near(sub[0], [8.0, 0.0]) && near(sub[1], [10.0, 0.0]) && near(sub[2], [10.0, 3.0]));
        assert!((geom::polyline_length(&sub) - 5.0).abs() < 1e-9);
        let inner = sub_line(&lane, 2.0, 3.5);
        assert!(inner.len() == 2 && near(inner[0], [2.0, 0.0]) && near(inner[1], [3.5, 0.0]));
    }

    #[test]
    fn headings_are_clockwise_from_north() {
        assert!((heading_deg([0.0, 1.0]) - 0.0).abs() < 1e-12);
        assert!((heading_deg([1.0, 0.0]) - 90.0).abs() < 1e-12);
        assert!((heading_deg([0.0, -1.0]) - 180.0).abs() < 1e-12);
        assert!((heading_deg([-1.0, 0.0]) - 270.0).abs() < 1e-12);
    }

    #[test]
    fn params_validate_and_parse() {
        assert!(Params::default().validate().is_ok());
        let p: Params = serde_json::from_str(r#"{"lane_lines": {"max_gap_m": 40}}"#).unwrap();
        assert_eq!(p.lane_lines.max_gap_m, 40.0);
        assert_eq!(p.lane_lines.min_dashes, 3);
        let bad: Params = serde_json::from_str(r#"{"lane_lines": {"max_angle_deg": -1}}"#).unwrap();
        assert!(bad.validate().unwrap_err().contains("max_angle_deg"));
        assert!(serde_json::from_str::<Params>(r#"{"lanes": {}}"#).is_err());
        for (field, json) in [
            ("curved_min_sagitta_m", r#"{"curved_min_sagitta_m": 2}"#),
            ("max_bar_width_m", r#"{"max_bar_width_m": 0}"#),
            ("bridge_long_gap_m", r#"{"bridge_long_gap_m": 60}"#),
            ("fill_missing_stripes", r#"{"fill_missing_stripes": 11}"#),
        ] {
            let bad: Params = serde_json::from_str(json).unwrap();
            assert!(bad.validate().unwrap_err().starts_with(field), "{field}");
        }
    }

    fn solid(x0: f64, x1: f64) -> Piece {
        Piece {
            marking: Marking {
                id: String::new(),
                class: MarkingClass::SolidLine,
                outline: outline::buffered_line(&[[x0, 0.0], [x1, 0.0]], 0.075),
                confidence: 0.8,
                length_m: x1 - x0,
                width_m: 0.15,
                heading_deg: 90.0,
                point_count: 100,
            },
            centerline: Some(vec![[x0, 0.0], [x1, 0.0]]),
            undersampled: None,
            fragment: false,
            not_paint: false,
            contrast: None,
        }
    }

    /// `p` moved by `y` across the road.
    fn shifted(mut p: Piece, y: f64) -> Piece {
        p.marking.outline.iter_mut().for_each(|q| q[1] += y);
        p.centerline.iter_mut().flatten().for_each(|q| q[1] += y);
        p
    }

    /// A 2 m dash from `x0` at offset `y`.
    fn dash(x0: f64, y: f64) -> Piece {
        let mut p = shifted(solid(x0, x0 + 2.0), y);
        p.marking.class = MarkingClass::DashedLine;
        p
    }

    /// An axis-aligned rectangular mark without a centreline.
    fn rect(class: MarkingClass, x0: f64, x1: f64, y0: f64, y1: f64) -> Piece {
        Piece {
            marking: Marking {
                class,
                outline: vec![[x0, y0], [x1, y0], [x1, y1], [x0, y1]],
                ..solid(0.0, 1.0).marking
            },
            centerline: None,
            undersampled: None,
            fragment: false,
            not_paint: false,
            contrast: None,
        }
    }

    /// Three hatching stripes 1.5 m apart stay guidelines; a stripe 10 m from them and a
    /// crosswalk stripe beside it do not make it one of a group.
    #[test]
    fn a_lone_guideline_stripe_is_dropped_and_hatching_kept() {
        let g = |x: f64| rect(MarkingClass::Guideline, x, x + 0.45, 0.0, 1.5);
        let pieces = vec![
            g(0.0),
            g(1.95),
            g(3.9),
            g(14.0),
            rect(MarkingClass::Crosswalk, 15.0, 15.45, 0.0, 3.0),
        ];
        assert_eq!(lone_guidelines(&pieces), vec![3]);
        assert!(lone_guidelines(&pieces[..2]).is_empty());
    }

    #[test]
    fn short_gaps_of_a_solid_line_are_bridged_along_it_and_long_ones_not() {
        let lane: Vec<[f64; 2]> = (0..=30).map(|i| [i as f64, 0.0]).collect();
        let b = bridge(&solid(0.0, 10.0), &solid(13.0, 30.0), &lane, 4.0).expect("3 m gap");
        assert_eq!(b.marking.class, MarkingClass::SolidLine);
        assert_eq!(b.marking.point_count, 0);
        assert!((b.marking.confidence - 0.4).abs() < 1e-12);
        assert!((b.marking.length_m - 3.0).abs() < 1e-9);
        assert!((outline::area(&b.marking.outline) - 3.0 * 0.15).abs() < 1e-6);
        // Either piece order and centreline direction give the same bridge.
        let mut rev = solid(13.0, 30.0);
        rev.centerline.as_mut().unwrap().reverse();
        let b2 = bridge(&rev, &solid(0.0, 10.0), &lane, 4.0).expect("3 m gap");
        assert!((b2.marking.length_m - 3.0).abs() < 1e-9);
        // Too long, or a mere joint: nothing.
        assert!(bridge(&solid(0.0, 10.0), &solid(15.0, 30.0), &lane, 4.0).is_none());
        assert!(bridge(&solid(0.0, 10.0), &solid(10.05, 30.0), &lane, 4.0).is_none());
    }

    #[test]
    fn only_the_stretches_no_piece_covers_are_gaps_of_a_line() {
        // A long piece with a short one beside it (0.1 m across), then a gap, then a piece;
        // taken pairwise in order, the short piece "started" a 10 m gap along paint.
        let pieces = vec![
            solid(0.0, 50.0),
            shifted(solid(10.0, 20.0), 0.1),
            solid(60.0, 100.0),
            solid(100.0, 120.0),
        ];
        let l = lanes::LaneResult {
            class: LaneLineClass::SolidLine,
            line: vec![[0.0, 0.0], [120.0, 0.0]],
            confidence: 0.9,
            length_m: 120.0,
            pieces: vec![0, 1, 2, 3],
            start: [0.0, 0.0],
        };
        assert_eq!(uncovered_gaps(&l, &pieces), vec![(0, 2)]);
        // The piece beside reaching past the long one ends the covered stretch instead.
        let mut beside = pieces.clone();
        beside[1] = shifted(solid(40.0, 55.0), 0.1);
        assert_eq!(uncovered_gaps(&l, &beside), vec![(1, 2)]);
    }

    #[test]
    fn undersampled_line_pieces_are_drawn_along_their_lane_line() {
        let far = |p: Piece| Piece {
            undersampled: Some(0.3),
            ..p
        };
        // A far piece 4 cm off its line's course and tilted, one 0.3 m off (not on it), a
        // resolved piece 4 cm off (its own points say where it is).
        let mut tilted = far(solid(10.0, 20.0));
        tilted.centerline = Some(vec![[10.0, 0.06], [20.0, 0.02]]);
        let mut pieces = vec![
            tilted,
            far(shifted(solid(30.0, 40.0), 0.3)),
            shifted(solid(50.0, 60.0), 0.04),
        ];
        let before: Vec<Vec<[f64; 2]>> = pieces.iter().map(|p| p.marking.outline.clone()).collect();
        let l = lanes::LaneResult {
            class: LaneLineClass::SolidLine,
            line: vec![[0.0, 0.0], [100.0, 0.0]],
            confidence: 0.9,
            length_m: 100.0,
            pieces: vec![0, 1, 2],
            start: [0.0, 0.0],
        };
        recentre_undersampled(&mut pieces, &[l]);
        let ys: Vec<f64> = pieces[0].marking.outline.iter().map(|q| q[1]).collect();
        let (lo, hi) = ys.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |a, &y| {
            (a.0.min(y), a.1.max(y))
        });
        assert!((lo + 0.075).abs() < 1e-9 && (hi - 0.075).abs() < 1e-9, "{ys:?}");
        assert!((outline::area(&pieces[0].marking.outline) - 10.0 * 0.15).abs() < 1e-6);
        assert_eq!(pieces[0].centerline, Some(vec![[10.0, 0.0], [20.0, 0.0]]));
        assert_eq!(pieces[1].marking.outline, before[1]);
        assert_eq!(pieces[2].marking.outline, before[2]);
    }

    #[test]
    fn long_gaps_are_bridged_only_between_longer_solid_pieces() {
        let p = Params::default();
        assert_eq!(
            bridge_limit(1.0, 50.0, &p),
            8.0,
            "a short piece beside: short gaps only"
        );
        assert_eq!(bridge_limit(9.0, 50.0, &p), 9.0);
        assert_eq!(bridge_limit(30.0, 50.0, &p), 12.0);
        let off = Params {
            bridge_long_gap_m: 0.0,
            ..Params::default()
        };
        assert_eq!(bridge_limit(30.0, 50.0, &off), 8.0);
        // Far-range pieces (undersampled) are short because the scan rows drift off the
        // line, not because it is broken: long gaps between them are bridged.
        let far = |x0: f64, x1: f64| Piece {
            undersampled: Some(0.4),
            ..solid(x0, x1)
        };
        assert_eq!(gap_limit(&far(0.0, 1.0), &far(9.0, 10.0), &p), 12.0);
        assert_eq!(gap_limit(&far(0.0, 1.0), &solid(9.0, 10.0), &p), 8.0);
        assert_eq!(gap_limit(&solid(0.0, 30.0), &solid(40.0, 90.0), &p), 12.0);
        let bad = Params {
            bridge_long_gap_m: -1.0,
            ..Params::default()
        };
        assert!(bad.validate().unwrap_err().contains("bridge_long_gap_m"));
    }

    /// A far solid line's 5 m piece read as a "stop line" along the road continues the line
    /// and becomes a solid piece; a side street's stop line set back 1 m from the line, and
    /// a stop line across the road, stay.
    #[test]
    fn bars_along_the_road_that_continue_a_line_are_line_pieces() {
        let traj = crate::pipeline::types::test_straight_trajectory(100, -20.0);
        let refl = RefLine::new(&traj);
        let bar = |x0: f64, x1: f64, y0: f64, y1: f64| rect(MarkingClass::StopLine, x0, x1, y0, y1);
        let mut pieces = vec![
            shifted(solid(0.0, 10.0), 26.5),
            bar(14.0, 19.0, 26.35, 26.65),
            bar(14.0, 19.0, 27.35, 27.65),
            bar(22.0, 22.3, 20.0, 26.0),
        ];
        lines_not_stop_lines(&mut pieces, &refl);
        let classes: Vec<MarkingClass> = pieces.iter().map(|p| p.marking.class).collect();
        assert_eq!(
            classes,
            [
                MarkingClass::SolidLine,
                MarkingClass::SolidLine,
                MarkingClass::StopLine,
                MarkingClass::StopLine
            ]
        );
        let cl = pieces[1]
            .centerline
            .as_ref()
            .expect("a line piece has a centreline");
        let near = |p: [f64; 2], q: [f64; 2]| (p[0] - q[0]).hypot(p[1] - q[1]) < 1e-9;
        assert!(near(cl[0], [14.0, 26.5]) && near(cl[1], [19.0, 26.5]), "{cl:?}");
        assert!((pieces[1].marking.heading_deg - 90.0).abs() < 1e-9);
    }

    /// A bar across the road that a solid line runs on through (an expansion joint) is not
    /// reported at all, while the line stays one lane line; a bar where the line ends is a
    /// stop line.
    #[test]
    fn bars_that_lane_lines_run_through_are_not_reported() {
        let traj = crate::pipeline::types::test_straight_trajectory(100, -20.0);
        let bar = || bar_across(30.0, 0.3, -1.75, 5.25);
        let (marks, lines) = assemble(
            vec![bar(), shifted(solid(0.0, 60.0), 1.75)],
            &traj,
            &Params::default(),
            None,
        );
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert_eq!(marks.len(), 1, "{marks:?}");
        assert_eq!(marks[0].class, MarkingClass::SolidLine);
        let marks = marks_of(vec![bar(), shifted(solid(0.0, 29.5), 1.75)]);
        assert!(
            marks.iter().any(|m| m.class == MarkingClass::StopLine),
            "{marks:?}"
        );
    }

    /// Two pieces of a joint across the road, each ending at a line on one side only, are
    /// no crossed bars one by one; joined into one bar, a line runs through it, and it is
    /// not reported.
    #[test]
    fn joined_bars_that_lane_lines_run_through_are_not_reported() {
        let with_lines = |bars: &[(f64, f64)]| -> Vec<Piece> {
            (0..3)
                .map(|k| shifted(solid(0.0, 60.0), 3.5 * k as f64))
                .chain(bars.iter().map(|&(y0, y1)| bar_across(30.0, 0.3, y0, y1)))
                .collect()
        };
        let marks = marks_of(with_lines(&[(1.0, 3.4), (3.6, 6.0)]));
        assert!(
            marks.iter().all(|m| m.class == MarkingClass::SolidLine),
            "{marks:?}"
        );
        // One piece alone stays a stop line.
        let marks = marks_of(with_lines(&[(1.0, 3.4)]));
        assert!(
            marks.iter().any(|m| m.class == MarkingClass::StopLine),
            "{marks:?}"
        );
    }

    /// An `unknown` line fragment (1.5 m, shorter than any dash) between two 18 m pieces
    /// of a line 42 m apart joins them into one lane line and takes its class; without
    /// it the gap is too long and they stay two lines.
    #[test]
    fn unknown_line_fragments_join_lane_lines() {
        let traj = crate::pipeline::types::test_straight_trajectory(100, -20.0);
        let mut fragment = shifted(solid(38.0, 39.5), 3.5);
        fragment.marking.class = MarkingClass::Unknown;
        let ends = vec![shifted(solid(0.0, 18.0), 3.5), shifted(solid(60.0, 78.0), 3.5)];
        let (_, lines) = assemble(ends.clone(), &traj, &Params::default(), None);
        assert_eq!(lines.len(), 2);
        let mut with = ends;
        with.push(fragment.clone());
        let (marks, lines) = assemble(with, &traj, &Params::default(), None);
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert!((lines[0].length_m - 78.0).abs() < 1.0, "{}", lines[0].length_m);
        assert!(marks.iter().all(|m| m.class == MarkingClass::SolidLine));
        // Alone it stays `unknown`.
        let (marks, lines) = assemble(vec![fragment], &traj, &Params::default(), None);
        assert!(lines.is_empty());
        assert_eq!(marks[0].class, MarkingClass::Unknown);
    }

    /// Six 2/4 m dashes make a dashed lane line and stay dashes; a lone dash 3.5 m beside
    /// them belongs to no lane line and is `unknown` (unless the rule is off).
    #[test]
    fn dashes_outside_every_lane_line_are_unknown() {
        let traj = crate::pipeline::types::test_straight_trajectory(100, -20.0);
        let pieces = || {
            let mut v: Vec<Piece> = (0..6).map(|i| dash(6.0 * i as f64, 3.5)).collect();
            v.push(dash(14.0, 7.0));
            v
        };
        let (marks, lines) = assemble(pieces(), &traj, &Params::default(), None);
        assert_eq!(lines.len(), 1);
        let count = |ms: &[Marking], c: MarkingClass| ms.iter().filter(|m| m.class == c).count();
        assert_eq!(count(&marks, MarkingClass::DashedLine), 6);
        assert_eq!(count(&marks, MarkingClass::Unknown), 1);
        let off = Params {
            isolated_dashes_unknown: false,
            ..Params::default()
        };
        let (marks, _) = assemble(pieces(), &traj, &off, None);
        assert_eq!(count(&marks, MarkingClass::DashedLine), 7);
    }

    /// `unknown` markings are reported only when their points are clearly paint: a faint
    /// one (a sealant streak at 1.3 times the asphalt) goes, a bright one stays, and so do
    /// one without a measured contrast and a faint piece of a named class.
    #[test]
    fn faint_unknown_markings_are_dropped() {
        let traj = crate::pipeline::types::test_straight_trajectory(100, -20.0);
        let with = |class: MarkingClass, x0: f64, contrast: Option<f64>| Piece {
            contrast,
            ..rect(class, x0, x0 + 1.5, 4.0, 4.4)
        };
        let pieces = || {
            vec![
                with(MarkingClass::Unknown, 10.0, Some(1.3)),
                with(MarkingClass::Unknown, 20.0, Some(3.0)),
                with(MarkingClass::Unknown, 30.0, None),
                with(MarkingClass::Diamond, 40.0, Some(1.3)),
            ]
        };
        let xs = |ms: &[Marking]| -> Vec<f64> {
            let mut v: Vec<f64> = ms.iter().map(|m| m.outline[0][0]).collect();
            v.sort_by(f64::total_cmp);
            v
        };
        let (marks, _) = assemble(pieces(), &traj, &Params::default(), None);
        assert_eq!(xs(&marks), vec![20.0, 30.0, 40.0]);
        let off = Params {
            unknown_min_contrast: 0.0,
            ..Params::default()
        };
        let (marks, _) = assemble(pieces(), &traj, &off, None);
        assert_eq!(marks.len(), 4);
    }

    /// Dashed lane lines end to end at one offset are one line: 8 m apart (a dash gap) or
    /// overlapping by 2 m they are joined, keeping all their pieces; 0.5 m across, across a
    /// stop line, 15 m apart, or solid, they are not.
    #[test]
    fn dashed_lines_end_to_end_are_joined() {
        let traj = crate::pipeline::types::test_straight_trajectory(300, -20.0);
        let refl = RefLine::new(&traj);
        let line = |x0: f64, x1: f64, y: f64, key: usize, class: LaneLineClass| lanes::LaneResult {
            class,
            line: vec![[x0, y], [0.5 * (x0 + x1), y], [x1, y]],
            confidence: 0.8,
            length_m: x1 - x0,
            pieces: vec![key],
            start: [x0, y],
        };
        let d = LaneLineClass::DashedLine;
        let mut lines = vec![
            line(0.0, 50.0, 3.0, 0, d),
            line(58.0, 100.0, 3.0, 1, d),
            line(98.0, 130.0, 3.0, 2, d),
            line(130.0, 160.0, 3.5, 3, d),
            line(175.0, 200.0, 3.5, 4, d),
            line(0.0, 100.0, -3.0, 5, LaneLineClass::SolidLine),
            line(108.0, 150.0, -3.0, 6, LaneLineClass::SolidLine),
            line(0.0, 60.0, -6.0, 7, d),
            line(64.0, 120.0, -6.0, 8, d),
        ];
        let stop = vec![[61.0, -7.0], [61.5, -7.0], [61.5, -5.0], [61.0, -5.0]];
        join_dashed_lines(&mut lines, &[stop], &refl);
        let mut keys: Vec<Vec<usize>> = lines.iter().map(|l| l.pieces.clone()).collect();
        keys.sort();
        assert_eq!(
            keys,
            vec![
                vec![0, 1, 2],
                vec![3],
                vec![4],
                vec![5],
                vec![6],
                vec![7],
                vec![8]
            ]
        );
        let joined = lines
            .iter()
            .find(|l| l.pieces.len() == 3)
            .expect("one joined line");
        assert!((joined.length_m - 130.0).abs() < 0.01, "{}", joined.length_m);
        assert!(
            joined.line.windows(2).all(|w| w[1][0] > w[0][0]),
            "{:?}",
            joined.line
        );
    }

    /// The edge line at y −5.3 breaks for a side street (x 30–50) whose crossing, stripes
    /// across the road from x 32 to 48, begins `set_back` metres beyond it: set back 1.4 m
    /// (as on the simulated junctions) the line is not joined across the mouth; set back
    /// 4 m it is (no mouth is known so far from the line), and so it is without the
    /// crossing.
    #[test]
    fn an_edge_line_is_not_joined_across_a_side_streets_mouth() {
        let traj = crate::pipeline::types::test_straight_trajectory(100, -20.0);
        let lines_with = |set_back: Option<f64>| {
            let mut pieces = vec![shifted(solid(0.0, 30.0), -5.3), shifted(solid(50.0, 80.0), -5.3)];
            if let Some(b) = set_back {
                pieces.extend((0..17).map(|k| {
                    rect(
                        MarkingClass::Crosswalk,
                        32.0 + k as f64,
                        32.45 + k as f64,
                        -14.0,
                        -5.3 - b,
                    )
                }));
            }
            let (_, lanes) = assemble(pieces, &traj, &Params::default(), None);
            let mut spans: Vec<(f64, f64)> = lanes
                .iter()
                .map(|l| {
                    (
                        l.line[0][0].min(l.line[l.line.len() - 1][0]),
                        l.line[0][0].max(l.line[l.line.len() - 1][0]),
                    )
                })
                .collect();
            spans.sort_by(|a, b| a.0.total_cmp(&b.0));
            spans
        };
        let two = lines_with(Some(1.4));
        assert_eq!(two.len(), 2, "{two:?}");
        assert!(two[0].1 <= 31.0 && two[1].0 >= 49.0, "{two:?}");
        for far in [Some(4.0), None] {
            let one = lines_with(far);
            assert_eq!(one.len(), 1, "{far:?}: {one:?}");
            assert!(one[0].0 <= 1.0 && one[0].1 >= 79.0, "{far:?}: {one:?}");
        }
    }

    /// A stop line across the road (y −1.75 to 5.25) from x0, `w` wide.
    fn stop_bar(x0: f64, w: f64) -> Piece {
        bar_across(x0, w, -1.75, 5.25)
    }

    /// A stop line across the road from x0, `w` wide, over y0..y1, its measured width and
    /// length too.
    fn bar_across(x0: f64, w: f64, y0: f64, y1: f64) -> Piece {
        let mut p = rect(MarkingClass::StopLine, x0, x0 + w, y0, y1);
        (p.marking.width_m, p.marking.length_m) = (w, y1 - y0);
        p
    }

    /// The markings `assemble` makes of `pieces` beside the test trajectory (default
    /// parameters).
    fn marks_of(pieces: Vec<Piece>) -> Vec<Marking> {
        let traj = crate::pipeline::types::test_straight_trajectory(100, -20.0);
        assemble(pieces, &traj, &Params::default(), None).0
    }

    /// (smallest x, class) of each marking, in order of x.
    fn classes_by_x(ms: &[Marking]) -> Vec<(f64, MarkingClass)> {
        let mut v: Vec<(f64, MarkingClass)> = ms
            .iter()
            .map(|m| {
                (
                    m.outline.iter().map(|q| q[0]).fold(f64::INFINITY, f64::min),
                    m.class,
                )
            })
            .collect();
        v.sort_by(|a, b| a.0.total_cmp(&b.0));
        v
    }

    /// A bar across the road is a stop line only where its points are clearly paint: one at
    /// 1.9 times the asphalt (a worn stop line) stays one, one at 1.55 (the edge of a
    /// resurfaced strip) becomes `unknown`, and one at 1.4 is then dropped as a faint
    /// `unknown`; with the parameter at 0 all three are stop lines.
    #[test]
    fn faint_bars_are_no_stop_lines() {
        let traj = crate::pipeline::types::test_straight_trajectory(100, -20.0);
        let bar = |x0: f64, contrast: f64| Piece {
            contrast: Some(contrast),
            ..stop_bar(x0, 0.4)
        };
        let pieces = || vec![bar(20.0, 1.9), bar(40.0, 1.55), bar(60.0, 1.4)];
        let (marks, _) = assemble(pieces(), &traj, &Params::default(), None);
        assert_eq!(
            classes_by_x(&marks),
            vec![(20.0, MarkingClass::StopLine), (40.0, MarkingClass::Unknown)]
        );
        let off = Params {
            stop_line_min_contrast: 0.0,
            ..Params::default()
        };
        let (marks, _) = assemble(pieces(), &traj, &off, None);
        assert_eq!(
            classes_by_x(&marks),
            vec![
                (20.0, MarkingClass::StopLine),
                (40.0, MarkingClass::StopLine),
                (60.0, MarkingClass::StopLine)
            ]
        );
    }

    /// A "stop line" narrower than any standard paints one (a far edge line's 0.16 m
    /// fragment the network named so) is `unknown`; 0.2 m and wider bars stay stop lines.
    #[test]
    fn narrow_bars_are_no_stop_lines() {
        let traj = crate::pipeline::types::test_straight_trajectory(100, -20.0);
        let pieces = vec![stop_bar(20.0, 0.16), stop_bar(40.0, 0.2), stop_bar(60.0, 0.3)];
        let (marks, _) = assemble(pieces, &traj, &Params::default(), None);
        assert_eq!(
            classes_by_x(&marks),
            vec![
                (20.0, MarkingClass::Unknown),
                (40.0, MarkingClass::StopLine),
                (60.0, MarkingClass::StopLine)
            ]
        );
    }

    /// A bar across the road (0.2 m × 7 m) that a dashed line runs on through (dashes ending
    /// 3 m before it and starting 4 m after it at its offset) is no stop line; one where the
    /// line ends, or with a crosswalk beside it, stays a stop line.
    #[test]
    fn bars_that_lane_lines_run_through_are_no_stop_lines() {
        let traj = crate::pipeline::types::test_straight_trajectory(100, -20.0);
        let refl = RefLine::new(&traj);
        let dash = |x0: f64| dash(x0, 1.75);
        let bar = || rect(MarkingClass::StopLine, 30.0, 30.2, -1.75, 5.25);
        let class_of_bar = |mut pieces: Vec<Piece>| {
            stop_lines_crossed_by_lines(&mut pieces, &refl);
            pieces[0].marking.class
        };
        assert_eq!(
            class_of_bar(vec![bar(), dash(25.0), dash(34.2)]),
            MarkingClass::Unknown
        );
        assert_eq!(class_of_bar(vec![bar(), dash(25.0)]), MarkingClass::StopLine);
        // One solid piece running on through it unbroken.
        assert_eq!(
            class_of_bar(vec![bar(), shifted(solid(0.0, 60.0), 1.75)]),
            MarkingClass::Unknown
        );
        // Beyond 10 m on: not the same line running on.
        assert_eq!(
            class_of_bar(vec![bar(), dash(25.0), dash(41.0)]),
            MarkingClass::StopLine
        );
        let stripe = rect(MarkingClass::Crosswalk, 32.0, 36.0, 2.0, 2.45);
        assert_eq!(
            class_of_bar(vec![bar(), dash(25.0), dash(34.2), stripe]),
            MarkingClass::StopLine
        );
        // A joint across one lane (between lines at -1.75 and 1.75): a solid line runs on
        // past its left end unbroken and a dashed line past its right end, so it is no stop
        // line; with the dashed line ending at it, it stays one.
        let joint = || rect(MarkingClass::StopLine, 30.0, 30.2, -1.6, 1.65);
        let through = || shifted(solid(0.0, 60.0), 1.75);
        let dash_r = |x0: f64| super::tests::dash(x0, -1.75);
        assert_eq!(
            class_of_bar(vec![joint(), through(), dash_r(28.5), dash_r(37.0)]),
            MarkingClass::Unknown
        );
        assert_eq!(
            class_of_bar(vec![joint(), through(), dash_r(28.0)]),
            MarkingClass::StopLine
        );
        assert_eq!(class_of_bar(vec![joint(), through()]), MarkingClass::StopLine);
    }

    /// Bars across the road: between the edge lines (or just beyond one) they stay stop
    /// lines; wholly beyond an edge line they are a side street's markings (`unknown`);
    /// with no lane line within 40 m nothing is known of the edges and they stay.
    #[test]
    fn bars_across_beyond_the_edge_lines_are_no_stop_lines() {
        let traj = crate::pipeline::types::test_straight_trajectory(100, -20.0);
        let refl = RefLine::new(&traj);
        let lane = |o: f64, x0: f64, x1: f64| lanes::LaneResult {
            class: LaneLineClass::SolidLine,
            line: vec![[x0, o], [x1, o]],
            confidence: 0.9,
            length_m: x1 - x0,
            pieces: vec![],
            start: [x0, o],
        };
        let edges = vec![
            lane(-5.3, 0.0, 25.0),
            lane(5.3, 0.0, 25.0),
            lane(-5.3, 35.0, 80.0),
        ];
        let class_of = |o0: f64, o1: f64, lines: &[lanes::LaneResult]| {
            let mut pieces = vec![rect(MarkingClass::StopLine, 30.0, 30.3, o0, o1)];
            stop_lines_beyond_edges(&mut pieces, lines, &refl);
            pieces[0].marking.class
        };
        assert_eq!(class_of(-5.0, -1.0, &edges), MarkingClass::StopLine);
        assert_eq!(class_of(-5.0, 5.0, &edges), MarkingClass::StopLine);
        assert_eq!(class_of(-14.0, -9.0, &edges), MarkingClass::Unknown);
        assert_eq!(class_of(6.0, 8.0, &edges), MarkingClass::StopLine);
        assert_eq!(class_of(9.0, 12.0, &edges), MarkingClass::Unknown);
        assert_eq!(
            class_of(-14.0, -9.0, &[lane(-5.3, 75.0, 80.0)]),
            MarkingClass::StopLine
        );
    }

    /// A mark named an arrow whose centre lies on a lane line's course (0.3 m from it, or
    /// just past its end) takes the line's class; an arrow in the middle of the lane (1.7 m
    /// from it) stays an arrow.
    #[test]
    fn arrows_on_a_lane_lines_course_are_pieces_of_it() {
        let line = |class: LaneLineClass| lanes::LaneResult {
            class,
            line: vec![[0.0, 0.0], [40.0, 0.0]],
            confidence: 0.9,
            length_m: 40.0,
            pieces: vec![],
            start: [0.0, 0.0],
        };
        let class_of = |x0: f64, o0: f64, o1: f64, l: LaneLineClass| {
            let mut pieces = vec![rect(MarkingClass::StraightArrow, x0, x0 + 3.0, o0, o1)];
            arrows_on_lane_lines(&mut pieces, &[line(l)]);
            pieces[0].marking.class
        };
        for (x0, o0, o1, line_class, want) in [
            (
                10.0,
                0.05,
                0.55,
                LaneLineClass::DashedLine,
                MarkingClass::DashedLine,
            ),
            (38.6, -0.4, 0.1, LaneLineClass::SolidLine, MarkingClass::SolidLine),
            (
                10.0,
                1.3,
                2.1,
                LaneLineClass::SolidLine,
                MarkingClass::StraightArrow,
            ),
            (
                45.0,
                -0.2,
                0.2,
                LaneLineClass::SolidLine,
                MarkingClass::StraightArrow,
            ),
        ] {
            assert_eq!(
                class_of(x0, o0, o1, line_class),
                want,
                "arrow at {x0}, {o0}..{o1}"
            );
        }
    }

    /// A 45 m gap of a solid lane line is bridged when the scanner did not see its course,
    /// and not when it saw bare asphalt there.
    #[test]
    fn solid_lines_are_bridged_across_gaps_the_scanner_did_not_see() {
        let traj = crate::pipeline::types::test_straight_trajectory(100, -20.0);
        let at = |p: Piece| shifted(p, 3.5);
        let pieces = || vec![at(solid(0.0, 15.0)), at(solid(60.0, 78.0))];
        let p = Params::default();
        let unseen = crate::pipeline::observed::test_seen_except(&traj, 3.5, |x| (15.0..60.0).contains(&x));
        let (marks, lines) = assemble(pieces(), &traj, &p, Some(&unseen.lookup()));
        assert_eq!(lines.len(), 1);
        assert_eq!(marks.len(), 3);
        let bridge = marks.iter().find(|m| m.point_count == 0).expect("a bridge");
        assert!((bridge.length_m - 45.0).abs() < 0.1, "{}", bridge.length_m);
        let bare = crate::pipeline::observed::test_seen_except(&traj, 3.5, |_| false);
        let (marks, lines) = assemble(pieces(), &traj, &p, Some(&bare.lookup()));
        assert_eq!((marks.len(), lines.len()), (2, 2));
    }

    /// A solid lane line whose last 20 m before a crossing the scanner did not see runs on
    /// to the crossing (with a solid piece along the extension), even though the crossing's
    /// stripes were seen only on the other half of the road; where bare asphalt was seen
    /// on that course the line ends where its paint does.
    #[test]
    fn a_solid_line_runs_on_through_what_was_not_seen_to_the_crossing_ahead() {
        let traj = crate::pipeline::types::test_straight_trajectory(100, -20.0);
        let pieces = || {
            let mut v = vec![shifted(solid(0.0, 30.0), 3.5)];
            v.extend((0..5).map(|k| {
                rect(
                    MarkingClass::Crosswalk,
                    50.0,
                    55.0,
                    -3.0 + k as f64,
                    -2.55 + k as f64,
                )
            }));
            v
        };
        let p = Params::default();
        let unseen = crate::pipeline::observed::test_seen_except(&traj, 3.5, |x| (30.0..50.0).contains(&x));
        let (marks, lines) = assemble(pieces(), &traj, &p, Some(&unseen.lookup()));
        assert_eq!(lines.len(), 1);
        let end = lines[0]
            .line
            .iter()
            .map(|q| q[0])
            .fold(f64::NEG_INFINITY, f64::max);
        assert!((end - 50.0).abs() < 0.1, "line ends at {end}");
        let run = marks
            .iter()
            .find(|m| m.point_count == 0)
            .expect("a solid piece along the extension");
        assert_eq!(run.class, MarkingClass::SolidLine);
        assert!((run.length_m - 20.0).abs() < 0.1, "{}", run.length_m);
        let bare = crate::pipeline::observed::test_seen_except(&traj, 3.5, |_| false);
        let (marks, lines) = assemble(pieces(), &traj, &p, Some(&bare.lookup()));
        let end = lines[0]
            .line
            .iter()
            .map(|q| q[0])
            .fold(f64::NEG_INFINITY, f64::max);
        assert!((end - 30.0).abs() < 0.1, "line ends at {end}");
        assert!(marks.iter().all(|m| m.point_count > 0));
    }

    /// A line fragment: a thin 0.6 m piece from `x0` at offset `y`.
    fn fragment(x0: f64, y: f64) -> Piece {
        let mut p = shifted(solid(x0, x0 + 0.6), y);
        p.marking.class = MarkingClass::DashedLine;
        p.marking.width_m = 0.03;
        p.marking.outline = outline::buffered_line(&[[x0, y], [x0 + 0.6, y]], 0.015);
        p.marking.confidence = 0.3;
        p.marking.point_count = 6;
        p.fragment = true;
        p
    }

    /// Where a far line's one fragment per 6 m dash lies in its dash (m from the dash's
    /// start), dash by dash.
    const FAR_FRAGMENT_AT: [f64; 16] = [
        0.2, 2.5, 5.0, 1.0, 4.2, 3.3, 0.6, 5.2, 2.0, 3.9, 1.5, 4.8, 0.9, 2.8, 5.3, 1.8,
    ];

    /// Two dashed lines 1.8 m either side of the trajectory, 6 m dashes every 15 m from x = 3
    /// to 270: the drive's design.
    fn near_dashed_lines() -> Vec<Piece> {
        let mut pieces = Vec::new();
        for k in 0..18 {
            let x0 = 3.0 + 15.0 * k as f64;
            for y in [-1.8, 1.8] {
                let mut d = shifted(solid(x0, x0 + 6.0), y);
                d.marking.class = MarkingClass::DashedLine;
                pieces.push(d);
            }
        }
        pieces
    }

    /// Two near dashed lines (6 m dashes every 15 m) give the drive's design. A far line
    /// seen only as one 0.6 m fragment per dash, at varying places in it, becomes a dashed
    /// lane line whose fragments are put on the painted dashes; a row of fragments at one
    /// offset that follows no period (a verge's bright returns) makes no line, and its
    /// fragments are dropped.
    #[test]
    fn a_far_line_seen_as_fragments_is_put_on_the_drive_design() {
        let traj = crate::pipeline::types::test_straight_trajectory(300, -20.0);
        let mut pieces = near_dashed_lines();
        for (k, &at) in FAR_FRAGMENT_AT.iter().enumerate() {
            pieces.push(fragment(3.0 + 15.0 * k as f64 + at, 22.75));
        }
        for k in 0..12 {
            pieces.push(fragment(16.25 * k as f64, 18.0));
        }
        let (marks, lines) = assemble(pieces, &traj, &Params::default(), None);
        let centre_y = |m: &Marking| m.outline.iter().map(|q| q[1]).sum::<f64>() / m.outline.len() as f64;
        let far: Vec<&Marking> = marks
            .iter()
            .filter(|m| (centre_y(m) - 22.75).abs() < 0.3)
            .collect();
        let placed = far
            .iter()
            .filter(|m| m.class == MarkingClass::DashedLine && (m.length_m - 6.0).abs() < 0.3)
            .count();
        assert!(placed >= 14, "{placed} far dashes put on the design: {far:?}");
        let far_line = lines
            .iter()
            .find(|l| l.line.iter().all(|q| (q[1] - 22.75).abs() < 0.1))
            .expect("a lane line of the far fragments");
        assert_eq!(far_line.class, LaneLineClass::DashedLine);
        assert!(far_line.length_m > 200.0, "{}", far_line.length_m);
        assert!(
            marks.iter().all(|m| (centre_y(m) - 18.0).abs() > 0.5),
            "the fragments off any period are dropped"
        );
        assert!(
            lines
                .iter()
                .all(|l| l.line.iter().all(|q| (q[1] - 18.0).abs() > 0.5))
        );
    }

    /// The drive's lines sway in the trajectory frame with the vehicle (0.3 m over a 100 m
    /// wavelength here). A far line seen as one fragment per dash follows the sway of the
    /// near dashed lines 21 m away (within 0.1 m); its fragments' own offsets smoothed over
    /// 25 m flatten it (0.30 m off).
    #[test]
    fn a_far_line_of_fragments_follows_the_sway_of_the_near_lines() {
        let traj = crate::pipeline::types::test_straight_trajectory(300, -20.0);
        let sway = |x: f64| 0.3 * (2.0 * std::f64::consts::PI * x / 100.0).sin();
        let mut pieces: Vec<Piece> = near_dashed_lines()
            .into_iter()
            .map(|p| {
                let x = p.centerline.as_ref().map_or(0.0, |c| 0.5 * (c[0][0] + c[1][0]));
                shifted(p, sway(x))
            })
            .collect();
        for (k, &at) in FAR_FRAGMENT_AT.iter().enumerate() {
            let x = 3.0 + 15.0 * k as f64 + at;
            pieces.push(fragment(x, 22.75 + sway(x + 0.3)));
        }
        let (_, lines) = assemble(pieces, &traj, &Params::default(), None);
        let far = lines
            .iter()
            .find(|l| l.line.iter().all(|q| (q[1] - 22.75).abs() < 1.0))
            .expect("a lane line of the far fragments");
        let worst = far
            .line
            .iter()
            .filter(|q| q[0] > 10.0 && q[0] < 230.0)
            .map(|q| (q[1] - 22.75 - sway(q[0])).abs())
            .fold(0.0, f64::max);
        assert!(worst < 0.1, "{worst}");
    }

    /// A far line seen as one fragment per 6/9 m dash, two dashes in a row unseen after the
    /// fourth (44 m from fragment to fragment): one lane line over all of it, not a line
    /// from the fifth fragment on with the first four dropped.
    #[test]
    fn a_far_line_of_fragments_spans_two_unseen_dashes() {
        let traj = crate::pipeline::types::test_straight_trajectory(300, -20.0);
        let mut pieces = near_dashed_lines();
        for (k, &at) in FAR_FRAGMENT_AT
            .iter()
            .enumerate()
            .filter(|(k, _)| !(4..6).contains(k))
        {
            pieces.push(fragment(3.0 + 15.0 * k as f64 + at, 22.75));
        }
        let (_, lines) = assemble(pieces, &traj, &Params::default(), None);
        let far: Vec<&LaneLine> = lines
            .iter()
            .filter(|l| l.line.iter().all(|q| (q[1] - 22.75).abs() < 0.1))
            .collect();
        assert_eq!(far.len(), 1, "{far:?}");
        let start = far[0].line.iter().map(|q| q[0]).fold(f64::INFINITY, f64::min);
        assert!(start < 6.0, "the far line starts at {start}");
    }

    /// A far line's fragments scatter a few decimetres about its axis (one per dash here),
    /// so a piece's nearest next one in offset is often not the next along it: the line is
    /// the path through the most of them. A row of strays 1.3 m beside it (a verge's
    /// returns), 12 of 16 on the dashes' phase, makes no line.
    #[test]
    fn a_far_line_of_scattered_fragments_is_one_line_and_strays_beside_it_none() {
        let traj = crate::pipeline::types::test_straight_trajectory(300, -20.0);
        let mut pieces = near_dashed_lines();
        let jitter = [
            0.0, -0.18, 0.1, -0.15, 0.14, -0.06, -0.2, 0.05, 0.1, -0.16, 0.15, -0.03, -0.14, 0.07, 0.12,
            -0.18,
        ];
        for (k, (&j, &at)) in jitter.iter().zip(&FAR_FRAGMENT_AT).enumerate() {
            pieces.push(fragment(3.0 + 15.0 * k as f64 + at, 22.75 + j));
        }
        for k in 0..16 {
            let at = if k % 4 < 3 {
                0.5 + 0.7 * (k % 7) as f64
            } else {
                9.5
            };
            pieces.push(fragment(3.0 + 15.0 * k as f64 + at, 21.45 + 0.1 * (k % 3) as f64));
        }
        let (_, lines) = assemble(pieces, &traj, &Params::default(), None);
        let far: Vec<&LaneLine> = lines
            .iter()
            .filter(|l| l.line.iter().all(|q| (q[1] - 22.75).abs() < 0.5))
            .collect();
        assert_eq!(far.len(), 1, "{far:?}");
        assert!(far[0].length_m > 220.0, "{}", far[0].length_m);
        assert!(
            lines
                .iter()
                .all(|l| l.line.iter().all(|q| (q[1] - 21.45).abs() > 0.5)),
            "no line along the strays"
        );
    }

    /// A row of fragments on the dash pattern that slants across the road (1.2 m over
    /// 240 m) beside a solid lane line that does not makes no lane line: lane lines run side
    /// by side. The far line parallel to it still does.
    #[test]
    fn a_fragment_row_slanting_across_its_neighbour_makes_no_line() {
        let traj = crate::pipeline::types::test_straight_trajectory(300, -20.0);
        let mut pieces = near_dashed_lines();
        for k in 0..9 {
            pieces.push(shifted(solid(30.0 * k as f64, 30.0 * k as f64 + 29.0), 12.0));
        }
        for (k, &at) in FAR_FRAGMENT_AT.iter().enumerate() {
            let x = 3.0 + 15.0 * k as f64 + at;
            pieces.push(fragment(x, 22.75));
            pieces.push(fragment(x, 9.0 + 0.005 * x));
        }
        let (marks, lines) = assemble(pieces, &traj, &Params::default(), None);
        let centre = |m: &Marking| {
            let n = m.outline.len() as f64;
            m.outline
                .iter()
                .fold([0.0, 0.0], |a, q| [a[0] + q[0] / n, a[1] + q[1] / n])
        };
        assert!(
            marks.iter().all(|m| {
                let c = centre(m);
                (c[1] - (9.0 + 0.005 * c[0])).abs() > 0.3
            }),
            "nothing along the slanting row"
        );
        assert!(
            lines
                .iter()
                .any(|l| l.line.iter().all(|q| (q[1] - 22.75).abs() < 0.1))
        );
        assert!(
            !lines
                .iter()
                .any(|l| l.line.iter().all(|q| (q[1] - (9.0 + 0.005 * q[0])).abs() < 0.3))
        );
    }
}
