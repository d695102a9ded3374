//! Trajectory table reader (the contract's text format).
//!
//! **What.** A text table with a header row; delimiter comma, semicolon, tab or runs of
//! spaces; required columns `time` (aliases `gps_time`, `gpstime`, `t`, `timestamp`), `x`,
//! `y` (aliases `easting`, `northing`); optional `z` (`altitude`, `height`, `elevation`),
//! `heading`, `roll`, `pitch` (each also with a `_deg` suffix), degrees; other columns are
//! ignored. Names are case-insensitive, may be quoted and may carry a unit suffix
//! (`time[s]`, `x (m)`).
//!
//! **Algorithm.** A UTF-8 byte-order mark is dropped; blank lines and lines starting with `#`
//! or `//` are skipped. The first remaining line is the header, unless it holds only numbers
//! and the comment line just before it names the columns (`# time x y`, as some exporters
//! write), which is then taken as the header. The delimiter is detected from the header line:
//! comma, else semicolon, else tab, else runs of whitespace. Every data row must have a
//! number in each required column (an empty optional cell is "not given"); rows may carry
//! extra trailing cells. The poses go to [`Trajectory::new`], which sorts them by time and
//! merges repeated positions.
//!
//! **Parameters.** None.
//!
//! **Reference.** `CONTRACT.md` § Trajectory.
//!
//! **Complexity.** O(n) in the text length plus O(n log n) for the time sort.

use crate::pipeline::error::PipelineError;
use crate::pipeline::types::{Pose, Trajectory, TrajectoryError};
use serde::Serialize;
use std::path::Path;

/// A column delimiter of the table.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Delimiter {
    Comma,
    Semicolon,
    Tab,
    Whitespace,
}

impl Delimiter {
    fn detect(header: &str) -> Self {
        if header.contains(',') {
            Delimiter::Comma
        } else if header.contains(';') {
            Delimiter::Semicolon
        } else if header.contains('\t') {
            Delimiter::Tab
        } else {
            Delimiter::Whitespace
        }
    }

    /// Calls `f` for each cell of `line` (trimmed); stops early when `f` returns false.
    fn for_each_cell<'a>(self, line: &'a str, mut f: impl FnMut(&'a str) -> bool) {
        match self {
            Delimiter::Whitespace => {
                for cell in line.split_whitespace() {
                    if !f(cell) {
                        return;
                    }
                }
            }
            _ => {
                let sep = match self {
                    Delimiter::Comma => ',',
                    Delimiter::Semicolon => ';',
                    _ => '\t',
                };
                for cell in line.split(sep) {
                    if !f(cell.trim()) {
                        return;
                    }
                }
            }
        }
    }

    fn describe(self) -> &'static str {
        match self {
            Delimiter::Comma => "comma",
            Delimiter::Semicolon => "semicolon",
            Delimiter::Tab => "tab",
            Delimiter::Whitespace => "spaces",
        }
    }
}

/// The known columns, in [`Layout::index`] order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Field {
    Time,
    X,
    Y,
    Z,
    Heading,
    Roll,
    Pitch,
}

const FIELDS: [Field; 7] = [
    Field::Time,
    Field::X,
    Field::Y,
    Field::Z,
    Field::Heading,
    Field::Roll,
    Field::Pitch,
];

impl Field {
    fn name(self) -> &'static str {
        match self {
            Field::Time => "time",
            Field::X => "x",
            Field::Y => "y",
            Field::Z => "z",
            Field::Heading => "heading",
            Field::Roll => "roll",
            Field::Pitch => "pitch",
        }
    }

    fn from_header_name(name: &str) -> Option<Field> {
        Some(match name {
            "time" | "gps_time" | "gpstime" | "gps time" | "t" | "timestamp" => Field::Time,
            "x" | "easting" => Field::X,
            "y" | "northing" => Field::Y,
            "z" | "altitude" | "height" | "elevation" => Field::Z,
            "heading" | "heading_deg" => Field::Heading,
            "roll" | "roll_deg" => Field::Roll,
            "pitch" | "pitch_deg" => Field::Pitch,
            _ => return None,
        })
    }
}

/// The header row, understood.
#[derive(Clone, Debug)]
struct Layout {
    delimiter: Delimiter,
    /// Cell index of each [`FIELDS`] entry, when present.
    index: [Option<usize>; 7],
    /// All column names as found (normalised), for summaries and error messages.
    names: Vec<String>,
}

/// Normalised column name: trimmed, unquoted, lower case, without a unit suffix.
fn normalise_column(raw: &str) -> String {
    let s = raw.trim().trim_matches(|c| c == '"' || c == '\'').trim();
    let s = s.split(['[', '(']).next().unwrap_or(s).trim();
    s.to_lowercase()
}

