//! The survey vehicle: where it is and how it is oriented at any time.
//!
//! **Model.** The vehicle follows a lane at offset `lane_d` with a slow lateral wander, at a
//! speed that varies ±6 % over 25 s (`s(t) = s_start + v t + A (1 − cos ω t)`). Its
//! attitude follows the road (pitch = grade, roll = cross slope under the wheels, yaw = the
//! path's tangent) plus small vibrations: sums of sines at 0.3–9 Hz with amplitudes of
//! 0.01–0.2°, phases from the seed. The reference point (the trajectory) is `mount_h` above
//! the ground along the vehicle's up axis.
//!
//! Conventions: vehicle frame x forward, y left, z up; roll positive = right side down;
//! pitch positive = nose up; heading in the trajectory = degrees clockwise from north.

use super::road::Road;
use super::surface::Ground;
use rand::Rng;
use std::f64::consts::TAU;

/// 3 × 3 rotation, row-major.
pub type Mat3 = [[f64; 3]; 3];

pub fn mat_mul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut m = [[0.0; 3]; 3];
    for (i, row) in m.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    m
}

pub fn mat_vec(a: &Mat3, v: [f64; 3]) -> [f64; 3] {
    [
        a[0][0] * v[0] + a[0][1] * v[1] + a[0][2] * v[2],
        a[1][0] * v[0] + a[1][1] * v[1] + a[1][2] * v[2],
        a[2][0] * v[0] + a[2][1] * v[1] + a[2][2] * v[2],
    ]
}

