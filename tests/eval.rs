//! The evaluator on hand-made scenes: self-evaluation, reprojection, and one test per kind of
//! error (shift, missing, wrong class, extra, split lane line), plus the CLI.

use roadmark::eval::{EvalOptions, Report, evaluate};
use roadmark::pipeline::geojson::{CrsMode, from_geojson, to_geojson, write_geojson};
use roadmark::pipeline::types::{Crs, Extraction, LaneLine, LaneLineClass, Marking, MarkingClass};

const X0: f64 = 231000.0;
const Y0: f64 = 3380000.0;

fn marking(id: &str, class: MarkingClass, ring: Vec<[f64; 2]>) -> Marking {
    Marking {
        id: id.into(),
        class,
        outline: ring.iter().map(|p| [X0 + p[0], Y0 + p[1]]).collect(),
        confidence: 1.0,
        length_m: 0.0,
        width_m: 0.0,
        heading_deg: 90.0,
        point_count: 100,
    }
}

fn rect(x0: f64, y0: f64, x1: f64, y1: f64) -> Vec<[f64; 2]> {
    vec![[x0, y0], [x1, y0], [x1, y1], [x0, y1]]
}

fn lane(id: &str, class: LaneLineClass, pts: &[[f64; 2]], marking_ids: &[&str]) -> LaneLine {
    let line: Vec<[f64; 2]> = pts.iter().map(|p| [X0 + p[0], Y0 + p[1]]).collect();
    LaneLine {
        id: id.into(),
        class,
        length_m: line
            .windows(2)
            .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
            .sum(),
        line,
        confidence: 1.0,
        marking_ids: marking_ids.iter().map(|s| s.to_string()).collect(),
    }
}

/// Lines only, along x: a solid edge line and a dashed lane line of four 6 m dashes.
fn lines_scene() -> Extraction {
    use MarkingClass::*;
    let mut markings = vec![marking("solid", SolidLine, rect(0.0, 0.0, 60.0, 0.15))];
    for k in 0..4 {
        let x = 15.0 * k as f64;
        markings.push(marking(&format!("d{k}"), DashedLine, rect(x, 3.5, x + 6.0, 3.65)));
    }
    Extraction {
        markings,
        lane_lines: vec![
            lane(
                "edge",
                LaneLineClass::SolidLine,
                &[[0.0, 0.075], [60.0, 0.075]],
                &["solid"],
            ),
            lane(
                "lane",
                LaneLineClass::DashedLine,
                &[[0.0, 3.575], [51.0, 3.575]],
                &["d0", "d1", "d2", "d3"],
            ),
        ],
        crs: Some(Crs::epsg(32650)),
    }
}

/// The lines plus a stop line, an arrow and three crosswalk stripes.
fn full_scene() -> Extraction {
    use MarkingClass::*;
    let mut ex = lines_scene();
    ex.markings
        .push(marking("stop", StopLine, rect(62.0, 0.2, 62.4, 3.4)));
    ex.markings.push(marking(
        "arrow",
        StraightArrow,
        vec![
            [20.0, 1.6],
            [23.0, 1.6],
            [23.0, 1.3],
            [25.0, 1.75],
            [23.0, 2.2],
            [23.0, 1.9],
            [20.0, 1.9],
        ],
    ));
    for k in 0..3 {
        let y = 0.3 + 1.0 * k as f64;
        ex.markings.push(marking(
            &format!("cw{k}"),
            Crosswalk,
            rect(64.0, y, 68.0, y + 0.45),
        ));
    }
    ex
}

fn score(t: &Extraction, r: &Extraction) -> Report {
    evaluate(t, r, &EvalOptions::default()).expect("evaluation runs")
}

fn shifted(ex: &Extraction, dx: f64, dy: f64) -> Extraction {
    roadmark::pipeline::reproject::map_coords(ex, |x, y| Ok((x + dx, y + dy))).unwrap()
}

