//! The pipeline driver: read → (per chunk) pavement → rasterize → threshold → cluster →
//! classify → vectorize, then lane lines over the whole drive.
//!
//! **Algorithm.**
//! 1. *read*: the trajectory is read and made local to the job origin (its first pose,
//!    floored to whole metres). Tiles are streamed; every point is located on the
//!    trajectory (kd-tree [`StationIndex`], in parallel) and kept when it lies within
//!    `pavement.max_offset_m` of it, then appended to the chunks that see its mileage
//!    ([`chunk::Store`], spilling to disk beyond `chunk.memory_budget_mb`). Decoding,
//!    locating and appending overlap: batch b + 2 is decoded while b + 1 is located and
//!    b appended.
//! 2. Per chunk: pavement, background normalisation + IDW, adaptive threshold, the verge
//!    check ([`pavement_verge`]), and the marking points of the chunk's *core* (each point
//!    belongs to exactly one core, so no point is counted twice). Chunks are taken in
//!    groups of `IN_FLIGHT`, computed side by side and while the previous group goes
//!    through steps 3–4; every result is consumed in mileage order.
//! 3. *cluster*: marking points are clustered across chunk joins by a streaming scheme:
//!    clusters that come within `JOIN_MARGIN_M` of the next core stay open and are
//!    re-clustered with the next chunk's points; the others are complete. Points are put in
//!    a canonical order (by coordinates) first, so the clusters do not depend on where the
//!    chunk edges fell. Clusters longer than `PIECE_M` along the trajectory are cut at
//!    global multiples of it (solid-line pieces; the lane-line stage joins them), which
//!    bounds the memory of open clusters on endless solid lines. Complete short clusters
//!    linked to an open one (points ≤ `LINK_M` apart, directly or through each other)
//!    wait for it, so the pieces of one painted object go to step 4 together.
//! 4. *classify* + *vectorize* complete clusters into markings (absolute coordinates),
//!    then lane lines are linked once over all markings.
//!
//! Everything is deterministic: parallel stages reduce in a fixed order and RANSAC is
//! seeded per slice.

use super::chunk::{ChunkPoints, Plan, Store};
use super::error::PipelineError;
use super::params::ValidParams;
use super::types::{Crs, Extraction, PointCloud, StationIndex, Trajectory};
use super::{
    Inputs, Progress, classify, cluster, geom, io, observed, pavement, pavement_verge, rasterize, threshold,
    vectorize,
};
use rayon::prelude::*;
use std::time::Instant;

/// Clusters reaching this close (mileage) to the next core stay open (m).
pub const JOIN_MARGIN_M: f64 = 2.5;
/// Clusters longer than this along the trajectory are cut at its global multiples (m).
pub const PIECE_M: f64 = 250.0;
/// Chunks whose marking points are computed side by side (see [`run_ctx`]); each holds
/// its points and stage buffers, so this bounds the extra memory.
const IN_FLIGHT: usize = 2;

/// Stable stage names, in pipeline order.
pub const STAGES: [&str; 7] = [
    "read",
    "pavement",
    "rasterize",
    "threshold",
    "cluster",
    "classify",
    "vectorize",
];

/// Counters and timings of one run (for the summary line and `roadmark bench`).
#[derive(Clone, Debug, Default)]
pub struct RunStats {
    /// Points read from the tiles.
    pub points_read: u64,
    /// Points within `max_offset_m` of the trajectory (what the chunks hold, without
    /// overlap duplicates).
    pub points_near_track: u64,
    /// Points processed by the chunk stages (overlaps counted in every chunk).
    pub points_processed: u64,
    pub pavement_points: u64,
    pub marking_points: u64,
    pub clusters: u64,
    pub chunks: usize,
    pub spilled_points: u64,
    /// Wall-clock seconds per stage, in [`STAGES`] order. Neighbouring chunks are
    /// processed at the same time (module docs, step 2), so the stages' sum can exceed
    /// `total_seconds`.
    pub stage_seconds: [f64; 7],
    pub total_seconds: f64,
}

impl RunStats {
    fn add(&mut self, stage: usize, t0: Instant) {
        self.stage_seconds[stage] += t0.elapsed().as_secs_f64();
    }

    /// Add the counters and stage times of one chunk's marking points.
    fn merge_chunk(&mut self, c: &ChunkMarks) {
        self.points_processed += c.points_processed;
        self.pavement_points += c.pavement_points;
        self.marking_points += c.cloud.len() as u64;
        for (a, b) in self.stage_seconds.iter_mut().zip(&c.stage_seconds) {
            *a += b;
        }
    }
}

/// The marking points of one chunk's core (job-local coordinates), their mileages, and
/// what computing them counted and took.
struct ChunkMarks {
    cloud: PointCloud,
    mileage: Vec<f64>,
    points_processed: u64,
    /// Pavement points of the core.
    pavement_points: u64,
    /// Seconds of the pavement, rasterize and threshold stages (in [`STAGES`] order).
    stage_seconds: [f64; 7],
    /// Dark pavement points of the core by cell (see [`observed`]).
    dark: observed::DarkRows,
}

