//! Scene definitions: road, cross-sections, markings, objects, pavement features, drive.
//!
//! | scene | road | what makes it hard |
//! |---|---|---|
//! | `highway` | 2 × 4 lanes, straight then a gentle arc (R 900 m), 1.2 % grade | far carriageway 17–26 m away, 6/9 m dashes, exit ramp with a diverging edge line and a gore of 45° guidelines, arrows, a diamond, a speed glyph, moving cars, a car on the shoulder |
//! | `urban_intersection` | 2 × 3 lanes, crossing street, curbs, sidewalks | 2/4 m dashes turning solid before stop lines, zebra crossings on all arms, every arrow type, parked cars over the edge lines, tree canopies over the kerb lanes, façades, manholes, sealant |
//! | `curved_ramp` | viaduct ramp, R 90 m right turn, 3.5 % grade, 4 % superelevation | tight curvature, lane split with a gore, barriers, ground far below |
//! | `dual_head` | the urban layout scanned by two butterfly heads | interleaved heads, gain differences, oblique scan lines |
//! | `worn` | the urban layout, old grey asphalt | heavy patchy wear and gaps, low contrast, many distractors |
//!
//! Every scene is laid out for any drive length (`length_m`); repeating elements (arrows,
//! manholes, trees, buildings) fill the whole length. All randomness comes from the seed.

use super::drive::Drive;
use super::intensity::{Reflectance, SurfaceFeature};
use super::markings::{ArrowKind, Colour, Frame2, MarkingSet, Quad, Standard, arrow, diamond, glyph, rect};
use super::objects::{CarSize, MovingCar, ObjKind, Object, Shape3, car_boxes};
use super::road::{Material, Profile, Road, Segment};
use super::scanner::Head;
use super::surface::ProfileFn;
use crate::pipeline::types::MarkingClass;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::FRAC_PI_2;

/// Names of the built-in scenes.
pub const SCENES: [&str; 5] = [
    "highway",
    "urban_intersection",
    "curved_ramp",
    "dual_head",
    "worn",
];

/// Absolute coordinates (EPSG:32650) of the local origin.
pub const ORIGIN: [f64; 3] = [231_150.0, 3_380_080.0, 0.0];

/// What the user chose.
#[derive(Clone, Debug)]
pub struct SceneOptions {
    pub seed: u64,
    /// Drive length (m); the scene's default when `None`.
    pub length_m: Option<f64>,
    pub standard: Standard,
    /// Number of heads (1 or 2); the scene's default when `None`.
    pub heads: Option<usize>,
}

/// A complete scene, ready to be scanned.
pub struct Scene {
    pub name: String,
    pub road: Road,
    pub profile: Box<ProfileFn>,
    pub marks: MarkingSet,
    pub objects: Vec<Object>,
    pub moving: Vec<MovingCar>,
    pub refl: Reflectance,
    pub drive: Drive,
    pub heads: Vec<Head>,
    pub origin: [f64; 3],
    /// Stations covered by indices (the drive plus the scanner's reach).
    pub s_range: (f64, f64),
}

/// Build a scene by name.
pub fn build(name: &str, opt: &SceneOptions) -> Result<Scene, String> {
    let mut rng = ChaCha8Rng::seed_from_u64(opt.seed ^ 0x5EED_0F5C_E4E5);
    let mut scene = match name {
        "highway" => highway(opt, &mut rng),
        "urban_intersection" => urban(name, opt, &mut rng, UrbanStyle::Normal),
        "dual_head" => urban(name, opt, &mut rng, UrbanStyle::DualHead),
        "worn" => urban(name, opt, &mut rng, UrbanStyle::Worn),
        "curved_ramp" => ramp(opt, &mut rng),
        _ => {
            return Err(format!("unknown scene '{name}' (known: {})", SCENES.join(", ")));
        }
    };
    if let Some(h) = opt.heads {
        scene.heads = match h {
            1 => Head::single(),
            2 => Head::butterfly(),
            _ => return Err(format!("--heads must be 1 or 2, got {h}")),
        };
    }
    Ok(scene)
}

fn uniform(rng: &mut ChaCha8Rng, a: f64, b: f64) -> f64 {
    rng.random_range(a..b)
}

/// Buildings along one side: boxes with their façade at |d| = `face` (± 1 m), gaps between,
/// skipped where `skip(s)` (intersections).
fn buildings(
    road: &Road,
    rng: &mut ChaCha8Rng,
    range: (f64, f64),
    face: f64,
    side: f64,
    skip: &dyn Fn(f64, f64) -> bool,
) -> Vec<Object> {
    let mut out = Vec::new();
    let mut s = range.0 + uniform(rng, 0.0, 6.0);
    while s < range.1 {
        let len = uniform(rng, 10.0, 24.0);
        let (a, b) = (s, s + len);
        s = b + uniform(rng, 1.5, 7.0);
        if skip(a, b) {
            continue;
        }
        let sm = 0.5 * (a + b);
        let depth = 12.0;
        let setback = uniform(rng, 0.0, 1.2);
        let h = uniform(rng, 7.0, 28.0);
        let [x, y] = road.to_xy(sm, side * (face + setback + 0.5 * depth));
        let (t, _) = road.frame(sm);
        let zg = road.zc(sm);
        out.push(Object {
            shape: Shape3::Box {
                c: [x, y, zg - 0.5 + 0.5 * h],
                axis: t,
                half: [0.5 * len, 0.5 * depth, 0.5 * h + 0.5],
            },
            kind: ObjKind::Building,
            rho: uniform(rng, 0.22, 0.5),
        });
    }
    out
}

/// A tree: trunk cylinder and porous canopy.
fn tree(road: &Road, rng: &mut ChaCha8Rng, s: f64, d: f64, ground_z: f64) -> [Object; 2] {
    let [x, y] = road.to_xy(s, d);
    let r = uniform(rng, 2.2, 3.3);
    let trunk_h = uniform(rng, 2.8, 3.6);
    [
        Object {
            shape: Shape3::Cylinder {
                c: [x, y],
                r: uniform(rng, 0.12, 0.2),
                z0: ground_z - 0.1,
                z1: ground_z + trunk_h + 0.5 * r,
            },
            kind: ObjKind::Trunk,
            rho: 0.2,
        },
        Object {
            shape: Shape3::Sphere {
                c: [x, y, ground_z + trunk_h + 0.8 * r],
                r,
                porosity_k: uniform(rng, 0.9, 1.6),
            },
            kind: ObjKind::Canopy,
            rho: 0.32,
        },
    ]
}

