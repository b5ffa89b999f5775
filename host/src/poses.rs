//! Handle-pose input: reading and validating a pose CSV, and resampling it to the model's
//! 1 ms tick.
//!
//! # Format
//!
//! A header with exactly the columns `t,x,y,z,qw,qx,qy,qz` (in that order), then one row per
//! sample: time in seconds, the ferrule position in millimetres, the handle orientation as a
//! unit quaternion (Hamilton, `w` first; the identity holds the brush straight down). Rows may
//! come at any rate. Fields may be surrounded by spaces.
//!
//! # Validation
//!
//! Every problem is an error naming the file, the line and (where there is one) the column;
//! nothing is silently repaired:
//!
//! * malformed CSV (a row with the wrong number of fields, invalid UTF-8), a field that is not
//!   a number, a number that is not finite;
//! * a header that is not exactly the columns above;
//! * a file without data rows;
//! * time going backwards (equal consecutive times are allowed: the later row wins from that
//!   instant on);
//! * a quaternion whose norm differs from 1 by more than [`QUAT_NORM_TOLERANCE`]. Quaternions
//!   within the tolerance are normalised.
//!
//! # Resampling
//!
//! Tick k lies at `t0 + k * 1 ms` for k = 0, 1, ... while it is not after the last row's time.
//! Positions are interpolated linearly and orientations by [`slerp`] (shortest arc) between
//! the two rows around the tick.

use std::fmt;
use std::io::Read;
use std::path::Path;

use maobi_shared::{Pose, Quat, Vec3};

/// The header a pose file must have, column by column.
pub const COLUMNS: [&str; 8] = ["t", "x", "y", "z", "qw", "qx", "qy", "qz"];

/// How far a quaternion's norm may differ from 1 before the row is rejected.
pub const QUAT_NORM_TOLERANCE: f64 = 1e-3;

/// The model's tick (seconds).
pub const TICK_S: f64 = 0.001;

/// The longest span a track may cover (s): four hours, 14.4 million ticks. Beyond it a file is
/// far more likely to be wrong (times written in milliseconds) than a session, and its
/// simulation would run for hours and its trace fill a disk.
pub const MAX_SPAN_S: f64 = 4.0 * 3600.0;

/// One validated input row.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct PoseRow {
    /// Seconds.
    pub t: f64,
    /// Ferrule position (mm).
    pub pos: [f64; 3],
    /// Unit quaternion (w, x, y, z), normalised.
    pub rot: [f64; 4],
}

impl PoseRow {
    pub fn pose(&self) -> Pose<f64> {
        Pose::new(Vec3::from_f64(self.pos), Quat::from_f64(self.rot))
    }
}

/// What is wrong with a pose file.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum PoseErrorKind {
    #[error("cannot read the file: {0}")]
    Io(String),
    #[error("the file is empty: expected the header `{}`", COLUMNS.join(","))]
    NoHeader,
    #[error("the header must be exactly `{}`, found `{found}` ({why})", COLUMNS.join(","))]
    BadHeader { found: String, why: String },
    #[error("no data rows after the header")]
    NoRows,
    #[error("expected {expected} fields, found {found}")]
    FieldCount { expected: usize, found: usize },
    #[error("malformed CSV: {0}")]
    Malformed(String),
    #[error("`{0}` is not a number")]
    NotANumber(String),
    #[error("`{0}` is not a finite number")]
    NotFinite(String),
    #[error("time {t} s is before the previous row's {prev} s (times must not decrease)")]
    TimeBackwards { t: f64, prev: f64 },
    #[error("quaternion norm {norm} differs from 1 by more than {QUAT_NORM_TOLERANCE}")]
    QuatNorm { norm: f64 },
    #[error(
        "time {t} s is {span} s after the first row's: a track may span at most {MAX_SPAN_S} s \
         (4 hours; times are in seconds, not milliseconds)"
    )]
    TooLong { t: f64, span: f64 },
}

/// A pose-file error with its place: `FILE:LINE: column `NAME`: what`.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseError {
    pub file: String,
    /// 1-based line, when the error has one.
    pub line: Option<u64>,
    /// Column name, when the error is about one field.
    pub column: Option<&'static str>,
    pub kind: PoseErrorKind,
}

