//! The learned classifier through ONNX Runtime: the committed model loads, batches agree with
//! single runs, fixed clusters get their classes, and a missing runtime is a clear error.
//!
//! Needs the ONNX Runtime library (`.ci/run` installs it into `.venv-ort` and exports
//! `ORT_DYLIB_PATH`; see models/README.md).

use roadmark::pipeline::PointCloud;
use roadmark::pipeline::classify::{self, Candidate, Shape};
use roadmark::pipeline::cluster;
use roadmark::pipeline::learned::{
    Classifier, ClusterPoints, FEATURES_PER_POINT, Prediction, refine, runtime,
};
use roadmark::pipeline::types::{MarkingClass, Pose, Trajectory};
use roadmark::sim::markings::{self, ArrowKind, Frame2, Paint, Standard};

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

/// Points filling a simulator marking (its polygon minus its hole), like [`fill`].
fn fill_marking(cloud: &mut PointCloud, m: &markings::MarkingDef) -> Vec<usize> {
    let Paint::Poly { ring, hole, .. } = &m.paint else {
        panic!("polygon marking expected");
    };
    let idx = fill(cloud, ring, 0.0);
    match hole {
        Some(h) => idx
            .into_iter()
            .filter(|&i| !inside(h, cloud.x[i], cloud.y[i]))
            .collect(),
        None => idx,
    }
}

/// One fixture per class the network alone decides (arrows, diamond), drawn by the
/// simulator's own shape generator (GB dimensions) with its forward axis along `heading`
/// (radians from east). Dashes: [`dashes`].
fn fixtures(cloud: &mut PointCloud, heading: f64, at: [f64; 2]) -> Vec<(MarkingClass, Vec<usize>)> {
    let st = Standard::parse("gb").unwrap();
    let (s, c) = heading.sin_cos();
    let frame = |k: f64| Frame2 {
        o: [at[0] + k * 15.0 * c, at[1] + k * 15.0 * s],
        u: [c, s],
        v: [-s, c],
    };
    let (dl, dw, dlw) = st.diamond;
    let shapes = [
        markings::arrow(ArrowKind::Straight, &frame(1.0), st.arrow_len_urban),
        markings::arrow(ArrowKind::Left, &frame(2.0), st.arrow_len_urban),
        markings::arrow(ArrowKind::Right, &frame(3.0), st.arrow_len_urban),
        markings::arrow(ArrowKind::StraightLeft, &frame(4.0), st.arrow_len_urban),
        markings::arrow(ArrowKind::StraightRight, &frame(5.0), st.arrow_len_urban),
        markings::diamond(&frame(6.0), dl, dw, dlw),
    ];
    shapes.iter().map(|m| (m.class, fill_marking(cloud, m))).collect()
}

