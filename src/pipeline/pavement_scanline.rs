//! Stage 1, alternative: pavement from scan lines in acquisition order (Yao et al. 2021).
//!
//! **What.** The scan-line pavement method of Yao et al. (2021 § 2.1), selected with
//! `pavement.method: "scan_lines"`. It needs the points of each scanner head in
//! acquisition order (GPS time when present, else file order) and suits single-profile
//! scanners; the default slice method does not depend on order.
//!
//! **Algorithm.** Per scanner head, with `d_i` the 3D distance between consecutive points:
//! 1. *Key points* (eq. 2): `d_i > d_{i-1}`, `d_i > d_{i+1}` and `d_i > Ld`
//!    (`key_gap_m`, ≈ 1/3 of the road width): the jumps between scan lines, e.g. through
//!    the sky.
//! 2. *Leap points* (eq. 3–5): a key point followed by more than `Mn` points and more than
//!    `Ml` (`min_line_length_m`) of path before the next key point; `Mn` is
//!    `min_line_points`, or 0.75 × the mean key-point spacing when 0 (eq. 5). Consecutive
//!    leap points delimit one scan line.
//! 3. *Break points* (eq. 10–12): point i breaks the line when `ds > cH` (`curb_height_m`)
//!    and either `dxy = 0`, the slope exceeds `mS` (`min_curb_slope_deg`) or
//!    `dh > fH` (`fluctuation_m`).
//! 4. The longest run of non-break points is the pavement of the scan line when it holds
//!    more than `minN` points (eq. 28; `min_pavement_fraction` of the line's points, the
//!    paper uses one half).
//!
//! **Parameters** ([`Params`], defaults): `key_gap_m` 3.0, `min_line_length_m` 5.0,
//! `min_line_points` 0 (eq. 5), `curb_height_m` 0.08, `min_curb_slope_deg` 25,
//! `fluctuation_m` 0.05, `min_pavement_fraction` 0.5.
//!
//! **Reference.** Yao L., Qin C., Chen Q., Wu H. (2021) Automatic road marking extraction
//! and vectorization from vehicle-borne laser scanning data, Remote Sensing 13(13):2612.
//!
//! **Complexity.** O(n log n) for ordering by GPS time, then O(n).

use super::pavement::{Input, check_range};
use serde::{Deserialize, Serialize};

/// Parameters of the scan-line method (JSON object `pavement.scan_lines`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Params {
    /// Ld: minimum 3D jump between scan lines (m).
    pub key_gap_m: f64,
    /// Ml: minimum path length of a scan line (m).
    pub min_line_length_m: f64,
    /// Mn: minimum points of a scan line; 0 = 0.75 × mean key spacing (eq. 5).
    pub min_line_points: u32,
    /// cH: curb height threshold on the 3D step (m).
    pub curb_height_m: f64,
    /// mS: minimum slope of a curb step (degrees).
    pub min_curb_slope_deg: f64,
    /// fH: height fluctuation of the pavement (m).
    pub fluctuation_m: f64,
    /// minN as a fraction of the scan line's points.
    pub min_pavement_fraction: f64,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            key_gap_m: 3.0,
            min_line_length_m: 5.0,
            min_line_points: 0,
            curb_height_m: 0.08,
            min_curb_slope_deg: 25.0,
            fluctuation_m: 0.05,
            min_pavement_fraction: 0.5,
        }
    }
}

impl Params {
    /// Check every field; the message names the offending parameter.
    pub fn validate(&self) -> Result<(), String> {
        check_range("key_gap_m", self.key_gap_m, 0.01, 100.0)?;
        check_range("min_line_length_m", self.min_line_length_m, 0.0, 1000.0)?;
        check_range("curb_height_m", self.curb_height_m, 0.001, 2.0)?;
        check_range("min_curb_slope_deg", self.min_curb_slope_deg, 0.0, 90.0)?;
        check_range("fluctuation_m", self.fluctuation_m, 0.001, 2.0)?;
        check_range("min_pavement_fraction", self.min_pavement_fraction, 0.0, 1.0)?;
        Ok(())
    }
}

/// Indices (ascending) of the pavement points.
pub fn run(input: &Input<'_>, p: &Params, max_offset_m: f64) -> Vec<usize> {
    let n = input.z.len();
    let mut heads: Vec<u8> = input.scanner.to_vec();
    heads.sort_unstable();
    heads.dedup();
    let mut kept = Vec::new();
    for h in heads {
        let mut order: Vec<usize> = (0..n).filter(|&i| input.scanner[i] == h).collect();
        if let Some(t) = input.gps_time {
            order.sort_by(|&a, &b| t[a].total_cmp(&t[b])); // stable: ties keep file order
        }
        kept.extend(head_pavement(&order, input, p));
    }
    kept.retain(|&i| input.offset[i].abs() <= max_offset_m);
    kept.sort_unstable();
    kept
}

