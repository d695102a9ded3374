//! Whole simulated surveys (short drives, reduced pulse rate so the suite stays quick).

use las::Reader;
use roadmark::pipeline::types::MarkingClass;
use roadmark::sim::{SimOptions, markings::Standard, simulate};
use std::collections::{BTreeSet, HashMap};
use std::path::Path;

fn opts(scene: &str, seed: u64, len: f64) -> SimOptions {
    SimOptions {
        scene: scene.into(),
        seed,
        length_m: Some(len),
        points_per_s: 100_000.0,
        ..SimOptions::default()
    }
}

fn read_labels(dir: &Path) -> Vec<u32> {
    let b = std::fs::read(dir.join("labels.bin")).unwrap();
    b.chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

struct Pt {
    x: f64,
    y: f64,
    z: f64,
    i: u16,
    t: f64,
    ch: u8,
}

fn read_points(path: &Path) -> Vec<Pt> {
    let mut r = Reader::from_path(path).unwrap();
    let pd = r.read_all().unwrap();
    pd.points()
        .map(|p| {
            let p = p.unwrap();
            Pt {
                x: p.x,
                y: p.y,
                z: p.z,
                i: p.intensity,
                t: p.gps_time.unwrap(),
                ch: p.scanner_channel,
            }
        })
        .collect()
}

fn truth(dir: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(dir.join("truth.geojson")).unwrap()).unwrap()
}

fn markings(t: &serde_json::Value) -> Vec<&serde_json::Value> {
    t["features"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|f| f["properties"]["layer"] == "marking")
        .collect()
}

/// Trajectory rows (time, x, y, z).
fn trajectory(dir: &Path) -> Vec<[f64; 4]> {
    let s = std::fs::read_to_string(dir.join("trajectory.csv")).unwrap();
    let mut lines = s.lines();
    assert_eq!(lines.next().unwrap(), "time,x,y,z,heading,roll,pitch");
    lines
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            [v[0], v[1], v[2], v[3]]
        })
        .collect()
}

#[test]
fn same_seed_same_bytes_other_seed_other_bytes() {
    let base = tempfile::tempdir().unwrap();
    let (a, b, c) = (
        base.path().join("a"),
        base.path().join("b"),
        base.path().join("c"),
    );
    simulate(&opts("urban_intersection", 7, 12.0), &a).unwrap();
    simulate(&opts("urban_intersection", 7, 12.0), &b).unwrap();
    simulate(&opts("urban_intersection", 8, 12.0), &c).unwrap();
    for f in ["points.las", "labels.bin", "truth.geojson", "trajectory.csv"] {
        assert_eq!(
            std::fs::read(a.join(f)).unwrap(),
            std::fs::read(b.join(f)).unwrap(),
            "{f}"
        );
    }
    assert_ne!(
        std::fs::read(a.join("points.las")).unwrap(),
        std::fs::read(c.join("points.las")).unwrap()
    );
}

#[test]
fn las_header_crs_counts_and_coordinates() {
    let dir = tempfile::tempdir().unwrap();
    let s = simulate(&opts("highway", 1, 10.0), dir.path()).unwrap();
    let r = Reader::from_path(dir.path().join("points.las")).unwrap();
    let h = r.header();
    assert_eq!(h.version(), las::Version::new(1, 4));
    assert_eq!(h.point_format().to_u8().unwrap(), 6);
    assert!(h.gps_time_type().is_standard());
    let wkt = String::from_utf8_lossy(h.get_wkt_crs_bytes().expect("WKT VLR")).to_string();
    assert!(wkt.contains("\"EPSG\",\"32650\""), "{wkt}");
    assert!(h.has_wkt_crs());
    assert_eq!(h.number_of_points(), s.points);
    assert!(s.points > 10_000);
    let labels = read_labels(dir.path());
    assert_eq!(labels.len() as u64, h.number_of_points());
    let b = h.bounds();
    assert!(b.min.x > 231_000.0 && b.max.x < 232_000.0, "{b:?}");
    assert!(b.min.y > 3_379_900.0 && b.max.y < 3_380_400.0, "{b:?}");
    // Acquisition order: GPS time never decreases; same time base as the trajectory.
    let pts = read_points(&dir.path().join("points.las"));
    assert!(pts.windows(2).all(|w| w[1].t >= w[0].t));
    let traj = trajectory(dir.path());
    assert!(pts[0].t >= traj[0][0] && pts.last().unwrap().t <= traj.last().unwrap()[0] + 0.01);
    assert!(traj.len() >= 50, "100 Hz");
}

