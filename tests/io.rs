//! Readers of point clouds and trajectories: every point format, LAZ, CRS, tiles, streaming,
//! every broken-input error, fuzzed bytes, and the real sample surveys in `../shared`.

use las::point::Format;
use las::{Builder, Point, Transform, Vector, Version, Vlr};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use roadmark::pipeline::PointCloud;
use roadmark::pipeline::io::{
    FileKind, PointReader, ReadOptions, ScannerSource, inspect_points, inspect_trajectory, read_points,
    read_points_with, read_trajectory, sniff, sniff_file,
};
use std::path::{Path, PathBuf};

const UTM50_WKT: &str = r#"PROJCS["WGS 84 / UTM zone 50N",GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563,AUTHORITY["EPSG","7030"]],AUTHORITY["EPSG","6326"]],PRIMEM["Greenwich",0,AUTHORITY["EPSG","8901"]],UNIT["degree",0.0174532925199433,AUTHORITY["EPSG","9122"]],AUTHORITY["EPSG","4326"]],PROJECTION["Transverse_Mercator"],PARAMETER["latitude_of_origin",0],PARAMETER["central_meridian",117],PARAMETER["scale_factor",0.9996],PARAMETER["false_easting",500000],PARAMETER["false_northing",0],UNIT["metre",1,AUTHORITY["EPSG","9001"]],AUTHORITY["EPSG","32650"]]"#;

fn shared() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/real")
}

/// How a test file is written.
struct Spec {
    version: (u8, u8),
    format: u8,
    wkt: Option<&'static str>,
    geotiff_epsg: Option<u16>,
}

impl Spec {
    fn new(version: (u8, u8), format: u8) -> Self {
        Spec {
            version,
            format,
            wkt: None,
            geotiff_epsg: None,
        }
    }
}

/// Point `i` of the synthetic test drive: UTM-like coordinates on a 1 mm grid.
fn test_point(i: usize, format: &Format) -> Point {
    let fi = i as f64;
    Point {
        x: 231_456.789 + fi * 0.137,
        y: 3_380_123.456 + fi * 0.071,
        z: 12.345 + fi * 0.002 + (i % 7) as f64 * 0.001,
        intensity: ((i * 997) % 65_000 + 1) as u16,
        return_number: 1,
        number_of_returns: 1,
        user_data: if i.is_multiple_of(2) { 3 } else { 7 },
        point_source_id: 12,
        scanner_channel: if format.is_extended { (i % 2) as u8 } else { 0 },
        gps_time: format.has_gps_time.then_some(400_000.0 + fi * 1e-5),
        color: format.has_color.then_some(las::Color {
            red: 1,
            green: 2,
            blue: 3,
        }),
        nir: format.has_nir.then_some(4),
        waveform: format.has_waveform.then(Default::default),
        ..Default::default()
    }
}

fn write_points(path: &Path, spec: &Spec, points: &[Point]) {
    let mut b = Builder::default();
    b.version = Version::new(spec.version.0, spec.version.1);
    b.point_format = Format::new(spec.format).unwrap();
    b.transforms = Vector {
        x: Transform {
            scale: 0.001,
            offset: 231_000.0,
        },
        y: Transform {
            scale: 0.001,
            offset: 3_380_000.0,
        },
        z: Transform {
            scale: 0.001,
            offset: 0.0,
        },
    };
    if let Some(code) = spec.geotiff_epsg {
        // GeoKeyDirectory: version 1.1.0, 1 key: ProjectedCSTypeGeoKey (3072) = code.
        let keys: [u16; 8] = [1, 1, 0, 1, 3072, 0, 1, code];
        b.vlrs.push(Vlr {
            user_id: "LASF_Projection".into(),
            record_id: 34735,
            description: String::new(),
            data: keys.iter().flat_map(|k| k.to_le_bytes()).collect(),
        });
    }
    let mut header = b.into_header().unwrap();
    if let Some(wkt) = spec.wkt {
        header.set_wkt_crs(wkt.as_bytes().to_vec()).unwrap();
    }
    let mut w = las::Writer::from_path(path, header).unwrap();
    for p in points {
        w.write_point(p.clone()).unwrap();
    }
    w.close().unwrap();
}

fn write_drive(path: &Path, spec: &Spec, n: usize) -> Vec<Point> {
    let format = Format::new(spec.format).unwrap();
    let pts: Vec<Point> = (0..n).map(|i| test_point(i, &format)).collect();
    write_points(path, spec, &pts);
    pts
}

