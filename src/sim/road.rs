//! Road geometry: a centreline of straights and circular arcs, the road frame (s, d) ↔ (x, y),
//! the vertical alignment, and the cross-section profile.
//!
//! **Frame.** `s` is the arc length along the centreline (m), `d` the signed offset from it,
//! positive to the left of the direction of increasing `s`. Coordinates are local (the
//! scene's origin subtracted), in metres, x = east, y = north.
//!
//! **Algorithm.** Segments join with a continuous tangent (no clothoids). `to_xy` is closed
//! form; `to_sd` projects onto every segment (a straight: dot products; an arc: the angle
//! around its centre) and keeps the nearest valid projection. The first and last segments
//! are straights that extend to infinity, so every point has a station.
//!
//! **Cross section.** A [`Profile`] is a piecewise-linear height function of `d` (relative
//! to the centreline height `zc(s)`), with vertical steps (two vertices at the same `d`) for
//! curbs, and a material per piece.
//!
//! Complexity: `to_xy` O(log segments), `to_sd` O(segments) with one `atan2` per arc.

use std::f64::consts::{PI, TAU};

/// One piece of the centreline.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Segment {
    Straight {
        len_m: f64,
    },
    /// Circular arc; `radius_m > 0` turns left, `< 0` turns right.
    Arc {
        len_m: f64,
        radius_m: f64,
    },
}

#[derive(Clone, Copy, Debug)]
struct Geom {
    s0: f64,
    len: f64,
    p0: [f64; 2],
    h0: f64,
    /// Signed curvature (1/m), 0 for straights.
    kappa: f64,
    centre: [f64; 2],
}

/// The road centreline with its vertical alignment.
#[derive(Clone, Debug)]
pub struct Road {
    geoms: Vec<Geom>,
    /// Centreline height: `z0 + grade * s + 0.5 * vcurve * s²`.
    pub z0: f64,
    pub grade: f64,
    pub vcurve: f64,
}

/// Length of the straight lead-in and lead-out added around the user's segments.
pub const LEAD_M: f64 = 400.0;

fn wrap_pi(a: f64) -> f64 {
    let mut a = (a + PI).rem_euclid(TAU) - PI;
    if a <= -PI {
        a += TAU;
    }
    a
}

impl Road {
    /// A road starting at local `start` with math heading `heading_rad` (counter-clockwise
    /// from east). `s = 0` is the start of the first given segment; straight lead-in and
    /// lead-out of [`LEAD_M`] are added so the frame is defined well beyond the ends.
    pub fn new(start: [f64; 2], heading_rad: f64, segments: &[Segment], z0: f64, grade: f64) -> Road {
        let mut geoms = Vec::with_capacity(segments.len() + 2);
        let (c, s) = (heading_rad.cos(), heading_rad.sin());
        let mut p = [start[0] - LEAD_M * c, start[1] - LEAD_M * s];
        let mut h = heading_rad;
        let mut s_acc = -LEAD_M;
        let all = std::iter::once(Segment::Straight { len_m: LEAD_M })
            .chain(segments.iter().copied())
            .chain(std::iter::once(Segment::Straight { len_m: LEAD_M }));
        for seg in all {
            let (len, kappa) = match seg {
                Segment::Straight { len_m } => (len_m, 0.0),
                Segment::Arc { len_m, radius_m } => (len_m, 1.0 / radius_m),
            };
            let n = [-h.sin(), h.cos()];
            let centre = if kappa != 0.0 {
                [p[0] + n[0] / kappa, p[1] + n[1] / kappa]
            } else {
                p
            };
            let g = Geom {
                s0: s_acc,
                len,
                p0: p,
                h0: h,
                kappa,
                centre,
            };
            let (q, hq) = g.pose(s_acc + len);
            geoms.push(g);
            p = q;
            h = hq;
            s_acc += len;
        }
        Road {
            geoms,
            z0,
            grade,
            vcurve: 0.0,
        }
    }

    /// Length of the user's segments (without lead-in/out).
    pub fn length_m(&self) -> f64 {
        let last = &self.geoms[self.geoms.len() - 1];
        last.s0
    }

    fn geom_at(&self, s: f64) -> &Geom {
        let i = self.geoms.partition_point(|g| g.s0 <= s);
        &self.geoms[i.saturating_sub(1)]
    }

    /// Centreline position and math heading (rad) at `s`.
    pub fn pose(&self, s: f64) -> ([f64; 2], f64) {
        self.geom_at(s).pose(s)
    }

    /// Signed curvature at `s` (1/m, positive turning left).
    pub fn curvature(&self, s: f64) -> f64 {
        self.geom_at(s).kappa
    }