impl ChunkMarks {
    fn empty(origin: [f64; 3]) -> Self {
        Self {
            cloud: PointCloud::with_origin(origin),
            mileage: Vec::new(),
            points_processed: 0,
            pavement_points: 0,
            stage_seconds: [0.0; 7],
            dark: observed::DarkRows::default(),
        }
    }
}

struct Ctx<'a> {
    params: &'a ValidParams,
    progress: &'a dyn Progress,
    stats: RunStats,
    /// When set, every marking point is also appended here (job-local coordinates).
    collect: Option<PointCloud>,
}

impl Ctx<'_> {
    fn check(&self) -> Result<(), PipelineError> {
        if self.progress.is_cancelled() {
            Err(PipelineError::Cancelled)
        } else {
            Ok(())
        }
    }
}

/// Fractions of the whole job: reading, chunk processing, final linking.
const READ_SHARE: f64 = 0.3;
const CHUNK_SHARE: f64 = 0.65;

/// Run the whole pipeline and return the extraction with its statistics.
pub fn run_with_stats(
    inputs: &Inputs,
    params: &ValidParams,
    progress: &dyn Progress,
) -> Result<(Extraction, RunStats), PipelineError> {
    let mut ctx = Ctx {
        params,
        progress,
        stats: RunStats::default(),
        collect: None,
    };
    let ex = run_ctx(&mut ctx, inputs)?;
    Ok((ex, ctx.stats))
}

/// Run the pipeline and also return every marking point (absolute coordinates in the
/// returned cloud's `origin` + local), for per-point evaluation against labelled data.
pub fn run_collecting_marking_points(
    inputs: &Inputs,
    params: &ValidParams,
    progress: &dyn Progress,
) -> Result<(Extraction, PointCloud), PipelineError> {
    let (ex, _, marks) = run_collecting_with_stats(inputs, params, progress)?;
    Ok((ex, marks))
}

/// [`run_collecting_marking_points`] with the run's statistics.
pub fn run_collecting_with_stats(
    inputs: &Inputs,
    params: &ValidParams,
    progress: &dyn Progress,
) -> Result<(Extraction, RunStats, PointCloud), PipelineError> {
    let mut ctx = Ctx {
        params,
        progress,
        stats: RunStats::default(),
        collect: Some(PointCloud::default()),
    };
    let ex = run_ctx(&mut ctx, inputs)?;
    let marks = ctx.collect.take().unwrap_or_default();
    Ok((ex, ctx.stats, marks))
}

