//! The laser scanner: a rotating-mirror profiler (RIEGL VUX-1-like) and the ray casting of
//! one scan line.
//!
//! **Scan pattern.** Each head sweeps a full circle in its scan plane at `lines_per_s`
//! (≈ 200 profiles/s) with `points_per_s` (≈ 500 k/s) pulses, i.e. 2500 pulses per line,
//! 0.144° apart. The plane of a single head is the vehicle's cross-section (y–z). A butterfly
//! pair yaws its planes by ±`yaw` about the vertical and tilts them about their own lateral
//! axis; the heads run with a phase offset, so their points interleave in time.
//!
//! **Per pulse.** Position of the head interpolated along the line (the vehicle moves
//! ≈ 6 cm during one line), the vehicle attitude of the line's middle; the nearest of the
//! ground hit ([`super::surface`]), static objects and moving cars (placed at the line's
//! time); range noise along the ray; intensity from [`super::intensity`]. No return for
//! the sky, beyond `max_range_m`, or when the echo is too weak.
//!
//! **Determinism.** Each (head, line) has its own ChaCha8 generator seeded from the scene
//! seed, so lines can be computed in any order on any number of threads.
//!
//! Complexity: O(pulses × (ground intervals + objects per bucket)).

use super::drive::{Drive, Mat3, mat_mul, mat_vec, rot_y, rot_z};
use super::intensity::{Radiometry, Reflectance};
use super::markings::{MarkingDef, MarkingIndex};
use super::objects::{MovingCar, ObjHit, ObjKind, Object, ObjectIndex, car_boxes};
use super::road::Road;
use super::surface::Ground;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use std::f64::consts::TAU;

/// One scanner head.
#[derive(Clone, Copy, Debug)]
pub struct Head {
    /// Scanner channel written to the LAS file.
    pub index: u8,
    /// Lever arm from the reference point, vehicle frame (m).
    pub mount: [f64; 3],
    /// Yaw of the scan plane from the cross-section (rad).
    pub yaw: f64,
    /// Tilt of the scan plane about its lateral axis (rad).
    pub tilt: f64,
    /// Relative receiver gain.
    pub gain: f64,
    /// Start of this head's lines as a fraction of the line period.
    pub phase: f64,
}

impl Head {
    pub fn single() -> Vec<Head> {
        vec![Head {
            index: 0,
            mount: [-0.6, 0.0, 0.0],
            yaw: 0.0,
            tilt: 0.0,
            gain: 1.0,
            phase: 0.0,
        }]
    }

    /// Two heads in a butterfly arrangement (planes yawed ±35°, tilted 10°), the second
    /// 18 % less sensitive.
    pub fn butterfly() -> Vec<Head> {
        vec![
            Head {
                index: 0,
                mount: [-0.7, 0.45, 0.0],
                yaw: 35f64.to_radians(),
                tilt: 10f64.to_radians(),
                gain: 1.0,
                phase: 0.0,
            },
            Head {
                index: 1,
                mount: [-0.7, -0.45, 0.0],
                yaw: -35f64.to_radians(),
                tilt: 10f64.to_radians(),
                gain: 0.82,
                phase: 0.3711,
            },
        ]
    }
}

/// Timing and ranging of the scanner.
#[derive(Clone, Copy, Debug)]
pub struct ScanConfig {
    pub lines_per_s: f64,
    /// Pulses per second per head.
    pub points_per_s: f64,
    pub max_range_m: f64,
    pub min_range_m: f64,
    pub range_noise_m: f64,
}

impl Default for ScanConfig {
    fn default() -> Self {
        ScanConfig {
            lines_per_s: 200.0,
            points_per_s: 500_000.0,
            max_range_m: 100.0,
            min_range_m: 1.5,
            range_noise_m: 0.005,
        }
    }
}

impl ScanConfig {
    pub fn pulses_per_line(&self) -> usize {
        (self.points_per_s / self.lines_per_s).round().max(1.0) as usize
    }
}

/// One simulated return (local coordinates).
#[derive(Clone, Copy, Debug)]
pub struct SimPoint {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    /// Seconds since the start of the survey.
    pub t: f64,
    pub intensity: u16,
    pub head: u8,
    /// 0 = not paint, k = 1 + marking index.
    pub label: u32,
    /// Mirror angle (degrees, −180..180).
    pub scan_angle_deg: f32,
}

/// Everything a scan line needs, read-only and shared by all threads.
pub struct World<'a> {
    pub seed: u64,
    pub road: &'a Road,
    pub ground: Ground<'a>,
    pub objects: &'a ObjectIndex,
    pub moving: &'a [MovingCar],
    pub markings: &'a [MarkingDef],
    pub mindex: &'a MarkingIndex,
    pub refl: &'a Reflectance,
    pub radio: Radiometry,
    pub drive: &'a Drive,
    pub scan: ScanConfig,
    pub heads: &'a [Head],
}

