//! `roadmark export-clusters`: the training (and held-out) set of the learned classifier.
//!
//! # What
//! Simulates surveys (`roadmark simulate`'s generator, called directly) for every
//! scene × standard × seed asked for, cuts marking clusters out of them with the damage the
//! pipeline produces, labels them from the truth, and writes them as prepared network input:
//!
//! - `points.npy`: f32 `[M, n, 4]`, exactly what the pipeline feeds the network
//!   ([`features::prepare`]: trajectory frame, farthest-point order);
//! - `labels.npy`: u8 `[M]`, index into `index.json`'s `classes` (the model's output order);
//! - `surveys.npy`: u32 `[M]`, the survey each cluster comes from (for splits);
//! - `index.json`: classes, points per cluster, feature version, surveys, counts, the command;
//! - `clusters.csv`: per cluster the survey, marking id, class, point count and damage flags.
//!
//! With `--eval MODEL` (a path or `builtin`) the clusters are also classified through ONNX
//! Runtime and the confusion matrix and per-class precision/recall/F1 are printed.
//!
//! # Algorithm (per survey; every random draw seeded from scene, standard, seed, marking and
//! variant, so the output does not depend on thread count)
//! 1. Points of marking `k` = points with label `k` (`labels.bin`); class from `truth.geojson`.
//!    Solid lines are cut into pieces 9–40 m long (longer than any dash, so a piece is never
//!    a dash's twin). Classes with few markings get more variants, so a survey gives at most
//!    `--per-class` clusters of each class.
//! 2. Variant 0 of a marking is clean; the others get a random mix of damage:
//!    worn patches (discs of lost paint), occlusion by a car (a 1.8 × 4.5 m box), clipping at
//!    a tile or scan edge (a straight cut), over-segmentation (the larger part of a random
//!    split), under-segmentation (merged with a marking less than 0.8 m away; labelled by the
//!    majority only when it holds ≥ 65 % of the points), bleed of asphalt points within 0.1 m,
//!    stray noise points within 1 m, and multiplicative intensity noise with a gradient.
//!    A damaged cluster must keep ≥ 45 % of the marking's points (about where IoU 0.3 with
//!    the truth outline is still reachable), else the draw is repeated.
//! 3. `unknown` clusters: the simulated glyphs (speed numbers), and asphalt patches shaped
//!    like the bright distractors (manhole discs, sealant streaks, blobs) next to markings.
//!
//! # Parameters
//! See [`Args`]. Defaults give ≈ 250 clusters per survey.
//!
//! # Complexity
//! Simulation dominates (≈ 10 M points per survey); cutting is O(points of the markings).

use std::collections::HashMap;
use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::pipeline::learned::features::{self, ClusterPoints, FEATURE_VERSION, FEATURES_PER_POINT};
use crate::pipeline::learned::{Classifier, Prediction};
use crate::pipeline::types::{MarkingClass, PointCloud, StationIndex, Trajectory};
use crate::pipeline::{PipelineError, io};
use crate::sim::{self, SimOptions, markings::Standard};

/// Output order of the exported labels (the model's classes, `training/model.py`).
pub const CLASSES: [MarkingClass; 12] = MarkingClass::ALL;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Output directory (created): points.npy, labels.npy, surveys.npy, index.json, clusters.csv.
    #[arg(long)]
    pub out: PathBuf,
    /// Survey seeds: `A..B` (B excluded) or a comma-separated list.
    #[arg(long, default_value = "1..11")]
    pub seeds: String,
    /// Scenes to simulate.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "highway,urban_intersection,curved_ramp,dual_head,worn"
    )]
    pub scenes: Vec<String>,
    /// Marking standards to simulate (gb, mutcd).
    #[arg(long, value_delimiter = ',', default_value = "gb,mutcd")]
    pub standards: Vec<String>,
    /// At most this many clusters of one class per survey (rare classes get more damaged
    /// variants per marking, frequent ones a random subset of markings).
    #[arg(long, default_value_t = 24)]
    pub per_class: usize,
    /// Simulated surveys are kept in (and reused from) this directory; default OUT/surveys.
    #[arg(long)]
    pub cache: Option<PathBuf>,
    /// Delete each simulated survey once its clusters are cut.
    #[arg(long)]
    pub no_cache: bool,
    /// Points per cluster (must match the model).
    #[arg(long, default_value_t = 256)]
    pub points: usize,
    /// Classify the exported clusters with this model (`builtin` or a path) and print the
    /// confusion matrix and per-class precision/recall/F1.
    #[arg(long)]
    pub eval: Option<String>,
}

/// One simulated survey, loaded.
struct Survey {
    cloud: PointCloud,
    labels: Vec<u32>,
    /// Class of marking `k` (label `k + 1`).
    classes: Vec<MarkingClass>,
    /// Truth id of marking `k` (`m{k+1}`).
    ids: Vec<String>,
    traj: Trajectory,
}

/// Which of the points near a distractor's centre belong to it.
type Keep = Box<dyn Fn(f64, f64) -> bool>;

/// One exported cluster before feature preparation.
struct Sample {
    label: MarkingClass,
    marking: String,
    damage: Vec<&'static str>,
    x: Vec<f64>,
    y: Vec<f64>,
    z: Vec<f64>,
    intensity: Vec<f32>,
}

impl Sample {
    fn len(&self) -> usize {
        self.x.len()
    }
}

