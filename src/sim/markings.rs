//! Road-marking geometry, the per-point paint lookup, and the truth `Extraction`.
//!
//! **Shapes.** Longitudinal lines (dashes and solid pieces) are *bands* in the road frame:
//! `s0 ≤ s ≤ s1`, `|d − d(s)| ≤ w/2`, with `d(s)` quadratic so lines can taper apart at a
//! gore. Everything else (arrows, stop lines, crosswalk stripes, guideline stripes, diamonds,
//! glyphs) is a planar polygon in local (x, y), optionally with a hole (hollow diamond, the
//! glyph "0"), as paint is laid with stencils. A point is paint of marking k when it lies in
//! the shape (bands test in (s, d), polygons in (x, y)); the truth outline of a band is its
//! two edges sampled every ≤ 1 m, which follows an arc of radius 60 m within 2 mm.
//!
//! **Dimensions** come from a [`Standard`]: China GB 5768 (lanes 3.5–3.75 m, dashes 6/9 m on
//! highways and 2/4 m in towns, 0.15 m lines, 0.20 m edge lines, 0.45 m zebra stripes with
//! 0.6 m gaps, 6 m / 9 m arrows) or US MUTCD (12 ft lanes, 10 ft / 30 ft dashes, 4–6 in
//! lines, 24 in crosswalk bars).
//!
//! **Truth.** `length_m`/`width_m` are the extents along/across the shape's own axis (for a
//! band: the painted length along the line and its width); `heading_deg` is that axis,
//! clockwise from north: lines point towards increasing survey mileage, arrows the way they
//! point traffic (shaft tail to head), stop lines and crosswalk stripes along their long side.
//!
//! Complexity: lookup O(markings in a 1 m station bucket) per ground point.

use super::road::Road;
use crate::pipeline::types::{Crs, Extraction, LaneLine, LaneLineClass, Marking, MarkingClass};

/// A quadratic offset `d(s) = c0 + c1 (s − sr) + c2 (s − sr)²`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Quad {
    pub sr: f64,
    pub c0: f64,
    pub c1: f64,
    pub c2: f64,
}

impl Quad {
    pub fn constant(d: f64) -> Quad {
        Quad {
            sr: 0.0,
            c0: d,
            c1: 0.0,
            c2: 0.0,
        }
    }

    pub fn at(&self, s: f64) -> f64 {
        let u = s - self.sr;
        self.c0 + u * (self.c1 + u * self.c2)
    }

    /// The same curve shifted sideways by `dd`.
    pub fn shifted(&self, dd: f64) -> Quad {
        Quad {
            c0: self.c0 + dd,
            ..*self
        }
    }
}

/// Paint colour (yellow paint reflects a little less at 1550 nm).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Colour {
    White,
    Yellow,
}

/// Where the paint of a marking is.
#[derive(Clone, Debug)]
pub enum Paint {
    Band {
        s0: f64,
        s1: f64,
        d: Quad,
        half_w: f64,
    },
    Poly {
        ring: Vec<[f64; 2]>,
        hole: Option<Vec<[f64; 2]>>,
        bbox: [f64; 4],
    },
}

/// One painted object of a scene.
#[derive(Clone, Debug)]
pub struct MarkingDef {
    pub class: MarkingClass,
    pub paint: Paint,
    pub colour: Colour,
    /// Extra wear of this marking, 0 (fresh) ..1 (gone), added to the scene's wear.
    pub wear: f64,
    /// For polygons: length and width along their own axis and the axis' math angle (rad).
    pub dims: Option<(f64, f64, f64)>,
}

/// Centreline of a lane line.
#[derive(Clone, Debug)]
pub enum LanePath {
    /// Along the road at offset `d(s)` from `s0` to `s1`.
    Road { d: Quad, s0: f64, s1: f64 },
    /// A polyline in local (x, y) (lines of a side street).
    Poly(Vec<[f64; 2]>),
}

/// One lane line through its member markings.
#[derive(Clone, Debug)]
pub struct LaneLineDef {
    pub class: LaneLineClass,
    pub path: LanePath,
    pub members: Vec<usize>,
}

/// Marking dimensions of a national standard.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Standard {
    pub name: &'static str,
    pub lane_w_highway: f64,
    pub lane_w_urban: f64,
    /// (paint, gap) of dashed lane lines.
    pub dash_highway: (f64, f64),
    pub dash_urban: (f64, f64),
    pub line_w_highway: f64,
    pub line_w_urban: f64,
    pub edge_w: f64,
    pub arrow_len_highway: f64,
    pub arrow_len_urban: f64,
    /// (stripe width, gap) of zebra crossings.
    pub zebra: (f64, f64),
    pub stop_w: f64,
    /// (length, width, line width) of the diamond.
    pub diamond: (f64, f64, f64),
    /// (stripe width, spacing along the road) of gore guidelines.
    pub guideline: (f64, f64),
}