fn line_seed(seed: u64, head: u8, k: u64) -> u64 {
    let mut z = seed ^ (k.wrapping_mul(0x9E37_79B9_7F4A_7C15)) ^ ((head as u64) << 56);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl World<'_> {
    /// Start time (s since the survey start) of line `k` of head `h`.
    pub fn line_time(&self, h: usize, k: u64) -> f64 {
        (k as f64 + self.heads[h].phase) / self.scan.lines_per_s
    }

    /// All returns of line `k` of head `h`, in acquisition order.
    pub fn scan_line(&self, h: usize, k: u64) -> Vec<SimPoint> {
        let head = self.heads[h];
        let sc = &self.scan;
        let n = sc.pulses_per_line();
        let t_line = self.line_time(h, k);
        let dt_line = 1.0 / sc.lines_per_s;
        let mut rng = ChaCha8Rng::seed_from_u64(line_seed(self.seed, head.index, k));
        let st0 = self.drive.state(t_line, self.road, &self.ground);
        let st1 = self.drive.state(t_line + dt_line, self.road, &self.ground);
        let stm = self.drive.state(t_line + 0.5 * dt_line, self.road, &self.ground);
        let hrot: Mat3 = mat_mul(&stm.rot, &mat_mul(&rot_z(head.yaw), &rot_y(head.tilt)));
        let o0 = add(st0.pos, mat_vec(&st0.rot, head.mount));
        let o1 = add(st1.pos, mat_vec(&st1.rot, head.mount));
        let (s_head, _) = self.road.to_sd(o0[0], o0[1]);
        // Moving cars at this line's time.
        let movers: Vec<Object> = self
            .moving
            .iter()
            .flat_map(|c| {
                let s = c.s0 + c.v * t_line;
                let (zg, _) = self.ground.height(s, c.d);
                car_boxes(self.road, s, c.d, zg, c.size)
            })
            .collect();
        let mut out = Vec::with_capacity(n / 2);
        let theta0 = 0.5 * std::f64::consts::PI; // lines start pointing up
        for i in 0..n {
            let f = i as f64 / n as f64;
            let theta = theta0 + TAU * f;
            let dir = mat_vec(&hrot, [0.0, theta.cos(), theta.sin()]);
            let o = [
                o0[0] + f * (o1[0] - o0[0]),
                o0[1] + f * (o1[1] - o0[1]),
                o0[2] + f * (o1[2] - o0[2]),
            ];
            let t_pulse = t_line + i as f64 / sc.points_per_s;
            if let Some(p) = self.cast(o, dir, s_head, &movers, &head, &mut rng) {
                let ang = (theta.to_degrees() + 180.0).rem_euclid(360.0) - 180.0;
                out.push(SimPoint {
                    t: t_pulse,
                    scan_angle_deg: ang as f32,
                    ..p
                });
            }
        }
        out
    }

    /// One pulse: the nearest surface along the ray, with intensity and label.
    fn cast(
        &self,
        o: [f64; 3],
        v: [f64; 3],
        s_head: f64,
        movers: &[Object],
        head: &Head,
        rng: &mut ChaCha8Rng,
    ) -> Option<SimPoint> {
        let sc = &self.scan;
        let g = self.ground.intersect(o, v, sc.max_range_m);
        let t_lim = g.map_or(sc.max_range_m, |h| h.t);
        let end = [o[0] + t_lim * v[0], o[1] + t_lim * v[1]];
        let (s_end, _) = self.road.to_sd(end[0], end[1]);
        let mid = [o[0] + 0.5 * t_lim * v[0], o[1] + 0.5 * t_lim * v[1]];
        let (s_mid, _) = self.road.to_sd(mid[0], mid[1]);
        let (s_lo, s_hi) = (s_head.min(s_end).min(s_mid), s_head.max(s_end).max(s_mid));
        let mut obj: Option<ObjHit> =
            self.objects
                .intersect(o, v, (sc.min_range_m, t_lim), (s_lo, s_hi), rng);
        for m in movers {
            let tm = obj.map_or(t_lim, |h| h.t);
            if let Some(hh) = m.intersect(o, v, sc.min_range_m, tm, rng) {
                obj = Some(hh);
            }
        }
        let (t, normal, rho, label, paint) = match (obj, g) {
            (Some(h), _) => {
                let jitter = if h.kind == ObjKind::Canopy {
                    1.0
                } else {
                    0.9 + 0.2 * rng_unit(rng)
                };
                (h.t, h.normal, h.rho * jitter, 0u32, false)
            }
            (None, Some(gh)) => {
                let p = [o[0] + gh.t * v[0], o[1] + gh.t * v[1]];
                let (s, d) = self.road.to_sd(p[0], p[1]);
                let mut label = 0u32;
                let mut rho = None;
                if let Some(k) = self.mindex.lookup(self.markings, s, d, p[0], p[1]) {
                    let m = &self.markings[k];
                    if let Some(r) = self.refl.paint(m.colour, m.wear, d, p[0], p[1]) {
                        label = k as u32 + 1;
                        rho = Some(r);
                    }
                }
                let rho = rho.unwrap_or_else(|| self.refl.ground(gh.material, s, d, p[0], p[1]));
                (gh.t, gh.normal, rho, label, label > 0)
            }
            (None, None) => return None,
        };
        if t < sc.min_range_m {
            return None;
        }
        let cos_inc = -(normal[0] * v[0] + normal[1] * v[1] + normal[2] * v[2]);
        let intensity = self.radio.intensity(rho, cos_inc.abs(), t, head.gain, rng)?;
        let e: f64 = StandardNormal.sample(rng);
        let tr = t + sc.range_noise_m * e;
        let lift = if paint { 0.003 } else { 0.0 }; // paint thickness
        Some(SimPoint {
            x: o[0] + tr * v[0],
            y: o[1] + tr * v[1],
            z: o[2] + tr * v[2] + lift,
            t: 0.0,
            intensity,
            head: head.index,
            label,
            scan_angle_deg: 0.0,
        })
    }
}

fn rng_unit(rng: &mut ChaCha8Rng) -> f64 {
    use rand::Rng;
    rng.random::<f64>()
}

fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
