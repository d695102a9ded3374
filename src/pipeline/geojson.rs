//! GeoJSON output and input in the contract's schema (layers `marking` and `lane_line`).
//!
//! **What.** [`to_geojson`] turns an [`Extraction`] into a FeatureCollection, [`write_geojson`]
//! writes it to a file; [`from_geojson`] / [`read_geojson`] read one back (truth files,
//! results of other runs) with strict schema checks.
//!
//! **Output.**
//! - [`CrsMode::Native`]: coordinates exactly as they are (full f64), plus
//!   `"crs": {"type": "name", "properties": {"name": "EPSG:NNNN"}}` when the EPSG code is known.
//! - [`CrsMode::Wgs84`] (RFC 7946): longitude/latitude rounded to 7 decimals (≈ 1 cm),
//!   closed rings, counter-clockwise outer rings, no `crs` member.
//! - When the CRS is not known, `Wgs84` falls back to native coordinates, and a native file
//!   without an EPSG code says what its CRS is through a top-level foreign member:
//!   `"roadmark": {"crs": "unknown"}`, or `"roadmark": {"crs": "wkt", "crs_wkt": "<OGC WKT>"}`
//!   when only a WKT is known. Readers that do not know the member ignore it (RFC 7946 §6.1).
//! - Properties: every feature has `id`, `layer`, `class`, `confidence` (3 decimals);
//!   markings `length_m`, `width_m` (3 decimals, mm), `heading_deg` (2 decimals),
//!   `point_count`; lane lines `length_m` and `marking_ids`.
//!
//! **Input.** The CRS is found, in order, from the `crs` member (`EPSG:N`,
//! `urn:ogc:def:crs:EPSG::N`, `…OGC:1.3:CRS84`), the `roadmark` member, and finally the
//! coordinates: without either member, a file whose every coordinate is within
//! lon/lat range is RFC 7946 (EPSG:4326); otherwise it is native with an unknown CRS.
//! `id`, `layer`, `class` and the geometry are required and checked; `confidence` defaults to
//! 1, and the derived marking/lane-line measures are computed from the geometry when absent
//! (so hand-drawn truth files work). Polygon holes and multi-geometries are rejected: a
//! marking is one outline.
//!
//! **Complexity.** Linear in the number of vertices (plus one reprojection per vertex).
//!
//! [`to_geojson`]: crate::pipeline::geojson::to_geojson
//! [`write_geojson`]: crate::pipeline::geojson::write_geojson
//! [`from_geojson`]: crate::pipeline::geojson::from_geojson
//! [`read_geojson`]: crate::pipeline::geojson::read_geojson
//! [`CrsMode::Native`]: crate::pipeline::geojson::CrsMode::Native
//! [`CrsMode::Wgs84`]: crate::pipeline::geojson::CrsMode::Wgs84

use super::reproject::{EPSG_WGS84, Reprojector, crs_label};
use super::types::{Crs, Extraction, LaneLine, LaneLineClass, Marking, MarkingClass};
use geo::MinimumRotatedRect;
use serde_json::{Map, Value, json};
use std::collections::HashSet;
use std::path::{Path, PathBuf};

/// Coordinate output mode (`crs=native|wgs84`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CrsMode {
    /// Coordinates in the input CRS.
    Native,
    /// RFC 7946 longitude/latitude.
    Wgs84,
}

impl CrsMode {
    /// The contract's default: `wgs84` whenever the input CRS is known, else `native`.
    pub fn default_for(crs: Option<&Crs>) -> CrsMode {
        match crs {
            Some(c) if c.epsg.is_some() || c.wkt.is_some() => CrsMode::Wgs84,
            _ => CrsMode::Native,
        }
    }

    pub fn as_str(self) -> &'static str {
        match self {
            CrsMode::Native => "native",
            CrsMode::Wgs84 => "wgs84",
        }
    }
}

impl std::str::FromStr for CrsMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "native" => Ok(CrsMode::Native),
            "wgs84" => Ok(CrsMode::Wgs84),
            _ => Err(format!("unknown crs mode \"{s}\" (expected native or wgs84)")),
        }
    }
}

/// Errors writing or reading GeoJSON.
#[derive(Debug, thiserror::Error)]
pub enum GeoJsonError {
    /// The coordinates could not be reprojected.
    #[error("{0}")]
    Reproject(String),
    /// A feature has a NaN or infinite coordinate.
    #[error("feature {0} has a non-finite coordinate")]
    NonFinite(String),
    #[error("cannot write {path}: {source}")]
    Write { path: PathBuf, source: std::io::Error },
    /// Unreadable file or not the contract's schema.
    #[error("{path}: {message}")]
    Read { path: PathBuf, message: String },
}

