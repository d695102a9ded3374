//! Where the pavement was seen bare: a coarse record, over the whole drive, of the pavement
//! points that are clearly not paint, so that lane-line growth can tell a gap the scanner
//! saw as asphalt (a dash gap, paint worn away, the end of a line) from a gap it did not
//! see (a car in between, or a far line crossed by too few scan rows: its paint returns
//! few points and the asphalt beside it returns more, but its own course holds no dark
//! point at all).
//!
//! # Interface
//! - Per chunk, [`dark_rows`] counts the dark pavement points of the core (normalised value
//!   below [`DARK_MAX`]) in cells of [`CELL_ALONG_M`] × [`CELL_ACROSS_M`] in the chunk
//!   frame (mileage, offset of the trajectory).
//! - [`Observed`] gathers the rows of all chunks (cells at global multiples, so nothing
//!   depends on the chunking); [`Observed::gap`] reads it along a course given in absolute
//!   coordinates and says whether the course was seen bare ([`Gap`]).
//!
//! # Algorithm
//! A course is sampled every [`CELL_ALONG_M`] / 2. Its dark points are those in the cells
//! within `half_width` of it; the asphalt density expected there is that of the cells
//! [`BESIDE_FROM_M`]–[`BESIDE_TO_M`] beside it on both sides (paint of the line itself is
//! never there). A gap is *seen bare* when its course holds at least
//! [`SEEN_MIN_DARK`] dark points and at least [`SEEN_MIN_SHARE`] of the dark points the
//! density beside it predicts; *unseen* when the prediction is at least
//! [`SEEN_MIN_DARK`] points (so the scanner would have shown bare asphalt) but the course
//! holds under [`SEEN_MIN_SHARE`] of it, or when neither the course nor its sides hold any
//! point (an occlusion); otherwise the evidence is too thin to say.
//!
//! # Complexity
//! O(p) per chunk for p pavement points; memory one byte per cell, 1.2 MB per km of drive
//! at the default 30 m offset limit. O(L) per course of L m.

use super::types::{StationIndex, Trajectory};

/// Cell length along the trajectory (m).
pub const CELL_ALONG_M: f64 = 1.0;
/// Cell width across the trajectory (m): a third of a lane line's width, so a course
/// predicted a few centimetres off still lies on the line's cells.
pub const CELL_ACROSS_M: f64 = 0.05;
/// Normalised values (intensity over the asphalt background) below this are dark: no
/// reading of paint, even worn paint at 1.5 × the asphalt, is that dim.
pub const DARK_MAX: f32 = 1.3;
/// The band beside a course whose dark points predict the asphalt density (m from the
/// course, both sides): clear of any line's paint (≤ 0.3 m wide with its scatter) and
/// close enough to see the same range and incidence.
pub const BESIDE_FROM_M: f64 = 0.3;
pub const BESIDE_TO_M: f64 = 0.8;
/// Fewest dark points that make a seen-bare course, or its prediction, count.
pub const SEEN_MIN_DARK: f64 = 3.0;
/// Share of the predicted dark points a course must hold to be seen bare.
pub const SEEN_MIN_SHARE: f64 = 0.3;

/// The dark counts of one chunk's core: rows from global row `first_row`, `cols` cells
/// each (offset −`max_off` upwards).
#[derive(Debug, Default)]
pub struct DarkRows {
    first_row: i64,
    counts: Vec<u8>,
}

fn cols_for(max_off: f64) -> usize {
    ((2.0 * max_off / CELL_ACROSS_M).ceil() as usize).max(1)
}

/// Count the dark points (`values` < [`DARK_MAX`]) of the core `core_lo..core_hi` by cell;
/// `m`, `o` are the points' mileages and offsets, `max_off` the offset limit of the drive.
pub fn dark_rows(
    m: &[f64],
    o: &[f64],
    values: &[f32],
    (core_lo, core_hi): (f64, f64),
    max_off: f64,
) -> DarkRows {
    let cols = cols_for(max_off);
    let first_row = (core_lo / CELL_ALONG_M).floor() as i64;
    let last_row = ((core_hi / CELL_ALONG_M).ceil() as i64).max(first_row);
    let n_rows = (last_row - first_row) as usize;
    let mut counts = vec![0u8; n_rows * cols];
    for ((&mi, &oi), &v) in m.iter().zip(o).zip(values) {
        if !(v < DARK_MAX && mi >= core_lo && mi < core_hi && oi.abs() < max_off) {
            continue;
        }
        let row = (mi / CELL_ALONG_M).floor() as i64 - first_row;
        let col = ((oi + max_off) / CELL_ACROSS_M).floor() as usize;
        if row >= 0 && (row as usize) < n_rows && col < cols {
            let c = &mut counts[row as usize * cols + col];
            *c = c.saturating_add(1);
        }
    }
    DarkRows { first_row, counts }
}

