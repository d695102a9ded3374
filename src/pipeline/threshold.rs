//! Stage 3: adaptive thresholding of the intensity raster, cleanup, and marking points.
//!
//! **What.** Decides which pixels of the normalised intensity raster (stage 2) are paint,
//! removes what is bright but not paint, and returns the pavement points that lie on paint.
//!
//! **Algorithm.**
//! 1. *Gaussian smoothing* (`gaussian_sigma_px`), no-data aware: a normalised convolution
//!    (smoothed values ÷ smoothed validity) so that holes do not darken their borders.
//! 2. *Bradley–Roth adaptive threshold* with the integral image (Yao 2019 eq. 14–15,
//!    Yao 2021 eq. 17–19, after Bradley & Roth 2007): a pixel is foreground when
//!    `I > mean(window of (2s+1)² pixels) · t`, the mean taken over valid pixels only
//!    (the image border and no-data holes shrink the window instead of darkening it).
//!    Because stage 2 divides by the asphalt background, a pixel must also reach
//!    `min_contrast` (times the background): this rejects the faint texture of bare
//!    asphalt where the window holds no paint at all.
//! 3. *Cleanup* on 8-connected components: optional morphological closing/opening
//!    (`close_radius_px`, `open_radius_px`, off by default because a 3×3 closing already
//!    bridges the 0.1 m gap of a double line); foreground pixels separated only by
//!    unobserved pixels (no point within the IDW radius), at most `bridge_nodata_m` apart
//!    along a row or column, are joined first, so that a far crosswalk stripe crossed by
//!    scan rows 0.3–0.5 m apart is judged as one stripe, not as a stack of small blobs
//!    (the filled pixels hold no points and add no marking point); components smaller than
//!    `min_component_area_m2` are dropped (speckle, thin crack-sealant streaks that
//!    survive smoothing); compact bright blobs — short (`blob_max_length_m`), not
//!    elongated (`blob_max_elongation`) and solidly filled (`blob_min_fill`) — are dropped
//!    as manhole covers and similar street furniture: no road marking is a small disc or
//!    square. Length, width and fill come from the component's second moments
//!    (a bar of length L has variance L²/12 along its axis).
//! 4. *Points back from the mask* (Yao 2019 § 2.7): a pavement point is a marking point
//!    when its pixel is foreground and its own normalised intensity reaches
//!    `1 + point_contrast_fraction · (level − 1)`, where `level` is the median value of the
//!    component's pixels — the per-object refinement of Pan et al. (2019, per-object Otsu)
//!    in a form that stays stable for very worn paint. It trims the asphalt points that
//!    IDW blurring put inside the outline.
//! 5. *Flatness* ([`clear_unflat`]): paint lies flat on the road. Marking points in a cell
//!    (`flat_cell_m`) whose pavement points spread in height more than
//!    max(`flat_min_spread_m`, `flat_noise_factor` × the median spread of the marked cells)
//!    are cleared: the bright foot of a barrier or curb face, wheels, bumpers.
//!
//! 6. *Sparse-line rescue* ([`rescue_sparse_lines`]): at long range a line is a row of
//!    isolated points that the raster turns into lone discs (dropped by the blob rule, as
//!    they should be where they stand alone). Where the pavement holds fewer than
//!    `sparse_max_density` points per m², a point at least `sparse_min_value` bright with
//!    `sparse_min_support` others as bright at its offset (± `sparse_across_m`) within
//!    `sparse_along_m` along the trajectory is paint. It runs before the flatness check.
//!
//! `method: "none"` skips 1–3 and keeps every pavement point (for inputs that were
//! thresholded upstream).
//!
//! **Parameters** ([`Params`]): `window_radius_px` s = 12, `factor` t = 1.27 (Yao 2019
//! best (s, t) ≈ (10–12, 1.27–1.29)), `gaussian_sigma_px` 1.0, `min_contrast` 1.25,
//! `bridge_nodata_m` 0.3, `min_component_area_m2` 0.03, `blob_max_length_m` 1.2,
//! `blob_max_elongation` 2.0, `blob_min_fill` 0.7, `point_contrast_fraction` 0.3,
//! `flat_cell_m` 0.2, `flat_noise_factor` 4 (0 = off), `flat_min_spread_m` 0.06,
//! `sparse_min_value` 2 (0 = off), `sparse_max_density` 40, `sparse_along_m` 1.5,
//! `sparse_across_m` 0.08, `sparse_min_support` 2.
//!
//! **Reference.** Bradley D., Roth G. (2007) Adaptive thresholding using the integral image,
//! J. Graphics Tools 12(2); Yao et al. (2019, 2021); Pan et al. (2019) ISPRS J.
//!
//! **Complexity.** O(pixels) for smoothing (separable), integral image, threshold,
//! morphology (running windows) and labelling; O(points) to map points back. Smoothing,
//! integral images, thresholds and the point passes run in parallel; with hysteresis the
//! weak mask is built and labelled beside the strong one.

use super::geom::GridIndex;
use super::rasterize::Raster;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// How foreground is decided.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// Bradley–Roth on the smoothed raster, then cleanup.
    #[default]
    Adaptive,
    /// Every pavement point is a marking point (input already thresholded).
    None,
}