fn pole(road: &Road, s: f64, d: f64, ground_z: f64, h: f64, r: f64) -> Object {
    let [x, y] = road.to_xy(s, d);
    Object {
        shape: Shape3::Cylinder {
            c: [x, y],
            r,
            z0: ground_z - 0.1,
            z1: ground_z + h,
        },
        kind: ObjKind::Pole,
        rho: 0.35,
    }
}

/// A straight wall-like box along the road from s to s + len at offset d.
/// Cross-section of a wall-like object: width, bottom and top above the ground, reflectance.
struct Wall {
    width: f64,
    z0: f64,
    z1: f64,
    rho: f64,
}

/// `span` = (start station, length).
fn barrier(road: &Road, span: (f64, f64), d: f64, ground_z: f64, wall: Wall) -> Object {
    let (s, len) = span;
    let Wall { width, z0, z1, rho } = wall;
    let sm = s + 0.5 * len;
    let [x, y] = road.to_xy(sm, d);
    let (t, _) = road.frame(sm);
    Object {
        shape: Shape3::Box {
            c: [x, y, ground_z + 0.5 * (z0 + z1)],
            axis: t,
            half: [0.5 * len + 0.02, 0.5 * width, 0.5 * (z1 - z0)],
        },
        kind: ObjKind::Barrier,
        rho,
    }
}

/// Crack-sealant streak: a meandering polyline starting at (s, d), heading `angle` in the
/// road frame (rad from the s axis), `len` long.
fn sealant(road: &Road, rng: &mut ChaCha8Rng, s: f64, d: f64, angle: f64, len: f64) -> SurfaceFeature {
    let mut pts = Vec::new();
    let (mut cs, mut cd, mut a) = (s, d, angle);
    let n = (len / 0.4).ceil() as usize;
    for _ in 0..=n {
        pts.push(road.to_xy(cs, cd));
        a += uniform(rng, -0.35, 0.35);
        cs += 0.4 * a.cos();
        cd += 0.4 * a.sin();
    }
    SurfaceFeature::Sealant {
        pts,
        hw: uniform(rng, 0.015, 0.03),
        rho: uniform(rng, 0.28, 0.4),
    }
}

fn manhole(road: &Road, rng: &mut ChaCha8Rng, s: f64, d: f64) -> SurfaceFeature {
    SurfaceFeature::Manhole {
        c: road.to_xy(s, d),
        r: uniform(rng, 0.3, 0.4),
        rho: uniform(rng, 0.35, 0.5),
    }
}

// ---------------------------------------------------------------------------------------
// highway