#[test]
fn truth_against_itself_is_exactly_perfect() {
    let t = full_scene();
    let r = score(&t, &t);
    assert_eq!(r.pixel.completeness, Some(1.0));
    assert_eq!(r.pixel.correctness, Some(1.0));
    assert_eq!(r.pixel.f_score, Some(1.0));
    assert_eq!(r.solid_line.recall, Some(1.0));
    assert_eq!(r.solid_line.precision, Some(1.0));
    assert_eq!(r.objects.detection.f_score, Some(1.0));
    assert_eq!(r.objects.mean_iou, Some(1.0));
    assert_eq!(r.objects.macro_f1, Some(1.0));
    assert_eq!(r.objects.classification_accuracy, Some(1.0));
    for c in &r.objects.per_class {
        assert_eq!(
            (c.precision, c.recall, c.f1),
            (Some(1.0), Some(1.0), Some(1.0)),
            "{}",
            c.class
        );
    }
    let n = r.objects.confusion.labels.len();
    for (i, row) in r.objects.confusion.counts.iter().enumerate() {
        for (j, &v) in row.iter().enumerate() {
            assert!(i == j || v == 0, "off-diagonal confusion at {i},{j}");
        }
    }
    assert_eq!(r.objects.confusion.counts[n - 1][n - 1], 0);
    assert_eq!(r.lanes.completeness, Some(1.0));
    assert_eq!(r.lanes.correctness, Some(1.0));
    assert_eq!(r.lanes.rmse_m, Some(0.0));
    assert_eq!(r.lanes.fragmentation_mean, Some(1.0));
    assert_eq!(r.lanes.fragmentation_max, Some(1));
    assert_eq!(r.lanes.class_agreement, Some(1.0));
    assert_eq!(r.corners.pairs, 4 + 1 + 3);
    assert_eq!(r.corners.rmse_m, Some(0.0));
    assert!(r.notes.is_empty());
    assert_eq!(r.working_crs, "EPSG:32650");
}

#[test]
fn a_wgs84_result_is_reprojected_into_the_truth_crs() {
    let t = full_scene();
    let lonlat = from_geojson(&to_geojson(&t, CrsMode::Wgs84).unwrap()).unwrap();
    assert_eq!(lonlat.crs, Some(Crs::epsg(4326)));
    let r = score(&t, &lonlat);
    assert!(
        r.notes
            .iter()
            .any(|n| n.contains("reprojected from EPSG:4326 to EPSG:32650")),
        "{:?}",
        r.notes
    );
    // 7 decimals are ≤ 0.6 cm: axis-aligned edges 2.5 cm from pixel centres never change
    // side; only a few pixels along the slanted edges of the arrow head do.
    assert!(r.pixel.f_score.unwrap() > 0.999, "{:?}", r.pixel);
    assert_eq!(r.objects.detection.f_score, Some(1.0));
    assert_eq!(r.lanes.completeness, Some(1.0));
    assert!(r.lanes.rmse_m.unwrap() < 0.006, "{:?}", r.lanes.rmse_m);
    assert!(r.corners.rmse_m.unwrap() < 0.008, "{:?}", r.corners.rmse_m);
    // And the other way round: a lon/lat truth goes into the result's CRS.
    let r = score(&lonlat, &t);
    assert_eq!(r.working_crs, "EPSG:32650");
    assert_eq!(r.objects.detection.f_score, Some(1.0));
    // Both lon/lat: scored in the UTM zone.
    let r = score(&lonlat, &lonlat);
    assert_eq!(r.working_crs, "EPSG:32650");
    assert_eq!(r.pixel.f_score, Some(1.0));
    assert_eq!(r.lanes.rmse_m, Some(0.0));
}