/// Parameters of this stage (JSON object `threshold` in the job parameters).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Params {
    pub method: Method,
    /// Bradley–Roth background radius s (pixels): the window is (2s+1)².
    pub window_radius_px: u32,
    /// Bradley–Roth segmentation coefficient t: foreground when I > mean · t.
    pub factor: f64,
    /// Gaussian smoothing before thresholding (pixels; 0 = off).
    pub gaussian_sigma_px: f64,
    /// Second, along-track detector: Gaussian widths along the trajectory (raster x) and
    /// across it (raster y), in pixels; `along_sigma_px` 0 turns it off.
    pub along_sigma_px: f64,
    pub across_sigma_px: f64,
    /// Minimum normalised intensity of a foreground pixel (× asphalt background).
    pub min_contrast: f64,
    /// Hysteresis: pixels passing these weaker limits are foreground when connected to a
    /// pixel passing `factor` and `min_contrast` (equal values turn hysteresis off).
    pub weak_factor: f64,
    pub weak_min_contrast: f64,
    /// Morphological closing radius (pixels, square element; 0 = off).
    pub close_radius_px: u32,
    /// Morphological opening radius (pixels, square element; 0 = off).
    pub open_radius_px: u32,
    /// Foreground pixels separated only by unobserved (no-data) pixels, at most this far
    /// apart along a raster row or column, are one component (m; 0 = off): far-range scan
    /// rows cross a crosswalk stripe 0.3–0.5 m apart, and the stripe must be judged whole
    /// by the size and blob rules, not as a stack of small fragments. Default 0.3.
    pub bridge_nodata_m: f64,
    /// Components smaller than this are dropped (m²).
    pub min_component_area_m2: f64,
    /// Blob rejection: components shorter than this …
    pub blob_max_length_m: f64,
    /// … with length/width at most this …
    pub blob_max_elongation: f64,
    /// … and area / (length · width) at least this are dropped (manhole covers).
    pub blob_min_fill: f64,
    /// Per-point check: a point needs ≥ 1 + fraction · (component level − 1).
    pub point_contrast_fraction: f64,
    /// Flatness check: cells of this size (m) in the trajectory frame …
    pub flat_cell_m: f64,
    /// … whose pavement points spread in height by more than
    /// max(`flat_min_spread_m`, `flat_noise_factor` × the median spread of the cells holding
    /// marking points) hold no paint (0 turns the check off).
    pub flat_noise_factor: f64,
    pub flat_min_spread_m: f64,
    /// Sparse-line rescue (step 6 of the module docs; 0 turns it off): an unmarked pavement
    /// point at least this bright (× asphalt background) …
    pub sparse_min_value: f64,
    /// … in a 0.5 m cell of fewer pavement points per m² than this (far range) …
    pub sparse_max_density: f64,
    /// … with at least `sparse_min_support` other such points within `sparse_along_m`
    /// along the trajectory and `sparse_across_m` across it is a marking point.
    pub sparse_along_m: f64,
    pub sparse_across_m: f64,
    pub sparse_min_support: u32,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            method: Method::Adaptive,
            window_radius_px: 12,
            factor: 1.27,
            gaussian_sigma_px: 1.0,
            along_sigma_px: 4.0,
            across_sigma_px: 0.7,
            min_contrast: 1.25,
            weak_factor: 1.12,
            weak_min_contrast: 1.12,
            close_radius_px: 0,
            open_radius_px: 0,
            bridge_nodata_m: 0.3,
            min_component_area_m2: 0.03,
            blob_max_length_m: 1.2,
            blob_max_elongation: 2.0,
            blob_min_fill: 0.7,
            point_contrast_fraction: 0.3,
            flat_cell_m: 0.2,
            flat_noise_factor: 4.0,
            flat_min_spread_m: 0.06,
            sparse_min_value: 2.0,
            sparse_max_density: 40.0,
            sparse_along_m: 1.5,
            sparse_across_m: 0.08,
            sparse_min_support: 2,
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
        if !(1..=200).contains(&self.window_radius_px) {
            return Err(format!(
                "window_radius_px: must be within 1..=200, got {}",
                self.window_radius_px
            ));
        }
        check_range("factor", self.factor, 0.1, 10.0)?;
        check_range("gaussian_sigma_px", self.gaussian_sigma_px, 0.0, 10.0)?;
        check_range("along_sigma_px", self.along_sigma_px, 0.0, 20.0)?;
        check_range("across_sigma_px", self.across_sigma_px, 0.0, 10.0)?;
        check_range("min_contrast", self.min_contrast, 0.0, 100.0)?;
        check_range("weak_factor", self.weak_factor, 0.1, 10.0)?;
        check_range("weak_min_contrast", self.weak_min_contrast, 0.0, 100.0)?;
        if self.close_radius_px > 10 {
            return Err(format!(
                "close_radius_px: at most 10, got {}",
                self.close_radius_px
            ));
        }
        if self.open_radius_px > 10 {
            return Err(format!("open_radius_px: at most 10, got {}", self.open_radius_px));
        }
        check_range("bridge_nodata_m", self.bridge_nodata_m, 0.0, 2.0)?;
        check_range("min_component_area_m2", self.min_component_area_m2, 0.0, 100.0)?;
        check_range("blob_max_length_m", self.blob_max_length_m, 0.0, 10.0)?;
        check_range("blob_max_elongation", self.blob_max_elongation, 1.0, 100.0)?;
        check_range("blob_min_fill", self.blob_min_fill, 0.0, 2.0)?;
        check_range("point_contrast_fraction", self.point_contrast_fraction, 0.0, 1.0)?;
        check_range("flat_cell_m", self.flat_cell_m, 0.02, 2.0)?;
        check_range("flat_noise_factor", self.flat_noise_factor, 0.0, 100.0)?;
        check_range("flat_min_spread_m", self.flat_min_spread_m, 0.0, 10.0)?;
        check_range("sparse_min_value", self.sparse_min_value, 0.0, 100.0)?;
        check_range("sparse_max_density", self.sparse_max_density, 0.0, 1.0e6)?;
        check_range("sparse_along_m", self.sparse_along_m, 0.05, 10.0)?;
        check_range("sparse_across_m", self.sparse_across_m, 0.01, 1.0)?;
        if !(1..=100).contains(&self.sparse_min_support) {
            return Err(format!(
                "sparse_min_support: must be within 1..=100, got {}",
                self.sparse_min_support
            ));
        }
        Ok(())
    }

    /// How far (m) the decision for one pixel can depend on other pixels, excluding whole
    /// components: the chunking needs at least this much overlap.
    pub fn reach_m(&self, cell_m: f64) -> f64 {
        let px = 3.0
            * self
                .gaussian_sigma_px
                .max(self.along_sigma_px)
                .max(self.across_sigma_px)
            + self.window_radius_px as f64
            + 2.0 * (self.close_radius_px + self.open_radius_px) as f64
            + 1.0;
        (px * cell_m).max(self.sparse_along_m)
    }
}

// ---------------------------------------------------------------------------------------
// Smoothing
// ---------------------------------------------------------------------------------------

/// Separable Gaussian blur of the valid pixels, normalised by the blurred validity.
/// Pixels that were NaN stay NaN.
pub fn gaussian_smooth(img: &Raster<f32>, sigma_px: f64) -> Raster<f32> {
    gaussian_smooth_xy(img, sigma_px, sigma_px)
}

fn kernel_1d(sigma: f64) -> (i64, Vec<f32>) {
    if sigma <= 0.0 {
        return (0, vec![1.0]);
    }
    let rad = (3.0 * sigma).ceil() as i64;
    let k = (-rad..=rad)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32)
        .collect();
    (rad, k)
}

/// [`gaussian_smooth`] with different widths along x (columns) and y (rows).
///
/// Both passes run tap-major (for each kernel tap, over a whole row), the horizontal one
/// on a zero-padded copy of the row, so the inner loops have no bounds checks and
/// vectorise. Each output still adds its taps in kernel order starting from 0, and the
/// padding adds exact zeros, so the result equals the direct per-pixel sums bit for bit.
pub fn gaussian_smooth_xy(img: &Raster<f32>, sigma_x: f64, sigma_y: f64) -> Raster<f32> {
    if (sigma_x <= 0.0 && sigma_y <= 0.0) || img.data.is_empty() {
        return img.clone();
    }
    let (rx, kx) = kernel_1d(sigma_x);
    let (ry, ky) = kernel_1d(sigma_y);
    let (w, h) = (img.width, img.height);
    let rxu = rx as usize;
    // Horizontal pass of the valid values and of the validity, per row.
    let mut hv = vec![0f32; w * h];
    let mut ho = vec![0f32; w * h];
    hv.par_chunks_mut(w)
        .zip(ho.par_chunks_mut(w))
        .enumerate()
        .for_each_init(
            || (vec![0f32; w + 2 * rxu], vec![0f32; w + 2 * rxu]),
            |(pv, po), (r, (ov, oo))| {
                for ((v, o), &x) in pv[rxu..rxu + w]
                    .iter_mut()
                    .zip(&mut po[rxu..rxu + w])
                    .zip(&img.data[r * w..(r + 1) * w])
                {
                    let ok = x.is_finite();
                    *v = if ok { x } else { 0.0 };
                    *o = if ok { 1.0 } else { 0.0 };
                }
                for (t, &k) in kx.iter().enumerate() {
                    for (o, &x) in ov.iter_mut().zip(&pv[t..t + w]) {
                        *o += k * x;
                    }
                    for (o, &x) in oo.iter_mut().zip(&po[t..t + w]) {
                        *o += k * x;
                    }
                }
            },
        );
    // Vertical pass (rows outside the image contribute nothing), then the ratio.
    let mut data = vec![0f32; w * h];
    data.par_chunks_mut(w).enumerate().for_each_init(
        || (vec![0f32; w], vec![0f32; w]),
        |(sv, so), (r, line)| {
            sv.fill(0.0);
            so.fill(0.0);
            for (k, &kv) in ky.iter().enumerate() {
                let rr = r as i64 + k as i64 - ry;
                if rr < 0 || rr as usize >= h {
                    continue;
                }
                let at = rr as usize * w;
                for (o, &x) in sv.iter_mut().zip(&hv[at..at + w]) {
                    *o += kv * x;
                }
                for (o, &x) in so.iter_mut().zip(&ho[at..at + w]) {
                    *o += kv * x;
                }
            }
            for (((d, &orig), &v), &o) in line
                .iter_mut()
                .zip(&img.data[r * w..(r + 1) * w])
                .zip(sv.iter())
                .zip(so.iter())
            {
                *d = if orig.is_finite() && o > 0.0 {
                    v / o
                } else {
                    f32::NAN
                };
            }
        },
    );
    Raster {
        col0: img.col0,
        row0: img.row0,
        cell_m: img.cell_m,
        width: w,
        height: h,
        data,
    }
}