/// Decimals of RFC 7946 output coordinates (1e-7° ≈ 1.1 cm).
pub const WGS84_DECIMALS: i32 = 7;

fn round_to(v: f64, decimals: i32) -> f64 {
    let f = 10f64.powi(decimals);
    (v * f).round() / f
}

/// Twice the signed area of a ring (positive when counter-clockwise).
fn signed_area2(ring: &[[f64; 2]]) -> f64 {
    let n = ring.len();
    (0..n)
        .map(|i| {
            let (a, b) = (ring[i], ring[(i + 1) % n]);
            a[0] * b[1] - b[0] * a[1]
        })
        .sum()
}

fn marking_properties(m: &Marking) -> Value {
    json!({
        "id": m.id, "layer": "marking", "class": m.class.as_str(),
        "confidence": round_to(m.confidence, 3),
        "length_m": round_to(m.length_m, 3), "width_m": round_to(m.width_m, 3),
        "heading_deg": round_to(m.heading_deg, 2), "point_count": m.point_count,
    })
}

fn lane_properties(l: &LaneLine) -> Value {
    json!({
        "id": l.id, "layer": "lane_line", "class": l.class.as_str(),
        "confidence": round_to(l.confidence, 3),
        "length_m": round_to(l.length_m, 3), "marking_ids": l.marking_ids,
    })
}

/// Closed ring; counter-clockwise when `ccw` (RFC 7946), else in the given orientation.
/// Repeated consecutive vertices (rounding can merge near ones) are removed.
fn closed_ring(outline: &[[f64; 2]], ccw: bool) -> Vec<[f64; 2]> {
    let mut ring = distinct_ring(outline);
    if ccw && signed_area2(&ring) < 0.0 {
        ring.reverse();
    }
    if let Some(first) = ring.first().copied() {
        ring.push(first);
    }
    ring
}

/// The ring without consecutive repeats (and without a closing repeat of the first vertex).
fn distinct_ring(outline: &[[f64; 2]]) -> Vec<[f64; 2]> {
    let mut ring = outline.to_vec();
    ring.dedup();
    while ring.len() > 1 && ring.first() == ring.last() {
        ring.pop();
    }
    ring
}

/// The polyline without consecutive repeats.
fn distinct_line(line: &[[f64; 2]]) -> Vec<[f64; 2]> {
    let mut l = line.to_vec();
    l.dedup();
    l
}

fn feature(geometry: Value, properties: Value) -> Value {
    json!({"type": "Feature", "geometry": geometry, "properties": properties})
}

/// The features; a marking whose outline has fewer than 3 distinct vertices, or a lane line
/// with fewer than 2 distinct positions (possible only after rounding to WGS84 decimals, for
/// features of about a centimetre), is left out: it would be invalid GeoJSON.
fn collection(ex: &Extraction, polygon_ccw: bool) -> Vec<Value> {
    ex.markings
        .iter()
        .filter(|m| distinct_ring(&m.outline).len() >= 3)
        .map(|m| {
            feature(
                json!({"type": "Polygon", "coordinates": [closed_ring(&m.outline, polygon_ccw)]}),
                marking_properties(m),
            )
        })
        .chain(
            ex.lane_lines
                .iter()
                .filter(|l| distinct_line(&l.line).len() >= 2)
                .map(|l| {
                    feature(
                        json!({"type": "LineString", "coordinates": distinct_line(&l.line)}),
                        lane_properties(l),
                    )
                }),
        )
        .collect()
}

/// Native-CRS FeatureCollection: the `crs` member when the EPSG code is known, else the
/// `roadmark` foreign member saying what the CRS is (see the module docs).
pub fn to_native(ex: &Extraction) -> Value {
    let mut fc = json!({"type": "FeatureCollection", "features": collection(ex, false)});
    match &ex.crs {
        Some(Crs { epsg: Some(code), .. }) => {
            fc["crs"] = json!({"type": "name", "properties": {"name": format!("EPSG:{code}")}});
        }
        Some(Crs { wkt: Some(w), .. }) => fc["roadmark"] = json!({"crs": "wkt", "crs_wkt": w}),
        _ => fc["roadmark"] = json!({"crs": "unknown"}),
    }
    fc
}

fn check_finite(ex: &Extraction) -> Result<(), GeoJsonError> {
    let ok = |pts: &[[f64; 2]]| pts.iter().all(|p| p[0].is_finite() && p[1].is_finite());
    if let Some(m) = ex.markings.iter().find(|m| !ok(&m.outline)) {
        return Err(GeoJsonError::NonFinite(format!("marking {}", m.id)));
    }
    if let Some(l) = ex.lane_lines.iter().find(|l| !ok(&l.line)) {
        return Err(GeoJsonError::NonFinite(format!("lane_line {}", l.id)));
    }
    Ok(())
}

