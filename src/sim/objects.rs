//! Objects above the ground: buildings, cars, poles, tree trunks and porous canopies,
//! barriers; moving cars; and their ray intersection.
//!
//! **Algorithm.** Static objects are boxes oriented along the road (slab test in the box
//! frame), vertical cylinders (circle test plus height range) and spheres. A canopy is a
//! porous sphere: a ray crossing a chord of length L returns from a depth drawn from an
//! exponential law with rate `k` (Beer–Lambert), or passes through with probability
//! exp(-k L), which leaves partial shadows on the road below. Static objects are bucketed by
//! station `s` (4 m buckets); a ray tests the buckets between the stations of its ends.
//! Moving cars are placed once per scan line (at its time) and tested by every ray.
//!
//! Complexity: O(objects in the ray's buckets) per ray.

use super::road::Road;
use rand::Rng;

/// A solid (or porous) primitive in local coordinates.
#[derive(Clone, Debug)]
pub enum Shape3 {
    /// Box with horizontal axis `axis` (unit, long side), half extents along (axis, left, up).
    Box {
        c: [f64; 3],
        axis: [f64; 2],
        half: [f64; 3],
    },
    /// Vertical cylinder from z0 to z1.
    Cylinder { c: [f64; 2], r: f64, z0: f64, z1: f64 },
    /// Sphere; `porosity_k` > 0 makes it porous (extinction per metre).
    Sphere { c: [f64; 3], r: f64, porosity_k: f64 },
}

/// What an object is (for reflectance and for the scene statistics).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ObjKind {
    Building,
    Car,
    Pole,
    Trunk,
    Canopy,
    Barrier,
}

#[derive(Clone, Debug)]
pub struct Object {
    pub shape: Shape3,
    pub kind: ObjKind,
    /// Reflectance at the scanner's wavelength.
    pub rho: f64,
}

/// Size and paint of a car.
#[derive(Clone, Copy, Debug)]
pub struct CarSize {
    pub length: f64,
    pub width: f64,
    pub height: f64,
    pub rho: f64,
}

/// A car driving along the road at constant speed in the road frame.
#[derive(Clone, Debug)]
pub struct MovingCar {
    /// Station at time 0 of the survey.
    pub s0: f64,
    pub d: f64,
    /// Signed speed along s (m/s).
    pub v: f64,
    pub size: CarSize,
}

/// A ray's hit on an object.
#[derive(Clone, Copy, Debug)]
pub struct ObjHit {
    pub t: f64,
    pub normal: [f64; 3],
    pub kind: ObjKind,
    pub rho: f64,
}

/// Two boxes (body and cabin) for a car at (s, d), resting on `ground_z`.
pub fn car_boxes(road: &Road, s: f64, d: f64, ground_z: f64, size: CarSize) -> [Object; 2] {
    let CarSize {
        length: l,
        width: w,
        height: h,
        rho,
    } = size;
    let [x, y] = road.to_xy(s, d);
    let (t, _) = road.frame(s);
    let body = Object {
        shape: Shape3::Box {
            c: [x, y, ground_z + 0.25 + 0.5 * (0.55 * h - 0.25)],
            axis: t,
            half: [0.5 * l, 0.5 * w, 0.5 * (0.55 * h - 0.25)],
        },
        kind: ObjKind::Car,
        rho,
    };
    let cabin = Object {
        shape: Shape3::Box {
            c: [x - 0.05 * l * t[0], y - 0.05 * l * t[1], ground_z + 0.775 * h],
            axis: t,
            half: [0.3 * l, 0.45 * w, 0.225 * h],
        },
        kind: ObjKind::Car,
        rho: rho * 0.5, // glass and roof: darker on average
    };
    [body, cabin]
}

