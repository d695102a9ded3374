//! Whole-pipeline tests: real SemanticKITTI scans (per-point precision/recall of the marking
//! points against label 60), the `extract` command's error handling, and simulated scenes
//! scored by `evaluate` against the contract's targets.

// Columns (x, y, z, labels) are walked in step by index: clearer than zipped iterators.
#![allow(clippy::needless_range_loop)]

use roadmark::pipeline::driver;
use roadmark::pipeline::params::{Params, ValidParams};
use roadmark::pipeline::{Inputs, NoProgress, io};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

fn shared() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared")
}

fn defaults() -> ValidParams {
    Params::default().validate().unwrap()
}

/// Absolute coordinates quantised to 0.1 mm: the key to find a point again.
fn key(x: f64, y: f64, z: f64) -> (i64, i64, i64) {
    let q = |v: f64| (v * 1e4).round() as i64;
    (q(x), q(y), q(z))
}

/// (true positives, extracted, labelled) of one SemanticKITTI scan.
fn kitti_counts(scan: &str) -> (usize, usize, usize) {
    let dir = shared().join("data/real/semantickitti_00");
    let las = dir.join(format!("scan_{scan}.las"));
    let labels = std::fs::read(dir.join(format!("{scan}.label"))).unwrap();
    let labels: Vec<u32> = labels
        .chunks_exact(4)
        .map(|b| u32::from_le_bytes(b.try_into().unwrap()) & 0xFFFF)
        .collect();
    let cloud = io::read_points(&[las.as_path()]).unwrap();
    assert_eq!(cloud.len(), labels.len(), "labels and points line up");
    let mut is_marking: HashMap<(i64, i64, i64), (usize, usize)> = HashMap::new();
    for i in 0..cloud.len() {
        let o = cloud.origin;
        let e = is_marking
            .entry(key(cloud.x[i] + o[0], cloud.y[i] + o[1], cloud.z[i] + o[2]))
            .or_default();
        if labels[i] == 60 {
            e.0 += 1;
        } else {
            e.1 += 1;
        }
    }
    let inputs = Inputs {
        points: vec![las],
        trajectory: dir.join("trajectory.csv"),
    };
    let (_, marks) = driver::run_collecting_marking_points(&inputs, &defaults(), &NoProgress).unwrap();
    let o = marks.origin;
    let mut tp = 0;
    for i in 0..marks.len() {
        let k = key(marks.x[i] + o[0], marks.y[i] + o[1], marks.z[i] + o[2]);
        let (m, _) = is_marking
            .get(&k)
            .copied()
            .expect("an extracted point exists in the input");
        if m > 0 {
            tp += 1;
        }
    }
    let labelled = labels.iter().filter(|&&l| l == 60).count();
    (tp, marks.len(), labelled)
}

#[test]
fn semantickitti_marking_points_precision_and_recall() {
    let (mut tp, mut ext, mut lab) = (0, 0, 0);
    for scan in ["000000", "000001", "000002"] {
        let (t, e, l) = kitti_counts(scan);
        eprintln!(
            "scan {scan}: extracted {e}, labelled {l}, tp {t}: precision {:.3}, recall {:.3}",
            t as f64 / e.max(1) as f64,
            t as f64 / l.max(1) as f64
        );
        tp += t;
        ext += e;
        lab += l;
    }
    let precision = tp as f64 / ext.max(1) as f64;
    let recall = tp as f64 / lab.max(1) as f64;
    eprintln!("semantickitti all: precision {precision:.3}, recall {recall:.3}");
    // Measured 2026-12-03 (release): precision 0.125, recall 0.459 over the three scans
    // (0.104 / 0.388 before the no-data bridging of the threshold stage joined ring pieces).
    // A single ring scan with per-laser gains is far from what the pipeline is built for;
    // these floors only keep it from getting worse.
    assert!(precision >= 0.10, "precision {precision:.3} below 0.10");
    assert!(recall >= 0.40, "recall {recall:.3} below 0.40");
}

/// A stand-in trajectory for a tile that has none: a straight drive along the principal axis
/// of the tile's ground points (the street's direction), 2 m above their median height,
/// extended 5 m beyond the points at both ends, one pose per metre.
fn principal_axis_trajectory(cloud: &roadmark::pipeline::types::PointCloud, out: &Path) {
    let n = cloud.len() as f64;
    let (mx, my) = (cloud.x.iter().sum::<f64>() / n, cloud.y.iter().sum::<f64>() / n);
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for i in 0..cloud.len() {
        let (dx, dy) = (cloud.x[i] - mx, cloud.y[i] - my);
        sxx += dx * dx;
        sxy += dx * dy;
        syy += dy * dy;
    }
    // Direction of the larger eigenvalue of the 2×2 covariance.
    let angle = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    let (ux, uy) = (angle.cos(), angle.sin());
    let along: Vec<f64> = (0..cloud.len())
        .map(|i| (cloud.x[i] - mx) * ux + (cloud.y[i] - my) * uy)
        .collect();
    let lo = along.iter().cloned().fold(f64::INFINITY, f64::min) - 5.0;
    let hi = along.iter().cloned().fold(f64::NEG_INFINITY, f64::max) + 5.0;
    let mut z = cloud.z.clone();
    z.sort_by(f64::total_cmp);
    let zc = z[z.len() / 2] + 2.0;
    let heading = ux.atan2(uy).to_degrees().rem_euclid(360.0);
    let o = cloud.origin;
    let mut csv = String::from("time,x,y,z,heading\n");
    let steps = (hi - lo).ceil() as usize;
    for k in 0..=steps {
        let t = lo + k as f64;
        csv += &format!(
            "{:.2},{:.3},{:.3},{:.3},{:.2}\n",
            k as f64 * 0.1,
            o[0] + mx + t * ux,
            o[1] + my + t * uy,
            o[2] + zc,
            heading
        );
    }
    std::fs::write(out, csv).unwrap();
}