#[test]
fn a_shift_of_ten_centimetres() {
    let t = lines_scene();
    let r = score(&t, &shifted(&t, 0.0, 0.1));
    // Lines 0.15 m wide shifted 0.10 m across: one pixel column in three still overlaps.
    let third = 1.0 / 3.0;
    assert!((r.pixel.f_score.unwrap() - third).abs() < 1e-6, "{:?}", r.pixel);
    assert!((r.pixel.completeness.unwrap() - third).abs() < 1e-6);
    // The lane lines are still all there, 0.1 m off.
    assert_eq!(r.lanes.completeness, Some(1.0));
    assert_eq!(r.lanes.correctness, Some(1.0));
    assert!((r.lanes.rmse_m.unwrap() - 0.1).abs() < 1e-6);
    assert_eq!(r.lanes.fragmentation_max, Some(1));
    // Solid-line length is found within the 0.15 m tolerance.
    assert_eq!(r.solid_line.recall, Some(1.0));
    // IoU of a 0.15 m dash shifted 0.1 m is 0.05/0.25 = 0.2 < 0.3: no dash matches.
    let dashed = r.objects.class("dashed_line").unwrap();
    assert_eq!((dashed.tp, dashed.fn_, dashed.fp), (0, 4, 4));
    // Along the line, the same shift barely matters.
    let r = score(&t, &shifted(&t, 0.1, 0.0));
    let dashed = r.objects.class("dashed_line").unwrap();
    assert_eq!(dashed.f1, Some(1.0));
    assert!(r.pixel.f_score.unwrap() > 0.97);
    assert!(r.corners.rmse_m.unwrap() > 0.099 && r.corners.rmse_m.unwrap() < 0.101);
}

#[test]
fn a_missing_marking() {
    let t = full_scene();
    let mut res = t.clone();
    res.markings.retain(|m| m.id != "d2");
    let r = score(&t, &res);
    let dashed = r.objects.class("dashed_line").unwrap();
    assert_eq!((dashed.tp, dashed.fn_, dashed.fp), (3, 1, 0));
    assert_eq!(dashed.recall, Some(0.75));
    assert_eq!(dashed.precision, Some(1.0));
    assert_eq!(r.objects.confusion.get("dashed_line", "none"), 1);
    assert_eq!(r.pixel.correctness, Some(1.0));
    assert!(r.pixel.completeness.unwrap() < 1.0);
    assert!(r.objects.macro_f1.unwrap() < 1.0);
}

#[test]
fn a_wrong_class_appears_in_the_confusion_matrix() {
    let t = full_scene();
    let mut res = t.clone();
    res.markings.iter_mut().find(|m| m.id == "stop").unwrap().class = MarkingClass::Crosswalk;
    let r = score(&t, &res);
    assert_eq!(r.objects.confusion.get("stop_line", "crosswalk"), 1);
    assert_eq!(
        r.objects.detection.f_score,
        Some(1.0),
        "detection ignores the class"
    );
    // 10 matched pairs, one with the wrong class.
    assert_eq!(r.objects.classification_accuracy, Some(0.9));
    let stop = r.objects.class("stop_line").unwrap();
    assert_eq!((stop.tp, stop.fn_, stop.recall), (0, 1, Some(0.0)));
    let cw = r.objects.class("crosswalk").unwrap();
    assert_eq!((cw.tp, cw.fp), (3, 1));
    assert_eq!(r.pixel.f_score, Some(1.0), "pixels ignore the class");
}

#[test]
fn an_extra_false_marking() {
    let t = full_scene();
    let mut res = t.clone();
    res.markings.push(marking(
        "ghost",
        MarkingClass::Diamond,
        vec![[40.0, 8.0], [41.0, 9.0], [40.0, 10.0], [39.0, 9.0]],
    ));
    let r = score(&t, &res);
    assert_eq!(r.objects.confusion.get("none", "diamond"), 1);
    assert_eq!(r.objects.detection.fp, 1);
    assert_eq!(r.objects.detection.recall, Some(1.0));
    assert!(r.objects.detection.precision.unwrap() < 1.0);
    assert_eq!(r.objects.class("diamond").unwrap().precision, Some(0.0));
    // The diamond is not in the truth, so it does not enter the macro-F1.
    assert_eq!(r.objects.macro_f1, Some(1.0));
    assert_eq!(r.pixel.completeness, Some(1.0));
    assert!(r.pixel.correctness.unwrap() < 1.0);
}

