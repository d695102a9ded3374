//! CRS detection: the coordinate reference system of a LAS/LAZ file, reduced to an EPSG code.
//!
//! **What.** A LAS file may describe its CRS with an OGC WKT VLR (LAS 1.4, required for point
//! formats 6–10) or with GeoTIFF keys (LAS 1.0–1.3 and many 1.4 writers); it may also say
//! nothing. [`crs_from_header`] returns `None` when the file says nothing, otherwise a
//! [`Crs`] holding the WKT as found and the EPSG code when it can be derived.
//!
//! **Algorithm.**
//! - WKT (preferred when present): the text is parsed into a tree (WKT1 and WKT2 share the
//!   `KEYWORD[item, item, ...]` grammar, with `[` or `(` brackets). The code of the top-level
//!   CRS is its *own* `AUTHORITY["EPSG","NNNN"]` (WKT1) or `ID["EPSG",NNNN]` (WKT2): the last
//!   such direct child of the root node; authorities nested deeper belong to the datum,
//!   ellipsoid, units and base CRS and are ignored. A compound CRS without its own code takes
//!   the code of its horizontal component (the first CRS inside); a `BOUNDCRS` that of its
//!   source CRS. Without any authority, the CRS name is looked up: UTM names in EPSG or ESRI
//!   spelling (`WGS 84 / UTM zone 50N`, `WGS_1984_UTM_Zone_50N`, ETRS89, NAD83, NAD27) map
//!   arithmetically, any other name is matched exactly (case- and `_`-insensitively) against
//!   the EPSG names of the `crs-definitions` table.
//! - GeoTIFF keys: `ProjectedCSTypeGeoKey` (3072) when it is an EPSG code (not 32767
//!   "user-defined"); else a user-defined projection whose `ProjectionGeoKey` (3074) is a UTM
//!   zone (16001–16060 north, 16101–16160 south) on a known datum; else the citation string
//!   (`PCSCitationGeoKey`/`GTCitationGeoKey`) looked up by name; else `GeographicTypeGeoKey`
//!   (2048) for a geographic CRS.
//!
//! **Parameters.** None.
//!
//! **Reference.** ASPRS LAS 1.4 R15 §2.5 (CRS VLRs); OGC 01-009 (WKT1) and ISO 19162 (WKT2);
//! GeoTIFF 1.1 (OGC 19-008) key ids.
//!
//! **Complexity.** Linear in the WKT length. The name table is built once per process
//! (~6000 definitions, a few milliseconds) and only when a name has to be looked up.

use crate::pipeline::types::Crs;
use std::collections::HashMap;
use std::sync::OnceLock;

/// GeoTIFF "user-defined" marker value.
const USER_DEFINED: u16 = 32767;
const GEOGRAPHIC_TYPE_KEY: u16 = 2048;
const GT_CITATION_KEY: u16 = 1026;
const GEOG_CITATION_KEY: u16 = 2049;
const PROJECTED_CS_TYPE_KEY: u16 = 3072;
const PCS_CITATION_KEY: u16 = 3073;
const PROJECTION_KEY: u16 = 3074;

/// The CRS stated by a LAS header: WKT VLR first, then GeoTIFF keys; `None` when neither is
/// there (or neither can be read).
pub fn crs_from_header(header: &las::Header) -> Option<Crs> {
    if let Some(bytes) = header.get_wkt_crs_bytes() {
        // The WKT VLR is a null-terminated string; some writers pad with several NULs.
        let text = String::from_utf8_lossy(bytes);
        let wkt = text.trim_end_matches('\0').trim();
        if !wkt.is_empty() {
            return Some(Crs {
                epsg: epsg_from_wkt(wkt),
                wkt: Some(wkt.to_string()),
            });
        }
    }
    // A malformed GeoTIFF VLR is treated like a missing CRS: the points are still usable.
    let geotiff = header.get_geotiff_crs().ok().flatten()?;
    epsg_from_geotiff(&geotiff).map(Crs::epsg)
}

fn geotiff_u16(crs: &las::crs::GeoTiffCrs, key: u16) -> Option<u16> {
    crs.entries
        .iter()
        .find(|e| e.id == key)
        .and_then(|e| match e.data {
            las::crs::GeoTiffData::U16(v) => Some(v),
            _ => None,
        })
}

fn geotiff_string(crs: &las::crs::GeoTiffCrs, key: u16) -> Option<&str> {
    crs.entries
        .iter()
        .find(|e| e.id == key)
        .and_then(|e| match &e.data {
            las::crs::GeoTiffData::String(s) => Some(s.trim_end_matches(['|', '\0']).trim()),
            _ => None,
        })
}

