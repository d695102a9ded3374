//! Stage 2: intensity normalisation and IDW rasterisation of the pavement points.
//!
//! **What.** Turns the pavement points of one chunk into a grey image whose pixels say how
//! much brighter than the surrounding asphalt the road is there, so that one threshold
//! works for near and far lanes, for every scanner head and for any intensity scale.
//!
//! **Algorithm.**
//! 1. *Background normalisation.* Raw intensity falls with range and incidence angle and
//!    differs between scanner heads, so a marking in a far lane can be darker than bare
//!    asphalt near the vehicle. For every scanner head, every trajectory slice (the
//!    pavement stage's mileage slices) and every lateral-offset bin (`background_bin_m`
//!    across the road) a log-intensity histogram is built; the background of a
//!    (head, slice, bin) is the `background_percentile` of the histograms of the slices
//!    within `background_window_slices` on either side — a robust statistic, because
//!    paint covers far less than half of a 1 m wide, 10 m long strip of road. Sparse
//!    strips borrow from neighbouring offset bins, then from the whole head. At long range
//!    weak asphalt returns drop out and a strip holding a line can be mostly paint by
//!    count, so a strip's background is the median of its own and its two neighbours'
//!    across the road (the lower of two at the edge). Each point's
//!    background is bilinearly interpolated (mileage × offset) between strip centres, and
//!    the point's value becomes `intensity / background` (asphalt ≈ 1, paint ≫ 1). Nothing
//!    assumes a particular range law, so it carries over to other scanners and roads.
//! 2. *IDW* (Yao et al. 2019 eq. 10–12; Yao et al. 2021 eq. 13–15): each pixel of
//!    `cell_size_m` takes the inverse-distance-weighted mean (weight `1/d^power`) of the
//!    points within `radius_m` of its centre; pixels with no point are no-data (NaN). For
//!    speed the points are first summed into `subcells` × `subcells` sub-cells per pixel
//!    and each sub-cell acts as one weighted sample at its centre (position error
//!    ≤ cell/subcells·√2/2, 1.8 cm by default): the IDW then becomes a fixed sparse
//!    convolution whose cost depends on the area, not on the point density. The paper's
//!    min–max normalisation (eq. 13) is not needed: values are already relative.
//!
//! The grid is aligned to global multiples of the cell size in the job's local frame, so
//! overlapping chunks compute bit-identical pixels.
//!
//! **Parameters** ([`Params`]): `cell_size_m` 0.05, `radius_m` 0.15, `power` 1 (Yao 2019;
//! Yao 2021 preferred 3 on its data), `subcells` 2, `background_bin_m` 1.0,
//! `background_window_slices` 2, `background_percentile` 0.5, `background_min_points` 30.
//!
//! **Reference.** Yao L., Qin C., Chen Q., Wu H., Zhang S. (2019) ISPRS Archives XLII-2/W13;
//! Yao L. et al. (2021) Remote Sensing 13:2612.
//!
//! **Complexity.** Normalisation O(n + strips · 512); IDW O(n + pixels · taps) with
//! taps ≈ π (radius·subcells/cell)² (≈ 113 by default), parallel over pixel rows.

use super::geom::floor_i64;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Parameters of this stage (JSON object `rasterize` in the job parameters).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Params {
    /// Pixel size (m). Papers: 0.05.
    pub cell_size_m: f64,
    /// IDW search radius around each pixel centre (m). Papers: 0.15.
    pub radius_m: f64,
    /// IDW weight exponent: weight = 1 / d^power. Yao 2019: 1; Yao 2021: 3.
    pub power: f64,
    /// Sub-cells per pixel side used to pre-aggregate points (even, 2..=8).
    pub subcells: u32,
    /// Width of the lateral-offset bins of the background estimate (m).
    pub background_bin_m: f64,
    /// Slices on either side pooled into a background estimate (window = 2k+1 slices).
    pub background_window_slices: u32,
    /// Quantile of the pooled intensities taken as the asphalt background (0..1).
    pub background_percentile: f64,
    /// Fewer points than this in a strip: borrow from neighbouring offset bins.
    pub background_min_points: u32,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            cell_size_m: 0.05,
            radius_m: 0.15,
            power: 1.0,
            subcells: 2,
            background_bin_m: 1.0,
            background_window_slices: 2,
            background_percentile: 0.5,
            background_min_points: 30,
        }
    }
}

fn check_range(name: &str, v: f64, lo: f64, hi: f64) -> Result<(), String> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(format!("{name}: must be within {lo}..={hi}, got {v}"))
    }
}

impl Params {
    /// Check every field; the message names the offending parameter.
    pub fn validate(&self) -> Result<(), String> {
        check_range("cell_size_m", self.cell_size_m, 0.005, 1.0)?;
        check_range("radius_m", self.radius_m, 0.0, 2.0)?;
        if self.radius_m < self.cell_size_m / 2.0 {
            return Err(format!(
                "radius_m: must be at least half of cell_size_m ({}), got {}",
                self.cell_size_m / 2.0,
                self.radius_m
            ));
        }
        if self.radius_m / self.cell_size_m > 20.0 {
            return Err(format!(
                "radius_m: at most 20 pixels ({} m), got {}",
                20.0 * self.cell_size_m,
                self.radius_m
            ));
        }
        check_range("power", self.power, 0.0, 8.0)?;
        if !(2..=8).contains(&self.subcells) || !self.subcells.is_multiple_of(2) {
            return Err(format!("subcells: must be 2, 4, 6 or 8, got {}", self.subcells));
        }
        check_range("background_bin_m", self.background_bin_m, 0.1, 10.0)?;
        if self.background_window_slices > 50 {
            return Err(format!(
                "background_window_slices: at most 50, got {}",
                self.background_window_slices
            ));
        }
        check_range("background_percentile", self.background_percentile, 0.01, 0.99)?;
        if self.background_min_points == 0 {
            return Err("background_min_points: must be at least 1".into());
        }
        Ok(())
    }
}