// ---------------------------------------------------------------------------------------
// Integral image
// ---------------------------------------------------------------------------------------

/// Summed-area tables of the valid pixel values and of the valid-pixel counts.
pub struct IntegralImage {
    w: usize,
    h: usize,
    /// (w+1) × (h+1), entry (c, r) = sum over cols < c, rows < r.
    sum: Vec<f64>,
    count: Vec<u32>,
}

impl IntegralImage {
    /// Row prefix sums in parallel, then each row adds the finished row above it (a
    /// sequential but vectorised pass): the same additions as the textbook recurrence.
    pub fn new(img: &Raster<f32>) -> Self {
        let (w, h) = (img.width, img.height);
        let stride = w + 1;
        let mut sum = vec![0f64; stride * (h + 1)];
        let mut count = vec![0u32; stride * (h + 1)];
        sum[stride..]
            .par_chunks_mut(stride)
            .zip(count[stride..].par_chunks_mut(stride))
            .enumerate()
            .for_each(|(r, (srow, crow))| {
                let (mut rs, mut rc) = (0f64, 0u32);
                for (c, &v) in img.data[r * w..(r + 1) * w].iter().enumerate() {
                    if v.is_finite() {
                        rs += v as f64;
                        rc += 1;
                    }
                    srow[c + 1] = rs;
                    crow[c + 1] = rc;
                }
            });
        for r in 1..h {
            let (above, rest) = sum[r * stride..].split_at_mut(stride);
            for (x, &a) in rest[..stride].iter_mut().zip(above.iter()) {
                *x += a;
            }
            let (above, rest) = count[r * stride..].split_at_mut(stride);
            for (x, &a) in rest[..stride].iter_mut().zip(above.iter()) {
                *x += a;
            }
        }
        Self { w, h, sum, count }
    }

    /// Sum and count of valid pixels in cols c0..=c1, rows r0..=r1, clipped to the image.
    pub fn window(&self, c0: i64, r0: i64, c1: i64, r1: i64) -> (f64, u32) {
        let c0 = c0.max(0) as usize;
        let r0 = r0.max(0) as usize;
        let c1 = (c1 + 1).min(self.w as i64).max(0) as usize;
        let r1 = (r1 + 1).min(self.h as i64).max(0) as usize;
        if c1 <= c0 || r1 <= r0 {
            return (0.0, 0);
        }
        let s = self.w + 1;
        let sum =
            self.sum[r1 * s + c1] - self.sum[r0 * s + c1] - self.sum[r1 * s + c0] + self.sum[r0 * s + c0];
        let cnt = self.count[r1 * s + c1] + self.count[r0 * s + c0]
            - self.count[r0 * s + c1]
            - self.count[r1 * s + c0];
        (sum, cnt)
    }
}

/// Bradley–Roth: foreground (1) where `I > mean((2s+1)² window) · t` and `I ≥ min_contrast`.
pub fn bradley_roth(img: &Raster<f32>, s: u32, t: f64, min_contrast: f64) -> Raster<u8> {
    bradley_roth_with(img, &IntegralImage::new(img), s, t, min_contrast)
}

/// [`bradley_roth`] with the image's integral image already built (it does not depend on
/// `t` or `min_contrast`, so the strong and weak detections share it).
fn bradley_roth_with(img: &Raster<f32>, ii: &IntegralImage, s: u32, t: f64, min_contrast: f64) -> Raster<u8> {
    let s = s as i64;
    let w = img.width;
    let mut out = img.map(|_| 0u8);
    out.data
        .par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(r, line)| {
            for (c, o) in line.iter_mut().enumerate() {
                let v = img.data[r * w + c];
                if !v.is_finite() || (v as f64) < min_contrast {
                    continue;
                }
                let (c, r) = (c as i64, r as i64);
                let (sum, cnt) = ii.window(c - s, r - s, c + s, r + s);
                if cnt > 0 && v as f64 * cnt as f64 > sum * t {
                    *o = 1;
                }
            }
        });
    out
}

// ---------------------------------------------------------------------------------------
// Morphology and components
// ---------------------------------------------------------------------------------------

fn running(mask: &Raster<u8>, r: u32, dilate: bool) -> Raster<u8> {
    if r == 0 {
        return mask.clone();
    }
    let (w, h) = (mask.width, mask.height);
    let r = r as i64;
    let pass = |src: &[u8], horizontal: bool| -> Vec<u8> {
        let mut out = vec![0u8; w * h];
        for y in 0..h {
            for x in 0..w {
                let mut any = false;
                let mut all = true;
                for d in -r..=r {
                    let (xx, yy) = if horizontal {
                        (x as i64 + d, y as i64)
                    } else {
                        (x as i64, y as i64 + d)
                    };
                    let v = if xx < 0 || yy < 0 || xx >= w as i64 || yy >= h as i64 {
                        0
                    } else {
                        src[yy as usize * w + xx as usize]
                    };
                    any |= v != 0;
                    all &= v != 0;
                }
                out[y * w + x] = u8::from(if dilate { any } else { all });
            }
        }
        out
    };
    let tmp = pass(&mask.data, true);
    let data = pass(&tmp, false);
    Raster { data, ..mask.clone() }
}

/// Binary dilation with a (2r+1)² square.
pub fn dilate(mask: &Raster<u8>, r: u32) -> Raster<u8> {
    running(mask, r, true)
}

/// Binary erosion with a (2r+1)² square (outside the raster counts as background).
pub fn erode(mask: &Raster<u8>, r: u32) -> Raster<u8> {
    running(mask, r, false)
}

/// Shape statistics of one 8-connected component.
#[derive(Clone, Debug, PartialEq)]
pub struct Component {
    pub area_px: usize,
    /// Length and width (m) of the equivalent bar (√(12·λ) of the second moments).
    pub length_m: f64,
    pub width_m: f64,
    /// area / (length · width): ≈ 1 for bars, ≈ 1.05 for discs, lower for irregular shapes.
    pub fill: f64,
    /// Pixel bounding box: first column, first row, last column, last row.
    pub bbox: [usize; 4],
}

/// 8-connected labels (0 = background, 1.. = components in raster order) and their shapes.
pub fn label(mask: &Raster<u8>) -> (Vec<u32>, Vec<Component>) {
    let (w, h) = (mask.width, mask.height);
    let mut labels = vec![0u32; w * h];
    let mut comps = Vec::new();
    let mut stack = Vec::new();
    let cell = mask.cell_m;
    for start in 0..w * h {
        if mask.data[start] == 0 || labels[start] != 0 {
            continue;
        }
        let id = comps.len() as u32 + 1;
        labels[start] = id;
        stack.push(start);
        let (mut n, mut sx, mut sy, mut sxx, mut syy, mut sxy) = (0usize, 0f64, 0f64, 0f64, 0f64, 0f64);
        let mut bbox = [start % w, start / w, start % w, start / w];
        while let Some(k) = stack.pop() {
            let (x, y) = ((k % w) as f64, (k / w) as f64);
            bbox = [
                bbox[0].min(k % w),
                bbox[1].min(k / w),
                bbox[2].max(k % w),
                bbox[3].max(k / w),
            ];
            n += 1;
            sx += x;
            sy += y;
            sxx += x * x;
            syy += y * y;
            sxy += x * y;
            let (cx, cy) = ((k % w) as i64, (k / w) as i64);
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let (xx, yy) = (cx + dx, cy + dy);
                    if xx < 0 || yy < 0 || xx >= w as i64 || yy >= h as i64 {
                        continue;
                    }
                    let kk = yy as usize * w + xx as usize;
                    if mask.data[kk] != 0 && labels[kk] == 0 {
                        labels[kk] = id;
                        stack.push(kk);
                    }
                }
            }
        }
        let nf = n as f64;
        let (mx, my) = (sx / nf, sy / nf);
        // Pixel variance includes the pixel's own extent (1/12 px²).
        let vxx = sxx / nf - mx * mx + 1.0 / 12.0;
        let vyy = syy / nf - my * my + 1.0 / 12.0;
        let vxy = sxy / nf - mx * my;
        let tr = vxx + vyy;
        let det = vxx * vyy - vxy * vxy;
        let disc = (tr * tr / 4.0 - det).max(0.0).sqrt();
        let (l1, l2) = (tr / 2.0 + disc, (tr / 2.0 - disc).max(1.0 / 12.0));
        let length_m = (12.0 * l1).sqrt() * cell;
        let width_m = (12.0 * l2).sqrt() * cell;
        comps.push(Component {
            area_px: n,
            length_m,
            width_m,
            fill: nf * cell * cell / (length_m * width_m),
            bbox,
        });
    }
    (labels, comps)
}

