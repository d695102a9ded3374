//! Scratch diagnostics on simulated scenes (not committed).
use roadmark::pipeline::{driver, io, Inputs, NoProgress, params::Params};
use std::collections::HashMap;
use std::path::Path;

fn key(x: f64, y: f64, z: f64) -> (i64, i64, i64) {
    ((x * 1e4).round() as i64, (y * 1e4).round() as i64, (z * 1e4).round() as i64)
}

#[test]
fn diag_sim() {
    let scene = std::env::var("SCENE").unwrap_or("highway".into());
    let js = std::env::var("PARAMS").unwrap_or("{}".into());
    let dir = Path::new("/tmp/sim").join(&scene);
    let las = dir.join("points.las");
    let labels = std::fs::read(dir.join("labels.bin")).unwrap();
    let labels: Vec<u32> = labels.chunks_exact(4).map(|b| u32::from_le_bytes(b.try_into().unwrap())).collect();
    let c = io::read_points(&[las.as_path()]).unwrap();
    let o = c.origin;
    let mut map: HashMap<(i64, i64, i64), u32> = HashMap::new();
    for i in 0..c.len() {
        map.insert(key(c.x[i] + o[0], c.y[i] + o[1], c.z[i] + o[2]), labels[i]);
    }
    let params = Params::from_json(&js).unwrap().validate().unwrap();
    let inputs = Inputs { points: vec![las], trajectory: dir.join("trajectory.csv") };
    let (_, m) = driver::run_collecting_marking_points(&inputs, &params, &NoProgress).unwrap();
    let mo = m.origin;
    let mut found = vec![false; c.len()];
    let mut tp = 0;
    let mut fp_pts = Vec::new();
    let mut is_mark: HashMap<(i64, i64, i64), bool> = HashMap::new();
    for i in 0..m.len() {
        let k = key(m.x[i] + mo[0], m.y[i] + mo[1], m.z[i] + mo[2]);
        is_mark.insert(k, true);
        if map.get(&k).copied().unwrap_or(0) > 0 { tp += 1 } else { fp_pts.push(i) }
    }
    let lab = labels.iter().filter(|&&l| l > 0).count();
    eprintln!("{scene}: marking points {} labelled {} tp {} P {:.3} R {:.3}", m.len(), lab, tp, tp as f64 / m.len() as f64, tp as f64 / lab as f64);
    // image: 0.1 m pixels of all points (grey), TP green, FP red, FN blue
    let px = 0.1;
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for i in 0..c.len() { x0 = x0.min(c.x[i]); x1 = x1.max(c.x[i]); y0 = y0.min(c.y[i]); y1 = y1.max(c.y[i]); }
    let w = ((x1 - x0) / px) as usize + 1; let h = ((y1 - y0) / px) as usize + 1;
    let mut img = vec![0u8; w * h * 3];
    let mut cls = vec![0u8; w * h]; // 1 tp 2 fp 3 fn
    for i in 0..c.len() {
        let cx = ((c.x[i] - x0) / px) as usize; let cy = h - 1 - ((c.y[i] - y0) / px) as usize;
        let k = key(c.x[i] + o[0], c.y[i] + o[1], c.z[i] + o[2]);
        let mk = is_mark.contains_key(&k);
        let l = labels[i] > 0;
        let p = cy * w + cx;
        let g = (c.intensity[i] / 256.0).min(255.0) as u8;
        if img[p*3] < g / 2 { img[p*3] = g/2; img[p*3+1] = g/2; img[p*3+2] = g/2; }
        let v = match (mk, l) { (true, true) => 1, (true, false) => 2, (false, true) => 3, _ => 0 };
        if v > 0 && (cls[p] == 0 || v == 2) { cls[p] = v; }
        found[i] = mk;
    }
    for p in 0..w*h { match cls[p] { 1 => { img[p*3]=0; img[p*3+1]=255; img[p*3+2]=0 }, 2 => { img[p*3]=255; img[p*3+1]=0; img[p*3+2]=0 }, 3 => { img[p*3]=60; img[p*3+1]=120; img[p*3+2]=255 }, _ => {} } }
    let f = std::fs::File::create(dir.join("diag.png")).unwrap();
    let mut enc = png::Encoder::new(std::io::BufWriter::new(f), w as u32, h as u32);
    enc.set_color(png::ColorType::Rgb); enc.set_depth(png::BitDepth::Eight);
    enc.write_header().unwrap().write_image_data(&img).unwrap();
    eprintln!("image {w}x{h}");
    // per truth marking: points labelled vs found, with offset from trajectory
    let t = io::read_trajectory(&dir.join("trajectory.csv")).unwrap().to_local(o);
    let nmark = *labels.iter().max().unwrap() as usize;
    let mut tot = vec![0usize; nmark + 1]; let mut got = vec![0usize; nmark + 1]; let mut off = vec![0f64; nmark + 1];
    for i in 0..c.len() { let l = labels[i] as usize; if l > 0 { tot[l] += 1; if found[i] { got[l] += 1; } if tot[l] == 1 { off[l] = t.locate(c.x[i], c.y[i]).offset_m; } } }
    let mut missing_far = 0; let mut missing_near = 0;
    for l in 1..=nmark { if tot[l] > 0 && (got[l] as f64) < 0.5 * tot[l] as f64 { if off[l].abs() > 25.0 { missing_far += tot[l]; } else { missing_near += tot[l]; eprintln!("  missed m{l}: {}/{} pts, offset {:.1}", got[l], tot[l], off[l]); } } }
    eprintln!("missing points: far (>25 m) {missing_far}, near {missing_near}");
}