fn lowest_version(format: u8) -> (u8, u8) {
    match format {
        0 | 1 => (1, 0),
        2 | 3 => (1, 2),
        4 | 5 => (1, 3),
        _ => (1, 4),
    }
}

fn input_error(r: Result<impl std::fmt::Debug, roadmark::pipeline::PipelineError>) -> String {
    match r {
        Err(e @ roadmark::pipeline::PipelineError::Input { .. }) => e.to_string(),
        other => panic!("expected an input error, got {other:?}"),
    }
}

fn assert_same_points(cloud: &PointCloud, pts: &[Point], format: &Format, what: &str) {
    assert_eq!(cloud.len(), pts.len(), "{what}");
    for (i, p) in pts.iter().enumerate() {
        let got = [
            cloud.x[i] + cloud.origin[0],
            cloud.y[i] + cloud.origin[1],
            cloud.z[i] + cloud.origin[2],
        ];
        for (g, e) in got.iter().zip([p.x, p.y, p.z]) {
            assert!((g - e).abs() < 5e-4, "{what}: point {i} coordinate {g} vs {e}");
        }
        assert_eq!(
            cloud.intensity[i],
            f32::from(p.intensity),
            "{what}: intensity {i}"
        );
    }
    match (&cloud.gps_time, format.has_gps_time) {
        (Some(t), true) => {
            for (i, p) in pts.iter().enumerate() {
                assert_eq!(Some(t[i]), p.gps_time, "{what}: gps {i}");
            }
        }
        (None, false) => {}
        (t, has) => panic!(
            "{what}: gps_time {:?} but format has gps: {has}",
            t.as_ref().map(|t| t.len())
        ),
    }
    // Two heads told apart: the scanner channel (6–10) or user_data 3/7 (0–5).
    for (i, s) in cloud.scanner.iter().enumerate() {
        assert_eq!(*s, (i % 2) as u8, "{what}: scanner {i}");
    }
}

#[test]
fn every_point_format_and_version_round_trips_las_and_laz() {
    let dir = tempfile::tempdir().unwrap();
    for format_id in 0..=10u8 {
        let format = Format::new(format_id).unwrap();
        let mut versions = vec![lowest_version(format_id)];
        if versions[0] != (1, 4) {
            versions.push((1, 4));
        }
        for version in versions {
            for ext in ["las", "laz"] {
                let what = format!("format {format_id} LAS {}.{} {ext}", version.0, version.1);
                let path = dir
                    .path()
                    .join(format!("f{format_id}_{}{}.{ext}", version.0, version.1));
                let pts = write_drive(&path, &Spec::new(version, format_id), 300);
                let s = inspect_points(&path).unwrap_or_else(|e| panic!("{what}: {e}"));
                assert_eq!(s.point_count, 300, "{what}");
                assert_eq!(s.point_format, format_id, "{what}");
                assert_eq!(s.compressed, ext == "laz", "{what}");
                assert_eq!(s.has_gps_time, format.has_gps_time, "{what}");
                assert_eq!(s.version, format!("{}.{}", version.0, version.1), "{what}");
                assert!(s.crs.is_none(), "{what}");
                let cloud = read_points(&[&path]).unwrap_or_else(|e| panic!("{what}: {e}"));
                assert_same_points(&cloud, &pts, &format, &what);
                assert_eq!(cloud.origin, [231_456.0, 3_380_123.0, 12.0], "{what}: origin");
                let kind = sniff_file(&path).unwrap();
                assert_eq!(
                    kind,
                    if ext == "laz" {
                        FileKind::Laz
                    } else {
                        FileKind::Las
                    },
                    "{what}"
                );
                let r = PointReader::open(&path).unwrap();
                let expected = if format.is_extended {
                    ScannerSource::Channel
                } else {
                    ScannerSource::UserData
                };
                assert_eq!(r.scanner_source(), expected, "{what}");
            }
        }
    }
}