/// The adaptive mask after cleanup, with its component labels and per-component level.
pub struct Segmentation {
    pub mask: Raster<u8>,
    /// Component label per pixel (0 = background), after cleanup.
    pub labels: Vec<u32>,
    /// Median smoothed value of each component's pixels (index label − 1).
    pub levels: Vec<f32>,
    /// Components dropped by the cleanup, by reason: (small, blob).
    pub dropped: (usize, usize),
}

/// Steps 1–3: smoothing, Bradley–Roth and cleanup.
pub fn segment(img: &Raster<f32>, p: &Params) -> Segmentation {
    let smooth = gaussian_smooth(img, p.gaussian_sigma_px);
    // Worn lines are patchy along their length: averaging along the track raises their
    // contrast above the asphalt texture, which has no preferred direction.
    let along =
        (p.along_sigma_px > 0.0).then(|| gaussian_smooth_xy(img, p.along_sigma_px, p.across_sigma_px));
    let (ii_smooth, ii_along) = rayon::join(
        || IntegralImage::new(&smooth),
        || along.as_ref().map(IntegralImage::new),
    );
    let detect = |t: f64, floor: f64| {
        let mut m = bradley_roth_with(&smooth, &ii_smooth, p.window_radius_px, t, floor);
        if let (Some(a), Some(ia)) = (&along, &ii_along) {
            let m2 = bradley_roth_with(a, ia, p.window_radius_px, t, floor);
            for (x, y) in m.data.iter_mut().zip(&m2.data) {
                *x |= *y;
            }
        }
        m
    };
    let hysteresis = p.weak_factor < p.factor || p.weak_min_contrast < p.min_contrast;
    // The weak mask and its (serial) labelling run beside the strong mask.
    let (strong, weak) = rayon::join(
        || detect(p.factor, p.min_contrast),
        || {
            hysteresis.then(|| {
                let weak = detect(
                    p.weak_factor.min(p.factor),
                    p.weak_min_contrast.min(p.min_contrast),
                );
                let labelled = label(&weak);
                (weak, labelled)
            })
        },
    );
    let mut mask = if let Some((weak, (wl, wc))) = weak {
        // Hysteresis: weak pixels count only in components that hold a strong one.
        let mut seeded = vec![false; wc.len() + 1];
        for (l, s) in wl.iter().zip(&strong.data) {
            if *s != 0 {
                seeded[*l as usize] = true;
            }
        }
        let mut m = weak;
        for (x, l) in m.data.iter_mut().zip(&wl) {
            *x = u8::from(*l != 0 && seeded[*l as usize]);
        }
        m
    } else {
        strong
    };
    if p.close_radius_px > 0 {
        mask = erode(&dilate(&mask, p.close_radius_px), p.close_radius_px);
    }
    if p.open_radius_px > 0 {
        mask = dilate(&erode(&mask, p.open_radius_px), p.open_radius_px);
    }
    let gap_px = (p.bridge_nodata_m / img.cell_m).round() as usize;
    if gap_px > 0 {
        bridge_nodata(&mut mask, img, gap_px);
    }
    let (mut labels, comps) = label(&mask);
    let px_area = img.cell_m * img.cell_m;
    let mut keep = vec![0u32; comps.len() + 1];
    let (mut small, mut blob) = (0, 0);
    let mut next = 0u32;
    for (i, c) in comps.iter().enumerate() {
        let is_small = (c.area_px as f64) * px_area < p.min_component_area_m2;
        let is_blob = c.length_m <= p.blob_max_length_m
            && c.length_m / c.width_m <= p.blob_max_elongation
            && c.fill >= p.blob_min_fill;
        if is_small {
            small += 1;
        } else if is_blob {
            blob += 1;
        } else {
            next += 1;
            keep[i + 1] = next;
        }
    }
    let mut values: Vec<Vec<f32>> = vec![Vec::new(); next as usize];
    for (k, l) in labels.iter_mut().enumerate() {
        *l = keep[*l as usize];
        mask.data[k] = u8::from(*l != 0);
        // Bridged pixels are unobserved (NaN in the no-data-aware smoothing too) and stay
        // out of the level; every component holds an observed foreground pixel, since a
        // bridge only runs between two.
        if *l != 0 && smooth.data[k].is_finite() {
            values[*l as usize - 1].push(smooth.data[k]);
        }
    }
    let mut levels: Vec<f32> = values
        .into_iter()
        .map(|mut v| {
            let mid = v.len() / 2;
            *v.select_nth_unstable_by(mid, f32::total_cmp).1
        })
        .collect();
    // Rims of bright surfaces: kept components that enclose a large hole as bright as
    // themselves are dropped (their label becomes 0); labels are not renumbered.
    let mut rims = 0;
    for (i, c) in comps.iter().enumerate() {
        let l = keep[i + 1];
        if l != 0 && bright_rim(&labels, &smooth, c, l, levels[l as usize - 1]) {
            rims += 1;
            for row in c.bbox[1]..=c.bbox[3] {
                for col in c.bbox[0]..=c.bbox[2] {
                    let k = row * mask.width + col;
                    if labels[k] == l {
                        labels[k] = 0;
                        mask.data[k] = 0;
                    }
                }
            }
            levels[l as usize - 1] = f32::NAN;
        }
    }
    Segmentation {
        mask,
        labels,
        levels,
        dropped: (small, blob + rims),
    }
}

/// Smallest side (m) of a component's bounding box for the bright-rim test.
const RIM_MIN_SIDE_M: f64 = 1.5;
/// Width (m) of the band along the bounding box's border where a rim lies; the rest of
/// the box is its core.
const RIM_BAND_M: f64 = 0.5;
/// Largest share of the component's pixels in the core: a rim, not a filled shape.
const RIM_MAX_CORE_SHARE: f64 = 0.2;
/// The core is "as bright" when the median value of its background pixels lies at least
/// this share of the way from the asphalt (1) to the component's level.
const RIM_HOLE_BRIGHTNESS: f32 = 0.5;

/// Is component `c` (label `l`, median value `level`) the rim of a bright surface — a
/// concrete patch, a plate — rather than paint? Bradley–Roth marks only the border of a
/// uniformly bright area wider than its window, so such an area comes out as a ring (open
/// where the patch's edge is faint) around a core that is background yet as bright as the
/// ring. A painted outline (a diamond, a box) encloses asphalt, and no road marking is a
/// filled area metres wide both ways. Written here: a scan of the bounding box.
fn bright_rim(labels: &[u32], smooth: &Raster<f32>, c: &Component, l: u32, level: f32) -> bool {
    let cell = smooth.cell_m;
    let (c0, r0, c1, r1) = (c.bbox[0], c.bbox[1], c.bbox[2], c.bbox[3]);
    let (bw, bh) = (c1 - c0 + 1, r1 - r0 + 1);
    if (bw.min(bh) as f64) * cell < RIM_MIN_SIDE_M || !level.is_finite() || level <= 1.0 {
        return false;
    }
    let band = (RIM_BAND_M / cell).round() as usize;
    let (mut in_core, mut core_px, mut own) = (0usize, 0usize, 0usize);
    let mut hole: Vec<f32> = Vec::new();
    for row in r0..=r1 {
        for col in c0..=c1 {
            let k = row * smooth.width + col;
            let core = col >= c0 + band && col + band <= c1 && row >= r0 + band && row + band <= r1;
            if labels[k] == l {
                own += 1;
                in_core += usize::from(core);
            } else if core {
                core_px += 1;
                if labels[k] == 0 && smooth.data[k].is_finite() {
                    hole.push(smooth.data[k]);
                }
            }
        }
    }
    if own == 0 || in_core as f64 > RIM_MAX_CORE_SHARE * own as f64 || hole.len() * 2 < core_px.max(1) {
        return false;
    }
    let mid = hole.len() / 2;
    let v = *hole.select_nth_unstable_by(mid, f32::total_cmp).1;
    v >= 1.0 + RIM_HOLE_BRIGHTNESS * (level - 1.0)
}

