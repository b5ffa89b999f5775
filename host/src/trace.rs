//! The trace CSV: one row per 1 ms tick with the handle pose and the spine (Liang's brush;
//! [`BaxterLinTraceWriter`] for Baxter & Lin's).
//!
//! Columns, in order: `t` (s), the handle pose `x,y,z,qw,qx,qy,qz` (the resampled input pose
//! the handle was driven to), `s{i}_x,s{i}_y,s{i}_z` for every spine mass i = 0..N-1 (mm,
//! mass 0 is the ferrule), `contacts` (masses lying on the paper), `fx,fy,fz` (the force model's
//! force on the hand, N, paper frame, before any device's output stage) and `depth` (D_p, the
//! virtual skeleton's depth below the paper, mm).
//!
//! Each column is a [`Column`] that knows both its name and its value, so the header and the
//! rows cannot drift apart: a new column is a new variant plus its place in [`columns`].

use std::fmt::Write as _;
use std::io::Write;

use maobi_shared::baxter_lin::brush::BaxterLinBrush;
use maobi_shared::{Pose, Scalar, Vec3};

use crate::offline::Tick;

/// Decimals for lengths (mm): 1 nm.
const MM_DECIMALS: usize = 6;
/// Decimals for forces (N): 1 uN.
const FORCE_DECIMALS: usize = 6;
/// Decimals for quaternion components: 1e-9 rad, far below anything the model resolves.
const QUAT_DECIMALS: usize = 9;

/// One trace column.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum Column {
    /// Time (s).
    T,
    /// Handle pose component: 0..3 = x, y, z (mm), 3..7 = qw, qx, qy, qz.
    Handle(usize),
    /// Spine mass `mass`, coordinate `axis` (0 = x, 1 = y, 2 = z), mm.
    Spine { mass: usize, axis: usize },
    /// Number of masses lying on the paper.
    Contacts,
    /// Force on the hand, axis 0 = x, 1 = y, 2 = z (N).
    Force(usize),
    /// Depth of the virtual skeleton below the paper (mm).
    Depth,
}

const HANDLE_NAMES: [&str; 7] = ["x", "y", "z", "qw", "qx", "qy", "qz"];
const AXES: [&str; 3] = ["x", "y", "z"];

impl Column {
    pub fn name(self) -> String {
        match self {
            Column::T => "t".into(),
            Column::Handle(c) => HANDLE_NAMES[c].into(),
            Column::Spine { mass, axis } => format!("s{mass}_{}", AXES[axis]),
            Column::Contacts => "contacts".into(),
            Column::Force(axis) => format!("f{}", AXES[axis]),
            Column::Depth => "depth".into(),
        }
    }

    /// Appends this column's value at `tick` to `out`; `t_decimals` is the precision of `t`.
    pub fn write_value<S: Scalar>(self, tick: &Tick<'_, S>, t_decimals: usize, out: &mut String) {
        match self {
            Column::T => push_decimal(out, tick.t, t_decimals),
            Column::Handle(c) if c < 3 => push_decimal(out, tick.pose.pos.to_f64()[c], MM_DECIMALS),
            Column::Handle(c) => push_decimal(out, tick.pose.rot.to_f64()[c - 3], QUAT_DECIMALS),
            Column::Spine { mass, axis } => {
                push_decimal(out, tick.brush.spine()[mass].to_f64()[axis], MM_DECIMALS)
            }
            Column::Contacts => {
                let _ = write!(out, "{}", tick.brush.contacts());
            }
            Column::Force(axis) => {
                push_decimal(out, tick.forces.total.to_f64()[axis], FORCE_DECIMALS)
            }
            Column::Depth => push_decimal(out, tick.forces.depth_mm.to_f64(), MM_DECIMALS),
        }
    }
}

/// The trace's columns for a brush of `masses` spine masses.
pub fn columns(masses: usize) -> Vec<Column> {
    let mut cols = vec![Column::T];
    cols.extend((0..HANDLE_NAMES.len()).map(Column::Handle));
    for mass in 0..masses {
        cols.extend((0..3).map(|axis| Column::Spine { mass, axis }));
    }
    cols.push(Column::Contacts);
    cols.extend((0..3).map(Column::Force));
    cols.push(Column::Depth);
    cols
}