/// Clean 2, 4 and 6 m dashes (0.15 m wide) along `heading`, placed after the [`fixtures`].
fn dashes(cloud: &mut PointCloud, heading: f64, at: [f64; 2]) -> Vec<(MarkingClass, Vec<usize>)> {
    let (s, c) = heading.sin_cos();
    [(8.0, 2.0), (9.0, 4.0), (10.0, 6.0)]
        .iter()
        .map(|&(k, len)| {
            let (cx, cy) = (at[0] + k * 15.0 * c, at[1] + k * 15.0 * s);
            let poly: Vec<[f64; 2]> = rect(0.0, 0.0, len, 0.15)
                .iter()
                .map(|p| [cx + p[0] * c - p[1] * s, cy + p[0] * s + p[1] * c])
                .collect();
            (MarkingClass::DashedLine, fill(cloud, &poly, 0.0))
        })
        .collect()
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

#[test]
fn fixed_clusters_get_their_classes_at_any_heading() {
    let c = classifier();
    for heading_deg in [0.0f64, 37.0, 180.0, 251.0] {
        let h = heading_deg.to_radians();
        let mut cloud = PointCloud::with_origin([500_000.0, 4_000_000.0, 10.0]);
        let mut fx = fixtures(&mut cloud, h, [3.0, -7.0]);
        fx.extend(dashes(&mut cloud, h, [3.0, -7.0]));
        let views: Vec<ClusterPoints> = fx
            .iter()
            .map(|(_, idx)| ClusterPoints {
                cloud: &cloud,
                indices: idx,
                direction: [h.cos(), h.sin()],
            })
            .collect();
        let preds = c.classify(&views).unwrap();
        for ((want, idx), p) in fx.iter().zip(&preds) {
            assert!(idx.len() > 100, "{want:?}: {} points", idx.len());
            assert_eq!(
                p.class, *want,
                "heading {heading_deg}: {want:?} predicted as {p:?}"
            );
            assert!(p.confidence >= c.info().unknown_threshold, "{p:?}");
        }
    }
}

fn candidate(
    cloud: &PointCloud,
    indices: Vec<usize>,
    class: MarkingClass,
    confidence: f64,
    dir: [f64; 2],
) -> Candidate {
    let n = indices.len() as f64;
    let cx = indices.iter().map(|&i| cloud.x[i]).sum::<f64>() / n;
    let cy = indices.iter().map(|&i| cloud.y[i]).sum::<f64>() / n;
    Candidate {
        shape: Shape {
            center: [cx, cy],
            axis: dir,
            length_m: 1.0,
            width_m: 1.0,
            fill_ratio: 1.0,
            angle_to_trajectory_deg: 0.0,
            mileage_m: 0.0,
            offset_m: 0.0,
            driving_direction: dir,
            spacing_m: 0.04,
            point_count: indices.len(),
            mean_intensity: 30000.0,
        },
        indices,
        class,
        confidence,
        line: None,
        whole: None,
        group: None,
        alternatives: Vec::new(),
    }
}

/// The network's prediction for one cluster.
fn network_says(cloud: &PointCloud, indices: &[usize], direction: [f64; 2]) -> Vec<Prediction> {
    classifier()
        .classify(&[ClusterPoints {
            cloud,
            indices,
            direction,
        }])
        .unwrap()
}

#[test]
fn refine_names_undecided_candidates_and_keeps_decisive_ones() {
    let dir: [f64; 2] = [0.6, 0.8];
    let h = dir[1].atan2(dir[0]);
    let mut cloud = PointCloud::with_origin([500_000.0, 4_000_000.0, 10.0]);
    let fx = fixtures(&mut cloud, h, [0.0, 0.0]);
    let mut cands: Vec<Candidate> = fx
        .iter()
        .map(|(_, idx)| candidate(&cloud, idx.clone(), MarkingClass::Unknown, 0.0, dir))
        .collect();
    // A decisive geometric verdict (even a wrong one) is not re-examined.
    let (_, arrow_pts) = &fx[1];
    cands.push(candidate(
        &cloud,
        arrow_pts.clone(),
        MarkingClass::StopLine,
        0.9,
        dir,
    ));
    // A non-decisive one is.
    cands.push(candidate(
        &cloud,
        arrow_pts.clone(),
        MarkingClass::DashedLine,
        0.3,
        dir,
    ));
    let params = refine::Params {
        mode: refine::Mode::On,
        ..refine::Params::default()
    };
    // What the network says about each fixture on its own.
    let views: Vec<ClusterPoints> = fx
        .iter()
        .map(|(_, idx)| ClusterPoints {
            cloud: &cloud,
            indices: idx,
            direction: dir,
        })
        .collect();
    let direct = classifier().classify(&views).unwrap();
    let threshold = classifier().info().unknown_threshold as f64;
    let stats = refine::refine(&mut cands, &cloud, &params, &classify::Params::default()).unwrap();
    assert_eq!(stats.examined, fx.len() + 1);
    let named = direct.iter().filter(|p| p.class != MarkingClass::Unknown).count();
    assert!(named >= fx.len() - 1, "{direct:?}");
    assert_eq!(stats.reclassified, named + 1);
    for (p, c) in direct.iter().zip(&cands) {
        assert_eq!(c.class, p.class);
        assert!((c.confidence - p.confidence as f64).abs() < 1e-6);
        if c.class != MarkingClass::Unknown {
            assert!(c.confidence >= threshold && c.confidence <= 1.0);
        }
    }
    let n = cands.len();
    assert_eq!(cands[n - 2].class, MarkingClass::StopLine);
    assert_eq!(cands[n - 2].confidence, 0.9);
    assert_eq!(cands[n - 1].class, MarkingClass::LeftArrow);
    let off = refine::Params {
        mode: refine::Mode::Off,
        ..refine::Params::default()
    };
    let before = cands.clone();
    cands[0].class = MarkingClass::Unknown;
    let stats = refine::refine(&mut cands, &cloud, &off, &classify::Params::default()).unwrap();
    assert_eq!(stats, refine::RefineStats::default());
    assert_eq!(cands[0].class, MarkingClass::Unknown);
    assert_eq!(cands[1..], before[1..]);
}

#[test]
fn a_confident_dash_is_overruled_only_into_a_painted_object_the_network_is_sure_of() {
    let dir: [f64; 2] = [0.8, -0.6];
    let h = dir[1].atan2(dir[0]);
    let mut cloud = PointCloud::with_origin([500_000.0, 4_000_000.0, 10.0]);
    let fx = fixtures(&mut cloud, h, [0.0, 0.0]);
    let ds = dashes(&mut cloud, h, [0.0, 0.0]);
    // A straight arrow whose head the rules missed, and three clean dashes: all confident
    // dashes to the rules.
    let (_, arrow) = &fx[0];
    let mut cands: Vec<Candidate> = std::iter::once(arrow)
        .chain(ds.iter().map(|(_, idx)| idx))
        .map(|idx| candidate(&cloud, idx.clone(), MarkingClass::DashedLine, 0.7, dir))
        .collect();
    let views: Vec<ClusterPoints> = cands
        .iter()
        .map(|c| ClusterPoints {
            cloud: &cloud,
            indices: &c.indices,
            direction: dir,
        })
        .collect();
    let direct = classifier().classify(&views).unwrap();
    drop(views);
    assert_eq!(direct[0].class, MarkingClass::StraightArrow, "{direct:?}");
    let params = refine::Params {
        mode: refine::Mode::On,
        ..refine::Params::default()
    };
    let stats = refine::refine(&mut cands, &cloud, &params, &classify::Params::default()).unwrap();
    assert_eq!(stats.examined, 4);
    assert_eq!(stats.reclassified, 1);
    assert_eq!(cands[0].class, MarkingClass::StraightArrow);
    assert!((cands[0].confidence - direct[0].confidence as f64).abs() < 1e-6);
    for (c, p) in cands[1..].iter().zip(&direct[1..]) {
        assert_eq!(c.class, MarkingClass::DashedLine);
        // Agreement raises the confidence; disagreement leaves it.
        let want = if p.class == MarkingClass::DashedLine {
            0.7f64.max(p.confidence as f64)
        } else {
            0.7
        };
        assert!((c.confidence - want).abs() < 1e-6, "{c:?} {p:?}");
    }
    // Below the overrule confidence the arrow stays a dash.
    let strict = refine::Params {
        dash_overrule_confidence: (direct[0].confidence + 0.01).min(1.0) as f64,
        ..params.clone()
    };
    let mut again = vec![candidate(
        &cloud,
        arrow.clone(),
        MarkingClass::DashedLine,
        0.7,
        dir,
    )];
    let stats = refine::refine(&mut again, &cloud, &strict, &classify::Params::default()).unwrap();
    assert_eq!((stats.examined, stats.reclassified), (1, 0));
    assert_eq!(again[0].class, MarkingClass::DashedLine);
    // A confident dash the network calls a crosswalk stripe stays a dash (the rules saw no
    // stripe beside it): a lone 0.45 m wide, 5 m long bar.
    let bar: Vec<[f64; 2]> = rect(0.0, 0.0, 5.0, 0.45)
        .iter()
        .map(|p| {
            [
                200.0 + p[0] * dir[0] - p[1] * dir[1],
                50.0 + p[0] * dir[1] + p[1] * dir[0],
            ]
        })
        .collect();
    let bar = fill(&mut cloud, &bar, 0.0);
    let said = network_says(&cloud, &bar, dir);
    assert_eq!(said[0].class, MarkingClass::Crosswalk, "{said:?}");
    // Even with the overrule confidence below the network's, the class is not one a dash
    // may become.
    let lenient = refine::Params {
        dash_overrule_confidence: (said[0].confidence as f64 - 0.05).max(0.0),
        ..params.clone()
    };
    let mut lone = vec![candidate(&cloud, bar, MarkingClass::DashedLine, 0.7, dir)];
    let stats = refine::refine(&mut lone, &cloud, &lenient, &classify::Params::default()).unwrap();
    assert_eq!((stats.examined, stats.reclassified), (1, 0));
    assert_eq!(lone[0].class, MarkingClass::DashedLine);
}

/// A solid piece no longer than a painted object is shown to the network like a confident
/// dash, and becomes the painted object the network is sure of (here the straight arrow
/// fixture); a longer solid piece is a lane line and is not examined.
#[test]
fn a_short_solid_piece_is_overruled_into_a_painted_object_a_long_one_is_not_examined() {
    let dir: [f64; 2] = [0.8, -0.6];
    let mut cloud = PointCloud::with_origin([500_000.0, 4_000_000.0, 10.0]);
    let fx = fixtures(&mut cloud, dir[1].atan2(dir[0]), [0.0, 0.0]);
    let (_, arrow) = &fx[0];
    let params = refine::Params {
        mode: refine::Mode::On,
        ..refine::Params::default()
    };
    let mut short = vec![candidate(
        &cloud,
        arrow.clone(),
        MarkingClass::SolidLine,
        0.9,
        dir,
    )];
    let stats = refine::refine(&mut short, &cloud, &params, &classify::Params::default()).unwrap();
    assert_eq!((stats.examined, stats.reclassified), (1, 1));
    assert_eq!(short[0].class, MarkingClass::StraightArrow);
    let mut long = vec![candidate(
        &cloud,
        arrow.clone(),
        MarkingClass::SolidLine,
        0.9,
        dir,
    )];
    long[0].shape.length_m = classify::MAX_OBJECT_LENGTH_M + 1.0;
    let stats = refine::refine(&mut long, &cloud, &params, &classify::Params::default()).unwrap();
    assert_eq!((stats.examined, stats.reclassified), (0, 0));
    assert_eq!(long[0].class, MarkingClass::SolidLine);
}

/// A straight drive along +x from x = −20 to 40, 3.5 m to the right of y = 0.
fn drive_along_x() -> Trajectory {
    let poses: Vec<Pose> = (0..=60)
        .map(|i| Pose {
            time: i as f64,
            x: i as f64 - 20.0,
            y: -3.5,
            z: 0.0,
            heading_deg: None,
            roll_deg: None,
            pitch_deg: None,
        })
        .collect();
    Trajectory::new(poses).unwrap()
}

/// A GB 5768 straight arrow of the length `len` picks, pointing along +x from x = 10, filled
/// densely ([`fill_marking`]); its point indices.
fn straight_arrow_from_x10(len: impl Fn(&Standard) -> f64) -> (PointCloud, Vec<usize>) {
    let mut cloud = PointCloud::with_origin([500_000.0, 4_000_000.0, 10.0]);
    let st = Standard::parse("gb").unwrap();
    let frame = Frame2 {
        o: [10.0, 0.0],
        u: [1.0, 0.0],
        v: [0.0, 1.0],
    };
    let arrow = fill_marking(
        &mut cloud,
        &markings::arrow(ArrowKind::Straight, &frame, len(&st)),
    );
    (cloud, arrow)
}

#[test]
fn a_long_arrow_the_rules_peeled_apart_is_put_back_together() {
    // GB 5768 highway straight arrow (9 m) in a lane beside a straight drive along +x.
    let (cloud, arrow) = straight_arrow_from_x10(|st| st.arrow_len_highway);
    let traj = drive_along_x();
    let clusters = cluster::run(&cloud, &cluster::Params::default());
    assert_eq!(clusters.len(), 1);
    let mut cands = classify::run(&cloud, &clusters, &traj, &classify::Params::default());
    // The shaft passes the line test and is peeled off the head.
    assert!(
        cands.len() >= 2,
        "{:?}",
        cands.iter().map(|c| c.class).collect::<Vec<_>>()
    );
    assert!(cands.iter().all(|c| c.whole.is_some()));
    assert!(cands.iter().all(|c| c.class != MarkingClass::StraightArrow));
    let params = refine::Params {
        mode: refine::Mode::On,
        ..refine::Params::default()
    };
    let stats = refine::refine(&mut cands, &cloud, &params, &classify::Params::default()).unwrap();
    assert_eq!(stats.reassembled, 1);
    assert_eq!(cands.len(), 1);
    assert_eq!(cands[0].class, MarkingClass::StraightArrow);
    assert!(cands[0].confidence >= 0.8);
    assert_eq!(cands[0].indices.len(), arrow.len());
    assert!(cands[0].whole.is_none());
    // The robust rectangle of the whole arrow (trimmed extent: 8.5 of its 9 m).
    assert!(cands[0].shape.length_m > 8.0, "{:?}", cands[0].shape);
    // With the overrule confidence out of reach the pieces stay as the rules left them.
    let mut apart = classify::run(&cloud, &clusters, &traj, &classify::Params::default());
    let n = apart.len();
    let strict = refine::Params {
        dash_overrule_confidence: 1.0,
        ..params
    };
    let stats = refine::refine(&mut apart, &cloud, &strict, &classify::Params::default()).unwrap();
    assert_eq!((stats.reassembled, apart.len()), (0, n));
}

/// Added time of the learned hook on a whole scene (a measurement, not a check; run with
/// `cargo test --release --test learned -- --ignored --nocapture refine_overhead`).
/// The marking points are the scene's labelled paint points (what a perfect front half
/// gives); they go through the real cluster and classify stages, then [`refine`]. Prints the
/// time of each step and the class accuracy of the candidates (majority label) before and
/// after the refinement. Scene directory: `ROADMARK_BENCH_SCENE` (default
/// /work/scenes/urban_intersection, made by `roadmark simulate --scene urban_intersection
/// --seed 1`).
#[test]
#[ignore]
fn refine_overhead() {
    use roadmark::pipeline::{classify, cluster, io, params};
    use std::path::{Path, PathBuf};
    use std::time::Instant;
    let dir = PathBuf::from(
        std::env::var("ROADMARK_BENCH_SCENE").unwrap_or_else(|_| "/work/scenes/urban_intersection".into()),
    );
    if !dir.join("labels.bin").is_file() {
        println!("no scene at {}: skipped", dir.display());
        return;
    }
    let cloud = io::read_points(&[dir.join("points.las").as_path()]).unwrap();
    let raw = std::fs::read(dir.join("labels.bin")).unwrap();
    let labels: Vec<u32> = raw
        .chunks_exact(4)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let truth: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("truth.geojson")).unwrap()).unwrap();
    let classes: Vec<MarkingClass> = truth["features"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|f| f["properties"]["layer"] == "marking")
        .map(|f| MarkingClass::parse(f["properties"]["class"].as_str().unwrap()).unwrap())
        .collect();
    let paint: Vec<usize> = (0..cloud.len()).filter(|&i| labels[i] != 0).collect();
    let marks = cloud.select(&paint);
    let mark_labels: Vec<u32> = paint.iter().map(|&i| labels[i]).collect();
    let traj = io::read_trajectory(Path::new(&dir.join("trajectory.csv")))
        .unwrap()
        .to_local(marks.origin);
    let p = params::Params::default();
    let t0 = Instant::now();
    let clusters = cluster::run(&marks, &p.cluster);
    let mut cands = classify::run(&marks, &clusters, &traj, &p.classify);
    let t_geo = t0.elapsed().as_secs_f64();
    let t0 = Instant::now();
    let c = classifier();
    let t_load = t0.elapsed().as_secs_f64();
    let truth_of = |cand: &Candidate| {
        let mut count = std::collections::HashMap::new();
        for &i in &cand.indices {
            *count.entry(mark_labels[i]).or_insert(0usize) += 1;
        }
        let (&l, _) = count
            .iter()
            .max_by_key(|(l, n)| (**n, std::cmp::Reverse(**l)))
            .unwrap();
        classes[l as usize - 1]
    };
    let accuracy = |cands: &[Candidate]| {
        let ok = cands.iter().filter(|c| c.class == truth_of(c)).count();
        ok as f64 / cands.len().max(1) as f64
    };
    let before = accuracy(&cands);
    let t0 = Instant::now();
    let stats = refine::refine_with(
        c,
        &mut cands,
        &marks,
        &refine::Params::default(),
        &classify::Params::default(),
    )
    .unwrap();
    let t_refine = t0.elapsed().as_secs_f64();
    let after = accuracy(&cands);
    println!(
        "\n{}: {} points, {} paint points, {} clusters, {} candidates",
        dir.display(),
        cloud.len(),
        marks.len(),
        clusters.len(),
        cands.len()
    );
    println!(
        "cluster+classify {t_geo:.3} s; model load {t_load:.3} s; refine {t_refine:.3} s \
         ({} examined, {} reclassified)",
        stats.examined, stats.reclassified
    );
    println!("candidate class accuracy: geometric {before:.3}, after refine {after:.3}");
}