fn run_ctx(ctx: &mut Ctx<'_>, inputs: &Inputs) -> Result<Extraction, PipelineError> {
    let t_start = Instant::now();
    let params = ctx.params;
    if inputs.points.is_empty() {
        return Err(PipelineError::Params("no point files given".into()));
    }
    ctx.progress.report("read", 0.0);
    let t0 = Instant::now();
    let traj_abs = io::read_trajectory(&inputs.trajectory)?;
    let first = traj_abs.poses()[0];
    let origin = [
        first.x.floor(),
        first.y.floor(),
        if first.z.is_finite() { first.z.floor() } else { 0.0 },
    ];
    let traj = traj_abs.to_local(origin);
    let max_off = params.pavement.max_offset_m;
    let plan = Plan::new(params, -max_off, traj.length_m() + max_off);
    let mut store = Store::new(plan, params.chunk.memory_budget_mb);
    let crs = read_into(ctx, inputs, origin, &traj, &mut store)?;
    ctx.stats.add(0, t0);
    ctx.stats.spilled_points = store.spilled_points;
    ctx.check()?;

    // Per chunk: points → marking points of the core → complete clusters → markings.
    // Chunks go in groups of IN_FLIGHT: while the clusters of one group are completed,
    // classified and outlined (mostly serial work, in chunk order), the marking points of
    // the next group's chunks are computed side by side, so the serial parts of each fill
    // the core the others leave idle. Results are merged in chunk order, so nothing
    // depends on the overlap.
    let mut streaming = Streaming::default();
    let mut seen = observed::Observed::new(traj.clone(), origin, max_off);
    let mut pieces: Vec<vectorize::Piece> = Vec::new();
    let n_chunks = plan.count();
    ctx.stats.chunks = n_chunks;
    let (params, progress) = (ctx.params, ctx.progress);
    let step = CHUNK_SHARE / n_chunks as f64;
    let base_of = |ci: usize| READ_SHARE + CHUNK_SHARE * ci as f64 / n_chunks as f64;
    // Marking points of chunks lo..hi (indices from the plan's first), side by side.
    let group_marks = |lo: usize, group: Vec<ChunkPoints>| -> Result<Vec<ChunkMarks>, PipelineError> {
        group
            .into_par_iter()
            .enumerate()
            .map(|(j, pts)| {
                let ci = lo + j;
                if pts.is_empty() {
                    return Ok(ChunkMarks::empty(origin));
                }
                let core = plan.core(plan.first + ci as i64);
                marking_points(params, progress, &pts, origin, core, base_of(ci), step)
            })
            .collect()
    };
    let mut take_group =
        |lo: usize, hi: usize, stats: &mut RunStats| -> Result<Vec<ChunkPoints>, PipelineError> {
            let t0 = Instant::now();
            let group = (lo..hi)
                .map(|ci| store.take(plan.first + ci as i64))
                .collect::<Result<Vec<_>, _>>();
            stats.add(0, t0);
            group
        };
    let first = take_group(0, IN_FLIGHT.min(n_chunks), &mut ctx.stats)?;
    let mut ready = group_marks(0, first)?;
    let mut lo = 0;
    while lo < n_chunks {
        let hi = (lo + IN_FLIGHT).min(n_chunks);
        let next_hi = (hi + IN_FLIGHT).min(n_chunks);
        let next_pts = take_group(hi, next_hi, &mut ctx.stats)?;
        let cur = std::mem::take(&mut ready);
        let (next, done) = rayon::join(
            || group_marks(hi, next_pts),
            || -> Result<Vec<vectorize::Piece>, PipelineError> {
                let mut out = Vec::new();
                for (j, cm) in cur.into_iter().enumerate() {
                    let ci = lo + j;
                    let base = base_of(ci);
                    ctx.stats.merge_chunk(&cm);
                    seen.add(&cm.dark);
                    ctx.progress.report("cluster", base + 0.8 * step);
                    let t0 = Instant::now();
                    let last = ci + 1 == n_chunks;
                    let (_, core_hi) = plan.core(plan.first + ci as i64);
                    let ChunkMarks {
                        cloud: marks,
                        mileage: marks_m,
                        ..
                    } = cm;
                    if let Some(all) = ctx.collect.as_mut() {
                        if all.is_empty() {
                            *all = PointCloud::with_origin(origin);
                        }
                        all.extend_from(&marks);
                    }
                    let complete =
                        streaming.feed(marks, marks_m, (!last).then_some(core_hi), cluster_groups, params);
                    ctx.stats.clusters += complete.len() as u64;
                    ctx.stats.add(4, t0);
                    ctx.check()?;
                    ctx.progress.report("classify", base + 0.9 * step);
                    out.extend(finish_clusters(ctx, complete, &traj, origin)?);
                    ctx.check()?;
                }
                Ok(out)
            },
        );
        pieces.extend(done?);
        ready = next?;
        lo = hi;
    }

    // Lane lines over the whole drive, class corrections, stable ids in driving order.
    ctx.progress.report("vectorize", READ_SHARE + CHUNK_SHARE);
    let t0 = Instant::now();
    let (markings, lane_lines) =
        vectorize::assemble(pieces, &traj_abs, &params.vectorize, Some(&seen.lookup()));
    ctx.stats.add(6, t0);
    ctx.progress.report("vectorize", 1.0);
    ctx.stats.total_seconds = t_start.elapsed().as_secs_f64();
    Ok(Extraction {
        markings,
        lane_lines,
        crs,
    })
}