/// Fill runs of at most `gap_px` unobserved pixels (NaN in `img`, background in `mask`)
/// that lie between two foreground pixels of one raster row or column. The filled pixels
/// hold no point, so no marking point comes from them; they only make the sparse scan rows
/// of one painted object one component for the cleanup rules. A run that reaches an
/// observed background pixel is never filled: asphalt seen between two marks keeps them
/// apart. Written here because no image crate of ours labels through no-data.
fn bridge_nodata(mask: &mut Raster<u8>, img: &Raster<f32>, gap_px: usize) {
    let (w, h) = (mask.width, mask.height);
    let unobserved = |k: usize| img.data[k].is_nan();
    let mut fill = vec![false; w * h];
    // One line of the raster: `at(i)` is the flat index of its i-th pixel.
    let mut scan = |len: usize, at: &dyn Fn(usize) -> usize| {
        // Whether the pixel before the current one is foreground.
        let mut after_fg = false;
        let mut i = 0;
        while i < len {
            let k = at(i);
            if mask.data[k] != 0 || !unobserved(k) {
                after_fg = mask.data[k] != 0;
                i += 1;
                continue;
            }
            // A run of unobserved background pixels from i, filled when foreground closes it.
            let start = i;
            while i < len && mask.data[at(i)] == 0 && unobserved(at(i)) {
                i += 1;
            }
            if after_fg && i < len && mask.data[at(i)] != 0 && i - start <= gap_px {
                for j in start..i {
                    fill[at(j)] = true;
                }
            }
            after_fg = false;
        }
    };
    for y in 0..h {
        scan(w, &|i| y * w + i);
    }
    for x in 0..w {
        scan(h, &|i| i * w + x);
    }
    for (m, f) in mask.data.iter_mut().zip(&fill) {
        if *f {
            *m = 1;
        }
    }
}

/// Step 4: which points are marking points (`true`), given their position and value.
pub fn points_from_mask(seg: &Segmentation, xs: &[f64], ys: &[f64], values: &[f32], p: &Params) -> Vec<bool> {
    let m = &seg.mask;
    xs.par_iter()
        .zip(ys.par_iter())
        .zip(values.par_iter())
        .map(|((&x, &y), &v)| {
            let Some((c, r)) = m.cell_of(x, y) else {
                return false;
            };
            let l = seg.labels[r * m.width + c];
            if l == 0 {
                return false;
            }
            let level = seg.levels[l as usize - 1] as f64;
            let need = 1.0 + p.point_contrast_fraction * (level - 1.0).max(0.0);
            v.is_finite() && v as f64 >= need
        })
        .collect()
}

/// Cell side (m) of the density grid of the sparse-line rescue.
const SPARSE_CELL_M: f64 = 0.5;
/// Support points of the sparse-line rescue must spread at least this far along (m), so
/// that one bright spot (a stud, a stone) does not support itself.
const SPARSE_MIN_SPREAD_M: f64 = 0.15;
/// Most density cells of the sparse-line rescue (a 2 km × 2 km box of 0.5 m cells).
const SPARSE_MAX_CELLS: f64 = (1u64 << 24) as f64;

/// Sparse-line rescue (step 6 of the module docs): at long range a painted line is a row
/// of isolated points, 0.3–3 m apart, each several times brighter than the asphalt. In the
/// raster each one is a lone 0.3 m disc that the blob rule rightly drops (a lone disc is
/// what a manhole or a stone looks like) and Bradley–Roth compares with a window that holds
/// little but paint. Here, in sparse cells only (fewer than `sparse_max_density` pavement
/// points per m², where the raster cannot resolve the line), a point at least
/// `sparse_min_value` bright is paint when at least `sparse_min_support` other such points
/// lie at its offset (± `sparse_across_m`) within `sparse_along_m` along the trajectory,
/// spread along it: bright asphalt noise is rare (well under 1 % of far points at twice
/// the background) and is not aligned with the trajectory. `m`, `o` are the points'
/// mileage and offset; returns how many points were added.
///
/// Density counted on a [`Raster`] over the bright points' bounding box (cells at global
/// multiples, so a point's cell does not depend on the chunk), neighbours found with
/// [`GridIndex`] in units of (`sparse_along_m`, `sparse_across_m`); O(points).
pub fn rescue_sparse_lines(m: &[f64], o: &[f64], values: &[f32], is_mark: &mut [bool], p: &Params) -> usize {
    if p.sparse_min_value <= 0.0 || m.is_empty() {
        return 0;
    }
    let bright: Vec<usize> = (0..m.len())
        .into_par_iter()
        .filter(|&i| {
            values[i].is_finite()
                && values[i] as f64 >= p.sparse_min_value
                && m[i].is_finite()
                && o[i].is_finite()
        })
        .collect();
    let (bm, bo): (Vec<f64>, Vec<f64>) = bright.iter().map(|&i| (m[i], o[i])).unzip();
    let extent = |v: &[f64]| {
        v.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &x| {
            (lo.min(x), hi.max(x))
        })
    };
    let ((m_lo, m_hi), (o_lo, o_hi)) = (extent(&bm), extent(&bo));
    // One chunk's bright points span a few hundred metres; anything wider is no survey.
    let cells = ((m_hi - m_lo) / SPARSE_CELL_M + 2.0) * ((o_hi - o_lo) / SPARSE_CELL_M + 2.0);
    if bright.is_empty() || cells.is_nan() || cells > SPARSE_MAX_CELLS {
        return 0;
    }
    // Pavement points per density cell (points outside the box are tested in f64 first).
    let mut density = Raster::covering(&bm, &bo, SPARSE_CELL_M, 0, 0u32);
    for (&a, &b) in m.iter().zip(o) {
        if (m_lo..=m_hi).contains(&a)
            && (o_lo..=o_hi).contains(&b)
            && let Some((c, r)) = density.cell_of(a, b)
        {
            density.data[r * density.width + c] += 1;
        }
    }
    let max_count = p.sparse_max_density * SPARSE_CELL_M * SPARSE_CELL_M;
    let sparse: Vec<usize> = bright
        .into_iter()
        .filter(|&i| {
            density
                .cell_of(m[i], o[i])
                .is_some_and(|(c, r)| (*density.get(c, r) as f64) < max_count)
        })
        .collect();
    // Neighbours within (sparse_along_m, sparse_across_m): a 3 × 3 block of unit cells in
    // coordinates scaled by them (relative to the box, so they stay small).
    let (ca, cx) = (p.sparse_along_m, p.sparse_across_m);
    let scaled: Vec<[f64; 2]> = sparse
        .iter()
        .map(|&i| [(m[i] - m_lo) / ca, (o[i] - o_lo) / cx])
        .collect();
    let grid = GridIndex::new(&scaled, 1.0);
    let need = p.sparse_min_support as usize;
    let add: Vec<usize> = (0..sparse.len())
        .into_par_iter()
        .filter(|&a| !is_mark[sparse[a]])
        .filter(|&a| {
            let i = sparse[a];
            let mut support = 0;
            let mut spread = false;
            for k in grid.around(scaled[a], 1).filter(|&b| b != a).map(|b| sparse[b]) {
                let dm = (m[k] - m[i]).abs();
                if dm <= ca && (o[k] - o[i]).abs() <= cx {
                    support += 1;
                    spread |= dm >= SPARSE_MIN_SPREAD_M;
                }
            }
            support >= need && spread
        })
        .map(|a| sparse[a])
        .collect();
    for &i in &add {
        is_mark[i] = true;
    }
    add.len()
}