/// Why a line is not a usable header.
enum HeaderError {
    /// The line holds only numbers.
    Numeric,
    /// Names found, but the required ones are missing.
    Missing {
        found: Vec<String>,
        missing: Vec<&'static str>,
    },
    /// A known column appears twice.
    Duplicate(&'static str),
}

fn parse_header(line: &str) -> Result<Layout, HeaderError> {
    let delimiter = Delimiter::detect(line);
    let mut names = Vec::new();
    delimiter.for_each_cell(line, |c| {
        names.push(normalise_column(c));
        true
    });
    if names.iter().all(|n| n.is_empty() || n.parse::<f64>().is_ok()) {
        return Err(HeaderError::Numeric);
    }
    let mut index = [None; 7];
    for (i, name) in names.iter().enumerate() {
        if let Some(field) = Field::from_header_name(name) {
            let slot = &mut index[field as usize];
            if slot.is_some() {
                return Err(HeaderError::Duplicate(field.name()));
            }
            *slot = Some(i);
        }
    }
    let missing: Vec<&'static str> = [Field::Time, Field::X, Field::Y]
        .into_iter()
        .filter(|f| index[*f as usize].is_none())
        .map(|f| f.name())
        .collect();
    if !missing.is_empty() {
        return Err(HeaderError::Missing {
            found: names,
            missing,
        });
    }
    Ok(Layout {
        delimiter,
        index,
        names,
    })
}

/// Lines of the table with their 1-based line numbers: BOM dropped, `\r` trimmed, blank lines
/// skipped. Comment lines are kept (flagged) so a commented header can be recognised.
fn lines(text: &str) -> impl Iterator<Item = (usize, &str, bool)> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    text.split('\n').enumerate().filter_map(|(i, l)| {
        let l = l.trim_end_matches('\r');
        let t = l.trim_start();
        if t.is_empty() {
            None
        } else {
            let comment = t.starts_with('#') || t.starts_with("//");
            Some((i + 1, l, comment))
        }
    })
}

fn strip_comment(line: &str) -> &str {
    let t = line.trim_start();
    t.strip_prefix("//").or_else(|| t.strip_prefix('#')).unwrap_or(t)
}

fn missing_columns_message(found: &[String], missing: &[&str]) -> String {
    format!(
        "unknown column layout: found columns [{}], missing required {} (required: time (or gps_time, t), x, y; \
         optional: z, heading, roll, pitch)",
        found.join(", "),
        missing.join(", ")
    )
}

/// Locate the header: returns the layout and the line number after which data rows start.
fn find_header(text: &str, path: &Path) -> Result<(Layout, usize), PipelineError> {
    let mut last_comment: Option<(usize, &str)> = None;
    for (no, line, comment) in lines(text) {
        if comment {
            last_comment = Some((no, line));
            continue;
        }
        return match parse_header(line) {
            Ok(layout) => Ok((layout, no)),
            Err(HeaderError::Numeric) => {
                // `# time x y` style header in the comment just above the first data row.
                if let Some(Ok(layout)) = last_comment.map(|(_, c)| parse_header(strip_comment(c))) {
                    return Ok((layout, no - 1));
                }
                Err(PipelineError::input(
                    path,
                    format!(
                        "no header row: line {no} ('{}') holds numbers; the table needs a header such as \
                         'time,x,y,z'",
                        truncate(line, 60)
                    ),
                ))
            }
            Err(HeaderError::Missing { found, missing }) => Err(PipelineError::input(
                path,
                missing_columns_message(&found, &missing),
            )),
            Err(HeaderError::Duplicate(name)) => Err(PipelineError::input(
                path,
                format!("column '{name}' appears more than once in the header (line {no})"),
            )),
        };
    }
    Err(PipelineError::input(
        path,
        if last_comment.is_some() {
            "empty trajectory: the file holds only comments, no header row and no data"
        } else {
            "empty trajectory: the file has no header row and no data"
        },
    ))
}

fn truncate(s: &str, n: usize) -> String {
    if s.chars().count() <= n {
        s.to_string()
    } else {
        format!("{}…", s.chars().take(n).collect::<String>())
    }
}

/// What a trajectory table holds (for upload summaries).
#[derive(Clone, Debug, Serialize)]
pub struct TrajectorySummary {
    /// Data rows in the table.
    pub row_count: usize,
    /// Poses kept after sorting and merging repeated positions.
    pub pose_count: usize,
    /// Column names as found (lower case).
    pub columns: Vec<String>,
    pub delimiter: Delimiter,
    /// [first, last] time.
    pub time_range: [f64; 2],
    /// Length of the track (m).
    pub length_m: f64,
    pub has_z: bool,
    pub has_heading: bool,
}