/// Stream every tile into the chunk store; returns the CRS of the first tile that has one.
///
/// This thread decodes the next batch while a worker locates the one before (in parallel
/// blocks, each walking from point to point along the trajectory, see
/// [`StationIndex::locate_near`]) and, at the same time, appends the one before that to
/// the chunks.
fn read_into(
    ctx: &mut Ctx<'_>,
    inputs: &Inputs,
    origin: [f64; 3],
    traj: &Trajectory,
    store: &mut Store,
) -> Result<Option<Crs>, PipelineError> {
    let index = StationIndex::new(traj, 1.0);
    let max_off = ctx.params.pavement.max_offset_m;
    let (m_lo, m_hi) = (-max_off, traj.length_m() + max_off);
    let need_intensity = ctx.params.threshold.method != threshold::Method::None;
    let mut crs: Option<Crs> = None;
    let total: u64 = inputs
        .points
        .iter()
        .map(|p| io::inspect_points(p).map(|s| s.point_count))
        .sum::<Result<u64, _>>()?
        .max(1);
    for path in &inputs.points {
        ctx.check()?;
        let mut reader = io::PointReader::open(path)?;
        reader.set_origin(origin);
        if crs.is_none() {
            crs = reader.crs().cloned();
        }
        let chunk = reader.preferred_chunk().max(1 << 18);
        // This thread decodes; a worker locates one batch while it stores the one before
        // (rayon::join: appending to the chunks is serial, locating is parallel).
        // Buffers go round between the two through a pair of channels.
        let (full_tx, full_rx) = std::sync::mpsc::sync_channel::<PointCloud>(1);
        let (empty_tx, empty_rx) = std::sync::mpsc::sync_channel::<PointCloud>(BATCHES);
        for _ in 0..BATCHES {
            empty_tx.send(PointCloud::default()).expect("receiver alive");
        }
        let index = &index;
        let (res, near) = std::thread::scope(|sc| {
            let store = &mut *store;
            let worker = sc.spawn(move || -> Result<u64, PipelineError> {
                let keep = |m: f64, o: f64| o.abs() <= max_off && m >= m_lo && m <= m_hi;
                let mut near = 0;
                // The located batch waiting to be stored, and a spare pair of station columns.
                let mut located: Option<(PointCloud, Stations)> = None;
                let mut spare = Stations::default();
                for batch in full_rx.iter() {
                    let mut st = std::mem::take(&mut spare);
                    let (_, stored) = rayon::join(
                        || locate_batch(&batch, index, &mut st),
                        || {
                            located.take().map(|(b, s)| {
                                let n = store.push_cloud(&b, &s.mileage, &s.offset, keep);
                                (b, s, n, store.maybe_spill())
                            })
                        },
                    );
                    located = Some((batch, st));
                    if let Some((b, s, n, spilled)) = stored {
                        near += n;
                        spilled?;
                        spare = s;
                        if empty_tx.send(b).is_err() {
                            return Ok(near);
                        }
                    }
                }
                if let Some((b, s)) = located {
                    near += store.push_cloud(&b, &s.mileage, &s.offset, keep);
                    store.maybe_spill()?;
                }
                Ok(near)
            });
            let mut run = || -> Result<u64, PipelineError> {
                let mut n_tile = 0u64;
                // A closed channel means the worker stopped on an error (reported below).
                while let Ok(mut batch) = empty_rx.recv() {
                    if reader.next_chunk(&mut batch, chunk)? == 0 {
                        break;
                    }
                    n_tile += batch.len() as u64;
                    ctx.stats.points_read += batch.len() as u64;
                    ctx.progress
                        .report("read", READ_SHARE * ctx.stats.points_read as f64 / total as f64);
                    ctx.check()?;
                    if full_tx.send(batch).is_err() {
                        break;
                    }
                }
                Ok(n_tile)
            };
            let res = run();
            drop(full_tx);
            let near = worker.join().expect("the locating thread does not panic");
            (res, near)
        });
        ctx.stats.points_near_track += near?;
        let n_tile = res?;
        let nonzero = reader.nonzero_intensity_count();
        if need_intensity && n_tile > 0 && nonzero == 0 {
            return Err(PipelineError::input(
                path,
                "has no intensity values (all zero); marking extraction needs intensity",
            ));
        }
    }
    if ctx.stats.points_near_track == 0 && ctx.stats.points_read > 0 {
        return Err(PipelineError::input(
            &inputs.trajectory,
            format!(
                "no point lies within {max_off} m of this trajectory (another drive, or a different CRS?)"
            ),
        ));
    }
    Ok(crs)
}

/// Points per block located by one walk (the first point of a block asks the kd-tree).
const LOCATE_BLOCK: usize = 8192;
/// Point buffers going round between the reading thread and the locating worker: one
/// being decoded, one waiting, one being located, one being stored.
const BATCHES: usize = 4;

/// Mileage and offset of every point of a batch.
#[derive(Default)]
struct Stations {
    mileage: Vec<f64>,
    offset: Vec<f64>,
}

/// Locate a batch on the trajectory (parallel blocks, each walking from point to point).
fn locate_batch(cloud: &PointCloud, index: &StationIndex<'_>, st: &mut Stations) {
    let n = cloud.len();
    st.mileage.resize(n, 0.0);
    st.offset.resize(n, 0.0);
    st.mileage
        .par_chunks_mut(LOCATE_BLOCK)
        .zip(st.offset.par_chunks_mut(LOCATE_BLOCK))
        .enumerate()
        .for_each(|(b, (ms, os))| {
            let base = b * LOCATE_BLOCK;
            let mut hint = usize::MAX;
            for (j, (m, o)) in ms.iter_mut().zip(os.iter_mut()).enumerate() {
                let s = index.locate_near(cloud.x[base + j], cloud.y[base + j], &mut hint);
                (*m, *o) = (s.mileage_m, s.offset_m);
            }
        });
}