fn highway(opt: &SceneOptions, rng: &mut ChaCha8Rng) -> Scene {
    let st = opt.standard;
    let len = opt.length_m.unwrap_or(250.0);
    let lw = st.lane_w_highway;
    let (sa, sb) = (-110.0, len + 110.0);
    let road = Road::new(
        [0.0, 0.0],
        20f64.to_radians(),
        &[
            Segment::Straight {
                len_m: 0.45 * len + 30.0,
            },
            Segment::Arc {
                len_m: 0.55 * len + 300.0,
                radius_m: 900.0,
            },
        ],
        18.0,
        0.012,
    );
    // Our carriageway: lanes between d = 0 and d = -4 lw; the opposite one mirrored beyond
    // the median (0.75 .. 1.35).
    let right = -4.0 * lw;
    let opp0 = 2.1; // opposite carriageway's left edge line
    let opp_right = opp0 + 4.0 * lw;
    // Exit ramp: its right edge leaves the main edge at s_t (quadratic taper), its left edge
    // (the gore's outer side) starts at the gore nose s_g where the taper is one lane wide.
    let s_t = 0.42 * len;
    let s_g = s_t + 80.0;
    let c1 = lw / (80.0f64 * 80.0);
    let ramp_right = Quad {
        sr: s_t,
        c0: right,
        c1: 0.0,
        c2: -c1,
    };
    let ramp_left = ramp_right.shifted(lw);
    // The ramp lines end where they are 15 m out; the pavement keeps that width.
    let s_re = (s_t + 80.0 * 2.0).min(sb);
    let pave_r = move |s: f64| {
        let sc = s.min(s_re);
        if sc > s_t {
            (right - 3.0).min(ramp_right.at(sc) - 2.5)
        } else {
            right - 3.0
        }
    };
    let pave_l = opp_right + 3.0;
    // Beyond the painted gore (wider than 4.5 m) the ramp and the main road are separated
    // by a grass island.
    let s_island = s_t + (80.0f64 * 80.0 + 4.5 / c1).sqrt();
    let profile = move |s: f64| {
        let pr = pave_r(s);
        let zr = 0.02 * (pr - 0.75);
        let zl = 0.02 * (1.35 - pave_l);
        let mut p = Profile::new();
        p.push(pr - 14.0, zr + 0.4, Material::Grass)
            .push(pr - 9.0, zr - 0.9, Material::Grass)
            .push(pr - 5.0, zr - 1.0, Material::Grass)
            .push(pr - 2.0, zr - 0.2, Material::Grass)
            .push(pr - 0.6, zr - 0.04, Material::Grass)
            .push(pr, zr, Material::Asphalt);
        if s > s_island && s < s_re {
            let (a, b) = (ramp_left.at(s) + 0.6, right - 0.6);
            p.push(a, 0.02 * (a - 0.75), Material::Grass)
                .push(b, 0.02 * (b - 0.75), Material::Asphalt);
        }
        p.push(0.75, 0.0, Material::Concrete)
            .push(1.35, 0.0, Material::Asphalt)
            .push(pave_l, zl, Material::Grass)
            .push(pave_l + 0.6, zl - 0.04, Material::Grass)
            .push(pave_l + 2.0, zl - 0.2, Material::Grass)
            .push(pave_l + 5.0, zl - 1.0, Material::Grass)
            .push(pave_l + 9.0, zl - 0.9, Material::Grass)
            .push(pave_l + 14.0, zl + 0.4, Material::Grass);
        p
    };
    let mut m = MarkingSet::default();
    let (dash, gap) = st.dash_highway;
    let phase = uniform(rng, 0.0, dash + gap);
    let w = st.line_w_highway;
    // Our carriageway.
    m.solid(
        sa,
        sb,
        Quad::constant(-0.5 * st.edge_w),
        st.edge_w,
        Colour::Yellow,
    );
    for i in 1..4 {
        m.dashed(
            &road,
            (sa, sb),
            Quad::constant(-(i as f64) * lw),
            w,
            (dash, gap, phase),
        );
    }
    m.solid(sa, s_t, Quad::constant(right), st.edge_w, Colour::White);
    m.solid(s_t, s_re, ramp_right, st.edge_w, Colour::White);
    // Exit lane separation: wide short dashes between the taper start and the gore nose.
    let (ed, eg, ew) = if st.name == "gb" {
        (3.0, 3.0, 0.45)
    } else {
        (0.9144, 2.7432, 0.2032)
    };
    m.dashed(&road, (s_t + 6.0, s_g), Quad::constant(right), ew, (ed, eg, 0.0));
    m.solid(s_g, sb, Quad::constant(right), st.edge_w, Colour::White);
    m.solid(s_g, s_re, ramp_left, st.edge_w, Colour::White);
    // Gore guidelines: 45° stripes between the two edge lines, until the gore is 4 m wide.
    let lower = ramp_left.shifted(0.5 * st.edge_w);
    let upper = Quad::constant(right - 0.5 * st.edge_w);
    gore_stripes(&mut m, &road, (s_g + 2.0, sb), (lower, upper), st.guideline, 4.0);
    // Arrows (9 m), a diamond and a speed glyph in our lanes.
    let lane_c = |i: usize| -(i as f64 - 0.5) * lw;
    let mut s = 25.0;
    while s + 12.0 < s_t - 40.0 {
        m.add(arrow(
            ArrowKind::Straight,
            &Frame2::at(&road, s, lane_c(2), 1.0),
            st.arrow_len_highway,
        ));
        m.add(arrow(
            ArrowKind::Straight,
            &Frame2::at(&road, s + 4.0, lane_c(3), 1.0),
            st.arrow_len_highway,
        ));
        s += 120.0;
    }
    m.add(arrow(
        ArrowKind::StraightRight,
        &Frame2::at(&road, s_t - 35.0, lane_c(4), 1.0),
        st.arrow_len_highway,
    ));
    let sr = s_g - 12.0 - st.arrow_len_highway;
    m.add(arrow(
        ArrowKind::Right,
        &Frame2::at(&road, sr, 0.5 * (right + ramp_right.at(sr)), 1.0),
        st.arrow_len_highway,
    ));
    let (dl, dw, dlw) = st.diamond;
    m.add(diamond(&Frame2::at(&road, 60.0, lane_c(1), 1.0), dl, dw, dlw));
    let gh = 5.0;
    // Speed number "70" read by the driver: '7' on the left, '0' on the right.
    m.add(glyph(
        '7',
        &Frame2::at(&road, 95.0, lane_c(1) + 0.2 * gh, 1.0),
        gh,
    ));
    m.add(glyph(
        '0',
        &Frame2::at(&road, 95.0, lane_c(1) - 0.2 * gh, 1.0),
        gh,
    ));
    // Opposite carriageway (traffic towards −s).
    m.solid(
        sa,
        sb,
        Quad::constant(opp0 + 0.5 * st.edge_w - 0.1),
        st.edge_w,
        Colour::Yellow,
    );
    for i in 1..4 {
        m.dashed(
            &road,
            (sa, sb),
            Quad::constant(opp0 + i as f64 * lw),
            w,
            (dash, gap, phase + 4.0),
        );
    }
    m.solid(sa, sb, Quad::constant(opp_right), st.edge_w, Colour::White);
    let mut s = 70.0;
    while s < len + 60.0 {
        m.add(arrow(
            ArrowKind::Straight,
            &Frame2::at(&road, s, opp0 + 1.5 * lw, -1.0),
            st.arrow_len_highway,
        ));
        s += 150.0;
    }

    // Objects.
    let mut objects = Vec::new();
    let mut s = sa;
    while s < sb {
        let zg = road.zc(s + 3.0);
        objects.push(barrier(
            &road,
            (s, 6.0),
            1.05,
            zg,
            Wall {
                width: 0.5,
                z0: 0.0,
                z1: 0.85,
                rho: 0.38,
            },
        ));
        let pr = pave_r(s + 3.0);
        let zr = road.zc(s + 3.0) + 0.02 * (pr - 0.75);
        objects.push(barrier(
            &road,
            (s, 6.0),
            pr - 0.7,
            zr,
            Wall {
                width: 0.08,
                z0: 0.55,
                z1: 0.85,
                rho: 0.55,
            },
        ));
        objects.push(barrier(
            &road,
            (s, 6.0),
            pave_l + 0.7,
            road.zc(s + 3.0) - 0.4,
            Wall {
                width: 0.08,
                z0: 0.55,
                z1: 0.85,
                rho: 0.55,
            },
        ));
        s += 6.0;
    }
    let mut s = sa + uniform(rng, 0.0, 40.0);
    while s < sb {
        objects.push(pole(&road, s, 1.05, road.zc(s) + 0.85, 11.0, 0.12));
        s += 40.0;
    }
    let mut s = sa;
    while s < sb {
        let d = pave_r(s) - uniform(rng, 18.0, 30.0);
        let [a, b] = tree(&road, rng, s, d, road.zc(s) - 0.8);
        objects.extend([a, b]);
        s += uniform(rng, 6.0, 20.0);
    }
    // A broken-down car on the hard shoulder.
    let sc = 0.3 * len;
    let zg = road.zc(sc) + 0.02 * (right - 1.5 - 0.75);
    objects.extend(car_boxes(
        &road,
        sc,
        right - 1.6,
        zg,
        CarSize {
            length: 4.7,
            width: 1.85,
            height: 1.5,
            rho: 0.45,
        },
    ));

    let drive = Drive::new(0.0, len, 15.0, lane_c(3), rng);
    let moving = vec![
        moving_car(rng, 20.0, 30.0, lane_c(3), 15.0),
        moving_car(rng, -10.0, 10.0, lane_c(2), 25.0),
        moving_car(rng, 40.0, 80.0, lane_c(1), 27.0),
        moving_car(rng, -40.0, -20.0, lane_c(4), 24.0),
        moving_car(rng, len + 0.0, len + 60.0, opp0 + 1.5 * lw, -25.0),
        moving_car(rng, len + 100.0, len + 200.0, opp0 + 2.5 * lw, -22.0),
        moving_car(rng, len + 250.0, len + 400.0, opp0 + 0.5 * lw, -28.0),
    ];

    // Pavement: old asphalt with a resurfaced lane, a concrete patch and sealed cracks.
    let mut feats = vec![
        SurfaceFeature::Patch {
            s0: 0.15 * len,
            s1: 0.15 * len + 70.0,
            d0: right,
            d1: right + lw,
            rho: 0.07,
        },
        SurfaceFeature::Patch {
            s0: 0.5 * len,
            s1: 0.5 * len + 3.0,
            d0: lane_c(2) - 1.0,
            d1: lane_c(2) + 1.2,
            rho: 0.34,
        },
    ];
    for _ in 0..(len / 25.0) as usize {
        let s = uniform(rng, 0.0, len);
        let d = uniform(rng, right, 0.0);
        let a = if rng.random_bool(0.5) {
            uniform(rng, -0.2, 0.2)
        } else {
            FRAC_PI_2 + uniform(rng, -0.3, 0.3)
        };
        let l = uniform(rng, 2.0, 9.0);
        feats.push(sealant(&road, rng, s, d, a, l));
    }
    let mut refl = Reflectance::new(opt.seed, 0.11, 0.22, 0.08, feats);
    refl.tracks = wheel_tracks(&[lane_c(1), lane_c(2), lane_c(3), lane_c(4)]);
    refl.track_wear = 0.25;
    Scene {
        name: "highway".into(),
        road,
        profile: Box::new(profile),
        marks: m,
        objects,
        moving,
        refl,
        drive,
        heads: Head::single(),
        origin: ORIGIN,
        s_range: (sa - 20.0, sb + 20.0),
    }
}

