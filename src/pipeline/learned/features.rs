//! Feature preparation for the learned classifier: one cluster → a fixed-size, normalised
//! point set in farthest-point order.
//!
//! # What
//! The network sees every cluster as exactly `n` points × [`FEATURES_PER_POINT`] values
//! (`along, across, dz, intensity`), the same contract in training (`roadmark export-clusters`
//! writes these arrays with this very code) and in the pipeline.
//!
//! # Algorithm
//! 1. **Local frame** aligned to the driving direction `d` at the cluster: origin at the
//!    centroid, `along = (p − c)·d`, `across = d × (p − c)` (positive to the left), both divided
//!    by [`COORD_SCALE_M`]. The frame is metric (no per-cluster scaling) because size tells a
//!    2 m dash from a 6 m one; it is tied to the trajectory, not to the cluster's own axis,
//!    because a guideline stripe is told from a dash by its angle to the road.
//! 2. `dz` = height above the cluster's least-squares plane z = a + b·along + c·across, divided
//!    by [`Z_SCALE_M`] and clipped to ±[`FEATURE_CLIP`]: paint is flat, clutter is not. The
//!    plane, not the median, is the reference so that the road's crossfall and grade (which
//!    say where a marking lies, not what it is) do not reach the network; a cluster too small
//!    or too thin for a plane falls back to its median height. `intensity` = I / median I − 1,
//!    clipped to ±1: a ratio, so sensors with other intensity scales and range fall-off do
//!    not matter.
//! 3. **Farthest-point sampling** (PointNet++, Qi et al. 2017) in the (along, across) plane,
//!    starting from the point nearest the centroid (so the order does not depend on the input
//!    order and is invariant under rotations and mirroring of the cluster). The first `k`
//!    points of an FPS order are the FPS sample of size `k`, so the network takes its
//!    set-abstraction centroids as prefixes of the input: no sampling loop inside the graph.
//!    Clusters with fewer than `n` points are padded by cycling through their FPS order
//!    (duplicates do not change a max-pooled feature); clusters with more than
//!    [`MAX_FPS_INPUT`] points are first thinned by a fixed stride.
//!
//! # Parameters
//! `n` (points per cluster, stored in the model's metadata, 256 for the shipped model).
//!
//! # Reference
//! Qi, Yi, Su, Guibas: PointNet++: Deep Hierarchical Feature Learning on Point Sets in a Metric
//! Space, NeurIPS 2017. Yao et al. 2019/2021 (see `papers/README.md`) feed PointNet++ with
//! marking clusters the same way.
//!
//! # Complexity
//! O(m·n) per cluster for m ≤ [`MAX_FPS_INPUT`] input points; O(n) memory besides the output.

use crate::pipeline::types::PointCloud;

/// Values per point: along, across, dz, intensity.
pub const FEATURES_PER_POINT: usize = 4;
/// Metres per unit of the along/across coordinates (a 9 m arrow spans about ±1.1).
pub const COORD_SCALE_M: f64 = 4.0;
/// Metres per unit of the height feature.
pub const Z_SCALE_M: f64 = 0.1;
/// Height features are clipped to ± this.
pub const FEATURE_CLIP: f64 = 4.0;
/// Larger clusters are thinned by a stride before sampling (bounds the O(m·n) cost).
pub const MAX_FPS_INPUT: usize = 8192;
/// Version of this feature recipe; the model's metadata must name the same.
pub const FEATURE_VERSION: &str = "2";

/// The points of one cluster and the driving direction there.
#[derive(Clone, Copy, Debug)]
pub struct ClusterPoints<'a> {
    /// The cloud the cluster indexes into (local coordinates).
    pub cloud: &'a PointCloud,
    /// Indices of the cluster's points in `cloud`.
    pub indices: &'a [usize],
    /// Unit driving direction at the cluster (x = east, y = north), e.g. from
    /// [`crate::pipeline::types::Trajectory::locate`] at the centroid.
    pub direction: [f64; 2],
}

