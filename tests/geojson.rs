//! GeoJSON round trips: native (exact) and RFC 7946 lon/lat (CCW closed rings, 7 decimals,
//! within 1e-7° of the reprojection), for the Chinese UTM and the Dutch RD New data.

use roadmark::pipeline::geojson::{
    CrsMode, WGS84_DECIMALS, from_geojson, read_geojson, to_geojson, write_geojson,
};
use roadmark::pipeline::reproject::Reprojector;
use roadmark::pipeline::types::{Crs, Extraction, LaneLine, LaneLineClass, Marking, MarkingClass};
use serde_json::Value;

/// A small scene around (x0, y0): a clockwise dash, a counter-clockwise arrow, a rotated
/// crosswalk stripe and a curved lane line. Properties already at output precision.
fn scene(x0: f64, y0: f64, epsg: u32) -> Extraction {
    let at = |pts: &[[f64; 2]]| -> Vec<[f64; 2]> { pts.iter().map(|p| [x0 + p[0], y0 + p[1]]).collect() };
    let mk = |id: &str, class, outline| Marking {
        id: id.into(),
        class,
        outline,
        confidence: 0.875,
        length_m: 6.0,
        width_m: 0.15,
        heading_deg: 12.5,
        point_count: 321,
    };
    let (c, s) = (0.3f64.cos(), 0.3f64.sin());
    let stripe: Vec<[f64; 2]> = [[0.0, 0.0], [4.0, 0.0], [4.0, 0.45], [0.0, 0.45]]
        .iter()
        .map(|p| [30.0 + p[0] * c - p[1] * s, 2.0 + p[0] * s + p[1] * c])
        .collect();
    Extraction {
        markings: vec![
            mk(
                "m1",
                MarkingClass::DashedLine,
                at(&[[0.0, 0.0], [0.0, 6.0], [0.15, 6.0], [0.15, 0.0]]),
            ),
            mk(
                "m2",
                MarkingClass::StraightArrow,
                at(&[
                    [10.0, 1.6],
                    [13.0, 1.6],
                    [13.0, 1.3],
                    [15.0, 1.75],
                    [13.0, 2.2],
                    [13.0, 1.9],
                    [10.0, 1.9],
                ]),
            ),
            mk("m3", MarkingClass::Crosswalk, at(&stripe)),
        ],
        lane_lines: vec![LaneLine {
            id: "l1".into(),
            class: LaneLineClass::DashedLine,
            line: at(&(0..=20)
                .map(|i| [0.075 + 0.01 * (i * i) as f64, 3.0 * i as f64])
                .collect::<Vec<_>>()),
            confidence: 0.5,
            length_m: 60.25,
            marking_ids: vec!["m1".into()],
        }],
        crs: Some(Crs::epsg(epsg)),
    }
}

fn signed_area(ring: &[Value]) -> f64 {
    let p: Vec<(f64, f64)> = ring
        .iter()
        .map(|c| (c[0].as_f64().unwrap(), c[1].as_f64().unwrap()))
        .collect();
    p.windows(2)
        .map(|w| w[0].0 * w[1].1 - w[1].0 * w[0].1)
        .sum::<f64>()
        / 2.0
}

fn decimals(v: &Value) -> usize {
    let s = v.to_string();
    s.split_once('.').map_or(0, |(_, d)| d.len())
}

/// Equal, with coordinates to 1e-9 m: serde_json's default float parser may be 1 ulp off
/// (≈ 3e-11 m at UTM magnitudes) unless its `float_roundtrip` feature is on.
fn assert_same(a: &Extraction, b: &Extraction) {
    let strip = |e: &Extraction| {
        let mut e = e.clone();
        e.markings.iter_mut().for_each(|m| m.outline.clear());
        e.lane_lines.iter_mut().for_each(|l| l.line.clear());
        e
    };
    assert_eq!(strip(a), strip(b));
    let pts = |e: &Extraction| -> Vec<[f64; 2]> {
        e.markings
            .iter()
            .flat_map(|m| m.outline.clone())
            .chain(e.lane_lines.iter().flat_map(|l| l.line.clone()))
            .collect()
    };
    let (pa, pb) = (pts(a), pts(b));
    assert_eq!(pa.len(), pb.len());
    for (p, q) in pa.iter().zip(&pb) {
        assert!(
            (p[0] - q[0]).abs() < 1e-9 && (p[1] - q[1]).abs() < 1e-9,
            "{p:?} vs {q:?}"
        );
    }
}