/// The extraction as a GeoJSON FeatureCollection in the requested mode.
///
/// `Wgs84` with an unknown CRS gives the native collection (marked `"roadmark": {"crs":
/// "unknown"}`); a known CRS that cannot be reprojected is an error.
pub fn to_geojson(ex: &Extraction, mode: CrsMode) -> Result<Value, GeoJsonError> {
    check_finite(ex)?;
    let crs = match (&ex.crs, mode) {
        (Some(c), CrsMode::Wgs84) if c.epsg.is_some() || c.wkt.is_some() => c,
        _ => return Ok(to_native(ex)),
    };
    let rp = Reprojector::new(crs).map_err(GeoJsonError::Reproject)?;
    let lonlat = super::reproject::map_coords(ex, |x, y| {
        let (lon, lat) = rp.to_wgs84(x, y)?;
        Ok((round_to(lon, WGS84_DECIMALS), round_to(lat, WGS84_DECIMALS)))
    })
    .map_err(GeoJsonError::Reproject)?;
    Ok(json!({"type": "FeatureCollection", "features": collection(&lonlat, true)}))
}

/// Write the extraction as GeoJSON (through a temporary file renamed into place, so a reader
/// never sees half a file).
pub fn write_geojson(path: &Path, ex: &Extraction, mode: CrsMode) -> Result<(), GeoJsonError> {
    let value = to_geojson(ex, mode)?;
    let write_err = |source| GeoJsonError::Write {
        path: path.to_path_buf(),
        source,
    };
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    let text = serde_json::to_vec(&value).map_err(|e| write_err(std::io::Error::other(e)))?;
    std::fs::write(&tmp, text).map_err(write_err)?;
    std::fs::rename(&tmp, path).map_err(write_err)
}

/// Read a GeoJSON file in the contract's schema; errors name the file.
pub fn read_geojson(path: &Path) -> Result<Extraction, GeoJsonError> {
    let err = |message: String| GeoJsonError::Read {
        path: path.to_path_buf(),
        message,
    };
    let text = std::fs::read(path).map_err(|e| err(format!("cannot read: {e}")))?;
    let value: Value = serde_json::from_slice(&text).map_err(|e| err(format!("not valid JSON: {e}")))?;
    from_geojson(&value).map_err(err)
}

/// EPSG code of a GeoJSON `crs` name (`EPSG:N`, `urn:ogc:def:crs:EPSG:[version]:N`, CRS84).
pub fn parse_crs_name(name: &str) -> Option<u32> {
    let n = name.trim();
    let upper = n.to_ascii_uppercase();
    if upper.ends_with("CRS84") {
        return Some(EPSG_WGS84);
    }
    let code = if let Some(c) = upper.strip_prefix("EPSG:") {
        c
    } else if upper.starts_with("URN:OGC:DEF:CRS:EPSG:") {
        upper.rsplit(':').next()?
    } else {
        return None;
    };
    code.parse().ok()
}

/// Where a feature is, for error messages.
struct At(usize);
impl std::fmt::Display for At {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "feature {}", self.0)
    }
}

fn position(v: &Value, at: &At) -> Result<[f64; 2], String> {
    let arr = v
        .as_array()
        .filter(|a| a.len() >= 2)
        .ok_or_else(|| format!("{at}: a position must be an array of at least 2 numbers"))?;
    let x = arr[0].as_f64();
    let y = arr[1].as_f64();
    match (x, y) {
        (Some(x), Some(y)) if x.is_finite() && y.is_finite() => Ok([x, y]),
        _ => Err(format!("{at}: a position holds a non-number")),
    }
}

fn positions(v: &Value, at: &At, what: &str) -> Result<Vec<[f64; 2]>, String> {
    v.as_array()
        .ok_or_else(|| format!("{at}: {what} must be an array of positions"))?
        .iter()
        .map(|p| position(p, at))
        .collect()
}

fn prop_f64(props: &Map<String, Value>, key: &str, at: &At) -> Result<Option<f64>, String> {
    match props.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(v) => v
            .as_f64()
            .filter(|x| x.is_finite())
            .map(Some)
            .ok_or_else(|| format!("{at}: property \"{key}\" must be a number, found {v}")),
    }
}

fn prop_id(v: &Value, at: &At) -> Result<String, String> {
    match v {
        Value::String(s) if !s.is_empty() => Ok(s.clone()),
        Value::Number(n) if n.is_u64() || n.is_i64() => Ok(n.to_string()),
        _ => Err(format!(
            "{at}: property \"id\" must be a non-empty string or an integer, found {v}"
        )),
    }
}