#[test]
fn every_class_appears_across_scenes() {
    let mut seen: BTreeSet<String> = BTreeSet::new();
    for (scene, len) in [
        ("highway", 8.0),
        ("urban_intersection", 8.0),
        ("curved_ramp", 8.0),
    ] {
        let dir = tempfile::tempdir().unwrap();
        simulate(&opts(scene, 3, len), dir.path()).unwrap();
        let t = truth(dir.path());
        assert_eq!(t["crs"]["properties"]["name"], "EPSG:32650");
        for m in markings(&t) {
            seen.insert(m["properties"]["class"].as_str().unwrap().to_string());
        }
        // Ids are m1.. in order; lane lines name existing markings.
        let ms = markings(&t);
        for (i, m) in ms.iter().enumerate() {
            assert_eq!(m["properties"]["id"], format!("m{}", i + 1));
        }
        let ids: BTreeSet<&str> = ms
            .iter()
            .map(|m| m["properties"]["id"].as_str().unwrap())
            .collect();
        for f in t["features"].as_array().unwrap() {
            if f["properties"]["layer"] == "lane_line" {
                for id in f["properties"]["marking_ids"].as_array().unwrap() {
                    assert!(ids.contains(id.as_str().unwrap()));
                }
            }
        }
    }
    for c in MarkingClass::ALL {
        assert!(
            seen.contains(c.as_str()),
            "class {} missing: {seen:?}",
            c.as_str()
        );
    }
}

#[test]
fn markings_have_their_real_dimensions() {
    let dir = tempfile::tempdir().unwrap();
    simulate(&opts("highway", 1, 8.0), dir.path()).unwrap();
    let t = truth(dir.path());
    let dashes: Vec<_> = markings(&t)
        .into_iter()
        .filter(|m| m["properties"]["class"] == "dashed_line")
        .collect();
    // Regular lane dashes are 6 m × 0.15 m, on the straight and on the arc.
    let regular: Vec<_> = dashes
        .iter()
        .filter(|m| m["properties"]["width_m"].as_f64().unwrap() < 0.2)
        .collect();
    assert!(regular.len() > 20);
    for m in regular {
        let l = m["properties"]["length_m"].as_f64().unwrap();
        let w = m["properties"]["width_m"].as_f64().unwrap();
        assert!((l - 6.0).abs() < 0.01 && (w - 0.15).abs() < 1e-9, "{l} × {w}");
    }
    let dir = tempfile::tempdir().unwrap();
    simulate(&opts("urban_intersection", 1, 8.0), dir.path()).unwrap();
    let t = truth(dir.path());
    let mut by_class: HashMap<String, Vec<(f64, f64)>> = HashMap::new();
    for m in markings(&t) {
        let p = &m["properties"];
        by_class
            .entry(p["class"].as_str().unwrap().into())
            .or_default()
            .push((p["length_m"].as_f64().unwrap(), p["width_m"].as_f64().unwrap()));
    }
    for (l, w) in &by_class["dashed_line"] {
        assert!((l - 2.0).abs() < 0.01 && (w - 0.15).abs() < 1e-9);
    }
    for (l, w) in &by_class["crosswalk"] {
        assert!((w - 0.45).abs() < 1e-9 && (3.0..=6.0).contains(l), "{l} × {w}");
    }
    for (l, w) in &by_class["stop_line"] {
        assert!((w - 0.3).abs() < 1e-9 && *l > 3.0, "{l} × {w}");
    }
    for (l, w) in &by_class["straight_arrow"] {
        assert!((l - 6.0).abs() < 1e-9 && *w < 1.0, "{l} × {w}");
    }
    // MUTCD: 10 ft dashes.
    let dir = tempfile::tempdir().unwrap();
    let o = SimOptions {
        standard: Standard::MUTCD,
        ..opts("highway", 1, 8.0)
    };
    simulate(&o, dir.path()).unwrap();
    let t = truth(dir.path());
    assert!(markings(&t).iter().any(|m| {
        m["properties"]["class"] == "dashed_line"
            && (m["properties"]["length_m"].as_f64().unwrap() - 3.048).abs() < 0.01
    }));
}