impl fmt::Display for PoseError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file)?;
        if let Some(line) = self.line {
            write!(f, ":{line}")?;
        }
        write!(f, ": ")?;
        if let Some(col) = self.column {
            write!(f, "column `{col}`: ")?;
        }
        write!(f, "{}", self.kind)
    }
}

impl std::error::Error for PoseError {}

/// A validated pose file.
#[derive(Clone, Debug)]
pub struct PoseTrack {
    rows: Vec<PoseRow>,
}

impl PoseTrack {
    /// Reads and validates the pose CSV at `path`.
    pub fn from_path(path: &Path) -> Result<Self, PoseError> {
        let name = path.display().to_string();
        let file = std::fs::File::open(path).map_err(|e| PoseError {
            file: name.clone(),
            line: None,
            column: None,
            kind: PoseErrorKind::Io(e.to_string()),
        })?;
        Self::from_reader(&name, std::io::BufReader::new(file))
    }

    /// Reads and validates pose CSV from `reader`; `name` is used in error messages.
    pub fn from_reader<R: Read>(name: &str, reader: R) -> Result<Self, PoseError> {
        let err = |line: Option<u64>, column: Option<&'static str>, kind| PoseError {
            file: name.to_string(),
            line,
            column,
            kind,
        };
        let mut rdr = csv::ReaderBuilder::new()
            .has_headers(false)
            .flexible(true)
            .trim(csv::Trim::All)
            .from_reader(reader);
        let mut record = csv::StringRecord::new();

        let csv_err = |e: csv::Error| {
            let line = e.position().map(|p| p.line());
            let kind = match e.into_kind() {
                csv::ErrorKind::Io(io) => PoseErrorKind::Io(io.to_string()),
                csv::ErrorKind::Utf8 { err, .. } => {
                    PoseErrorKind::Malformed(format!("invalid UTF-8 in field {}", err.field() + 1))
                }
                other => PoseErrorKind::Malformed(format!("{other:?}")),
            };
            err(line, None, kind)
        };

        // Header.
        if !rdr.read_record(&mut record).map_err(csv_err)? {
            return Err(err(None, None, PoseErrorKind::NoHeader));
        }
        let header_line = record.position().map_or(1, |p| p.line());
        check_header(&record).map_err(|kind| err(Some(header_line), None, kind))?;