    /// Local (x, y) of the road-frame point (s, d).
    pub fn to_xy(&self, s: f64, d: f64) -> [f64; 2] {
        let (p, h) = self.pose(s);
        [p[0] - d * h.sin(), p[1] + d * h.cos()]
    }

    /// Road-frame (s, d) of the local point (x, y).
    pub fn to_sd(&self, x: f64, y: f64) -> (f64, f64) {
        let last = self.geoms.len() - 1;
        let mut best = (f64::INFINITY, 0.0, 0.0);
        for (i, g) in self.geoms.iter().enumerate() {
            let (s, d, inside) = g.project(x, y);
            let ok = inside || (i == 0 && s < g.s0) || (i == last && s > g.s0 + g.len);
            if ok && d.abs() < best.0 {
                best = (d.abs(), s, d);
            }
        }
        if best.0.is_finite() {
            return (best.1, best.2);
        }
        // Not inside any segment (a point off the outer side of a joint): nearest end.
        let mut best = (f64::INFINITY, 0.0, 0.0);
        for g in &self.geoms {
            for s in [g.s0, g.s0 + g.len] {
                let (p, h) = g.pose(s);
                let (dx, dy) = (x - p[0], y - p[1]);
                let dist = dx.hypot(dy);
                if dist < best.0 {
                    best = (dist, s, -dx * h.sin() + dy * h.cos());
                }
            }
        }
        (best.1, best.2)
    }

    /// Unit tangent and left normal at `s`.
    pub fn frame(&self, s: f64) -> ([f64; 2], [f64; 2]) {
        let (_, h) = self.pose(s);
        let (sn, cs) = h.sin_cos();
        ([cs, sn], [-sn, cs])
    }

    /// Centreline height at `s`.
    pub fn zc(&self, s: f64) -> f64 {
        self.z0 + self.grade * s + 0.5 * self.vcurve * s * s
    }

    /// Longitudinal slope dz/ds of the centreline at `s`.
    pub fn zc_slope(&self, s: f64) -> f64 {
        self.grade + self.vcurve * s
    }
}

impl Geom {
    fn pose(&self, s: f64) -> ([f64; 2], f64) {
        let u = s - self.s0;
        if self.kappa == 0.0 {
            let (sn, cs) = self.h0.sin_cos();
            ([self.p0[0] + u * cs, self.p0[1] + u * sn], self.h0)
        } else {
            let h = self.h0 + self.kappa * u;
            let r = 1.0 / self.kappa;
            // p = centre - r * n(h), n = (-sin h, cos h)
            ([self.centre[0] + r * h.sin(), self.centre[1] - r * h.cos()], h)
        }
    }

    /// (s, d, projection inside the segment).
    fn project(&self, x: f64, y: f64) -> (f64, f64, bool) {
        if self.kappa == 0.0 {
            let (sn, cs) = self.h0.sin_cos();
            let (rx, ry) = (x - self.p0[0], y - self.p0[1]);
            let along = rx * cs + ry * sn;
            let d = -rx * sn + ry * cs;
            (self.s0 + along, d, (0.0..=self.len).contains(&along))
        } else {
            let (vx, vy) = (x - self.centre[0], y - self.centre[1]);
            let r = vx.hypot(vy);
            let phi = vy.atan2(vx);
            let rad = 1.0 / self.kappa.abs();
            // Heading of the tangent at the point's angle around the centre.
            let h = if self.kappa > 0.0 {
                phi + PI / 2.0
            } else {
                phi - PI / 2.0
            };
            let mid = self.kappa * self.len / 2.0;
            let delta = mid + wrap_pi(h - self.h0 - mid);
            let u = delta / self.kappa;
            let d = if self.kappa > 0.0 { rad - r } else { r - rad };
            (self.s0 + u, d, (0.0..=self.len).contains(&u))
        }
    }
}

/// Surface material of a profile piece (drives the reflectance model).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Material {
    Asphalt,
    Sidewalk,
    Curb,
    Grass,
    Concrete,
}

/// Maximum number of vertices in a [`Profile`].
pub const MAX_PROFILE: usize = 16;

/// A cross-section: heights relative to `zc(s)` at increasing offsets `d`; a vertical step
/// is two consecutive vertices with the same `d`. `mat[i]` is the material of the piece
/// from vertex `i` to `i + 1` (vertical steps use their own entry). Beyond the ends the
/// height is constant.
#[derive(Clone, Copy, Debug)]
pub struct Profile {
    pub n: usize,
    pub d: [f64; MAX_PROFILE],
    pub z: [f64; MAX_PROFILE],
    pub mat: [Material; MAX_PROFILE],
}