/// A feature parsed except for the metric measures, which need the CRS.
enum Parsed {
    Marking(Marking, [bool; 3]),
    Lane(LaneLine, bool),
}

fn parse_feature(i: usize, f: &Value) -> Result<Parsed, String> {
    let at = At(i);
    if f.get("type").and_then(Value::as_str) != Some("Feature") {
        return Err(format!("{at}: \"type\" must be \"Feature\""));
    }
    let props = f
        .get("properties")
        .and_then(Value::as_object)
        .ok_or_else(|| format!("{at}: missing \"properties\" object"))?;
    let layer = match props.get("layer") {
        None => return Err(format!("{at}: missing property \"layer\"")),
        Some(v) => v
            .as_str()
            .ok_or_else(|| format!("{at}: property \"layer\" must be a string"))?,
    };
    let id = prop_id(
        props
            .get("id")
            .ok_or_else(|| format!("{at}: missing property \"id\""))?,
        &at,
    )?;
    let at = At(i);
    let class = props
        .get("class")
        .ok_or_else(|| format!("{at} (id {id}): missing property \"class\""))?
        .as_str()
        .ok_or_else(|| format!("{at} (id {id}): property \"class\" must be a string"))?;
    let confidence = prop_f64(props, "confidence", &at)?.unwrap_or(1.0);
    if !(0.0..=1.0).contains(&confidence) {
        return Err(format!("{at} (id {id}): confidence {confidence} is outside 0..1"));
    }
    let geom = f
        .get("geometry")
        .and_then(Value::as_object)
        .ok_or_else(|| format!("{at} (id {id}): missing \"geometry\""))?;
    let gtype = geom.get("type").and_then(Value::as_str).unwrap_or("");
    let coords = geom.get("coordinates").unwrap_or(&Value::Null);
    match layer {
        "marking" => {
            let class = MarkingClass::parse(class).ok_or_else(|| {
                format!(
                    "{at} (id {id}): unknown marking class \"{class}\" (expected one of {})",
                    MarkingClass::ALL.map(|c| c.as_str()).join(", ")
                )
            })?;
            if gtype != "Polygon" {
                return Err(format!(
                    "{at} (id {id}): a marking must be a Polygon, found \"{gtype}\""
                ));
            }
            let rings = coords
                .as_array()
                .ok_or_else(|| format!("{at} (id {id}): Polygon coordinates must be an array of rings"))?;
            match rings.len() {
                1 => {}
                0 => return Err(format!("{at} (id {id}): the Polygon has no ring")),
                n => {
                    return Err(format!(
                        "{at} (id {id}): the Polygon has {} holes; a marking outline has none",
                        n - 1
                    ));
                }
            }
            let mut outline = positions(&rings[0], &at, "a ring")?;
            if outline.len() > 1 && outline.first() == outline.last() {
                outline.pop();
            }
            outline.dedup();
            if outline.len() < 3 {
                return Err(format!(
                    "{at} (id {id}): the outline has fewer than 3 distinct vertices"
                ));
            }
            let length = prop_f64(props, "length_m", &at)?;
            let width = prop_f64(props, "width_m", &at)?;
            let heading = prop_f64(props, "heading_deg", &at)?;
            let point_count = match props.get("point_count") {
                None | Some(Value::Null) => 0,
                Some(v) => v.as_u64().ok_or_else(|| {
                    format!("{at} (id {id}): \"point_count\" must be a non-negative integer")
                })? as usize,
            };
            let given = [length.is_some(), width.is_some(), heading.is_some()];
            Ok(Parsed::Marking(
                Marking {
                    id,
                    class,
                    outline,
                    confidence,
                    length_m: length.unwrap_or(0.0),
                    width_m: width.unwrap_or(0.0),
                    heading_deg: heading.unwrap_or(0.0),
                    point_count,
                },
                given,
            ))
        }
        "lane_line" => {
            let class = LaneLineClass::parse(class).ok_or_else(|| {
                format!(
                    "{at} (id {id}): unknown lane_line class \"{class}\" (expected solid_line or dashed_line)"
                )
            })?;
            if gtype != "LineString" {
                return Err(format!(
                    "{at} (id {id}): a lane_line must be a LineString, found \"{gtype}\""
                ));
            }
            let mut line = positions(coords, &at, "LineString coordinates")?;
            line.dedup();
            if line.len() < 2 {
                return Err(format!(
                    "{at} (id {id}): the LineString has fewer than 2 distinct positions"
                ));
            }
            let length = prop_f64(props, "length_m", &at)?;
            let marking_ids = match props.get("marking_ids") {
                None | Some(Value::Null) => Vec::new(),
                Some(Value::Array(a)) => a.iter().map(|v| prop_id(v, &at)).collect::<Result<_, _>>()?,
                Some(v) => {
                    return Err(format!(
                        "{at} (id {id}): \"marking_ids\" must be an array, found {v}"
                    ));
                }
            };
            Ok(Parsed::Lane(
                LaneLine {
                    id,
                    class,
                    line,
                    confidence,
                    length_m: length.unwrap_or(0.0),
                    marking_ids,
                },
                length.is_some(),
            ))
        }
        other => Err(format!(
            "{at} (id {id}): unknown layer \"{other}\" (expected marking or lane_line)"
        )),
    }
}

