//! The learned classifier through ONNX Runtime: the committed model loads, batches agree with
//! single runs, fixed clusters get their classes, and a missing runtime is a clear error.
//!
//! Needs the ONNX Runtime library (`.ci/run` installs it into `.venv-ort` and exports
//! `ORT_DYLIB_PATH`; see models/README.md).

use roadmark::pipeline::PointCloud;
use roadmark::pipeline::learned::{Classifier, ClusterPoints, FEATURES_PER_POINT, runtime};
use roadmark::pipeline::types::MarkingClass;

fn classifier() -> &'static Classifier {
    Classifier::shared().unwrap_or_else(|e| panic!("{e}"))
}

/// Points filling a polygon (local coordinates) on a jittered 4 cm grid, like a dense MLS
/// survey; intensity bright with a little texture. Deterministic.
fn fill(cloud: &mut PointCloud, poly: &[[f64; 2]], z: f64) -> Vec<usize> {
    let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for p in poly {
        x0 = x0.min(p[0]);
        y0 = y0.min(p[1]);
        x1 = x1.max(p[0]);
        y1 = y1.max(p[1]);
    }
    let step = 0.04;
    let mut out = Vec::new();
    let mut k = 0u64;
    let mut y = y0;
    while y <= y1 {
        let mut x = x0;
        while x <= x1 {
            k = k
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let jx = ((k >> 33) % 1000) as f64 / 1000.0 - 0.5;
            let jy = ((k >> 13) % 1000) as f64 / 1000.0 - 0.5;
            let (px, py) = (x + jx * step, y + jy * step);
            if inside(poly, px, py) {
                out.push(cloud.len());
                cloud.push_local(px, py, z, 30000.0 + ((k >> 40) % 3000) as f32, None, 0);
            }
            x += step;
        }
        y += step;
    }
    out
}

fn inside(poly: &[[f64; 2]], x: f64, y: f64) -> bool {
    let mut c = false;
    let n = poly.len();
    for i in 0..n {
        let (a, b) = (poly[i], poly[(i + n - 1) % n]);
        if (a[1] > y) != (b[1] > y) && x < (b[0] - a[0]) * (y - a[1]) / (b[1] - a[1]) + a[0] {
            c = !c;
        }
    }
    c
}

fn rect(cx: f64, cy: f64, len: f64, wid: f64) -> Vec<[f64; 2]> {
    vec![
        [cx - len / 2.0, cy - wid / 2.0],
        [cx + len / 2.0, cy - wid / 2.0],
        [cx + len / 2.0, cy + wid / 2.0],
        [cx - len / 2.0, cy + wid / 2.0],
    ]
}

#[test]
fn the_committed_model_loads_and_describes_itself() {
    let c = classifier();
    let info = c.info();
    assert_eq!(info.points_per_cluster, 256);
    assert_eq!(info.classes.len(), 12);
    for class in [
        MarkingClass::DashedLine,
        MarkingClass::LeftArrow,
        MarkingClass::Diamond,
    ] {
        assert!(info.classes.contains(&class), "{class:?}");
    }
    assert!((0.0..1.0).contains(&info.unknown_threshold));
    assert!(runtime::ensure_loaded().unwrap().exists());
}

#[test]
fn batched_parallel_runs_match_single_runs() {
    let mut cloud = PointCloud::with_origin([231_000.0, 3_380_000.0, 20.0]);
    let mut clusters = Vec::new();
    for i in 0..37 {
        let len = 0.5 + 0.25 * i as f64;
        let idx = fill(
            &mut cloud,
            &rect(i as f64 * 20.0, 0.0, len, 0.15 + 0.01 * i as f64),
            0.0,
        );
        clusters.push(idx);
    }
    let views: Vec<ClusterPoints> = clusters
        .iter()
        .map(|idx| ClusterPoints {
            cloud: &cloud,
            indices: idx,
            direction: [1.0, 0.2],
        })
        .collect();
    let batched = classifier().classify(&views).unwrap();
    assert_eq!(batched.len(), views.len());
    for (v, b) in views.iter().zip(&batched) {
        let single = classifier().classify(std::slice::from_ref(v)).unwrap();
        for (p, q) in single[0].probs.iter().zip(&b.probs) {
            assert!((p - q).abs() < 1e-5, "{p} vs {q}");
        }
        let sum: f32 = b.probs.iter().sum();
        assert!((sum - 1.0).abs() < 1e-4, "probabilities sum to {sum}");
        assert!(b.confidence > 0.0 && b.confidence <= 1.0);
    }
    let n = classifier().info().points_per_cluster * FEATURES_PER_POINT;
    let err = classifier().classify_features(&vec![0.0; n + 1], 1).unwrap_err();
    assert!(err.to_string().contains("feature values"), "{err}");
}

/// Child half of [`a_missing_runtime_library_is_a_clear_error`]: only meaningful in the
/// subprocess that test starts (ONNX Runtime is loaded once per process).
#[test]
fn child_process_with_a_missing_runtime() {
    if std::env::var_os("ROADMARK_TEST_CHILD").is_none() {
        return;
    }
    let err = Classifier::builtin().unwrap_err();
    println!("\nCHILD-ERROR: {err}");
}

#[test]
fn a_missing_runtime_library_is_a_clear_error() {
    let out = std::process::Command::new(std::env::current_exe().unwrap())
        .args([
            "--exact",
            "child_process_with_a_missing_runtime",
            "--nocapture",
            "--test-threads=1",
        ])
        .env("ROADMARK_TEST_CHILD", "1")
        .env("ORT_DYLIB_PATH", "/nonexistent/libonnxruntime.so.1.31.1")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "the child panicked instead of returning an error:\n{stdout}"
    );
    let line = stdout
        .lines()
        .find_map(|l| l.split_once("CHILD-ERROR: ").map(|(_, e)| e))
        .unwrap_or_else(|| panic!("no error line in\n{stdout}"));
    assert!(line.contains("/nonexistent/libonnxruntime.so.1.31.1"), "{line}");
    assert!(
        line.contains("pip install --no-deps onnxruntime==1.31.1"),
        "{line}"
    );
}
