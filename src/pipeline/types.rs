//! Core data types shared by every pipeline stage.
//!
//! Coordinates: a [`PointCloud`] stores points relative to a local `origin` (f64), never
//! absolute projected coordinates in f32. Output geometry ([`Marking`], [`LaneLine`]) is
//! absolute, in the input CRS.

use serde::{Deserialize, Serialize};

/// Coordinate reference system of the input data.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Crs {
    /// EPSG code when the CRS could be reduced to one.
    pub epsg: Option<u32>,
    /// The OGC WKT as found in the file, when there was one.
    pub wkt: Option<String>,
}

impl Crs {
    pub fn epsg(code: u32) -> Self {
        Self {
            epsg: Some(code),
            wkt: None,
        }
    }
}

/// A column-oriented point cloud; coordinates are relative to `origin`.
#[derive(Clone, Debug, Default)]
pub struct PointCloud {
    /// Local origin in the input CRS (absolute x, y, z).
    pub origin: [f64; 3],
    pub x: Vec<f64>,
    pub y: Vec<f64>,
    pub z: Vec<f64>,
    /// Raw LAS intensity (0..=65535) as f32.
    pub intensity: Vec<f32>,
    /// GPS time per point, when the point format has it.
    pub gps_time: Option<Vec<f64>>,
    /// Scanner head per point (from the scanner channel, user_data or point_source_id;
    /// 0 when the file does not tell heads apart).
    pub scanner: Vec<u8>,
    pub crs: Option<Crs>,
    /// Marking points only: each point's intensity over the asphalt background around it
    /// (the normalised value the threshold stage judged it by), when known.
    pub contrast: Option<Vec<f32>>,
}

impl PointCloud {
    pub fn with_origin(origin: [f64; 3]) -> Self {
        Self {
            origin,
            ..Default::default()
        }
    }

    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Append one point given in local coordinates.
    pub fn push_local(&mut self, x: f64, y: f64, z: f64, intensity: f32, gps_time: Option<f64>, scanner: u8) {
        self.x.push(x);
        self.y.push(y);
        self.z.push(z);
        self.intensity.push(intensity);
        if let (Some(times), Some(t)) = (self.gps_time.as_mut(), gps_time) {
            times.push(t);
        }
        self.scanner.push(scanner);
    }

    /// A new cloud holding the points at `indices` (same origin and CRS).
    pub fn select(&self, indices: &[usize]) -> PointCloud {
        PointCloud {
            origin: self.origin,
            x: indices.iter().map(|&i| self.x[i]).collect(),
            y: indices.iter().map(|&i| self.y[i]).collect(),
            z: indices.iter().map(|&i| self.z[i]).collect(),
            intensity: indices.iter().map(|&i| self.intensity[i]).collect(),
            gps_time: self
                .gps_time
                .as_ref()
                .map(|t| indices.iter().map(|&i| t[i]).collect()),
            scanner: indices.iter().map(|&i| self.scanner[i]).collect(),
            crs: self.crs.clone(),
            contrast: self
                .contrast
                .as_ref()
                .map(|c| indices.iter().map(|&i| c[i]).collect()),
        }
    }

    /// Append another cloud, re-expressing its points relative to this cloud's origin.
    /// The optional columns (GPS time, contrast) are kept only if both clouds have them; an
    /// empty cloud takes them from the first cloud appended.
    pub fn extend_from(&mut self, other: &PointCloud) {
        fn column<T: Copy>(empty: bool, mine: &mut Option<Vec<T>>, theirs: &Option<Vec<T>>) {
            if empty {
                *mine = theirs.as_ref().map(|_| Vec::new());
            }
            match (mine.as_mut(), theirs) {
                (Some(a), Some(b)) => a.extend_from_slice(b),
                _ => *mine = None,
            }
        }
        let empty = self.is_empty();
        column(empty, &mut self.gps_time, &other.gps_time);
        column(empty, &mut self.contrast, &other.contrast);
        let d = [
            other.origin[0] - self.origin[0],
            other.origin[1] - self.origin[1],
            other.origin[2] - self.origin[2],
        ];
        self.x.extend(other.x.iter().map(|v| v + d[0]));
        self.y.extend(other.y.iter().map(|v| v + d[1]));
        self.z.extend(other.z.iter().map(|v| v + d[2]));
        self.intensity.extend_from_slice(&other.intensity);
        self.scanner.extend_from_slice(&other.scanner);
        if self.crs.is_none() {
            self.crs = other.crs.clone();
        }
    }
}