/// EPSG code from GeoTIFF keys (see the module docs for the order of the rules).
pub fn epsg_from_geotiff(crs: &las::crs::GeoTiffCrs) -> Option<u32> {
    if let Some(code) = geotiff_u16(crs, PROJECTED_CS_TYPE_KEY).filter(|&c| c != 0 && c != USER_DEFINED) {
        return Some(u32::from(code));
    }
    let geographic = geotiff_u16(crs, GEOGRAPHIC_TYPE_KEY).filter(|&c| c != 0 && c != USER_DEFINED);
    if let Some(projection) = geotiff_u16(crs, PROJECTION_KEY) {
        // EPSG projection (conversion) codes 16001..16060 are "UTM zone 1N".."60N",
        // 16101..16160 "UTM zone 1S".."60S".
        let zone_north = match projection {
            16001..=16060 => Some((u32::from(projection - 16000), true)),
            16101..=16160 => Some((u32::from(projection - 16100), false)),
            _ => None,
        };
        if let Some((zone, north)) = zone_north {
            let datum = match geographic {
                Some(4326) | None => Datum::Wgs84,
                Some(4258) => Datum::Etrs89,
                Some(4269) => Datum::Nad83,
                Some(4267) => Datum::Nad27,
                Some(_) => Datum::Other,
            };
            if let Some(code) = utm_code(datum, zone, north) {
                return Some(code);
            }
        }
    }
    for key in [PCS_CITATION_KEY, GT_CITATION_KEY] {
        if let Some(code) = geotiff_string(crs, key).and_then(epsg_from_name) {
            return Some(code);
        }
    }
    if let Some(code) = geographic {
        return Some(u32::from(code));
    }
    geotiff_string(crs, GEOG_CITATION_KEY).and_then(epsg_from_name)
}

/// One element of a WKT list: a nested node, a quoted string or a bare word/number.
#[derive(Debug)]
enum Item {
    Node(Node),
    Text(String),
    Word(String),
}

#[derive(Debug)]
struct Node {
    keyword: String,
    items: Vec<Item>,
}

/// Deepest nesting accepted; real CRS WKT stays below 10.
const MAX_DEPTH: usize = 64;

/// Parse WKT into its root node; `None` when the text is not well-formed WKT.
fn parse_wkt(text: &str) -> Option<Node> {
    let bytes = text.as_bytes();
    let mut pos = 0;
    let root = parse_node(bytes, &mut pos, 0)?;
    Some(root)
}

fn skip_ws(b: &[u8], pos: &mut usize) {
    while *pos < b.len() && b[*pos].is_ascii_whitespace() {
        *pos += 1;
    }
}

fn parse_word(b: &[u8], pos: &mut usize) -> Option<String> {
    let start = *pos;
    while *pos < b.len() && !matches!(b[*pos], b'[' | b']' | b'(' | b')' | b',' | b'"') {
        *pos += 1;
    }
    let w = std::str::from_utf8(&b[start..*pos]).ok()?.trim();
    (!w.is_empty()).then(|| w.to_string())
}

fn parse_node(b: &[u8], pos: &mut usize, depth: usize) -> Option<Node> {
    if depth > MAX_DEPTH {
        return None;
    }
    skip_ws(b, pos);
    let keyword = parse_word(b, pos)?;
    skip_ws(b, pos);
    let close = match b.get(*pos)? {
        b'[' => b']',
        b'(' => b')',
        _ => return None,
    };
    *pos += 1;
    let mut items = Vec::new();
    loop {
        skip_ws(b, pos);
        match *b.get(*pos)? {
            c if c == close => {
                *pos += 1;
                return Some(Node { keyword, items });
            }
            b',' => *pos += 1,
            b'"' => {
                // Quoted string; a doubled quote is an escaped quote.
                *pos += 1;
                let mut s = Vec::new();
                loop {
                    match *b.get(*pos)? {
                        b'"' if b.get(*pos + 1) == Some(&b'"') => {
                            s.push(b'"');
                            *pos += 2;
                        }
                        b'"' => {
                            *pos += 1;
                            break;
                        }
                        c => {
                            s.push(c);
                            *pos += 1;
                        }
                    }
                }
                items.push(Item::Text(String::from_utf8_lossy(&s).into_owned()));
            }
            _ => {
                let save = *pos;
                let word = parse_word(b, pos)?;
                skip_ws(b, pos);
                if matches!(b.get(*pos), Some(b'[') | Some(b'(')) {
                    *pos = save;
                    items.push(Item::Node(parse_node(b, pos, depth + 1)?));
                } else {
                    items.push(Item::Word(word));
                }
            }
        }
    }
}

const CRS_KEYWORDS: [&str; 14] = [
    "PROJCS",
    "GEOGCS",
    "GEOCCS",
    "COMPD_CS",
    "PROJCRS",
    "PROJECTEDCRS",
    "GEOGCRS",
    "GEOGRAPHICCRS",
    "GEODCRS",
    "GEODETICCRS",
    "COMPOUNDCRS",
    "BOUNDCRS",
    "VERT_CS",
    "VERTCRS",
];

