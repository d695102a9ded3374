//! `roadmark bench-read`: LAS/LAZ reading throughput, compared with the raw file bandwidth.
//!
//! For each file it measures (best of `--repeat` runs, page cache warm after the first):
//! - *raw read*: the file's bytes read sequentially into one reused 8 MB buffer, nothing
//!   decoded — the ceiling for any reader of that file;
//! - *parse*: [`PointReader`] streaming the whole file chunk by chunk into a reused
//!   [`PointCloud`] with every column materialised (x, y, z in f64 relative to the origin,
//!   intensity, GPS time, scanner head).
//!
//! `--generate N --out DIR` first writes a synthetic survey of about N points, as a LAS 1.4
//! point format 6 file and its LAZ twin, with realistic UTM coordinates (X ≈ 231000,
//! Y ≈ 3380000, EPSG:32650 WKT, scale 0.001, per-axis offsets): a rotating-mirror profiler
//! (200 profiles/s, two heads alternating) over a road with lane markings and facades, so the
//! LAZ encoder sees realistic coherence. The run is reproducible without the simulator.

use crate::pipeline::PointCloud;
use crate::pipeline::io::PointReader;
use anyhow::Context;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::io::Read;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// LAS/LAZ files to read.
    #[arg(long, num_args = 1..)]
    pub points: Vec<PathBuf>,
    /// Write a synthetic file of about N points (LAS 1.4 format 6 and its LAZ twin) first,
    /// and benchmark it (with --out).
    #[arg(long, value_name = "N")]
    pub generate: Option<u64>,
    /// Directory for --generate (bench.las, bench.laz).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Points per chunk (default: the reader's preferred chunk).
    #[arg(long)]
    pub chunk: Option<usize>,
    /// Runs per measurement; the fastest is reported.
    #[arg(long, default_value_t = 3)]
    pub repeat: usize,
    /// Seed of the synthetic survey.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let mut files = args.points.clone();
    if let Some(n) = args.generate {
        let dir = args.out.as_deref().context("--generate needs --out DIR")?;
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let (las, laz) = (dir.join("bench.las"), dir.join("bench.laz"));
        let t = Instant::now();
        let written = generate(n, &las, &laz, args.seed)?;
        println!(
            "generated {} points: {} ({:.0} MB), {} ({:.0} MB) in {:.1} s",
            written,
            las.display(),
            mb(file_len(&las)?),
            laz.display(),
            mb(file_len(&laz)?),
            t.elapsed().as_secs_f64()
        );
        files.push(las);
        files.push(laz);
    }
    anyhow::ensure!(
        !files.is_empty(),
        "give --points FILE... or --generate N --out DIR"
    );
    let repeat = args.repeat.max(1);
    for path in &files {
        bench_file(path, args.chunk, repeat)?;
    }
    Ok(())
}

fn mb(bytes: u64) -> f64 {
    bytes as f64 / 1e6
}

fn file_len(path: &Path) -> anyhow::Result<u64> {
    Ok(std::fs::metadata(path)
        .with_context(|| format!("{}", path.display()))?
        .len())
}

/// CPU time of the whole process (every thread, rayon's included) in seconds, from
/// `/proc/self/task/*/schedstat` (ns resolution); `None` off Linux. On a shared machine the
/// wall clock includes waiting for a core, the CPU time does not.
fn cpu_seconds() -> Option<f64> {
    let mut ns = 0u64;
    for task in std::fs::read_dir("/proc/self/task").ok()? {
        let stat = std::fs::read_to_string(task.ok()?.path().join("schedstat")).ok()?;
        ns += stat.split_whitespace().next()?.parse::<u64>().ok()?;
    }
    Some(ns as f64 * 1e-9)
}

/// (wall, cpu) seconds of `f`; cpu is NaN when unavailable.
fn timed<T>(f: impl FnOnce() -> anyhow::Result<T>) -> anyhow::Result<(f64, f64, T)> {
    let c0 = cpu_seconds();
    let t = Instant::now();
    let out = f()?;
    let wall = t.elapsed().as_secs_f64();
    let cpu = match (c0, cpu_seconds()) {
        (Some(a), Some(b)) => b - a,
        _ => f64::NAN,
    };
    Ok((wall, cpu, out))
}

/// Read the file's bytes into a reused buffer.
fn raw_read(path: &Path, buf: &mut [u8]) -> anyhow::Result<usize> {
    let mut f = std::fs::File::open(path)?;
    let mut total = 0usize;
    loop {
        let n = f.read(buf)?;
        if n == 0 {
            break;
        }
        total += n;
    }
    Ok(std::hint::black_box(total))
}