/// Parse a trajectory table held in memory; `name_for_errors` names it in error messages.
pub fn parse_trajectory(text: &str, name_for_errors: &Path) -> Result<Trajectory, PipelineError> {
    parse_with_summary(text, name_for_errors).map(|(t, _)| t)
}

/// Parse a trajectory table and describe it.
pub fn parse_with_summary(text: &str, path: &Path) -> Result<(Trajectory, TrajectorySummary), PipelineError> {
    let (layout, header_line) = find_header(text, path)?;
    let needed = layout.index.iter().flatten().max().copied().unwrap_or(0) + 1;
    let mut poses = Vec::new();
    let mut cells: Vec<&str> = Vec::with_capacity(layout.names.len().max(needed));
    for (no, line, comment) in lines(text) {
        if no <= header_line || comment {
            continue;
        }
        cells.clear();
        layout.delimiter.for_each_cell(line, |c| {
            cells.push(c);
            true
        });
        if cells.len() < needed {
            return Err(PipelineError::input(
                path,
                format!(
                    "line {no} has {} cells but the header ({} delimited) needs at least {needed}: '{}'",
                    cells.len(),
                    layout.delimiter.describe(),
                    truncate(line, 60)
                ),
            ));
        }
        let mut values = [f64::NAN; 7];
        let mut given = [false; 7];
        for field in FIELDS {
            let Some(col) = layout.index[field as usize] else {
                continue;
            };
            let cell = cells[col];
            let required = matches!(field, Field::Time | Field::X | Field::Y);
            if cell.is_empty() {
                if required {
                    return Err(PipelineError::input(
                        path,
                        format!(
                            "line {no}, column '{}': empty cell, a number is required",
                            field.name()
                        ),
                    ));
                }
                continue;
            }
            let v: f64 = cell.parse().map_err(|_| {
                PipelineError::input(
                    path,
                    format!(
                        "line {no}, column '{}' (column {}): '{}' is not a number",
                        field.name(),
                        col + 1,
                        truncate(cell, 40)
                    ),
                )
            })?;
            if required && !v.is_finite() {
                return Err(PipelineError::input(
                    path,
                    format!(
                        "line {no}, column '{}': '{cell}' is not a finite number",
                        field.name()
                    ),
                ));
            }
            values[field as usize] = v;
            given[field as usize] = v.is_finite();
        }
        let opt = |f: Field| given[f as usize].then_some(values[f as usize]);
        poses.push(Pose {
            time: values[Field::Time as usize],
            x: values[Field::X as usize],
            y: values[Field::Y as usize],
            z: values[Field::Z as usize],
            heading_deg: opt(Field::Heading),
            roll_deg: opt(Field::Roll),
            pitch_deg: opt(Field::Pitch),
        });
    }
    let row_count = poses.len();
    let traj = Trajectory::new(poses).map_err(|e| {
        PipelineError::input(
            path,
            match e {
                TrajectoryError::Empty => {
                    "empty trajectory: the table has a header but no data rows".to_string()
                }
                TrajectoryError::TooShort(n) => format!(
                    "the trajectory needs at least 2 distinct positions, found {n} (in {row_count} rows)"
                ),
                TrajectoryError::NonFinite { row } => format!("non-finite value in data row {}", row + 1),
            },
        )
    })?;
    let poses = traj.poses();
    let summary = TrajectorySummary {
        row_count,
        pose_count: poses.len(),
        columns: layout.names.clone(),
        delimiter: layout.delimiter,
        time_range: [poses[0].time, poses[poses.len() - 1].time],
        length_m: traj.length_m(),
        has_z: layout.index[Field::Z as usize].is_some(),
        has_heading: layout.index[Field::Heading as usize].is_some(),
    };
    Ok((traj, summary))
}