/// A GB highway straight-right arrow along +x from x = 10 whose turning branch lost its
/// first `gap` metres beside the shaft (a worn spot).
fn straight_right_arrow_worn_at_the_branch(gap: f64) -> PointCloud {
    let mut full = PointCloud::with_origin([500_000.0, 4_000_000.0, 10.0]);
    let st = Standard::parse("gb").unwrap();
    let len = st.arrow_len_highway;
    let frame = Frame2 {
        o: [10.0, 0.0],
        u: [1.0, 0.0],
        v: [0.0, 1.0],
    };
    let all = fill_marking(&mut full, &markings::arrow(ArrowKind::StraightRight, &frame, len));
    // The shaft's half width, from its tail.
    let h = all
        .iter()
        .filter(|&&i| full.x[i] < 11.0)
        .map(|&i| full.y[i].abs())
        .fold(0.0, f64::max);
    let worn = |i: usize| {
        let (u, v) = (full.x[i] - 10.0, full.y[i]);
        u < 0.6 * len && v < -h && v > -h - gap
    };
    let kept: Vec<usize> = all.iter().copied().filter(|&i| !worn(i)).collect();
    assert!(kept.len() < all.len());
    full.select(&kept)
}

/// The network's guess of a glyph (arrow, diamond) below `glyph_min_confidence` is not
/// taken for an `unknown` candidate: the worn arrow with 0.32 m of its branch gone, shown
/// whole, is a straight-right arrow to the network at p ≈ 0.79 only; with the bar just
/// above that it stays `unknown`, just below it it is taken.
#[test]
fn an_unsure_glyph_stays_unknown() {
    let cloud = straight_right_arrow_worn_at_the_branch(0.32);
    let all: Vec<usize> = (0..cloud.len()).collect();
    let said = classifier()
        .classify(&[ClusterPoints {
            cloud: &cloud,
            indices: &all,
            direction: [1.0, 0.0],
        }])
        .unwrap();
    let p = said[0].prob(said[0].class) as f64;
    assert_eq!(said[0].class, MarkingClass::StraightRightArrow);
    assert!(p > 0.5 && p < 0.8, "{p}");
    let with_bar = |bar: f64| {
        let params = refine::Params {
            mode: refine::Mode::On,
            glyph_min_confidence: bar,
            ..refine::Params::default()
        };
        let mut cands = vec![candidate(
            &cloud,
            all.clone(),
            MarkingClass::Unknown,
            0.4,
            [1.0, 0.0],
        )];
        refine::refine(&mut cands, &cloud, &params, &classify::Params::default()).unwrap();
        cands[0].class
    };
    assert_eq!(with_bar(p + 0.01), MarkingClass::Unknown);
    assert_eq!(with_bar(p - 0.01), MarkingClass::StraightRightArrow);
}