impl Standard {
    /// China, GB 5768.3.
    pub const GB: Standard = Standard {
        name: "gb",
        lane_w_highway: 3.75,
        lane_w_urban: 3.5,
        dash_highway: (6.0, 9.0),
        dash_urban: (2.0, 4.0),
        line_w_highway: 0.15,
        line_w_urban: 0.15,
        edge_w: 0.20,
        arrow_len_highway: 9.0,
        arrow_len_urban: 6.0,
        zebra: (0.45, 0.6),
        stop_w: 0.3,
        diamond: (3.0, 1.5, 0.2),
        guideline: (0.45, 2.5),
    };

    /// United States, MUTCD (feet converted to metres).
    pub const MUTCD: Standard = Standard {
        name: "mutcd",
        lane_w_highway: 3.6576,
        lane_w_urban: 3.6576,
        dash_highway: (3.048, 9.144),
        dash_urban: (3.048, 9.144),
        line_w_highway: 0.1524,
        line_w_urban: 0.1016,
        edge_w: 0.1524,
        arrow_len_highway: 7.3152,
        arrow_len_urban: 3.6576,
        zebra: (0.6096, 0.6096),
        stop_w: 0.4572,
        diamond: (3.6576, 1.2192, 0.1524),
        guideline: (0.3048, 3.0),
    };

    pub fn parse(s: &str) -> Option<Standard> {
        match s {
            "gb" => Some(Self::GB),
            "mutcd" => Some(Self::MUTCD),
            _ => None,
        }
    }
}

/// Arrow types (their class follows).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ArrowKind {
    Straight,
    Left,
    Right,
    StraightLeft,
    StraightRight,
}

impl ArrowKind {
    pub fn class(self) -> MarkingClass {
        match self {
            ArrowKind::Straight => MarkingClass::StraightArrow,
            ArrowKind::Left => MarkingClass::LeftArrow,
            ArrowKind::Right => MarkingClass::RightArrow,
            ArrowKind::StraightLeft => MarkingClass::StraightLeftArrow,
            ArrowKind::StraightRight => MarkingClass::StraightRightArrow,
        }
    }
}

fn bbox(ring: &[[f64; 2]]) -> [f64; 4] {
    let mut b = [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY];
    for p in ring {
        b[0] = b[0].min(p[0]);
        b[1] = b[1].min(p[1]);
        b[2] = b[2].max(p[0]);
        b[3] = b[3].max(p[1]);
    }
    b
}

/// Even-odd point-in-polygon test.
pub fn point_in_ring(ring: &[[f64; 2]], x: f64, y: f64) -> bool {
    let mut inside = false;
    let n = ring.len();
    let mut j = n - 1;
    for i in 0..n {
        let (a, b) = (ring[i], ring[j]);
        if (a[1] > y) != (b[1] > y) && x < (b[0] - a[0]) * (y - a[1]) / (b[1] - a[1]) + a[0] {
            inside = !inside;
        }
        j = i;
    }
    inside
}

/// A local planar frame for stencilled shapes: origin and unit axes u (forward), v (left).
#[derive(Clone, Copy, Debug)]
pub struct Frame2 {
    pub o: [f64; 2],
    pub u: [f64; 2],
    pub v: [f64; 2],
}

impl Frame2 {
    /// Frame at road station (s, d); `dir` = +1 along increasing s, −1 against it.
    pub fn at(road: &Road, s: f64, d: f64, dir: f64) -> Frame2 {
        let (t, n) = road.frame(s);
        Frame2 {
            o: road.to_xy(s, d),
            u: [t[0] * dir, t[1] * dir],
            v: [n[0] * dir, n[1] * dir],
        }
    }

    /// The frame turned by `angle` (rad, counter-clockwise).
    pub fn rotated(&self, angle: f64) -> Frame2 {
        let (sn, cs) = angle.sin_cos();
        let u = [cs * self.u[0] + sn * self.v[0], cs * self.u[1] + sn * self.v[1]];
        Frame2 {
            o: self.o,
            u,
            v: [-u[1], u[0]],
        }
    }

    pub fn map(&self, p: [f64; 2]) -> [f64; 2] {
        [
            self.o[0] + p[0] * self.u[0] + p[1] * self.v[0],
            self.o[1] + p[0] * self.u[1] + p[1] * self.v[1],
        ]
    }