#[test]
fn profile() {
    use roadmark::pipeline::types::StationIndex;
    let scene = std::env::var("SCENE").unwrap_or("highway".into());
    let at: f64 = std::env::var("AT").unwrap_or("100".into()).parse().unwrap();
    let dir = Path::new("/tmp/sim").join(&scene);
    let c = io::read_points(&[dir.join("points.las").as_path()]).unwrap();
    let t = io::read_trajectory(&dir.join("trajectory.csv")).unwrap().to_local(c.origin);
    let idx = StationIndex::new(&t, 1.0);
    let mut bins: std::collections::BTreeMap<i64, (f64, f64, usize, f64)> = Default::default();
    for i in 0..c.len() {
        let s = idx.locate(c.x[i], c.y[i]);
        if (s.mileage_m - at).abs() > 1.0 { continue; }
        let b = (s.offset_m / 0.5).floor() as i64;
        let e = bins.entry(b).or_insert((f64::MAX, f64::MIN, 0, 0.0));
        e.0 = e.0.min(c.z[i]); e.1 = e.1.max(c.z[i]); e.2 += 1; e.3 += c.intensity[i] as f64;
    }
    for (b, (lo, hi, n, si)) in bins { eprintln!("u {:6.1} zmin {:7.3} zmax {:7.3} n {:6} meanI {:7.0}", b as f64 * 0.5, lo, hi, n, si / n as f64); }
}