pub fn run(args: Args) -> Result<()> {
    let seeds = parse_seeds(&args.seeds)?;
    let standards: Vec<Standard> = args
        .standards
        .iter()
        .map(|s| Standard::parse(s).with_context(|| format!("unknown standard '{s}' (known: gb, mutcd)")))
        .collect::<Result<_>>()?;
    for s in &args.scenes {
        if !sim::scene::SCENES.contains(&s.as_str()) {
            bail!("unknown scene '{s}' (known: {})", sim::scene::SCENES.join(", "));
        }
    }
    if args.points < 16 {
        bail!("--points must be at least 16");
    }
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let cache = args.cache.clone().unwrap_or_else(|| args.out.join("surveys"));
    let mut writer = NpyF32Writer::create(&args.out.join("points.npy"), [args.points, FEATURES_PER_POINT])?;
    let mut labels: Vec<u8> = Vec::new();
    let mut survey_of: Vec<u32> = Vec::new();
    let mut csv = BufWriter::new(File::create(args.out.join("clusters.csv"))?);
    writeln!(csv, "index,survey,marking,class,points,damage")?;
    let mut surveys = Vec::new();
    let started = Instant::now();
    let mut feats_all: Vec<f32> = Vec::new();
    let keep_feats = args.eval.is_some();
    for &seed in &seeds {
        for scene in &args.scenes {
            for standard in &standards {
                let name = format!("{scene}_{}_{seed}", standard.name);
                let dir = cache.join(&name);
                let t0 = Instant::now();
                ensure_simulated(scene, *standard, seed, &dir)?;
                let survey = load_survey(&dir)?;
                let t_sim = t0.elapsed().as_secs_f64();
                let samples = cut_survey(&survey, survey_seed(scene, standard.name, seed), args.per_class);
                let survey_id = surveys.len() as u32;
                let n = args.points;
                let mut feats = vec![0.0f32; samples.len() * n * FEATURES_PER_POINT];
                feats
                    .par_chunks_mut(n * FEATURES_PER_POINT)
                    .zip(samples.par_iter())
                    .for_each(|(out, s)| prepare_sample(s, &survey.traj, n, out));
                writer.append(&feats)?;
                if keep_feats {
                    feats_all.extend_from_slice(&feats);
                }
                let mut per_class = [0usize; 12];
                for s in &samples {
                    writeln!(
                        csv,
                        "{},{},{},{},{},{}",
                        labels.len(),
                        name,
                        s.marking,
                        s.label.as_str(),
                        s.len(),
                        s.damage.join("+")
                    )?;
                    labels.push(s.label as u8);
                    survey_of.push(survey_id);
                    per_class[s.label as usize] += 1;
                }
                eprintln!(
                    "{name}: {} points, {} markings, {} clusters ({:.1} s simulate+load, {:.1} s total)",
                    survey.cloud.len(),
                    survey.classes.len(),
                    samples.len(),
                    t_sim,
                    t0.elapsed().as_secs_f64()
                );
                surveys.push(
                    serde_json::json!({"name": name, "scene": scene, "standard": standard.name,
                    "seed": seed, "clusters": samples.len(), "per_class": per_class}),
                );
                if args.no_cache {
                    std::fs::remove_dir_all(&dir).ok();
                }
            }
        }
    }
    let count = writer.finish()?;
    write_npy_u8(&args.out.join("labels.npy"), &labels)?;
    write_npy_u32(&args.out.join("surveys.npy"), &survey_of)?;
    csv.flush()?;
    let mut totals = [0usize; 12];
    for &l in &labels {
        totals[l as usize] += 1;
    }
    let index = serde_json::json!({
        "classes": CLASSES.iter().map(|c| c.as_str()).collect::<Vec<_>>(),
        "points_per_cluster": args.points,
        "features_per_point": FEATURES_PER_POINT,
        "feature_version": FEATURE_VERSION,
        "clusters": count,
        "per_class": CLASSES.iter().zip(totals).map(|(c, n)| (c.as_str().to_string(), n)).collect::<HashMap<_, _>>(),
        "seeds": seeds, "scenes": args.scenes, "standards": args.standards, "per_class_cap": args.per_class,
        "surveys": surveys,
        "command": std::env::args().collect::<Vec<_>>().join(" "),
    });
    std::fs::write(args.out.join("index.json"), serde_json::to_vec_pretty(&index)?)?;
    eprintln!(
        "wrote {count} clusters to {} in {:.0} s",
        args.out.display(),
        started.elapsed().as_secs_f64()
    );
    for (c, n) in CLASSES.iter().zip(totals) {
        eprintln!("  {:<22}{n:>7}", c.as_str());
    }
    if let Some(model) = &args.eval {
        let classifier = if model == "builtin" {
            Classifier::builtin()?
        } else {
            Classifier::load(Path::new(model))?
        };
        evaluate(&classifier, &feats_all, &labels)?;
    }
    Ok(())
}

/// `A..B` (B excluded) or `a,b,c`.
fn parse_seeds(s: &str) -> Result<Vec<u64>> {
    if let Some((a, b)) = s.split_once("..") {
        let a: u64 = a
            .trim()
            .parse()
            .with_context(|| format!("--seeds {s}: bad start"))?;
        let b: u64 = b
            .trim()
            .parse()
            .with_context(|| format!("--seeds {s}: bad end"))?;
        if b <= a {
            bail!("--seeds {s}: empty range");
        }
        Ok((a..b).collect())
    } else {
        s.split(',')
            .map(|t| {
                t.trim()
                    .parse::<u64>()
                    .with_context(|| format!("--seeds {s}: bad seed '{t}'"))
            })
            .collect()
    }
}