/// Stream every point with all columns; returns the point count.
fn parse(path: &Path, chunk: Option<usize>) -> anyhow::Result<u64> {
    let mut reader = PointReader::open(path)?;
    let chunk = chunk.unwrap_or_else(|| reader.preferred_chunk());
    let mut cloud = PointCloud::default();
    let mut n = 0u64;
    let mut check = 0.0;
    loop {
        let got = reader.next_chunk(&mut cloud, chunk)?;
        if got == 0 {
            break;
        }
        n += got as u64;
        // Touch the last point so the decode cannot be optimised away.
        check += cloud.x[got - 1] + f64::from(cloud.intensity[got - 1]);
    }
    std::hint::black_box(check);
    Ok(n)
}

/// Best (wall, cpu) over runs, each minimum taken separately.
#[derive(Clone, Copy)]
struct Best {
    wall: f64,
    cpu: f64,
}

impl Best {
    fn new() -> Self {
        Best {
            wall: f64::INFINITY,
            cpu: f64::INFINITY,
        }
    }

    fn add(&mut self, wall: f64, cpu: f64) {
        self.wall = self.wall.min(wall);
        self.cpu = self.cpu.min(cpu);
    }
}

fn bench_file(path: &Path, chunk: Option<usize>, repeat: usize) -> anyhow::Result<()> {
    let bytes = file_len(path)?;
    let summary = crate::pipeline::io::inspect_points(path)?;
    let mut buf = vec![0u8; 8 << 20];
    // Warm the page cache so both measurements see the same storage.
    raw_read(path, &mut buf)?;
    let mut raw = Best::new();
    let mut par = Best::new();
    let mut points = 0;
    for _ in 0..repeat {
        let (w, c, _) = timed(|| raw_read(path, &mut buf))?;
        raw.add(w, c);
        let (w, c, n) = timed(|| parse(path, chunk))?;
        par.add(w, c);
        points = n;
    }
    let kind = if summary.compressed { "LAZ" } else { "LAS" };
    let pts_per_byte = points as f64 / bytes as f64;
    let line = |what: &str, raw_s: f64, parse_s: f64| {
        let raw_bw = bytes as f64 / raw_s;
        format!(
            "{kind}  {:.1} M pts  {:.3} s  {:.1} M pts/s  {:.0} MB/s  (raw read {:.2} GB/s = {:.1} M pts/s \
             equiv, ratio {:.2})  [{what}]",
            points as f64 / 1e6,
            parse_s,
            points as f64 / parse_s / 1e6,
            mb(bytes) / parse_s,
            raw_bw / 1e9,
            raw_bw * pts_per_byte / 1e6,
            parse_s / raw_s,
        )
    };
    println!(
        "{} (LAS {} format {}, {:.0} MB, chunk {}, best of {repeat})",
        path.display(),
        summary.version,
        summary.point_format,
        mb(bytes),
        chunk.map_or_else(|| "auto".to_string(), |c| c.to_string()),
    );
    println!("  {}", line("wall clock", raw.wall, par.wall));
    if raw.cpu.is_finite() && par.cpu.is_finite() {
        println!("  {}", line("CPU time, all threads", raw.cpu, par.cpu));
    }
    Ok(())
}

/// WKT of EPSG:32650 written into the generated files.
const UTM50_WKT: &str = r#"PROJCS["WGS 84 / UTM zone 50N",GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563,AUTHORITY["EPSG","7030"]],AUTHORITY["EPSG","6326"]],PRIMEM["Greenwich",0,AUTHORITY["EPSG","8901"]],UNIT["degree",0.0174532925199433,AUTHORITY["EPSG","9122"]],AUTHORITY["EPSG","4326"]],PROJECTION["Transverse_Mercator"],PARAMETER["latitude_of_origin",0],PARAMETER["central_meridian",117],PARAMETER["scale_factor",0.9996],PARAMETER["false_easting",500000],PARAMETER["false_northing",0],UNIT["metre",1,AUTHORITY["EPSG","9001"]],AXIS["Easting",EAST],AXIS["Northing",NORTH],AUTHORITY["EPSG","32650"]]"#;

const OFFSET: [f64; 3] = [231_000.0, 3_380_000.0, 0.0];
const SCALE: f64 = 0.001;

fn bench_header() -> anyhow::Result<las::Header> {
    let mut b = las::Builder::default();
    b.version = las::Version::new(1, 4);
    b.point_format = las::point::Format::new(6)?;
    b.system_identifier = "roadmark bench-read".into();
    b.generating_software = "roadmark".into();
    let t = |offset| las::Transform { scale: SCALE, offset };
    b.transforms = las::Vector {
        x: t(OFFSET[0]),
        y: t(OFFSET[1]),
        z: t(OFFSET[2]),
    };
    let mut header = b.into_header()?;
    header.set_wkt_crs(UTM50_WKT.as_bytes().to_vec())?;
    Ok(header)
}