/// Pavement → rasterize → threshold for one chunk; returns the marking points of its core
/// (job-local coordinates) and their mileages. Needs no `Ctx`, so that it can run while
/// the previous chunk's clusters are finished.
fn marking_points(
    p: &ValidParams,
    progress: &dyn Progress,
    c: &ChunkPoints,
    origin: [f64; 3],
    (core_lo, core_hi): (f64, f64),
    base: f64,
    step: f64,
) -> Result<ChunkMarks, PipelineError> {
    let mut out = ChunkMarks::empty(origin);
    let check = || {
        if progress.is_cancelled() {
            Err(PipelineError::Cancelled)
        } else {
            Ok(())
        }
    };
    let add = |out: &mut ChunkMarks, stage: usize, t0: Instant| {
        out.stage_seconds[stage] += t0.elapsed().as_secs_f64();
    };
    out.points_processed = c.len() as u64;
    progress.report("pavement", base);
    let t0 = Instant::now();
    let has_time = c.gps_time.iter().all(|t| t.is_finite());
    let pav = pavement::run(
        &pavement::Input {
            x: &c.x,
            y: &c.y,
            z: &c.z,
            mileage: &c.mileage,
            offset: &c.offset,
            gps_time: has_time.then_some(c.gps_time.as_slice()),
            scanner: &c.scanner,
        },
        &p.pavement,
    );
    // Pavement points of the core count once (overlaps are seen by two chunks).
    out.pavement_points = pav
        .iter()
        .filter(|&&i| c.mileage[i] >= core_lo && c.mileage[i] < core_hi)
        .count() as u64;
    add(&mut out, 1, t0);
    check()?;

    let (is_mark, contrast): (Vec<bool>, Option<Vec<f32>>) = match p.threshold.method {
        threshold::Method::None => (vec![true; pav.len()], None),
        threshold::Method::Adaptive => {
            progress.report("rasterize", base + 0.25 * step);
            let t0 = Instant::now();
            // Columns of the pavement points, gathered in parallel (one pass each).
            let gather_f64 = |v: &[f64]| pav.par_iter().map(|&i| v[i]).collect::<Vec<f64>>();
            // The raster lives in trajectory coordinates (x = mileage, y = offset): lines run
            // along its rows, the along-track detector is a separable filter, and the grid
            // is global along the drive.
            // Only the mask lives in this frame: the marking points handed on keep their
            // local x/y (see the end of this function), which cluster/classify/vectorize use.
            let (px, offs) = (gather_f64(&c.mileage), gather_f64(&c.offset));
            let py = &offs;
            let slice: Vec<i64> = pav
                .par_iter()
                .map(|&i| pavement::slice_of(c.mileage[i], p.pavement.slice_length_m))
                .collect();
            let intensity: Vec<f32> = pav.par_iter().map(|&i| c.intensity[i]).collect();
            let scanner: Vec<u8> = pav.par_iter().map(|&i| c.scanner[i]).collect();
            let values = rasterize::normalise(
                &rasterize::BackgroundInput {
                    intensity: &intensity,
                    scanner: &scanner,
                    slice: &slice,
                    offset: &offs,
                },
                &p.rasterize,
            );
            out.dark = observed::dark_rows(&px, py, &values, (core_lo, core_hi), p.pavement.max_offset_m);
            let raster = rasterize::idw(&px, py, &values, &p.rasterize);
            add(&mut out, 2, t0);
            check()?;
            progress.report("threshold", base + 0.5 * step);
            let t0 = Instant::now();
            let seg = threshold::segment(&raster, &p.threshold);
            drop(raster);
            let mut marks = threshold::points_from_mask(&seg, &px, py, &values, &p.threshold);
            threshold::rescue_sparse_lines(&px, py, &values, &mut marks, &p.threshold);
            let z = gather_f64(&c.z);
            threshold::clear_unflat(&px, py, &z, &mut marks, &p.threshold);
            // Bright verge beyond the asphalt: candidates lying below the road beside them.
            let label: Vec<u32> = px
                .par_iter()
                .zip(py.par_iter())
                .map(|(&x, &y)| {
                    seg.mask
                        .cell_of(x, y)
                        .map_or(0, |(col, row)| seg.labels[row * seg.mask.width + col])
                })
                .collect();
            pavement_verge::clear_verge(
                &pavement_verge::Input {
                    mileage: &px,
                    offset: py,
                    z: &z,
                    slice: &slice,
                    label: &label,
                },
                &mut marks,
                &p.pavement.verge,
            );
            add(&mut out, 3, t0);
            check()?;
            (marks, Some(values))
        }
    };
    // (position among the pavement points, index in the chunk) of the core's marking points.
    let (at, idx): (Vec<usize>, Vec<usize>) = pav
        .iter()
        .zip(&is_mark)
        .enumerate()
        .filter(|&(_, (&i, &m))| m && c.mileage[i] >= core_lo && c.mileage[i] < core_hi)
        .map(|(k, (&i, _))| (k, i))
        .unzip();
    let cloud = &mut out.cloud;
    cloud.x = idx.iter().map(|&i| c.x[i]).collect();
    cloud.y = idx.iter().map(|&i| c.y[i]).collect();
    cloud.z = idx.iter().map(|&i| c.z[i]).collect();
    cloud.intensity = idx.iter().map(|&i| c.intensity[i]).collect();
    cloud.gps_time = has_time.then(|| idx.iter().map(|&i| c.gps_time[i]).collect());
    cloud.scanner = idx.iter().map(|&i| c.scanner[i]).collect();
    cloud.contrast = contrast.map(|v| at.iter().map(|&k| v[k]).collect());
    out.mileage = idx.iter().map(|&i| c.mileage[i]).collect();
    Ok(out)
}

// ---------------------------------------------------------------------------------------
// Streaming clusters across chunk joins
// ---------------------------------------------------------------------------------------