fn ensure_simulated(scene: &str, standard: Standard, seed: u64, dir: &Path) -> Result<()> {
    if dir.join("summary.json").is_file() && dir.join("labels.bin").is_file() {
        return Ok(());
    }
    let opt = SimOptions {
        scene: scene.to_string(),
        seed,
        standard,
        ..SimOptions::default()
    };
    sim::simulate(&opt, dir).with_context(|| format!("simulating {scene} seed {seed}"))?;
    Ok(())
}

fn load_survey(dir: &Path) -> Result<Survey> {
    let points_path = dir.join("points.las");
    let cloud = io::read_points(&[points_path.as_path()])?;
    let labels_path = dir.join("labels.bin");
    let raw = std::fs::read(&labels_path).with_context(|| format!("reading {}", labels_path.display()))?;
    if raw.len() != cloud.len() * 4 {
        return Err(PipelineError::input(
            &labels_path,
            format!(
                "{} bytes for {} points (expected 4 per point)",
                raw.len(),
                cloud.len()
            ),
        )
        .into());
    }
    let labels: Vec<u32> = raw
        .chunks_exact(4)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let truth_path = dir.join("truth.geojson");
    let truth: serde_json::Value = serde_json::from_slice(
        &std::fs::read(&truth_path).with_context(|| format!("reading {}", truth_path.display()))?,
    )
    .with_context(|| format!("parsing {}", truth_path.display()))?;
    let mut classes = Vec::new();
    let mut ids = Vec::new();
    for f in truth["features"].as_array().into_iter().flatten() {
        let p = &f["properties"];
        if p["layer"].as_str() != Some("marking") {
            continue;
        }
        let class = p["class"]
            .as_str()
            .and_then(MarkingClass::parse)
            .with_context(|| format!("{}: marking without a known class", truth_path.display()))?;
        classes.push(class);
        ids.push(p["id"].as_str().unwrap_or("?").to_string());
    }
    if let Some(&bad) = labels.iter().find(|&&l| l as usize > classes.len()) {
        return Err(PipelineError::input(
            &labels_path,
            format!("label {bad} but only {} markings in truth.geojson", classes.len()),
        )
        .into());
    }
    let traj = io::read_trajectory(&dir.join("trajectory.csv"))?.to_local(cloud.origin);
    Ok(Survey {
        cloud,
        labels,
        classes,
        ids,
        traj,
    })
}

fn survey_seed(scene: &str, standard: &str, seed: u64) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for b in scene.bytes().chain([b'/']).chain(standard.bytes()) {
        h = (h ^ b as u64).wrapping_mul(0x100_0000_01b3);
    }
    mix(h ^ seed)
}

/// splitmix64: independent seeds from structured inputs.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

fn prepare_sample(s: &Sample, traj: &Trajectory, n: usize, out: &mut [f32]) {
    let m = s.len().max(1) as f64;
    let cx = s.x.iter().sum::<f64>() / m;
    let cy = s.y.iter().sum::<f64>() / m;
    let direction = traj.locate(cx, cy).direction;
    let cloud = PointCloud {
        x: s.x.clone(),
        y: s.y.clone(),
        z: s.z.clone(),
        intensity: s.intensity.clone(),
        scanner: vec![0; s.len()],
        ..Default::default()
    };
    let idx: Vec<usize> = (0..s.len()).collect();
    features::prepare(
        &ClusterPoints {
            cloud: &cloud,
            indices: &idx,
            direction,
        },
        n,
        out,
    );
}

// ------------------------------------------------------------------------------------------
// Cutting clusters

/// Points of the survey bucketed in 0.5 m cells, only around paint (for bleed, noise and
/// neighbour queries).
struct Grid {
    cells: HashMap<(i64, i64), Vec<u32>>,
}

const CELL_M: f64 = 0.5;

fn cell_of(x: f64, y: f64) -> (i64, i64) {
    ((x / CELL_M).floor() as i64, (y / CELL_M).floor() as i64)
}

impl Grid {
    /// All points within `margin_cells` cells of a paint point.
    fn around_paint(cloud: &PointCloud, labels: &[u32], margin_cells: i64) -> Grid {
        let mut wanted = std::collections::HashSet::new();
        for (i, &label) in labels.iter().enumerate().take(cloud.len()) {
            if label > 0 {
                let (cx, cy) = cell_of(cloud.x[i], cloud.y[i]);
                for dx in -margin_cells..=margin_cells {
                    for dy in -margin_cells..=margin_cells {
                        wanted.insert((cx + dx, cy + dy));
                    }
                }
            }
        }
        let mut cells: HashMap<(i64, i64), Vec<u32>> = HashMap::new();
        for i in 0..cloud.len() {
            let c = cell_of(cloud.x[i], cloud.y[i]);
            if wanted.contains(&c) {
                cells.entry(c).or_default().push(i as u32);
            }
        }
        Grid { cells }
    }

    /// Indices within `r` of (x, y), in a deterministic order.
    fn within(&self, cloud: &PointCloud, x: f64, y: f64, r: f64, out: &mut Vec<usize>) {
        let (c0, c1) = (cell_of(x - r, y - r), cell_of(x + r, y + r));
        for cx in c0.0..=c1.0 {
            for cy in c0.1..=c1.1 {
                if let Some(v) = self.cells.get(&(cx, cy)) {
                    for &i in v {
                        let i = i as usize;
                        if (cloud.x[i] - x).powi(2) + (cloud.y[i] - y).powi(2) <= r * r {
                            out.push(i);
                        }
                    }
                }
            }
        }
    }
}

/// A marking (or a piece of a solid line) to cut variants from.
struct Source {
    marking: usize,
    piece: usize,
    points: Vec<usize>,
}