#[test]
fn streaming_in_any_chunk_size_gives_the_same_points() {
    let dir = tempfile::tempdir().unwrap();
    for ext in ["las", "laz"] {
        let path = dir.path().join(format!("s.{ext}"));
        let pts = write_drive(&path, &Spec::new((1, 4), 6), 70_001);
        let all = read_points(&[&path]).unwrap();
        let format = Format::new(6).unwrap();
        assert_same_points(&all, &pts, &format, ext);
        for chunk in [1usize, 999, 65_536, 100_000] {
            let mut r = PointReader::open(&path).unwrap();
            let mut buf = PointCloud::default();
            let mut seen = 0;
            loop {
                let n = r.next_chunk(&mut buf, chunk).unwrap();
                if n == 0 {
                    break;
                }
                assert!(n <= chunk && buf.len() == n);
                assert_eq!(buf.origin, all.origin);
                for k in (0..n).step_by(97) {
                    assert_eq!(buf.x[k], all.x[seen + k], "{ext} chunk {chunk}");
                    assert_eq!(
                        buf.gps_time.as_ref().unwrap()[k],
                        all.gps_time.as_ref().unwrap()[seen + k]
                    );
                    assert_eq!(buf.scanner[k], all.scanner[seen + k]);
                }
                seen += n;
                assert_eq!(r.remaining(), (pts.len() - seen) as u64);
            }
            assert_eq!(seen, pts.len(), "{ext} chunk {chunk}");
            assert_eq!(r.next_chunk(&mut buf, chunk).unwrap(), 0, "stays at the end");
        }
    }
}

#[test]
fn several_tiles_share_the_first_tiles_origin() {
    let dir = tempfile::tempdir().unwrap();
    let format = Format::new(1).unwrap();
    let a: Vec<Point> = (0..500).map(|i| test_point(i, &format)).collect();
    let b: Vec<Point> = (500..900).map(|i| test_point(i, &format)).collect();
    let (pa, pb) = (dir.path().join("a.las"), dir.path().join("b.laz"));
    let spec = Spec {
        geotiff_epsg: Some(32650),
        ..Spec::new((1, 2), 1)
    };
    write_points(&pa, &spec, &a);
    write_points(&pb, &spec, &b);
    let cloud = read_points(&[&pa, &pb]).unwrap();
    let all: Vec<Point> = a.iter().chain(&b).cloned().collect();
    assert_same_points(&cloud, &all, &format, "tiles");
    assert_eq!(cloud.origin, [231_456.0, 3_380_123.0, 12.0]);
    assert_eq!(cloud.crs.as_ref().and_then(|c| c.epsg), Some(32650));

    // A tile without GPS time drops GPS time for the whole cloud.
    let pc = dir.path().join("c.las");
    write_drive(&pc, &Spec::new((1, 2), 0), 10);
    let mixed = read_points(&[&pa, &pc]).unwrap();
    assert!(mixed.gps_time.is_none());
    assert_eq!(mixed.len(), 510);

    // Tiles declaring different CRSs are refused.
    let pd = dir.path().join("d.las");
    write_drive(
        &pd,
        &Spec {
            geotiff_epsg: Some(32651),
            ..Spec::new((1, 2), 1)
        },
        10,
    );
    let e = input_error(read_points(&[&pa, &pd]));
    assert!(
        e.contains("d.las") && e.contains("EPSG:32651") && e.contains("EPSG:32650"),
        "{e}"
    );
    let e = input_error(read_points(&[]));
    assert!(e.contains("no point cloud files"), "{e}");
}

#[test]
fn crs_from_wkt_and_geotiff_and_missing() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("wkt.las");
    write_drive(
        &p,
        &Spec {
            wkt: Some(UTM50_WKT),
            ..Spec::new((1, 4), 6)
        },
        5,
    );
    let crs = inspect_points(&p).unwrap().crs.unwrap();
    assert_eq!(crs.epsg, Some(32650));
    assert!(crs.wkt.unwrap().starts_with("PROJCS[\"WGS 84 / UTM zone 50N\""));
    let p = dir.path().join("wkt.laz");
    write_drive(
        &p,
        &Spec {
            wkt: Some(UTM50_WKT),
            ..Spec::new((1, 4), 7)
        },
        5,
    );
    assert_eq!(read_points(&[&p]).unwrap().crs.unwrap().epsg, Some(32650));
    let p = dir.path().join("geotiff.las");
    write_drive(
        &p,
        &Spec {
            geotiff_epsg: Some(28992),
            ..Spec::new((1, 2), 3)
        },
        5,
    );
    assert_eq!(inspect_points(&p).unwrap().crs.unwrap().epsg, Some(28992));
    let p = dir.path().join("none.las");
    write_drive(&p, &Spec::new((1, 2), 3), 5);
    assert!(inspect_points(&p).unwrap().crs.is_none());
}