#[test]
fn truth_where() {
    use roadmark::pipeline::types::StationIndex;
    let scene = std::env::var("SCENE").unwrap_or("highway".into());
    let dir = Path::new("/tmp/sim").join(&scene);
    let truth = roadmark::pipeline::geojson::read_geojson(&dir.join("truth.geojson")).unwrap();
    let t = io::read_trajectory(&dir.join("trajectory.csv")).unwrap();
    let idx = StationIndex::new(&t, 1.0);
    let labels = std::fs::read(dir.join("labels.bin")).unwrap();
    let labels: Vec<u32> = labels.chunks_exact(4).map(|b| u32::from_le_bytes(b.try_into().unwrap())).collect();
    let mut npts = std::collections::HashMap::<usize, usize>::new();
    for &l in &labels { if l > 0 { *npts.entry(l as usize).or_default() += 1; } }
    let mut cats: std::collections::BTreeMap<String, (f64, usize)> = Default::default();
    let mut total = 0.0;
    for (k, m) in truth.markings.iter().enumerate() {
        // sample the polygon on a 0.1 m grid
        let r = &m.outline;
        let (x0, x1) = r.iter().fold((f64::MAX, f64::MIN), |a, p| (a.0.min(p[0]), a.1.max(p[0])));
        let (y0, y1) = r.iter().fold((f64::MAX, f64::MIN), |a, p| (a.0.min(p[1]), a.1.max(p[1])));
        let inside = |x: f64, y: f64| { let mut c = false; let n = r.len(); for i in 0..n { let (a, b) = (r[i], r[(i + 1) % n]); if (a[1] > y) != (b[1] > y) && x < a[0] + (y - a[1]) * (b[0] - a[0]) / (b[1] - a[1]) { c = !c; } } c };
        let id: usize = m.id.trim_start_matches('m').parse().unwrap_or(k + 1);
        let pts = npts.get(&id).copied().unwrap_or(0);
        let mut x = x0;
        while x < x1 { let mut y = y0; while y < y1 { if inside(x, y) {
            let s = idx.locate(x, y);
            let cat = if s.mileage_m < 0.0 || s.mileage_m > t.length_m() { "beyond_ends" } else if s.offset_m.abs() > 30.0 { "offset>30" } else if s.offset_m.abs() > 20.0 { "offset20-30" } else { "near" };
            let cat = format!("{cat} {}", if pts == 0 { "nopts" } else if pts < 50 { "sparse" } else { "" });
            let e = cats.entry(cat).or_default(); e.0 += 0.01; total += 0.01;
        } y += 0.1; } x += 0.1; }
    }
    for (k, (a, _)) in &cats { eprintln!("{scene} {k:25} {a:8.1} m2 {:5.1}%", a / total * 100.0); }
}

#[test]
fn nopts() {
    use roadmark::pipeline::types::StationIndex;
    let scene = std::env::var("SCENE").unwrap_or("highway".into());
    let dir = Path::new("/tmp/sim").join(&scene);
    let truth = roadmark::pipeline::geojson::read_geojson(&dir.join("truth.geojson")).unwrap();
    let c = io::read_points(&[dir.join("points.las").as_path()]).unwrap();
    let t = io::read_trajectory(&dir.join("trajectory.csv")).unwrap();
    let tl = t.to_local(c.origin);
    let idx = StationIndex::new(&tl, 1.0);
    let labels = std::fs::read(dir.join("labels.bin")).unwrap();
    let labels: Vec<u32> = labels.chunks_exact(4).map(|b| u32::from_le_bytes(b.try_into().unwrap())).collect();
    let mut npts = std::collections::HashMap::<usize, usize>::new();
    for &l in &labels { if l > 0 { *npts.entry(l as usize).or_default() += 1; } }
    let (mut mlo, mut mhi) = (f64::MAX, f64::MIN);
    for i in (0..c.len()).step_by(97) { let s = idx.locate(c.x[i], c.y[i]); mlo = mlo.min(s.mileage_m); mhi = mhi.max(s.mileage_m); }
    eprintln!("traj length {:.1}, point mileage range {:.1}..{:.1}", t.length_m(), mlo, mhi);
    let tabs = StationIndex::new(&t, 1.0);
    for m in &truth.markings {
        let id: usize = m.id.trim_start_matches('m').parse().unwrap();
        let p = npts.get(&id).copied().unwrap_or(0);
        let cx = m.outline.iter().map(|q| q[0]).sum::<f64>() / m.outline.len() as f64;
        let cy = m.outline.iter().map(|q| q[1]).sum::<f64>() / m.outline.len() as f64;
        let s = tabs.locate(cx, cy);
        if p < 10 { eprintln!("  {} {:?} len {:.1} pts {} at mileage {:.1} offset {:.1}", m.id, m.class, m.length_m, p, s.mileage_m, s.offset_m); }
    }
}

