//! Reprojection between the input CRS and WGS84 longitude/latitude.
//!
//! **What.** A [`Reprojector`] converts coordinates of one projected (or geographic) CRS to
//! WGS84 longitude/latitude in degrees and back; [`reproject_extraction`] moves a whole
//! [`Extraction`] from one CRS to another (through WGS84).
//!
//! **Algorithm.** The CRS is resolved to a PROJ.4 definition: from the EPSG table of the
//! `crs-definitions` crate when the EPSG code is known and listed, otherwise from the OGC WKT
//! (`proj4wkt` converts WKT1/WKT2 to a PROJ string). The pure-Rust `proj4rs` then runs the
//! inverse projection, the datum shift (`+towgs84` Helmert parameters when the definition has
//! them) and the forward projection. `proj4rs` works in radians for geographic CRSs; this
//! module converts to and from degrees at its boundary so callers only ever see degrees.
//!
//! **Parameters.** None beyond the CRS. Datum shifts are the 3/7-parameter Helmert
//! transformations of the definitions; grid shifts (NTv2, RDNAPTRANS) are not available,
//! which for EPSG:28992 means agreement with PROJ's Helmert path (≈ 1 m absolute accuracy of
//! the datum shift itself, but exactly reversible).
//!
//! **Reference.** PROJ (<https://proj.org>), proj4rs (<https://github.com/3liz/proj4rs>);
//! the test values were computed independently with pyproj 3.7 / PROJ 9.5.
//!
//! **Complexity.** O(1) per point, ≈ 1 M points/s on one core.

use super::types::{Crs, Extraction};
use proj4rs::Proj;
use proj4rs::transform::transform;

/// EPSG code of WGS84 longitude/latitude.
pub const EPSG_WGS84: u32 = 4326;

/// Converts coordinates of one CRS to WGS84 lon/lat (degrees) and back.
pub struct Reprojector {
    src: Proj,
    wgs84: Proj,
    geographic: bool,
    label: String,
}

impl std::fmt::Debug for Reprojector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Reprojector").field("crs", &self.label).finish()
    }
}

/// A readable name for a CRS in messages: `EPSG:NNNN`, `WKT "name"` or `unknown`.
pub fn crs_label(crs: Option<&Crs>) -> String {
    match crs {
        Some(Crs { epsg: Some(code), .. }) => format!("EPSG:{code}"),
        Some(Crs { wkt: Some(w), .. }) => {
            // The name is the first quoted string of the WKT.
            let name = w.split('"').nth(1).unwrap_or("?");
            format!("WKT \"{name}\"")
        }
        _ => "unknown".to_string(),
    }
}

/// The PROJ.4 definition of a CRS: EPSG table first, then the WKT.
fn proj_string(crs: &Crs) -> Result<String, String> {
    let mut why = Vec::new();
    if let Some(code) = crs.epsg {
        match u16::try_from(code).ok().and_then(crs_definitions::from_code) {
            Some(def) => return Ok(def.proj4.to_string()),
            None => why.push(format!("EPSG:{code} is not in the EPSG table")),
        }
    }
    if let Some(wkt) = &crs.wkt {
        match proj4wkt::wkt_to_projstring(wkt) {
            Ok(s) => return Ok(s),
            Err(e) => why.push(format!("its WKT cannot be converted ({e})")),
        }
    }
    if why.is_empty() {
        why.push("it has neither an EPSG code nor a WKT".into());
    }
    Err(format!("cannot reproject from {}: {}", crs_label(Some(crs)), why.join("; ")))
}

impl Reprojector {
    /// A reprojector for `crs` (EPSG code from the table, else its WKT).
    pub fn new(crs: &Crs) -> Result<Self, String> {
        let def = proj_string(crs)?;
        let label = crs_label(Some(crs));
        let src = Proj::from_proj_string(&def)
            .map_err(|e| format!("cannot reproject from {label}: bad definition \"{def}\" ({e})"))?;
        let wgs84 = Proj::from_proj_string("+proj=longlat +datum=WGS84 +no_defs")
            .map_err(|e| format!("cannot build the WGS84 definition ({e})"))?;
        let geographic = src.is_latlong();
        Ok(Self {
            src,
            wgs84,
            geographic,
            label,
        })
    }

    /// A reprojector for an EPSG code.
    pub fn from_epsg(code: u32) -> Result<Self, String> {
        Self::new(&Crs::epsg(code))
    }

    /// True when the CRS itself is geographic (coordinates are lon/lat degrees).
    pub fn is_geographic(&self) -> bool {
        self.geographic
    }

    /// `EPSG:NNNN`, `WKT "name"`.
    pub fn label(&self) -> &str {
        &self.label
    }

