//! Reflectance of surfaces and the scanner's intensity response.
//!
//! **Intensity.** `I = G · ρ · cos(θ) / R^α`, then a soft saturation
//! `I_max (1 − e^{−I/I_max})`, multiplicative speckle (log-normal, σ ≈ 8 %), additive
//! detector noise, a detection threshold (weaker returns are lost: far, grazing, dark
//! asphalt drops out), and quantisation to u16. With α = 1.6 and the incidence cosine, paint
//! 12 m away returns less than bare asphalt 3 m away, as in real raw MLS amplitudes.
//!
//! **Reflectance.** Asphalt is a base value (new, dark ≈ 0.07; old, grey ≈ 0.15) plus
//! spatially correlated value noise at 0.4 m and 3 m (aggregate texture and ageing), plus
//! repair patches. Paint is ≈ 0.55 (white) or 0.45 (yellow), reduced by wear from a noise
//! field; where wear is strongest the paint is gone (gaps). Distractors: manhole covers
//! (bright metal ring), crack sealant streaks, concrete patches.
//!
//! Complexity: O(1) per point (a few hashed lattice lookups).

use super::markings::Colour;
use super::road::Material;
use rand::Rng;
use rand_distr::{Distribution, StandardNormal};

/// Lattice value noise in [-1, 1], smooth at scale `scale_m`.
pub fn value_noise(seed: u64, x: f64, y: f64, scale_m: f64) -> f64 {
    let (fx, fy) = (x / scale_m, y / scale_m);
    let (ix, iy) = (fx.floor(), fy.floor());
    let (tx, ty) = (fx - ix, fy - iy);
    let (sx, sy) = (tx * tx * (3.0 - 2.0 * tx), ty * ty * (3.0 - 2.0 * ty));
    let (ix, iy) = (ix as i64, iy as i64);
    let h = |a: i64, b: i64| lattice(seed, a, b);
    let v0 = h(ix, iy) + sx * (h(ix + 1, iy) - h(ix, iy));
    let v1 = h(ix, iy + 1) + sx * (h(ix + 1, iy + 1) - h(ix, iy + 1));
    v0 + sy * (v1 - v0)
}