/// A regular grid aligned to global multiples of `cell_m` in the job's local frame.
///
/// Row 0 is the southernmost row; `data` is row-major. Cell `(col, row)` covers
/// `[(col0 + col)·cell, (col0 + col + 1)·cell) × [(row0 + row)·cell, …)`.
#[derive(Clone, Debug, PartialEq)]
pub struct Raster<T> {
    /// Global column index of column 0 (x = col0 · cell_m is its west edge).
    pub col0: i64,
    /// Global row index of row 0.
    pub row0: i64,
    pub cell_m: f64,
    pub width: usize,
    pub height: usize,
    pub data: Vec<T>,
}

impl<T: Clone> Raster<T> {
    pub fn new(col0: i64, row0: i64, cell_m: f64, width: usize, height: usize, fill: T) -> Self {
        Self {
            col0,
            row0,
            cell_m,
            width,
            height,
            data: vec![fill; width * height],
        }
    }

    /// The smallest grid covering every (x, y), or an empty raster when there is none.
    pub fn covering(xs: &[f64], ys: &[f64], cell_m: f64, margin_cells: i64, fill: T) -> Self {
        if xs.is_empty() {
            return Self::new(0, 0, cell_m, 0, 0, fill);
        }
        let (mut c0, mut c1, mut r0, mut r1) = (i64::MAX, i64::MIN, i64::MAX, i64::MIN);
        for (&x, &y) in xs.iter().zip(ys) {
            let (c, r) = (global_index(x, cell_m), global_index(y, cell_m));
            c0 = c0.min(c);
            c1 = c1.max(c);
            r0 = r0.min(r);
            r1 = r1.max(r);
        }
        let (c0, r0) = (c0 - margin_cells, r0 - margin_cells);
        let (c1, r1) = (c1 + margin_cells, r1 + margin_cells);
        Self::new(
            c0,
            r0,
            cell_m,
            (c1 - c0 + 1) as usize,
            (r1 - r0 + 1) as usize,
            fill,
        )
    }

    #[inline]
    pub fn get(&self, col: usize, row: usize) -> &T {
        &self.data[row * self.width + col]
    }

    #[inline]
    pub fn set(&mut self, col: usize, row: usize, v: T) {
        self.data[row * self.width + col] = v;
    }

    /// Local (col, row) of the cell holding (x, y), when inside the raster.
    #[inline]
    pub fn cell_of(&self, x: f64, y: f64) -> Option<(usize, usize)> {
        let c = global_index(x, self.cell_m) - self.col0;
        let r = global_index(y, self.cell_m) - self.row0;
        (c >= 0 && r >= 0 && (c as usize) < self.width && (r as usize) < self.height)
            .then_some((c as usize, r as usize))
    }

    /// Centre of cell (col, row) in local coordinates.
    pub fn centre(&self, col: usize, row: usize) -> [f64; 2] {
        [
            ((self.col0 + col as i64) as f64 + 0.5) * self.cell_m,
            ((self.row0 + row as i64) as f64 + 0.5) * self.cell_m,
        ]
    }

    /// A raster of the same geometry with other contents.
    pub fn map<U: Clone + Send, F: Fn(&T) -> U + Sync + Send>(&self, f: F) -> Raster<U>
    where
        T: Sync,
    {
        Raster {
            col0: self.col0,
            row0: self.row0,
            cell_m: self.cell_m,
            width: self.width,
            height: self.height,
            data: self.data.par_iter().map(f).collect(),
        }
    }
}

/// Global grid index of coordinate `v` for cells of `cell` (floor division).
#[inline]
pub fn global_index(v: f64, cell: f64) -> i64 {
    floor_i64(v / cell)
}

// ---------------------------------------------------------------------------------------
// Background normalisation
// ---------------------------------------------------------------------------------------

/// Histogram bins per octave of intensity (1/32 octave ≈ 2.2 % steps).
const BINS_PER_OCTAVE: f32 = 32.0;
/// 17 octaves cover 0..=65535 (values below 1 go to bin 0).
const HIST_BINS: usize = 17 * BINS_PER_OCTAVE as usize;

#[inline]
fn hist_bin(v: f32) -> usize {
    if v <= 1.0 {
        0
    } else {
        ((v.log2() * BINS_PER_OCTAVE) as usize).min(HIST_BINS - 1)
    }
}

#[inline]
fn hist_value(bin: f32) -> f32 {
    (bin / BINS_PER_OCTAVE).exp2()
}

/// The `q` quantile of a log histogram, interpolated within the bin.
fn hist_quantile(h: &[u32], total: u64, q: f64) -> f32 {
    let target = q * total as f64;
    let mut acc = 0u64;
    for (i, &c) in h.iter().enumerate() {
        let next = acc + c as u64;
        if c > 0 && next as f64 >= target {
            let f = ((target - acc as f64) / c as f64).clamp(0.0, 1.0) as f32;
            return hist_value(i as f32 + f);
        }
        acc = next;
    }
    hist_value(h.len() as f32)
}