/// What a course across a gap shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Gap {
    /// Bare asphalt was seen on the course: the paint is not there.
    SeenBare,
    /// The scanner did not see the course (or only its paint): no evidence of a break.
    Unseen,
    /// Too few points to tell.
    Unknown,
}

/// Dark counts over the whole drive, in the frame of the job-local trajectory.
pub struct Observed {
    traj: Trajectory,
    origin: [f64; 2],
    max_off: f64,
    cols: usize,
    first_row: i64,
    counts: Vec<u8>,
}

impl Observed {
    /// An empty record for `traj` (job-local coordinates, `origin` added to make them
    /// absolute) with offsets up to `max_off`.
    pub fn new(traj: Trajectory, origin: [f64; 3], max_off: f64) -> Self {
        Self {
            traj,
            origin: [origin[0], origin[1]],
            max_off,
            cols: cols_for(max_off),
            first_row: 0,
            counts: Vec::new(),
        }
    }

    /// Add one chunk's rows (cores do not overlap; counts add where they would).
    pub fn add(&mut self, rows: &DarkRows) {
        if rows.counts.is_empty() {
            return;
        }
        let n_rows = (rows.counts.len() / self.cols) as i64;
        if self.counts.is_empty() {
            self.first_row = rows.first_row;
        }
        let lo = self.first_row.min(rows.first_row);
        let hi = (self.first_row + (self.counts.len() / self.cols) as i64).max(rows.first_row + n_rows);
        if lo < self.first_row {
            let pad = (self.first_row - lo) as usize * self.cols;
            self.counts.splice(0..0, std::iter::repeat_n(0u8, pad));
            self.first_row = lo;
        }
        self.counts.resize((hi - lo) as usize * self.cols, 0);
        let at = (rows.first_row - self.first_row) as usize * self.cols;
        for (c, &r) in self.counts[at..at + rows.counts.len()]
            .iter_mut()
            .zip(&rows.counts)
        {
            *c = c.saturating_add(r);
        }
    }

    fn count(&self, row: i64, col: i64) -> u32 {
        let r = row - self.first_row;
        if r < 0 || col < 0 || col as usize >= self.cols {
            return 0;
        }
        self.counts
            .get(r as usize * self.cols + col as usize)
            .map_or(0, |&c| c as u32)
    }

    /// A reader of the record (it indexes the trajectory once for all its queries).
    pub fn lookup(&self) -> Lookup<'_> {
        Lookup {
            obs: self,
            index: StationIndex::new(&self.traj, 1.0),
        }
    }
}

/// Queries on an [`Observed`] record.
pub struct Lookup<'a> {
    obs: &'a Observed,
    index: StationIndex<'a>,
}

impl Lookup<'_> {
    /// The evidence along `course` (absolute coordinates, in order), whose paint is
    /// `half_width` either side of it. See the module docs.
    pub fn gap(&self, course: &[[f64; 2]], half_width: f64) -> Gap {
        let obs = self.obs;
        if course.len() < 2 || obs.counts.is_empty() {
            return Gap::Unknown;
        }
        let index = &self.index;
        let mut hint = usize::MAX;
        let step = CELL_ALONG_M / 2.0;
        let (mut on, mut on_cells, mut beside, mut beside_cells) = (0.0, 0.0, 0.0, 0.0);
        for w in course.windows(2) {
            let (a, b) = (w[0], w[1]);
            let len = (b[0] - a[0]).hypot(b[1] - a[1]);
            let n = (len / step).ceil().max(1.0) as usize;
            for k in 0..n {
                let t = (k as f64 + 0.5) / n as f64;
                let x = a[0] + t * (b[0] - a[0]) - obs.origin[0];
                let y = a[1] + t * (b[1] - a[1]) - obs.origin[1];
                let st = index.locate_near(x, y, &mut hint);
                // One sample per half cell along: each cell's count is shared by its samples.
                let row = (st.mileage_m / CELL_ALONG_M).floor() as i64;
                let col_of = |o: f64| ((o + obs.max_off) / CELL_ACROSS_M).floor() as i64;
                let share = step / CELL_ALONG_M;
                let band = |lo: f64, hi: f64| {
                    let (c0, c1) = (col_of(st.offset_m + lo), col_of(st.offset_m + hi));
                    let dark: u32 = (c0..=c1).map(|c| obs.count(row, c)).sum();
                    (dark as f64 * share, (c1 - c0 + 1) as f64 * share)
                };
                let (d, c) = band(-half_width, half_width);
                on += d;
                on_cells += c;
                for (lo, hi) in [(-BESIDE_TO_M, -BESIDE_FROM_M), (BESIDE_FROM_M, BESIDE_TO_M)] {
                    let (d, c) = band(lo, hi);
                    beside += d;
                    beside_cells += c;
                }
            }
        }
        let expected = beside / beside_cells.max(1e-9) * on_cells;
        if on >= SEEN_MIN_DARK && on >= SEEN_MIN_SHARE * expected {
            Gap::SeenBare
        } else if expected >= SEEN_MIN_DARK || (on == 0.0 && beside == 0.0) {
            Gap::Unseen
        } else {
            Gap::Unknown
        }
    }
}