/// Write the features of one cluster into `out` (`n × FEATURES_PER_POINT` values, row-major).
///
/// An empty cluster gives all zeros. `direction` need not be normalised; a zero direction
/// falls back to east.
pub fn prepare(cluster: &ClusterPoints<'_>, n: usize, out: &mut [f32]) {
    assert_eq!(out.len(), n * FEATURES_PER_POINT, "output buffer size");
    out.fill(0.0);
    let cloud = cluster.cloud;
    // Thin very large clusters by a fixed stride: deterministic and spread along the
    // acquisition order, which covers the whole cluster.
    let stride = cluster.indices.len().div_ceil(MAX_FPS_INPUT).max(1);
    let idx: Vec<usize> = cluster.indices.iter().step_by(stride).copied().collect();
    let m = idx.len();
    if m == 0 || n == 0 {
        return;
    }
    let (dx, dy) = {
        let [a, b] = cluster.direction;
        let l = a.hypot(b);
        if l > 0.0 && l.is_finite() {
            (a / l, b / l)
        } else {
            (1.0, 0.0)
        }
    };
    let (cx, cy) = {
        let (mut sx, mut sy) = (0.0, 0.0);
        for &i in &idx {
            sx += cloud.x[i];
            sy += cloud.y[i];
        }
        (sx / m as f64, sy / m as f64)
    };
    let mut is: Vec<f64> = idx.iter().map(|&i| cloud.intensity[i] as f64).collect();
    let i_med = median(&mut is).max(1e-6);

    let mut along = Vec::with_capacity(m);
    let mut across = Vec::with_capacity(m);
    for &i in &idx {
        let (px, py) = (cloud.x[i] - cx, cloud.y[i] - cy);
        along.push((px * dx + py * dy) / COORD_SCALE_M);
        across.push((dx * py - dy * px) / COORD_SCALE_M);
    }
    let zs: Vec<f64> = idx.iter().map(|&i| cloud.z[i]).collect();
    let plane = ground_plane(&along, &across, &zs);
    let order = farthest_point_order(&along, &across, n.min(m));
    for k in 0..n {
        let j = order[k % order.len()];
        let i = idx[j];
        let row = &mut out[k * FEATURES_PER_POINT..(k + 1) * FEATURES_PER_POINT];
        row[0] = along[j] as f32;
        row[1] = across[j] as f32;
        let base = plane[0] + plane[1] * along[j] + plane[2] * across[j];
        row[2] = ((cloud.z[i] - base) / Z_SCALE_M).clamp(-FEATURE_CLIP, FEATURE_CLIP) as f32;
        row[3] = (cloud.intensity[i] as f64 / i_med - 1.0).clamp(-1.0, 1.0) as f32;
    }
}

/// Farthest-point order of `k` of the 2-D points (`xs[i]`, `ys[i]`), starting from the point
/// nearest their centroid; ties go to the lower index, so the result is deterministic.
///
/// O(m·k) time, O(m) memory.
pub fn farthest_point_order(xs: &[f64], ys: &[f64], k: usize) -> Vec<usize> {
    let m = xs.len();
    let k = k.min(m);
    if k == 0 {
        return Vec::new();
    }
    let cx = xs.iter().sum::<f64>() / m as f64;
    let cy = ys.iter().sum::<f64>() / m as f64;
    let mut first = 0;
    let mut best = f64::INFINITY;
    for i in 0..m {
        let d = (xs[i] - cx).powi(2) + (ys[i] - cy).powi(2);
        if d < best {
            best = d;
            first = i;
        }
    }
    let mut order = Vec::with_capacity(k);
    let mut dist = vec![f64::INFINITY; m];
    let mut cur = first;
    for _ in 0..k {
        order.push(cur);
        let (px, py) = (xs[cur], ys[cur]);
        let mut far = 0;
        let mut far_d = -1.0;
        for i in 0..m {
            let d = (xs[i] - px).powi(2) + (ys[i] - py).powi(2);
            if d < dist[i] {
                dist[i] = d;
            }
            if dist[i] > far_d {
                far_d = dist[i];
                far = i;
            }
        }
        cur = far;
    }
    order
}