/// Where each point sits for the background estimate.
pub struct BackgroundInput<'a> {
    pub intensity: &'a [f32],
    pub scanner: &'a [u8],
    /// Global slice index of each point (the pavement stage's mileage slices).
    pub slice: &'a [i64],
    /// Signed lateral offset from the trajectory (m).
    pub offset: &'a [f64],
}

/// Intensity divided by the local asphalt background, per point (asphalt ≈ 1).
///
/// Deterministic and independent of point order; the background of a point depends only
/// on points within `background_window_slices + 1` slices of it.
pub fn normalise(input: &BackgroundInput<'_>, params: &Params) -> Vec<f32> {
    let n = input.intensity.len();
    if n == 0 {
        return Vec::new();
    }
    let mut heads: Vec<u8> = input.scanner.to_vec();
    heads.sort_unstable();
    heads.dedup();
    let mut head_of = [0usize; 256];
    for (i, &h) in heads.iter().enumerate() {
        head_of[h as usize] = i;
    }
    let s_min = *input.slice.iter().min().expect("non-empty");
    let s_max = *input.slice.iter().max().expect("non-empty");
    let bin_m = params.background_bin_m;
    let b_of = |o: f64| floor_i64(o / bin_m);
    let b_min = input.offset.iter().map(|&o| b_of(o)).min().expect("non-empty");
    let b_max = input.offset.iter().map(|&o| b_of(o)).max().expect("non-empty");
    let (nh, ns, nb) = (
        heads.len(),
        (s_max - s_min + 1) as usize,
        (b_max - b_min + 1) as usize,
    );
    let strip = |h: usize, s: usize, b: usize| (h * ns + s) * nb + b;

    // Per-strip log histograms (u32 counts; a strip never holds 4 G points).
    let mut hist = vec![0u32; nh * ns * nb * HIST_BINS];
    for i in 0..n {
        let k = strip(
            head_of[input.scanner[i] as usize],
            (input.slice[i] - s_min) as usize,
            (b_of(input.offset[i]) - b_min) as usize,
        );
        hist[k * HIST_BINS + hist_bin(input.intensity[i])] += 1;
    }

    // Background per (head, slice, bin) pooled over the slice window; widen across offset
    // bins while too sparse, then fall back to the head's whole window.
    let w = params.background_window_slices as i64;
    let min_pts = params.background_min_points as u64;
    let q = params.background_percentile;
    let bg: Vec<f32> = (0..nh * ns * nb)
        .into_par_iter()
        .map(|k| {
            let (h, s, b) = (k / (ns * nb), (k / nb) % ns, k % nb);
            let s_lo = (s as i64 - w).max(0) as usize;
            let s_hi = ((s as i64 + w) as usize).min(ns - 1);
            let mut acc = vec![0u32; HIST_BINS];
            let mut total = 0u64;
            let add = |bb: usize, acc: &mut Vec<u32>| {
                let mut t = 0u64;
                for ss in s_lo..=s_hi {
                    let src = &hist[strip(h, ss, bb) * HIST_BINS..][..HIST_BINS];
                    for (a, &c) in acc.iter_mut().zip(src) {
                        *a += c;
                        t += c as u64;
                    }
                }
                t
            };
            total += add(b, &mut acc);
            let mut r = 1usize;
            while total < min_pts && (r <= b || b + r < nb) {
                if r <= b {
                    total += add(b - r, &mut acc);
                }
                if b + r < nb {
                    total += add(b + r, &mut acc);
                }
                r += 1;
            }
            if total == 0 {
                f32::NAN
            } else {
                hist_quantile(&acc, total, q)
            }
        })
        .collect();

    // Paint returns more points than dark asphalt at long range (weak returns drop out),
    // so a far strip holding a line can be mostly paint by point count and its median read
    // as paint. Paint never fills three neighbouring 1 m bins of one strip except on a
    // crosswalk or a symbol, which the median of three keeps as before: a strip's
    // background is the median of its own value and its two neighbours' across the road,
    // the lower of the two where one neighbour is missing (a contaminated strip only reads
    // too bright).
    let bg: Vec<f32> = (0..nh * ns * nb)
        .into_par_iter()
        .map(|k| {
            let b = k % nb;
            let own = bg[k];
            if !own.is_finite() {
                return own;
            }
            let left = if b > 0 { bg[k - 1] } else { f32::NAN };
            let right = if b + 1 < nb { bg[k + 1] } else { f32::NAN };
            match (left.is_finite(), right.is_finite()) {
                (true, true) => own.max(left.min(right)).min(left.max(right)),
                (true, false) => own.min(left),
                (false, true) => own.min(right),
                (false, false) => own,
            }
        })
        .collect();

    // Fallback for strips with no data at all: the median of the head's known strips.
    let mut known: Vec<f32> = bg.iter().copied().filter(|v| v.is_finite()).collect();
    known.sort_unstable_by(f32::total_cmp);
    let fallback = known.get(known.len() / 2).copied().unwrap_or(1.0).max(1.0);

    let value = |h: usize, s: i64, b: i64| -> f32 {
        let s = s.clamp(0, ns as i64 - 1) as usize;
        let b = b.clamp(0, nb as i64 - 1) as usize;
        let v = bg[strip(h, s, b)];
        if v.is_finite() { v.max(1.0) } else { fallback }
    };

    (0..n)
        .into_par_iter()
        .map(|i| {
            let h = head_of[input.scanner[i] as usize];
            // Bilinear between strip centres: slices along mileage, bins across the road.
            // Slices are identified by index only, so take their centre as index + 0.5 and
            // the point as sitting at its slice centre (sub-slice position is not needed:
            // the window already spans 2k+1 slices).
            let s = input.slice[i] - s_min;
            let fb = input.offset[i] / bin_m - 0.5 - b_min as f64;
            let b0 = floor_i64(fb);
            let tb = (fb - b0 as f64) as f32;
            let v = value(h, s, b0) * (1.0 - tb) + value(h, s, b0 + 1) * tb;
            input.intensity[i] / v
        })
        .collect()
}