impl Profile {
    pub fn new() -> Profile {
        Profile {
            n: 0,
            d: [0.0; MAX_PROFILE],
            z: [0.0; MAX_PROFILE],
            mat: [Material::Asphalt; MAX_PROFILE],
        }
    }

    /// Append a vertex; `mat` is the material of the piece that starts at it.
    pub fn push(&mut self, d: f64, z: f64, mat: Material) -> &mut Self {
        debug_assert!(self.n < MAX_PROFILE);
        debug_assert!(self.n == 0 || d >= self.d[self.n - 1]);
        self.d[self.n] = d;
        self.z[self.n] = z;
        self.mat[self.n] = mat;
        self.n += 1;
        self
    }

    /// Height and the index of the piece at `d` (the right-hand limit at a vertical step).
    pub fn eval(&self, d: f64) -> (f64, usize) {
        let n = self.n;
        if d < self.d[0] {
            return (self.z[0], 0);
        }
        if d >= self.d[n - 1] {
            return (self.z[n - 1], n - 1);
        }
        let i = self.d[..n].partition_point(|&v| v <= d) - 1;
        let (d0, d1) = (self.d[i], self.d[i + 1]);
        let f = if d1 > d0 { (d - d0) / (d1 - d0) } else { 0.0 };
        (self.z[i] + f * (self.z[i + 1] - self.z[i]), i)
    }

    /// Slope dz/dd of piece `i` (0 beyond the ends and on vertical steps).
    pub fn slope(&self, i: usize) -> f64 {
        if i + 1 >= self.n {
            return 0.0;
        }
        let dd = self.d[i + 1] - self.d[i];
        if dd > 0.0 {
            (self.z[i + 1] - self.z[i]) / dd
        } else {
            0.0
        }
    }

    /// Material at piece `i`; before the first vertex the first piece's material.
    pub fn material(&self, i: usize) -> Material {
        self.mat[i.min(self.n - 1)]
    }
}

impl Default for Profile {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn road() -> Road {
        Road::new(
            [10.0, 20.0],
            0.3,
            &[
                Segment::Straight { len_m: 50.0 },
                Segment::Arc {
                    len_m: 80.0,
                    radius_m: 60.0,
                },
                Segment::Arc {
                    len_m: 40.0,
                    radius_m: -120.0,
                },
                Segment::Straight { len_m: 30.0 },
            ],
            5.0,
            0.01,
        )
    }

    #[test]
    fn frame_round_trips() {
        let r = road();
        assert!((r.length_m() - 200.0).abs() < 1e-9);
        for i in 0..400 {
            let s = -50.0 + i as f64 * 0.75;
            for d in [-20.0, -3.7, 0.0, 1.2, 15.0] {
                let [x, y] = r.to_xy(s, d);
                let (s2, d2) = r.to_sd(x, y);
                assert!(
                    (s - s2).abs() < 1e-6 && (d - d2).abs() < 1e-6,
                    "{s} {d} -> {s2} {d2}"
                );
            }
        }
    }

    #[test]
    fn arc_length_and_continuity() {
        let r = road();
        // Consecutive points 1 mm apart in s are 1 mm apart in space on the centreline.
        for i in 0..200 {
            let s = i as f64;
            let a = r.to_xy(s, 0.0);
            let b = r.to_xy(s + 1e-3, 0.0);
            let dist = (a[0] - b[0]).hypot(a[1] - b[1]);
            assert!((dist - 1e-3).abs() < 1e-8, "{s}");
        }
        // Offset curve on the inside of a left arc is shorter by (1 - d/R).
        let (a, b) = (r.to_xy(60.0, 5.0), r.to_xy(60.1, 5.0));
        let dist = (a[0] - b[0]).hypot(a[1] - b[1]);
        assert!((dist - 0.1 * (1.0 - 5.0 / 60.0)).abs() < 1e-6);
    }

    #[test]
    fn profile_steps() {
        let mut p = Profile::new();
        p.push(-5.0, 0.15, Material::Sidewalk)
            .push(-3.0, 0.15, Material::Curb)
            .push(-3.0, 0.0, Material::Asphalt)
            .push(3.0, 0.0, Material::Asphalt);
        assert_eq!(p.eval(-4.0).0, 0.15);
        assert_eq!(p.eval(-3.0).0, 0.0);
        assert_eq!(p.eval(-2.9).0, 0.0);
        assert_eq!(p.eval(10.0).0, 0.0);
        assert_eq!(p.eval(-10.0).0, 0.15);
    }
}