#[test]
fn contrast() {
    use roadmark::pipeline::{pavement, rasterize, threshold, types::StationIndex};
    let scene = std::env::var("SCENE").unwrap_or("worn".into());
    let dir = Path::new("/tmp/sim").join(&scene);
    let c = io::read_points(&[dir.join("points.las").as_path()]).unwrap();
    let labels = std::fs::read(dir.join("labels.bin")).unwrap();
    let labels: Vec<u32> = labels.chunks_exact(4).map(|b| u32::from_le_bytes(b.try_into().unwrap())).collect();
    let t = io::read_trajectory(&dir.join("trajectory.csv")).unwrap().to_local(c.origin);
    let idx = StationIndex::new(&t, 1.0);
    let st: Vec<_> = (0..c.len()).map(|i| idx.locate(c.x[i], c.y[i])).collect();
    let m: Vec<f64> = st.iter().map(|s| s.mileage_m).collect();
    let o: Vec<f64> = st.iter().map(|s| s.offset_m).collect();
    let p = Params::from_json(&std::env::var("PARAMS").unwrap_or("{}".into())).unwrap();
    let pav = pavement::run(&pavement::Input { x: &c.x, y: &c.y, z: &c.z, mileage: &m, offset: &o, gps_time: None, scanner: &c.scanner }, &p.pavement);
    let lab_in_pav = pav.iter().filter(|&&i| labels[i] > 0).count();
    eprintln!("pavement {} of {}, labelled in pav {} of {}", pav.len(), c.len(), lab_in_pav, labels.iter().filter(|&&l| l > 0).count());
    let slice: Vec<i64> = pav.iter().map(|&i| pavement::slice_of(m[i], 2.0)).collect();
    let inten: Vec<f32> = pav.iter().map(|&i| c.intensity[i]).collect();
    let sc: Vec<u8> = pav.iter().map(|&i| c.scanner[i]).collect();
    let off: Vec<f64> = pav.iter().map(|&i| o[i]).collect();
    let v = rasterize::normalise(&rasterize::BackgroundInput { intensity: &inten, scanner: &sc, slice: &slice, offset: &off }, &p.rasterize);
    let q = |mut v: Vec<f32>| { v.sort_by(f32::total_cmp); let g = |f: f64| v[((v.len() - 1) as f64 * f) as usize]; format!("q05 {:.2} q25 {:.2} q50 {:.2} q75 {:.2} q95 {:.2} q99 {:.2}", g(0.05), g(0.25), g(0.5), g(0.75), g(0.95), g(0.99)) };
    eprintln!("paint   {}", q(pav.iter().zip(&v).filter(|(i, _)| labels[**i] > 0).map(|(_, v)| *v).collect()));
    eprintln!("asphalt {}", q(pav.iter().zip(&v).filter(|(i, _)| labels[**i] == 0).map(|(_, v)| *v).collect()));
    let px: Vec<f64> = pav.iter().map(|&i| m[i]).collect();
    let py: Vec<f64> = pav.iter().map(|&i| o[i]).collect();
    let r = rasterize::idw(&px, &py, &v, &p.rasterize);
    let sm = threshold::gaussian_smooth(&r, p.threshold.gaussian_sigma_px);
    let pix = |i: usize| { let (cc, rr) = sm.cell_of(px[i], py[i]).unwrap(); *sm.get(cc, rr) };
    eprintln!("pix paint   {}", q((0..pav.len()).filter(|&k| labels[pav[k]] > 0).map(pix).collect()));
    eprintln!("pix asphalt {}", q((0..pav.len()).filter(|&k| labels[pav[k]] == 0).map(pix).collect()));
    let al = threshold::gaussian_smooth_xy(&r, p.threshold.along_sigma_px, p.threshold.across_sigma_px);
    let pixa = |i: usize| { let (cc, rr) = al.cell_of(px[i], py[i]).unwrap(); *al.get(cc, rr) };
    eprintln!("along paint   {}", q((0..pav.len()).filter(|&k| labels[pav[k]] > 0).map(pixa).collect()));
    let mut asp: Vec<f32> = (0..pav.len()).filter(|&k| labels[pav[k]] == 0).map(pixa).collect();
    asp.sort_by(f32::total_cmp);
    eprintln!("along asphalt {} q999 {:.2}", q(asp.clone()), asp[(asp.len() as f64 * 0.999) as usize]);
    let seg = threshold::segment(&r, &p.threshold);
    eprintln!("components kept {}, dropped {:?}", seg.levels.len(), seg.dropped);
    let fg = |i: usize| { let (cc, rr) = seg.mask.cell_of(px[i], py[i]).unwrap(); *seg.mask.get(cc, rr) == 1 };
    let pf = (0..pav.len()).filter(|&k| labels[pav[k]] > 0 && fg(k)).count();
    let af = (0..pav.len()).filter(|&k| labels[pav[k]] == 0 && fg(k)).count();
    eprintln!("in mask: paint {pf} asphalt {af}");
    let pts = threshold::points_from_mask(&seg, &px, &py, &v, &p.threshold);
    let pp = (0..pav.len()).filter(|&k| labels[pav[k]] > 0 && pts[k]).count();
    let ap = (0..pav.len()).filter(|&k| labels[pav[k]] == 0 && pts[k]).count();
    eprintln!("after point check: paint {pp} asphalt {ap}");
}