fn lattice(seed: u64, a: i64, b: i64) -> f64 {
    let mut z = seed
        ^ (a as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (b as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
}

/// A feature painted or set into the pavement that changes its reflectance.
#[derive(Clone, Debug)]
pub enum SurfaceFeature {
    /// Rectangle in the road frame with its own asphalt reflectance (repair, resurfacing).
    Patch {
        s0: f64,
        s1: f64,
        d0: f64,
        d1: f64,
        rho: f64,
    },
    /// Round manhole cover (local xy), radius r.
    Manhole { c: [f64; 2], r: f64, rho: f64 },
    /// Crack sealant: a thin bright streak along a polyline (local xy), half width hw.
    Sealant { pts: Vec<[f64; 2]>, hw: f64, rho: f64 },
}

impl SurfaceFeature {
    /// Reflectance override at a ground point, if the feature covers it.
    fn rho_at(&self, s: f64, d: f64, x: f64, y: f64) -> Option<f64> {
        match self {
            SurfaceFeature::Patch { s0, s1, d0, d1, rho } => {
                (s >= *s0 && s <= *s1 && d >= *d0 && d <= *d1).then_some(*rho)
            }
            SurfaceFeature::Manhole { c, r, rho } => {
                let q = (x - c[0]).hypot(y - c[1]);
                if q > *r {
                    None
                } else if q > r - 0.06 {
                    Some(rho * 1.25) // polished rim
                } else {
                    // Cast pattern: concentric ribs.
                    Some(rho * (0.85 + 0.15 * (q * 40.0).sin()))
                }
            }
            SurfaceFeature::Sealant { pts, hw, rho } => {
                for w in pts.windows(2) {
                    let (a, b) = (w[0], w[1]);
                    let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
                    let l2 = ex * ex + ey * ey;
                    let t = (((x - a[0]) * ex + (y - a[1]) * ey) / l2).clamp(0.0, 1.0);
                    let (px, py) = (a[0] + t * ex, a[1] + t * ey);
                    if (x - px).hypot(y - py) <= *hw {
                        return Some(*rho);
                    }
                }
                None
            }
        }
    }

    /// Station range covered (for bucketing), given a station function.
    pub fn s_range(&self, to_s: &dyn Fn(f64, f64) -> f64) -> (f64, f64) {
        match self {
            SurfaceFeature::Patch { s0, s1, .. } => (*s0, *s1),
            SurfaceFeature::Manhole { c, r, .. } => {
                let s = to_s(c[0], c[1]);
                (s - r, s + r)
            }
            SurfaceFeature::Sealant { pts, .. } => {
                pts.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |a, p| {
                    let s = to_s(p[0], p[1]);
                    (a.0.min(s), a.1.max(s))
                })
            }
        }
    }
}

/// Reflectance model of a scene.
#[derive(Clone, Debug)]
pub struct Reflectance {
    pub seed: u64,
    /// Base asphalt reflectance.
    pub asphalt: f64,
    /// Amplitude of the asphalt texture noise (fraction of the base).
    pub texture: f64,
    /// Scene-wide paint wear 0..1.
    pub wear: f64,
    pub features: Vec<SurfaceFeature>,
    /// Offsets d of the wheel tracks (road frame) and the extra wear at their centre: tyres
    /// abrade transverse markings (crosswalks, stop lines, arrows) where vehicles run.
    pub tracks: Vec<f64>,
    pub track_wear: f64,
    s_min: f64,
    buckets: Vec<Vec<u32>>,
}

impl Reflectance {
    pub fn new(
        seed: u64,
        asphalt: f64,
        texture: f64,
        wear: f64,
        features: Vec<SurfaceFeature>,
    ) -> Reflectance {
        Reflectance {
            seed,
            asphalt,
            texture,
            wear,
            features,
            tracks: Vec::new(),
            track_wear: 0.0,
            s_min: 0.0,
            buckets: Vec::new(),
        }
    }

    /// Bucket the features by station (2 m buckets) over [s_min, s_max].
    pub fn index(&mut self, to_s: &dyn Fn(f64, f64) -> f64, s_min: f64, s_max: f64) {
        let nb = (((s_max - s_min) / 2.0).ceil() as usize).max(1);
        let mut buckets = vec![Vec::new(); nb];
        for (i, f) in self.features.iter().enumerate() {
            let (lo, hi) = f.s_range(to_s);
            let a = ((lo - s_min) / 2.0).floor().max(0.0) as usize;
            let b = ((hi - s_min) / 2.0).floor();
            if b < 0.0 {
                continue;
            }
            for bk in buckets.iter_mut().take((b as usize + 1).min(nb)).skip(a) {
                bk.push(i as u32);
            }
        }
        self.s_min = s_min;
        self.buckets = buckets;
    }

    /// Reflectance of the bare ground (no paint) at a point.
    pub fn ground(&self, mat: Material, s: f64, d: f64, x: f64, y: f64) -> f64 {
        match mat {
            Material::Asphalt => {
                let mut rho = self.asphalt;
                let b = ((s - self.s_min) / 2.0).floor();
                if b >= 0.0 && (b as usize) < self.buckets.len() {
                    // Later features lie on top of earlier ones.
                    for &i in self.buckets[b as usize].iter().rev() {
                        if let Some(r) = self.features[i as usize].rho_at(s, d, x, y) {
                            rho = r;
                            break;
                        }
                    }
                }
                let tex =
                    0.6 * value_noise(self.seed, x, y, 0.4) + 0.4 * value_noise(self.seed ^ 7, x, y, 3.0);
                rho * (1.0 + self.texture * tex)
            }
            Material::Sidewalk => {
                // Paving slabs 0.5 m with slightly different tones.
                let t = value_noise(
                    self.seed ^ 11,
                    (x / 0.5).floor() * 0.5,
                    (y / 0.5).floor() * 0.5,
                    0.5,
                );
                0.24 * (1.0 + 0.15 * t)
            }
            Material::Curb => 0.32,
            Material::Concrete => 0.33 * (1.0 + 0.08 * value_noise(self.seed ^ 13, x, y, 0.8)),
            Material::Grass => 0.18 * (1.0 + 0.3 * value_noise(self.seed ^ 17, x, y, 0.7)),
        }
    }

    /// Paint reflectance at a point (road offset `d`, local x, y) of a marking with extra
    /// wear `extra`; `None` where the paint has worn away completely.
    pub fn paint(&self, colour: Colour, extra: f64, d: f64, x: f64, y: f64) -> Option<f64> {
        let fresh = match colour {
            Colour::White => 0.55,
            Colour::Yellow => 0.45,
        };
        let near = self
            .tracks
            .iter()
            .map(|t| (d - t).abs())
            .fold(f64::INFINITY, f64::min);
        let track = self.track_wear * (-near * near / (2.0 * 0.3 * 0.3)).exp();
        let wear = (self.wear + extra + track).clamp(0.0, 1.0);
        if wear <= 0.0 {
            return Some(fresh * (1.0 + 0.05 * value_noise(self.seed ^ 23, x, y, 0.3)));
        }
        // Wear field: patchy at 0.5 m and streaky at 0.15 m.
        let n =
            0.65 * value_noise(self.seed ^ 29, x, y, 0.5) + 0.35 * value_noise(self.seed ^ 31, x, y, 0.15);
        let local = (wear * (1.0 + 1.2 * n)).clamp(0.0, 1.0);
        // Paint gone where the local wear is extreme.
        if local > 0.92 {
            return None;
        }
        Some(fresh * (1.0 - 0.85 * local))
    }
}

/// The scanner's radiometric response.
#[derive(Clone, Copy, Debug)]
pub struct Radiometry {
    /// Gain G (counts · m^α).
    pub gain: f64,
    pub alpha: f64,
    pub i_max: f64,
    /// Relative σ of the speckle (log-normal).
    pub speckle: f64,
    /// σ of the additive detector noise (counts).
    pub noise: f64,
    /// Returns below this are lost (counts).
    pub threshold: f64,
}

impl Default for Radiometry {
    fn default() -> Self {
        Radiometry {
            gain: 320_000.0,
            alpha: 1.6,
            i_max: 60_000.0,
            speckle: 0.08,
            noise: 8.0,
            threshold: 12.0,
        }
    }
}

impl Radiometry {
    /// Recorded intensity of a return, or `None` when too weak to be detected.
    pub fn intensity<R: Rng>(
        &self,
        rho: f64,
        cos_inc: f64,
        range: f64,
        head_gain: f64,
        rng: &mut R,
    ) -> Option<u16> {
        let raw = self.gain * head_gain * rho * cos_inc.max(0.0) / range.max(0.5).powf(self.alpha);
        let sat = self.i_max * (1.0 - (-raw / self.i_max).exp());
        let z: f64 = StandardNormal.sample(rng);
        let e: f64 = StandardNormal.sample(rng);
        let v = sat * (self.speckle * z).exp() + self.noise * e;
        if v < self.threshold {
            return None;
        }
        Some(v.round().min(65535.0) as u16)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn noise_is_bounded_smooth_and_seeded() {
        let mut prev = value_noise(1, 0.0, 0.3, 1.0);
        for i in 1..1000 {
            let x = i as f64 * 0.01;
            let v = value_noise(1, x, 0.3, 1.0);
            assert!((-1.0..=1.0).contains(&v));
            assert!((v - prev).abs() < 0.05, "smooth at 1 cm steps");
            prev = v;
        }
        assert_ne!(value_noise(1, 0.5, 0.5, 1.0), value_noise(2, 0.5, 0.5, 1.0));
    }

    #[test]
    fn far_paint_is_darker_than_near_asphalt() {
        let r = Radiometry::default();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let mean = |rho: f64, dist: f64, rng: &mut rand_chacha::ChaCha8Rng| {
            let range = (dist * dist + 2.2 * 2.2f64).sqrt();
            let cos = 2.2 / range;
            let v: Vec<f64> = (0..500)
                .filter_map(|_| r.intensity(rho, cos, range, 1.0, rng))
                .map(f64::from)
                .collect();
            v.iter().sum::<f64>() / v.len() as f64
        };
        let near_asphalt = mean(0.12, 2.0, &mut rng);
        let near_paint = mean(0.55, 2.0, &mut rng);
        let far_paint = mean(0.55, 12.0, &mut rng);
        assert!(near_paint > 2.0 * near_asphalt);
        assert!(far_paint < near_asphalt, "{far_paint} vs {near_asphalt}");
    }
}
