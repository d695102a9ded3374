use roadmark::pipeline::{io, params::Params, pavement, rasterize, types::StationIndex};
use std::path::Path;

#[test]
fn diag() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/real/semantickitti_00");
    for scan in ["000000", "000001", "000002"] {
        let las = dir.join(format!("scan_{scan}.las"));
        let labels = std::fs::read(dir.join(format!("{scan}.label"))).unwrap();
        let labels: Vec<u32> = labels
            .chunks_exact(4)
            .map(|b| u32::from_le_bytes(b.try_into().unwrap()) & 0xFFFF)
            .collect();
        let c = io::read_points(&[las.as_path()]).unwrap();
        let t = io::read_trajectory(&dir.join("trajectory.csv"))
            .unwrap()
            .to_local(c.origin);
        let idx = StationIndex::new(&t, 1.0);
        let st: Vec<_> = (0..c.len()).map(|i| idx.locate(c.x[i], c.y[i])).collect();
        let m: Vec<f64> = st.iter().map(|s| s.mileage_m).collect();
        let o: Vec<f64> = st.iter().map(|s| s.offset_m).collect();
        let p = Params::default();
        let pav = pavement::run(
            &pavement::Input {
                x: &c.x,
                y: &c.y,
                z: &c.z,
                mileage: &m,
                offset: &o,
                gps_time: None,
                scanner: &c.scanner,
            },
            &p.pavement,
        );
        let mut in_pav = vec![false; c.len()];
        for &i in &pav {
            in_pav[i] = true;
        }
        let lab60: Vec<usize> = (0..c.len()).filter(|&i| labels[i] == 60).collect();
        let road: Vec<usize> = (0..c.len()).filter(|&i| labels[i] == 40).collect();
        let near = |i: usize| o[i].abs() <= 30.0 && m[i] >= -30.0 && m[i] <= t.length_m() + 30.0;
        eprintln!(
            "scan {scan}: n {} pav {} | lab60 {} near {} in pav {} | road {} in pav {}",
            c.len(),
            pav.len(),
            lab60.len(),
            lab60.iter().filter(|&&i| near(i)).count(),
            lab60.iter().filter(|&&i| in_pav[i]).count(),
            road.len(),
            road.iter().filter(|&&i| in_pav[i]).count()
        );
        let other_in_pav = pav
            .iter()
            .filter(|&&i| labels[i] != 40 && labels[i] != 60)
            .count();
        eprintln!("  pav non-road non-marking {other_in_pav}");
        // normalised intensity
        let slice: Vec<i64> = pav.iter().map(|&i| pavement::slice_of(m[i], 2.0)).collect();
        let inten: Vec<f32> = pav.iter().map(|&i| c.intensity[i]).collect();
        let sc: Vec<u8> = pav.iter().map(|&i| c.scanner[i]).collect();
        let off: Vec<f64> = pav.iter().map(|&i| o[i]).collect();
        let v = rasterize::normalise(
            &rasterize::BackgroundInput {
                intensity: &inten,
                scanner: &sc,
                slice: &slice,
                offset: &off,
            },
            &p.rasterize,
        );
        let mut a: Vec<f32> = pav
            .iter()
            .zip(&v)
            .filter(|(i, _)| labels[**i] == 60)
            .map(|(_, v)| *v)
            .collect();
        let mut b: Vec<f32> = pav
            .iter()
            .zip(&v)
            .filter(|(i, _)| labels[**i] == 40)
            .map(|(_, v)| *v)
            .collect();
        a.sort_by(f32::total_cmp);
        b.sort_by(f32::total_cmp);
        let q = |v: &[f32], f: f64| v[((v.len() - 1) as f64 * f) as usize];
        eprintln!(
            "  norm marking q10 {:.2} q50 {:.2} q90 {:.2}; road q10 {:.2} q50 {:.2} q90 {:.2} q99 {:.2}",
            q(&a, 0.1),
            q(&a, 0.5),
            q(&a, 0.9),
            q(&b, 0.1),
            q(&b, 0.5),
            q(&b, 0.9),
            q(&b, 0.99)
        );
    }
}

#[test]
fn sweep() {
    use roadmark::pipeline::{Inputs, NoProgress, driver};
    use std::collections::HashMap;
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/real/semantickitti_00");
    let variants: Vec<(&str, String)> = vec![
        ("default", "{}".into()),
        ("pcf0", r#"{"threshold":{"point_contrast_fraction":0.0}}"#.into()),
        (
            "pcf0.5",
            r#"{"threshold":{"point_contrast_fraction":0.5}}"#.into(),
        ),
        ("mc1.4", r#"{"threshold":{"min_contrast":1.4}}"#.into()),
        ("t1.4", r#"{"threshold":{"factor":1.4}}"#.into()),
        ("s25", r#"{"threshold":{"window_radius_px":25}}"#.into()),
        ("r0.25", r#"{"rasterize":{"radius_m":0.25}}"#.into()),
        (
            "cell0.1",
            r#"{"rasterize":{"cell_size_m":0.1, "radius_m":0.25}, "threshold":{"window_radius_px":8}}"#
                .into(),
        ),
        ("pav_none", r#"{"pavement":{"method":"none"}}"#.into()),
    ];
    for (name, js) in variants {
        let params = roadmark::pipeline::params::Params::from_json(&js)
            .unwrap()
            .validate()
            .unwrap();
        let (mut tp, mut ext, mut lab) = (0, 0, 0);
        for scan in ["000000", "000001", "000002"] {
            let las = dir.join(format!("scan_{scan}.las"));
            let labels = std::fs::read(dir.join(format!("{scan}.label"))).unwrap();
            let labels: Vec<u32> = labels
                .chunks_exact(4)
                .map(|b| u32::from_le_bytes(b.try_into().unwrap()) & 0xFFFF)
                .collect();
            let c = io::read_points(&[las.as_path()]).unwrap();
            let key = |x: f64, y: f64, z: f64| {
                (
                    (x * 1e4).round() as i64,
                    (y * 1e4).round() as i64,
                    (z * 1e4).round() as i64,
                )
            };
            let mut map: HashMap<(i64, i64, i64), bool> = HashMap::new();
            for i in 0..c.len() {
                let o = c.origin;
                let e = map
                    .entry(key(c.x[i] + o[0], c.y[i] + o[1], c.z[i] + o[2]))
                    .or_default();
                *e |= labels[i] == 60;
            }
            let inputs = Inputs {
                points: vec![las],
                trajectory: dir.join("trajectory.csv"),
            };
            let (_, m) = driver::run_collecting_marking_points(&inputs, &params, &NoProgress).unwrap();
            let o = m.origin;
            for i in 0..m.len() {
                if map[&key(m.x[i] + o[0], m.y[i] + o[1], m.z[i] + o[2])] {
                    tp += 1;
                }
            }
            ext += m.len();
            lab += labels.iter().filter(|&&l| l == 60).count();
        }
        eprintln!(
            "{name:10} P {:.3} R {:.3} (ext {ext})",
            tp as f64 / ext.max(1) as f64,
            tp as f64 / lab as f64
        );
    }
}