#[test]
fn missing_gps_time_is_fine_missing_intensity_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("nogps.las");
    write_drive(&p, &Spec::new((1, 2), 0), 50);
    let c = read_points(&[&p]).unwrap();
    assert!(c.gps_time.is_none());
    assert!(!inspect_points(&p).unwrap().has_gps_time);

    let format = Format::new(6).unwrap();
    let dark: Vec<Point> = (0..50)
        .map(|i| Point {
            intensity: 0,
            ..test_point(i, &format)
        })
        .collect();
    for ext in ["las", "laz"] {
        let p = dir.path().join(format!("dark.{ext}"));
        write_points(&p, &Spec::new((1, 4), 6), &dark);
        let e = input_error(read_points(&[&p]));
        assert!(
            e.contains(&format!("dark.{ext}"))
                && e.contains("has no intensity values (all zero); marking extraction needs intensity"),
            "{e}"
        );
        // The check is a reading option; the streaming reader only counts.
        let opts = ReadOptions {
            require_intensity: false,
            ..Default::default()
        };
        assert_eq!(read_points_with(&[&p], &opts).unwrap().len(), 50);
        let mut r = PointReader::open(&p).unwrap();
        r.next_chunk(&mut PointCloud::default(), 100).unwrap();
        assert_eq!(r.nonzero_intensity_count(), 0);
    }
}

#[test]
fn truncated_files_are_reported_before_reading() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("full.las");
    write_drive(&p, &Spec::new((1, 4), 6), 1000);
    let bytes = std::fs::read(&p).unwrap();
    let t = dir.path().join("cut.las");
    std::fs::write(&t, &bytes[..bytes.len() - 3 * 30 - 7]).unwrap();
    let e = input_error(inspect_points(&t));
    assert!(
        e.contains("cut.las") && e.contains("truncated file") && e.contains("announces 1000 points"),
        "{e}"
    );
    assert!(e.contains("room for 996 points"), "{e}");
    assert!(input_error(read_points(&[&t])).contains("truncated file"));
    assert!(input_error(PointReader::open(&t)).contains("truncated file"));
    std::fs::write(&t, &bytes[..100]).unwrap();
    assert!(input_error(inspect_points(&t)).contains("shorter than a LAS header"));

    let p = dir.path().join("full.laz");
    write_drive(&p, &Spec::new((1, 4), 6), 120_000);
    let bytes = std::fs::read(&p).unwrap();
    let t = dir.path().join("cut.laz");
    std::fs::write(&t, &bytes[..bytes.len() / 2]).unwrap();
    let e = input_error(inspect_points(&t));
    assert!(e.contains("cut.laz") && e.contains("truncated"), "{e}");
    assert!(input_error(read_points(&[&t])).contains("truncated"));
}

#[test]
fn not_las_at_all() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("trajectory_named.las");
    std::fs::write(&p, "time,x,y\n0,1,2\n1,2,3\n").unwrap();
    let e = input_error(inspect_points(&p));
    assert!(
        e.contains("trajectory_named.las") && e.contains("not a LAS/LAZ file: signature is not LASF"),
        "{e}"
    );
    assert!(e.contains("trajectory table"), "{e}");
    let p = dir.path().join("notes.las");
    std::fs::write(&p, "hello, these are my notes\n").unwrap();
    let e = input_error(read_points(&[&p]));
    assert!(e.contains("signature is not LASF (it is a text file)"), "{e}");
    let p = dir.path().join("empty.las");
    std::fs::write(&p, b"").unwrap();
    assert!(input_error(inspect_points(&p)).contains("empty file (0 bytes)"));
    let e = input_error(inspect_points(&dir.path().join("absent.las")));
    assert!(e.contains("absent.las: file not found"), "{e}");
    assert!(input_error(inspect_points(dir.path())).contains("is a directory"));
}

/// A way to damage a good file's bytes.
type Damage = fn(&mut Vec<u8>);

#[test]
fn corrupt_headers_name_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("ok.las");
    write_drive(&p, &Spec::new((1, 2), 1), 10);
    let good = std::fs::read(&p).unwrap();
    let cases: [(&str, Damage); 5] = [
        (
            "5 VLRs announced but VLR 1 would start inside the point data",
            |b| b[100..104].copy_from_slice(&5u32.to_le_bytes()),
        ),
        ("unsupported LAS version 2.2", |b| b[24] = 2),
        ("unsupported point format 11", |b| b[104] = 11),
        ("point record length 20 is shorter than format 1", |b| {
            b[105..107].copy_from_slice(&20u16.to_le_bytes())
        }),
        ("point data should start at byte", |b| {
            b[96..100].copy_from_slice(&9_000u32.to_le_bytes())
        }),
    ];
    for (expected, damage) in cases {
        let mut b = good.clone();
        damage(&mut b);
        let t = dir.path().join("bad.las");
        std::fs::write(&t, &b).unwrap();
        let e = input_error(inspect_points(&t));
        assert!(e.contains(expected), "{expected}: {e}");
    }
}