        // Rows.
        let mut rows: Vec<PoseRow> = Vec::new();
        while rdr.read_record(&mut record).map_err(csv_err)? {
            let line = record.position().map_or(0, |p| p.line());
            if record.len() != COLUMNS.len() {
                return Err(err(
                    Some(line),
                    None,
                    PoseErrorKind::FieldCount {
                        expected: COLUMNS.len(),
                        found: record.len(),
                    },
                ));
            }
            let mut v = [0.0f64; 8];
            for (i, (field, out)) in record.iter().zip(v.iter_mut()).enumerate() {
                let col = Some(COLUMNS[i]);
                let x: f64 = field
                    .parse()
                    .map_err(|_| err(Some(line), col, PoseErrorKind::NotANumber(field.into())))?;
                if !x.is_finite() {
                    return Err(err(Some(line), col, PoseErrorKind::NotFinite(field.into())));
                }
                *out = x;
            }
            let t = v[0];
            if let Some(first) = rows.first() {
                let span = t - first.t;
                if span > MAX_SPAN_S {
                    return Err(err(
                        Some(line),
                        Some("t"),
                        PoseErrorKind::TooLong { t, span },
                    ));
                }
            }
            if let Some(prev) = rows.last() {
                if t < prev.t {
                    return Err(err(
                        Some(line),
                        Some("t"),
                        PoseErrorKind::TimeBackwards { t, prev: prev.t },
                    ));
                }
            }
            let q = [v[4], v[5], v[6], v[7]];
            let norm = q.iter().map(|c| c * c).sum::<f64>().sqrt();
            if (norm - 1.0).abs() > QUAT_NORM_TOLERANCE {
                return Err(err(Some(line), None, PoseErrorKind::QuatNorm { norm }));
            }
            rows.push(PoseRow {
                t,
                pos: [v[1], v[2], v[3]],
                rot: q.map(|c| c / norm),
            });
        }
        if rows.is_empty() {
            return Err(err(None, None, PoseErrorKind::NoRows));
        }
        Ok(PoseTrack { rows })
    }

    pub fn rows(&self) -> &[PoseRow] {
        &self.rows
    }

    /// Time of the first row, which is tick 0.
    pub fn start(&self) -> f64 {
        self.rows[0].t
    }

    /// Number of 1 ms ticks the track covers, tick 0 included.
    pub fn ticks(&self) -> usize {
        let span = self.rows[self.rows.len() - 1].t - self.rows[0].t;
        // A tick that lands on the last row's time up to rounding still counts.
        (span / TICK_S + 1e-6).floor() as usize + 1
    }

    /// Time of tick k.
    pub fn tick_time(&self, k: usize) -> f64 {
        self.start() + k as f64 * TICK_S
    }

    /// The pose at tick k (k < [`Self::ticks`]).
    pub fn pose_at_tick(&self, k: usize) -> Pose<f64> {
        self.resample().nth(k).expect("tick within the track")
    }

    /// The poses at ticks 0, 1, ..., in order.
    pub fn resample(&self) -> Resample<'_> {
        Resample {
            track: self,
            k: 0,
            n: self.ticks(),
            seg: 0,
        }
    }

    /// Bounding box of the ferrule's x and y over all rows: `([min_x, min_y], [max_x, max_y])`.
    /// Interpolated positions lie between rows, so this bounds every tick too.
    pub fn xy_bounds(&self) -> ([f64; 2], [f64; 2]) {
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for r in &self.rows {
            for a in 0..2 {
                lo[a] = lo[a].min(r.pos[a]);
                hi[a] = hi[a].max(r.pos[a]);
            }
        }
        (lo, hi)
    }

    /// The ferrule's lowest height over all rows (mm; infinite for no rows). Interpolated
    /// positions lie between rows, so no tick is lower.
    pub fn lowest_z(&self) -> f64 {
        self.rows
            .iter()
            .map(|r| r.pos[2])
            .fold(f64::INFINITY, f64::min)
    }

    /// A warning if a brush whose hair is `hair_mm` long cannot touch the paper anywhere on
    /// this track (the ferrule never comes lower than that): a render of it is blank and a
    /// trace all air.
    pub fn never_reaches_paper(&self, hair_mm: f64, brush: &str) -> Option<String> {
        let lowest = self.lowest_z();
        // No rows (infinite) or a NaN says nothing about the paper.
        if !lowest.is_finite() || lowest <= hair_mm {
            return None;
        }
        Some(format!(
            "the brush never reaches the paper: the ferrule comes no lower than {lowest:.1} mm \
             above it, and the {brush} brush's hair is {hair_mm:.1} mm long"
        ))
    }
}

/// Iterator over the resampled tick poses of a [`PoseTrack`].
pub struct Resample<'a> {
    track: &'a PoseTrack,
    k: usize,
    n: usize,
    /// Index of the row at or before the current tick time.
    seg: usize,
}

impl Iterator for Resample<'_> {
    type Item = Pose<f64>;

    fn next(&mut self) -> Option<Pose<f64>> {
        if self.k >= self.n {
            return None;
        }
        let rows = &self.track.rows;
        let last = rows.len() - 1;
        let t = self.track.tick_time(self.k).min(rows[last].t);
        self.k += 1;
        // Advance to the last row whose time is not after t (so a repeated time takes the
        // later row).
        while self.seg < last && rows[self.seg + 1].t <= t {
            self.seg += 1;
        }
        let a = &rows[self.seg];
        if self.seg == last {
            return Some(a.pose());
        }
        let b = &rows[self.seg + 1];
        let u = ((t - a.t) / (b.t - a.t)).clamp(0.0, 1.0);
        let pos = [0, 1, 2].map(|i| a.pos[i] + (b.pos[i] - a.pos[i]) * u);
        Some(Pose::new(
            Vec3::from_f64(pos),
            Quat::from_f64(slerp(a.rot, b.rot, u)),
        ))
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        let left = self.n - self.k;
        (left, Some(left))
    }
}