#[test]
fn render() {
    use roadmark::pipeline::{pavement, rasterize, types::StationIndex};
    let scene = std::env::var("SCENE").unwrap_or("worn".into());
    let win: Vec<f64> = std::env::var("WIN").unwrap_or("60,80,-8,8".into()).split(',').map(|s| s.parse().unwrap()).collect();
    let dir = Path::new("/tmp/sim").join(&scene);
    let c = io::read_points(&[dir.join("points.las").as_path()]).unwrap();
    let labels = std::fs::read(dir.join("labels.bin")).unwrap();
    let labels: Vec<u32> = labels.chunks_exact(4).map(|b| u32::from_le_bytes(b.try_into().unwrap())).collect();
    let t = io::read_trajectory(&dir.join("trajectory.csv")).unwrap().to_local(c.origin);
    let idx = StationIndex::new(&t, 1.0);
    let st: Vec<_> = (0..c.len()).map(|i| idx.locate(c.x[i], c.y[i])).collect();
    let m: Vec<f64> = st.iter().map(|s| s.mileage_m).collect();
    let o: Vec<f64> = st.iter().map(|s| s.offset_m).collect();
    let p = Params::default();
    let pav = pavement::run(&pavement::Input { x: &c.x, y: &c.y, z: &c.z, mileage: &m, offset: &o, gps_time: None, scanner: &c.scanner }, &p.pavement);
    let slice: Vec<i64> = pav.iter().map(|&i| pavement::slice_of(m[i], 2.0)).collect();
    let inten: Vec<f32> = pav.iter().map(|&i| c.intensity[i]).collect();
    let sc: Vec<u8> = pav.iter().map(|&i| c.scanner[i]).collect();
    let off: Vec<f64> = pav.iter().map(|&i| o[i]).collect();
    let v = rasterize::normalise(&rasterize::BackgroundInput { intensity: &inten, scanner: &sc, slice: &slice, offset: &off }, &p.rasterize);
    let px = 0.02;
    let w = ((win[1] - win[0]) / px) as usize; let h = ((win[3] - win[2]) / px) as usize;
    let mut img = vec![0u8; w * h * 3 * 2];
    let ww = 2 * w;
    for (k, &i) in pav.iter().enumerate() {
        if m[i] < win[0] || m[i] >= win[1] || o[i] < win[2] || o[i] >= win[3] { continue; }
        let cx = ((m[i] - win[0]) / px) as usize; let cy = h - 1 - ((o[i] - win[2]) / px) as usize;
        let g = ((v[k] - 0.5) * 128.0).clamp(0.0, 255.0) as u8;
        let q = (cy * ww + cx) * 3; img[q] = g; img[q+1] = g; img[q+2] = g;
        let q = (cy * ww + cx + w) * 3; if labels[i] > 0 { img[q] = 0; img[q+1] = 255; img[q+2] = 0 } else { img[q] = 60; img[q+1] = 60; img[q+2] = 60 }
    }
    let f = std::fs::File::create(dir.join("render.png")).unwrap();
    let mut enc = png::Encoder::new(std::io::BufWriter::new(f), ww as u32, h as u32);
    enc.set_color(png::ColorType::Rgb); enc.set_depth(png::BitDepth::Eight);
    enc.write_header().unwrap().write_image_data(&img).unwrap();
}