/// Converts coordinates to metres for the derived measures (local equirectangular
/// approximation on lon/lat, good to well under 1 % over a marking).
fn to_metric(pts: &[[f64; 2]], geographic: bool) -> Vec<[f64; 2]> {
    if !geographic || pts.is_empty() {
        return pts.to_vec();
    }
    let lat0 = pts.iter().map(|p| p[1]).sum::<f64>() / pts.len() as f64;
    let my = 111_132.954;
    let mx = my * lat0.to_radians().cos();
    pts.iter().map(|p| [p[0] * mx, p[1] * my]).collect()
}

fn polyline_length(pts: &[[f64; 2]]) -> f64 {
    pts.windows(2)
        .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
        .sum()
}

/// Length, width and long-axis heading (degrees clockwise from north, in [0, 180)) of the
/// minimum rotated rectangle of an outline given in metres.
pub fn outline_dimensions(outline: &[[f64; 2]]) -> (f64, f64, f64) {
    let ls: geo::LineString<f64> = outline.iter().map(|p| geo::coord! {x: p[0], y: p[1]}).collect();
    let Some(rect) = geo::MultiPoint::from(ls.into_points()).minimum_rotated_rect() else {
        return (0.0, 0.0, 0.0);
    };
    let c: Vec<_> = rect.exterior().0.clone();
    if c.len() < 4 {
        return (0.0, 0.0, 0.0);
    }
    let e1 = (c[1].x - c[0].x, c[1].y - c[0].y);
    let e2 = (c[2].x - c[1].x, c[2].y - c[1].y);
    let (l1, l2) = (e1.0.hypot(e1.1), e2.0.hypot(e2.1));
    let (long, short, axis) = if l1 >= l2 { (l1, l2, e1) } else { (l2, l1, e2) };
    // Azimuth: clockwise from north = atan2(east, north).
    let heading = axis.0.atan2(axis.1).to_degrees().rem_euclid(180.0);
    (long, short, heading)
}

fn crs_from_members(v: &Value) -> Result<Option<Option<Crs>>, String> {
    if let Some(crs) = v.get("crs").filter(|c| !c.is_null()) {
        let name = crs
            .get("properties")
            .and_then(|p| p.get("name"))
            .and_then(Value::as_str)
            .ok_or_else(|| "the \"crs\" member has no properties.name".to_string())?;
        let code = parse_crs_name(name).ok_or_else(|| format!("unsupported crs name \"{name}\""))?;
        return Ok(Some(Some(Crs::epsg(code))));
    }
    if let Some(rm) = v.get("roadmark") {
        match rm.get("crs").and_then(Value::as_str) {
            Some("unknown") => return Ok(Some(None)),
            Some("wkt") => {
                let wkt = rm
                    .get("crs_wkt")
                    .and_then(Value::as_str)
                    .ok_or_else(|| "\"roadmark\": crs is \"wkt\" but there is no crs_wkt".to_string())?;
                return Ok(Some(Some(Crs {
                    epsg: None,
                    wkt: Some(wkt.to_string()),
                })));
            }
            Some(other) => return Err(format!("\"roadmark\": unknown crs \"{other}\"")),
            None => {}
        }
    }
    Ok(None)
}

