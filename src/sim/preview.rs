//! Top-down intensity preview (`preview.png`).
//!
//! Each pixel (default 0.1 m) holds the mean intensity of the points falling in it, drawn
//! on a logarithmic grey scale so that both near (bright) and far (dark) lanes stay
//! visible; pixels without points are black (the shadows of cars, trees and barriers, and
//! everything beyond the range). North is up.
//!
//! Complexity: O(points) to accumulate, O(pixels) to write.

use super::scanner::SimPoint;
use anyhow::{Context, Result};
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

pub struct Preview {
    x0: f64,
    y1: f64,
    px: f64,
    w: usize,
    h: usize,
    sum: Vec<f32>,
    cnt: Vec<u32>,
}

impl Preview {
    /// A canvas over the local box [x0, x1] × [y0, y1]; the pixel grows if the image
    /// would exceed 12 000 pixels on a side.
    pub fn new(bbox: [f64; 4], px_m: f64) -> Preview {
        let [x0, y0, x1, y1] = bbox;
        let px = px_m.max((x1 - x0).max(y1 - y0) / 12_000.0);
        let w = ((x1 - x0) / px).ceil().max(1.0) as usize;
        let h = ((y1 - y0) / px).ceil().max(1.0) as usize;
        Preview {
            x0,
            y1,
            px,
            w,
            h,
            sum: vec![0.0; w * h],
            cnt: vec![0; w * h],
        }
    }

    pub fn add(&mut self, pts: &[SimPoint]) {
        for p in pts {
            let c = ((p.x - self.x0) / self.px).floor();
            let r = ((self.y1 - p.y) / self.px).floor();
            if c < 0.0 || r < 0.0 || c >= self.w as f64 || r >= self.h as f64 {
                continue;
            }
            let i = r as usize * self.w + c as usize;
            self.sum[i] += f32::from(p.intensity);
            self.cnt[i] += 1;
        }
    }

    pub fn write(&self, path: &Path) -> Result<()> {
        let f = File::create(path).with_context(|| format!("creating {}", path.display()))?;
        let mut enc = png::Encoder::new(BufWriter::new(f), self.w as u32, self.h as u32);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Eight);
        let mut wr = enc.write_header()?;
        let (lo, hi) = (20.0f32, 40_000.0f32);
        let scale = 255.0 / (hi / lo).ln();
        let data: Vec<u8> = self
            .sum
            .iter()
            .zip(&self.cnt)
            .map(|(&s, &c)| {
                if c == 0 {
                    0
                } else {
                    let m = (s / c as f32).max(lo);
                    (1.0 + (m / lo).ln() * scale).min(255.0) as u8
                }
            })
            .collect();
        wr.write_image_data(&data)?;
        Ok(())
    }
}