/// One trajectory station (absolute coordinates in the input CRS).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    pub time: f64,
    pub x: f64,
    pub y: f64,
    /// NaN when the table had no z column.
    pub z: f64,
    /// Degrees clockwise from north, when given.
    pub heading_deg: Option<f64>,
    pub roll_deg: Option<f64>,
    pub pitch_deg: Option<f64>,
}

/// Where a point lies relative to the trajectory.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Station {
    /// Distance along the track from its first pose (m).
    pub mileage_m: f64,
    /// Signed perpendicular distance, positive to the left of the driving direction (m).
    pub offset_m: f64,
    /// Unit driving direction at that station (x = east, y = north).
    pub direction: [f64; 2],
    /// Index of the trajectory segment the point projects onto.
    pub segment: usize,
}

/// Errors constructing a trajectory.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum TrajectoryError {
    #[error("the trajectory has no rows")]
    Empty,
    #[error("the trajectory needs at least 2 distinct positions, found {0}")]
    TooShort(usize),
    #[error("non-finite value in trajectory row {row}")]
    NonFinite { row: usize },
}

/// A vehicle trajectory: poses sorted by time, with cumulative distance for mileage queries.
///
/// Consecutive poses closer than 1 mm are merged so every segment has a direction.
#[derive(Clone, Debug)]
pub struct Trajectory {
    poses: Vec<Pose>,
    cum_m: Vec<f64>,
}

impl Trajectory {
    pub fn new(mut poses: Vec<Pose>) -> Result<Self, TrajectoryError> {
        if poses.is_empty() {
            return Err(TrajectoryError::Empty);
        }
        for (row, p) in poses.iter().enumerate() {
            if !(p.time.is_finite() && p.x.is_finite() && p.y.is_finite()) {
                return Err(TrajectoryError::NonFinite { row });
            }
        }
        poses.sort_by(|a, b| a.time.total_cmp(&b.time));
        let mut kept: Vec<Pose> = Vec::with_capacity(poses.len());
        for p in poses {
            match kept.last() {
                Some(q) if (p.x - q.x).hypot(p.y - q.y) < 1e-3 => {}
                _ => kept.push(p),
            }
        }
        if kept.len() < 2 {
            return Err(TrajectoryError::TooShort(kept.len()));
        }
        let mut cum_m = Vec::with_capacity(kept.len());
        let mut acc = 0.0;
        cum_m.push(0.0);
        for w in kept.windows(2) {
            acc += (w[1].x - w[0].x).hypot(w[1].y - w[0].y);
            cum_m.push(acc);
        }
        Ok(Self { poses: kept, cum_m })
    }

    pub fn poses(&self) -> &[Pose] {
        &self.poses
    }

    /// Cumulative distance (m) at each pose.
    pub fn mileages(&self) -> &[f64] {
        &self.cum_m
    }

    pub fn length_m(&self) -> f64 {
        *self.cum_m.last().unwrap_or(&0.0)
    }

    /// The same trajectory with `origin` subtracted from x, y (and z when present).
    pub fn to_local(&self, origin: [f64; 3]) -> Trajectory {
        let poses = self
            .poses
            .iter()
            .map(|p| Pose {
                x: p.x - origin[0],
                y: p.y - origin[1],
                z: p.z - origin[2],
                ..*p
            })
            .collect();
        Trajectory {
            poses,
            cum_m: self.cum_m.clone(),
        }
    }

    fn segment_direction(&self, i: usize) -> [f64; 2] {
        let (a, b) = (&self.poses[i], &self.poses[i + 1]);
        let (dx, dy) = (b.x - a.x, b.y - a.y);
        let l = dx.hypot(dy);
        [dx / l, dy / l]
    }

    /// Position (x, y, z) and unit direction interpolated at time `t` (clamped to the track).
    pub fn at_time(&self, t: f64) -> ([f64; 3], [f64; 2]) {
        let i = match self.poses.binary_search_by(|p| p.time.total_cmp(&t)) {
            Ok(i) => i.min(self.poses.len() - 2),
            Err(0) => 0,
            Err(i) => (i - 1).min(self.poses.len() - 2),
        };
        let (a, b) = (&self.poses[i], &self.poses[i + 1]);
        let span = b.time - a.time;
        let f = if span > 0.0 {
            ((t - a.time) / span).clamp(0.0, 1.0)
        } else {
            0.0
        };
        (
            [
                a.x + f * (b.x - a.x),
                a.y + f * (b.y - a.y),
                a.z + f * (b.z - a.z),
            ],
            self.segment_direction(i),
        )
    }