/// Parse a FeatureCollection in the contract's schema; the CRS found is in `Extraction::crs`
/// (see the module docs for the rules). Errors name the feature index and id.
pub fn from_geojson(v: &Value) -> Result<Extraction, String> {
    match v.get("type").and_then(Value::as_str) {
        Some("FeatureCollection") => {}
        Some(t) => return Err(format!("expected a FeatureCollection, found a {t}")),
        None => return Err("expected a GeoJSON FeatureCollection (no \"type\" member)".into()),
    }
    let features = v
        .get("features")
        .and_then(Value::as_array)
        .ok_or_else(|| "the FeatureCollection has no \"features\" array".to_string())?;
    let mut ex = Extraction::default();
    let mut derive = Vec::new();
    let (mut marking_ids, mut lane_ids) = (HashSet::new(), HashSet::new());
    for (i, f) in features.iter().enumerate() {
        match parse_feature(i, f)? {
            Parsed::Marking(m, given) => {
                if !marking_ids.insert(m.id.clone()) {
                    return Err(format!("feature {i}: duplicate marking id \"{}\"", m.id));
                }
                derive.push((true, ex.markings.len(), given));
                ex.markings.push(m);
            }
            Parsed::Lane(l, given) => {
                if !lane_ids.insert(l.id.clone()) {
                    return Err(format!("feature {i}: duplicate lane_line id \"{}\"", l.id));
                }
                derive.push((false, ex.lane_lines.len(), [given; 3]));
                ex.lane_lines.push(l);
            }
        }
    }
    ex.crs = match crs_from_members(v)? {
        Some(crs) => crs,
        None => {
            let in_range = |p: &[f64; 2]| (-180.0..=180.0).contains(&p[0]) && (-90.0..=90.0).contains(&p[1]);
            let all = ex.markings.iter().flat_map(|m| m.outline.iter());
            let all = all.chain(ex.lane_lines.iter().flat_map(|l| l.line.iter()));
            let mut all = all.peekable();
            if all.peek().is_some() && all.all(in_range) {
                Some(Crs::epsg(EPSG_WGS84))
            } else {
                None
            }
        }
    };
    let geographic = match &ex.crs {
        Some(c) if c.epsg == Some(EPSG_WGS84) => true,
        Some(c) => Reprojector::new(c).map(|r| r.is_geographic()).unwrap_or(false),
        None => false,
    };
    // Measures missing from the file come from the geometry (in metres).
    for (is_marking, k, given) in derive {
        if given.iter().all(|g| *g) {
            continue;
        }
        if is_marking {
            let m = &mut ex.markings[k];
            let (l, w, h) = outline_dimensions(&to_metric(&m.outline, geographic));
            // Keep whichever values the file did give.
            if !given[0] {
                m.length_m = l;
            }
            if !given[1] {
                m.width_m = w;
            }
            if !given[2] {
                m.heading_deg = h;
            }
        } else {
            let l = &mut ex.lane_lines[k];
            l.length_m = polyline_length(&to_metric(&l.line, geographic));
        }
    }
    Ok(ex)
}

/// A short description of the CRS of an extraction, for reports.
pub fn describe_crs(ex: &Extraction) -> String {
    crs_label(ex.crs.as_ref())
}