fn cut_survey(survey: &Survey, seed: u64, per_class: usize) -> Vec<Sample> {
    let cloud = &survey.cloud;
    let nm = survey.classes.len();
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); nm];
    for (i, &l) in survey.labels.iter().enumerate() {
        if l > 0 {
            members[l as usize - 1].push(i);
        }
    }
    let grid = Grid::around_paint(cloud, &survey.labels, 6);
    let stations = StationIndex::new(&survey.traj, 1.0);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);

    // Sources per class: markings, or 9–40 m pieces of solid lines.
    let mut sources: Vec<Vec<Source>> = (0..CLASSES.len()).map(|_| Vec::new()).collect();
    for (k, pts) in members.iter().enumerate() {
        if pts.len() < MIN_POINTS {
            continue;
        }
        let class = survey.classes[k];
        if class == MarkingClass::SolidLine {
            let mut by_m: Vec<(f64, usize)> = pts
                .iter()
                .map(|&i| (stations.locate(cloud.x[i], cloud.y[i]).mileage_m, i))
                .collect();
            by_m.sort_by(|a, b| a.0.total_cmp(&b.0));
            let (m0, m1) = (by_m[0].0, by_m[by_m.len() - 1].0);
            let span = m1 - m0;
            let pieces = ((span / 40.0).ceil() as usize).clamp(1, 6);
            for piece in 0..pieces {
                let len = rng.random_range(9.0..40.0f64).min(span);
                let start = m0 + rng.random::<f64>() * (span - len).max(0.0);
                let lo = by_m.partition_point(|p| p.0 < start);
                let hi = by_m.partition_point(|p| p.0 <= start + len);
                let points: Vec<usize> = by_m[lo..hi].iter().map(|p| p.1).collect();
                if points.len() >= MIN_POINTS {
                    sources[class as usize].push(Source {
                        marking: k,
                        piece,
                        points,
                    });
                }
            }
        } else {
            sources[class as usize].push(Source {
                marking: k,
                piece: 0,
                points: pts.clone(),
            });
        }
    }

    // Jobs: (source, variant) with a per-class budget.
    let mut jobs: Vec<(MarkingClass, &Source, usize, u64)> = Vec::new();
    for (ci, list) in sources.iter().enumerate() {
        if list.is_empty() {
            continue;
        }
        let class = CLASSES[ci];
        let budget = if class == MarkingClass::Unknown {
            per_class / 2
        } else {
            per_class
        };
        let mut order: Vec<usize> = (0..list.len()).collect();
        // Fisher–Yates with the survey generator: which markings a budget keeps.
        for i in (1..order.len()).rev() {
            order.swap(i, rng.random_range(0..=i));
        }
        let variants = budget.div_ceil(list.len()).clamp(1, 16);
        let mut taken = 0;
        'outer: for &si in &order {
            for v in 0..variants {
                if taken >= budget {
                    break 'outer;
                }
                jobs.push((class, &list[si], v, rng.random()));
                taken += 1;
            }
        }
    }
    // Bounding boxes for under-segmentation partners.
    let boxes: Vec<[f64; 4]> = members.iter().map(|p| bbox(cloud, p)).collect();
    let mut samples: Vec<Sample> = jobs
        .par_iter()
        .filter_map(|&(class, src, v, s)| {
            let mut rng = ChaCha8Rng::seed_from_u64(s);
            damaged_variant(survey, &members, &boxes, &grid, class, src, v, &mut rng)
        })
        .collect();
    // Unknown: asphalt shaped like bright distractors next to the markings.
    let n_noise = per_class.saturating_sub(
        samples
            .iter()
            .filter(|s| s.label == MarkingClass::Unknown)
            .count(),
    );
    let anchors: Vec<usize> = members
        .iter()
        .filter(|p| p.len() >= MIN_POINTS)
        .map(|p| p[p.len() / 2])
        .collect();
    let noise_seeds: Vec<u64> = (0..n_noise).map(|_| rng.random()).collect();
    if !anchors.is_empty() {
        let noise: Vec<Sample> = noise_seeds
            .par_iter()
            .enumerate()
            .filter_map(|(j, &s)| {
                let mut rng = ChaCha8Rng::seed_from_u64(s);
                distractor(survey, &grid, anchors[j % anchors.len()], j, &mut rng)
            })
            .collect();
        samples.extend(noise);
    }
    samples
}

const MIN_POINTS: usize = 20;

fn bbox(cloud: &PointCloud, pts: &[usize]) -> [f64; 4] {
    pts.iter()
        .fold([f64::MAX, f64::MAX, f64::MIN, f64::MIN], |b, &i| {
            [
                b[0].min(cloud.x[i]),
                b[1].min(cloud.y[i]),
                b[2].max(cloud.x[i]),
                b[3].max(cloud.y[i]),
            ]
        })
}

fn box_gap(a: &[f64; 4], b: &[f64; 4]) -> f64 {
    let dx = (b[0] - a[2]).max(a[0] - b[2]).max(0.0);
    let dy = (b[1] - a[3]).max(a[1] - b[3]).max(0.0);
    dx.hypot(dy)
}