    /// Position and unit direction at mileage `m` (clamped to the track).
    pub fn at_mileage(&self, m: f64) -> ([f64; 2], [f64; 2]) {
        let i = match self.cum_m.binary_search_by(|c| c.total_cmp(&m)) {
            Ok(i) => i.min(self.poses.len() - 2),
            Err(0) => 0,
            Err(i) => (i - 1).min(self.poses.len() - 2),
        };
        let seg = self.cum_m[i + 1] - self.cum_m[i];
        let f = ((m - self.cum_m[i]) / seg).clamp(0.0, 1.0);
        let (a, b) = (&self.poses[i], &self.poses[i + 1]);
        (
            [a.x + f * (b.x - a.x), a.y + f * (b.y - a.y)],
            self.segment_direction(i),
        )
    }

    /// Project (x, y) onto segment `i`: (mileage, signed offset, clamped parameter).
    fn project_on(&self, i: usize, x: f64, y: f64) -> (f64, f64, f64) {
        let a = &self.poses[i];
        let d = self.segment_direction(i);
        let seg = self.cum_m[i + 1] - self.cum_m[i];
        let (rx, ry) = (x - a.x, y - a.y);
        let along = rx * d[0] + ry * d[1];
        let cl = along.clamp(0.0, seg);
        let (px, py) = (a.x + cl * d[0], a.y + cl * d[1]);
        let side = d[0] * ry - d[1] * rx; // cross product: positive on the left
        let (mileage, offset) = station_on_segment(
            self.cum_m[i],
            (along, cl, side),
            [x - px, y - py],
            (i == 0, i + 2 == self.poses.len()),
        );
        (mileage, offset, (x - px).hypot(y - py))
    }

    /// Nearest station to (x, y), searching segments `hint_lo..=hint_hi` (all when `None`).
    ///
    /// Linear in the number of segments searched; for many points use a [`StationIndex`].
    pub fn locate_in(&self, x: f64, y: f64, range: Option<(usize, usize)>) -> Station {
        let n = self.poses.len() - 1;
        let (lo, hi) = range
            .map(|(a, b)| (a.min(n - 1), b.min(n - 1)))
            .unwrap_or((0, n - 1));
        let mut best = (f64::INFINITY, 0usize, 0.0, 0.0);
        for i in lo..=hi {
            let (m, off, dist) = self.project_on(i, x, y);
            if dist < best.0 {
                best = (dist, i, m, off);
            }
        }
        Station {
            mileage_m: best.2,
            offset_m: best.3,
            direction: self.segment_direction(best.1),
            segment: best.1,
        }
    }

    /// Nearest station to (x, y) over the whole track.
    pub fn locate(&self, x: f64, y: f64) -> Station {
        self.locate_in(x, y, None)
    }
}

/// Fast nearest-station queries for many points: a kd-tree over segment sample points, and
/// a walk from the previous answer for points that come in acquisition order.
///
/// **Algorithm.** Every segment is sampled at most `step_m` apart (every pose is a sample).
/// [`StationIndex::locate`] takes the nearest sample (kd-tree) and searches its segment and
/// the two neighbours exactly. [`StationIndex::locate_near`] finds the nearest sample by
/// walking along the samples from a hint (the previous point's sample): downhill steps,
/// then a check of the `WALK_WINDOW` samples on each side so that jitter of the trajectory
/// does not stop the walk early. The walk is trusted only where no far part of the track
/// can be nearer: samples are grouped in blocks of [`BLOCK`] and every block knows its
/// *clearance* (the distance from the block to the nearest sample more than
/// [`FAR_ARC_M`] away along the track); a point closer than half the clearance to the
/// walked sample cannot have its nearest sample on a far part of the track. Otherwise
/// (far points, loops, the first point) the kd-tree answers.
///
/// **Complexity.** Build O(n log n); `locate` O(log n); `locate_near` O(1) amortised for
/// points in acquisition order.
pub struct StationIndex<'a> {
    traj: &'a Trajectory,
    tree: kiddo::ImmutableKdTree<f64, 2>,
    seg_of: Vec<usize>,
    /// Sample positions (x, y), in track order.
    samples: Vec<[f64; 2]>,
    /// Unit direction and length of every segment (cached: `hypot` is costly per point).
    dir: Vec<[f64; 2]>,
    seg_len: Vec<f64>,
    /// Per block of [`BLOCK`] samples: squared half clearance (see the type docs).
    half_clear2: Vec<f64>,
    /// Samples per metre of track.
    per_m: f64,
}

/// Samples per clearance block of [`StationIndex`].
const BLOCK: usize = 32;
/// Along-track distance beyond which a part of the track counts as "far" (m).
const FAR_ARC_M: f64 = 100.0;
/// Samples checked on each side of a walk's local minimum.
const WALK_WINDOW: usize = 6;
/// Pose jitter the walk tolerates (m).
const WALK_JITTER_M: f64 = 0.02;
/// Walks longer than this give up and ask the kd-tree.
const WALK_MAX_STEPS: usize = 256;