/// Amsterdam tiles (real dense MLS of narrow streets without lane lines, LAZ, EPSG:28992,
/// quantised intensity): the pipeline must not invent lane lines there. The tiles come
/// without a trajectory; the street's principal axis stands in for it.
#[test]
fn amsterdam_tiles_get_no_invented_lane_lines() {
    let dir = shared().join("data/real/amsterdam_cyclomedia");
    let tmp = tempfile::tempdir().expect("tempdir");
    for tile in ["2292_9700", "2293_9698", "2294_9700", "2294_9701"] {
        let laz = dir.join(format!("{tile}.laz"));
        let cloud = io::read_points(&[laz.as_path()]).unwrap();
        assert!(
            cloud.len() > 10_000,
            "tile {tile} read whole: {} points",
            cloud.len()
        );
        let trajectory = tmp.path().join(format!("{tile}.csv"));
        principal_axis_trajectory(&cloud, &trajectory);
        let inputs = Inputs {
            points: vec![laz],
            trajectory,
        };
        let (extraction, _) =
            driver::run_collecting_marking_points(&inputs, &defaults(), &NoProgress).unwrap();
        eprintln!(
            "amsterdam {tile}: {} points, {} markings, {} lane lines",
            cloud.len(),
            extraction.markings.len(),
            extraction.lane_lines.len()
        );
        assert!(
            extraction.lane_lines.is_empty(),
            "tile {tile}: {} lane lines invented on a street without any",
            extraction.lane_lines.len()
        );
    }
}

/// Pixel F (and per-point precision/recall against `labels.bin`) of a short simulated scene
/// run through the whole pipeline and scored by the evaluator.
fn sim_scores(scene: &str, length_m: f64) -> (f64, f64, f64) {
    let dir = tempfile::tempdir().expect("tempdir");
    let opt = roadmark::sim::SimOptions {
        scene: scene.into(),
        seed: 3,
        length_m: Some(length_m),
        ..Default::default()
    };
    roadmark::sim::simulate(&opt, dir.path()).expect("simulate");
    let las = dir.path().join("points.las");
    let cloud = io::read_points(&[las.as_path()]).unwrap();
    let labels = std::fs::read(dir.path().join("labels.bin")).unwrap();
    let mut paint: HashMap<(i64, i64, i64), bool> = HashMap::new();
    let o = cloud.origin;
    for (i, b) in labels.chunks_exact(4).enumerate() {
        let l = u32::from_le_bytes(b.try_into().unwrap());
        let e = paint
            .entry(key(cloud.x[i] + o[0], cloud.y[i] + o[1], cloud.z[i] + o[2]))
            .or_default();
        *e |= l > 0;
    }
    let labelled = labels
        .chunks_exact(4)
        .filter(|b| u32::from_le_bytes((*b).try_into().unwrap()) > 0)
        .count();
    let inputs = Inputs {
        points: vec![las],
        trajectory: dir.path().join("trajectory.csv"),
    };
    let (result, marks) = driver::run_collecting_marking_points(&inputs, &defaults(), &NoProgress).unwrap();
    let mo = marks.origin;
    let tp = (0..marks.len())
        .filter(|&i| paint[&key(marks.x[i] + mo[0], marks.y[i] + mo[1], marks.z[i] + mo[2])])
        .count();
    let truth = roadmark::pipeline::geojson::read_geojson(&dir.path().join("truth.geojson")).unwrap();
    let report = roadmark::eval::evaluate(&truth, &result, &roadmark::eval::EvalOptions::default()).unwrap();
    let f = report.pixel.f_score.unwrap_or(0.0);
    let (p, r) = (
        tp as f64 / marks.len().max(1) as f64,
        tp as f64 / labelled.max(1) as f64,
    );
    eprintln!(
        "{scene} {length_m} m: pixel F {f:.3}; marking points {} labelled {labelled}: precision {p:.3} recall {r:.3}; {} markings, {} lane lines",
        marks.len(),
        result.markings.len(),
        result.lane_lines.len()
    );
    (f, p, r)
}