    pub fn angle(&self) -> f64 {
        self.u[1].atan2(self.u[0])
    }
}

fn poly_marking(
    class: MarkingClass,
    frame: &Frame2,
    ring_uv: &[[f64; 2]],
    hole_uv: Option<&[[f64; 2]]>,
) -> MarkingDef {
    let ring: Vec<[f64; 2]> = ring_uv.iter().map(|&p| frame.map(p)).collect();
    let b = bbox(ring_uv);
    MarkingDef {
        class,
        paint: bbox_paint(ring, hole_uv.map(|h| h.iter().map(|&p| frame.map(p)).collect())),
        colour: Colour::White,
        wear: 0.0,
        dims: Some((b[2] - b[0], b[3] - b[1], frame.angle())),
    }
}

fn bbox_paint(ring: Vec<[f64; 2]>, hole: Option<Vec<[f64; 2]>>) -> Paint {
    Paint::Poly {
        bbox: bbox(&ring),
        ring,
        hole,
    }
}

/// A rectangle `len × wid` centred at the frame origin, long axis along u.
pub fn rect(class: MarkingClass, frame: &Frame2, len: f64, wid: f64) -> MarkingDef {
    let (a, b) = (0.5 * len, 0.5 * wid);
    poly_marking(class, frame, &[[-a, -b], [a, -b], [a, b], [-a, b]], None)
}

/// Outline of a polyline of width `w` with miter joins, ending in an arrow head
/// (`head_len` long, `head_w` wide) in the last segment's direction; starts at the right
/// edge of the tail and runs counter-clockwise. Returns the ring.
fn stroke_with_head(pts: &[[f64; 2]], w: f64, head: Option<(f64, f64)>) -> Vec<[f64; 2]> {
    let n = pts.len();
    let dirs: Vec<[f64; 2]> = pts
        .windows(2)
        .map(|p| {
            let (dx, dy) = (p[1][0] - p[0][0], p[1][1] - p[0][1]);
            let l = dx.hypot(dy);
            [dx / l, dy / l]
        })
        .collect();
    let h = 0.5 * w;
    // Offset vertex i on side `side` (+1 left, −1 right) with a miter join.
    let off = |i: usize, side: f64| -> [f64; 2] {
        let nrm = |d: [f64; 2]| [-d[1], d[0]];
        let m = if i == 0 {
            nrm(dirs[0])
        } else if i == n - 1 {
            nrm(dirs[n - 2])
        } else {
            let (a, b) = (nrm(dirs[i - 1]), nrm(dirs[i]));
            let s = [a[0] + b[0], a[1] + b[1]];
            let l = s[0] * a[0] + s[1] * a[1]; // = 1 + cos(turn)
            [s[0] / l, s[1] / l]
        };
        [pts[i][0] + side * h * m[0], pts[i][1] + side * h * m[1]]
    };
    let mut ring: Vec<[f64; 2]> = (0..n).map(|i| off(i, -1.0)).collect();
    if let Some((hl, hw)) = head {
        let d = dirs[n - 2];
        let nr = [-d[1], d[0]];
        let e = pts[n - 1];
        ring.push([e[0] - 0.5 * hw * nr[0], e[1] - 0.5 * hw * nr[1]]);
        ring.push([e[0] + hl * d[0], e[1] + hl * d[1]]);
        ring.push([e[0] + 0.5 * hw * nr[0], e[1] + 0.5 * hw * nr[1]]);
    }
    ring.extend((0..n).rev().map(|i| off(i, 1.0)));
    ring
}

/// An arrow of total length `len` (tail at u = 0, pointing to +u) in `frame`.
pub fn arrow(kind: ArrowKind, frame: &Frame2, len: f64) -> MarkingDef {
    let k = len / 6.0;
    let (w, hl, hw) = (0.25 * k.sqrt().max(0.6), 1.9 * k, 0.75 * k.sqrt().max(0.6) * 1.0);
    let hw = hw.max(3.0 * w);
    // A turning branch: 45° away from the shaft, then (nearly) square to it.
    let branch = |side: f64, j: f64| -> Vec<[f64; 2]> {
        let c = std::f64::consts::FRAC_1_SQRT_2;
        let a = 1.0 * k;
        let b = 0.2 * k;
        vec![
            [j, 0.0],
            [j + a * c, side * a * c],
            [j + a * c + 0.15 * b, side * (a * c + b)],
        ]
    };
    let ring = match kind {
        ArrowKind::Straight => stroke_with_head(&[[0.0, 0.0], [len - hl, 0.0]], w, Some((hl, hw))),
        ArrowKind::Left | ArrowKind::Right => {
            let side = if kind == ArrowKind::Left { 1.0 } else { -1.0 };
            let mut pts = vec![[0.0, 0.0]];
            pts.extend(branch(1.0, 0.55 * len));
            let r = stroke_with_head(&pts, w, Some((0.45 * hl, hw)));
            if side < 0.0 { mirror_ring(&r) } else { r }
        }
        ArrowKind::StraightLeft | ArrowKind::StraightRight => {
            let side = if kind == ArrowKind::StraightLeft {
                1.0
            } else {
                -1.0
            };
            let main = stroke_with_head(&[[0.0, 0.0], [len - hl, 0.0]], w, Some((hl, hw)));
            let j = 0.3 * len;
            let br = stroke_with_head(&branch(1.0, j), w, Some((0.45 * hl, hw)));
            let ring = union_branch(&main, &br, w, j);
            if side < 0.0 { mirror_ring(&ring) } else { ring }
        }
    };
    poly_marking(kind.class(), frame, &ring, None)
}

