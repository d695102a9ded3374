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
        }
    }

    /// Append another cloud, re-expressing its points relative to this cloud's origin.
    /// GPS time is kept only if both clouds have it.
    pub fn extend_from(&mut self, other: &PointCloud) {
        let d = [
            other.origin[0] - self.origin[0],
            other.origin[1] - self.origin[1],
            other.origin[2] - self.origin[2],
        ];
        self.x.extend(other.x.iter().map(|v| v + d[0]));
        self.y.extend(other.y.iter().map(|v| v + d[1]));
        self.z.extend(other.z.iter().map(|v| v + d[2]));
        self.intensity.extend_from_slice(&other.intensity);
        match (&mut self.gps_time, &other.gps_time) {
            (Some(a), Some(b)) => a.extend_from_slice(b),
            _ => self.gps_time = None,
        }
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
        let dist = (x - px).hypot(y - py);
        // Beyond the ends of the track, extrapolate mileage along the end segments.
        let mileage = if (i == 0 && along < 0.0) || (i + 2 == self.poses.len() && along > seg) {
            self.cum_m[i] + along
        } else {
            self.cum_m[i] + cl
        };
        let offset = if cl == along {
            side
        } else {
            dist.copysign(if side == 0.0 { 1.0 } else { side })
        };
        (mileage, offset, dist)
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

/// Fast nearest-station queries for many points: a kd-tree over segment sample points.
pub struct StationIndex<'a> {
    traj: &'a Trajectory,
    tree: kiddo::ImmutableKdTree<f64, 2>,
    seg_of: Vec<usize>,
}

impl<'a> StationIndex<'a> {
    /// Samples every segment at most `step_m` apart.
    pub fn new(traj: &'a Trajectory, step_m: f64) -> Self {
        let step = step_m.max(0.01);
        let mut pts = Vec::new();
        let mut seg_of = Vec::new();
        for i in 0..traj.poses.len() - 1 {
            let (a, b) = (&traj.poses[i], &traj.poses[i + 1]);
            let len = traj.cum_m[i + 1] - traj.cum_m[i];
            let k = (len / step).ceil().max(1.0) as usize;
            for j in 0..k {
                let f = j as f64 / k as f64;
                pts.push([a.x + f * (b.x - a.x), a.y + f * (b.y - a.y)]);
                seg_of.push(i);
            }
        }
        let last = traj.poses.last().expect("trajectory has >= 2 poses");
        pts.push([last.x, last.y]);
        seg_of.push(traj.poses.len() - 2);
        let tree = kiddo::ImmutableKdTree::new_from_slice(&pts).expect("finite trajectory samples");
        Self { traj, tree, seg_of }
    }

    /// Nearest station: the nearest sample's segment and its neighbours are searched exactly.
    pub fn locate(&self, x: f64, y: f64) -> Station {
        let nn = self
            .tree
            .query(&[x, y])
            .nearest_one::<kiddo::SquaredEuclidean<f64>>()
            .execute();
        let s = self.seg_of[nn.item as usize];
        self.traj.locate_in(x, y, Some((s.saturating_sub(1), s + 1)))
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(t: f64, x: f64, y: f64) -> Pose {
        Pose {
            time: t,
            x,
            y,
            z: 0.0,
            heading_deg: None,
            roll_deg: None,
            pitch_deg: None,
        }
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
        let (p, _) = t.at_mileage(12.0);
        assert!((p[0] - 10.0).abs() < 1e-12 && (p[1] - 2.0).abs() < 1e-12);
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