/// A highway straight-right arrow whose turning branch broke off the shaft at a worn spot
/// (its first 0.28 m beside the shaft gone): two clusters, the shaft and straight head
/// (which the rules peel apart; alone a straight arrow, p 0.98) and the branch 0.28 m
/// away. The classify stage groups them and the network names the group the straight-right
/// arrow it is (p ≥ 0.8); the pieces are put back together.
#[test]
fn an_arrow_whose_branch_wore_off_the_shaft_is_put_back_together() {
    let cloud = straight_right_arrow_worn_at_the_branch(0.28);
    let traj = drive_along_x();
    let clusters = cluster::run(&cloud, &cluster::Params::default());
    assert_eq!(clusters.len(), 2, "shaft and head, and the branch");
    let mut cands = classify::run(&cloud, &clusters, &traj, &classify::Params::default());
    assert!(cands.iter().any(|c| c.group.is_some()));
    let params = refine::Params {
        mode: refine::Mode::On,
        ..refine::Params::default()
    };
    refine::refine(&mut cands, &cloud, &params, &classify::Params::default()).unwrap();
    let classes: Vec<_> = cands.iter().map(|c| (c.class, c.indices.len())).collect();
    assert_eq!(cands.len(), 1, "{classes:?}");
    assert_eq!(cands[0].class, MarkingClass::StraightRightArrow, "{classes:?}");
    assert_eq!(cands[0].indices.len(), cloud.len());
    assert!(cands[0].confidence >= 0.8);
}