/// `v` with `decimals` digits after the point, never as negative zero (so a value that
/// rounds to zero prints the same whatever its sign or the scalar type).
pub fn push_decimal(out: &mut String, v: f64, decimals: usize) {
    let start = out.len();
    let _ = write!(out, "{v:.decimals$}");
    if out[start..].starts_with('-') && out[start + 1..].bytes().all(|b| b == b'0' || b == b'.') {
        out.remove(start);
    }
}

/// Decimals for `t`: 3 when the ticks fall on whole milliseconds, else 6 (so ticks of a
/// track that starts between milliseconds still print distinct times).
pub fn time_decimals(start: f64) -> usize {
    let ms = start * 1000.0;
    if (ms - ms.round()).abs() < 1e-6 {
        3
    } else {
        6
    }
}

/// Writes the trace CSV, one [`Tick`] at a time.
pub struct TraceWriter<W: Write> {
    out: csv::Writer<W>,
    cols: Vec<Column>,
    t_decimals: usize,
    field: String,
}

impl<W: Write> TraceWriter<W> {
    /// Writes the header for a brush of `masses` spine masses.
    pub fn new(out: W, masses: usize, t_decimals: usize) -> csv::Result<Self> {
        let cols = columns(masses);
        let mut out = csv::WriterBuilder::new().from_writer(out);
        out.write_record(cols.iter().map(|c| c.name()))?;
        Ok(TraceWriter {
            out,
            cols,
            t_decimals,
            field: String::with_capacity(32),
        })
    }

    pub fn columns(&self) -> &[Column] {
        &self.cols
    }

    pub fn write_tick<S: Scalar>(&mut self, tick: &Tick<'_, S>) -> csv::Result<()> {
        for &c in &self.cols {
            self.field.clear();
            c.write_value(tick, self.t_decimals, &mut self.field);
            self.out.write_field(&self.field)?;
        }
        self.out.write_record(None::<&[u8]>)
    }

    /// Flushes and returns the underlying writer.
    pub fn finish(self) -> std::io::Result<W> {
        self.out.into_inner().map_err(|e| e.into_error())
    }
}

/// The trace of Baxter & Lin's brush (`maobi trace --model baxter-lin`), one row per 1 ms
/// tick. Columns: `t`, the handle pose `x,y,z,qw,qx,qy,qz` (as the trace above), then every
/// spine's joints `p{k}_{i}_x,p{k}_{i}_y,p{k}_{i}_z` (spine k, joint i = 0..J, joint 0 the
/// root on the ferrule, J the tip; mm), `contacts` (joints on the paper, every spine),
/// `fx,fy,fz` (the force the spines put on the handle: the paper's push on the hair as the
/// hand feels it, N; zero in free air, where Liang's trace has the brush's weight) and `fr{k}_x,fr{k}_y` (the paper's friction on spine k, summed over its
/// joints on the paper, N).
pub struct BaxterLinTraceWriter<W: Write> {
    out: csv::Writer<W>,
    t_decimals: usize,
    joints: usize,
    field: String,
}

impl<W: Write> BaxterLinTraceWriter<W> {
    /// Writes the header for `brush`'s spines.
    pub fn new(out: W, brush: &BaxterLinBrush, t_decimals: usize) -> csv::Result<Self> {
        let joints = brush.spines().first().map_or(0, |s| s.joints());
        let mut names: Vec<String> = vec!["t".into()];
        names.extend(HANDLE_NAMES.iter().map(|n| n.to_string()));
        for k in 0..brush.spines().len() {
            for i in 0..=joints {
                names.extend(AXES.iter().map(|a| format!("p{k}_{i}_{a}")));
            }
        }
        names.push("contacts".into());
        names.extend(AXES.iter().map(|a| format!("f{a}")));
        for k in 0..brush.spines().len() {
            names.extend(AXES[..2].iter().map(|a| format!("fr{k}_{a}")));
        }
        let mut out = csv::WriterBuilder::new().from_writer(out);
        out.write_record(&names)?;
        Ok(BaxterLinTraceWriter {
            out,
            t_decimals,
            joints,
            field: String::with_capacity(32),
        })
    }

    fn field(&mut self, v: f64, decimals: usize) -> csv::Result<()> {
        self.field.clear();
        push_decimal(&mut self.field, v, decimals);
        self.out.write_field(&self.field)
    }