#[allow(clippy::too_many_arguments)]
fn damaged_variant(
    survey: &Survey,
    members: &[Vec<usize>],
    boxes: &[[f64; 4]],
    grid: &Grid,
    class: MarkingClass,
    src: &Source,
    variant: usize,
    rng: &mut ChaCha8Rng,
) -> Option<Sample> {
    let cloud = &survey.cloud;
    let base = &src.points;
    let mut damage: Vec<&'static str> = Vec::new();
    let mut kept: Vec<usize> = base.clone();
    let mut label = class;
    if variant > 0 {
        let mut ok = false;
        for _try in 0..6 {
            damage.clear();
            let mut cand = base.clone();
            if rng.random_bool(0.5) {
                damage.push("worn");
                cand = wear(cloud, &cand, rng);
            }
            if rng.random_bool(0.3) {
                damage.push("occluded");
                cand = occlude(cloud, &cand, rng);
            }
            if rng.random_bool(0.3) {
                damage.push("clipped");
                cand = clip(cloud, &cand, rng);
            }
            if rng.random_bool(0.15) {
                damage.push("split");
                cand = split(cloud, &cand, rng);
            }
            if cand.len() >= MIN_POINTS && cand.len() * 100 >= base.len() * 45 {
                kept = cand;
                ok = true;
                break;
            }
        }
        if !ok {
            damage.clear();
            damage.push("retained-clean");
        }
        if rng.random_bool(0.15) {
            let me = bbox(cloud, &kept);
            let partner = (0..members.len())
                .filter(|&j| j != src.marking && members[j].len() >= MIN_POINTS)
                .map(|j| (box_gap(&me, &boxes[j]), j))
                .filter(|(g, _)| *g < 0.8)
                .min_by(|a, b| a.0.total_cmp(&b.0));
            if let Some((_, j)) = partner {
                // Only the part of the partner near this cluster merges (large partners,
                // e.g. solid lines, are cut to a 3 m neighbourhood).
                let c = [(me[0] + me[2]) / 2.0, (me[1] + me[3]) / 2.0];
                let reach = ((me[2] - me[0]).hypot(me[3] - me[1]) / 2.0 + 3.0).powi(2);
                let extra: Vec<usize> = members[j]
                    .iter()
                    .copied()
                    .filter(|&i| (cloud.x[i] - c[0]).powi(2) + (cloud.y[i] - c[1]).powi(2) < reach)
                    .collect();
                let total = kept.len() + extra.len();
                if extra.len() * 100 <= total * 35 {
                    damage.push("merged");
                    kept.extend(extra);
                } else if kept.len() * 100 <= total * 35 && survey.classes[j] != MarkingClass::SolidLine {
                    damage.push("merged-into");
                    label = survey.classes[j];
                    kept.extend(extra);
                }
            }
        }
    }
    let mut s = Sample {
        label,
        marking: format!("{}#{}", survey.ids[src.marking], src.piece),
        damage,
        x: kept.iter().map(|&i| cloud.x[i]).collect(),
        y: kept.iter().map(|&i| cloud.y[i]).collect(),
        z: kept.iter().map(|&i| cloud.z[i]).collect(),
        intensity: kept.iter().map(|&i| cloud.intensity[i]).collect(),
    };
    if variant > 0 {
        if rng.random_bool(0.6) {
            s.damage.push("bleed");
            bleed(survey, grid, &kept, &mut s, rng);
        }
        if rng.random_bool(0.3) {
            s.damage.push("noise");
            stray(survey, grid, &mut s, rng);
        }
        if rng.random_bool(0.5) {
            s.damage.push("intensity");
            vary_intensity(&mut s, rng);
        }
    }
    Some(s)
}

/// Random point of the cluster.
fn pick(cloud: &PointCloud, pts: &[usize], rng: &mut ChaCha8Rng) -> [f64; 2] {
    let i = pts[rng.random_range(0..pts.len())];
    [cloud.x[i], cloud.y[i]]
}

/// Worn patches: 1–6 discs (radius 0.05–0.4 m) where 70–100 % of the paint is gone.
fn wear(cloud: &PointCloud, pts: &[usize], rng: &mut ChaCha8Rng) -> Vec<usize> {
    if pts.is_empty() {
        return Vec::new();
    }
    let discs: Vec<([f64; 2], f64, f64)> = (0..rng.random_range(1..=6))
        .map(|_| {
            (
                pick(cloud, pts, rng),
                rng.random_range(0.05..0.4),
                rng.random_range(0.7..1.0),
            )
        })
        .collect();
    pts.iter()
        .copied()
        .filter(|&i| {
            !discs.iter().any(|(c, r, p)| {
                (cloud.x[i] - c[0]).powi(2) + (cloud.y[i] - c[1]).powi(2) < r * r && rng.random_bool(*p)
            })
        })
        .collect()
}

/// A car's shadow: a 1.8 × 4.5 m box at a random heading over a random point.
fn occlude(cloud: &PointCloud, pts: &[usize], rng: &mut ChaCha8Rng) -> Vec<usize> {
    if pts.is_empty() {
        return Vec::new();
    }
    let c = pick(cloud, pts, rng);
    let a: f64 = rng.random_range(0.0..std::f64::consts::PI);
    let (ca, sa) = (a.cos(), a.sin());
    let shift = [rng.random_range(-2.0..2.0), rng.random_range(-0.9..0.9)];
    pts.iter()
        .copied()
        .filter(|&i| {
            let (dx, dy) = (cloud.x[i] - c[0], cloud.y[i] - c[1]);
            let (u, v) = (dx * ca + dy * sa - shift[0], -dx * sa + dy * ca - shift[1]);
            !(u.abs() < 2.25 && v.abs() < 0.9)
        })
        .collect()
}