/// Read a file's text: errors for missing, empty and binary files. The first bytes are
/// checked before the rest is read, so a multi-gigabyte point file given by mistake is
/// refused at once.
fn read_text(path: &Path) -> Result<String, PipelineError> {
    use std::io::Read;
    let io_err = |e| PipelineError::Io {
        path: path.to_path_buf(),
        source: e,
    };
    let mut file = super::open_file(path)?;
    let mut bytes = Vec::new();
    (&mut file)
        .take(super::SNIFF_BYTES as u64)
        .read_to_end(&mut bytes)
        .map_err(io_err)?;
    if bytes.starts_with(b"LASF") {
        return Err(PipelineError::input(
            path,
            "this is a LAS/LAZ point file, not a trajectory table",
        ));
    }
    if bytes.contains(&0) {
        return Err(PipelineError::input(
            path,
            "not a text file (it contains NUL bytes); a trajectory is a text table",
        ));
    }
    file.read_to_end(&mut bytes).map_err(io_err)?;
    if bytes.iter().all(|b| b.is_ascii_whitespace()) {
        return Err(PipelineError::input(
            path,
            if bytes.is_empty() {
                "empty trajectory: the file is empty (0 bytes)"
            } else {
                "empty trajectory: the file holds only blank lines"
            },
        ));
    }
    if bytes.contains(&0) {
        return Err(PipelineError::input(
            path,
            "not a text file (it contains NUL bytes); a trajectory is a text table",
        ));
    }
    // Names and numbers are ASCII; a stray Latin-1 byte in a comment must not stop the job.
    Ok(match String::from_utf8(bytes) {
        Ok(s) => s,
        Err(e) => String::from_utf8_lossy(e.as_bytes()).into_owned(),
    })
}

/// Read a trajectory table from a file.
pub fn read_trajectory(path: &Path) -> Result<Trajectory, PipelineError> {
    parse_trajectory(&read_text(path)?, path)
}

/// Read a trajectory table and describe it (row count, columns, time range, length).
pub fn inspect_trajectory(path: &Path) -> Result<TrajectorySummary, PipelineError> {
    parse_with_summary(&read_text(path)?, path).map(|(_, s)| s)
}