/// Least-squares plane `z = a + b·u + c·v` through the points, as `[a, b, c]` (`u`, `v` centred
/// on their mean, which the feature frame is). Falls back to the flat plane at the median
/// height when the 2 × 2 system is near-singular (fewer than three points, or all of them on
/// a line), so a thin line does not get an arbitrary tilt across itself.
fn ground_plane(u: &[f64], v: &[f64], z: &[f64]) -> [f64; 3] {
    let m = z.len();
    let mut zs = z.to_vec();
    let z_med = median(&mut zs);
    if m < 3 {
        return [z_med, 0.0, 0.0];
    }
    let (mut suu, mut suv, mut svv, mut suz, mut svz, mut sz) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for k in 0..m {
        let dz = z[k] - z_med;
        suu += u[k] * u[k];
        suv += u[k] * v[k];
        svv += v[k] * v[k];
        suz += u[k] * dz;
        svz += v[k] * dz;
        sz += dz;
    }
    let det = suu * svv - suv * suv;
    // det / (suu·svv) = 1 − correlation² of u and v: near 0 only for collinear point sets.
    // Both axes must spread by more than 1 mm RMS (u, v are in COORD_SCALE_M units).
    let min_sq = (1e-3 / COORD_SCALE_M).powi(2) * m as f64;
    if suu < min_sq || svv < min_sq || det <= 1e-9 * suu * svv {
        return [z_med, 0.0, 0.0];
    }
    let b = (suz * svv - svz * suv) / det;
    let c = (svz * suu - suz * suv) / det;
    // u, v are centred, so the intercept is the mean height.
    [z_med + sz / m as f64, b, c]
}