/// Mirror across the u axis, keeping counter-clockwise order.
fn mirror_ring(r: &[[f64; 2]]) -> Vec<[f64; 2]> {
    r.iter().rev().map(|p| [p[0], -p[1]]).collect()
}

/// Union of a straight arrow ring (right edge first, CCW) and a left branch stroke leaving
/// the shaft at u = j at 45°: walk the main ring, and on the shaft's left edge detour
/// around the branch.
fn union_branch(main: &[[f64; 2]], br: &[[f64; 2]], w: f64, j: f64) -> Vec<[f64; 2]> {
    let h = 0.5 * w;
    let c = std::f64::consts::FRAC_1_SQRT_2;
    // Branch edges meet the shaft's left edge (v = h) at these u (see the module docs).
    let u_front = j + h * (1.0 + 2.0 * c); // right edge of the branch (faces forward)
    let u_back = j + h * (1.0 - 2.0 * c); // left edge of the branch
    // The branch ring: right-edge vertices, head, left-edge vertices (reversed); drop the
    // tail vertices (index 0 and last), which lie inside the shaft.
    let inner = &br[1..br.len() - 1];
    let mut out = Vec::with_capacity(main.len() + inner.len() + 2);
    // Main ring: [tail right, end right, head.., end left, tail left].
    let m = main.len();
    out.extend_from_slice(&main[..m - 1]); // up to the end of the left edge (near the head)
    out.push([u_front, h]);
    out.extend_from_slice(inner);
    out.push([u_back, h]);
    out.push(main[m - 1]);
    out
}

/// Hollow diamond: outer rhombus `len × wid`, paint band `line_w` wide.
pub fn diamond(frame: &Frame2, len: f64, wid: f64, line_w: f64) -> MarkingDef {
    let (a, b) = (0.5 * len, 0.5 * wid);
    let outer = [[-a, 0.0], [0.0, -b], [a, 0.0], [0.0, b]];
    // Inner rhombus: edges moved inwards by line_w.
    let l = a.hypot(b);
    let (ai, bi) = (a - line_w * l / b, b - line_w * l / a);
    let inner = [[-ai, 0.0], [0.0, -bi], [ai, 0.0], [0.0, bi]];
    poly_marking(MarkingClass::Diamond, frame, &outer, Some(&inner))
}

/// Painted glyphs of unknown class (speed numbers): "7" as a stroke, "0" hollow.
pub fn glyph(ch: char, frame: &Frame2, height: f64) -> MarkingDef {
    let w = 0.05 * height + 0.05;
    let gw = 0.3 * height; // glyph width (across the road)
    match ch {
        '7' => {
            // Read by a driver: the top of the glyph is farther along u.
            let ring = stroke_with_head(
                &[
                    [0.0, 0.1 * gw],
                    [height - 0.5 * w, -0.5 * gw],
                    [height - 0.5 * w, 0.5 * gw],
                ],
                w,
                None,
            );
            poly_marking(MarkingClass::Unknown, frame, &ring, None)
        }
        _ => {
            let (a, b) = (0.5 * height, 0.5 * gw);
            let outer = [[0.0, -b], [2.0 * a, -b], [2.0 * a, b], [0.0, b]];
            let inner = [
                [w, -b + w],
                [2.0 * a - w, -b + w],
                [2.0 * a - w, b - w],
                [w, b - w],
            ];
            poly_marking(MarkingClass::Unknown, frame, &outer, Some(&inner))
        }
    }
}