#[test]
fn a_lane_line_split_in_two() {
    let t = lines_scene();
    let mut res = t.clone();
    let dashed = res.lane_lines.remove(1);
    res.lane_lines.push(lane(
        "a",
        LaneLineClass::DashedLine,
        &[[0.0, 3.575], [25.0, 3.575]],
        &[],
    ));
    res.lane_lines.push(lane(
        "b",
        LaneLineClass::DashedLine,
        &[[25.0, 3.575], [51.0, 3.575]],
        &[],
    ));
    assert_eq!(dashed.id, "lane");
    let r = score(&t, &res);
    assert_eq!(r.lanes.fragmentation_max, Some(2));
    assert_eq!(r.lanes.fragmentation_mean, Some(1.5));
    assert_eq!(r.lanes.completeness, Some(1.0));
    assert_eq!(r.lanes.correctness, Some(1.0));
}

#[test]
fn solid_line_in_pieces_is_scored_by_length() {
    let t = lines_scene();
    let mut res = t.clone();
    res.markings.retain(|m| m.class != MarkingClass::SolidLine);
    // The 60 m line found as three 10 m pieces over 0..30 m.
    for k in 0..3 {
        let x = 10.0 * k as f64;
        res.markings.push(marking(
            &format!("s{k}"),
            MarkingClass::SolidLine,
            rect(x, 0.0, x + 10.0, 0.15),
        ));
    }
    let r = score(&t, &res);
    // 30 m, plus the tolerance past the last piece.
    assert!(
        (r.solid_line.recall.unwrap() - 30.15 / 60.0).abs() < 1e-3,
        "{:?}",
        r.solid_line
    );
    assert_eq!(r.solid_line.precision, Some(1.0));
    // Lengths come from the outlines when the files leave `length_m` out.
    assert!((r.solid_line.truth_length_m - 60.0).abs() < 1e-6);
    assert!((r.solid_line.detected_length_m.unwrap() - 30.15).abs() < 0.06);
    let row = r.objects.class("solid_line").unwrap();
    assert_eq!(row.method, "length");
    assert_eq!(row.recall, r.solid_line.recall);
    // The pieces are fragments, not false markings.
    assert_eq!(r.objects.solid_line_fragments, [1, 3]);
    assert_eq!(r.objects.confusion.get("none", "solid_line"), 0);
}