/// Write about `n` synthetic format-6 points to `las` and `laz`; returns the count written.
pub fn generate(n: u64, las_path: &Path, laz_path: &Path, seed: u64) -> anyhow::Result<u64> {
    let header = bench_header()?;
    let mut w_las = las::Writer::from_path(las_path, header.clone())
        .with_context(|| format!("creating {}", las_path.display()))?;
    let mut w_laz = las::Writer::from_path(laz_path, header)
        .with_context(|| format!("creating {}", laz_path.display()))?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, 0.005)?;
    let texture = Normal::new(0.0, 0.15)?;
    const PROFILES_PER_S: f64 = 200.0;
    const PER_PROFILE: usize = 2500;
    const SPEED: f64 = 15.0;
    const HEIGHT: f64 = 2.3;
    const FACADE: f64 = 12.0;
    let heading = 30f64.to_radians();
    let along = [heading.sin(), heading.cos()];
    let right = [heading.cos(), -heading.sin()];
    let start = [231_123.456, 3_380_456.789, 18.5];
    let record = 30usize;
    let batch = 1 << 20;
    let mut bytes: Vec<u8> = Vec::with_capacity(batch * record);
    let mut written = 0u64;
    let mut profile = 0u64;
    while written < n {
        let t0 = 300_000.0 + profile as f64 / PROFILES_PER_S;
        let head = (profile % 2) as u8;
        // The two heads look slightly forward and backward (butterfly arrangement).
        let s0 = SPEED * (t0 - 300_000.0) + if head == 0 { 0.3 } else { -0.3 };
        for k in 0..PER_PROFILE {
            if written >= n {
                break;
            }
            let theta = std::f64::consts::TAU * k as f64 / PER_PROFILE as f64;
            let (up, lat_dir) = theta.sin_cos();
            let (lat, z, range, class) = if up < -0.02 && (HEIGHT / -up * lat_dir).abs() <= FACADE {
                let r = HEIGHT / -up;
                let lat = r * lat_dir;
                (lat, -0.02 * lat.abs(), r, 2u8)
            } else if lat_dir.abs() > 0.05 {
                let r = FACADE / lat_dir.abs();
                let z = HEIGHT + r * up;
                if z > 18.0 {
                    continue;
                }
                (FACADE.copysign(lat_dir), z - HEIGHT, r, 6u8)
            } else {
                continue;
            };
            let s = s0 + 0.002 * k as f64 / PER_PROFILE as f64;
            // Paint: dashed lane lines (6 m on, 9 m off) at ±1.8 m, solid edge lines at ±5.4 m.
            let reflectance = if class == 2 {
                let dashed = (lat.abs() - 1.8).abs() < 0.075 && s.rem_euclid(15.0) < 6.0;
                let solid = (lat.abs() - 5.4).abs() < 0.1;
                if dashed || solid { 0.8 } else { 0.18 }
            } else {
                0.35
            } * (1.0 + texture.sample(&mut rng));
            let incidence = if class == 2 { -up } else { lat_dir.abs() };
            let intensity =
                (reflectance * incidence * 60_000.0 / (1.0 + (range / 15.0).powi(2))).clamp(1.0, 65_535.0);
            let x = start[0] + s * along[0] + lat * right[0] + noise.sample(&mut rng);
            let y = start[1] + s * along[1] + lat * right[1] + noise.sample(&mut rng);
            let zz = start[2] + 0.01 * s + z + noise.sample(&mut rng);
            let gps = t0 + k as f64 / (PER_PROFILE as f64 * PROFILES_PER_S);
            for (v, o) in [(x, OFFSET[0]), (y, OFFSET[1]), (zz, OFFSET[2])] {
                bytes.extend_from_slice(&(((v - o) / SCALE).round() as i32).to_le_bytes());
            }
            bytes.extend_from_slice(&(intensity as u16).to_le_bytes());
            bytes.push(0x11); // return 1 of 1
            bytes.push(head << 4); // scanner channel
            bytes.push(class);
            bytes.push(0); // user data
            let angle = (theta.to_degrees() - 180.0) / 0.006;
            bytes.extend_from_slice(&(angle.round() as i16).to_le_bytes());
            bytes.extend_from_slice(&1u16.to_le_bytes()); // point source id
            bytes.extend_from_slice(&gps.to_le_bytes());
            written += 1;
            if bytes.len() >= batch * record {
                flush(&mut w_las, &mut w_laz, &mut bytes)?;
            }
        }
        profile += 1;
    }
    flush(&mut w_las, &mut w_laz, &mut bytes)?;
    w_las.close()?;
    w_laz.close()?;
    Ok(written)
}

fn flush(
    w_las: &mut las::Writer<std::io::BufWriter<std::fs::File>>,
    w_laz: &mut las::Writer<std::io::BufWriter<std::fs::File>>,
    bytes: &mut Vec<u8>,
) -> anyhow::Result<()> {
    if bytes.is_empty() {
        return Ok(());
    }
    let data = las::PointDataBuilder::new()
        .for_header(w_las.header())
        .build_from_bytes(std::mem::take(bytes))?;
    w_las.write_points(&data)?;
    w_laz.write_points(&data)?;
    bytes.reserve(data.raw_bytes().len());
    Ok(())
}