/// A band marking (dash or solid piece).
pub fn band(class: MarkingClass, s0: f64, s1: f64, d: Quad, width: f64, colour: Colour) -> MarkingDef {
    MarkingDef {
        class,
        paint: Paint::Band {
            s0,
            s1,
            d,
            half_w: 0.5 * width,
        },
        colour,
        wear: 0.0,
        dims: None,
    }
}

/// Accumulates markings and lane lines of a scene.
#[derive(Default)]
pub struct MarkingSet {
    pub markings: Vec<MarkingDef>,
    pub lane_lines: Vec<LaneLineDef>,
}

impl MarkingSet {
    pub fn add(&mut self, m: MarkingDef) -> usize {
        self.markings.push(m);
        self.markings.len() - 1
    }

    /// A solid lane line from s0 to s1.
    pub fn solid(&mut self, s0: f64, s1: f64, d: Quad, width: f64, colour: Colour) {
        if s1 - s0 < 0.5 {
            return; // nothing left of it within the painted stretch
        }
        let i = self.add(band(MarkingClass::SolidLine, s0, s1, d, width, colour));
        self.lane_lines.push(LaneLineDef {
            class: LaneLineClass::SolidLine,
            path: LanePath::Road { d, s0, s1 },
            members: vec![i],
        });
    }

    /// A dashed lane line: dashes of `paint` m every `paint + gap` m measured along the
    /// painted line itself (so dashes on curves keep their length), the first starting at
    /// `s0 + phase`, only whole dashes before `s1`.
    /// `span` = (s0, s1), `pattern` = (paint, gap, phase).
    pub fn dashed(&mut self, road: &Road, span: (f64, f64), d: Quad, width: f64, pattern: (f64, f64, f64)) {
        let (s0, s1) = span;
        let (paint, gap, phase) = pattern;
        let mut members = Vec::new();
        let mut s = advance(road, &d, s0, phase.rem_euclid(paint + gap));
        let mut first = f64::NAN;
        let mut last = f64::NAN;
        loop {
            let e = advance(road, &d, s, paint);
            if e > s1 + 1e-9 {
                break;
            }
            members.push(self.add(band(MarkingClass::DashedLine, s, e, d, width, Colour::White)));
            if first.is_nan() {
                first = s;
            }
            last = e;
            s = advance(road, &d, e, gap);
        }
        if !members.is_empty() {
            self.lane_lines.push(LaneLineDef {
                class: LaneLineClass::DashedLine,
                path: LanePath::Road {
                    d,
                    s0: first,
                    s1: last,
                },
                members,
            });
        }
    }
}

/// The station reached after `dist` metres along the curve d(s) from station `s`.
pub fn advance(road: &Road, d: &Quad, s: f64, dist: f64) -> f64 {
    let step = 0.25;
    let mut acc = 0.0;
    let mut cur = s;
    let mut p = road.to_xy(cur, d.at(cur));
    loop {
        let nx = cur + step;
        let q = road.to_xy(nx, d.at(nx));
        let l = (q[0] - p[0]).hypot(q[1] - p[1]);
        if acc + l >= dist {
            return cur + step * (dist - acc) / l;
        }
        acc += l;
        cur = nx;
        p = q;
    }
}

impl MarkingSet {
    /// A straight solid line from `a` to `b` (local xy) as one polygon and one lane line.
    pub fn solid_xy(&mut self, a: [f64; 2], b: [f64; 2], width: f64, colour: Colour) {
        let (f, len) = seg_frame(a, b);
        let mut m = rect(MarkingClass::SolidLine, &f, len, width);
        m.colour = colour;
        let i = self.add(m);
        self.lane_lines.push(LaneLineDef {
            class: LaneLineClass::SolidLine,
            path: LanePath::Poly(vec![a, b]),
            members: vec![i],
        });
    }

    /// A straight dashed line from `a` to `b` (local xy), first dash at `a`.
    pub fn dashed_xy(&mut self, a: [f64; 2], b: [f64; 2], width: f64, paint: f64, gap: f64) {
        let (f, len) = seg_frame(a, b);
        let mut members = Vec::new();
        let mut u = 0.0;
        let mut end = 0.0;
        while u + paint <= len + 1e-9 {
            let c = f.map([u + 0.5 * paint - 0.5 * len, 0.0]);
            let fd = Frame2 { o: c, ..f };
            members.push(self.add(rect(MarkingClass::DashedLine, &fd, paint, width)));
            end = u + paint;
            u += paint + gap;
        }
        if !members.is_empty() {
            let e = f.map([end - 0.5 * len, 0.0]);
            self.lane_lines.push(LaneLineDef {
                class: LaneLineClass::DashedLine,
                path: LanePath::Poly(vec![a, e]),
                members,
            });
        }
    }
}