/// Median of a non-empty slice (reorders it). NaNs sort last.
fn median(v: &mut [f64]) -> f64 {
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    *m
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud(points: &[(f64, f64, f64, f32)]) -> PointCloud {
        let mut c = PointCloud::with_origin([500_000.0, 4_000_000.0, 10.0]);
        for &(x, y, z, i) in points {
            c.push_local(x, y, z, i, None, 0);
        }
        c
    }

    #[test]
    fn empty_cluster_gives_zeros() {
        let c = cloud(&[]);
        let mut out = vec![1.0; 8 * FEATURES_PER_POINT];
        prepare(
            &ClusterPoints {
                cloud: &c,
                indices: &[],
                direction: [1.0, 0.0],
            },
            8,
            &mut out,
        );
        assert!(out.iter().all(|&v| v == 0.0));
    }

    #[test]
    fn fps_visits_extremes_first_and_is_a_permutation() {
        // A 1-D row of points: after the centre, FPS must jump to one end, then the other.
        let xs: Vec<f64> = (0..11).map(|i| i as f64).collect();
        let ys = vec![0.0; 11];
        let order = farthest_point_order(&xs, &ys, 11);
        assert_eq!(order[0], 5);
        assert_eq!(order[1], 0);
        assert_eq!(order[2], 10);
        let mut sorted = order.clone();
        sorted.sort();
        assert_eq!(sorted, (0..11).collect::<Vec<_>>());
        assert_eq!(farthest_point_order(&xs, &ys, 3), order[..3].to_vec());
        assert!(farthest_point_order(&[], &[], 5).is_empty());
    }

    #[test]
    fn frame_follows_the_driving_direction() {
        // A 2 m bar along the north direction, driving north: the bar lies along the first axis.
        let pts: Vec<_> = (0..21).map(|i| (3.0, i as f64 * 0.1, 0.0, 1000.0)).collect();
        let c = cloud(&pts);
        let idx: Vec<usize> = (0..pts.len()).collect();
        let n = 32;
        let mut out = vec![0.0; n * FEATURES_PER_POINT];
        prepare(
            &ClusterPoints {
                cloud: &c,
                indices: &idx,
                direction: [0.0, 2.0],
            },
            n,
            &mut out,
        );
        let along: Vec<f32> = out.chunks(4).map(|r| r[0]).collect();
        let across: Vec<f32> = out.chunks(4).map(|r| r[1]).collect();
        let max_along = along.iter().cloned().fold(f32::MIN, f32::max);
        assert!((max_along as f64 - 1.0 / COORD_SCALE_M).abs() < 1e-6);
        assert!(across.iter().all(|v| v.abs() < 1e-9));
        // 21 points padded to 32 by cycling through the FPS order.
        assert_eq!(out[21 * 4..22 * 4], out[0..4]);
        // Driving south instead mirrors along and across.
        let mut south = vec![0.0; n * FEATURES_PER_POINT];
        prepare(
            &ClusterPoints {
                cloud: &c,
                indices: &idx,
                direction: [0.0, -1.0],
            },
            n,
            &mut south,
        );
        for (a, b) in out.chunks(4).zip(south.chunks(4)) {
            assert!((a[0] + b[0]).abs() < 1e-6 && (a[1] + b[1]).abs() < 1e-6);
        }
    }

    #[test]
    fn road_tilt_does_not_reach_the_height_feature() {
        // A 3 × 1 m patch of paint on a road with 2.5 % crossfall and 3 % grade, with a 6 cm
        // bump (clutter) on one corner: dz is ~0 on the paint, the bump stands out.
        let mut pts = Vec::new();
        for i in 0..60 {
            for j in 0..20 {
                let (x, y) = (i as f64 * 0.05, j as f64 * 0.05);
                let bump = if i >= 55 && j >= 15 { 0.06 } else { 0.0 };
                pts.push((x, y, 0.03 * x + 0.025 * y + bump, 1000.0));
            }
        }
        let c = cloud(&pts);
        let idx: Vec<usize> = (0..pts.len()).collect();
        let n = 256;
        let mut out = vec![0.0; n * FEATURES_PER_POINT];
        prepare(
            &ClusterPoints {
                cloud: &c,
                indices: &idx,
                direction: [1.0, 0.0],
            },
            n,
            &mut out,
        );
        let mut flat = 0;
        for r in out.chunks(4) {
            // Bump points: along ≥ 1.275 m, across ≥ 0.275 m from the centroid (1.475, 0.475).
            let on_bump = r[0] as f64 * COORD_SCALE_M > 1.25 && r[1] as f64 * COORD_SCALE_M > 0.25;
            if on_bump {
                assert!(r[2] > 0.4, "{r:?}");
            } else if (r[0] as f64 * COORD_SCALE_M) < 0.9 {
                assert!(r[2].abs() < 0.1, "{r:?}");
                flat += 1;
            }
        }
        assert!(flat > 100, "{flat}");
        // A single row of points (no extent across) falls back to the median height.
        let row: Vec<_> = (0..50)
            .map(|i| (i as f64 * 0.1, 0.0, 0.01 * i as f64, 1000.0))
            .collect();
        let c = cloud(&row);
        let idx: Vec<usize> = (0..row.len()).collect();
        let mut out = vec![0.0; 64 * FEATURES_PER_POINT];
        prepare(
            &ClusterPoints {
                cloud: &c,
                indices: &idx,
                direction: [1.0, 0.0],
            },
            64,
            &mut out,
        );
        assert!(
            out.chunks(4)
                .all(|r| r[2].is_finite() && r[2].abs() <= FEATURE_CLIP as f32)
        );
        assert!(
            out.chunks(4).any(|r| r[2].abs() > 1.0),
            "median fallback keeps the slope"
        );
    }

    #[test]
    fn features_do_not_depend_on_point_order_or_intensity_scale() {
        let pts: Vec<_> = (0..300)
            .map(|i| {
                let a = i as f64 * 0.37;
                (
                    a.cos() * (i % 17) as f64 * 0.1,
                    a.sin() * 0.5,
                    0.01 * (i % 3) as f64,
                    900.0 + (i % 7) as f32,
                )
            })
            .collect();
        let c = cloud(&pts);
        let scaled = cloud(
            &pts.iter()
                .map(|&(x, y, z, i)| (x, y, z, i * 3.0))
                .collect::<Vec<_>>(),
        );
        let idx: Vec<usize> = (0..pts.len()).collect();
        let rev: Vec<usize> = idx.iter().rev().copied().collect();
        let n = 64;
        let run = |c: &PointCloud, ix: &[usize]| {
            let mut o = vec![0.0; n * FEATURES_PER_POINT];
            prepare(
                &ClusterPoints {
                    cloud: c,
                    indices: ix,
                    direction: [1.0, 1.0],
                },
                n,
                &mut o,
            );
            o
        };
        let a = run(&c, &idx);
        let b = run(&c, &rev);
        let s = run(&scaled, &idx);
        for ((x, y), z) in a.iter().zip(&b).zip(&s) {
            assert!((x - y).abs() < 1e-5 && (x - z).abs() < 1e-5);
        }
        assert!(a.iter().all(|v| v.is_finite() && v.abs() <= FEATURE_CLIP as f32));
    }
}