// ---------------------------------------------------------------------------------------
// IDW
// ---------------------------------------------------------------------------------------

/// Pixel rows per parallel task of the IDW gather: the task densifies the sub-cell rows
/// its pixels reach once, so the larger the band, the less that is repeated
/// (`(BAND + 2·reach) / BAND`), while bands stay small enough to balance over threads.
const IDW_BAND_ROWS: usize = 32;

/// Inverse-distance-weighted raster of `values` at (xs, ys); NaN where no point is within
/// `radius_m` of a pixel centre. Points with non-finite values are ignored.
///
/// Three steps:
/// 1. Points are keyed by sub-cell and sorted (key, value), so each sub-cell's sum is
///    taken in a fixed order: the pixels do not depend on the order of the points.
/// 2. The non-empty sub-cells are kept sparse (compressed rows), because the chunk's
///    bounding box is mostly empty far from the road and a dense sub-cell grid would cost
///    `subcells²` times the raster's memory.
/// 3. Gather, per band of [`IDW_BAND_ROWS`] pixel rows in parallel: the sub-cell rows the
///    band reaches are made dense, split by column phase (sub-column mod `subcells`) and
///    padded by the kernel reach, so that for one kernel tap the sub-cells of consecutive
///    pixels are consecutive in memory. The loop runs over the taps outside and the pixels
///    inside, without bounds checks, and vectorises. Every pixel adds its taps in raster
///    order of the sub-cells (rows, then columns), which is the order of a direct
///    sparse gather, and empty sub-cells add exact zeros, so the result is bit-identical
///    to it (`idw_equals_the_sparse_gather` keeps that reference).
pub fn idw(xs: &[f64], ys: &[f64], values: &[f32], params: &Params) -> Raster<f32> {
    let cell = params.cell_size_m;
    let q = params.subcells as i64;
    let sub = cell / q as f64;
    let reach = (params.radius_m / cell).ceil() as i64;
    let mut out = Raster::covering(xs, ys, cell, reach, f32::NAN);
    if out.width == 0 {
        return out;
    }
    let subcells = SubCells::new(xs, ys, values, &out, q, sub);
    // Weight table over sub-cell offsets (dc, dr) relative to a pixel's first sub-cell,
    // 0 outside the radius of the pixel centre. Sub-cell centres are never at the pixel
    // centre (subcells is even), so every weight is finite.
    let r2 = params.radius_m * params.radius_m;
    let mut taps: Vec<(i64, i64, f32)> = Vec::new();
    for dr in -reach * q..(reach + 1) * q {
        for dc in -reach * q..(reach + 1) * q {
            let dx = (dc as f64 + 0.5 - q as f64 / 2.0) * sub;
            let dy = (dr as f64 + 0.5 - q as f64 / 2.0) * sub;
            let d2 = dx * dx + dy * dy;
            if d2 <= r2 {
                taps.push((dr, dc, d2.sqrt().powf(-params.power) as f32));
            }
        }
    }
    let width = out.width;
    let qu = q as usize;
    let pad = reach as usize;
    // One phase plane row: pixel columns −reach ..= width − 1 + reach.
    let plane = width + 2 * pad;
    let band_sub_rows = (IDW_BAND_ROWS + 2 * pad) * qu;
    out.data
        .par_chunks_mut(width * IDW_BAND_ROWS)
        .enumerate()
        .for_each_init(
            || {
                (
                    vec![0f32; band_sub_rows * qu * plane],
                    vec![0f32; band_sub_rows * qu * plane],
                    vec![0f32; width],
                    vec![0f32; width],
                )
            },
            |(sums, cnts, num, den), (band, lines)| {
                let row0 = (band * IDW_BAND_ROWS) as i64;
                // Sub-cell row of local row 0 of the dense band.
                let base = (row0 - reach) * q;
                subcells.densify(base, band_sub_rows, pad, plane, sums, cnts);
                for (i, line) in lines.chunks_mut(width).enumerate() {
                    num.fill(0.0);
                    den.fill(0.0);
                    let br = (row0 + i as i64) * q;
                    for &(dr, dc, w) in &taps {
                        let r = br + dr;
                        if r < 0 || r >= subcells.rows {
                            continue;
                        }
                        let (ph, shift) = (dc.rem_euclid(q) as usize, dc.div_euclid(q));
                        let at = ((r - base) as usize * qu + ph) * plane;
                        let from = at + (pad as i64 + shift) as usize;
                        let s = &sums[from..from + width];
                        let c = &cnts[from..from + width];
                        for (((nu, de), &sv), &cv) in num.iter_mut().zip(den.iter_mut()).zip(s).zip(c) {
                            *nu += w * sv;
                            *de += w * cv;
                        }
                    }
                    for ((px, &nu), &de) in line.iter_mut().zip(num.iter()).zip(den.iter()) {
                        if de > 0.0 {
                            *px = nu / de;
                        }
                    }
                }
            },
        );
    out
}