/// One complete cluster (or piece of a long one): its points and their mileages.
pub struct Complete {
    pub points: PointCloud,
    pub mileage: Vec<f64>,
}

/// Open clusters carried from one chunk to the next.
#[derive(Default)]
pub struct Streaming {
    open: Option<PointCloud>,
    open_m: Vec<f64>,
    /// Per open point: its cluster was already longer than [`PIECE_M`] (so it is cut at
    /// the piece grid even if the rest alone is shorter).
    open_long: Vec<bool>,
    /// Complete short clusters held back because they lie within [`LINK_M`] of an open
    /// cluster (see [`Streaming::feed`]).
    deferred: Vec<Complete>,
}

impl Streaming {
    /// Add the marking points of the next core. `frontier` is the end of that core
    /// (`None` for the last chunk: everything completes). `cluster` partitions a cloud.
    pub fn feed(
        &mut self,
        new: PointCloud,
        new_m: Vec<f64>,
        frontier: Option<f64>,
        cluster: impl Fn(&PointCloud, &ValidParams) -> Vec<Vec<usize>>,
        params: &ValidParams,
    ) -> Vec<Complete> {
        let (mut all, mut all_m, mut all_long) = match self.open.take() {
            Some(open) => (
                open,
                std::mem::take(&mut self.open_m),
                std::mem::take(&mut self.open_long),
            ),
            None => (PointCloud::with_origin(new.origin), Vec::new(), Vec::new()),
        };
        all.extend_from(&new);
        all_m.extend_from_slice(&new_m);
        all_long.resize(all_m.len(), false);
        if all.is_empty() {
            return Vec::new();
        }
        // Canonical order: the same points give the same input to `cluster` whatever
        // the chunking.
        let mut order: Vec<usize> = (0..all.len()).collect();
        order.sort_by(|&a, &b| {
            all.x[a]
                .total_cmp(&all.x[b])
                .then(all.y[a].total_cmp(&all.y[b]))
                .then(all.z[a].total_cmp(&all.z[b]))
                .then(all.intensity[a].total_cmp(&all.intensity[b]))
        });
        let all = all.select(&order);
        let all_m: Vec<f64> = order.iter().map(|&i| all_m[i]).collect();
        let all_long: Vec<bool> = order.iter().map(|&i| all_long[i]).collect();
        let groups = cluster(&all, params);

        let mut complete = Vec::new();
        let mut short = std::mem::take(&mut self.deferred);
        let mut keep: Vec<usize> = Vec::new();
        let mut long_groups: Vec<Vec<usize>> = Vec::new();
        for g in groups {
            let lo = g.iter().map(|&i| all_m[i]).fold(f64::INFINITY, f64::min);
            let hi = g.iter().map(|&i| all_m[i]).fold(f64::NEG_INFINITY, f64::max);
            let long = hi - lo > PIECE_M || g.iter().any(|&i| all_long[i]);
            let open = frontier.is_some_and(|f| hi >= f - JOIN_MARGIN_M);
            if !open {
                // Complete: cut at the piece grid when long.
                if long {
                    complete.extend(pieces(&all, &all_m, &g, true));
                } else {
                    short.extend(pieces(&all, &all_m, &g, false));
                }
                continue;
            }
            let f = frontier.expect("open implies a frontier");
            if long {
                // Parts below a grid line that lies behind the join margin are final.
                let safe = ((f - JOIN_MARGIN_M) / PIECE_M).floor() * PIECE_M;
                let (done, rest): (Vec<usize>, Vec<usize>) = g.iter().partition(|&&i| all_m[i] < safe);
                complete.extend(pieces(&all, &all_m, &done, true));
                keep.extend(rest.iter().copied());
                long_groups.push(rest);
            } else {
                keep.extend(g);
            }
        }
        keep.sort_unstable();
        self.open_m = keep.iter().map(|&i| all_m[i]).collect();
        // Points of clusters that were long stay marked (see `open_long`).
        let mut long_pt = vec![false; all.len()];
        for g in &long_groups {
            for &i in g {
                long_pt[i] = true;
            }
        }
        self.open_long = keep.iter().map(|&i| long_pt[i]).collect();
        let open = all.select(&keep);
        // Short clusters beside an open one wait for it, so the pieces of one painted
        // object that fell into several clusters (an arrow's branch that touches an edge
        // line and broke off its shaft) reach the classify stage in one batch, which
        // groups such pieces (`classify::group_fragments`).
        let wait = linked_to(&open, &short);
        for (c, wait) in short.into_iter().zip(wait) {
            if wait {
                self.deferred.push(c);
            } else {
                complete.push(c);
            }
        }
        self.open = Some(open);
        complete
    }
}

/// Clusters this close (m, nearest points) to an open cluster wait for it (see
/// [`Streaming::feed`]); the gap of `classify::group_fragments`.
const LINK_M: f64 = 0.5;