/// Flatness check (step 5 of the module docs): paint lies flat on the road, so marking
/// points in a cell whose pavement points spread in height like a vertical face (the
/// bright foot of a barrier or curb, a wheel, a bumper kept by the road buffer) are
/// cleared. The allowed spread adapts to the scanner's noise: `flat_noise_factor` × the
/// median spread of the cells that hold marking points (mostly real paint), never below
/// `flat_min_spread_m`. Inputs are the pavement points' mileage, offset and height and the
/// marking decision to refine; returns how many points were cleared.
///
/// Hand-written: a dense min/max grid over the chunk's bounding box, O(points + cells);
/// filled in up to [`FLAT_PARTS`] parallel parts (merged cell-wise) when the grid is small
/// next to the point count.
pub fn clear_unflat(m: &[f64], o: &[f64], z: &[f64], is_mark: &mut [bool], p: &Params) -> usize {
    if p.flat_noise_factor <= 0.0 || m.is_empty() || !is_mark.iter().any(|&b| b) {
        return 0;
    }
    // Min / max / count reductions do not depend on the order, so the parallel passes
    // give exactly the serial result.
    let bound = |v: &[f64]| {
        v.par_iter()
            .filter(|x| x.is_finite())
            .fold(
                || (f64::INFINITY, f64::NEG_INFINITY),
                |(a, b), &x| (a.min(x), b.max(x)),
            )
            .reduce(
                || (f64::INFINITY, f64::NEG_INFINITY),
                |(a, b), (c, d)| (a.min(c), b.max(d)),
            )
    };
    let ((m0, m1), (o0, o1)) = rayon::join(|| bound(m), || bound(o));
    if !(m0.is_finite() && o0.is_finite()) {
        return 0;
    }
    // Grow the cell if the box is huge, so the grid stays small (≤ 32 M cells).
    let mut cell = p.flat_cell_m;
    while ((m1 - m0) / cell + 1.0) * ((o1 - o0) / cell + 1.0) > 3.2e7 {
        cell *= 2.0;
    }
    let nc = ((m1 - m0) / cell) as usize + 1;
    let nr = ((o1 - o0) / cell) as usize + 1;
    let idx = |i: usize| -> Option<usize> {
        if !(m[i].is_finite() && o[i].is_finite() && z[i].is_finite()) {
            return None;
        }
        let c = (((m[i] - m0) / cell) as usize).min(nc - 1);
        let r = (((o[i] - o0) / cell) as usize).min(nr - 1);
        Some(r * nc + c)
    };
    // Height range and count per cell: one grid per part of the points (at most
    // FLAT_PARTS, and only when the grid is small next to the points), merged cell-wise.
    let cells = nc * nr;
    let n = m.len().min(z.len());
    let parts = if cells * 4 <= n { FLAT_PARTS } else { 1 };
    let fill = |range: std::ops::Range<usize>| {
        let mut lo = vec![f32::INFINITY; cells];
        let mut hi = vec![f32::NEG_INFINITY; cells];
        let mut count = vec![0u32; cells];
        for i in range {
            if let Some(k) = idx(i) {
                let v = z[i] as f32;
                lo[k] = lo[k].min(v);
                hi[k] = hi[k].max(v);
                count[k] += 1;
            }
        }
        (lo, hi, count)
    };
    let part = n.div_ceil(parts).max(1);
    let (lo, hi, count) = (0..parts)
        .into_par_iter()
        .map(|k| fill(k * part..((k + 1) * part).min(n)))
        .reduce_with(|mut a, b| {
            for k in 0..cells {
                a.0[k] = a.0[k].min(b.0[k]);
                a.1[k] = a.1[k].max(b.1[k]);
                a.2[k] += b.2[k];
            }
            a
        })
        .expect("at least one part");
    let spread = |k: usize| if count[k] >= 3 { hi[k] - lo[k] } else { 0.0 };
    let mut mark_cells: Vec<usize> = (0..m.len())
        .into_par_iter()
        .filter(|&i| is_mark[i])
        .filter_map(idx)
        .collect();
    mark_cells.par_sort_unstable();
    mark_cells.dedup();
    let mut spreads: Vec<f32> = mark_cells
        .iter()
        .filter(|&&k| count[k] >= 3)
        .map(|&k| spread(k))
        .collect();
    if spreads.is_empty() {
        return 0;
    }
    let mid = spreads.len() / 2;
    let median = *spreads.select_nth_unstable_by(mid, f32::total_cmp).1 as f64;
    let tol = (p.flat_noise_factor * median).max(p.flat_min_spread_m) as f32;
    let nm = m.len().min(is_mark.len());
    is_mark[..nm]
        .par_iter_mut()
        .enumerate()
        .map(|(i, mark)| {
            let clear = *mark && idx(i).is_some_and(|k| spread(k) > tol);
            if clear {
                *mark = false;
            }
            usize::from(clear)
        })
        .sum()
}