impl ExactSizeIterator for Resample<'_> {}

/// Spherical linear interpolation between unit quaternions (w, x, y, z) along the shorter
/// arc; `u` = 0 gives `a`, 1 gives `b` (or `-b`, the same rotation).
pub fn slerp(a: [f64; 4], b: [f64; 4], u: f64) -> [f64; 4] {
    let mut d: f64 = a.iter().zip(&b).map(|(p, q)| p * q).sum();
    let mut b = b;
    if d < 0.0 {
        d = -d;
        b = b.map(|c| -c);
    }
    let (wa, wb) = if d > 0.9995 {
        // Nearly the same rotation: sin(theta) is tiny, linear weights are exact enough.
        (1.0 - u, u)
    } else {
        let theta = d.min(1.0).acos();
        let s = theta.sin();
        (((1.0 - u) * theta).sin() / s, (u * theta).sin() / s)
    };
    let q = [0, 1, 2, 3].map(|i| wa * a[i] + wb * b[i]);
    let n = q.iter().map(|c| c * c).sum::<f64>().sqrt();
    q.map(|c| c / n)
}

fn check_header(record: &csv::StringRecord) -> Result<(), PoseErrorKind> {
    let found: Vec<&str> = record.iter().collect();
    if found == COLUMNS {
        return Ok(());
    }
    let missing: Vec<&str> = COLUMNS
        .iter()
        .copied()
        .filter(|c| !found.contains(c))
        .collect();
    let unexpected: Vec<&str> = found
        .iter()
        .copied()
        .filter(|c| !COLUMNS.contains(c))
        .collect();
    let mut why = Vec::new();
    if !missing.is_empty() {
        why.push(format!("missing column(s) {}", missing.join(", ")));
    }
    if !unexpected.is_empty() {
        why.push(format!("unexpected column(s) {}", unexpected.join(", ")));
    }
    if why.is_empty() {
        if found.len() != COLUMNS.len() {
            why.push("repeated column(s)".to_string());
        } else {
            why.push("columns out of order".to_string());
        }
    }
    Err(PoseErrorKind::BadHeader {
        found: found.join(","),
        why: why.join("; "),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEADER: &str = "t,x,y,z,qw,qx,qy,qz\n";

    fn parse(text: &str) -> Result<PoseTrack, PoseError> {
        PoseTrack::from_reader("test.csv", text.as_bytes())
    }

    fn parse_err(text: &str) -> PoseError {
        parse(text).expect_err("should be rejected")
    }

    #[test]
    fn reads_valid_file() {
        let t = parse(&format!(
            "{HEADER}0,1,2,3,1,0,0,0\n 0.01 , 2 , 2 , 3 , 1 , 0 , 0 , 0 \n"
        ))
        .unwrap();
        assert_eq!(t.rows().len(), 2);
        assert_eq!(t.rows()[1].pos, [2.0, 2.0, 3.0]);
        assert_eq!(t.ticks(), 11);
    }

    #[test]
    fn empty_file() {
        let e = parse_err("");
        assert_eq!(e.kind, PoseErrorKind::NoHeader);
        assert!(e.to_string().starts_with("test.csv: "), "{e}");
    }

    #[test]
    fn header_only() {
        let e = parse_err(HEADER);
        assert_eq!(e.kind, PoseErrorKind::NoRows);
        assert!(e.to_string().contains("no data rows"), "{e}");
    }

    #[test]
    fn missing_header_column() {
        let e = parse_err("t,x,y,z,qw,qx,qy\n0,0,0,0,1,0,0\n");
        assert_eq!(e.line, Some(1));
        assert!(e.to_string().contains("missing column(s) qz"), "{e}");
    }

    #[test]
    fn wrong_header_column() {
        let e = parse_err("time,x,y,z,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n");
        let s = e.to_string();
        assert!(s.contains("missing column(s) t"), "{s}");
        assert!(s.contains("unexpected column(s) time"), "{s}");
        assert!(s.starts_with("test.csv:1: "), "{s}");
    }

    #[test]
    fn header_out_of_order_or_repeated() {
        let e = parse_err("t,y,x,z,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n");
        assert!(e.to_string().contains("out of order"), "{e}");
        let e = parse_err("t,x,y,z,qw,qx,qy,qz,qz\n0,0,0,0,1,0,0,0,0\n");
        assert!(e.to_string().contains("repeated"), "{e}");
    }

    #[test]
    fn data_without_header() {
        let e = parse_err("0,0,0,0,1,0,0,0\n");
        assert!(matches!(e.kind, PoseErrorKind::BadHeader { .. }), "{e}");
    }

    #[test]
    fn wrong_field_count() {
        let e = parse_err(&format!("{HEADER}0,0,0,0,1,0,0,0\n0.1,0,0,0,1,0,0\n"));
        assert_eq!(e.line, Some(3));
        assert_eq!(
            e.kind,
            PoseErrorKind::FieldCount {
                expected: 8,
                found: 7
            }
        );
        assert!(e.to_string().starts_with("test.csv:3: "), "{e}");
    }

    #[test]
    fn invalid_utf8() {
        let mut bytes = HEADER.as_bytes().to_vec();
        bytes.extend_from_slice(b"0,0,0,\xff,1,0,0,0\n");
        let e = PoseTrack::from_reader("test.csv", &bytes[..]).unwrap_err();
        assert_eq!(e.line, Some(2));
        assert!(matches!(e.kind, PoseErrorKind::Malformed(_)), "{e}");
    }

    #[test]
    fn not_a_number() {
        let e = parse_err(&format!("{HEADER}0,0,0,0,1,0,0,0\n0.1,0,abc,0,1,0,0,0\n"));
        assert_eq!(e.line, Some(3));
        assert_eq!(e.column, Some("y"));
        assert_eq!(
            e.to_string(),
            "test.csv:3: column `y`: `abc` is not a number"
        );
    }

    #[test]
    fn empty_field() {
        let e = parse_err(&format!("{HEADER}0,0,0,0,,0,0,0\n"));
        assert_eq!((e.line, e.column), (Some(2), Some("qw")));
        assert!(matches!(e.kind, PoseErrorKind::NotANumber(_)));
    }

    #[test]
    fn non_finite() {
        for bad in ["NaN", "inf", "-infinity", "1e999"] {
            let e = parse_err(&format!("{HEADER}0,0,0,{bad},1,0,0,0\n"));
            assert_eq!((e.line, e.column), (Some(2), Some("z")), "{bad}");
            assert!(matches!(e.kind, PoseErrorKind::NotFinite(_)), "{bad}: {e}");
        }
    }

    #[test]
    fn time_backwards() {
        let e = parse_err(&format!(
            "{HEADER}0,0,0,0,1,0,0,0\n0.02,0,0,0,1,0,0,0\n0.01,0,0,0,1,0,0,0\n"
        ));
        assert_eq!((e.line, e.column), (Some(4), Some("t")));
        assert!(e.to_string().contains("before the previous row"), "{e}");
    }

    #[test]
    fn repeated_time_is_allowed_and_later_row_wins() {
        let t = parse(&format!(
            "{HEADER}0,0,0,0,1,0,0,0\n0.002,0,0,0,1,0,0,0\n0.002,5,0,0,1,0,0,0\n0.004,5,0,0,1,0,0,0\n"
        ))
        .unwrap();
        let xs: Vec<f64> = t.resample().map(|p| p.pos.x).collect();
        assert_eq!(xs, [0.0, 0.0, 5.0, 5.0, 5.0]);
    }

    #[test]
    fn quaternion_norm() {
        let e = parse_err(&format!("{HEADER}0,0,0,0,1,0,0.1,0\n"));
        assert_eq!(e.line, Some(2));
        assert!(matches!(e.kind, PoseErrorKind::QuatNorm { .. }), "{e}");
        assert!(e.to_string().contains("quaternion norm"), "{e}");
        // Within tolerance: accepted and normalised.
        let t = parse(&format!("{HEADER}0,0,0,0,1.0005,0,0,0\n")).unwrap();
        assert_eq!(t.rows()[0].rot, [1.0, 0.0, 0.0, 0.0]);
    }

    #[test]
    fn io_error_names_the_file() {
        let e = PoseTrack::from_path(Path::new("/nonexistent/poses.csv")).unwrap_err();
        assert!(matches!(e.kind, PoseErrorKind::Io(_)));
        assert!(e.to_string().starts_with("/nonexistent/poses.csv: "), "{e}");
    }

    #[test]
    fn tick_count_and_times() {
        // 0 .. 1 s at 100 Hz: 1001 ticks, the last exactly on the last row.
        let mut s = HEADER.to_string();
        for i in 0..=100 {
            s += &format!("{},0,0,0,1,0,0,0\n", i as f64 * 0.01);
        }
        let t = parse(&s).unwrap();
        assert_eq!(t.ticks(), 1001);
        assert_eq!(t.resample().len(), 1001);
        // A single row is one tick; a span shorter than a tick is one tick.
        assert_eq!(
            parse(&format!("{HEADER}3,0,0,0,1,0,0,0\n"))
                .unwrap()
                .ticks(),
            1
        );
        let t = parse(&format!("{HEADER}3,0,0,0,1,0,0,0\n3.0009,1,0,0,1,0,0,0\n")).unwrap();
        assert_eq!(t.ticks(), 1);
        assert_eq!(t.tick_time(0), 3.0);
    }

    #[test]
    fn linear_position_interpolation() {
        let t = parse(&format!(
            "{HEADER}1.0,0,0,40,1,0,0,0\n1.01,10,-20,30,1,0,0,0\n"
        ))
        .unwrap();
        let p: Vec<Pose<f64>> = t.resample().collect();
        assert_eq!(p.len(), 11);
        let mid = p[5].pos.to_f64();
        for (a, b) in mid.iter().zip([5.0, -10.0, 35.0]) {
            assert!((a - b).abs() < 1e-9, "{mid:?}");
        }
        assert_eq!(p[10].pos.to_f64(), [10.0, -20.0, 30.0]);
    }

    #[test]
    fn slerp_is_uniform_and_takes_the_short_arc() {
        let angle = 1.2f64; // about z
        let a = [1.0, 0.0, 0.0, 0.0];
        let b = [(angle / 2.0).cos(), 0.0, 0.0, (angle / 2.0).sin()];
        for u in [0.0, 0.25, 0.5, 0.9, 1.0] {
            let q = slerp(a, b, u);
            let half = angle * u / 2.0;
            let want = [half.cos(), 0.0, 0.0, half.sin()];
            for i in 0..4 {
                assert!((q[i] - want[i]).abs() < 1e-12, "u {u}: {q:?} vs {want:?}");
            }
            // -b is the same rotation: the result is the same.
            let q2 = slerp(a, b.map(|c| -c), u);
            for i in 0..4 {
                assert!((q2[i] - want[i]).abs() < 1e-12);
            }
        }
        // Nearly equal quaternions stay unit.
        let c = [1.0, 1e-9, 0.0, 0.0];
        let q = slerp(a, c, 0.5);
        assert!((q.iter().map(|x| x * x).sum::<f64>() - 1.0).abs() < 1e-15);
    }

    #[test]
    fn orientation_is_slerped_between_rows() {
        let h = (0.5f64).sin(); // 1 rad about y
        let c = (0.5f64).cos();
        let t = parse(&format!(
            "{HEADER}0,0,0,40,1,0,0,0\n0.004,0,0,40,{c},0,{h},0\n"
        ))
        .unwrap();
        let q = t.pose_at_tick(2).rot.to_f64();
        assert!((q[0] - 0.25f64.cos()).abs() < 1e-12 && (q[2] - 0.25f64.sin()).abs() < 1e-12);
    }

    #[test]
    fn xy_bounds() {
        let t = parse(&format!(
            "{HEADER}0,1,-2,40,1,0,0,0\n1,-3,5,40,1,0,0,0\n2,0,0,40,1,0,0,0\n"
        ))
        .unwrap();
        assert_eq!(t.xy_bounds(), ([-3.0, -2.0], [1.0, 5.0]));
    }
}