/// A moving car starting somewhere in stations [lo, hi).
/// Wheel tracks 0.85 m either side of each lane centre.
fn wheel_tracks(lane_centres: &[f64]) -> Vec<f64> {
    lane_centres.iter().flat_map(|&c| [c - 0.85, c + 0.85]).collect()
}

fn moving_car(rng: &mut ChaCha8Rng, lo: f64, hi: f64, d: f64, v: f64) -> MovingCar {
    MovingCar {
        s0: uniform(rng, lo, hi),
        d,
        v,
        size: CarSize {
            length: uniform(rng, 4.2, 5.0),
            width: uniform(rng, 1.75, 1.9),
            height: uniform(rng, 1.4, 1.7),
            rho: uniform(rng, 0.2, 0.6),
        },
    }
}

/// 45° guideline stripes between the curves `lower` and `upper` (lower < upper), every
/// `spacing` m along the road from `s0`, while the gore is at most `max_w` wide.
fn gore_stripes(
    m: &mut MarkingSet,
    road: &Road,
    span: (f64, f64),
    sides: (Quad, Quad),
    g: (f64, f64),
    max_w: f64,
) {
    let ((s0, s1), (lower, upper)) = (span, sides);
    let (w, spacing) = g;
    let c = std::f64::consts::FRAC_1_SQRT_2;
    let dir = [c, c]; // (ds, dd): forward and to the left
    // Where the line through (s, d) in direction `dir` meets curve q (bisection on s).
    let meet = |s: f64, d: f64, q: &Quad| -> [f64; 2] {
        let f = |tau: f64| d + tau * dir[1] - q.at(s + tau * dir[0]);
        let (mut a, mut b) = (-20.0, 20.0);
        for _ in 0..60 {
            let mid = 0.5 * (a + b);
            if (f(a) > 0.0) == (f(mid) > 0.0) {
                a = mid;
            } else {
                b = mid;
            }
        }
        let t = 0.5 * (a + b);
        [s + t * dir[0], d + t * dir[1]]
    };
    let mut s = s0;
    while s < s1 {
        let width = upper.at(s) - lower.at(s);
        if width > max_w {
            break;
        }
        // Stripe axis through (s, lower(s)); its two edges offset by ±w/2 perpendicular.
        let d = lower.at(s);
        let off = [-dir[1] * 0.5 * w, dir[0] * 0.5 * w];
        let e1 = (s + off[0], d + off[1]);
        let e2 = (s - off[0], d - off[1]);
        let a1 = meet(e1.0, e1.1, &lower);
        let b1 = meet(e1.0, e1.1, &upper);
        let a2 = meet(e2.0, e2.1, &lower);
        let b2 = meet(e2.0, e2.1, &upper);
        let ax = (b1[0] - a1[0])
            .hypot(b1[1] - a1[1])
            .min((b2[0] - a2[0]).hypot(b2[1] - a2[1]));
        if ax > 0.6 {
            let ring: Vec<[f64; 2]> = [a2, a1, b1, b2].iter().map(|p| road.to_xy(p[0], p[1])).collect();
            // Axis of the stripe in the world: from the middle of the lower end to the upper.
            let lo = road.to_xy(0.5 * (a1[0] + a2[0]), 0.5 * (a1[1] + a2[1]));
            let hi = road.to_xy(0.5 * (b1[0] + b2[0]), 0.5 * (b1[1] + b2[1]));
            let len = (hi[0] - lo[0]).hypot(hi[1] - lo[1]);
            let angle = (hi[1] - lo[1]).atan2(hi[0] - lo[0]);
            let mut mk = rect(MarkingClass::Guideline, &Frame2::at(road, s, d, 1.0), 1.0, 1.0);
            mk.paint = super::markings::Paint::Poly {
                bbox: ring.iter().fold(
                    [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY],
                    |b, p| [b[0].min(p[0]), b[1].min(p[1]), b[2].max(p[0]), b[3].max(p[1])],
                ),
                ring,
                hole: None,
            };
            mk.dims = Some((len, w, angle));
            m.add(mk);
        }
        s += spacing;
    }
}