/// A straight cut (tile edge: axis-aligned; scan edge: any angle) through a random point.
fn clip(cloud: &PointCloud, pts: &[usize], rng: &mut ChaCha8Rng) -> Vec<usize> {
    if pts.is_empty() {
        return Vec::new();
    }
    let c = pick(cloud, pts, rng);
    let a: f64 = if rng.random_bool(0.5) {
        rng.random_range(0..4) as f64 * std::f64::consts::FRAC_PI_2
    } else {
        rng.random_range(0.0..std::f64::consts::TAU)
    };
    let (ca, sa) = (a.cos(), a.sin());
    pts.iter()
        .copied()
        .filter(|&i| (cloud.x[i] - c[0]) * ca + (cloud.y[i] - c[1]) * sa < 0.0)
        .collect()
}

/// Over-segmentation: the larger side of a random line near the centre.
fn split(cloud: &PointCloud, pts: &[usize], rng: &mut ChaCha8Rng) -> Vec<usize> {
    if pts.is_empty() {
        return Vec::new();
    }
    let c = pick(cloud, pts, rng);
    let a: f64 = rng.random_range(0.0..std::f64::consts::PI);
    let (ca, sa) = (a.cos(), a.sin());
    let (l, r): (Vec<usize>, Vec<usize>) = pts
        .iter()
        .partition(|&&i| (cloud.x[i] - c[0]) * ca + (cloud.y[i] - c[1]) * sa < 0.0);
    if l.len() >= r.len() { l } else { r }
}

/// Asphalt points within 0.1 m of the cluster join it (threshold bleed at the paint edge).
fn bleed(survey: &Survey, grid: &Grid, kept: &[usize], s: &mut Sample, rng: &mut ChaCha8Rng) {
    let cloud = &survey.cloud;
    let frac: f64 = rng.random_range(0.02..0.15);
    let want = ((kept.len() as f64 * frac) as usize).max(1);
    let mut near = Vec::new();
    for _ in 0..want * 3 {
        if near.len() >= want {
            break;
        }
        let c = pick(cloud, kept, rng);
        let mut found = Vec::new();
        grid.within(cloud, c[0], c[1], 0.12, &mut found);
        found.retain(|&i| survey.labels[i] == 0);
        if !found.is_empty() {
            near.push(found[rng.random_range(0..found.len())]);
        }
    }
    near.sort_unstable();
    near.dedup();
    for i in near {
        s.x.push(cloud.x[i]);
        s.y.push(cloud.y[i]);
        s.z.push(cloud.z[i]);
        s.intensity.push(cloud.intensity[i]);
    }
}

/// 1–6 stray points 0.3–1 m from the cluster (isolated bright returns the threshold kept).
fn stray(survey: &Survey, grid: &Grid, s: &mut Sample, rng: &mut ChaCha8Rng) {
    let cloud = &survey.cloud;
    let bright = percentile(&s.intensity, 0.5);
    for _ in 0..rng.random_range(1..=6) {
        let j = rng.random_range(0..s.len());
        let a: f64 = rng.random_range(0.0..std::f64::consts::TAU);
        let r: f64 = rng.random_range(0.3..1.0);
        let (x, y) = (s.x[j] + r * a.cos(), s.y[j] + r * a.sin());
        let mut found = Vec::new();
        grid.within(cloud, x, y, 0.1, &mut found);
        if let Some(&i) = found.first() {
            s.x.push(cloud.x[i]);
            s.y.push(cloud.y[i]);
            s.z.push(cloud.z[i]);
            s.intensity.push(bright * rng.random_range(0.7..1.1));
        }
    }
}

/// Per-point multiplicative noise and a linear gradient (range fall-off across the cluster).
fn vary_intensity(s: &mut Sample, rng: &mut ChaCha8Rng) {
    let sigma: f64 = rng.random_range(0.05..0.3);
    let g: f64 = rng.random_range(-0.15..0.15);
    let a: f64 = rng.random_range(0.0..std::f64::consts::TAU);
    let (cx, cy) = (s.x[0], s.y[0]);
    for k in 0..s.len() {
        let t = (s.x[k] - cx) * a.cos() + (s.y[k] - cy) * a.sin();
        let n: f64 = rng.sample(rand_distr::StandardNormal);
        let f = ((1.0 + sigma * n) * (1.0 + g * t)).clamp(0.2, 3.0);
        s.intensity[k] = (s.intensity[k] as f64 * f) as f32;
    }
}

fn percentile(v: &[f32], q: f64) -> f32 {
    if v.is_empty() {
        return 0.0;
    }
    let mut s = v.to_vec();
    let k = ((s.len() - 1) as f64 * q) as usize;
    let (_, m, _) = s.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
    *m
}

