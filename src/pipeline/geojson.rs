//! GeoJSON output in the contract's schema (layers `marking` and `lane_line`).

use super::types::{Extraction, LaneLine, Marking};
use serde_json::{Value, json};

/// Coordinate output mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CrsMode {
    Native,
    Wgs84,
}

fn marking_feature(m: &Marking) -> Value {
    let mut ring: Vec<[f64; 2]> = m.outline.clone();
    if let Some(first) = ring.first().copied() {
        ring.push(first);
    }
    json!({
        "type": "Feature",
        "geometry": {"type": "Polygon", "coordinates": [ring]},
        "properties": {
            "id": m.id, "layer": "marking", "class": m.class.as_str(), "confidence": m.confidence,
            "length_m": m.length_m, "width_m": m.width_m, "heading_deg": m.heading_deg,
            "point_count": m.point_count,
        }
    })
}

fn lane_feature(l: &LaneLine) -> Value {
    json!({
        "type": "Feature",
        "geometry": {"type": "LineString", "coordinates": l.line},
        "properties": {
            "id": l.id, "layer": "lane_line", "class": l.class.as_str(), "confidence": l.confidence,
            "length_m": l.length_m, "marking_ids": l.marking_ids,
        }
    })
}

/// Native-CRS FeatureCollection (with the `crs` member when the EPSG code is known).
pub fn to_native(ex: &Extraction) -> Value {
    let features: Vec<Value> = ex
        .markings
        .iter()
        .map(marking_feature)
        .chain(ex.lane_lines.iter().map(lane_feature))
        .collect();
    let mut fc = json!({"type": "FeatureCollection", "features": features});
    if let Some(code) = ex.crs.as_ref().and_then(|c| c.epsg) {
        fc["crs"] = json!({"type": "name", "properties": {"name": format!("EPSG:{code}")}});
    }
    fc
}