// ---------------------------------------------------------------------------------------
// urban

#[derive(Clone, Copy, PartialEq, Eq)]
enum UrbanStyle {
    Normal,
    DualHead,
    Worn,
}

fn urban(name: &str, opt: &SceneOptions, rng: &mut ChaCha8Rng, style: UrbanStyle) -> Scene {
    let st = opt.standard;
    let len = opt.length_m.unwrap_or(if style == UrbanStyle::DualHead {
        160.0
    } else {
        200.0
    });
    let lw = st.lane_w_urban;
    let (sa, sb) = (-100.0, len + 100.0);
    let road = Road::new(
        [0.0, 0.0],
        35f64.to_radians(),
        &[
            Segment::Straight {
                len_m: 0.8 * len + 40.0,
            },
            Segment::Arc {
                len_m: 0.2 * len + 300.0,
                radius_m: -400.0,
            },
        ],
        9.0,
        -0.006,
    );
    let inner = 0.3; // half width of the double yellow centre area
    let edge = inner + 3.0 * lw; // edge lines
    let curb = edge + 0.45;
    let walk = curb + 4.0;
    let face = walk + 1.0;
    let cross = 0.02;
    // Intersections: one every 250 m, the first at 55 % of the drive.
    let hw_x = 7.5; // half width of the crossing street
    let r_c = 8.0; // corner radius
    let xs: Vec<f64> = {
        let mut v = vec![];
        let mut s = 0.55 * len;
        while s < 0.8 * len + 20.0 || v.is_empty() {
            v.push(s);
            s += 250.0;
        }
        v
    };
    let xs_p = xs.clone();
    let profile = move |s: f64| {
        let zroad = -cross * curb;
        // Distance into the crossing-street zone: u < 0 inside the street, 0..r_c corner.
        let u = xs_p
            .iter()
            .map(|&x| (s - x).abs() - hw_x)
            .fold(f64::INFINITY, f64::min);
        let mut p = Profile::new();
        if u < 0.0 {
            p.push(-curb, zroad, Material::Asphalt)
                .push(0.0, 0.0, Material::Asphalt)
                .push(curb, zroad, Material::Asphalt);
            return p;
        }
        let c = if u < r_c {
            curb + r_c - (r_c * r_c - (r_c - u) * (r_c - u)).sqrt()
        } else {
            curb
        };
        let zc = -cross * c;
        let top = zc + 0.15;
        p.push(-c - 25.0, top + 0.3, Material::Sidewalk)
            .push(-c, top, Material::Curb)
            .push(-c, zc, Material::Asphalt)
            .push(-curb, zroad, Material::Asphalt)
            .push(0.0, 0.0, Material::Asphalt)
            .push(curb, zroad, Material::Asphalt)
            .push(c, zc, Material::Curb)
            .push(c, top, Material::Sidewalk)
            .push(c + 25.0, top + 0.3, Material::Sidewalk);
        p
    };
    let mut m = MarkingSet::default();
    let (dash, gap) = st.dash_urban;
    let w = st.line_w_urban;
    let (zeb_w, zeb_g) = st.zebra;
    let cw = 5.0; // crosswalk width (along the road)
    let lane_c = |i: usize| inner + (i as f64 - 0.5) * lw; // |d| of lane i's centre
    // Stretches between intersections: [start, end] of the straight approach.
    let mut bounds = vec![sa];
    for &x in &xs {
        bounds.push(x - hw_x - r_c);
        bounds.push(x + hw_x + r_c);
    }
    bounds.push(sb);
    let solid_len = 30.0;
    for k in 0..bounds.len() / 2 {
        let (a, b) = (bounds[2 * k], bounds[2 * k + 1]);
        let has_end = k + 1 < bounds.len() / 2; // an intersection follows (towards +s)
        let has_start = k > 0; // an intersection precedes
        // Our direction (d < 0) approaches the intersection at b; the opposite at a.
        let stop_ours = if has_end { b - 1.0 - cw - 1.5 } else { b };
        let stop_opp = if has_start { a + 1.0 + cw + 1.5 } else { a };
        let cw_ours = (b - 1.0 - cw, b - 1.0);
        let cw_opp = (a + 1.0, a + 1.0 + cw);
        // Centre double yellow and edge lines.
        let (ya, yb) = (
            if has_start { cw_opp.1 + 1.0 } else { a },
            if has_end { cw_ours.0 - 1.0 } else { b },
        );
        m.solid(ya, yb, Quad::constant(-0.15), 0.15, Colour::Yellow);
        m.solid(ya, yb, Quad::constant(0.15), 0.15, Colour::Yellow);
        m.solid(a, b, Quad::constant(-edge), w, Colour::White);
        m.solid(a, b, Quad::constant(edge), w, Colour::White);
        // Lane lines: solid for the last 30 m before a stop line, dashed elsewhere.
        let phase = uniform(rng, 0.0, dash + gap);
        for i in 1..3 {
            let dl = inner + i as f64 * lw;
            // ours (−d): dashed from after the previous crossing to 30 m before our stop line
            let start = if has_start { cw_opp.1 + 2.0 } else { a };
            if has_end {
                m.dashed(
                    &road,
                    (start, stop_ours - solid_len),
                    Quad::constant(-dl),
                    w,
                    (dash, gap, phase),
                );
                m.solid(
                    stop_ours - solid_len,
                    stop_ours,
                    Quad::constant(-dl),
                    w,
                    Colour::White,
                );
            } else {
                m.dashed(&road, (start, b), Quad::constant(-dl), w, (dash, gap, phase));
            }
            // opposite (+d): solid for 30 m after its stop line (towards +s), then dashed
            let end = if has_end { cw_ours.0 - 2.0 } else { b };
            if has_start {
                m.solid(
                    stop_opp,
                    stop_opp + solid_len,
                    Quad::constant(dl),
                    w,
                    Colour::White,
                );
                m.dashed(
                    &road,
                    (stop_opp + solid_len, end),
                    Quad::constant(dl),
                    w,
                    (dash, gap, phase + 1.0),
                );
            } else {
                m.dashed(&road, (a, end), Quad::constant(dl), w, (dash, gap, phase + 1.0));
            }
        }
        let al = st.arrow_len_urban;
        if has_end {
            // Stop line, crosswalk, arrows (two sets), diamonds.
            m.add(rect(
                MarkingClass::StopLine,
                &Frame2::at(&road, stop_ours - 0.5 * st.stop_w, -0.5 * (inner + edge), 1.0)
                    .rotated(FRAC_PI_2),
                edge - inner,
                st.stop_w,
            ));
            zebra(
                &mut m,
                &road,
                0.5 * (cw_ours.0 + cw_ours.1),
                (-edge, edge),
                cw,
                (zeb_w, zeb_g),
            );
            for rep in [0.0, 30.0] {
                let s_tail = stop_ours - 4.0 - al - rep;
                if s_tail - 2.0 < a {
                    continue;
                }
                for (i, kind) in [
                    (1, ArrowKind::Left),
                    (2, ArrowKind::Straight),
                    (3, ArrowKind::StraightRight),
                ] {
                    m.add(arrow(kind, &Frame2::at(&road, s_tail, -lane_c(i), 1.0), al));
                }
            }
            let sd = stop_ours - 55.0;
            if sd - 3.0 > a {
                let (dl, dw, dlw) = st.diamond;
                for i in [2, 3] {
                    m.add(diamond(&Frame2::at(&road, sd, -lane_c(i), 1.0), dl, dw, dlw));
                }
            }
        }
        if has_start {
            m.add(rect(
                MarkingClass::StopLine,
                &Frame2::at(&road, stop_opp + 0.5 * st.stop_w, 0.5 * (inner + edge), 1.0).rotated(FRAC_PI_2),
                edge - inner,
                st.stop_w,
            ));
            zebra(
                &mut m,
                &road,
                0.5 * (cw_opp.0 + cw_opp.1),
                (-edge, edge),
                cw,
                (zeb_w, zeb_g),
            );
            for rep in [0.0, 30.0] {
                let s_tail = stop_opp + 4.0 + al + rep;
                if s_tail + 2.0 > b {
                    continue;
                }
                for (i, kind) in [
                    (1, ArrowKind::StraightLeft),
                    (2, ArrowKind::Straight),
                    (3, ArrowKind::Right),
                ] {
                    m.add(arrow(kind, &Frame2::at(&road, s_tail, lane_c(i), -1.0), al));
                }
            }
        }
    }
    // Crossing streets: crosswalks across them, stop lines, centre and lane lines.
    for &x in &xs {
        for side in [-1.0, 1.0] {
            let d0 = curb + 1.0;
            let zc = zebra_side(&mut m, &road, (x, side), (d0, hw_x - 0.3, 4.0), (zeb_w, zeb_g));
            // Vehicles approaching from this side drive towards −side·n; their lanes are on
            // their right: for side = −1 (right street) at s < x, for side = +1 at s > x.
            let ds = d0 + 4.0 + 1.5;
            let s_lane = if side < 0.0 {
                x + 0.5 * hw_x
            } else {
                x - 0.5 * hw_x
            };
            let f = Frame2::at(&road, s_lane, side * (ds + 0.5 * st.stop_w), 1.0);
            m.add(rect(MarkingClass::StopLine, &f, hw_x - 0.3, st.stop_w));
            let p0 = road.to_xy(x, side * (zc + 2.0));
            let p1 = road.to_xy(x, side * (zc + 35.0));
            m.solid_xy(p0, p1, 0.15, Colour::Yellow);
            for off in [-0.5 * hw_x, 0.5 * hw_x] {
                let a = road.to_xy(x + off, side * (zc + 2.0));
                let b = road.to_xy(x + off, side * (zc + 35.0));
                m.dashed_xy(a, b, w, dash, gap);
            }
        }
    }

    // Objects: façades, trees, street lights, parked and moving cars.
    let xs_o = xs.clone();
    let near_x = move |a: f64, b: f64| {
        xs_o.iter()
            .any(|&x| b > x - hw_x - r_c - 3.0 && a < x + hw_x + r_c + 3.0)
    };
    let mut objects = Vec::new();
    for side in [-1.0, 1.0] {
        objects.extend(buildings(&road, rng, (sa, sb), face, side, &near_x));
        let mut s = sa + uniform(rng, 0.0, 8.0);
        while s < sb {
            if !near_x(s - 3.0, s + 3.0) {
                let d = side * (curb + 1.0 + uniform(rng, -0.1, 0.3));
                let zg = road.zc(s) - cross * curb + 0.15;
                let [a, b] = tree(&road, rng, s, d, zg);
                objects.extend([a, b]);
            }
            s += uniform(rng, 7.0, 10.0);
        }
        let mut s = sa + uniform(rng, 0.0, 25.0);
        while s < sb {
            if !near_x(s, s) {
                objects.push(pole(
                    &road,
                    s + 4.0,
                    side * (curb + 0.4),
                    road.zc(s) - cross * curb + 0.15,
                    9.0,
                    0.1,
                ));
            }
            s += 28.0;
        }
        // Parked cars along the kerb over the edge line.
        let mut s = sa + uniform(rng, 5.0, 20.0);
        while s < sb {
            let run = uniform(rng, 10.0, 40.0);
            let n = (run / 6.2) as usize;
            for k in 0..n {
                let sc = s + k as f64 * 6.2 + uniform(rng, -0.3, 0.3);
                if near_x(sc - 15.0, sc + 15.0) {
                    continue;
                }
                let d = side * (curb - 1.05 + uniform(rng, -0.1, 0.1));
                let zg = road.zc(sc) - cross * (curb - 1.0);
                objects.extend(car_boxes(
                    &road,
                    sc,
                    d,
                    zg,
                    CarSize {
                        length: uniform(rng, 4.2, 4.9),
                        width: uniform(rng, 1.7, 1.9),
                        height: uniform(rng, 1.4, 1.7),
                        rho: uniform(rng, 0.15, 0.6),
                    },
                ));
            }
            s += run + uniform(rng, 20.0, 60.0);
        }
    }
    let speed = if style == UrbanStyle::DualHead { 10.0 } else { 11.0 };
    let drive = Drive::new(0.0, len, speed, -lane_c(2), rng);
    let moving = vec![
        moving_car(rng, 15.0, 25.0, -lane_c(2), speed),
        moving_car(rng, -20.0, 0.0, -lane_c(1), speed + 2.5),
        moving_car(rng, len + 0.0, len + 40.0, lane_c(2), -12.0),
        moving_car(rng, len + 60.0, len + 120.0, lane_c(1), -10.0),
        moving_car(rng, len + 120.0, len + 200.0, lane_c(3), -9.0),
    ];

    // Pavement features.
    let worn = style == UrbanStyle::Worn;
    let mut feats = Vec::new();
    let mut s = uniform(rng, 0.0, 20.0);
    while s < len + 40.0 {
        let d = -lane_c(rng.random_range(1..4)) + uniform(rng, -1.0, 1.0);
        feats.push(manhole(&road, rng, s, d));
        if rng.random_bool(0.6) {
            let s2 = s + uniform(rng, 3.0, 10.0);
            feats.push(manhole(&road, rng, s2, -d));
        }
        s += uniform(rng, 18.0, if worn { 30.0 } else { 45.0 });
    }
    let n_seal = (len / if worn { 8.0 } else { 20.0 }) as usize;
    for _ in 0..n_seal {
        let s = uniform(rng, -20.0, len + 20.0);
        let d = uniform(rng, -edge, edge);
        let a = if rng.random_bool(0.5) {
            uniform(rng, -0.25, 0.25)
        } else {
            FRAC_PI_2 + uniform(rng, -0.4, 0.4)
        };
        let l = uniform(rng, 2.0, 10.0);
        feats.push(sealant(&road, rng, s, d, a, l));
    }
    // A utility trench across the road, a concrete patch, a resurfaced strip.
    let tr = uniform(rng, 0.1, 0.3) * len;
    feats.push(SurfaceFeature::Patch {
        s0: tr,
        s1: tr + 1.2,
        d0: -edge,
        d1: edge,
        rho: 0.065,
    });
    let cp = xs[0] - hw_x - 1.0;
    feats.push(SurfaceFeature::Patch {
        s0: cp,
        s1: cp + 2.5,
        d0: -lane_c(1) - 1.5,
        d1: -lane_c(1) + 1.5,
        rho: 0.34,
    });
    feats.push(SurfaceFeature::Patch {
        s0: 0.05 * len,
        s1: 0.05 * len + 45.0,
        d0: 0.0,
        d1: edge + 0.3,
        rho: if worn { 0.1 } else { 0.075 },
    });
    let (asphalt, texture, wear) = match style {
        UrbanStyle::Worn => (0.16, 0.35, 0.4),
        _ => (0.12, 0.25, 0.12),
    };
    for mk in &mut m.markings {
        mk.wear = if worn {
            uniform(rng, 0.0, 0.25)
        } else {
            uniform(rng, 0.0, 0.15)
        };
    }
    let mut refl = Reflectance::new(opt.seed, asphalt, texture, wear, feats);
    refl.tracks = wheel_tracks(&[
        -lane_c(1),
        -lane_c(2),
        -lane_c(3),
        lane_c(1),
        lane_c(2),
        lane_c(3),
    ]);
    refl.track_wear = if worn { 0.35 } else { 0.25 };
    let heads = if style == UrbanStyle::DualHead {
        Head::butterfly()
    } else {
        Head::single()
    };
    Scene {
        name: name.into(),
        road,
        profile: Box::new(profile),
        marks: m,
        objects,
        moving,
        refl,
        drive,
        heads,
        origin: ORIGIN,
        s_range: (sa - 20.0, sb + 20.0),
    }
}

