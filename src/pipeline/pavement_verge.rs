//! Stage 3, refinement: bright verge strips beyond the asphalt are not paint.
//!
//! **What.** Where the asphalt ends at grass, gravel or a concrete apron instead of a curb,
//! the pavement stage keeps the first strip of that verge (it is nearly flat and at road
//! height), and since such materials reflect more than asphalt the threshold marks the strip
//! as paint: a long false "lane line" just outside the real road edge. This step clears
//! marking points whose surface does not lie on the road.
//!
//! **Algorithm.** Paint is a film on the road surface: it lies on the plane of the asphalt
//! next to it (or a few millimetres above it: thermoplastic, profiled lines). A verge falls
//! away from the road (drainage), so even its flattest first strip lies below the plane of
//! the asphalt inside it, by an amount that grows across the strip. Intensity does not tell
//! the two apart (worn paint and grass can have the same contrast), height does. The
//! marking points are grouped by (pavement slice of `pavement.slice_length_m`, component of
//! the threshold mask); for each group that lies on one side of the trajectory and is at
//! most `max_width_m` wide across it (a longitudinal line piece, not a crossing stripe):
//! 1. the *reference* is the unmarked pavement of the same slice in the band of
//!    `reference_width_m` just inside the group (towards the trajectory, `gap_m` away
//!    from its inner edge), at least `min_reference_points` points whose residual spread
//!    (1.4826 × MAD) is at most `max_reference_noise_m` (else the surface is not a single
//!    plane and nothing is decided);
//! 2. the plane `z = a + b·offset + c·mileage` is fitted to it by least squares;
//! 3. the group is cleared when the median height of its points lies more than
//!    max(`min_drop_m`, `noise_factor` × σ / √n) *below* that plane (σ the reference's
//!    noise, n the group's points: the median of a noisy strip is not mistaken for a drop)
//!    — unless the unmarked surface in the band of `reference_width_m` just beyond it
//!    (`gap_m` past its outer edge, at least `min_reference_points` points) is back at the
//!    plane's level: a verge keeps falling away, a line sunk in a rut or lowered by a
//!    scanner's per-laser height bias (a ring scan) has road beyond it.
//!
//! Only drops count: a line raised above a rutted wheel path beside it, or standing on a
//! crown, is still paint. Groups with fewer than `min_points` points are left alone.
//!
//! **Parameters** ([`Params`], defaults): `min_drop_m` 0.008 (0 turns the step off),
//! `noise_factor` 3, `reference_width_m` 0.6, `gap_m` 0.05, `max_width_m` 1.0,
//! `min_points` 10, `min_reference_points` 30, `max_reference_noise_m` 0.02.
//!
//! **Reference.** The road-surface buffer and moving-window cut of Yao et al. (2019 § 2.3–2.4)
//! applied to the marking candidates: a marking is kept only where it lies on the road
//! surface the pavement stage fitted, here checked locally against the asphalt beside it.
//!
//! **Complexity.** O(n) to bucket the points by slice; each slice holding a group is
//! gathered once into contiguous memory (slices in parallel), then each group scans it:
//! O(n + Σ groups × slice points), the scans being sequential reads. Each band is put in a
//! total order before the fit, so the result does not depend on the order of the points.

use super::pavement::{check_range, lsq_plane};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Parameters of this step (JSON object `pavement.verge`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Params {
    /// A marking group whose median lies more than this below the asphalt plane beside it
    /// is verge, not paint (m). 0 turns the step off.
    pub min_drop_m: f64,
    /// … or more than this many standard errors of its median, when that is larger.
    pub noise_factor: f64,
    /// Width of the asphalt band inside the group that the plane is fitted to (m).
    pub reference_width_m: f64,
    /// Distance between that band and the group's inner edge (m): keeps the blurred edge
    /// of the paint out of the reference.
    pub gap_m: f64,
    /// Groups wider than this across the road are not line pieces and are not tested (m).
    pub max_width_m: f64,
    /// Groups with fewer marking points are not tested.
    pub min_points: u32,
    /// A reference needs at least this many points …
    pub min_reference_points: u32,
    /// … and a residual noise (1.4826 × MAD about the plane) of at most this (m).
    pub max_reference_noise_m: f64,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            min_drop_m: 0.008,
            noise_factor: 3.0,
            reference_width_m: 0.6,
            gap_m: 0.05,
            max_width_m: 1.0,
            min_points: 10,
            min_reference_points: 30,
            max_reference_noise_m: 0.02,
        }
    }
}