/// An `unknown` cluster: asphalt (label 0) points inside a distractor-like shape 1–4 m to the
/// side of a marking: a manhole disc, a sealant streak, or an irregular blob; intensities
/// raised to paint level (distractors are bright; the network sees only ratios anyway).
fn distractor(survey: &Survey, grid: &Grid, anchor: usize, j: usize, rng: &mut ChaCha8Rng) -> Option<Sample> {
    let cloud = &survey.cloud;
    let side: f64 = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    let a0: f64 = rng.random_range(0.0..std::f64::consts::TAU);
    let off: f64 = rng.random_range(1.0..4.0);
    let c = [
        cloud.x[anchor] + side * off * a0.cos(),
        cloud.y[anchor] + side * off * a0.sin(),
    ];
    let kind = rng.random_range(0..3);
    let mut found = Vec::new();
    let (name, keep): (&'static str, Keep) = match kind {
        0 => {
            let r: f64 = rng.random_range(0.3..0.45);
            grid.within(cloud, c[0], c[1], r, &mut found);
            ("manhole", Box::new(|_, _| true))
        }
        1 => {
            // A wavy streak: |v - amp·sin(k·u)| < w/2 over |u| < len/2.
            let len: f64 = rng.random_range(1.0..5.0);
            let w: f64 = rng.random_range(0.04..0.15);
            let amp: f64 = rng.random_range(0.0..0.3);
            let k: f64 = rng.random_range(0.5..3.0);
            let a: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            grid.within(cloud, c[0], c[1], len / 2.0 + amp + w, &mut found);
            let (ca, sa) = (a.cos(), a.sin());
            (
                "streak",
                Box::new(move |x: f64, y: f64| {
                    let (dx, dy) = (x - c[0], y - c[1]);
                    let (u, v) = (dx * ca + dy * sa, -dx * sa + dy * ca);
                    u.abs() < len / 2.0 && (v - amp * (k * u).sin()).abs() < w / 2.0
                }),
            )
        }
        _ => {
            // A blob: a disc with a radius varying with the angle.
            let r0: f64 = rng.random_range(0.15..0.8);
            let h: [f64; 3] = [
                rng.random_range(0.0..0.4),
                rng.random_range(0.0..0.3),
                rng.random_range(0.0..6.3),
            ];
            grid.within(cloud, c[0], c[1], r0 * 1.8, &mut found);
            (
                "blob",
                Box::new(move |x: f64, y: f64| {
                    let (dx, dy) = (x - c[0], y - c[1]);
                    let t = dy.atan2(dx);
                    dx.hypot(dy) < r0 * (1.0 + h[0] * (2.0 * t + h[2]).sin() + h[1] * (3.0 * t).cos())
                }),
            )
        }
    };
    found.retain(|&i| survey.labels[i] == 0 && keep(cloud.x[i], cloud.y[i]));
    if found.len() < MIN_POINTS {
        return None;
    }
    let level = cloud.intensity[anchor];
    let mut s = Sample {
        label: MarkingClass::Unknown,
        marking: format!("{name}{j}"),
        damage: vec![name],
        x: found.iter().map(|&i| cloud.x[i]).collect(),
        y: found.iter().map(|&i| cloud.y[i]).collect(),
        z: found.iter().map(|&i| cloud.z[i]).collect(),
        intensity: found
            .iter()
            .map(|&i| (level * rng.random_range(0.8f32..1.2)).max(cloud.intensity[i]))
            .collect(),
    };
    if rng.random_bool(0.5) {
        vary_intensity(&mut s, rng);
    }
    Some(s)
}

// ------------------------------------------------------------------------------------------
// Evaluation

fn evaluate(classifier: &Classifier, feats: &[f32], labels: &[u8]) -> Result<()> {
    let t0 = Instant::now();
    let preds = classifier.classify_features(feats, labels.len())?;
    let dt = t0.elapsed().as_secs_f64();
    let batches = labels.len().div_ceil(classifier.batch_size());
    println!(
        "classified {} clusters in {:.2} s on {} threads ({:.1} ms per batch of {}, {:.2} ms per cluster)",
        labels.len(),
        dt,
        rayon::current_num_threads(),
        1000.0 * dt / batches.max(1) as f64 * rayon::current_num_threads() as f64,
        classifier.batch_size(),
        1000.0 * dt / labels.len().max(1) as f64
    );
    let truth: Vec<usize> = labels.iter().map(|&l| l as usize).collect();
    let argmax: Vec<usize> = preds.iter().map(|p| argmax_class(p) as usize).collect();
    let decided: Vec<usize> = preds.iter().map(|p| p.class as usize).collect();
    println!("\n== argmax ==");
    print_report(&confusion(&truth, &argmax));
    println!(
        "\n== with the unknown threshold {:.3} (what the pipeline uses) ==",
        classifier.info().unknown_threshold
    );
    print_report(&confusion(&truth, &decided));
    Ok(())
}

fn argmax_class(p: &Prediction) -> MarkingClass {
    let mut best = 0;
    for i in 1..p.probs.len() {
        if p.probs[i] > p.probs[best] {
            best = i;
        }
    }
    MarkingClass::ALL[best]
}

/// cm[truth][prediction].
pub fn confusion(truth: &[usize], pred: &[usize]) -> Vec<Vec<usize>> {
    let k = CLASSES.len();
    let mut cm = vec![vec![0usize; k]; k];
    for (&t, &p) in truth.iter().zip(pred) {
        cm[t][p] += 1;
    }
    cm
}

/// Per-class (precision, recall, F1, support) and macro-F1 over the classes in the truth.
pub fn scores(cm: &[Vec<usize>]) -> (Vec<(f64, f64, f64, usize)>, f64) {
    let k = cm.len();
    let mut rows = Vec::with_capacity(k);
    let (mut sum_f, mut present) = (0.0, 0);
    for (c, row) in cm.iter().enumerate() {
        let tp = row[c] as f64;
        let support: usize = row.iter().sum();
        let predicted: usize = (0..k).map(|t| cm[t][c]).sum();
        let p = if predicted > 0 { tp / predicted as f64 } else { 0.0 };
        let r = if support > 0 { tp / support as f64 } else { 0.0 };
        let f = if p + r > 0.0 { 2.0 * p * r / (p + r) } else { 0.0 };
        if support > 0 {
            sum_f += f;
            present += 1;
        }
        rows.push((p, r, f, support));
    }
    (rows, if present > 0 { sum_f / present as f64 } else { 0.0 })
}