/// Per cluster: whether it is linked to `open` through points at most [`LINK_M`] apart
/// (directly or through other clusters).
fn linked_to(open: &PointCloud, clusters: &[Complete]) -> Vec<bool> {
    if open.is_empty() || clusters.is_empty() {
        return vec![false; clusters.len()];
    }
    // Points: each cluster's with its owner, then the open ones (None) that lie in a
    // LINK_M cell next to a cluster point's: only those can link a cluster to the open
    // ones, and the open clusters hold up to PIECE_M of every line.
    let cell = |x: f64, y: f64| (geom::floor_i64(x / LINK_M), geom::floor_i64(y / LINK_M));
    let mut xy: Vec<[f64; 2]> = Vec::new();
    let mut owner: Vec<Option<usize>> = Vec::new();
    let mut near = std::collections::HashSet::new();
    for (k, c) in clusters.iter().enumerate() {
        for (&x, &y) in c.points.x.iter().zip(&c.points.y) {
            xy.push([x, y]);
            owner.push(Some(k));
            let (cx, cy) = cell(x, y);
            near.extend((cx - 1..=cx + 1).flat_map(|i| (cy - 1..=cy + 1).map(move |j| (i, j))));
        }
    }
    for (&x, &y) in open.x.iter().zip(&open.y) {
        if near.contains(&cell(x, y)) {
            xy.push([x, y]);
            owner.push(None);
        }
    }
    let mut wait = vec![false; clusters.len()];
    for comp in geom::components(&xy, LINK_M) {
        if comp.iter().any(|&i| owner[i].is_none()) {
            for &i in &comp {
                if let Some(k) = owner[i] {
                    wait[k] = true;
                }
            }
        }
    }
    wait
}

/// A group as one complete cluster, or cut into pieces at multiples of [`PIECE_M`].
fn pieces(all: &PointCloud, m: &[f64], g: &[usize], cut: bool) -> Vec<Complete> {
    if g.is_empty() {
        return Vec::new();
    }
    let mut parts: std::collections::BTreeMap<i64, Vec<usize>> = Default::default();
    for &i in g {
        let key = if cut { (m[i] / PIECE_M).floor() as i64 } else { 0 };
        parts.entry(key).or_default().push(i);
    }
    parts
        .into_values()
        .map(|idx| Complete {
            points: all.select(&idx),
            mileage: idx.iter().map(|&i| m[i]).collect(),
        })
        .collect()
}

// ---------------------------------------------------------------------------------------
// Adapter to the cluster / classify / vectorize stages
// ---------------------------------------------------------------------------------------

/// Partition marking points into clusters (indices into `cloud`).
fn cluster_groups(cloud: &PointCloud, params: &ValidParams) -> Vec<Vec<usize>> {
    cluster::run(cloud, &params.cluster)
        .into_iter()
        .map(|c| c.indices)
        .collect()
}

/// Classify and outline the complete clusters of one chunk (pieces in absolute
/// coordinates; lane lines and ids come once for the whole drive in `assemble`).
fn finish_clusters(
    ctx: &mut Ctx<'_>,
    complete: Vec<Complete>,
    traj: &Trajectory,
    origin: [f64; 3],
) -> Result<Vec<vectorize::Piece>, PipelineError> {
    if complete.is_empty() {
        return Ok(Vec::new());
    }
    let t0 = Instant::now();
    let p = ctx.params;
    // One cloud of all complete clusters, each a cluster of consecutive indices.
    let mut cloud = PointCloud::with_origin(origin);
    let mut clusters = Vec::with_capacity(complete.len());
    for c in &complete {
        let start = cloud.len();
        cloud.extend_from(&c.points);
        clusters.push(as_cluster(&cloud, start..cloud.len()));
    }
    drop(complete);
    // The classifier's reference line only needs the trajectory around these clusters.
    let (mut candidates, fragments) = classify::run_with_fragments(&cloud, &clusters, traj, &p.classify);
    // The learned classifier takes the candidates the geometric rules could not decide.
    super::learned::refine(&mut candidates, &cloud, &p.learned, &p.classify)?;
    classify::drop_thin_strokes(&mut candidates, &p.classify);
    ctx.stats.add(5, t0);
    let t0 = Instant::now();
    let mut pieces = vectorize::outlines(&cloud, &candidates, &p.vectorize);
    pieces.extend(
        vectorize::outlines(&cloud, &fragments, &p.vectorize)
            .into_iter()
            .map(|q| vectorize::Piece { fragment: true, ..q }),
    );
    ctx.stats.add(6, t0);
    Ok(pieces)
}

/// A [`cluster::Cluster`] over a range of `cloud`'s points.
fn as_cluster(cloud: &PointCloud, range: std::ops::Range<usize>) -> cluster::Cluster {
    let n = range.len().max(1) as f64;
    let (mut sx, mut sy, mut si) = (0.0, 0.0, 0.0f64);
    let mut bounds = [[f64::INFINITY; 2], [f64::NEG_INFINITY; 2]];
    for i in range.clone() {
        let p = [cloud.x[i], cloud.y[i]];
        sx += p[0];
        sy += p[1];
        si += cloud.intensity[i] as f64;
        for k in 0..2 {
            bounds[0][k] = bounds[0][k].min(p[k]);
            bounds[1][k] = bounds[1][k].max(p[k]);
        }
    }
    cluster::Cluster {
        indices: range.collect(),
        centroid: [sx / n, sy / n],
        bounds,
        mean_intensity: (si / n) as f32,
        split: false,
    }
}