    /// (x, y) in the CRS → (longitude, latitude) in degrees.
    pub fn to_wgs84(&self, x: f64, y: f64) -> Result<(f64, f64), String> {
        // proj4rs takes geographic input in radians.
        let mut p = if self.geographic {
            (x.to_radians(), y.to_radians(), 0.0)
        } else {
            (x, y, 0.0)
        };
        transform(&self.src, &self.wgs84, &mut p)
            .map_err(|e| format!("cannot reproject ({x}, {y}) from {} to WGS84: {e}", self.label))?;
        let out = (p.0.to_degrees(), p.1.to_degrees());
        if out.0.is_finite() && out.1.is_finite() {
            Ok(out)
        } else {
            Err(format!("({x}, {y}) in {} has no WGS84 position", self.label))
        }
    }

    /// (longitude, latitude) in degrees → (x, y) in the CRS.
    pub fn from_wgs84(&self, lon: f64, lat: f64) -> Result<(f64, f64), String> {
        let mut p = (lon.to_radians(), lat.to_radians(), 0.0);
        transform(&self.wgs84, &self.src, &mut p)
            .map_err(|e| format!("cannot reproject lon/lat ({lon}, {lat}) to {}: {e}", self.label))?;
        let out = if self.geographic {
            (p.0.to_degrees(), p.1.to_degrees())
        } else {
            (p.0, p.1)
        };
        if out.0.is_finite() && out.1.is_finite() {
            Ok(out)
        } else {
            Err(format!("lon/lat ({lon}, {lat}) has no position in {}", self.label))
        }
    }
}

/// EPSG code of the WGS84 UTM zone holding (lon, lat): 326zz north, 327zz south.
pub fn utm_epsg_for(lon: f64, lat: f64) -> u32 {
    let zone = (((lon + 180.0) / 6.0).floor() as i64).rem_euclid(60) as u32 + 1;
    if lat >= 0.0 { 32600 + zone } else { 32700 + zone }
}

/// Apply `f` to every vertex of an extraction (marking outlines and lane lines).
pub fn map_coords(
    ex: &Extraction,
    mut f: impl FnMut(f64, f64) -> Result<(f64, f64), String>,
) -> Result<Extraction, String> {
    let mut out = ex.clone();
    for m in &mut out.markings {
        for p in &mut m.outline {
            let (x, y) = f(p[0], p[1])?;
            *p = [x, y];
        }
    }
    for l in &mut out.lane_lines {
        for p in &mut l.line {
            let (x, y) = f(p[0], p[1])?;
            *p = [x, y];
        }
    }
    Ok(out)
}