fn print_report(cm: &[Vec<usize>]) {
    let (rows, macro_f1) = scores(cm);
    println!(
        "{:<22}{:>10}{:>8}{:>8}{:>9}",
        "class", "precision", "recall", "F1", "support"
    );
    for (c, &(p, r, f, n)) in CLASSES.iter().zip(&rows) {
        let predicted: usize = cm.iter().map(|row| row[*c as usize]).sum();
        if n > 0 || predicted > 0 {
            println!("{:<22}{p:>10.4}{r:>8.4}{f:>8.4}{n:>9}", c.as_str());
        }
    }
    let total: usize = rows.iter().map(|r| r.3).sum();
    let correct: usize = (0..cm.len()).map(|i| cm[i][i]).sum();
    println!(
        "macro-F1 {macro_f1:.4}, accuracy {:.4}, {total} clusters",
        correct as f64 / total.max(1) as f64
    );
    println!("confusion matrix (rows = truth, columns = prediction):");
    print!("{:<22}", "");
    for c in CLASSES {
        print!("{:>7}", &c.as_str()[..c.as_str().len().min(6)]);
    }
    println!();
    for (c, row) in CLASSES.iter().zip(cm) {
        if row.iter().sum::<usize>() > 0 {
            print!("{:<22}", c.as_str());
            for v in row {
                print!("{v:>7}");
            }
            println!();
        }
    }
}

// ------------------------------------------------------------------------------------------
// .npy files (NumPy format 1.0: magic, header dict padded to 64 bytes, raw little-endian data)

fn npy_header(descr: &str, shape: &[usize]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape = if dims.len() == 1 {
        format!("({},)", dims[0])
    } else {
        format!("({})", dims.join(", "))
    };
    let dict = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
    // Fixed 128-byte header so a streamed file can be rewritten in place at the end.
    let mut h = b"\x93NUMPY\x01\x00".to_vec();
    let total = 128;
    let len = total - 10;
    h.extend_from_slice(&(len as u16).to_le_bytes());
    h.extend_from_slice(dict.as_bytes());
    while h.len() < total - 1 {
        h.push(b' ');
    }
    h.push(b'\n');
    h
}

/// Streams `[M, ...inner]` f32 rows into an .npy file; M is written at the end.
struct NpyF32Writer {
    file: BufWriter<File>,
    path: PathBuf,
    inner: [usize; 2],
    rows: usize,
}

impl NpyF32Writer {
    fn create(path: &Path, inner: [usize; 2]) -> Result<Self> {
        let mut file =
            BufWriter::new(File::create(path).with_context(|| format!("creating {}", path.display()))?);
        file.write_all(&npy_header("<f4", &[0, inner[0], inner[1]]))?;
        Ok(Self {
            file,
            path: path.to_path_buf(),
            inner,
            rows: 0,
        })
    }

    fn append(&mut self, values: &[f32]) -> Result<()> {
        let per = self.inner[0] * self.inner[1];
        assert_eq!(values.len() % per, 0);
        for v in values {
            self.file.write_all(&v.to_le_bytes())?;
        }
        self.rows += values.len() / per;
        Ok(())
    }

    fn finish(mut self) -> Result<usize> {
        self.file.seek(SeekFrom::Start(0))?;
        self.file
            .write_all(&npy_header("<f4", &[self.rows, self.inner[0], self.inner[1]]))?;
        self.file
            .flush()
            .with_context(|| format!("writing {}", self.path.display()))?;
        Ok(self.rows)
    }
}

fn write_npy_u8(path: &Path, v: &[u8]) -> Result<()> {
    let mut bytes = npy_header("|u1", &[v.len()]);
    bytes.extend_from_slice(v);
    std::fs::write(path, bytes).with_context(|| format!("writing {}", path.display()))
}

fn write_npy_u32(path: &Path, v: &[u32]) -> Result<()> {
    let mut bytes = npy_header("<u4", &[v.len()]);
    for x in v {
        bytes.extend_from_slice(&x.to_le_bytes());
    }
    std::fs::write(path, bytes).with_context(|| format!("writing {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seeds_parse_as_ranges_or_lists() {
        assert_eq!(parse_seeds("3..6").unwrap(), vec![3, 4, 5]);
        assert_eq!(parse_seeds("7, 9").unwrap(), vec![7, 9]);
        assert!(parse_seeds("5..5").is_err());
        assert!(parse_seeds("x").is_err());
    }

    #[test]
    fn npy_headers_are_aligned_and_rewritable() {
        let a = npy_header("<f4", &[0, 256, 4]);
        let b = npy_header("<f4", &[123_456_789, 256, 4]);
        assert_eq!(a.len(), 128);
        assert_eq!(b.len(), 128);
        assert!(String::from_utf8_lossy(&b).contains("'shape': (123456789, 256, 4)"));
        assert!(String::from_utf8_lossy(&npy_header("|u1", &[5])).contains("(5,)"));
    }

    #[test]
    fn scores_of_a_known_confusion_matrix() {
        let truth = [0, 0, 1, 1, 1, 11];
        let pred = [0, 1, 1, 1, 1, 11];
        let (rows, macro_f1) = scores(&confusion(&truth, &pred));
        assert!((rows[0].0 - 1.0).abs() < 1e-12 && (rows[0].1 - 0.5).abs() < 1e-12);
        assert!((rows[1].0 - 0.75).abs() < 1e-12 && (rows[1].1 - 1.0).abs() < 1e-12);
        let f0 = 2.0 * 0.5 / 1.5;
        let f1 = 2.0 * 0.75 / 1.75;
        assert!((macro_f1 - (f0 + f1 + 1.0) / 3.0).abs() < 1e-12);
    }
}