impl<'a> StationIndex<'a> {
    /// Samples every segment at most `step_m` apart.
    pub fn new(traj: &'a Trajectory, step_m: f64) -> Self {
        let step = step_m.max(0.01);
        let mut pts = Vec::new();
        let mut seg_of = Vec::new();
        let mut arc = Vec::new();
        for i in 0..traj.poses.len() - 1 {
            let (a, b) = (&traj.poses[i], &traj.poses[i + 1]);
            let len = traj.cum_m[i + 1] - traj.cum_m[i];
            let k = (len / step).ceil().max(1.0) as usize;
            for j in 0..k {
                let f = j as f64 / k as f64;
                pts.push([a.x + f * (b.x - a.x), a.y + f * (b.y - a.y)]);
                seg_of.push(i);
                arc.push(traj.cum_m[i] + f * len);
            }
        }
        let last = traj.poses.last().expect("trajectory has >= 2 poses");
        pts.push([last.x, last.y]);
        seg_of.push(traj.poses.len() - 2);
        arc.push(traj.length_m());
        let tree = kiddo::ImmutableKdTree::new_from_slice(&pts).expect("finite trajectory samples");
        let dir = (0..traj.poses.len() - 1)
            .map(|i| traj.segment_direction(i))
            .collect();
        let seg_len = traj.cum_m.windows(2).map(|w| w[1] - w[0]).collect();
        let half_clear2 = block_clearance(&tree, &pts, &arc);
        let per_m = pts.len() as f64 / traj.length_m().max(1e-3);
        Self {
            per_m,
            traj,
            tree,
            seg_of,
            samples: pts,
            dir,
            seg_len,
            half_clear2,
        }
    }

    /// Nearest station: the nearest sample's segment and its neighbours are searched exactly.
    pub fn locate(&self, x: f64, y: f64) -> Station {
        self.station_near_sample(x, y, self.nearest_sample(x, y))
    }

    /// Like [`StationIndex::locate`], starting from `hint` (a sample index returned through
    /// `hint` by the previous call; any value, e.g. `usize::MAX`, when there is none). Fast
    /// for points in acquisition order.
    pub fn locate_near(&self, x: f64, y: f64, hint: &mut usize) -> Station {
        let s = match self.walk(x, y, *hint) {
            Some(s) => s,
            None => self.nearest_sample(x, y),
        };
        *hint = s;
        self.station_near_sample(x, y, s)
    }

    fn nearest_sample(&self, x: f64, y: f64) -> usize {
        self.tree
            .query(&[x, y])
            .nearest_one::<kiddo::SquaredEuclidean<f64>>()
            .execute()
            .item as usize
    }

    #[inline]
    fn d2(&self, j: usize, x: f64, y: f64) -> f64 {
        let q = self.samples[j];
        (q[0] - x) * (q[0] - x) + (q[1] - y) * (q[1] - y)
    }

    /// The nearest sample found by walking from `hint`, when it is certainly not on a far
    /// part of the track (see the type docs); `None` asks for the kd-tree.
    fn walk(&self, x: f64, y: f64, hint: usize) -> Option<usize> {
        let n = self.samples.len();
        if hint >= n {
            return None;
        }
        let mut s = hint;
        let mut best = self.d2(s, x, y);
        for _ in 0..WALK_MAX_STEPS {
            // Downhill in the cheaper direction first, then the window around the minimum.
            let mut moved = false;
            while s + 1 < n {
                let d = self.d2(s + 1, x, y);
                if d < best {
                    (s, best, moved) = (s + 1, d, true);
                } else {
                    break;
                }
            }
            if !moved {
                while s > 0 {
                    let d = self.d2(s - 1, x, y);
                    if d < best {
                        (s, best) = (s - 1, d);
                    } else {
                        break;
                    }
                }
            }
            // Jitter of the poses makes shallow local minima over a length that grows
            // with the distance: sqrt(8 d jitter).
            let w = ((8.0 * best.sqrt() * WALK_JITTER_M).sqrt() * self.per_m).ceil() as usize;
            let w = w.max(WALK_WINDOW);
            let (lo, hi) = (s.saturating_sub(w), (s + w).min(n - 1));
            let mut bs = s;
            for j in lo..=hi {
                let d = self.d2(j, x, y);
                if d < best {
                    (bs, best) = (j, d);
                }
            }
            if bs == s {
                return (best < self.half_clear2[s / BLOCK]).then_some(s);
            }
            s = bs;
        }
        None
    }