/// Whether the first bytes of a file look like a trajectory table: printable text whose
/// first non-comment line is a header naming time, x and y.
pub(super) fn looks_like_trajectory(head: &[u8]) -> bool {
    // The head may end in the middle of a UTF-8 sequence or of a line.
    let text = match std::str::from_utf8(head) {
        Ok(s) => s,
        Err(e) => match std::str::from_utf8(&head[..e.valid_up_to()]) {
            Ok(s) if head.len() - e.valid_up_to() < 4 => s,
            _ => return false,
        },
    };
    if text
        .chars()
        .any(|c| c.is_control() && !matches!(c, '\n' | '\r' | '\t'))
    {
        return false;
    }
    let mut last_comment = None;
    for (_, line, comment) in lines(text) {
        if comment {
            last_comment = Some(line);
            continue;
        }
        return match parse_header(line) {
            Ok(_) => true,
            Err(HeaderError::Numeric) => last_comment.is_some_and(|c| parse_header(strip_comment(c)).is_ok()),
            Err(_) => false,
        };
    }
    false
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Trajectory, String> {
        parse_trajectory(text, Path::new("traj.csv")).map_err(|e| e.to_string())
    }

    #[test]
    fn every_delimiter_parses_the_same_track() {
        for text in [
            "time,x,y,z\n0,0,0,1\n1,10,0,1\n2,20,0,1\n",
            "time;x;y;z\n0;0;0;1\n1;10;0;1\n2;20;0;1\n",
            "time\tx\ty\tz\n0\t0\t0\t1\n1\t10\t0\t1\n2\t20\t0\t1\n",
            "time   x  y z\n0 0   0 1\n  1 10 0 1\n2\t20 0 1\n",
        ] {
            let t = parse(text).unwrap_or_else(|e| panic!("{e}\n{text}"));
            assert_eq!(t.poses().len(), 3, "{text}");
            assert_eq!(t.length_m(), 20.0);
            assert_eq!(t.poses()[2].z, 1.0);
        }
    }

    #[test]
    fn aliases_case_units_bom_comments_and_blank_lines() {
        let text = "\u{feff}# exported by a test\r\n\r\nGPS_Time,\"X\" , Y[m],Heading,ignored\r\n\
                    # a comment between rows\r\n100.5,1,2,90,abc\r\n\r\n101.5,3,2,,zzz\r\n";
        let t = parse(text).unwrap();
        let p = t.poses();
        assert_eq!(p.len(), 2);
        assert_eq!((p[0].time, p[0].x, p[0].y), (100.5, 1.0, 2.0));
        assert_eq!(p[0].heading_deg, Some(90.0));
        assert_eq!(p[1].heading_deg, None, "empty optional cell");
        assert!(p[0].z.is_nan(), "no z column");
        let t = parse("T EASTING NORTHING\n0 1 1\n1 2 2\n").unwrap();
        assert_eq!(t.poses().len(), 2);
    }

    #[test]
    fn commented_header_is_recognised() {
        let t = parse("# time x y\n0 0 0\n1 5 0\n").unwrap();
        assert_eq!(t.length_m(), 5.0);
    }

    #[test]
    fn errors_name_the_problem() {
        let e = parse("").unwrap_err();
        assert!(e.contains("traj.csv") && e.contains("empty trajectory"), "{e}");
        let e = parse("# only a comment\n").unwrap_err();
        assert!(e.contains("empty trajectory"), "{e}");
        let e = parse("time,x,y\n").unwrap_err();
        assert!(e.contains("header but no data rows"), "{e}");
        let e = parse("0,1,2\n1,2,3\n").unwrap_err();
        assert!(e.contains("no header row") && e.contains("line 1"), "{e}");
        let e = parse("a,b,c,x\n1,2,3,4\n").unwrap_err();
        assert!(
            e.contains("unknown column layout") && e.contains("[a, b, c, x]") && e.contains("time, y"),
            "{e}"
        );
        let e = parse("time,x,y\n0,1,2\n1,abc,3\n").unwrap_err();
        assert!(
            e.contains("line 3") && e.contains("'x'") && e.contains("'abc'"),
            "{e}"
        );
        let e = parse("time,x,y\n0,1,2\n1,2\n").unwrap_err();
        assert!(e.contains("line 3 has 2 cells"), "{e}");
        let e = parse("time,x,y\n0,1,2\n").unwrap_err();
        assert!(e.contains("at least 2 distinct positions, found 1"), "{e}");
        let e = parse("time,x,y\n0,1,2\n1,1,2\n").unwrap_err();
        assert!(e.contains("found 1"), "{e}");
        let e = parse("time,x,x,y\n0,1,1,2\n").unwrap_err();
        assert!(e.contains("'x' appears more than once"), "{e}");
        let e = parse("time,x,y\n0,inf,2\n1,2,3\n").unwrap_err();
        assert!(e.contains("not a finite number"), "{e}");
    }

    #[test]
    fn sniffing_text() {
        assert!(looks_like_trajectory(b"time,x,y,z\n0,1,2,3\n"));
        assert!(looks_like_trajectory(b"\xef\xbb\xbfGPS_TIME;X;Y\n"));
        assert!(looks_like_trajectory(b"# t x y\n0 1 2\n"));
        assert!(!looks_like_trajectory(b"0,1,2\n"));
        assert!(!looks_like_trajectory(b"hello world\n"));
        assert!(!looks_like_trajectory(b"time,x,y\0\0\0"));
        assert!(!looks_like_trajectory(b""));
        // Cut in the middle of a multi-byte character.
        assert!(looks_like_trajectory(
            "time,x,y,\"é".as_bytes().split_last().unwrap().1
        ));
    }

    mod properties {
        use super::*;
        use proptest::prelude::*;

        proptest! {
            /// Any text: a trajectory or an input error, never a panic.
            #[test]
            fn arbitrary_text_never_panics(text in "\\PC{0,200}") {
                let _ = parse_trajectory(&text, Path::new("p.csv"));
                let _ = looks_like_trajectory(text.as_bytes());
            }

            /// Column order, extra columns, delimiter and name case do not change the poses.
            #[test]
            fn layout_does_not_change_the_poses(
                order in Just(vec![0usize, 1, 2, 3, 4]).prop_shuffle(),
                delimiter in 0usize..4,
                upper in any::<bool>(),
                rows in proptest::collection::vec((-1e6f64..1e6, -1e6f64..1e6, -100f64..100.0), 2..20),
            ) {
                let names = ["time", "x", "y", "z", "quality"];
                let sep = [",", ";", "\t", "   "][delimiter];
                let cell = |name: &str| if upper { name.to_uppercase() } else { name.to_string() };
                let mut text = order.iter().map(|&c| cell(names[c])).collect::<Vec<_>>().join(sep);
                text.push('\n');
                for (i, (x, y, z)) in rows.iter().enumerate() {
                    let values = [i as f64, *x, *y, *z, 7.0];
                    let line: Vec<String> = order.iter().map(|&c| format!("{}", values[c])).collect();
                    text.push_str(&line.join(sep));
                    text.push('\n');
                }
                match parse_trajectory(&text, Path::new("p.csv")) {
                    Ok(t) => {
                        for p in t.poses() {
                            let (x, y, z) = rows[p.time as usize];
                            prop_assert_eq!((p.x, p.y, p.z), (x, y, z));
                        }
                    }
                    // Rows can coincide (merged); fewer than 2 distinct positions is an error.
                    Err(e) => prop_assert!(e.to_string().contains("distinct positions"), "{}", e),
                }
            }
        }
    }
}