impl Object {
    /// Nearest intersection with t in (t_min, t_max).
    pub fn intersect<R: Rng>(
        &self,
        o: [f64; 3],
        v: [f64; 3],
        t_min: f64,
        t_max: f64,
        rng: &mut R,
    ) -> Option<ObjHit> {
        let hit = |t: f64, normal: [f64; 3]| ObjHit {
            t,
            normal,
            kind: self.kind,
            rho: self.rho,
        };
        match &self.shape {
            Shape3::Box { c, axis, half } => {
                let n = [-axis[1], axis[0]];
                let r = [o[0] - c[0], o[1] - c[1], o[2] - c[2]];
                let ol = [r[0] * axis[0] + r[1] * axis[1], r[0] * n[0] + r[1] * n[1], r[2]];
                let vl = [v[0] * axis[0] + v[1] * axis[1], v[0] * n[0] + v[1] * n[1], v[2]];
                let (mut t0, mut t1) = (t_min, t_max);
                let mut face = (0usize, 0.0f64);
                for k in 0..3 {
                    if vl[k].abs() < 1e-12 {
                        if ol[k].abs() > half[k] {
                            return None;
                        }
                        continue;
                    }
                    let inv = 1.0 / vl[k];
                    let (mut ta, mut tb) = ((-half[k] - ol[k]) * inv, (half[k] - ol[k]) * inv);
                    let mut sign = -1.0;
                    if ta > tb {
                        std::mem::swap(&mut ta, &mut tb);
                        sign = 1.0;
                    }
                    if ta > t0 {
                        t0 = ta;
                        face = (k, sign);
                    }
                    t1 = t1.min(tb);
                    if t0 > t1 {
                        return None;
                    }
                }
                if t0 <= t_min {
                    return None; // started inside (or behind): ignore
                }
                let normal = match face.0 {
                    0 => [axis[0] * face.1, axis[1] * face.1, 0.0],
                    1 => [n[0] * face.1, n[1] * face.1, 0.0],
                    _ => [0.0, 0.0, face.1],
                };
                Some(hit(t0, normal))
            }
            Shape3::Cylinder { c, r, z0, z1 } => {
                let (px, py) = (o[0] - c[0], o[1] - c[1]);
                let a = v[0] * v[0] + v[1] * v[1];
                if a < 1e-12 {
                    return None;
                }
                let b = px * v[0] + py * v[1];
                let cc = px * px + py * py - r * r;
                let disc = b * b - a * cc;
                if disc < 0.0 {
                    return None;
                }
                let t = (-b - disc.sqrt()) / a;
                if t <= t_min || t >= t_max {
                    return None;
                }
                let z = o[2] + t * v[2];
                if z < *z0 || z > *z1 {
                    return None;
                }
                let (nx, ny) = ((px + t * v[0]) / r, (py + t * v[1]) / r);
                Some(hit(t, [nx, ny, 0.0]))
            }
            Shape3::Sphere { c, r, porosity_k } => {
                let p = [o[0] - c[0], o[1] - c[1], o[2] - c[2]];
                let b = p[0] * v[0] + p[1] * v[1] + p[2] * v[2];
                let cc = p[0] * p[0] + p[1] * p[1] + p[2] * p[2] - r * r;
                let disc = b * b - cc;
                if disc < 0.0 {
                    return None;
                }
                let sq = disc.sqrt();
                let (ta, tb) = (-b - sq, -b + sq);
                let ta = ta.max(t_min);
                if tb <= ta || ta >= t_max {
                    return None;
                }
                if *porosity_k > 0.0 {
                    let u: f64 = rng.random();
                    let depth = -(1.0 - u).ln() / porosity_k;
                    let t = ta + depth;
                    if t >= tb.min(t_max) {
                        return None;
                    }
                    // Leaves face every way: a random normal biased towards the ray.
                    let w: f64 = rng.random_range(0.25..1.0);
                    let q = (1.0 - w * w).sqrt();
                    Some(hit(t, [-v[0] * w + q * v[1], -v[1] * w - q * v[0], -v[2] * w]))
                } else {
                    let pt = [p[0] + ta * v[0], p[1] + ta * v[1], p[2] + ta * v[2]];
                    Some(hit(ta, [pt[0] / r, pt[1] / r, pt[2] / r]))
                }
            }
        }
    }

    /// Bounding circle in the horizontal plane (centre, radius).
    fn footprint(&self) -> ([f64; 2], f64) {
        match &self.shape {
            Shape3::Box { c, half, .. } => ([c[0], c[1]], half[0].hypot(half[1])),
            Shape3::Cylinder { c, r, .. } => (*c, *r),
            Shape3::Sphere { c, r, .. } => ([c[0], c[1]], *r),
        }
    }
}

/// Static objects bucketed by station.
pub struct ObjectIndex {
    pub objects: Vec<Object>,
    s_min: f64,
    bucket_m: f64,
    buckets: Vec<Vec<u32>>,
}

impl ObjectIndex {
    pub fn new(road: &Road, objects: Vec<Object>, s_min: f64, s_max: f64) -> ObjectIndex {
        let bucket_m = 4.0;
        let nb = (((s_max - s_min) / bucket_m).ceil() as usize).max(1);
        let mut buckets = vec![Vec::new(); nb];
        for (i, ob) in objects.iter().enumerate() {
            let (c, r) = ob.footprint();
            let (s, _) = road.to_sd(c[0], c[1]);
            let lo = (((s - r - 1.0 - s_min) / bucket_m).floor().max(0.0)) as usize;
            let hi = (((s + r + 1.0 - s_min) / bucket_m).floor()).min(nb as f64 - 1.0);
            if hi < 0.0 {
                continue;
            }
            for b in buckets.iter_mut().take(hi as usize + 1).skip(lo) {
                b.push(i as u32);
            }
        }
        ObjectIndex {
            objects,
            s_min,
            bucket_m,
            buckets,
        }
    }

    /// Nearest hit of the ray among objects whose buckets overlap the station range.
    /// `t_range` = (t_min, t_max) along the ray, `s_range` = (s_lo, s_hi).
    pub fn intersect<R: Rng>(
        &self,
        o: [f64; 3],
        v: [f64; 3],
        t_range: (f64, f64),
        s_range: (f64, f64),
        rng: &mut R,
    ) -> Option<ObjHit> {
        let ((t_min, t_max), (s_lo, s_hi)) = (t_range, s_range);
        let nb = self.buckets.len() as isize;
        let lo = ((s_lo - self.s_min) / self.bucket_m).floor() as isize;
        let hi = ((s_hi - self.s_min) / self.bucket_m).floor() as isize;
        let (lo, hi) = (lo.clamp(0, nb - 1), hi.clamp(0, nb - 1));
        let mut best: Option<ObjHit> = None;
        let mut last_seen = u32::MAX;
        for b in lo..=hi {
            for &i in &self.buckets[b as usize] {
                if b > lo && self.buckets[(b - 1) as usize].binary_search(&i).is_ok() {
                    continue; // already tested in the previous bucket
                }
                if i == last_seen {
                    continue;
                }
                last_seen = i;
                let tm = best.map_or(t_max, |h| h.t);
                if let Some(h) = self.objects[i as usize].intersect(o, v, t_min, tm, rng) {
                    best = Some(h);
                }
            }
        }
        best
    }
}