/// Parts of the points whose flatness grids [`clear_unflat`] fills side by side.
const FLAT_PARTS: usize = 4;

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The previous per-pixel separable blur: the reference [`gaussian_smooth_xy`] must
    /// equal bit for bit.
    fn gaussian_reference(img: &Raster<f32>, sigma_x: f64, sigma_y: f64) -> Raster<f32> {
        if (sigma_x <= 0.0 && sigma_y <= 0.0) || img.data.is_empty() {
            return img.clone();
        }
        let (rx, kx) = kernel_1d(sigma_x);
        let (ry, ky) = kernel_1d(sigma_y);
        let (w, h) = (img.width, img.height);
        let val: Vec<f32> = img
            .data
            .iter()
            .map(|v| if v.is_finite() { *v } else { 0.0 })
            .collect();
        let ok: Vec<f32> = img
            .data
            .iter()
            .map(|v| if v.is_finite() { 1.0 } else { 0.0 })
            .collect();
        let horiz = |src: &[f32]| -> Vec<f32> {
            let mut out = vec![0f32; w * h];
            out.par_chunks_mut(w).enumerate().for_each(|(r, line)| {
                let row = &src[r * w..(r + 1) * w];
                for (c, o) in line.iter_mut().enumerate() {
                    let lo = (c as i64 - rx).max(0) as usize;
                    let hi = ((c as i64 + rx) as usize).min(w - 1);
                    let mut acc = 0f32;
                    for cc in lo..=hi {
                        acc += kx[(cc as i64 - c as i64 + rx) as usize] * row[cc];
                    }
                    *o = acc;
                }
            });
            out
        };
        let vert = |src: &[f32]| -> Vec<f32> {
            let mut out = vec![0f32; w * h];
            out.par_chunks_mut(w).enumerate().for_each(|(r, line)| {
                for (k, kv) in ky.iter().enumerate() {
                    let rr = r as i64 + k as i64 - ry;
                    if rr < 0 || rr as usize >= h {
                        continue;
                    }
                    let row = &src[rr as usize * w..(rr as usize + 1) * w];
                    for (o, s) in line.iter_mut().zip(row) {
                        *o += kv * s;
                    }
                }
            });
            out
        };
        let sv = vert(&horiz(&val));
        let so = vert(&horiz(&ok));
        let data = img
            .data
            .iter()
            .zip(sv.iter().zip(&so))
            .map(|(orig, (v, o))| {
                if orig.is_finite() && *o > 0.0 {
                    v / o
                } else {
                    f32::NAN
                }
            })
            .collect();
        Raster {
            data,
            ..img.map(|_| 0f32)
        }
    }

    #[test]
    fn smoothing_equals_the_per_pixel_sums() {
        let mut state = 7u64;
        let mut rnd = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 33) as f32 / (1u64 << 31) as f32
        };
        let vals: Vec<f32> = (0..97 * 41)
            .map(|_| {
                let v = rnd();
                if v < 0.2 { f32::NAN } else { 5.0 * v - 0.5 }
            })
            .collect();
        let img = raster(97, 41, |x, y| vals[y * 97 + x]);
        for (sx, sy) in [(1.0, 1.0), (4.0, 0.7), (0.0, 2.0), (3.0, 0.0), (20.0, 10.0)] {
            let a = gaussian_smooth_xy(&img, sx, sy);
            let b = gaussian_reference(&img, sx, sy);
            assert_eq!(
                (a.width, a.height, a.col0, a.row0),
                (b.width, b.height, b.col0, b.row0)
            );
            for (u, v) in a.data.iter().zip(&b.data) {
                assert_eq!(u.to_bits(), v.to_bits(), "sigma ({sx}, {sy}): {u} vs {v}");
            }
        }
    }

    fn raster(w: usize, h: usize, f: impl Fn(usize, usize) -> f32) -> Raster<f32> {
        let mut r = Raster::new(0, 0, 0.05, w, h, 0f32);
        for y in 0..h {
            for x in 0..w {
                r.set(x, y, f(x, y));
            }
        }
        r
    }

    #[test]
    fn defaults_validate_and_absurd_values_are_named() {
        Params::default().validate().unwrap();
        let p = Params {
            window_radius_px: 0,
            ..Params::default()
        };
        assert!(p.validate().unwrap_err().starts_with("window_radius_px"));
        let p = Params {
            factor: f64::NAN,
            ..Params::default()
        };
        assert!(p.validate().unwrap_err().starts_with("factor"));
        let p = Params {
            gaussian_sigma_px: -1.0,
            ..Params::default()
        };
        assert!(p.validate().unwrap_err().starts_with("gaussian_sigma_px"));
    }

    proptest! {
        #[test]
        fn integral_image_matches_brute_force(
            w in 1usize..12, h in 1usize..12,
            seed in any::<u64>(),
            c0 in -3i64..14, r0 in -3i64..14, dc in 0i64..14, dr in 0i64..14,
        ) {
            let img = raster(w, h, |x, y| {
                let k = (x as u64 * 31 + y as u64 * 17).wrapping_mul(seed | 1) % 97;
                if k.is_multiple_of(7) { f32::NAN } else { k as f32 * 0.5 }
            });
            let ii = IntegralImage::new(&img);
            let (c1, r1) = (c0 + dc, r0 + dr);
            let (mut s, mut n) = (0f64, 0u32);
            for y in 0..h as i64 {
                for x in 0..w as i64 {
                    let v = *img.get(x as usize, y as usize);
                    if x >= c0 && x <= c1 && y >= r0 && y <= r1 && v.is_finite() {
                        s += v as f64;
                        n += 1;
                    }
                }
            }
            let (fs, fnn) = ii.window(c0, r0, c1, r1);
            prop_assert_eq!(fnn, n);
            prop_assert!((fs - s).abs() < 1e-6);
        }

        #[test]
        fn smoothing_keeps_constants(v in 0.1f32..100.0, w in 1usize..20, h in 1usize..20, sigma in 0.3f64..3.0) {
            let img = raster(w, h, |x, y| if (x + 2 * y) % 5 == 0 { f32::NAN } else { v });
            let s = gaussian_smooth(&img, sigma);
            for (a, b) in img.data.iter().zip(&s.data) {
                prop_assert_eq!(a.is_nan(), b.is_nan());
                if a.is_finite() { prop_assert!((a - b).abs() < 1e-3 * v); }
            }
        }
    }

    #[test]
    fn bright_stripe_is_foreground_and_asphalt_is_not() {
        // 4 m × 3 m of asphalt (≈ 1 with texture) with a 0.15 m stripe at 2.5.
        let img = raster(80, 60, |x, y| {
            let tex = 1.0 + 0.08 * (((x * 7 + y * 13) % 11) as f32 / 11.0 - 0.5);
            if (28..31).contains(&y) { 2.5 } else { tex }
        });
        let m = bradley_roth(&img, 12, 1.27, 1.25);
        for y in 0..60 {
            for x in 0..80 {
                assert_eq!(*m.get(x, y) == 1, (28..31).contains(&y), "({x},{y})");
            }
        }
    }

    #[test]
    fn segment_drops_manhole_blobs_and_speckle_but_keeps_lines() {
        let img = raster(200, 100, |x, y| {
            let line = (20..23).contains(&y) && (10..190).contains(&x);
            let dx = x as f32 - 100.0;
            let dy = y as f32 - 60.0;
            let manhole = dx * dx + dy * dy <= 49.0; // 0.7 m disc
            let speck = x == 150 && y == 80;
            if line || manhole || speck { 3.0 } else { 1.0 }
        });
        let seg = segment(&img, &Params::default());
        assert_eq!(seg.dropped, (1, 1));
        assert_eq!(seg.levels.len(), 1);
        assert_eq!(*seg.mask.get(100, 21), 1);
        assert_eq!(*seg.mask.get(100, 60), 0);
        assert_eq!(*seg.mask.get(150, 80), 0);
    }

    /// A uniformly bright 2.5 × 3 m surface (a concrete patch) comes out of Bradley–Roth as
    /// its rim around a core as bright as the rim: dropped, also when one side of the patch
    /// is faint (an open ring). A painted diamond outline (0.2 m lines) of the same size
    /// encloses asphalt: kept.
    #[test]
    fn rims_of_bright_surfaces_are_dropped_painted_outlines_kept() {
        let img = raster(240, 100, |x, y| {
            let patch = (20..70).contains(&x) && (20..80).contains(&y);
            // Diamond centred at (170, 50): |dx|/40 + |dy|/30 = 1, 4 px thick.
            let (dx, dy) = ((x as f32 - 170.0).abs() / 40.0, (y as f32 - 50.0).abs() / 30.0);
            let diamond = ((dx + dy) - 1.0).abs() * 30.0 <= 2.0;
            if patch || diamond { 3.5 } else { 1.0 }
        });
        let seg = segment(&img, &Params::default());
        // The patch's interior is not foreground (a rim at most) and the rim is gone too.
        assert!((20..70).all(|x| *seg.mask.get(x, 20) == 0 && *seg.mask.get(x, 50) == 0));
        assert_eq!(*seg.mask.get(20, 50), 0);
        // The diamond's lines stay.
        assert_eq!(*seg.mask.get(130, 50), 1);
        assert_eq!(*seg.mask.get(170, 20), 1);
        let off = segment(
            &raster(240, 100, |x, y| {
                if (20..70).contains(&x) && (20..80).contains(&y) {
                    3.5
                } else {
                    1.0
                }
            }),
            &Params {
                blob_min_fill: 2.0,
                ..Params::default()
            },
        );
        assert_eq!(off.dropped.1, 1, "the rim counts as a dropped blob");
        // One side 1.2 m long fades into the asphalt: the ring is open, still a rim.
        let open = segment(
            &raster(100, 100, |x, y| {
                let patch = (20..70).contains(&x) && (20..80).contains(&y);
                let faint = x >= 60 && (35..60).contains(&y);
                if patch && !faint {
                    3.5
                } else if patch {
                    1.3
                } else {
                    1.0
                }
            }),
            &Params {
                blob_min_fill: 2.0,
                ..Params::default()
            },
        );
        assert_eq!(open.dropped.1, 1);
        assert!(open.mask.data.iter().all(|&m| m == 0));
    }

    /// Far range: the data come in rows (along x) 0.45 m apart with 0.15 m of no-data
    /// between them; crosswalk stripes 0.45 m wide run across the rows (along y), 1.05 m
    /// apart. Each stripe is one component (its row pieces, 0.45 × 0.3 m each, would be
    /// dropped as small), and neighbouring stripes stay apart: asphalt was seen between them.
    #[test]
    fn stripes_crossed_by_sparse_rows_are_one_component_each() {
        let stripe = |x: usize| (20..29).contains(&x) || (41..50).contains(&x);
        let img = raster(80, 90, |x, y| {
            if y % 9 >= 6 || !(9..81).contains(&y) {
                f32::NAN
            } else if stripe(x) {
                3.0
            } else {
                1.0
            }
        });
        let seg = segment(&img, &Params::default());
        let l1 = seg.labels[10 * 80 + 24];
        assert_ne!(l1, 0);
        for y in (9..78).step_by(9) {
            assert_eq!(seg.labels[y * 80 + 24], l1, "row {y} of the first stripe");
        }
        let l2 = seg.labels[10 * 80 + 45];
        assert_ne!(l2, 0);
        assert_ne!(l1, l2, "two stripes");
        assert_eq!(seg.labels[10 * 80 + 35], 0, "asphalt between the stripes");
        // Without the bridging the 0.0135 m² pieces are dropped as small.
        let off = Params {
            bridge_nodata_m: 0.0,
            ..Params::default()
        };
        let seg = segment(&img, &off);
        assert!(seg.labels.iter().all(|&l| l == 0));
    }

    #[test]
    fn components_measure_bars() {
        let mut m = Raster::new(0, 0, 0.05, 100, 20, 0u8);
        for x in 10..90 {
            for y in 5..8 {
                m.set(x, y, 1);
            }
        }
        let (labels, comps) = label(&m);
        assert_eq!(comps.len(), 1);
        assert_eq!(labels[6 * 100 + 50], 1);
        assert!((comps[0].length_m - 4.0).abs() < 0.01, "{:?}", comps[0]);
        assert!((comps[0].width_m - 0.15).abs() < 0.01, "{:?}", comps[0]);
        assert!((comps[0].fill - 1.0).abs() < 0.02);
    }

    #[test]
    fn morphology_closes_a_pinhole() {
        let mut m = Raster::new(0, 0, 0.05, 9, 9, 0u8);
        for y in 2..7 {
            for x in 2..7 {
                m.set(x, y, u8::from(!(x == 4 && y == 4)));
            }
        }
        let closed = erode(&dilate(&m, 1), 1);
        assert_eq!(*closed.get(4, 4), 1);
        assert_eq!(*closed.get(1, 1), 0);
        assert_eq!(closed.data.iter().filter(|&&v| v == 1).count(), 25);
    }

    #[test]
    fn points_inherit_the_mask_and_need_contrast() {
        let img = raster(60, 40, |_, y| if (18..21).contains(&y) { 3.0 } else { 1.0 });
        let seg = segment(&img, &Params::default());
        let xs = [1.0, 1.0, 1.0];
        let ys = [0.96, 0.96, 0.5];
        let vals = [3.1, 1.1, 3.0];
        let got = points_from_mask(&seg, &xs, &ys, &vals, &Params::default());
        assert_eq!(got, vec![true, false, false]);
    }

    /// A far line read as single points 0.4-1.2 m apart (value 3) among asphalt (value 1),
    /// with bright noise points at random: the line's points are rescued, the noise (not
    /// aligned) and a bright pair at one spot are not, and nothing is rescued where the
    /// points are dense (the raster resolves paint there) or with the rescue off.
    #[test]
    fn sparse_aligned_bright_points_are_paint_and_lone_ones_are_not() {
        let (mut m, mut o, mut v) = (Vec::new(), Vec::new(), Vec::new());
        let mut jitter = crate::pipeline::geom::test_jitter(12345);
        let mut rnd = || jitter() + 0.5;
        // asphalt: 8 points per m² over 40 m x 6 m (offsets 23..29)
        for _ in 0..1920 {
            m.push(40.0 * rnd());
            o.push(23.0 + 6.0 * rnd());
            v.push(1.0f32);
        }
        let first_line = m.len();
        let mut s = 0.3;
        while s < 40.0 {
            m.push(s);
            o.push(26.5 + 0.05 * (rnd() - 0.5));
            v.push(3.0);
            s += 0.4 + 0.8 * rnd();
        }
        let end_line = m.len();
        // bright noise: isolated points away from the line, and a pair at one spot
        let noise = [
            (5.0, 24.0),
            (12.0, 25.1),
            (20.0, 27.8),
            (33.0, 23.6),
            (37.0, 28.4),
        ];
        for (a, b) in noise {
            m.push(a);
            o.push(b);
            v.push(3.0);
        }
        m.extend([15.0, 15.05]);
        o.extend([24.6, 24.62]);
        v.extend([3.0f32, 3.0]);
        let n = m.len();
        let mut marks = vec![false; n];
        let added = rescue_sparse_lines(&m, &o, &v, &mut marks, &Params::default());
        let line_found = (first_line..end_line).filter(|&i| marks[i]).count();
        assert!(
            line_found as f64 >= 0.9 * (end_line - first_line) as f64,
            "{line_found} of {} line points",
            end_line - first_line
        );
        assert!(marks[end_line..].iter().all(|&b| !b), "noise rescued");
        assert!(marks[..first_line].iter().all(|&b| !b), "asphalt rescued");
        assert_eq!(added, line_found);
        // dense: the same line inside 400 asphalt points per m² is left to the raster
        let (mut md, mut od, mut vd) = (m.clone(), o.clone(), v.clone());
        for k in 0..96_000 {
            md.push(40.0 * (k as f64 + 0.5) / 96_000.0);
            od.push(23.0 + 6.0 * rnd());
            vd.push(1.0);
        }
        let mut dense = vec![false; md.len()];
        assert_eq!(
            rescue_sparse_lines(&md, &od, &vd, &mut dense, &Params::default()),
            0
        );
        let off = Params {
            sparse_min_value: 0.0,
            ..Params::default()
        };
        let mut none = vec![false; n];
        assert_eq!(rescue_sparse_lines(&m, &o, &v, &mut none, &off), 0);
        // Absurd coordinates (cell indices saturate) neither panic nor rescue a lone point.
        let far_m = [1.0e300, -1.0e300, 0.0, f64::NAN];
        let far_o = [0.0, 1.0e300, -1.0e300, 0.0];
        let mut marks = vec![false; 4];
        assert_eq!(
            rescue_sparse_lines(&far_m, &far_o, &[3.0; 4], &mut marks, &Params::default()),
            0
        );
    }

    #[test]
    fn marks_on_a_vertical_face_are_cleared_and_flat_paint_kept() {
        // A flat road with 2 mm noise and a 1 m line of paint at offset 0; at offset 3 a
        // barrier face: bright points from road level to 0.25 m up.
        let (mut m, mut o, mut z, mut mark) = (vec![], vec![], vec![], vec![]);
        let mut k = 0u32;
        let mut noise = || {
            k = k.wrapping_mul(1_103_515_245).wrapping_add(12_345);
            (k >> 16) as f64 / 65_536.0 * 0.004 - 0.002
        };
        for i in 0..200 {
            for j in -40..80 {
                let (mi, oj) = (i as f64 * 0.01, j as f64 * 0.05);
                m.push(mi);
                o.push(oj);
                z.push(noise());
                mark.push(oj.abs() < 0.08);
            }
            for h in 0..6 {
                m.push(i as f64 * 0.01);
                o.push(3.0);
                z.push(h as f64 * 0.05);
                mark.push(true);
            }
        }
        let before = mark.clone();
        let cleared = clear_unflat(&m, &o, &z, &mut mark, &Params::default());
        assert_eq!(cleared, 200 * 6, "every point of the face");
        for i in 0..m.len() {
            if (o[i] - 3.0).abs() < 0.1 {
                assert!(!mark[i]);
            } else if o[i].abs() < 0.08 {
                assert_eq!(mark[i], before[i], "paint on the flat road stays");
            }
        }
        // Turned off: nothing changes.
        let mut again = before.clone();
        let off = Params {
            flat_noise_factor: 0.0,
            ..Params::default()
        };
        assert_eq!(clear_unflat(&m, &o, &z, &mut again, &off), 0);
        assert_eq!(again, before);
    }
}