/// A straight arrow in two pieces (shaft, head) with a lane line's 5 m piece passing 0.35 m
/// from its head. The classify stage's group of the three is no sure painted object with
/// the line in it (p ≈ 0.58); offered without the line piece as well
/// (`Candidate::alternatives`, p ≈ 0.95), the arrow's two pieces are put back together as
/// the arrow and the line piece stays.
#[test]
fn an_arrow_grouped_with_a_passing_line_piece_is_put_back_together_without_it() {
    let (mut cloud, arrow) = straight_arrow_from_x10(|st| st.arrow_len_urban);
    let min_y = arrow.iter().map(|&i| cloud.y[i]).fold(f64::INFINITY, f64::min);
    let line = fill(&mut cloud, &rect(12.5, min_y - 0.35 - 0.075, 5.0, 0.15), 0.0);
    let (shaft, head): (Vec<usize>, Vec<usize>) = arrow.iter().partition(|&&i| cloud.x[i] < 13.0);
    let dir = [1.0, 0.0];
    let mut cands = vec![
        candidate(&cloud, shaft, MarkingClass::DashedLine, 0.8, dir),
        candidate(&cloud, head, MarkingClass::Unknown, 0.4, dir),
        candidate(&cloud, line.clone(), MarkingClass::DashedLine, 0.8, dir),
    ];
    let mut all: Vec<usize> = arrow.iter().chain(&line).copied().collect();
    all.sort_unstable();
    let whole = std::sync::Arc::new(candidate(&cloud, all, MarkingClass::Unknown, 0.0, dir));
    let mut only_arrow = arrow.clone();
    only_arrow.sort_unstable();
    let alt = std::sync::Arc::new(candidate(&cloud, only_arrow, MarkingClass::Unknown, 0.0, dir));
    for c in &mut cands {
        c.whole = Some(std::sync::Arc::clone(&whole));
    }
    for c in &mut cands[..2] {
        c.alternatives.push(std::sync::Arc::clone(&alt));
    }
    let params = refine::Params {
        mode: refine::Mode::On,
        ..refine::Params::default()
    };
    // Without the alternative the group stays apart: with the line it is no arrow.
    let mut without: Vec<Candidate> = cands.clone();
    without.iter_mut().for_each(|c| c.alternatives.clear());
    refine::refine(&mut without, &cloud, &params, &classify::Params::default()).unwrap();
    assert_eq!(
        without.len(),
        3,
        "{:?}",
        without.iter().map(|c| c.class).collect::<Vec<_>>()
    );
    let stats = refine::refine(&mut cands, &cloud, &params, &classify::Params::default()).unwrap();
    let classes: Vec<_> = cands.iter().map(|c| (c.class, c.indices.len())).collect();
    assert_eq!(stats.reassembled, 1, "{classes:?}");
    assert_eq!(cands.len(), 2, "{classes:?}");
    assert_eq!(cands[0].class, MarkingClass::StraightArrow, "{classes:?}");
    assert_eq!(cands[0].indices.len(), arrow.len());
    assert_eq!(cands[1].indices, line);
}