/// Zebra stripes across the road (stripes along it) centred at station `sc`, filling
/// d in [d0, d1], each `len` long.
fn zebra(m: &mut MarkingSet, road: &Road, sc: f64, span: (f64, f64), len: f64, stripes: (f64, f64)) {
    let ((d0, d1), (w, gap)) = (span, stripes);
    let n = ((d1 - d0 + gap) / (w + gap)).floor() as usize;
    let used = n as f64 * (w + gap) - gap;
    let first = d0 + 0.5 * (d1 - d0 - used) + 0.5 * w;
    for k in 0..n {
        let d = first + k as f64 * (w + gap);
        m.add(rect(
            MarkingClass::Crosswalk,
            &Frame2::at(road, sc, d, 1.0),
            len,
            w,
        ));
    }
}

/// Zebra across a crossing street on `side` (stripes along d), from |d| = d0 to d0 + len,
/// over stations x ± half; returns the |d| of its far edge. `at` = (station of the street's axis, side), `geom` = (|d| of the near edge, half width,
/// length), `stripes` = (width, gap).
fn zebra_side(
    m: &mut MarkingSet,
    road: &Road,
    at: (f64, f64),
    geom: (f64, f64, f64),
    stripes: (f64, f64),
) -> f64 {
    let ((x, side), (d0, half, len), (w, gap)) = (at, geom, stripes);
    let n = ((2.0 * half + gap) / (w + gap)).floor() as usize;
    let used = n as f64 * (w + gap) - gap;
    let first = x - 0.5 * used + 0.5 * w;
    for k in 0..n {
        let s = first + k as f64 * (w + gap);
        let f = Frame2::at(road, s, side * (d0 + 0.5 * len), 1.0).rotated(FRAC_PI_2);
        m.add(rect(MarkingClass::Crosswalk, &f, len, w));
    }
    d0 + len
}