/// Random bytes, random headers, truncations and byte flips: an error or points, never a
/// panic (a panic fails the test).
#[test]
fn fuzzed_inputs_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let las_path = dir.path().join("seed.las");
    let laz_path = dir.path().join("seed.laz");
    write_drive(
        &las_path,
        &Spec {
            wkt: Some(UTM50_WKT),
            ..Spec::new((1, 4), 7)
        },
        2_000,
    );
    write_drive(&laz_path, &Spec::new((1, 4), 6), 60_000);
    let seeds = [
        std::fs::read(&las_path).unwrap(),
        std::fs::read(&laz_path).unwrap(),
    ];
    let t = dir.path().join("fuzz.las");
    let try_all = |bytes: &[u8]| {
        std::fs::write(&t, bytes).unwrap();
        let _ = sniff(bytes);
        let _ = inspect_points(&t);
        let _ = read_points(&[&t]);
        let _ = read_trajectory(&t);
    };
    for _ in 0..30 {
        let n = rng.random_range(0..600);
        let mut bytes: Vec<u8> = (0..n).map(|_| rng.random()).collect();
        try_all(&bytes);
        if bytes.len() >= 4 {
            bytes[..4].copy_from_slice(b"LASF");
            try_all(&bytes);
        }
    }
    for seed in &seeds {
        for _ in 0..25 {
            let cut = rng.random_range(0..seed.len());
            try_all(&seed[..cut]);
        }
        for _ in 0..40 {
            let mut b = seed.clone();
            for _ in 0..rng.random_range(1..8) {
                let i = rng.random_range(0..b.len());
                b[i] = rng.random();
            }
            try_all(&b);
        }
        // Flips confined to the header and VLRs.
        for _ in 0..60 {
            let mut b = seed.clone();
            let i = rng.random_range(0..1200.min(b.len()));
            b[i] = rng.random();
            try_all(&b);
        }
    }
}

#[test]
fn trajectory_files() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("t.txt");
    std::fs::write(&p, "").unwrap();
    let e = input_error(read_trajectory(&p));
    assert!(e.contains("t.txt") && e.contains("empty trajectory"), "{e}");
    std::fs::write(&p, "foo;bar\n1;2\n").unwrap();
    let e = input_error(read_trajectory(&p));
    assert!(
        e.contains("unknown column layout: found columns [foo, bar]"),
        "{e}"
    );
    assert!(e.contains("missing required time, x, y"), "{e}");
    std::fs::write(&p, "Time\tX\tY\tHeading\n0\t0\t0\t90\n1\t10\t0\t90\n").unwrap();
    let t = read_trajectory(&p).unwrap();
    assert_eq!(t.poses()[1].heading_deg, Some(90.0));
    assert_eq!(sniff_file(&p).unwrap(), FileKind::Trajectory);
    let s = inspect_trajectory(&p).unwrap();
    assert_eq!((s.row_count, s.pose_count, s.length_m), (2, 2, 10.0));
    let las = dir.path().join("p.las");
    write_drive(&las, &Spec::new((1, 2), 1), 3);
    assert!(input_error(read_trajectory(&las)).contains("LAS/LAZ point file, not a trajectory"));
    assert!(input_error(read_trajectory(&dir.path().join("nope.csv"))).contains("file not found"));
}

#[test]
fn real_nwu_rovereto() {
    let d = shared().join("nwu_rovereto");
    let p = d.join("points.las");
    assert_eq!(sniff_file(&p).unwrap(), FileKind::Las);
    let s = inspect_points(&p).unwrap();
    assert_eq!(
        (s.point_count, s.point_format, s.version.as_str()),
        (18_496, 1, "1.2")
    );
    assert!(s.crs.is_none(), "the file has no CRS VLR");
    let c = read_points(&[&p]).unwrap();
    assert_eq!(c.len(), 18_496);
    // Intensity 20–84 stored × 256.
    let (lo, hi) = c
        .intensity
        .iter()
        .fold((f32::MAX, 0f32), |(a, b), &v| (a.min(v), b.max(v)));
    assert!(
        lo >= 20.0 * 256.0 - 1.0 && hi <= 84.0 * 256.0 + 256.0,
        "{lo}..{hi}"
    );
    assert!(c.scanner.iter().all(|&s| s == 0));
    let t = read_trajectory(&d.join("trajectory.csv")).unwrap();
    assert_eq!(t.poses().len(), 9);
    assert!((t.length_m() - 88.0).abs() < 2.0, "{}", t.length_m());
    // The points lie along the trajectory (same local UTM frame).
    let mid = c.len() / 2;
    let st = t.locate(c.x[mid] + c.origin[0], c.y[mid] + c.origin[1]);
    assert!(st.offset_m.abs() < 15.0, "{st:?}");
}