    /// Nearest station among the segment of sample `s` and its two neighbours (what
    /// [`Trajectory::locate_in`] computes, with cached directions).
    fn station_near_sample(&self, x: f64, y: f64, s: usize) -> Station {
        let seg = self.seg_of[s];
        let n = self.dir.len();
        let (lo, hi) = (seg.saturating_sub(1), (seg + 1).min(n - 1));
        let mut best: (f64, usize, f64, f64, f64, f64, f64) = (f64::INFINITY, 0, 0.0, 0.0, 0.0, 0.0, 0.0);
        for i in lo..=hi {
            let a = &self.traj.poses[i];
            let d = self.dir[i];
            let len = self.seg_len[i];
            let (rx, ry) = (x - a.x, y - a.y);
            let along = rx * d[0] + ry * d[1];
            let cl = along.clamp(0.0, len);
            let (px, py) = (a.x + cl * d[0], a.y + cl * d[1]);
            let dist2 = (x - px) * (x - px) + (y - py) * (y - py);
            // Squared distances order like `locate_in`'s `hypot` ones except at near ties
            // (a point on the bisector of two segments): those are decided like there.
            let closer = if best.0.is_infinite() || (dist2 - best.0).abs() > 1e-12 * best.0 {
                dist2 < best.0
            } else {
                (x - px).hypot(y - py) < best.5.hypot(best.6)
            };
            if closer {
                let side = d[0] * ry - d[1] * rx;
                best = (dist2, i, along, cl, side, x - px, y - py);
            }
        }
        let (_, i, along, cl, side, ex, ey) = best;
        let (mileage, offset) = station_on_segment(
            self.traj.cum_m[i],
            (along, cl, side),
            [ex, ey],
            (i == 0, i + 1 == n),
        );
        Station {
            mileage_m: mileage,
            offset_m: offset,
            direction: self.dir[i],
            segment: i,
        }
    }
}

/// (mileage, offset) of a point projected on a segment starting at mileage `cum`: `along`
/// its parameter along the segment, `cl` that parameter clamped to the segment, `side` its
/// signed lateral distance from the segment's line (positive on the left), `e` the vector
/// from the clamped foot to the point, `(first, last)` whether the segment is the track's
/// first or last. Beyond either end of the track the frame goes on straight: mileage
/// extrapolates along the end segment and the offset is the lateral part. Past an inner
/// vertex the offset is the distance to that vertex, signed by the side.
fn station_on_segment(
    cum: f64,
    (along, cl, side): (f64, f64, f64),
    e: [f64; 2],
    (first, last): (bool, bool),
) -> (f64, f64) {
    let beyond_end = (first && along < cl) || (last && along > cl);
    if cl == along || beyond_end {
        (cum + along, side)
    } else {
        (
            cum + cl,
            e[0].hypot(e[1]).copysign(if side == 0.0 { 1.0 } else { side }),
        )
    }
}

/// Per block of [`BLOCK`] consecutive samples: (clearance / 2)², the clearance being the
/// distance from any sample of the block to the nearest sample more than [`FAR_ARC_M`]
/// along the track away from the whole block (infinite when there is none within a few
/// hundred metres; points that far are never near the track anyway, and fall back).
fn block_clearance(tree: &kiddo::ImmutableKdTree<f64, 2>, pts: &[[f64; 2]], arc: &[f64]) -> Vec<f64> {
    const SEARCH_M: f64 = 250.0;
    (0..pts.len().div_ceil(BLOCK))
        .map(|b| {
            let (lo, hi) = (b * BLOCK, ((b + 1) * BLOCK).min(pts.len()));
            let c = pts[(lo + hi) / 2];
            let radius = pts[lo..hi]
                .iter()
                .map(|q| (q[0] - c[0]).hypot(q[1] - c[1]))
                .fold(0.0, f64::max);
            let (a_lo, a_hi) = (arc[lo] - FAR_ARC_M, arc[hi - 1] + FAR_ARC_M);
            let r = SEARCH_M + radius;
            let nearest_far = tree
                .query(&c)
                .within::<kiddo::SquaredEuclidean<f64>>(r * r)
                .unsorted()
                .execute()
                .into_iter()
                .filter(|nb| {
                    let a = arc[nb.item as usize];
                    a < a_lo || a > a_hi
                })
                .map(|nb| nb.distance.sqrt())
                .fold(r, f64::min);
            // |p - q_far| >= |q_far - c| - radius - |p - q_s| - 2 radius (q_s within radius of c).
            let clear = (nearest_far - 2.0 * radius).max(0.0);
            if nearest_far >= r {
                // Nothing far within the search: |p - q_s| < SEARCH_M / 2 - radius is safe.
                let h = (SEARCH_M / 2.0 - radius).max(0.0);
                h * h
            } else {
                let h = clear / 2.0;
                h * h
            }
        })
        .collect()
}