/// `f32` bits as a `u32` whose unsigned order is [`f32::total_cmp`]'s order.
#[inline]
fn ordered_bits(v: f32) -> u32 {
    let b = v.to_bits();
    if b >> 31 == 1 { !b } else { b | 0x8000_0000 }
}

/// Inverse of [`ordered_bits`].
#[inline]
fn from_ordered_bits(u: u32) -> f32 {
    f32::from_bits(if u >> 31 == 1 { u & 0x7FFF_FFFF } else { !u })
}

/// The non-empty sub-cells of a raster, as compressed rows: sub-cell row `r` holds
/// entries `row_start[r]..row_start[r + 1]` of (`cols`, `sum`, `cnt`).
struct SubCells {
    /// Sub-cells per row and rows.
    cols_n: i64,
    rows: i64,
    q: i64,
    cols: Vec<u32>,
    sum: Vec<f32>,
    cnt: Vec<f32>,
    row_start: Vec<usize>,
}

impl SubCells {
    /// Sum and count of the finite values per sub-cell of side `sub` (`q` per pixel side).
    ///
    /// The values of a sub-cell are summed in ascending order (so the sums do not depend
    /// on the point order): points are bucketed by sub-cell row (counting sort), then each
    /// row is sorted in parallel as integers `column << 32 | value bits` (value bits mapped
    /// so that integer order is `f32::total_cmp` order). Cost O(n + rows) plus sorts of
    /// one row each, instead of one comparison sort of every point.
    fn new(xs: &[f64], ys: &[f64], values: &[f32], out: &Raster<f32>, q: i64, sub: f64) -> Self {
        let (sw, sh) = (out.width as i64 * q, out.height as i64 * q);
        let (sc0, sr0) = (out.col0 * q, out.row0 * q);
        // Non-finite values get row `u32::MAX` and are skipped (an indexed map collects
        // in place; a parallel filter would gather per-thread lists first).
        let keyed: Vec<(u32, u64)> = xs
            .par_iter()
            .zip(ys)
            .zip(values)
            .map(|((&x, &y), &v)| {
                if !v.is_finite() {
                    return (u32::MAX, 0);
                }
                let c = (global_index(x, sub) - sc0) as u64;
                let r = (global_index(y, sub) - sr0) as u32;
                (r, (c << 32) | u64::from(ordered_bits(v)))
            })
            .collect();
        let mut row_start = vec![0usize; sh as usize + 1];
        for &(r, _) in &keyed {
            if r != u32::MAX {
                row_start[r as usize + 1] += 1;
            }
        }
        for r in 0..sh as usize {
            row_start[r + 1] += row_start[r];
        }
        let mut packed = vec![0u64; row_start[sh as usize]];
        let mut fill = row_start.clone();
        for &(r, k) in keyed.iter().filter(|e| e.0 != u32::MAX) {
            packed[fill[r as usize]] = k;
            fill[r as usize] += 1;
        }
        drop(keyed);
        let mut rows: Vec<&mut [u64]> = Vec::with_capacity(sh as usize);
        let mut rest = packed.as_mut_slice();
        for r in 0..sh as usize {
            let (row, tail) = rest.split_at_mut(row_start[r + 1] - row_start[r]);
            rows.push(row);
            rest = tail;
        }
        // Per row: sort, then one (column, sum, count) per run of equal columns.
        let runs: Vec<Vec<(u32, f32, f32)>> = rows
            .into_par_iter()
            .map(|row| {
                row.sort_unstable();
                let mut out: Vec<(u32, f32, f32)> = Vec::new();
                for &k in row.iter() {
                    let (c, v) = ((k >> 32) as u32, from_ordered_bits(k as u32));
                    match out.last_mut() {
                        Some(last) if last.0 == c => {
                            last.1 += v;
                            last.2 += 1.0;
                        }
                        _ => out.push((c, v, 1.0)),
                    }
                }
                out
            })
            .collect();
        drop(packed);
        let total = runs.iter().map(Vec::len).sum();
        let (mut cols, mut sum, mut cnt) = (
            Vec::with_capacity(total),
            Vec::with_capacity(total),
            Vec::with_capacity(total),
        );
        for (r, run) in runs.iter().enumerate() {
            row_start[r] = cols.len();
            for &(c, s, n) in run {
                cols.push(c);
                sum.push(s);
                cnt.push(n);
            }
        }
        row_start[sh as usize] = cols.len();
        Self {
            cols_n: sw,
            rows: sh,
            q,
            cols,
            sum,
            cnt,
            row_start,
        }
    }