pub fn rot_z(a: f64) -> Mat3 {
    let (s, c) = a.sin_cos();
    [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
}

pub fn rot_y(a: f64) -> Mat3 {
    let (s, c) = a.sin_cos();
    [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
}

pub fn rot_x(a: f64) -> Mat3 {
    let (s, c) = a.sin_cos();
    [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]
}

/// Vehicle attitude → world rotation (yaw = math heading).
pub fn attitude(yaw: f64, pitch: f64, roll: f64) -> Mat3 {
    mat_mul(&mat_mul(&rot_z(yaw), &rot_y(-pitch)), &rot_x(roll))
}

/// Sum of sines: (amplitude rad, angular frequency rad/s, phase).
#[derive(Clone, Debug)]
struct Jitter(Vec<(f64, f64, f64)>);

impl Jitter {
    fn new<R: Rng>(rng: &mut R, amps_deg: &[(f64, f64)]) -> Jitter {
        Jitter(
            amps_deg
                .iter()
                .map(|&(a, hz)| (a.to_radians(), TAU * hz, rng.random_range(0.0..TAU)))
                .collect(),
        )
    }

    fn at(&self, t: f64) -> f64 {
        self.0.iter().map(|(a, w, p)| a * (w * t + p).sin()).sum()
    }
}

/// The drive of a survey.
#[derive(Clone, Debug)]
pub struct Drive {
    pub s_start: f64,
    pub length_m: f64,
    pub speed_mps: f64,
    pub lane_d: f64,
    pub wander_m: f64,
    /// Height of the reference point above the ground (m).
    pub mount_h: f64,
    /// GPS time (adjusted standard) at the start.
    pub t0: f64,
    wander_phase: f64,
    roll: Jitter,
    pitch: Jitter,
    yaw: Jitter,
}

/// Vehicle state at one instant (local coordinates).
#[derive(Clone, Copy, Debug)]
pub struct VehicleState {
    pub s: f64,
    /// Reference point (local x, y, z).
    pub pos: [f64; 3],
    pub rot: Mat3,
    pub yaw: f64,
    pub pitch: f64,
    pub roll: f64,
}

impl Drive {
    pub fn new<R: Rng>(s_start: f64, length_m: f64, speed_mps: f64, lane_d: f64, rng: &mut R) -> Drive {
        Drive {
            s_start,
            length_m,
            speed_mps,
            lane_d,
            wander_m: 0.12,
            mount_h: 2.2,
            t0: 380_000_000.0 + rng.random_range(0.0..1000.0f64).floor(),
            wander_phase: rng.random_range(0.0..TAU),
            roll: Jitter::new(rng, &[(0.15, 0.31), (0.05, 1.3), (0.012, 8.7)]),
            pitch: Jitter::new(rng, &[(0.12, 0.23), (0.04, 1.7), (0.01, 9.3)]),
            yaw: Jitter::new(rng, &[(0.08, 0.11), (0.02, 0.9), (0.005, 7.1)]),
        }
    }

    fn omega() -> f64 {
        TAU / 25.0
    }

    /// Station of the vehicle at time t (s since the start).
    pub fn s_at(&self, t: f64) -> f64 {
        let w = Self::omega();
        let a = 0.06 * self.speed_mps / w;
        self.s_start + self.speed_mps * t + a * (1.0 - (w * t).cos())
    }

    /// Time at which the vehicle reaches station `s` (Newton on the monotone s(t)).
    pub fn time_at(&self, s: f64) -> f64 {
        let w = Self::omega();
        let mut t = (s - self.s_start) / self.speed_mps;
        for _ in 0..30 {
            let f = self.s_at(t) - s;
            let df = self.speed_mps * (1.0 + 0.06 * (w * t).sin());
            t -= f / df;
            if f.abs() < 1e-9 {
                break;
            }
        }
        t
    }

    /// Duration of the drive (s).
    pub fn duration(&self) -> f64 {
        self.time_at(self.s_start + self.length_m)
    }

    /// Lateral offset of the path at station s.
    pub fn path_d(&self, s: f64) -> f64 {
        self.lane_d + self.wander_m * (TAU * (s - self.s_start) / 80.0 + self.wander_phase).sin()
    }

    pub fn state(&self, t: f64, road: &Road, ground: &Ground) -> VehicleState {
        let s = self.s_at(t);
        let d = self.path_d(s);
        let dd = (self.path_d(s + 0.5) - self.path_d(s - 0.5)) / 1.0;
        let (_, h) = road.pose(s);
        let kappa = road.curvature(s);
        let yaw = h + dd.atan2(1.0 - kappa * d) + self.yaw.at(t);
        let [x, y] = road.to_xy(s, d);
        let (zg, _) = ground.height(s, d);
        let (zl, _) = ground.height(s, d + 0.8);
        let (zr, _) = ground.height(s, d - 0.8);
        let roll = ((zl - zr) / 1.6).atan() + self.roll.at(t);
        let pitch = road.zc_slope(s).atan() + self.pitch.at(t);
        let rot = attitude(yaw, pitch, roll);
        let up = mat_vec(&rot, [0.0, 0.0, self.mount_h]);
        VehicleState {
            s,
            pos: [x + up[0], y + up[1], zg + up[2]],
            rot,
            yaw,
            pitch,
            roll,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::road::{Material, Profile, Segment};
    use rand::SeedableRng;

    #[test]
    fn time_and_station_invert() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let d = Drive::new(10.0, 200.0, 12.0, -1.8, &mut rng);
        for k in 0..50 {
            let s = 10.0 + k as f64 * 4.0;
            assert!((d.s_at(d.time_at(s)) - s).abs() < 1e-6);
        }
        assert!((d.duration() - 200.0 / 12.0).abs() < 2.0);
    }

    #[test]
    fn attitude_follows_the_road() {
        let road = Road::new([0.0, 0.0], 0.5, &[Segment::Straight { len_m: 300.0 }], 0.0, 0.03);
        let prof = |_s: f64| {
            let mut p = Profile::new();
            p.push(-10.0, -0.2, Material::Asphalt)
                .push(10.0, 0.2, Material::Asphalt);
            p
        };
        let g = Ground {
            road: &road,
            profile: &prof,
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let d = Drive::new(0.0, 200.0, 12.0, 0.0, &mut rng);
        let st = d.state(5.0, &road, &g);
        assert!((st.pitch - 0.03f64.atan()).abs() < 0.005);
        assert!(
            (st.roll - 0.02f64.atan()).abs() < 0.005,
            "left side higher: right side down"
        );
        assert!((st.yaw - 0.5).abs() < 0.01);
        // Forward axis points along the road, up axis nearly vertical.
        let f = mat_vec(&st.rot, [1.0, 0.0, 0.0]);
        assert!((f[1].atan2(f[0]) - 0.5).abs() < 0.01 && f[2] > 0.0);
    }
}