#[test]
fn native_round_trip_is_exact() {
    for (x0, y0, epsg) in [(231000.123, 3380000.456, 32650), (121000.5, 487000.25, 28992)] {
        let ex = scene(x0, y0, epsg);
        let v = to_geojson(&ex, CrsMode::Native).unwrap();
        assert_eq!(v["crs"]["properties"]["name"], format!("EPSG:{epsg}"));
        let back = from_geojson(&v).unwrap();
        assert_same(&back, &ex);
        // Through a file as well.
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("native.geojson");
        write_geojson(&p, &ex, CrsMode::Native).unwrap();
        assert_same(&read_geojson(&p).unwrap(), &ex);
    }
}

#[test]
fn wgs84_output_follows_rfc_7946() {
    for (x0, y0, epsg) in [(231000.123, 3380000.456, 32650), (121000.5, 487000.25, 28992)] {
        let ex = scene(x0, y0, epsg);
        let v = to_geojson(&ex, CrsMode::Wgs84).unwrap();
        assert!(v.get("crs").is_none() && v.get("roadmark").is_none());
        let rp = Reprojector::from_epsg(epsg).unwrap();
        let features = v["features"].as_array().unwrap();
        assert_eq!(features.len(), 4);
        for (k, f) in features.iter().enumerate() {
            let (coords, original): (Vec<Value>, Vec<[f64; 2]>) = if k < 3 {
                let ring = f["geometry"]["coordinates"][0].as_array().unwrap().clone();
                assert_eq!(ring.first(), ring.last(), "closed ring");
                assert!(
                    signed_area(&ring) > 0.0,
                    "outer ring counter-clockwise (feature {k})"
                );
                let mut o = ex.markings[k].outline.clone();
                // Outlines given clockwise come out reversed.
                let cw: f64 = o
                    .iter()
                    .zip(o.iter().cycle().skip(1))
                    .map(|(a, b)| a[0] * b[1] - b[0] * a[1])
                    .sum();
                if cw < 0.0 {
                    o.reverse();
                }
                o.push(o[0]);
                (ring, o)
            } else {
                let line = f["geometry"]["coordinates"].as_array().unwrap().clone();
                (line, ex.lane_lines[0].line.clone())
            };
            assert_eq!(coords.len(), original.len());
            for (c, o) in coords.iter().zip(&original) {
                assert!(
                    decimals(&c[0]) <= WGS84_DECIMALS as usize && decimals(&c[1]) <= 7,
                    "{c}"
                );
                let (lon, lat) = rp.to_wgs84(o[0], o[1]).unwrap();
                assert!(
                    (c[0].as_f64().unwrap() - lon).abs() <= 0.5e-7 + 1e-12,
                    "{c} vs {lon}"
                );
                assert!(
                    (c[1].as_f64().unwrap() - lat).abs() <= 0.5e-7 + 1e-12,
                    "{c} vs {lat}"
                );
                assert!((-180.0..=180.0).contains(&lon) && (-90.0..=90.0).contains(&lat));
            }
        }
        // Read back: recognised as lon/lat, and back in the projected CRS within 1 cm.
        let back = from_geojson(&v).unwrap();
        assert_eq!(back.crs, Some(Crs::epsg(4326)));
        assert_eq!(back.markings[1].class, MarkingClass::StraightArrow);
        assert_eq!(back.markings[0].point_count, 321);
        for (b, o) in back.lane_lines[0].line.iter().zip(&ex.lane_lines[0].line) {
            let (x, y) = rp.from_wgs84(b[0], b[1]).unwrap();
            assert!((x - o[0]).hypot(y - o[1]) < 0.01, "{x},{y} vs {o:?}");
        }
    }
}

#[test]
fn crs_mode_parses() {
    assert_eq!("wgs84".parse::<CrsMode>().unwrap(), CrsMode::Wgs84);
    assert_eq!("Native".parse::<CrsMode>().unwrap(), CrsMode::Native);
    assert!("utm".parse::<CrsMode>().unwrap_err().contains("native or wgs84"));
    let m: CrsMode = serde_json::from_str("\"wgs84\"").unwrap();
    assert_eq!(m.as_str(), "wgs84");
}
