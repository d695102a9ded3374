//! Stage 6: vectorisation — marking outlines, lane lines, ids.
//!
//! # Interface
//! - `outlines(&PointCloud, &[Candidate], &Params) -> Vec<Piece>`: one [`Piece`] per
//!   candidate: a [`Marking`] in ABSOLUTE coordinates (origin added; `id` still empty) and,
//!   for pieces along the road, the absolute centreline. Per chunk (the candidates already
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
//! alpha shapes for irregular marks (arrows, diamonds, unknown). Heading: long axis, pointing
//! along the driving direction (stop lines: pointing to the right of it), degrees clockwise
//! from north. Lane lines: see `lanes` (improved line-segment self-growth of Yao 2021).
//!
//! # Parameters
//! See [`Params`] (and `lanes::Params` under `lane_lines`).
//!
//! # Reference
//! Yao et al. 2021 §2.3 (self-growth, alpha shapes); Pan et al. 2019 §2.5 (vectorisation).
//!
//! # Complexity
//! O(n log n) for the alpha shapes of n points; see `lanes` for the growth.

use super::classify::Candidate;
use super::geom;
use super::lanes::{self, LanePiece};
use super::outline;
use super::refline::RefLine;
use super::types::{LaneLine, Marking, MarkingClass, PointCloud, Trajectory};
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
    /// Lane-line growth.
    pub lane_lines: lanes::Params,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            curved_min_sagitta_m: 0.03,
            outline_simplify_m: 0.01,
            max_bar_width_m: 0.8,
            lane_lines: lanes::Params::default(),
        }
    }
}

impl Params {
    /// Check every field; the message names the offending parameter.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.curved_min_sagitta_m >= 0.0 && self.curved_min_sagitta_m <= 1.0) {
            return Err(format!(
                "curved_min_sagitta_m must be in [0, 1], got {}",
                self.curved_min_sagitta_m
            ));
        }
        if !(self.outline_simplify_m >= 0.0 && self.outline_simplify_m <= 0.5) {
            return Err(format!(
                "outline_simplify_m must be in [0, 0.5], got {}",
                self.outline_simplify_m
            ));
        }
        if !(self.max_bar_width_m >= 0.1 && self.max_bar_width_m <= 20.0) {
            return Err(format!(
                "max_bar_width_m must be in [0.1, 20], got {}",
                self.max_bar_width_m
            ));
        }
        self.lane_lines.validate()
    }
}

/// A vectorised marking before ids are assigned (absolute coordinates).
#[derive(Clone, Debug, PartialEq)]
pub struct Piece {
    pub marking: Marking,
    /// Centreline of pieces along the road (dashes, solid pieces), driving order.
    pub centerline: Option<Vec<[f64; 2]>>,
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
            let (ring, length, width, heading, centerline) = match c.class {
                MarkingClass::SolidLine | MarkingClass::DashedLine if c.line.is_some() => {
                    let l = c.line.as_ref().expect("checked");
                    let (a, b) = (l.centerline[0], l.centerline[l.centerline.len() - 1]);
                    let chord = [b[0] - a[0], b[1] - a[1]];
                    let cl: Vec<[f64; 2]> = l.centerline.iter().map(|&p| abs(p)).collect();
                    if c.class == MarkingClass::SolidLine || l.sagitta_m > params.curved_min_sagitta_m {
                        let simple = geom::simplify(&l.centerline, params.outline_simplify_m / 2.0);
                        let ring = outline::buffered_line_simple(&simple, l.width_m / 2.0);
                        (ring, l.length_m, l.width_m, heading_deg(chord), Some(cl))
                    } else {
                        (
                            s.corners().to_vec(),
                            s.length_m,
                            s.width_m,
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
                    let pts: Vec<[f64; 2]> = c.indices.iter().map(|&i| [cloud.x[i], cloud.y[i]]).collect();
                    (
                        irregular_ring(&pts, s, params),
                        s.length_m,
                        s.width_m,
                        heading_deg(along),
                        None,
                    )
                }
                MarkingClass::StopLine => {
                    let right = [drive[1], -drive[0]];
                    let d = if s.axis[0] * right[0] + s.axis[1] * right[1] < 0.0 {
                        [-s.axis[0], -s.axis[1]]
                    } else {
                        s.axis
                    };
                    (s.corners().to_vec(), s.length_m, s.width_m, heading_deg(d), None)
                }
                MarkingClass::Crosswalk
                | MarkingClass::Guideline
                | MarkingClass::DashedLine
                | MarkingClass::SolidLine => (
                    s.corners().to_vec(),
                    s.length_m,
                    s.width_m,
                    heading_deg(along),
                    None,
                ),
                _ => {
                    let pts: Vec<[f64; 2]> = c.indices.iter().map(|&i| [cloud.x[i], cloud.y[i]]).collect();
                    (
                        irregular_ring(&pts, s, params),
                        s.length_m,
                        s.width_m,
                        heading_deg(along),
                        None,
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
                centerline,
            })
        })
        .collect()
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

/// Smallest outline area kept (m²): far below any real marking (a 0.1 m x 0.01 m sliver).
const MIN_OUTLINE_AREA_M2: f64 = 1e-3;

/// Lane lines over all pieces, lane-context class corrections, stable ids.
pub fn assemble(pieces: Vec<Piece>, traj_abs: &Trajectory, params: &Params) -> (Vec<Marking>, Vec<LaneLine>) {
    let lane_pieces: Vec<LanePiece> = pieces
        .iter()
        .enumerate()
        .filter_map(|(k, p)| {
            let cl = p.centerline.as_ref()?;
            Some(LanePiece {
                key: k,
                class: p.marking.class,
                centerline: cl.clone(),
                width_m: p.marking.width_m,
                confidence: p.marking.confidence,
            })
        })
        .collect();
    let barriers: Vec<Vec<[f64; 2]>> = pieces
        .iter()
        .filter(|p| matches!(p.marking.class, MarkingClass::StopLine | MarkingClass::Crosswalk))
        .map(|p| p.marking.outline.clone())
        .collect();
    let lanes = lanes::grow_with_barriers(&lane_pieces, traj_abs, &params.lane_lines, &barriers);
    let mut pieces = pieces;
    for &(k, class) in &lanes.classes {
        pieces[k].marking.class = class;
    }
    // Driving order: station of the outline's vertex mean on the absolute reference line.
    let refl = RefLine::new(traj_abs);
    let mut order: Vec<(f64, f64, usize)> = pieces
        .iter()
        .enumerate()
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
            marking_ids: l.pieces.iter().map(|&k| id_of[k].clone()).collect(),
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
    assemble(pieces, &traj_abs, params)
}

#[cfg(test)]
mod tests {
    use super::*;

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
    }
}