fn head_pavement(order: &[usize], input: &Input<'_>, p: &Params) -> Vec<usize> {
    let m = order.len();
    if m < 3 {
        return Vec::new();
    }
    let pos = |k: usize| {
        let i = order[k];
        (input.x[i], input.y[i], input.z[i])
    };
    // d[k] = distance between the k-th and (k+1)-th point.
    let d: Vec<f64> = (0..m - 1)
        .map(|k| {
            let (a, b) = (pos(k), pos(k + 1));
            ((b.0 - a.0).powi(2) + (b.1 - a.1).powi(2) + (b.2 - a.2).powi(2)).sqrt()
        })
        .collect();
    // 1. Key points: local maxima of the gap above Ld (gap after point k).
    let keys: Vec<usize> = (0..d.len())
        .filter(|&k| {
            let prev = if k > 0 { d[k - 1] } else { f64::NEG_INFINITY };
            let next = d.get(k + 1).copied().unwrap_or(f64::NEG_INFINITY);
            d[k] > p.key_gap_m && d[k] > prev && d[k] > next
        })
        .collect();
    // 2. Leap points. Line boundaries include the first and last point.
    let mn = if p.min_line_points > 0 {
        p.min_line_points as f64
    } else if keys.len() >= 2 {
        0.75 * (keys[keys.len() - 1] - keys[0]) as f64 / (keys.len() - 1) as f64
    } else {
        0.0
    };
    let mut bounds: Vec<usize> = vec![0]; // start index (in `order`) of each scan line
    for (j, &k) in keys.iter().enumerate() {
        let next = keys.get(j + 1).copied().unwrap_or(m - 1);
        let count = next.saturating_sub(k);
        let length: f64 = d[k + 1..next.min(d.len())].iter().sum();
        if count as f64 > mn && length > p.min_line_length_m {
            bounds.push(k + 1);
        }
    }
    bounds.push(m);
    bounds.dedup();
    // 3–4. Break points and the longest run per scan line.
    let slope_lim = p.min_curb_slope_deg.to_radians();
    let mut kept = Vec::new();
    for w in bounds.windows(2) {
        let (a, b) = (w[0], w[1]);
        if b - a < 2 {
            continue;
        }
        let (mut best, mut best_len) = ((a, a), 0usize);
        let mut run_start = a;
        for k in a + 1..=b {
            let brk = k == b || {
                let (p0, p1) = (pos(k - 1), pos(k));
                let dh = (p1.2 - p0.2).abs();
                let dxy = (p1.0 - p0.0).hypot(p1.1 - p0.1);
                let ds = dxy.hypot(dh);
                ds > p.curb_height_m && (dxy == 0.0 || dh.atan2(dxy) > slope_lim || dh > p.fluctuation_m)
            };
            if brk {
                if k - run_start > best_len {
                    best_len = k - run_start;
                    best = (run_start, k);
                }
                run_start = k;
            }
        }
        if best_len as f64 > p.min_pavement_fraction * (b - a) as f64 {
            kept.extend(order[best.0..best.1].iter().copied());
        }
    }
    kept
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Profiles across a road from a scanner at height 2 m: sidewalk (0.15 m up) on both
    /// sides of a 7 m road; between profiles the beam sweeps the sky (no returns), so the
    /// next profile starts far from where the previous one ended.
    fn profiles(n_lines: usize) -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<bool>) {
        let (mut x, mut y, mut z, mut road) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for l in 0..n_lines {
            let along = l as f64 * 0.05;
            // right sidewalk, road, left sidewalk: u from -6 to 6
            for j in 0..=480 {
                let u = -6.0 + j as f64 * 0.025;
                let on_road = u.abs() < 3.5;
                x.push(along);
                y.push(u);
                z.push(if on_road { 0.0 } else { 0.15 });
                road.push(on_road);
            }
            // a facade and roof points going up on the left, then the sky gap
            for j in 0..40 {
                x.push(along);
                y.push(6.5);
                z.push(0.2 + j as f64 * 0.2);
                road.push(false);
            }
        }
        (x, y, z, road)
    }

    #[test]
    fn scan_lines_keep_the_road_between_curbs() {
        let (x, y, z, road) = profiles(20);
        let heads = vec![0u8; x.len()];
        let input = Input {
            x: &x,
            y: &y,
            z: &z,
            mileage: &x,
            offset: &y,
            gps_time: None,
            scanner: &heads,
        };
        let kept = run(&input, &Params::default(), 30.0);
        let expected: Vec<usize> = (0..x.len()).filter(|&i| road[i]).collect();
        assert_eq!(kept, expected);
    }

    #[test]
    fn gps_time_orders_points_of_each_head() {
        let (x, y, z, road) = profiles(10);
        // Shuffle deterministically; GPS time restores the order.
        let n = x.len();
        let perm: Vec<usize> = (0..n).map(|i| (i * 7919) % n).collect();
        let pick = |v: &[f64]| perm.iter().map(|&i| v[i]).collect::<Vec<_>>();
        let t: Vec<f64> = perm.iter().map(|&i| i as f64).collect();
        let (xs, ys, zs) = (pick(&x), pick(&y), pick(&z));
        let heads = vec![3u8; n];
        let input = Input {
            x: &xs,
            y: &ys,
            z: &zs,
            mileage: &xs,
            offset: &ys,
            gps_time: Some(&t),
            scanner: &heads,
        };
        let kept = run(&input, &Params::default(), 30.0);
        assert_eq!(kept.len(), road.iter().filter(|&&r| r).count());
        assert!(kept.iter().all(|&k| road[perm[k]]));
    }
}