fn is_crs(node: &Node) -> bool {
    CRS_KEYWORDS.iter().any(|k| node.keyword.eq_ignore_ascii_case(k))
}

fn own_epsg(node: &Node) -> Option<u32> {
    node.items.iter().rev().find_map(|item| match item {
        Item::Node(n)
            if n.keyword.eq_ignore_ascii_case("AUTHORITY") || n.keyword.eq_ignore_ascii_case("ID") =>
        {
            let authority = match n.items.first()? {
                Item::Text(s) | Item::Word(s) => s,
                Item::Node(_) => return None,
            };
            if !authority.eq_ignore_ascii_case("EPSG") {
                return None;
            }
            match n.items.get(1)? {
                Item::Text(s) | Item::Word(s) => s.trim().parse::<u32>().ok(),
                Item::Node(_) => None,
            }
        }
        _ => None,
    })
}

fn node_name(node: &Node) -> Option<&str> {
    match node.items.first()? {
        Item::Text(s) => Some(s),
        _ => None,
    }
}

fn epsg_of_node(node: &Node) -> Option<u32> {
    if let Some(code) = own_epsg(node) {
        return Some(code);
    }
    let kw = node.keyword.to_ascii_uppercase();
    match kw.as_str() {
        "COMPD_CS" | "COMPOUNDCRS" => node
            .items
            .iter()
            .find_map(|i| match i {
                Item::Node(n) if is_crs(n) => Some(n),
                _ => None,
            })
            .and_then(epsg_of_node),
        "BOUNDCRS" => node
            .items
            .iter()
            .find_map(|i| match i {
                Item::Node(n) if n.keyword.eq_ignore_ascii_case("SOURCECRS") => Some(n),
                _ => None,
            })
            .and_then(|src| {
                src.items.iter().find_map(|i| match i {
                    Item::Node(n) if is_crs(n) => epsg_of_node(n),
                    _ => None,
                })
            }),
        _ if is_crs(node) => node_name(node).and_then(epsg_from_name),
        _ => None,
    }
}