/// Frame centred between `a` and `b` with u from a to b; and the distance.
fn seg_frame(a: [f64; 2], b: [f64; 2]) -> (Frame2, f64) {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len = dx.hypot(dy);
    let u = [dx / len, dy / len];
    (
        Frame2 {
            o: [0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1])],
            u,
            v: [-u[1], u[0]],
        },
        len,
    )
}

/// Fast paint lookup: markings bucketed by station (1 m buckets).
pub struct MarkingIndex {
    s_min: f64,
    buckets: Vec<Vec<u32>>,
}

impl MarkingIndex {
    pub fn new(road: &Road, markings: &[MarkingDef], s_min: f64, s_max: f64) -> MarkingIndex {
        let nb = ((s_max - s_min).ceil() as usize).max(1);
        let mut buckets = vec![Vec::new(); nb];
        for (i, m) in markings.iter().enumerate() {
            let (lo, hi) = match &m.paint {
                Paint::Band { s0, s1, .. } => (*s0, *s1),
                Paint::Poly { ring, .. } => ring.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |acc, p| {
                    let (s, _) = road.to_sd(p[0], p[1]);
                    (acc.0.min(s), acc.1.max(s))
                }),
            };
            let a = ((lo - 0.5 - s_min).floor().max(0.0)) as usize;
            let b = (hi + 0.5 - s_min).floor();
            if b < 0.0 {
                continue;
            }
            for bk in buckets.iter_mut().take((b as usize + 1).min(nb)).skip(a) {
                bk.push(i as u32);
            }
        }
        MarkingIndex { s_min, buckets }
    }

    /// Index of the marking whose shape contains the ground point (road frame and local xy).
    pub fn lookup(&self, markings: &[MarkingDef], s: f64, d: f64, x: f64, y: f64) -> Option<usize> {
        let b = (s - self.s_min).floor();
        if b < 0.0 || b as usize >= self.buckets.len() {
            return None;
        }
        for &i in &self.buckets[b as usize] {
            let m = &markings[i as usize];
            let inside = match &m.paint {
                Paint::Band { s0, s1, d: q, half_w } => {
                    s >= *s0 && s <= *s1 && (d - q.at(s)).abs() <= *half_w
                }
                Paint::Poly { ring, hole, bbox } => {
                    x >= bbox[0]
                        && x <= bbox[2]
                        && y >= bbox[1]
                        && y <= bbox[3]
                        && point_in_ring(ring, x, y)
                        && !hole.as_ref().is_some_and(|h| point_in_ring(h, x, y))
                }
            };
            if inside {
                return Some(i as usize);
            }
        }
        None
    }
}

/// Keep only the markings with `counts[i] > 0` (the ones the survey saw): returns the kept
/// markings, their counts, the lane lines restricted to kept members (their centreline
/// clipped to the kept members' extent; lane lines left empty are dropped), and the map
/// old index → new index.
pub fn keep_seen(
    markings: &[MarkingDef],
    lanes: &[LaneLineDef],
    counts: &[u64],
) -> (Vec<MarkingDef>, Vec<u64>, Vec<LaneLineDef>, Vec<Option<usize>>) {
    let mut map = vec![None; markings.len()];
    let mut kept = Vec::new();
    let mut kept_counts = Vec::new();
    for (i, m) in markings.iter().enumerate() {
        if counts[i] > 0 {
            map[i] = Some(kept.len());
            kept.push(m.clone());
            kept_counts.push(counts[i]);
        }
    }
    let mut out = Vec::new();
    for l in lanes {
        let members: Vec<usize> = l.members.iter().filter(|&&k| map[k].is_some()).copied().collect();
        if members.is_empty() {
            continue;
        }
        let path = match &l.path {
            LanePath::Road { d, .. } => {
                let (mut a, mut b) = (f64::INFINITY, f64::NEG_INFINITY);
                for &k in &members {
                    if let Paint::Band { s0, s1, .. } = markings[k].paint {
                        a = a.min(s0);
                        b = b.max(s1);
                    }
                }
                LanePath::Road { d: *d, s0: a, s1: b }
            }
            LanePath::Poly(p) if p.len() == 2 => {
                let (o, e) = (p[0], p[1]);
                let len = (e[0] - o[0]).hypot(e[1] - o[1]);
                let u = [(e[0] - o[0]) / len, (e[1] - o[1]) / len];
                let (mut a, mut b) = (f64::INFINITY, f64::NEG_INFINITY);
                for &k in &members {
                    if let Paint::Poly { ring, .. } = &markings[k].paint {
                        for q in ring {
                            let t = (q[0] - o[0]) * u[0] + (q[1] - o[1]) * u[1];
                            a = a.min(t);
                            b = b.max(t);
                        }
                    }
                }
                let at = |t: f64| [o[0] + t * u[0], o[1] + t * u[1]];
                LanePath::Poly(vec![at(a.max(0.0)), at(b.min(len))])
            }
            other => other.clone(),
        };
        out.push(LaneLineDef {
            class: l.class,
            path,
            members: members.iter().map(|&k| map[k].expect("kept")).collect(),
        });
    }
    (kept, kept_counts, out, map)
}