/// Marking classes of the contract (`properties.class`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MarkingClass {
    SolidLine,
    DashedLine,
    Guideline,
    StraightArrow,
    LeftArrow,
    RightArrow,
    StraightLeftArrow,
    StraightRightArrow,
    Crosswalk,
    Diamond,
    StopLine,
    Unknown,
}

impl MarkingClass {
    pub const ALL: [MarkingClass; 12] = [
        MarkingClass::SolidLine,
        MarkingClass::DashedLine,
        MarkingClass::Guideline,
        MarkingClass::StraightArrow,
        MarkingClass::LeftArrow,
        MarkingClass::RightArrow,
        MarkingClass::StraightLeftArrow,
        MarkingClass::StraightRightArrow,
        MarkingClass::Crosswalk,
        MarkingClass::Diamond,
        MarkingClass::StopLine,
        MarkingClass::Unknown,
    ];

    /// The contract's snake_case name.
    pub fn as_str(self) -> &'static str {
        match self {
            MarkingClass::SolidLine => "solid_line",
            MarkingClass::DashedLine => "dashed_line",
            MarkingClass::Guideline => "guideline",
            MarkingClass::StraightArrow => "straight_arrow",
            MarkingClass::LeftArrow => "left_arrow",
            MarkingClass::RightArrow => "right_arrow",
            MarkingClass::StraightLeftArrow => "straight_left_arrow",
            MarkingClass::StraightRightArrow => "straight_right_arrow",
            MarkingClass::Crosswalk => "crosswalk",
            MarkingClass::Diamond => "diamond",
            MarkingClass::StopLine => "stop_line",
            MarkingClass::Unknown => "unknown",
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.as_str() == s)
    }

    pub fn is_arrow(self) -> bool {
        matches!(
            self,
            MarkingClass::StraightArrow
                | MarkingClass::LeftArrow
                | MarkingClass::RightArrow
                | MarkingClass::StraightLeftArrow
                | MarkingClass::StraightRightArrow
        )
    }
}

/// Lane-line classes of the contract.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LaneLineClass {
    SolidLine,
    DashedLine,
}

impl LaneLineClass {
    /// The class of the markings (pieces, dashes) a lane line of this class joins.
    pub fn marking_class(self) -> MarkingClass {
        match self {
            LaneLineClass::SolidLine => MarkingClass::SolidLine,
            LaneLineClass::DashedLine => MarkingClass::DashedLine,
        }
    }

    pub fn as_str(self) -> &'static str {
        match self {
            LaneLineClass::SolidLine => "solid_line",
            LaneLineClass::DashedLine => "dashed_line",
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "solid_line" => Some(LaneLineClass::SolidLine),
            "dashed_line" => Some(LaneLineClass::DashedLine),
            _ => None,
        }
    }
}

/// One painted object: a classified polygon (absolute coordinates, input CRS).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Marking {
    pub id: String,
    pub class: MarkingClass,
    /// Outer ring, not closed (the first vertex is not repeated), any orientation.
    pub outline: Vec<[f64; 2]>,
    pub confidence: f64,
    pub length_m: f64,
    pub width_m: f64,
    /// Direction of the long axis (arrows: the direction they point), degrees clockwise
    /// from north, in [0, 360).
    pub heading_deg: f64,
    pub point_count: usize,
}

/// One lane line: the painted centreline through all its pieces (absolute coordinates).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LaneLine {
    pub id: String,
    pub class: LaneLineClass,
    pub line: Vec<[f64; 2]>,
    pub confidence: f64,
    pub length_m: f64,
    pub marking_ids: Vec<String>,
}

/// What the pipeline produces (and what the simulator writes as truth).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Extraction {
    pub markings: Vec<Marking>,
    pub lane_lines: Vec<LaneLine>,
    pub crs: Option<Crs>,
}

/// A flat pose with no attitude, for the unit tests of the pipeline modules.
#[cfg(test)]
pub(crate) fn test_pose(time: f64, x: f64, y: f64) -> Pose {
    Pose {
        time,
        x,
        y,
        z: 0.0,
        heading_deg: None,
        roll_deg: None,
        pitch_deg: None,
    }
}