    /// Write sub-cell rows `base .. base + n_rows` densely into `sums`/`cnts` (zero where
    /// empty or outside the raster): local row `lr`, phase `ph` (sub-column mod q) and
    /// pixel column `pc` go to `(lr·q + ph)·plane + pad + pc`.
    fn densify(
        &self,
        base: i64,
        n_rows: usize,
        pad: usize,
        plane: usize,
        sums: &mut [f32],
        cnts: &mut [f32],
    ) {
        sums.fill(0.0);
        cnts.fill(0.0);
        let q = self.q as usize;
        for lr in 0..n_rows {
            let r = base + lr as i64;
            if r < 0 || r >= self.rows {
                continue;
            }
            for k in self.row_start[r as usize]..self.row_start[r as usize + 1] {
                let c = self.cols[k] as usize;
                debug_assert!((c as i64) < self.cols_n);
                let at = (lr * q + c % q) * plane + pad + c / q;
                sums[at] = self.sum[k];
                cnts[at] = self.cnt[k];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The previous IDW, a sparse scatter (every non-empty sub-cell adds to the pixels in
    /// its reach): the reference that [`idw`] must equal bit for bit.
    fn idw_sparse(xs: &[f64], ys: &[f64], values: &[f32], params: &Params) -> Raster<f32> {
        let cell = params.cell_size_m;
        let q = params.subcells as i64;
        let sub = cell / q as f64;
        let reach = (params.radius_m / cell).ceil() as i64;
        let mut out = Raster::covering(xs, ys, cell, reach, f32::NAN);
        if out.width == 0 {
            return out;
        }
        // Non-empty sub-cells only (a sparse grid: far lanes and off-road areas are mostly
        // empty, and a dense grid of the chunk's whole bounding box would cost memory for
        // nothing): keys sorted by (row, col), then summed per key.
        let (sw, sh) = (out.width as i64 * q, out.height as i64 * q);
        let (sc0, sr0) = (out.col0 * q, out.row0 * q);
        let mut keyed: Vec<(u64, f32)> = xs
            .par_iter()
            .zip(ys)
            .zip(values)
            .filter(|(_, v)| v.is_finite())
            .map(|((&x, &y), &v)| {
                let c = global_index(x, sub) - sc0;
                let r = global_index(y, sub) - sr0;
                ((r * sw + c) as u64, v)
            })
            .collect();
        keyed.par_sort_unstable_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
        let mut cols: Vec<u32> = Vec::new();
        let mut sum: Vec<f32> = Vec::new();
        let mut cnt: Vec<f32> = Vec::new();
        let mut row_start = vec![0usize; sh as usize + 1];
        let mut last = u64::MAX;
        for &(k, v) in &keyed {
            if k != last {
                last = k;
                cols.push((k % sw as u64) as u32);
                sum.push(0.0);
                cnt.push(0.0);
                row_start[(k / sw as u64) as usize + 1] += 1;
            }
            *sum.last_mut().expect("pushed") += v;
            *cnt.last_mut().expect("pushed") += 1.0;
        }
        drop(keyed);
        for r in 0..sh as usize {
            row_start[r + 1] += row_start[r];
        }
        // Weight table over sub-cell offsets (dc, dr) relative to a pixel's first sub-cell,
        // 0 outside the radius of the pixel centre. Sub-cell centres are never at the pixel
        // centre (subcells is even), so every weight is finite.
        let r2 = params.radius_m * params.radius_m;
        let span = ((2 * reach + 1) * q) as usize;
        let mut weight = vec![0f32; span * span];
        for dr in -reach * q..(reach + 1) * q {
            for dc in -reach * q..(reach + 1) * q {
                let dx = (dc as f64 + 0.5 - q as f64 / 2.0) * sub;
                let dy = (dr as f64 + 0.5 - q as f64 / 2.0) * sub;
                let d2 = dx * dx + dy * dy;
                if d2 <= r2 {
                    weight[(dr + reach * q) as usize * span + (dc + reach * q) as usize] =
                        d2.sqrt().powf(-params.power) as f32;
                }
            }
        }
        // Per pixel row: every non-empty sub-cell within reach adds to the pixels whose
        // radius covers it. Cost O(non-empty sub-cells · taps) instead of O(pixels · taps).
        let width = out.width;
        out.data.par_chunks_mut(width).enumerate().for_each_init(
            || (vec![0f32; width], vec![0f32; width]),
            |(num, den), (row, line)| {
                num.fill(0.0);
                den.fill(0.0);
                let br = row as i64 * q;
                for dr in -reach * q..(reach + 1) * q {
                    let r = br + dr;
                    if r < 0 || r >= sh {
                        continue;
                    }
                    let wrow = &weight[(dr + reach * q) as usize * span..][..span];
                    let (lo, hi) = (row_start[r as usize], row_start[r as usize + 1]);
                    for k in lo..hi {
                        let c = cols[k] as i64;
                        let pc = c.div_euclid(q);
                        let (n, sm) = (cnt[k], sum[k]);
                        for col in (pc - reach).max(0)..=(pc + reach).min(width as i64 - 1) {
                            let w = wrow[(c - col * q + reach * q) as usize];
                            num[col as usize] += w * sm;
                            den[col as usize] += w * n;
                        }
                    }
                }
                for ((px, &nu), &de) in line.iter_mut().zip(num.iter()).zip(den.iter()) {
                    if de > 0.0 {
                        *px = nu / de;
                    }
                }
            },
        );
        out
    }

    #[test]
    fn defaults_validate_and_absurd_values_are_named() {
        Params::default().validate().unwrap();
        let p = Params {
            cell_size_m: 0.0,
            ..Params::default()
        };
        assert!(p.validate().unwrap_err().starts_with("cell_size_m"));
        let p = Params {
            radius_m: -1.0,
            ..Params::default()
        };
        assert!(p.validate().unwrap_err().starts_with("radius_m"));
        let p = Params {
            power: f64::NAN,
            ..Params::default()
        };
        assert!(p.validate().unwrap_err().starts_with("power"));
        let p = Params {
            subcells: 3,
            ..Params::default()
        };
        assert!(p.validate().unwrap_err().starts_with("subcells"));
    }

    #[test]
    fn raster_indexing_is_global() {
        let r = Raster::covering(&[-0.01, 0.26], &[1.0, 1.04], 0.05, 0, 0u8);
        assert_eq!((r.col0, r.row0), (-1, 20));
        assert_eq!((r.width, r.height), (7, 1));
        assert_eq!(r.cell_of(0.0, 1.01), Some((1, 0)));
        assert_eq!(r.cell_of(0.36, 1.01), None);
        let c = r.centre(1, 0);
        assert!((c[0] - 0.025).abs() < 1e-12 && (c[1] - 1.025).abs() < 1e-12);
    }

    #[test]
    fn idw_of_a_constant_is_that_constant_and_empty_pixels_are_nan() {
        let mut xs = Vec::new();
        let mut ys = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                xs.push(i as f64 * 0.013);
                ys.push(j as f64 * 0.017);
            }
        }
        let vals = vec![3.5f32; xs.len()];
        let r = idw(&xs, &ys, &vals, &Params::default());
        let finite: Vec<f32> = r.data.iter().copied().filter(|v| v.is_finite()).collect();
        assert!(!finite.is_empty());
        assert!(finite.iter().all(|v| (v - 3.5).abs() < 1e-5));
        // Corner pixels of the margin are farther than the radius from every point.
        assert!(r.get(0, 0).is_nan());
    }

    /// The sparse gather equals a direct IDW over the sub-cell samples.
    #[test]
    fn idw_matches_a_direct_computation() {
        let p = Params::default();
        let mut xs = Vec::new();
        let mut ys = Vec::new();
        let mut vs = Vec::new();
        let mut state = 12345u64;
        let mut rnd = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 33) as f64 / (1u64 << 31) as f64
        };
        for _ in 0..400 {
            xs.push(-0.7 + 1.5 * rnd());
            ys.push(2.0 + 0.8 * rnd());
            vs.push((1.0 + 4.0 * rnd()) as f32);
        }
        let r = idw(&xs, &ys, &vs, &p);
        let sub = p.cell_size_m / p.subcells as f64;
        let centre_of = |v: f64| (global_index(v, sub) as f64 + 0.5) * sub;
        for row in 0..r.height {
            for col in 0..r.width {
                let c = r.centre(col, row);
                let (mut num, mut den) = (0.0f64, 0.0f64);
                for i in 0..xs.len() {
                    let (dx, dy) = (centre_of(xs[i]) - c[0], centre_of(ys[i]) - c[1]);
                    let d2 = dx * dx + dy * dy;
                    if d2 <= p.radius_m * p.radius_m {
                        let w = d2.sqrt().powf(-p.power);
                        num += w * vs[i] as f64;
                        den += w;
                    }
                }
                let got = *r.get(col, row);
                if den > 0.0 {
                    assert!(
                        (got as f64 - num / den).abs() < 1e-3,
                        "({col},{row}): {got} vs {}",
                        num / den
                    );
                } else {
                    assert!(got.is_nan());
                }
            }
        }
    }