#[test]
fn the_cli_prints_a_table_and_a_json_report() {
    let dir = tempfile::tempdir().unwrap();
    let (tp, rp) = (
        dir.path().join("truth.geojson"),
        dir.path().join("result.geojson"),
    );
    let t = full_scene();
    let mut res = t.clone();
    res.markings.retain(|m| m.id != "d1");
    write_geojson(&tp, &t, CrsMode::Native).unwrap();
    write_geojson(&rp, &res, CrsMode::Wgs84).unwrap();
    let bin = env!("CARGO_BIN_EXE_roadmark");
    let out = std::process::Command::new(bin)
        .args(["evaluate", "--truth"])
        .arg(&tp)
        .arg("--result")
        .arg(&rp)
        .arg("--json")
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let report: Report = serde_json::from_slice(&out.stdout).expect("the JSON report parses");
    assert_eq!(report.truth.markings, 10);
    assert_eq!(report.result.markings, 9);
    assert_eq!(report.result.crs, "EPSG:4326");
    assert_eq!(report.objects.class("dashed_line").unwrap().recall, Some(0.75));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for key in [
        "pixel",
        "solid_line",
        "objects",
        "lanes",
        "corners",
        "options",
        "notes",
    ] {
        assert!(v.get(key).is_some(), "missing {key}");
    }
    assert_eq!(v["pixel"]["pixel_m"], 0.05);

    let out = std::process::Command::new(bin)
        .args(["evaluate", "--pixel-m", "0.1", "--truth"])
        .arg(&tp)
        .arg("--result")
        .arg(&tp)
        .output()
        .unwrap();
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(
        text.contains("pixels (0.1 m)") && text.contains("1.0000"),
        "{text}"
    );
    assert!(text.contains("confusion (rows truth, columns result)"), "{text}");

    // Bad input: one clear line naming the file.
    let bad = dir.path().join("bad.geojson");
    let no_layer = r#"{"type":"Feature","geometry":null,"properties":{"id":"x","class":"solid_line"}}"#;
    std::fs::write(
        &bad,
        format!(r#"{{"type":"FeatureCollection","features":[{no_layer}]}}"#),
    )
    .unwrap();
    let out = std::process::Command::new(bin)
        .args(["evaluate", "--truth"])
        .arg(&tp)
        .arg("--result")
        .arg(&bad)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(
        err.contains("bad.geojson") && err.contains("missing property \"layer\""),
        "{err}"
    );
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    let out = std::process::Command::new(bin)
        .args(["evaluate", "--iou", "0", "--truth"])
        .arg(&tp)
        .arg("--result")
        .arg(&tp)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("iou_min"));
}

#[test]
fn a_one_kilometre_drive_is_evaluated_quickly() {
    // 1 km of road, 4 lines (two solid, two dashed 6 m / 9 m gaps), along a gentle curve.
    use MarkingClass::*;
    let mut ex = Extraction {
        crs: Some(Crs::epsg(32650)),
        ..Default::default()
    };
    let at = |s: f64, off: f64| {
        let a = s / 2000.0; // radius 2 km
        [
            2000.0 * a.sin() - off * a.sin(),
            2000.0 * (1.0 - a.cos()) + off * a.cos(),
        ]
    };
    let band = |s0: f64, s1: f64, off: f64, w: f64| -> Vec<[f64; 2]> {
        let n = ((s1 - s0) / 2.0).ceil() as usize;
        let mut ring: Vec<[f64; 2]> = (0..=n)
            .map(|i| at(s0 + (s1 - s0) * i as f64 / n as f64, off - w / 2.0))
            .collect();
        ring.extend(
            (0..=n)
                .rev()
                .map(|i| at(s0 + (s1 - s0) * i as f64 / n as f64, off + w / 2.0)),
        );
        ring
    };
    for (k, off) in [0.0, 3.5, 7.0, 10.5].into_iter().enumerate() {
        if k == 0 || k == 3 {
            ex.markings
                .push(marking(&format!("s{k}"), SolidLine, band(0.0, 1000.0, off, 0.15)));
        } else {
            let mut s = 0.0;
            while s + 6.0 <= 1000.0 {
                ex.markings.push(marking(
                    &format!("d{k}_{s}"),
                    DashedLine,
                    band(s, s + 6.0, off, 0.15),
                ));
                s += 15.0;
            }
        }
        let pts: Vec<[f64; 2]> = (0..=500).map(|i| at(2.0 * i as f64, off)).collect();
        ex.lane_lines
            .push(lane(&format!("l{k}"), LaneLineClass::SolidLine, &pts, &[]));
    }
    let res = shifted(&ex, 0.03, -0.02);
    let start = std::time::Instant::now();
    let r = score(&ex, &res);
    let secs = start.elapsed().as_secs_f64();
    eprintln!("1 km evaluation: {secs:.2} s, pixel F {:?}", r.pixel.f_score);
    assert!(r.pixel.f_score.unwrap() > 0.6);
    assert_eq!(r.lanes.completeness, Some(1.0));
    assert_eq!(r.objects.class("dashed_line").unwrap().f1, Some(1.0));
}