    /// One row: the brush after its tick at `pose`, at time `t` (s).
    pub fn write_tick(
        &mut self,
        t: f64,
        pose: &Pose<f64>,
        brush: &BaxterLinBrush,
    ) -> csv::Result<()> {
        self.field(t, self.t_decimals)?;
        for v in pose.pos.to_f64() {
            self.field(v, MM_DECIMALS)?;
        }
        for v in pose.rot.to_f64() {
            self.field(v, QUAT_DECIMALS)?;
        }
        let mut contacts = 0;
        for spine in brush.spines() {
            for i in 0..=self.joints {
                for v in spine.position(i).to_f64() {
                    self.field(v, MM_DECIMALS)?;
                }
                contacts += usize::from(spine.in_contact(i));
            }
        }
        self.out.write_field(contacts.to_string())?;
        for v in brush.handle_force().to_f64() {
            self.field(v, FORCE_DECIMALS)?;
        }
        for spine in brush.spines() {
            let friction =
                (0..=self.joints).fold(Vec3::<f64>::ZERO, |acc, i| acc + spine.friction_force(i));
            self.field(friction.x, FORCE_DECIMALS)?;
            self.field(friction.y, FORCE_DECIMALS)?;
        }
        self.out.write_record(None::<&[u8]>)
    }

    /// Flushes and returns the underlying writer.
    pub fn finish(self) -> std::io::Result<W> {
        self.out.into_inner().map_err(|e| e.into_error())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::offline::simulate;
    use crate::poses::PoseTrack;
    use maobi_shared::presets;

    #[test]
    fn decimals_without_negative_zero() {
        let mut s = String::new();
        push_decimal(&mut s, -1e-9, 6);
        s.push(',');
        push_decimal(&mut s, -0.0, 3);
        s.push(',');
        push_decimal(&mut s, -1.25, 3);
        s.push(',');
        push_decimal(&mut s, 40.0, 6);
        assert_eq!(s, "0.000000,0.000,-1.250,40.000000");
    }

    #[test]
    fn time_precision() {
        assert_eq!(time_decimals(0.0), 3);
        assert_eq!(time_decimals(12.345), 3);
        assert_eq!(time_decimals(0.0005), 6);
    }

    #[test]
    fn header_names() {
        let names: Vec<String> = columns(2).into_iter().map(Column::name).collect();
        assert_eq!(
            names.join(","),
            "t,x,y,z,qw,qx,qy,qz,s0_x,s0_y,s0_z,s1_x,s1_y,s1_z,contacts,fx,fy,fz,depth"
        );
    }

    #[test]
    fn rows_match_header_and_ticks() {
        let csv = "t,x,y,z,qw,qx,qy,qz\n0,0,0,45,1,0,0,0\n0.003,0,0,44,1,0,0,0\n";
        let track = PoseTrack::from_reader("t.csv", csv.as_bytes()).unwrap();
        let params = presets::by_name("large").unwrap();
        let mut w = TraceWriter::new(Vec::new(), params.layers as usize, 3).unwrap();
        let n = simulate::<f64>(params, &track, |tick| Ok(w.write_tick(tick)?)).unwrap();
        assert_eq!(n, 4);
        let text = String::from_utf8(w.finish().unwrap()).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 5);
        let width = lines[0].split(',').count();
        assert_eq!(width, 1 + 7 + 3 * params.layers as usize + 1 + 4);
        for l in &lines[1..] {
            assert_eq!(l.split(',').count(), width, "{l}");
        }
        assert!(lines[1].starts_with("0.000,0.000000,0.000000,45.000000,1.000000000,"));
        assert!(lines[4].starts_with("0.003,0.000000,0.000000,44.000000,"));
        // At rest the ferrule is s0 = handle position, and nothing touches the paper: the
        // only force is the brush's weight, and the skeleton is above the paper.
        let s1_z = 45.0 - params.length_mm as f64 / (params.layers as f64 - 1.0);
        assert!(lines[1].contains(&format!(
            ",0.000000,0.000000,45.000000,0.000000,0.000000,{s1_z:.6},"
        )));
        assert!(
            lines[1].ends_with(",0,0.000000,0.000000,-0.147100,0.000000"),
            "{}",
            lines[1]
        );
    }
}