/// Path-free convenience used by tests and tools: parse GeoJSON text.
pub fn from_geojson_str(text: &str) -> Result<Extraction, String> {
    let v: Value = serde_json::from_str(text).map_err(|e| format!("not valid JSON: {e}"))?;
    from_geojson(&v)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(crs: Option<Crs>) -> Extraction {
        let (x0, y0) = (231000.0, 3380000.0);
        Extraction {
            markings: vec![Marking {
                id: "m1".into(),
                class: MarkingClass::DashedLine,
                // Clockwise on purpose.
                outline: vec![[x0, y0], [x0, y0 + 6.0], [x0 + 0.15, y0 + 6.0], [x0 + 0.15, y0]],
                confidence: 0.912345,
                length_m: 6.0001234,
                width_m: 0.15,
                heading_deg: 0.004,
                point_count: 1234,
            }],
            lane_lines: vec![LaneLine {
                id: "l1".into(),
                class: LaneLineClass::DashedLine,
                line: vec![[x0 + 0.075, y0], [x0 + 0.075, y0 + 15.0]],
                confidence: 0.8,
                length_m: 15.0,
                marking_ids: vec!["m1".into()],
            }],
            crs,
        }
    }

    #[test]
    fn native_has_crs_member_and_exact_properties() {
        let v = to_geojson(&sample(Some(Crs::epsg(32650))), CrsMode::Native).unwrap();
        assert_eq!(v["crs"]["properties"]["name"], "EPSG:32650");
        assert!(v.get("roadmark").is_none());
        let m = &v["features"][0]["properties"];
        let keys: Vec<&String> = m.as_object().unwrap().keys().collect();
        let mut want = vec![
            "class",
            "confidence",
            "heading_deg",
            "id",
            "layer",
            "length_m",
            "point_count",
            "width_m",
        ];
        want.sort();
        assert_eq!(keys, want);
        assert_eq!(m["confidence"], 0.912);
        assert_eq!(m["length_m"], 6.0);
        assert_eq!(m["heading_deg"], 0.0);
        let l = &v["features"][1]["properties"];
        let keys: Vec<&String> = l.as_object().unwrap().keys().collect();
        assert_eq!(
            keys,
            ["class", "confidence", "id", "layer", "length_m", "marking_ids"]
        );
        let ring = v["features"][0]["geometry"]["coordinates"][0].as_array().unwrap();
        assert_eq!(ring.len(), 5);
        assert_eq!(ring[0], ring[4]);
        assert_eq!(ring[1][1], 3380006.0, "native keeps the vertex order");
    }

    #[test]
    fn unknown_crs_is_native_and_says_so() {
        let v = to_geojson(&sample(None), CrsMode::Wgs84).unwrap();
        assert_eq!(v["roadmark"]["crs"], "unknown");
        assert!(v.get("crs").is_none());
        assert_eq!(v["features"][0]["geometry"]["coordinates"][0][0][0], 231000.0);
        let back = from_geojson(&v).unwrap();
        assert_eq!(back.crs, None);
        // Small local coordinates stay native thanks to the member.
        let mut local = sample(None);
        local.markings[0].outline = vec![[1.0, 1.0], [2.0, 1.0], [2.0, 2.0]];
        local.lane_lines[0].line = vec![[0.0, 0.0], [3.0, 4.0]];
        assert_eq!(from_geojson(&to_native(&local)).unwrap().crs, None);
    }

    #[test]
    fn wkt_only_crs_round_trips_natively() {
        let crs = Crs {
            epsg: None,
            wkt: Some(crs_definitions::EPSG_32650.wkt.into()),
        };
        let v = to_geojson(&sample(Some(crs.clone())), CrsMode::Native).unwrap();
        assert_eq!(v["roadmark"]["crs"], "wkt");
        assert_eq!(from_geojson(&v).unwrap().crs, Some(crs.clone()));
        // And the WKT is enough for lon/lat output.
        let w = to_geojson(&sample(Some(crs)), CrsMode::Wgs84).unwrap();
        assert!(
            w["features"][0]["geometry"]["coordinates"][0][0][0]
                .as_f64()
                .unwrap()
                < 180.0
        );
    }

    #[test]
    fn default_mode_follows_the_contract() {
        assert_eq!(CrsMode::default_for(Some(&Crs::epsg(32650))), CrsMode::Wgs84);
        assert_eq!(CrsMode::default_for(Some(&Crs::default())), CrsMode::Native);
        assert_eq!(CrsMode::default_for(None), CrsMode::Native);
    }

    #[test]
    fn crs_names() {
        assert_eq!(parse_crs_name("EPSG:32650"), Some(32650));
        assert_eq!(parse_crs_name("urn:ogc:def:crs:EPSG::28992"), Some(28992));
        assert_eq!(parse_crs_name("urn:ogc:def:crs:EPSG:6.6:4326"), Some(4326));
        assert_eq!(parse_crs_name("urn:ogc:def:crs:OGC:1.3:CRS84"), Some(4326));
        assert_eq!(parse_crs_name("EPSG:abc"), None);
        assert_eq!(parse_crs_name("local"), None);
    }

    #[test]
    fn lonlat_without_crs_member_is_wgs84_and_measures_are_derived() {
        let text = r#"{"type":"FeatureCollection","features":[
          {"type":"Feature","geometry":{"type":"Polygon","coordinates":[[[114.0,30.0],[114.0,30.00005],
            [114.000002,30.00005],[114.000002,30.0],[114.0,30.0]]]},
           "properties":{"id":7,"layer":"marking","class":"stop_line"}},
          {"type":"Feature","geometry":{"type":"LineString","coordinates":[[114.0,30.0],[114.0,30.0001]]},
           "properties":{"id":"a","layer":"lane_line","class":"solid_line","confidence":0.5}}]}"#;
        let ex = from_geojson_str(text).unwrap();
        assert_eq!(ex.crs, Some(Crs::epsg(4326)));
        let m = &ex.markings[0];
        assert_eq!(m.id, "7");
        assert_eq!(m.outline.len(), 4, "closing vertex dropped");
        assert!((m.length_m - 5.54).abs() < 0.05, "{}", m.length_m);
        assert!((m.width_m - 0.19).abs() < 0.01, "{}", m.width_m);
        assert!(m.heading_deg < 0.5 || m.heading_deg > 179.5, "{}", m.heading_deg);
        assert_eq!(m.confidence, 1.0);
        assert!((ex.lane_lines[0].length_m - 11.09).abs() < 0.05);
    }

    fn err_of(features: &str) -> String {
        from_geojson_str(&format!(
            r#"{{"type":"FeatureCollection","features":[{features}]}}"#
        ))
        .unwrap_err()
    }

    const SQUARE: &str = r#"{"type":"Polygon","coordinates":[[[0,0],[1,0],[1,1],[0,0]]]}"#;

    /// One feature with the given geometry and properties.
    fn feature_err(geometry: &str, props: &str) -> String {
        err_of(&format!(
            r#"{{"type":"Feature","geometry":{geometry},"properties":{{{props}}}}}"#
        ))
    }

    #[test]
    fn schema_errors_are_clear() {
        let cases = [
            (
                SQUARE,
                r#""id":"a","class":"dashed_line""#,
                "missing property \"layer\"",
            ),
            (
                SQUARE,
                r#""id":"a","layer":"marking","class":"zigzag""#,
                "unknown marking class \"zigzag\"",
            ),
            (
                SQUARE,
                r#""id":"a","layer":"lane_line","class":"solid_line""#,
                "must be a LineString",
            ),
            (
                SQUARE,
                r#""id":"a","layer":"roads","class":"solid_line""#,
                "unknown layer \"roads\"",
            ),
            (
                SQUARE,
                r#""layer":"marking","class":"solid_line""#,
                "missing property \"id\"",
            ),
            (
                SQUARE,
                r#""id":"a","layer":"marking""#,
                "missing property \"class\"",
            ),
            (
                SQUARE,
                r#""id":"a","layer":"marking","class":"diamond","confidence":3"#,
                "outside 0..1",
            ),
            (
                SQUARE,
                r#""id":"a","layer":"marking","class":"diamond","point_count":-1"#,
                "point_count",
            ),
            (
                r#"{"type":"Polygon","coordinates":[[[0,0],[9,0],[9,9],[0,0]],[[1,1],[2,1],[2,2],[1,1]]]}"#,
                r#""id":"a","layer":"marking","class":"diamond""#,
                "1 holes",
            ),
            (
                r#"{"type":"Polygon","coordinates":[[[0,0],[1,0],[0,0]]]}"#,
                r#""id":"a","layer":"marking","class":"diamond""#,
                "fewer than 3",
            ),
            (
                r#"{"type":"LineString","coordinates":[[0,0],["a",1]]}"#,
                r#""id":"a","layer":"lane_line","class":"solid_line""#,
                "non-number",
            ),
            (
                "null",
                r#""id":"a","layer":"marking","class":"diamond""#,
                "missing \"geometry\"",
            ),
        ];
        for (geometry, props, want) in cases {
            let e = feature_err(geometry, props);
            assert!(e.contains("feature 0") && e.contains(want), "{want}: {e}");
        }
        let props = r#"{"id":"a","layer":"marking","class":"diamond"}"#;
        let one = format!(r#"{{"type":"Feature","geometry":{SQUARE},"properties":{props}}}"#);
        let e = err_of(&format!("{one},{one}"));
        assert!(
            e.contains("feature 1") && e.contains("duplicate marking id"),
            "{e}"
        );
        let e = from_geojson_str(r#"{"type":"Feature"}"#).unwrap_err();
        assert!(e.contains("expected a FeatureCollection"), "{e}");
        let bogus = r#"{"type":"name","properties":{"name":"bogus"}}"#;
        let e = from_geojson_str(&format!(
            r#"{{"type":"FeatureCollection","features":[],"crs":{bogus}}}"#
        ))
        .unwrap_err();
        assert!(e.contains("unsupported crs name"), "{e}");
    }

    #[test]
    fn write_and_read_files_name_the_path() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("out.geojson");
        write_geojson(&p, &sample(Some(Crs::epsg(32650))), CrsMode::Native).unwrap();
        let back = read_geojson(&p).unwrap();
        assert_eq!(back.crs, Some(Crs::epsg(32650)));
        assert_eq!(back.markings[0].outline, sample(None).markings[0].outline);
        let bad = dir.path().join("bad.geojson");
        std::fs::write(&bad, "{ nope").unwrap();
        let e = read_geojson(&bad).unwrap_err().to_string();
        assert!(e.contains("bad.geojson") && e.contains("not valid JSON"), "{e}");
        let e = read_geojson(&dir.path().join("missing.geojson"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("missing.geojson") && e.contains("cannot read"), "{e}");
    }

    #[test]
    fn non_finite_coordinates_are_refused() {
        let mut ex = sample(Some(Crs::epsg(32650)));
        ex.lane_lines[0].line[1][0] = f64::NAN;
        let e = to_geojson(&ex, CrsMode::Native).unwrap_err().to_string();
        assert!(e.contains("lane_line l1"), "{e}");
    }
}