// ---------------------------------------------------------------------------------------
// curved ramp

fn ramp(opt: &SceneOptions, rng: &mut ChaCha8Rng) -> Scene {
    let st = opt.standard;
    let len = opt.length_m.unwrap_or(200.0);
    let lw = 3.6f64.min(st.lane_w_highway);
    let (sa, sb) = (-80.0, len + 80.0);
    let radius = 90.0;
    let road = Road::new(
        [20.0, -30.0],
        110f64.to_radians(),
        &[
            Segment::Straight { len_m: 40.0 },
            Segment::Arc {
                len_m: (len + 60.0).min(1.6 * std::f64::consts::PI * radius),
                radius_m: -radius,
            },
            Segment::Arc {
                len_m: 300.0,
                radius_m: 600.0,
            },
        ],
        24.0,
        0.035,
    );
    let s_g = 0.55 * len; // lane split
    let c2 = 4.0 / (60.0f64 * 60.0);
    let split_l = Quad {
        sr: s_g,
        c0: -lw,
        c1: 0.0,
        c2: -c2,
    };
    let split_r = split_l.shifted(-lw);
    // The split lines end 100 m after the split (9 m apart); the deck keeps that width.
    let s_se = (s_g + 100.0).min(sb);
    let right = move |s: f64| {
        if s > s_g {
            split_r.at(s.min(s_se))
        } else {
            -2.0 * lw
        }
    };
    let superelev = 0.04;
    let profile = move |s: f64| {
        let pr = right(s) - 2.5;
        let pl = 0.75;
        let z = |d: f64| superelev * d;
        let mut p = Profile::new();
        p.push(pr - 30.0, z(pr) - 7.5, Material::Grass)
            .push(pr - 0.6, z(pr) - 7.5, Material::Concrete)
            .push(pr - 0.6, z(pr), Material::Concrete)
            .push(pr, z(pr), Material::Asphalt)
            .push(pl, z(pl), Material::Concrete)
            .push(pl + 0.6, z(pl), Material::Concrete)
            .push(pl + 0.6, z(pl) - 7.5, Material::Grass)
            .push(pl + 40.0, z(pl) - 7.5, Material::Grass);
        p
    };
    let mut m = MarkingSet::default();
    let (dash, gap) = st.dash_highway;
    let w = st.line_w_highway;
    m.solid(
        sa,
        sb,
        Quad::constant(-0.5 * st.edge_w),
        st.edge_w,
        Colour::Yellow,
    );
    m.dashed(
        &road,
        (sa, s_g - 2.0),
        Quad::constant(-lw),
        w,
        (dash, gap, uniform(rng, 0.0, dash + gap)),
    );
    m.solid(s_g, sb, Quad::constant(-lw), st.edge_w, Colour::White);
    m.solid(s_g, s_se, split_l, st.edge_w, Colour::White);
    m.solid(sa, s_g, Quad::constant(-2.0 * lw), st.edge_w, Colour::White);
    m.solid(s_g, s_se, split_r, st.edge_w, Colour::White);
    gore_stripes(
        &mut m,
        &road,
        (s_g + 2.0, sb),
        (
            split_l.shifted(0.5 * st.edge_w),
            Quad::constant(-lw - 0.5 * st.edge_w),
        ),
        st.guideline,
        4.0,
    );
    let al = st.arrow_len_highway;
    for s in [s_g - 45.0, s_g - 95.0] {
        if s > sa + 5.0 {
            m.add(arrow(
                ArrowKind::Straight,
                &Frame2::at(&road, s, -0.5 * lw, 1.0),
                al,
            ));
            m.add(arrow(ArrowKind::Right, &Frame2::at(&road, s, -1.5 * lw, 1.0), al));
        }
    }
    // Objects: barrier segments (short, they follow the tight curve), lamp posts on them.
    let mut objects = Vec::new();
    let mut s = sa;
    while s < sb {
        let sm = s + 1.5;
        let pr = right(sm) - 2.5;
        let zc = road.zc(sm);
        objects.push(barrier(
            &road,
            (s, 3.0),
            pr - 0.3,
            zc + superelev * pr,
            Wall {
                width: 0.6,
                z0: 0.0,
                z1: 1.0,
                rho: 0.36,
            },
        ));
        objects.push(barrier(
            &road,
            (s, 3.0),
            1.05,
            zc + superelev * 0.75,
            Wall {
                width: 0.6,
                z0: 0.0,
                z1: 1.0,
                rho: 0.36,
            },
        ));
        s += 3.0;
    }
    let mut s = sa;
    while s < sb {
        objects.push(pole(&road, s, 1.05, road.zc(s) + 1.0, 10.0, 0.11));
        s += 35.0;
    }
    // Trees and buildings below the viaduct.
    let mut s = sa;
    while s < sb {
        let d = if rng.random_bool(0.5) {
            uniform(rng, 12.0, 30.0)
        } else {
            -uniform(rng, 16.0, 35.0)
        };
        let [a, b] = tree(&road, rng, s, d, road.zc(s) - 7.5);
        objects.extend([a, b]);
        s += uniform(rng, 5.0, 15.0);
    }
    let drive = Drive::new(0.0, len, 14.0, -0.5 * lw, rng);
    let moving = vec![
        moving_car(rng, 18.0, 28.0, -0.5 * lw, 14.0),
        moving_car(rng, -15.0, 5.0, -1.5 * lw, 15.5),
    ];
    let mut feats = Vec::new();
    for _ in 0..(len / 30.0) as usize {
        let s = uniform(rng, 0.0, len);
        let (d, a) = (uniform(rng, -2.0 * lw, 0.0), uniform(rng, -0.3, 0.3));
        feats.push(sealant(&road, rng, s, d, a, 6.0));
    }
    // Bridge expansion joints: steel strips across the deck.
    for k in 0..(len / 60.0).ceil() as usize {
        let s = 20.0 + 60.0 * k as f64;
        feats.push(SurfaceFeature::Patch {
            s0: s,
            s1: s + 0.25,
            d0: -2.0 * lw - 2.5,
            d1: 0.75,
            rho: 0.5,
        });
    }
    let mut refl = Reflectance::new(opt.seed, 0.1, 0.2, 0.1, feats);
    refl.tracks = wheel_tracks(&[-0.5 * lw, -1.5 * lw]);
    refl.track_wear = 0.2;
    Scene {
        name: "curved_ramp".into(),
        road,
        profile: Box::new(profile),
        marks: m,
        objects,
        moving,
        refl,
        drive,
        heads: Head::single(),
        origin: ORIGIN,
        s_range: (sa - 20.0, sb + 20.0),
    }
}