impl Params {
    /// Check every field; the message names the offending parameter.
    pub fn validate(&self) -> Result<(), String> {
        check_range("min_drop_m", self.min_drop_m, 0.0, 1.0)?;
        check_range("noise_factor", self.noise_factor, 0.0, 100.0)?;
        check_range("reference_width_m", self.reference_width_m, 0.05, 10.0)?;
        check_range("gap_m", self.gap_m, 0.0, 2.0)?;
        check_range("max_width_m", self.max_width_m, 0.01, 20.0)?;
        check_range("max_reference_noise_m", self.max_reference_noise_m, 0.0001, 1.0)?;
        if self.min_points == 0 {
            return Err("min_points: must be at least 1, got 0".into());
        }
        if self.min_reference_points < 3 {
            return Err(format!(
                "min_reference_points: must be at least 3 (a plane), got {}",
                self.min_reference_points
            ));
        }
        Ok(())
    }
}

/// The pavement points of one chunk as this step sees them (trajectory frame).
pub struct Input<'a> {
    /// Mileage (m) and signed lateral offset (m) of every pavement point.
    pub mileage: &'a [f64],
    pub offset: &'a [f64],
    pub z: &'a [f64],
    /// Global pavement slice of every point (see [`super::pavement::slice_of`]).
    pub slice: &'a [i64],
    /// Threshold-mask component of every point (0 = none).
    pub label: &'a [u32],
}

/// A marking point as this step groups it: (slice, mask component, point index).
type Mark = (i64, u32, usize);

/// Median of a scratch slice (reorders it); `v` is non-empty.
fn median(v: &mut [f64]) -> f64 {
    let k = v.len() / 2;
    *v.select_nth_unstable_by(k, f64::total_cmp).1
}

/// Clear the marking points of groups that lie below the road beside them (see the module
/// docs). Returns how many points were cleared.
pub fn clear_verge(input: &Input<'_>, is_mark: &mut [bool], p: &Params) -> usize {
    let n = input.z.len();
    if p.min_drop_m <= 0.0 || n == 0 || !is_mark.iter().any(|&b| b) {
        return 0;
    }
    // Points by slice (counting sort; slices are a contiguous range of integers).
    let s0 = *input.slice.iter().min().expect("non-empty");
    let s1 = *input.slice.iter().max().expect("non-empty");
    let ns = (s1 - s0 + 1) as usize;
    let mut start = vec![0usize; ns + 1];
    for &s in input.slice {
        start[(s - s0) as usize + 1] += 1;
    }
    for k in 0..ns {
        start[k + 1] += start[k];
    }
    let mut fill = start.clone();
    let mut by_slice = vec![0usize; n];
    for (i, &s) in input.slice.iter().enumerate() {
        let k = (s - s0) as usize;
        by_slice[fill[k]] = i;
        fill[k] += 1;
    }
    // Marking groups: (slice, component) → point indices, in a canonical order.
    let mut marks: Vec<Mark> = (0..n)
        .filter(|&i| is_mark[i] && input.label[i] != 0)
        .map(|i| (input.slice[i], input.label[i], i))
        .collect();
    marks.sort_unstable();
    let mut groups: Vec<&[Mark]> = Vec::new();
    let mut a = 0;
    for b in 1..=marks.len() {
        if b == marks.len() || (marks[b].0, marks[b].1) != (marks[a].0, marks[a].1) {
            groups.push(&marks[a..b]);
            a = b;
        }
    }
    groups.retain(|g| g.len() >= p.min_points as usize);
    // Per slice that holds a group: its unmarked points gathered once into contiguous
    // memory (each group's band is then a linear scan of it), and the decisions on its
    // groups.
    let mut runs: Vec<&[&[Mark]]> = Vec::new();
    let mut a = 0;
    for b in 1..=groups.len() {
        if b == groups.len() || groups[b][0].0 != groups[a][0].0 {
            runs.push(&groups[a..b]);
            a = b;
        }
    }
    let mark_flags: &[bool] = is_mark;
    let cleared: Vec<usize> = runs
        .par_iter()
        .flat_map_iter(|run| {
            let k = (run[0][0].0 - s0) as usize;
            let asphalt: Vec<[f64; 3]> = by_slice[start[k]..start[k + 1]]
                .iter()
                .filter(|&&i| !mark_flags[i])
                .map(|&i| [input.offset[i], input.mileage[i], input.z[i]])
                .collect();
            run.iter()
                .filter(|g| below_road(g, &asphalt, input, p))
                .flat_map(|g| g.iter().map(|&(_, _, i)| i))
                .collect::<Vec<usize>>()
        })
        .collect();
    for &i in &cleared {
        is_mark[i] = false;
    }
    cleared.len()
}