/// EPSG code of the top-level CRS of an OGC WKT string (WKT1 or WKT2), when derivable.
pub fn epsg_from_wkt(wkt: &str) -> Option<u32> {
    let root = parse_wkt(wkt.trim_matches(|c: char| c == '\0' || c.is_whitespace()))?;
    epsg_of_node(&root)
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Datum {
    Wgs84,
    Etrs89,
    Nad83,
    Nad27,
    Other,
}

fn utm_code(datum: Datum, zone: u32, north: bool) -> Option<u32> {
    match (datum, north) {
        (Datum::Wgs84, true) if (1..=60).contains(&zone) => Some(32600 + zone),
        (Datum::Wgs84, false) if (1..=60).contains(&zone) => Some(32700 + zone),
        (Datum::Etrs89, true) if (28..=38).contains(&zone) => Some(25800 + zone),
        (Datum::Nad83, true) if (1..=23).contains(&zone) => Some(26900 + zone),
        (Datum::Nad27, true) if (1..=22).contains(&zone) => Some(26700 + zone),
        _ => None,
    }
}

/// Lower case, `_` as space, single spaces.
fn normalise_name(name: &str) -> String {
    name.to_lowercase()
        .replace('_', " ")
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
}

/// `utm zone 50n` anywhere in a normalised name → (50, north).
fn parse_utm_zone(norm: &str) -> Option<(u32, bool)> {
    let at = norm.find("utm zone ")? + "utm zone ".len();
    let rest = &norm[at..];
    let digits: String = rest.chars().take_while(|c| c.is_ascii_digit()).collect();
    let zone = digits.parse::<u32>().ok()?;
    match rest[digits.len()..].chars().next()? {
        'n' => Some((zone, true)),
        's' => Some((zone, false)),
        _ => None,
    }
}

/// EPSG code of a CRS given by name: UTM names arithmetically, others through the EPSG name
/// table of `crs-definitions`.
pub fn epsg_from_name(name: &str) -> Option<u32> {
    let norm = normalise_name(name);
    if let Some((zone, north)) = parse_utm_zone(&norm) {
        // The datum is whatever precedes "utm zone"; only the plain datums map
        // arithmetically ("nad83(2011)" and the like have their own codes: name table).
        let prefix = norm[..norm.find("utm zone").unwrap_or(0)].trim_end_matches([' ', '/']);
        let datum = match prefix {
            "wgs 84" | "wgs 1984" | "wgs84" => Datum::Wgs84,
            "etrs89" | "etrs 1989" => Datum::Etrs89,
            "nad83" | "nad 1983" => Datum::Nad83,
            "nad27" | "nad 1927" => Datum::Nad27,
            _ => Datum::Other,
        };
        if let Some(code) = utm_code(datum, zone, north) {
            return Some(code);
        }
    }
    name_table().get(&norm).copied()
}

/// Normalised EPSG name → code, from the `crs-definitions` table (first code wins).
fn name_table() -> &'static HashMap<String, u32> {
    static TABLE: OnceLock<HashMap<String, u32>> = OnceLock::new();
    TABLE.get_or_init(|| {
        let mut table = HashMap::new();
        for code in 1024..=u16::MAX {
            let Some(def) = crs_definitions::from_code(code) else {
                continue;
            };
            // Every definition starts `KEYWORD["name",...`.
            let Some(start) = def.wkt.find('"') else {
                continue;
            };
            let Some(len) = def.wkt[start + 1..].find('"') else {
                continue;
            };
            let name = normalise_name(&def.wkt[start + 1..start + 1 + len]);
            table.entry(name).or_insert(u32::from(code));
        }
        table
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const UTM50_WKT1: &str = r#"PROJCS["WGS 84 / UTM zone 50N",GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563,AUTHORITY["EPSG","7030"]],AUTHORITY["EPSG","6326"]],PRIMEM["Greenwich",0,AUTHORITY["EPSG","8901"]],UNIT["degree",0.0174532925199433,AUTHORITY["EPSG","9122"]],AUTHORITY["EPSG","4326"]],PROJECTION["Transverse_Mercator"],PARAMETER["latitude_of_origin",0],PARAMETER["central_meridian",117],PARAMETER["scale_factor",0.9996],PARAMETER["false_easting",500000],PARAMETER["false_northing",0],UNIT["metre",1,AUTHORITY["EPSG","9001"]],AXIS["Easting",EAST],AXIS["Northing",NORTH],AUTHORITY["EPSG","32650"]]"#;

    #[test]
    fn wkt1_takes_the_top_level_authority_not_the_nested_ones() {
        assert_eq!(epsg_from_wkt(UTM50_WKT1), Some(32650));
        // NUL-terminated as stored in the VLR.
        assert_eq!(epsg_from_wkt(&format!("{UTM50_WKT1}\0\0")), Some(32650));
    }

    #[test]
    fn wkt2_id_and_compound_crs() {
        let wkt2 = r#"PROJCRS["ETRS89 / UTM zone 32N",BASEGEOGCRS["ETRS89",DATUM["European Terrestrial Reference System 1989",ELLIPSOID["GRS 1980",6378137,298.257222101,LENGTHUNIT["metre",1]]],ID["EPSG",4258]],CONVERSION["UTM zone 32N",METHOD["Transverse Mercator",ID["EPSG",9807]]],CS[Cartesian,2],ID["EPSG",25832]]"#;
        assert_eq!(epsg_from_wkt(wkt2), Some(25832));
        let compound = format!(
            r#"COMPD_CS["WGS 84 / UTM zone 50N + EGM96 height",{UTM50_WKT1},VERT_CS["EGM96 height",VERT_DATUM["EGM96 geoid",2005,AUTHORITY["EPSG","5171"]],AUTHORITY["EPSG","5773"]]]"#
        );
        assert_eq!(epsg_from_wkt(&compound), Some(32650));
    }

    #[test]
    fn names_without_authority() {
        let no_auth = r#"PROJCS["WGS 84 / UTM zone 50N",GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]]],PROJECTION["Transverse_Mercator"],UNIT["metre",1]]"#;
        assert_eq!(epsg_from_wkt(no_auth), Some(32650));
        assert_eq!(epsg_from_name("WGS_1984_UTM_Zone_33S"), Some(32733));
        assert_eq!(epsg_from_name("ETRS89 / UTM zone 32N"), Some(25832));
        assert_eq!(epsg_from_name("NAD83 / UTM zone 17N"), Some(26917));
        assert_eq!(epsg_from_name("Amersfoort / RD New"), Some(28992));
        assert_eq!(
            epsg_from_name("CGCS2000 / 3-degree Gauss-Kruger CM 117E"),
            Some(4548)
        );
        assert_eq!(epsg_from_name("my local grid"), None);
    }

    #[test]
    fn malformed_wkt_is_none_never_a_panic() {
        for s in [
            "",
            "PROJCS",
            "PROJCS[",
            "PROJCS[\"unterminated",
            "[[[[",
            "]]",
            "PROJCS[\"x\",AUTHORITY[\"EPSG\",\"notanumber\"]]",
            &"A[".repeat(200),
        ] {
            let _ = epsg_from_wkt(s);
        }
        assert_eq!(epsg_from_wkt("PROJCS[\"x\",AUTHORITY[\"EPSG\",\"abc\"]]"), None);
    }
}