#[test]
fn real_semantickitti_scan() {
    let d = shared().join("semantickitti_00");
    let p = d.join("scan_000000.las");
    let s = inspect_points(&p).unwrap();
    assert_eq!(s.point_count, 124_668);
    assert!(s.crs.is_none());
    let c = read_points(&[&p]).unwrap();
    assert_eq!(c.len(), 124_668);
    assert!(c.intensity.iter().any(|&v| v > 0.0));
    // Sensor frame: ground at z ≈ -1.73 m.
    let mut z: Vec<f64> = c.z.iter().map(|v| v + c.origin[2]).collect();
    z.sort_by(f64::total_cmp);
    assert!(z[z.len() / 10] < -1.0, "{}", z[z.len() / 10]);
    let t = read_trajectory(&d.join("trajectory.csv")).unwrap();
    assert_eq!(t.poses().len(), 21);
    assert_eq!(t.poses()[0].heading_deg, Some(90.0));
}

#[test]
fn real_amsterdam_laz_tiles() {
    let d = shared().join("amsterdam_cyclomedia");
    let names = ["2292_9700.laz", "2293_9698.laz", "2294_9700.laz", "2294_9701.laz"];
    let counts = [33_984u64, 293_074, 44_566, 26_378];
    let paths: Vec<PathBuf> = names.iter().map(|n| d.join(n)).collect();
    for (p, &n) in paths.iter().zip(&counts) {
        assert_eq!(sniff_file(p).unwrap(), FileKind::Laz);
        let s = inspect_points(p).unwrap();
        assert_eq!((s.point_count, s.point_format, s.compressed), (n, 3, true));
        assert!(s.has_gps_time);
        // The README says EPSG:28992, but the headers carry no CRS VLR at all (only the
        // extra-bytes and laszip VLRs): the reader must report "unknown", not guess.
        assert!(s.crs.is_none(), "{:?}", s.crs);
        // RD New coordinates.
        assert!(s.bounds[0][0] > 114_000.0 && s.bounds[0][1] > 484_000.0);
    }
    let refs: Vec<&Path> = paths.iter().map(|p| p.as_path()).collect();
    let c = read_points(&refs).unwrap();
    assert_eq!(c.len() as u64, counts.iter().sum::<u64>());
    assert!(c.gps_time.is_some());
    let first = inspect_points(&paths[0]).unwrap();
    assert_eq!(c.origin, first.bounds[0].map(f64::floor));
    // Every point lies inside the union of the tile bounds (all relative to one origin).
    for i in (0..c.len()).step_by(101) {
        let (x, y) = (c.x[i] + c.origin[0], c.y[i] + c.origin[1]);
        assert!(
            (114_590.0..114_760.0).contains(&x) && (484_890.0..485_110.0).contains(&y),
            "{x} {y}"
        );
    }
    // Intensity quantised to ~99 levels.
    let mut levels: Vec<u32> = c.intensity.iter().map(|&v| v as u32).collect();
    levels.sort_unstable();
    levels.dedup();
    assert!(levels.len() > 20 && levels.len() < 200, "{}", levels.len());
    // The labelled variant carries one extra byte per point and reads the same.
    let l = d.join("road_ground_labelled_2292_9700.laz");
    assert_eq!(read_points(&[&l]).unwrap().len(), 33_984);
}

#[test]
fn real_whu_templates_have_no_intensity() {
    let p = shared().join("whu_templates/Models_Cityroad/model03_forward_arrow.las");
    let s = inspect_points(&p).unwrap();
    assert_eq!(s.point_count, 533);
    let e = input_error(read_points(&[&p]));
    assert!(
        e.contains("model03_forward_arrow.las") && e.contains("has no intensity values"),
        "{e}"
    );
    let opts = ReadOptions {
        require_intensity: false,
        ..Default::default()
    };
    assert_eq!(read_points_with(&[&p], &opts).unwrap().len(), 533);
}