/// The extraction with its coordinates moved from `ex.crs` to `to` (through WGS84).
///
/// Properties (lengths, headings) are kept as they are: they are metric values of the
/// painted objects, not of the coordinates. Errors when `ex.crs` is unknown.
pub fn reproject_extraction(ex: &Extraction, to: &Crs) -> Result<Extraction, String> {
    let from = ex
        .crs
        .as_ref()
        .ok_or_else(|| format!("cannot reproject to {}: the source CRS is unknown", crs_label(Some(to))))?;
    if from == to || (from.epsg.is_some() && from.epsg == to.epsg) {
        return Ok(ex.clone());
    }
    let src = Reprojector::new(from)?;
    let dst = Reprojector::new(to)?;
    let mut out = map_coords(ex, |x, y| {
        let (lon, lat) = src.to_wgs84(x, y)?;
        dst.from_wgs84(lon, lat)
    })?;
    out.crs = Some(to.clone());
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Expected values from pyproj 3.7.2 / PROJ 9.5.1:
    /// `Transformer.from_crs("EPSG:32650", "EPSG:4326", always_xy=True)`.
    const UTM50N: [(f64, f64, f64, f64); 3] = [
        (231000.0, 3380000.0, 114.1966714842, 30.5222406683),
        (231234.567, 3380123.456, 114.1990815819, 30.5234059400),
        (500000.0, 0.0, 117.0, 0.0),
    ];

    /// Metres per degree, to express angular errors as distances.
    fn metres(dlon: f64, dlat: f64, lat: f64) -> f64 {
        let m = 111_320.0;
        (dlon * m * lat.to_radians().cos()).hypot(dlat * m)
    }

    #[test]
    fn utm_50n_matches_pyproj_to_the_centimetre() {
        let r = Reprojector::from_epsg(32650).unwrap();
        assert!(!r.is_geographic());
        for (x, y, lon, lat) in UTM50N {
            let (l, b) = r.to_wgs84(x, y).unwrap();
            // The reference has 10 decimals (1e-10 deg ≈ 0.01 mm): 1 cm is the bar, the
            // agreement is far better.
            let err = metres(l - lon, b - lat, lat);
            assert!(err < 0.01, "({x}, {y}) -> ({l}, {b}), off by {err} m");
            assert!(err < 1e-4, "({x}, {y}) off by {err} m");
        }
    }

    #[test]
    fn rd_new_matches_pyproj_helmert_path() {
        // pyproj with the same Helmert definition as the EPSG table
        // (+towgs84=565.2369,50.0087,465.658,-0.406857,0.350733,-1.87035,4.0812).
        let r = Reprojector::from_epsg(28992).unwrap();
        for (x, y, lon, lat) in [
            (121000.0, 487000.0, 4.8879708319, 52.3698262114),
            (155000.0, 463000.0, 5.3872035806, 52.1551723026),
        ] {
            let (l, b) = r.to_wgs84(x, y).unwrap();
            let err = metres(l - lon, b - lat, lat);
            assert!(err < 0.01, "({x}, {y}) -> ({l}, {b}), off by {err} m");
        }
    }

    #[test]
    fn round_trips_below_a_millimetre() {
        for (code, x, y) in [(32650, 231234.567, 3380123.456), (28992, 121456.789, 487654.321)] {
            let r = Reprojector::from_epsg(code).unwrap();
            let (lon, lat) = r.to_wgs84(x, y).unwrap();
            let (x2, y2) = r.from_wgs84(lon, lat).unwrap();
            assert!((x2 - x).hypot(y2 - y) < 1e-3, "EPSG:{code}: ({x2}, {y2})");
        }
    }

    #[test]
    fn wkt_only_crs_works_like_its_epsg_code() {
        let wkt = crs_definitions::EPSG_32650.wkt.to_string();
        let r = Reprojector::new(&Crs {
            epsg: None,
            wkt: Some(wkt),
        })
        .unwrap();
        let (lon, lat) = r.to_wgs84(UTM50N[0].0, UTM50N[0].1).unwrap();
        assert!(metres(lon - UTM50N[0].2, lat - UTM50N[0].3, lat) < 0.01);
        assert_eq!(r.label(), "WKT \"WGS 84 / UTM zone 50N\"");
    }

    #[test]
    fn geographic_crs_passes_degrees_through() {
        let r = Reprojector::from_epsg(EPSG_WGS84).unwrap();
        assert!(r.is_geographic());
        let (lon, lat) = r.to_wgs84(114.2, 30.5).unwrap();
        assert!((lon - 114.2).abs() < 1e-12 && (lat - 30.5).abs() < 1e-12);
        let (lon, lat) = r.from_wgs84(-3.5, 40.25).unwrap();
        assert!((lon + 3.5).abs() < 1e-12 && (lat - 40.25).abs() < 1e-12);
    }

    #[test]
    fn unusable_crs_is_a_clear_error() {
        let e = Reprojector::new(&Crs::default()).unwrap_err();
        assert!(e.contains("neither an EPSG code nor a WKT"), "{e}");
        let e = Reprojector::from_epsg(99999).unwrap_err();
        assert!(e.contains("EPSG:99999"), "{e}");
        let e = Reprojector::new(&Crs {
            epsg: None,
            wkt: Some("NOT WKT".into()),
        })
        .unwrap_err();
        assert!(e.contains("WKT"), "{e}");
    }

    #[test]
    fn utm_zone_lookup() {
        assert_eq!(utm_epsg_for(114.2, 30.5), 32650);
        assert_eq!(utm_epsg_for(4.9, 52.4), 32631);
        assert_eq!(utm_epsg_for(-70.6, -33.4), 32719);
        assert_eq!(utm_epsg_for(180.0, 0.0), 32601);
    }

    #[test]
    fn extraction_moves_between_projected_crs() {
        use crate::pipeline::types::{LaneLine, LaneLineClass};
        let ex = Extraction {
            markings: vec![],
            lane_lines: vec![LaneLine {
                id: "l1".into(),
                class: LaneLineClass::SolidLine,
                line: vec![[231000.0, 3380000.0], [231010.0, 3380000.0]],
                confidence: 1.0,
                length_m: 10.0,
                marking_ids: vec![],
            }],
            crs: Some(Crs::epsg(32650)),
        };
        let ll = reproject_extraction(&ex, &Crs::epsg(EPSG_WGS84)).unwrap();
        let p = ll.lane_lines[0].line[0];
        assert!((p[0] - UTM50N[0].2).abs() < 1e-8 && (p[1] - UTM50N[0].3).abs() < 1e-8);
        let back = reproject_extraction(&ll, &Crs::epsg(32650)).unwrap();
        for (a, b) in back.lane_lines[0].line.iter().zip(&ex.lane_lines[0].line) {
            assert!((a[0] - b[0]).hypot(a[1] - b[1]) < 1e-3);
        }
        let e = reproject_extraction(&Extraction::default(), &Crs::epsg(4326)).unwrap_err();
        assert!(e.contains("unknown"), "{e}");
    }
}