/// Test record: pavement seen dark everywhere over x −20..80, |y| ≤ 5 (points every
/// 0.1 × 0.05 m), except on the course at `y` (±0.1 m) where `hidden(x)`.
#[cfg(test)]
pub(crate) fn test_seen_except(t: &Trajectory, y: f64, hidden: impl Fn(f64) -> bool) -> Observed {
    test_seen_where(t, |px, py| (py - y).abs() < 0.1 && hidden(px))
}

/// Test record: pavement seen dark everywhere over x −20..80, |y| ≤ 5 (points every
/// 0.1 × 0.05 m), except where `hidden(x, y)`.
#[cfg(test)]
pub(crate) fn test_seen_where(t: &Trajectory, hidden: impl Fn(f64, f64) -> bool) -> Observed {
    let (mut m, mut o) = (Vec::new(), Vec::new());
    for i in 0..1000 {
        for j in -100..=100 {
            let (px, py) = (-20.0 + i as f64 * 0.1 + 0.05, j as f64 * 0.05);
            if hidden(px, py) {
                continue;
            }
            let st = t.locate(px, py);
            m.push(st.mileage_m);
            o.push(st.offset_m);
        }
    }
    let mut obs = Observed::new(t.clone(), [0.0; 3], 30.0);
    obs.add(&dark_rows(&m, &o, &vec![1.0; m.len()], (0.0, 100.0), 30.0));
    obs
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::types::test_straight_trajectory;

    /// Dark points every 0.1 m along and 0.05 m across over 0..100 m × −3..3 m, except on
    /// the lines y = ±2 (a far line's course: no dark point) between x = 20 and 60, and no
    /// point at all (a car) over 70..80 m × 1..3 m either side.
    fn observed() -> Observed {
        let traj = test_straight_trajectory(100, 0.0);
        let (mut m, mut o) = (Vec::new(), Vec::new());
        for i in 0..1000 {
            for j in -60..=60 {
                let (x, y) = (i as f64 * 0.1 + 0.05, j as f64 * 0.05);
                // Symmetric across the trajectory, whichever side offsets count positive.
                let on_line = (y.abs() - 2.0).abs() < 0.1 && (20.0..60.0).contains(&x);
                let car = (70.0..80.0).contains(&x) && (1.0..3.0).contains(&y.abs());
                if !on_line && !car {
                    m.push(x);
                    o.push(y);
                }
            }
        }
        let v = vec![1.0f32; m.len()];
        let mut obs = Observed::new(traj.clone(), [0.0; 3], 30.0);
        // Two chunks, added out of order.
        obs.add(&dark_rows(&m, &o, &v, (50.0, 100.0), 30.0));
        obs.add(&dark_rows(&m, &o, &v, (0.0, 50.0), 30.0));
        obs
    }

    #[test]
    fn gaps_are_seen_bare_unseen_or_unknown() {
        let obs = observed();
        let obs = obs.lookup();
        let course = |x0: f64, x1: f64, y: f64| [[x0, y], [x1, y]];
        assert_eq!(obs.gap(&course(5.0, 15.0, 2.0), 0.05), Gap::SeenBare);
        assert_eq!(obs.gap(&course(25.0, 55.0, 2.0), 0.05), Gap::Unseen);
        // Bare over part of the gap: seen.
        assert_eq!(obs.gap(&course(50.0, 65.0, 2.0), 0.05), Gap::SeenBare);
        // Occluded, sides too.
        assert_eq!(obs.gap(&course(71.0, 79.0, 2.0), 0.05), Gap::Unseen);
        // Outside the record: nothing to go by.
        assert_eq!(obs.gap(&course(5.0, 15.0, 29.0), 0.05), Gap::Unseen);
        let empty = Observed::new(test_straight_trajectory(10, 0.0), [0.0; 3], 30.0);
        assert_eq!(empty.lookup().gap(&course(1.0, 5.0, 0.0), 0.05), Gap::Unknown);
    }

    #[test]
    fn bright_points_are_not_dark() {
        let rows = dark_rows(
            &[1.5, 1.5, 1.5],
            &[0.0, 0.0, 0.0],
            &[1.0, 2.0, 1.29],
            (0.0, 10.0),
            30.0,
        );
        assert_eq!(rows.counts.iter().map(|&c| c as u32).sum::<u32>(), 2);
        // Outside the core or the offset limit: not counted.
        let rows = dark_rows(&[10.5, 5.0], &[0.0, 31.0], &[1.0, 1.0], (0.0, 10.0), 30.0);
        assert_eq!(rows.counts.iter().map(|&c| c as u32).sum::<u32>(), 0);
    }
}