/// Streaming clusters give the same partition whatever the chunk edges (used by tests).
#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::params::Params;

    fn cloud(pts: &[(f64, f64)]) -> PointCloud {
        let mut c = PointCloud::with_origin([0.0; 3]);
        for &(x, y) in pts {
            c.push_local(x, y, 0.0, 100.0, None, 0);
        }
        c
    }

    /// Clusters as sorted lists of x coordinates (×1000, rounded), for comparing runs.
    fn signature(done: &[Complete]) -> Vec<Vec<i64>> {
        let mut s: Vec<Vec<i64>> = done
            .iter()
            .map(|c| {
                let mut v: Vec<i64> = c.points.x.iter().map(|x| (x * 1000.0).round() as i64).collect();
                v.sort_unstable();
                v
            })
            .collect();
        s.sort();
        s
    }

    fn run_chunked(pts: &[(f64, f64)], len: f64) -> Vec<Vec<i64>> {
        let params = Params::default().validate().unwrap();
        let mut st = Streaming::default();
        let mut done = Vec::new();
        let end = pts.iter().map(|p| p.0).fold(0.0, f64::max);
        let mut lo = 0.0;
        while lo <= end {
            let hi = lo + len;
            let sel: Vec<(f64, f64)> = pts.iter().copied().filter(|p| p.0 >= lo && p.0 < hi).collect();
            let m: Vec<f64> = sel.iter().map(|p| p.0).collect();
            let last = hi > end;
            done.extend(st.feed(cloud(&sel), m, (!last).then_some(hi), cluster_groups, &params));
            lo = hi;
        }
        signature(&done)
    }

    /// An arrow beside an edge line: its turning branch touches the line (so it is part of
    /// the line's cluster, which runs on and completes piece by piece), its shaft lies 0.4
    /// m from the branch. The shaft waits for the line piece that holds the branch, so both
    /// reach the classify stage in one batch; without the wait it went four feeds earlier.
    #[test]
    fn a_cluster_beside_an_open_one_completes_with_it() {
        let mut pts = Vec::new();
        for i in 0..30_000 {
            pts.push((i as f64 * 0.02, 0.0));
        }
        for i in 1..=50 {
            pts.push((100.0, i as f64 * 0.02)); // branch, on the line
        }
        for i in 0..=150 {
            pts.push((100.0 + i as f64 * 0.02, 1.4)); // shaft
        }
        let params = Params::default().validate().unwrap();
        let mut st = Streaming::default();
        let (mut shaft_feed, mut branch_feed) = (None, None);
        let mut lo = 0.0;
        for feed in 0.. {
            let hi = lo + 40.0;
            let sel: Vec<(f64, f64)> = pts.iter().copied().filter(|p| p.0 >= lo && p.0 < hi).collect();
            let m: Vec<f64> = sel.iter().map(|p| p.0).collect();
            let last = hi > 600.0;
            for c in st.feed(cloud(&sel), m, (!last).then_some(hi), cluster_groups, &params) {
                if c.points.y.iter().all(|&y| (y - 1.4).abs() < 1e-3) {
                    shaft_feed = Some(feed);
                }
                if c.points.y.iter().any(|&y| (y - 1.0).abs() < 1e-3) {
                    branch_feed = Some(feed);
                }
            }
            if last {
                break;
            }
            lo = hi;
        }
        // The line's first piece (0-250 m, with the branch) completes once the frontier is
        // past 252.5 m: the feed of the chunk 240-280 m.
        assert_eq!(branch_feed, Some(6));
        assert_eq!(shaft_feed, branch_feed);
    }

    #[test]
    fn streaming_clusters_do_not_depend_on_chunk_edges() {
        // A 600 m solid line (y = 0), dashes (y = 3.5), a cross stripe near x = 120.
        let mut pts = Vec::new();
        for i in 0..6000 {
            pts.push((i as f64 * 0.1, 0.0));
        }
        for d in 0..60 {
            for i in 0..30 {
                pts.push((d as f64 * 10.0 + i as f64 * 0.1, 3.5));
            }
        }
        for i in 0..30 {
            pts.push((120.0, 5.0 + i as f64 * 0.1));
        }
        let a = run_chunked(&pts, 40.0);
        let b = run_chunked(&pts, 1000.0);
        let c = run_chunked(&pts, 77.0);
        assert_eq!(a, b);
        assert_eq!(a, c);
        // The solid line is cut into pieces at multiples of PIECE_M: 0-250, 250-500, 500-600.
        assert_eq!(a.iter().filter(|g| g.len() >= 1000).count(), 3);
        assert_eq!(a.len(), 3 + 60 + 1);
    }
}