/// Whether one group (points of one slice and component) lies below the asphalt beside it.
fn below_road(group: &[Mark], asphalt: &[[f64; 3]], input: &Input<'_>, p: &Params) -> bool {
    let (o, m, z) = (input.offset, input.mileage, input.z);
    let mut scratch: Vec<f64> = group.iter().map(|&(_, _, i)| o[i]).collect();
    let side = if median(&mut scratch) < 0.0 { -1.0 } else { 1.0 };
    // Across-road extent on this side (|offset|), robust to a few stray points.
    for v in scratch.iter_mut() {
        *v *= side;
    }
    scratch.sort_unstable_by(f64::total_cmp);
    let q = |f: f64| scratch[((scratch.len() - 1) as f64 * f).round() as usize];
    let (inner, outer) = (q(0.05), q(0.95));
    if inner <= 0.0 || outer - inner > p.max_width_m {
        return false; // across the trajectory or not a line piece
    }
    let (band_lo, band_hi) = (inner - p.gap_m - p.reference_width_m, inner - p.gap_m);
    let mut reference: Vec<[f64; 3]> = asphalt
        .iter()
        .filter(|r| {
            let u = side * r[0];
            u >= band_lo && u < band_hi
        })
        .copied()
        .collect();
    if reference.len() < p.min_reference_points as usize {
        return false;
    }
    // A total order on the band, so that not even the rounding of the fit depends on the
    // order of the points.
    reference.sort_unstable_by(|x, y| {
        x[0].total_cmp(&y[0])
            .then(x[1].total_cmp(&y[1]))
            .then(x[2].total_cmp(&y[2]))
    });
    let Some(plane) = lsq_plane(&reference) else {
        return false;
    };
    let mut res: Vec<f64> = reference.iter().map(|r| r[2] - plane.at(r[0], r[1])).collect();
    let mid = median(&mut res);
    for r in res.iter_mut() {
        *r = (*r - mid).abs();
    }
    let sigma = 1.4826 * median(&mut res);
    if sigma > p.max_reference_noise_m {
        return false; // not one plane: a crown, a step or another level in the band
    }
    let mut drop: Vec<f64> = group
        .iter()
        .map(|&(_, _, i)| z[i] - plane.at(o[i], m[i]))
        .collect();
    let h = median(&mut drop);
    let need = p
        .min_drop_m
        .max(p.noise_factor * sigma / (group.len() as f64).sqrt());
    if h >= -need {
        return false;
    }
    // A verge keeps falling away beyond the strip; where the surface beyond it is back at
    // the road's level the strip lies in the road (a line in a rut, or a scanner's
    // per-laser height bias on a ring scan): paint, not verge.
    let (out_lo, out_hi) = (outer + p.gap_m, outer + p.gap_m + p.reference_width_m);
    let mut beyond: Vec<f64> = asphalt
        .iter()
        .filter(|r| {
            let u = side * r[0];
            u >= out_lo && u < out_hi
        })
        .map(|r| r[2] - plane.at(r[0], r[1]))
        .collect();
    beyond.len() < p.min_reference_points as usize || median(&mut beyond) < -need
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 2 m slice across the right edge of a road: asphalt with a 2 % cross slope from the
    /// trajectory out to `edge` (negative offsets), then a verge falling away at `verge_slope`
    /// (relative to the horizontal) for 1 m. Points on a jittered 2.5 cm grid with ±3 mm
    /// height noise; `marked(u)` says which offsets the threshold marked.
    fn slice(edge: f64, verge_slope: f64, marked: impl Fn(f64) -> bool, paint_mm: f64) -> Scene {
        let mut s = Scene::default();
        let mut jit = crate::pipeline::geom::test_jitter(11);
        for i in 0..80 {
            for j in 0..200 {
                // Within one slice [0, 2) whatever the jitter.
                let m = 0.01 + i as f64 * 0.025 + 0.01 * jit();
                let u = -1.0 - j as f64 * 0.025 + 0.01 * jit();
                let road = 0.02 * u; // falls towards negative u
                let mut z = if u >= edge {
                    road
                } else {
                    0.02 * edge - verge_slope * (edge - u)
                };
                let mark = marked(u);
                if mark && u >= edge {
                    z += paint_mm * 1e-3;
                }
                z += 0.006 * jit();
                s.m.push(m);
                s.u.push(u);
                s.z.push(z);
                s.mark.push(mark);
            }
        }
        s
    }

    #[derive(Default)]
    struct Scene {
        m: Vec<f64>,
        u: Vec<f64>,
        z: Vec<f64>,
        mark: Vec<bool>,
    }

    fn run_on(s: &Scene, p: &Params) -> Vec<bool> {
        let slice: Vec<i64> = s.m.iter().map(|&m| (m / 2.0).floor() as i64).collect();
        // Mask components: one for the marks beyond u = -3.5, one for those inside.
        let label: Vec<u32> = (0..s.m.len())
            .map(|i| match (s.mark[i], s.u[i] < -3.5) {
                (false, _) => 0,
                (true, true) => 1,
                (true, false) => 2,
            })
            .collect();
        let mut mark = s.mark.clone();
        clear_verge(
            &Input {
                mileage: &s.m,
                offset: &s.u,
                z: &s.z,
                slice: &slice,
                label: &label,
            },
            &mut mark,
            p,
        );
        mark
    }

    #[test]
    fn defaults_validate_and_absurd_values_are_named() {
        Params::default().validate().unwrap();
        let p = Params {
            min_drop_m: -1.0,
            ..Params::default()
        };
        assert!(p.validate().unwrap_err().starts_with("min_drop_m"));
        let p = Params {
            min_reference_points: 2,
            ..Params::default()
        };
        assert!(p.validate().unwrap_err().starts_with("min_reference_points"));
    }

    #[test]
    fn empty_input_and_switched_off_step_change_nothing() {
        let none = Input {
            mileage: &[],
            offset: &[],
            z: &[],
            slice: &[],
            label: &[],
        };
        assert_eq!(clear_verge(&none, &mut [], &Params::default()), 0);
        let s = slice(-4.0, 0.067, |u| (-4.6..-4.05).contains(&u), 0.0);
        let off = Params {
            min_drop_m: 0.0,
            ..Params::default()
        };
        assert_eq!(run_on(&s, &off), s.mark);
    }

    /// The bright first 0.55 m of a grass verge that falls away at 6.7 % beside a road
    /// with a 2 % cross slope (the strip ends 2.5 cm below the road's plane): cleared.
    #[test]
    fn a_bright_strip_of_verge_below_the_road_is_cleared() {
        let s = slice(-4.0, 0.067, |u| (-4.6..-4.05).contains(&u), 0.0);
        let kept = run_on(&s, &Params::default());
        let before = s.mark.iter().filter(|&&b| b).count();
        assert!(before > 300, "the scene has a strip: {before}");
        assert_eq!(kept.iter().filter(|&&b| b).count(), 0);
    }

    /// A 0.15 m edge line painted right at the asphalt edge (2 mm proud of it) with the
    /// verge falling away beyond it: kept, and so is a line in the middle of the road.
    #[test]
    fn an_edge_line_at_the_asphalt_edge_is_kept() {
        let at_edge = |u: f64| (-4.0..-3.85).contains(&u);
        let s = slice(-4.0, 0.067, at_edge, 2.0);
        assert_eq!(run_on(&s, &Params::default()), s.mark);
        let inside = |u: f64| (-3.0..-2.85).contains(&u);
        let s = slice(-4.0, 0.1, inside, 0.0);
        assert_eq!(run_on(&s, &Params::default()), s.mark);
    }

    #[test]
    fn result_does_not_depend_on_point_order() {
        let s = slice(
            -4.0,
            0.067,
            |u| (-4.6..-4.05).contains(&u) || (-3.0..-2.85).contains(&u),
            0.0,
        );
        let a = run_on(&s, &Params::default());
        let rev = |v: &[f64]| v.iter().rev().copied().collect::<Vec<_>>();
        let r = Scene {
            m: rev(&s.m),
            u: rev(&s.u),
            z: rev(&s.z),
            mark: s.mark.iter().rev().copied().collect(),
        };
        let mut b = run_on(&r, &Params::default());
        b.reverse();
        assert_eq!(a, b);
        // The line inside the road stays, the strip goes.
        let line = (0..s.u.len()).filter(|&i| (-3.0..-2.85).contains(&s.u[i]));
        assert!(line.clone().all(|i| a[i]));
        assert!((0..s.u.len()).filter(|&i| s.u[i] < -4.05).all(|i| !a[i]));
    }
}