/// The network names a candidate a crosswalk stripe only when its rectangle is no wider than
/// a stripe (the rules' `crosswalk_max_width_m`): sparse far blobs of road noise 1–3 m wide read as
/// stripes. The same points, a 5 × 0.45 m stripe, as a 0.45 m wide candidate become one; as a
/// 1.2 m wide one (what such a blob measures) they keep their geometric class.
#[test]
fn a_candidate_wider_than_a_stripe_is_no_crosswalk_stripe() {
    let dir: [f64; 2] = [0.6, 0.8];
    let (s, c) = (dir[1], dir[0]);
    let mut cloud = PointCloud::with_origin([500_000.0, 4_000_000.0, 10.0]);
    let poly: Vec<[f64; 2]> = rect(0.0, 0.0, 5.0, 0.45)
        .iter()
        .map(|p| [p[0] * c - p[1] * s, p[0] * s + p[1] * c])
        .collect();
    let idx = fill(&mut cloud, &poly, 0.0);
    let direct = network_says(&cloud, &idx, dir);
    assert_eq!(direct[0].class, MarkingClass::Crosswalk, "{direct:?}");
    let params = refine::Params {
        mode: refine::Mode::On,
        ..refine::Params::default()
    };
    let mut cands: Vec<Candidate> = [0.45, 1.2]
        .iter()
        .map(|&w| {
            let mut k = candidate(&cloud, idx.clone(), MarkingClass::Unknown, 0.0, dir);
            k.shape.width_m = w;
            k
        })
        .collect();
    refine::refine(&mut cands, &cloud, &params, &classify::Params::default()).unwrap();
    assert_eq!(cands[0].class, MarkingClass::Crosswalk);
    assert_eq!(cands[1].class, MarkingClass::Unknown);
    // The bound is the rules' crosswalk width parameter.
    let wide = classify::Params {
        crosswalk_max_width_m: 1.5,
        ..classify::Params::default()
    };
    let mut again = vec![cands[1].clone()];
    refine::refine(&mut again, &cloud, &params, &wide).unwrap();
    assert_eq!(again[0].class, MarkingClass::Crosswalk);
}