/// Stations at which to sample a curve from s0 to s1: every ≤ 1 m, ends exact.
fn stations(s0: f64, s1: f64) -> Vec<f64> {
    let n = ((s1 - s0) / 1.0).ceil().max(1.0) as usize;
    (0..=n).map(|i| s0 + (s1 - s0) * i as f64 / n as f64).collect()
}

fn polyline_len(p: &[[f64; 2]]) -> f64 {
    p.windows(2)
        .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
        .sum()
}

/// Math angle (rad) → degrees clockwise from north in [0, 360).
pub fn compass_deg(angle: f64) -> f64 {
    (90.0 - angle.to_degrees()).rem_euclid(360.0)
}

/// The truth in the contract's types; `origin` is added to every coordinate.
pub fn truth(
    road: &Road,
    markings: &[MarkingDef],
    lanes: &[LaneLineDef],
    counts: &[u64],
    origin: [f64; 3],
    crs: Crs,
) -> Extraction {
    let abs = |p: [f64; 2]| [p[0] + origin[0], p[1] + origin[1]];
    let out_markings = markings
        .iter()
        .enumerate()
        .map(|(i, m)| {
            let (outline, length_m, width_m, angle) = match &m.paint {
                Paint::Band { s0, s1, d, half_w } => {
                    let st = stations(*s0, *s1);
                    let centre: Vec<[f64; 2]> = st.iter().map(|&s| road.to_xy(s, d.at(s))).collect();
                    let mut ring: Vec<[f64; 2]> =
                        st.iter().map(|&s| road.to_xy(s, d.at(s) - half_w)).collect();
                    ring.extend(st.iter().rev().map(|&s| road.to_xy(s, d.at(s) + half_w)));
                    let sm = 0.5 * (s0 + s1);
                    let a = road.to_xy(sm - 0.05, d.at(sm - 0.05));
                    let b = road.to_xy(sm + 0.05, d.at(sm + 0.05));
                    let angle = (b[1] - a[1]).atan2(b[0] - a[0]);
                    (ring, polyline_len(&centre), 2.0 * half_w, angle)
                }
                Paint::Poly { ring, .. } => {
                    let (l, w, a) = m.dims.unwrap_or((0.0, 0.0, 0.0));
                    (ring.clone(), l, w, a)
                }
            };
            Marking {
                id: format!("m{}", i + 1),
                class: m.class,
                outline: outline.into_iter().map(abs).collect(),
                confidence: 1.0,
                length_m,
                width_m,
                heading_deg: compass_deg(angle),
                point_count: counts.get(i).copied().unwrap_or(0) as usize,
            }
        })
        .collect();
    let lane_lines = lanes
        .iter()
        .enumerate()
        .map(|(i, l)| {
            let line: Vec<[f64; 2]> = match &l.path {
                LanePath::Road { d, s0, s1 } => stations(*s0, *s1)
                    .iter()
                    .map(|&s| road.to_xy(s, d.at(s)))
                    .collect(),
                LanePath::Poly(p) => p.clone(),
            };
            LaneLine {
                id: format!("l{}", i + 1),
                class: l.class,
                length_m: polyline_len(&line),
                line: line.into_iter().map(abs).collect(),
                confidence: 1.0,
                marking_ids: l.members.iter().map(|k| format!("m{}", k + 1)).collect(),
            }
        })
        .collect();
    Extraction {
        markings: out_markings,
        lane_lines,
        crs: Some(crs),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::road::Segment;

    fn ring_area(r: &[[f64; 2]]) -> f64 {
        let n = r.len();
        (0..n)
            .map(|i| {
                let (a, b) = (r[i], r[(i + 1) % n]);
                a[0] * b[1] - b[0] * a[1]
            })
            .sum::<f64>()
            * 0.5
    }

    fn simple(r: &[[f64; 2]]) -> bool {
        // No two non-adjacent edges cross.
        let n = r.len();
        let cross = |p: [f64; 2], q: [f64; 2], a: [f64; 2], b: [f64; 2]| {
            let o = |a: [f64; 2], b: [f64; 2], c: [f64; 2]| {
                (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
            };
            o(p, q, a) * o(p, q, b) < 0.0 && o(a, b, p) * o(a, b, q) < 0.0
        };
        for i in 0..n {
            for j in i + 2..n {
                if i == 0 && j == n - 1 {
                    continue;
                }
                if cross(r[i], r[(i + 1) % n], r[j], r[(j + 1) % n]) {
                    return false;
                }
            }
        }
        true
    }

    #[test]
    fn arrows_are_simple_ccw_polygons_of_the_right_length() {
        let road = Road::new([0.0, 0.0], 0.0, &[Segment::Straight { len_m: 50.0 }], 0.0, 0.0);
        let f = Frame2::at(&road, 10.0, 0.0, 1.0);
        for kind in [
            ArrowKind::Straight,
            ArrowKind::Left,
            ArrowKind::Right,
            ArrowKind::StraightLeft,
            ArrowKind::StraightRight,
        ] {
            for len in [6.0, 9.0] {
                let m = arrow(kind, &f, len);
                let Paint::Poly { ring, .. } = &m.paint else {
                    panic!()
                };
                assert!(ring_area(ring) > 0.0, "{kind:?} must be counter-clockwise");
                assert!(simple(ring), "{kind:?} self-intersects: {ring:?}");
                let (l, _, _) = m.dims.unwrap();
                if matches!(
                    kind,
                    ArrowKind::Straight | ArrowKind::StraightLeft | ArrowKind::StraightRight
                ) {
                    assert!((l - len).abs() < 1e-9, "{kind:?} {l}");
                } else {
                    assert!(l > 0.6 * len && l < len, "{kind:?} {l}");
                }
            }
        }
        // The tip of a straight arrow is paint, a point beside the shaft is not.
        let m = arrow(ArrowKind::Straight, &f, 6.0);
        let Paint::Poly { ring, .. } = &m.paint else {
            panic!()
        };
        assert!(point_in_ring(ring, 10.0 + 5.9, 0.0));
        assert!(!point_in_ring(ring, 10.0 + 2.0, 0.3));
    }

    #[test]
    fn dashes_and_lane_lines() {
        let mut set = MarkingSet::default();
        let straight = Road::new([0.0, 0.0], 0.3, &[Segment::Straight { len_m: 200.0 }], 0.0, 0.0);
        set.dashed(
            &straight,
            (0.0, 100.0),
            Quad::constant(-1.875),
            0.15,
            (6.0, 9.0, 2.0),
        );
        assert_eq!(set.markings.len(), 7); // 2, 17, ..., 92 (ends at 98)
        let LanePath::Road { s0, s1, .. } = set.lane_lines[0].path else {
            panic!()
        };
        assert!((s0 - 2.0).abs() < 1e-9 && (s1 - 98.0).abs() < 1e-9);
        let road = Road::new(
            [0.0, 0.0],
            0.3,
            &[Segment::Arc {
                len_m: 200.0,
                radius_m: 80.0,
            }],
            0.0,
            0.0,
        );
        let mut set = MarkingSet::default();
        set.dashed(&road, (0.0, 100.0), Quad::constant(-1.875), 0.15, (6.0, 9.0, 2.0));
        let ex = truth(
            &road,
            &set.markings,
            &set.lane_lines,
            &[5; 7],
            [231000.0, 3380000.0, 0.0],
            Crs::epsg(32650),
        );
        let m = &ex.markings[0];
        // Painted length is measured along the line itself, even on an arc.
        assert!((m.length_m - 6.0).abs() < 1e-3, "{}", m.length_m);
        assert!((m.width_m - 0.15).abs() < 1e-12);
        assert_eq!(ex.lane_lines[0].marking_ids.len(), set.markings.len());
        assert!(m.outline[0][0] > 231000.0 && m.outline[0][1] > 3380000.0 - 100.0);
    }

    #[test]
    fn diamond_is_hollow() {
        let road = Road::new([0.0, 0.0], 0.0, &[Segment::Straight { len_m: 50.0 }], 0.0, 0.0);
        let f = Frame2::at(&road, 10.0, 0.0, 1.0);
        let m = diamond(&f, 3.0, 1.5, 0.2);
        let idx = MarkingIndex::new(&road, std::slice::from_ref(&m), -10.0, 60.0);
        let ms = [m];
        assert_eq!(idx.lookup(&ms, 10.0, 0.0, 10.0, 0.0), None, "centre is not paint");
        assert_eq!(
            idx.lookup(&ms, 11.4, 0.0, 11.4, 0.0),
            Some(0),
            "near the tip is paint"
        );
    }
}