/// A straight trajectory along +x with a pose every metre from `x0` to `x0 + n`, for
/// the unit tests of the pipeline modules.
#[cfg(test)]
pub(crate) fn test_straight_trajectory(n: usize, x0: f64) -> Trajectory {
    let poses = (0..=n).map(|i| test_pose(i as f64, i as f64 + x0, 0.0)).collect();
    Trajectory::new(poses).expect("a straight trajectory is valid")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The marking points' contrast (and GPS time) travels with them: an empty cloud takes
    /// it from the first cloud appended, `select` keeps it in order, a cloud without it
    /// ends it.
    #[test]
    fn contrast_travels_with_the_points() {
        let mut a = PointCloud::with_origin([10.0, 0.0, 0.0]);
        a.push_local(1.0, 2.0, 0.0, 100.0, None, 0);
        a.push_local(3.0, 4.0, 0.0, 200.0, None, 0);
        a.contrast = Some(vec![1.5, 3.0]);
        a.gps_time = Some(vec![7.0, 8.0]);
        let mut all = PointCloud::with_origin([0.0, 0.0, 0.0]);
        all.extend_from(&a);
        all.extend_from(&a.select(&[1]));
        assert_eq!(all.contrast, Some(vec![1.5, 3.0, 3.0]));
        assert_eq!(all.gps_time, Some(vec![7.0, 8.0, 8.0]));
        assert_eq!(all.select(&[2, 0]).contrast, Some(vec![3.0, 1.5]));
        let mut plain = a.clone();
        plain.contrast = None;
        all.extend_from(&plain);
        assert_eq!(all.contrast, None);
        assert_eq!(all.len(), 5);
    }

    fn pose(t: f64, x: f64, y: f64) -> Pose {
        test_pose(t, x, y)
    }

    #[test]
    fn empty_and_degenerate_trajectories_are_errors() {
        assert_eq!(Trajectory::new(vec![]).unwrap_err(), TrajectoryError::Empty);
        assert_eq!(
            Trajectory::new(vec![pose(0.0, 1.0, 1.0), pose(1.0, 1.0, 1.0)]).unwrap_err(),
            TrajectoryError::TooShort(1)
        );
        assert_eq!(
            Trajectory::new(vec![pose(0.0, f64::NAN, 1.0), pose(1.0, 1.0, 1.0)]).unwrap_err(),
            TrajectoryError::NonFinite { row: 0 }
        );
    }

    #[test]
    fn interpolation_and_mileage_on_an_l_shaped_track() {
        let t = Trajectory::new(vec![
            pose(2.0, 10.0, 0.0),
            pose(0.0, 0.0, 0.0),
            pose(3.0, 10.0, 10.0),
        ])
        .unwrap();
        assert_eq!(t.length_m(), 20.0);
        let (p, d) = t.at_time(1.0);
        assert!((p[0] - 5.0).abs() < 1e-12 && d == [1.0, 0.0]);
        let (p, d) = t.at_time(2.5);
        assert!((p[1] - 5.0).abs() < 1e-12 && d == [0.0, 1.0]);
        let s = t.locate(5.0, 2.0);
        assert!((s.mileage_m - 5.0).abs() < 1e-12);
        assert!(
            (s.offset_m - 2.0).abs() < 1e-12,
            "left of an eastward track is positive"
        );
        let s = t.locate(12.0, 5.0);
        assert!((s.mileage_m - 15.0).abs() < 1e-12);
        assert!(
            (s.offset_m + 2.0).abs() < 1e-12,
            "right of a northward track is negative"
        );
        let s = t.locate(-3.0, 0.0);
        assert!(
            (s.mileage_m + 3.0).abs() < 1e-12,
            "mileage extrapolates before the start"
        );
        // Beyond either end the frame goes on straight: the offset is the lateral part
        // (not the distance to the end pose), so a line behind the start keeps its offset.
        let s = t.locate(-8.0, 1.5);
        assert!(
            (s.mileage_m + 8.0).abs() < 1e-12 && (s.offset_m - 1.5).abs() < 1e-12,
            "{s:?}"
        );
        let s = t.locate(11.5, 16.0);
        assert!(
            (s.mileage_m - 26.0).abs() < 1e-12 && (s.offset_m + 1.5).abs() < 1e-12,
            "{s:?}"
        );
        let s = t.locate_in(-8.0, 1.5, Some((0, 1)));
        assert!((s.offset_m - 1.5).abs() < 1e-12, "{s:?}");
        // The index the pipeline locates its points with agrees.
        let idx = StationIndex::new(&t, 1.0);
        for q in [[-8.0, 1.5], [11.5, 16.0]] {
            let mut hint = usize::MAX;
            assert_eq!(idx.locate_near(q[0], q[1], &mut hint), t.locate(q[0], q[1]));
            assert_eq!(idx.locate(q[0], q[1]), t.locate(q[0], q[1]));
        }
        let (p, _) = t.at_mileage(12.0);
        assert!((p[0] - 10.0).abs() < 1e-12 && (p[1] - 2.0).abs() < 1e-12);
    }

    /// A jittered S-bend sampled at 100 Hz, and points swept across it in scan lines (the
    /// order of acquisition), some of them far away.
    fn jittered_drive() -> (Trajectory, Vec<[f64; 2]>) {
        let mut rng = 12345u64;
        let mut noise = move || {
            rng = rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((rng >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        let mut poses = Vec::new();
        let (mut x, mut y, mut h) = (0.0f64, 0.0f64, 0.0f64);
        for i in 0..6000 {
            let curv = 0.02 * (i as f64 / 1500.0).sin();
            h += curv * 0.15;
            x += 0.15 * h.cos();
            y += 0.15 * h.sin();
            poses.push(pose(i as f64 * 0.01, x + 0.01 * noise(), y + 0.01 * noise()));
        }
        let t = Trajectory::new(poses).unwrap();
        let mut pts = Vec::new();
        for line in 0..3000 {
            let (c, d) = t.at_mileage(line as f64 * 0.3);
            for k in 0..60 {
                let r = (k as f64 - 30.0) * 1.5 + noise();
                let along = noise() * 0.2;
                pts.push([c[0] - d[1] * r + d[0] * along, c[1] + d[0] * r + d[1] * along]);
            }
            // Now and then a point far out (a building, the sky).
            pts.push([c[0] + 400.0 * noise(), c[1] + 400.0 * noise()]);
        }
        (t, pts)
    }

    #[test]
    fn walking_from_the_previous_point_matches_the_kd_tree() {
        let (t, pts) = jittered_drive();
        let idx = StationIndex::new(&t, 1.0);
        let mut hint = usize::MAX;
        let mut same = 0;
        let check = |k: usize, walked: Station, tree: Station| {
            // Where they differ, the two stations are equally near (a near tie).
            assert!(
                (walked.offset_m.abs() - tree.offset_m.abs()).abs() < 1e-3,
                "point {k}: {walked:?} {tree:?}"
            );
            assert!((walked.mileage_m - tree.mileage_m).abs() < 2.0, "point {k}");
            walked == tree
        };
        for (k, p) in pts.iter().enumerate() {
            let walked = idx.locate_near(p[0], p[1], &mut hint);
            same += check(k, walked, idx.locate(p[0], p[1])) as usize;
        }
        assert!(same as f64 >= 0.999 * pts.len() as f64, "{same} of {}", pts.len());
        // Any hint gives (almost always) the kd-tree's answer.
        let mut same = 0;
        let mut n = 0;
        for (k, p) in pts.iter().enumerate().step_by(97) {
            let mut far_hint = (k * 7919) % 6000;
            let walked = idx.locate_near(p[0], p[1], &mut far_hint);
            same += check(k, walked, idx.locate(p[0], p[1])) as usize;
            n += 1;
        }
        assert!(same as f64 >= 0.99 * n as f64, "{same} of {n}");
    }

    #[test]
    fn station_index_agrees_with_the_exact_search_on_a_jittered_track() {
        let (t, pts) = jittered_drive();
        let idx = StationIndex::new(&t, 1.0);
        let mut worst: f64 = 0.0;
        for p in pts.iter().step_by(7) {
            let fast = idx.locate(p[0], p[1]);
            let slow = t.locate(p[0], p[1]);
            if fast.offset_m.abs() < 30.0 {
                worst = worst.max((fast.offset_m.abs() - slow.offset_m.abs()).abs());
            }
        }
        assert!(worst < 1e-3, "offset error {worst}");
    }

    #[test]
    fn station_index_matches_linear_search() {
        let poses: Vec<Pose> = (0..200)
            .map(|i| {
                let a = i as f64 * 0.01;
                pose(i as f64, 100.0 * a.cos(), 100.0 * a.sin())
            })
            .collect();
        let t = Trajectory::new(poses).unwrap();
        let idx = StationIndex::new(&t, 0.5);
        for k in 0..500 {
            let a = k as f64 * 0.004;
            let r = 90.0 + (k % 20) as f64;
            let (x, y) = (r * a.cos(), r * a.sin());
            let fast = idx.locate(x, y);
            let slow = t.locate(x, y);
            assert!((fast.mileage_m - slow.mileage_m).abs() < 1e-9, "{k}");
            assert!((fast.offset_m - slow.offset_m).abs() < 1e-9, "{k}");
        }
    }
}