/// Horizontal distance of each point from the trajectory position at its time.
fn horizontal_range(pts: &[Pt], traj: &[[f64; 4]]) -> Vec<(f64, f64)> {
    pts.iter()
        .map(|p| {
            let k = traj.partition_point(|r| r[0] < p.t).min(traj.len() - 1);
            let r = traj[k];
            ((p.x - r[1]).hypot(p.y - r[2]), p.z - (r[3] - 2.2))
        })
        .collect()
}

#[test]
fn paint_is_brighter_than_asphalt_and_far_paint_darker_than_near() {
    let dir = tempfile::tempdir().unwrap();
    simulate(&opts("highway", 5, 30.0), dir.path()).unwrap();
    let pts = read_points(&dir.path().join("points.las"));
    let labels = read_labels(dir.path());
    let traj = trajectory(dir.path());
    let hr = horizontal_range(&pts, &traj);
    let mean = |f: &dyn Fn(usize) -> bool| {
        let v: Vec<f64> = (0..pts.len())
            .filter(|&i| f(i))
            .map(|i| f64::from(pts[i].i))
            .collect();
        assert!(v.len() > 30, "too few samples");
        v.iter().sum::<f64>() / v.len() as f64
    };
    // Ground points (the barriers start 9 m out), near the vehicle and a lane or two away.
    let ground = |i: usize| hr[i].1.abs() < 0.25;
    let near = |i: usize| (1.0..3.0).contains(&hr[i].0);
    let far = |i: usize| (5.0..8.5).contains(&hr[i].0);
    let paint_near = mean(&|i| labels[i] > 0 && near(i));
    let asphalt_near = mean(&|i| labels[i] == 0 && ground(i) && near(i));
    let paint_far = mean(&|i| labels[i] > 0 && far(i));
    let asphalt_far = mean(&|i| labels[i] == 0 && ground(i) && far(i));
    assert!(paint_near > 2.0 * asphalt_near, "{paint_near} vs {asphalt_near}");
    assert!(paint_far > 2.0 * asphalt_far, "{paint_far} vs {asphalt_far}");
    assert!(
        paint_far < 0.25 * paint_near,
        "far paint {paint_far} vs near {paint_near}"
    );
    assert!(paint_far < asphalt_near, "far paint darker than near asphalt");
}

#[test]
fn dual_head_interleaves_two_channels_and_tiles_split_the_drive() {
    let dir = tempfile::tempdir().unwrap();
    let o = SimOptions {
        tiles: 3,
        ..opts("dual_head", 2, 12.0)
    };
    let s = simulate(&o, dir.path()).unwrap();
    assert_eq!(s.tiles.len(), 3);
    let mut all = Vec::new();
    for (name, n) in &s.tiles {
        let p = read_points(&dir.path().join(name));
        assert_eq!(p.len() as u64, *n);
        assert!(*n > 0, "{name}");
        all.extend(p);
    }
    assert_eq!(read_labels(dir.path()).len(), all.len());
    let channels: BTreeSet<u8> = all.iter().map(|p| p.ch).collect();
    assert_eq!(channels, BTreeSet::from([0, 1]));
    let switches = all.windows(2).filter(|w| w[0].ch != w[1].ch).count();
    assert!(
        switches > all.len() / 100,
        "heads interleave in time: {switches} switches"
    );
    assert!(all.windows(2).all(|w| w[1].t >= w[0].t));
    // Some marking has points in two tiles.
    let labels = read_labels(dir.path());
    let mut tiles_of: HashMap<u32, BTreeSet<usize>> = HashMap::new();
    let mut k = 0;
    for (ti, (_, n)) in s.tiles.iter().enumerate() {
        for _ in 0..*n {
            if labels[k] > 0 {
                tiles_of.entry(labels[k]).or_default().insert(ti);
            }
            k += 1;
        }
    }
    assert!(
        tiles_of.values().any(|t| t.len() > 1),
        "a marking crosses a tile boundary"
    );
}

#[test]
fn bad_options_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let e = simulate(&opts("nowhere", 1, 10.0), dir.path())
        .unwrap_err()
        .to_string();
    assert!(e.contains("unknown scene 'nowhere'"), "{e}");
    let e = simulate(&opts("highway", 1, 1.0), dir.path())
        .unwrap_err()
        .to_string();
    assert!(e.contains("length"), "{e}");
    let o = SimOptions {
        heads: Some(3),
        ..opts("highway", 1, 10.0)
    };
    assert!(
        simulate(&o, dir.path())
            .unwrap_err()
            .to_string()
            .contains("heads")
    );
}