    #[test]
    fn ordered_bits_follow_total_cmp() {
        let mut v = vec![
            -f32::INFINITY,
            -3.5,
            -1e-30,
            -0.0,
            0.0,
            1e-40,
            1.0,
            2.5,
            f32::MAX,
            f32::INFINITY,
        ];
        for &x in &v {
            assert_eq!(from_ordered_bits(ordered_bits(x)).to_bits(), x.to_bits());
        }
        let sorted = v.clone();
        v.reverse();
        v.sort_by_key(|&x| ordered_bits(x));
        assert_eq!(
            v.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
            sorted.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
        );
    }

    /// The banded, tap-major gather equals the sparse scatter bit for bit, for several
    /// parameter sets, clouds spanning more than one band, gaps and non-finite values.
    #[test]
    fn idw_equals_the_sparse_gather() {
        let mut state = 99u64;
        let mut rnd = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 33) as f64 / (1u64 << 31) as f64
        };
        let base = Params::default();
        let params = [
            base.clone(),
            Params {
                power: 3.0,
                ..base.clone()
            },
            Params {
                subcells: 4,
                radius_m: 0.2,
                ..base.clone()
            },
            Params {
                subcells: 8,
                cell_size_m: 0.1,
                radius_m: 0.05,
                ..base.clone()
            },
            Params {
                subcells: 2,
                cell_size_m: 0.04,
                radius_m: 0.35,
                power: 0.0,
                ..base.clone()
            },
        ];
        for p in &params {
            let (mut xs, mut ys, mut vs) = (Vec::new(), Vec::new(), Vec::new());
            for i in 0..6000 {
                // Two separated blobs (rows without any point between them), one across
                // several bands; some points share a sub-cell.
                let (x, y) = if i % 3 == 0 {
                    (-3.0 + 0.4 * rnd(), 14.0 + 0.3 * rnd())
                } else {
                    (2.0 + 1.0 * rnd(), -1.0 + 9.0 * rnd())
                };
                xs.push(x);
                ys.push(y);
                vs.push(if i % 97 == 0 {
                    f32::NAN
                } else {
                    (0.5 + 4.0 * rnd()) as f32
                });
            }
            let a = idw(&xs, &ys, &vs, p);
            let b = idw_sparse(&xs, &ys, &vs, p);
            assert_eq!(
                (a.col0, a.row0, a.width, a.height),
                (b.col0, b.row0, b.width, b.height)
            );
            assert!(a.height > 2 * IDW_BAND_ROWS);
            for (k, (u, v)) in a.data.iter().zip(&b.data).enumerate() {
                assert_eq!(u.to_bits(), v.to_bits(), "{p:?} pixel {k}: {u} vs {v}");
            }
        }
        assert_eq!(idw(&[], &[], &[], &base).width, 0);
    }

    #[test]
    fn idw_weights_nearer_points_more() {
        // Two points: bright one near the pixel centre, dark one near the radius.
        let p = Params::default();
        let xs = [0.026, 0.14];
        let ys = [0.026, 0.026];
        let r = idw(&xs, &ys, &[10.0, 0.0], &p);
        let (c, rr) = r.cell_of(0.026, 0.026).unwrap();
        let v = *r.get(c, rr);
        assert!(v > 7.0 && v < 10.0, "{v}");
        // Higher power sharpens further.
        let r3 = idw(&xs, &ys, &[10.0, 0.0], &Params { power: 3.0, ..p });
        assert!(*r3.get(c, rr) > v);
    }

    /// Far range: weak asphalt returns drop out, so the 1 m strip holding a line returns
    /// more paint points than asphalt ones and its own median is paint. The median of it and
    /// its neighbours across the road is asphalt, and the line stands out at 3x.
    #[test]
    fn a_strip_mostly_paint_by_count_takes_its_neighbours_background() {
        let (mut intensity, mut offset, mut slice, mut scanner) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for s in 0..10i64 {
            // asphalt: 10 points per 1 m strip and slice from 23 to 29 m (intensity 20)
            for k in 0..60 {
                intensity.push(20.0);
                offset.push(23.0 + 6.0 * (k as f64 + 0.5) / 60.0);
                slice.push(s);
                scanner.push(0);
            }
            // a line at 26.5 m: 25 paint points per slice (intensity 60)
            for k in 0..25 {
                intensity.push(60.0);
                offset.push(26.42 + 0.16 * (k as f64 + 0.5) / 25.0);
                slice.push(s);
                scanner.push(0);
            }
        }
        let input = BackgroundInput {
            intensity: &intensity,
            scanner: &scanner,
            slice: &slice,
            offset: &offset,
        };
        let v = normalise(&input, &Params::default());
        for i in 0..v.len() {
            if intensity[i] > 30.0 {
                assert!(v[i] > 2.7, "paint at {} normalised to {}", offset[i], v[i]);
            } else {
                assert!(
                    (0.9..1.1).contains(&v[i]),
                    "asphalt at {} normalised to {}",
                    offset[i],
                    v[i]
                );
            }
        }
    }

    /// A bright stripe under a strong range gradient: raw intensity of the far stripe is
    /// lower than the near asphalt, normalised it stands out everywhere.
    #[test]
    fn normalisation_removes_a_range_gradient() {
        let mut intensity = Vec::new();
        let mut offset = Vec::new();
        let mut slice = Vec::new();
        let mut scanner = Vec::new();
        let gain = |o: f64| 30000.0 / (1.0 + 0.3 * o.abs()) as f32;
        for s in 0..10i64 {
            for k in 0..2000 {
                let o = -12.0 + 24.0 * (k as f64 + 0.5) / 2000.0;
                // stripes at 0.0 and 10.0 (0.15 m wide): paint reflects 3x asphalt
                let paint = (o - 0.0).abs() < 0.075 || (o - 10.0).abs() < 0.075;
                intensity.push(gain(o) * if paint { 3.0 } else { 1.0 });
                offset.push(o);
                slice.push(s);
                scanner.push(if k % 2 == 0 { 0 } else { 1 });
            }
        }
        let raw_far_paint = gain(10.0) * 3.0;
        assert!(
            raw_far_paint < gain(0.5),
            "the test needs far paint darker than near asphalt"
        );
        let v = normalise(
            &BackgroundInput {
                intensity: &intensity,
                scanner: &scanner,
                slice: &slice,
                offset: &offset,
            },
            &Params::default(),
        );
        for i in 0..v.len() {
            let paint = (offset[i]).abs() < 0.075 || (offset[i] - 10.0).abs() < 0.075;
            if paint {
                assert!(v[i] > 2.3, "paint at {} normalised to {}", offset[i], v[i]);
            } else {
                assert!(
                    v[i] < 1.35 && v[i] > 0.7,
                    "asphalt at {} normalised to {}",
                    offset[i],
                    v[i]
                );
            }
        }
    }

    #[test]
    fn normalisation_handles_heads_with_different_gain() {
        let n = 4000;
        let mut intensity = Vec::new();
        let mut scanner = Vec::new();
        for k in 0..n {
            let head = (k % 2) as u8;
            intensity.push(if head == 0 { 1000.0 } else { 4000.0 });
            scanner.push(head);
        }
        let slice = vec![0i64; n];
        let offset: Vec<f64> = (0..n).map(|k| (k as f64 / n as f64) * 6.0 - 3.0).collect();
        let v = normalise(
            &BackgroundInput {
                intensity: &intensity,
                scanner: &scanner,
                slice: &slice,
                offset: &offset,
            },
            &Params::default(),
        );
        assert!(v.iter().all(|x| (x - 1.0).abs() < 0.05), "{:?}", &v[..4]);
    }
}