/// Floors a little below what was measured on this 70 m highway (seed 3): pixel F 0.619,
/// point precision 0.822, recall 0.980 (2026-11-22).
const PIXEL_F_FLOOR: f64 = 0.55;
const POINT_P_FLOOR: f64 = 0.75;
const POINT_R_FLOOR: f64 = 0.93;

#[test]
fn simulated_highway_pixel_f_and_point_scores_do_not_regress() {
    let (f, p, r) = sim_scores("highway", 70.0);
    assert!(f >= PIXEL_F_FLOOR, "pixel F {f:.3} below {PIXEL_F_FLOOR}");
    assert!(p >= POINT_P_FLOOR, "point precision {p:.3} below {POINT_P_FLOOR}");
    assert!(r >= POINT_R_FLOOR, "point recall {r:.3} below {POINT_R_FLOOR}");
}

/// A zebra crossing across a side street lies along the scan rows. At 100 lines/s the
/// rows are 0.12-0.15 m apart and each stripe is a comb of four rows with empty gaps,
/// which the clustering's valley split once cut into rows that classify dropped as steep
/// one-row strokes: on this drive (urban, seed 3, 250 k points/s, 100 lines/s) 54 of the 69
/// stripes were found, 66 since the comb is kept whole (2026-12-08). The floor sits between.
#[test]
fn crosswalk_stripes_along_sparse_scan_rows_are_found() {
    let dir = tempfile::tempdir().expect("tempdir");
    let opt = roadmark::sim::SimOptions {
        scene: "urban_intersection".into(),
        seed: 3,
        points_per_s: 250_000.0,
        lines_per_s: 100.0,
        ..Default::default()
    };
    roadmark::sim::simulate(&opt, dir.path()).expect("simulate");
    let inputs = Inputs {
        points: vec![dir.path().join("points.las")],
        trajectory: dir.path().join("trajectory.csv"),
    };
    let (result, _) = driver::run_collecting_marking_points(&inputs, &defaults(), &NoProgress).unwrap();
    let truth = roadmark::pipeline::geojson::read_geojson(&dir.path().join("truth.geojson")).unwrap();
    let report = roadmark::eval::evaluate(&truth, &result, &roadmark::eval::EvalOptions::default()).unwrap();
    let cw = report
        .objects
        .per_class
        .iter()
        .find(|c| c.class == "crosswalk")
        .expect("the drive has crosswalks");
    let recall = cw.tp as f64 / cw.truth.max(1) as f64;
    eprintln!(
        "crosswalk stripes: {} of {} found, {} false",
        cw.tp, cw.truth, cw.fp
    );
    assert!(
        recall >= 0.9,
        "crosswalk recall {recall:.3} ({} of {})",
        cw.tp,
        cw.truth
    );
}

/// `roadmark extract` without ONNX Runtime: with the default `learned.mode` (auto) it runs
/// on the geometric classes and says so on stderr with the install hint; with `on` it
/// stops before reading any point, naming the missing library.
#[test]
fn extract_says_when_the_learned_classifier_is_missing() {
    let dir = tempfile::tempdir().unwrap();
    let bin = env!("CARGO_BIN_EXE_roadmark");
    let survey = dir.path().join("s");
    let sim = std::process::Command::new(bin)
        .args([
            "simulate",
            "--scene",
            "highway",
            "--seed",
            "3",
            "--length-m",
            "40",
            "--out",
        ])
        .arg(&survey)
        .output()
        .unwrap();
    assert!(sim.status.success(), "{}", String::from_utf8_lossy(&sim.stderr));
    let missing = "/nonexistent/libonnxruntime.so.1.31.1";
    let extract = |params: Option<&str>| {
        let mut cmd = std::process::Command::new(bin);
        cmd.args(["extract", "--crs", "native", "--points"])
            .arg(survey.join("points.las"))
            .arg("--trajectory")
            .arg(survey.join("trajectory.csv"))
            .arg("--output")
            .arg(dir.path().join("out.geojson"))
            .env("ORT_DYLIB_PATH", missing);
        if let Some(json) = params {
            let p = dir.path().join("params.json");
            std::fs::write(&p, json).unwrap();
            cmd.arg("--params").arg(p);
        }
        cmd.output().unwrap()
    };
    let out = extract(None);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(dir.path().join("out.geojson").is_file());
    assert!(err.contains("warning") && err.contains(missing), "{err}");
    assert!(err.contains("pip install --no-deps onnxruntime"), "{err}");
    std::fs::remove_file(dir.path().join("out.geojson")).unwrap();

    let out = extract(Some(r#"{"learned": {"mode": "on"}}"#));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(err.contains("learned.mode") && err.contains(missing), "{err}");
    assert!(
        !dir.path().join("out.geojson").exists(),
        "no output without the classifier"
    );

    let out = extract(Some(r#"{"learned": {"mode": "off"}}"#));
    assert!(out.status.success());
    assert!(out.stderr.is_empty(), "{}", String::from_utf8_lossy(&out.stderr));
}
