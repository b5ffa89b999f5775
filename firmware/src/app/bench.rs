//! The force loop's cost, measured on the device itself.
//!
//! Runs the large brush through a scripted stroke (hanging, pressing into the paper,
//! dragging, lifting) and measures every full force-loop tick ([`ForceLoop::tick`]: pen,
//! brush with all substeps, force model and output stage, motor output; the pen is
//! calibrated so the force path runs in full) with the board's counter, interrupts
//! masked by the caller. Then the two parts of a tick separately (one substep, the once per
//! tick surface update) and the same stroke at lower substep rates. Prints `BENCH` lines of
//! raw counter values; the host (`hil bench`) turns counts into instructions, since only it
//! knows the emulator's `-icount` shift.

use core::fmt::Write;

use maobi_shared::guide::{GuideInput, GuideStream, DEFAULT_GUIDE};
use maobi_shared::params::{INTEGRATOR_BACKWARD_EULER, INTEGRATOR_KANG_CHO};
use maobi_shared::{presets, Fx, ParamId, Pose, Quat, Scalar, Vec3};

use maobi_shared::kinematics::{KinematicsError, Pen, PenConfig, RawReadings};

use super::sensor_pen::SensorPen;
use super::{CmdQueue, ForceLoop};
use crate::board::{CycleCounter, JointReading, JointSensors, Motors, PoseSource, Watchdog};

/// Ticks of the scripted stroke.
pub const STROKE_TICKS: u32 = 600;

/// The handle pose at tick `k` of the bench stroke: hang 50 ticks, press 12 mm into the
/// paper over 150 ticks, drag 60 mm in x over 300 ticks, lift over 100.
pub fn stroke_pose(k: u32) -> Pose<Fx> {
    let hang = 44.0;
    let press = 32.0;
    let (x, z) = match k {
        0..=49 => (0.0, hang),
        50..=199 => (0.0, hang + (press - hang) * (k - 50) as f64 / 150.0),
        200..=499 => (60.0 * (k - 200) as f64 / 300.0, press),
        _ => (
            60.0,
            press + (hang - press) * (k.min(600) - 500) as f64 / 100.0,
        ),
    };
    // Tilted 15 degrees about y, as a writer holds the brush.
    let (s, c) = (0.130_526_192_220_051_6, 0.991_444_861_373_810_4);
    Pose::new(
        Vec3::from_f64([x, 0.0, z]),
        Quat::from_f64([c, 0.0, s, 0.0]),
    )
}

/// The bench's pen: the scripted stroke read through a physical pen's sensor path. Before
/// each timed tick, [`ScriptPen::feed`] turns the stroke's pose into the readings the
/// reference linkage ([`PenConfig::OMNI_LIKE`]) would give (inverse kinematics, untimed);
/// the tick then runs what the Black Pill runs on its sensors ([`SensorPen`]: encoder
/// unwrap, ADC filter, buttons, forward kinematics, and `J^T F` for the torques).
struct ScriptPen {
    sensed: SensorPen<ScriptedSensors>,
    /// The same linkage and calibration, for the inverse kinematics.
    synth: Pen<Fx>,
    guide: Option<GuideInput<Fx>>,
    /// Stroke poses the reference linkage could not reach (their ticks reuse the last
    /// reading); reported, and zero for the bench stroke.
    unreachable: u32,
}

/// The reference linkage at rest in its inkwell: mid-range encoder counts, so that the
/// 16-bit counters the unwrap extends start on the right turn, and mid-scale ADC codes.
const INKWELL: RawReadings = RawReadings {
    encoders: [1 << 15; 3],
    gimbal: [2048; 3],
};

impl ScriptPen {
    fn new() -> Option<Self> {
        let mut synth = Pen::new(PenConfig::OMNI_LIKE).ok()?;
        synth.calibrate(INKWELL);
        Some(ScriptPen {
            sensed: fresh_sensors(&synth),
            synth,
            guide: None,
            unreachable: 0,
        })
    }

    /// What the linkage's sensors read with the ferrule at `pose` (inverse kinematics).
    fn readings_at(&self, pose: &Pose<Fx>) -> Result<RawReadings, KinematicsError> {
        let joints = self.synth.inverse(pose)?;
        self.synth.raw_readings(&joints)
    }

    /// The sensors read `pose` on the next tick.
    fn feed(&mut self, pose: &Pose<Fx>) {
        match self.readings_at(pose) {
            Ok(raw) => {
                self.sensed.sensors_mut().0 = JointReading {
                    // The counters' low 16 bits, as a board reads them.
                    encoders: raw.encoders.map(|e| i32::from(e as u16)),
                    gimbal: raw.gimbal,
                    buttons: 0,
                }
            }
            Err(_) => self.unreachable += 1,
        }
    }

    /// A new stroke: the unwrap and the filters start afresh from the next reading.
    fn restart(&mut self) {
        self.sensed = fresh_sensors(&self.synth);
    }
}

impl PoseSource for ScriptPen {
    fn next_pose(&mut self) -> Option<Pose<Fx>> {
        self.sensed.next_pose()
    }
    fn take_guide(&mut self) -> Option<GuideInput<Fx>> {
        self.guide.take()
    }
    fn torques_for(&self, f: [Fx; 3]) -> [Fx; 3] {
        self.sensed.torques_for(f)
    }
    // The bench measures the force loop, not bring-up: no configuration, no sensor reports.
    fn configure(&mut self, _cfg: &maobi_shared::pen_io::DeviceConfig) {}
    fn raw_sensors(&mut self, _tick: u32) -> Option<maobi_shared::protocol::SensorReport> {
        None
    }
}

/// The sensor path of a board whose linkage is `pen`, before its first reading.
fn fresh_sensors(pen: &Pen<Fx>) -> SensorPen<ScriptedSensors> {
    SensorPen::new(ScriptedSensors::default(), Some(pen.clone()))
}

/// Sensors that read what [`ScriptPen::feed`] put there.
#[derive(Default)]
struct ScriptedSensors(JointReading);

impl JointSensors for ScriptedSensors {
    fn read(&mut self) -> Option<JointReading> {
        Some(self.0)
    }
}

struct NullMotors([Fx; 3]);
impl Motors for NullMotors {
    fn command(&mut self, t: [Fx; 3]) {
        self.0 = t;
    }
    fn disable(&mut self) {
        self.0 = [Fx::ZERO; 3];
    }
    fn applied(&self) -> [Fx; 3] {
        self.0
    }
    fn configure(&mut self, _cfg: &maobi_shared::pen_io::DeviceConfig) {}
}

struct NullWatchdog;
impl Watchdog for NullWatchdog {
    fn feed(&mut self) {}
}

#[derive(Default)]
struct Stats {
    n: u32,
    min: u32,
    max: u32,
    sum: u64,
    max_at: u32,
}

impl Stats {
    fn add(&mut self, k: u32, v: u32) {
        if self.n == 0 || v < self.min {
            self.min = v;
        }
        if v > self.max {
            self.max = v;
            self.max_at = k;
        }
        self.sum += v as u64;
        self.n += 1;
    }
    fn mean(&self) -> u64 {
        self.sum / self.n.max(1) as u64
    }
}

/// Back to the stroke's start as a new stroke: the brush at rest there, the forces (and the
/// guide) from zero, and no previous pose, so the jump back from the stroke's end is not a
/// sensor fault that would switch the forces (and the guide) off for the next run.
fn restart<M: crate::board::Motors, W: crate::board::Watchdog>(
    fl: &mut ForceLoop<ScriptPen, M, W>,
) {
    fl.core.reset_brush(stroke_pose(0));
    fl.core.forget_pose();
    fl.pen.restart();
    super::FAULTS.store(0, core::sync::atomic::Ordering::SeqCst);
    // A configuration that allows forces (the link sets this from the stored one): without
    // it the force loop holds the motors off every tick and the output stage and the
    // torques would not be counted.
    super::CONFIG_OK.store(true, core::sync::atomic::Ordering::SeqCst);
    super::FORCES_ENABLED.store(true, core::sync::atomic::Ordering::SeqCst);
}

/// Runs the bench and writes `BENCH ...` lines to `out`. Call with interrupts masked.
/// What [`run`] measures.
#[derive(Copy, Clone, PartialEq, Eq)]
pub enum BenchScope {
    /// Everything: each integrator at each substep rate, guided writing, the parts.
    Full,
    /// The presets' brush alone over the first [`PROFILE_TICKS`] ticks of the stroke (hang,
    /// press, the start of the drag), then exit: a run short enough to log every executed
    /// instruction for a profile (`scripts/profile-tick`).
    Profile,
    /// The presets' brush over the same [`PROFILE_TICKS`] ticks, each tick and after it a
    /// state fill bracketed by the trace markers ([`trace_tick_begin`] and the others), for
    /// `hil bench`'s cycle estimate, which weighs the instructions QEMU logs between them.
    Cycles,
}

/// Trace markers: calls whose entry addresses `hil` looks up by name in the image and finds
/// in QEMU's log of executed blocks. Each writes its own value, so that no two can be merged
/// into one body. Ordinary (mangled) functions: an image that never calls them, the Black
/// Pill's, does not keep them.
#[inline(never)]
pub fn trace_tick_begin() {
    mark(1);
}
/// See [`trace_tick_begin`].
#[inline(never)]
pub fn trace_tick_end() {
    mark(2);
}
/// See [`trace_tick_begin`].
#[inline(never)]
pub fn trace_fill_begin() {
    mark(3);
}
/// See [`trace_tick_begin`].
#[inline(never)]
pub fn trace_fill_end() {
    mark(4);
}
/// A store the compiler must keep (a volatile one), so that the markers' calls are kept.
#[inline(always)]
fn mark(n: u32) {
    static mut TRACE_MARK: u32 = 0;
    // SAFETY: a plain store to a static only the markers touch, on one core.
    unsafe { core::ptr::write_volatile(core::ptr::addr_of_mut!(TRACE_MARK), n) };
}

/// Ticks of the [`BenchScope::Profile`] run.
pub const PROFILE_TICKS: u32 = 300;

pub fn run<C: CycleCounter>(clk: &C, out: &mut impl Write, scope: BenchScope) {
    static mut CMDS: CmdQueue = CmdQueue::new();
    // SAFETY: the bench runs once, before anything else uses this queue.
    let (_tx, rx) = unsafe { (*core::ptr::addr_of_mut!(CMDS)).split() };

    // Cost of the measurement itself (two counter reads).
    let mut overhead = u32::MAX;
    for _ in 0..8 {
        let a = clk.now();
        let b = clk.now();
        overhead = overhead.min(b.wrapping_sub(a));
    }
    let _ = writeln!(out, "BENCH overhead_counts={overhead}");

    let params = presets::LARGE;
    let Some(pen) = ScriptPen::new() else {
        let _ = writeln!(out, "BENCH error=invalid_pen_config");
        return;
    };
    let Some(mut fl) = ForceLoop::new(
        params,
        stroke_pose(0),
        pen,
        NullMotors([Fx::ZERO; 3]),
        NullWatchdog,
        rx,
    ) else {
        let _ = writeln!(out, "BENCH error=invalid_preset_or_force_model");
        return;
    };
    super::FORCES_ENABLED.store(true, core::sync::atomic::Ordering::SeqCst);

    // Each integrator at each rate (the QEMU image, which runs the bench, has both; the
    // Black Pill's has backward Euler alone).
    let runs = [INTEGRATOR_BACKWARD_EULER, INTEGRATOR_KANG_CHO]
        .into_iter()
        .flat_map(|i| [25u8, 20, 16, 12, 10, 8, 5, 4, 3, 2, 1].map(|n| (i, n)));
    let (profile, ticks) = match scope {
        BenchScope::Full => (None, STROKE_TICKS),
        BenchScope::Profile | BenchScope::Cycles => (
            Some((params.integrator, params.substeps_per_tick)),
            PROFILE_TICKS,
        ),
    };
    for (integrator, substeps) in runs.filter(|run| profile.is_none_or(|p| p == *run)) {
        let brush = fl.core.brush_mut();
        if brush
            .set_param(ParamId::Integrator, integrator as f32)
            .and_then(|()| brush.set_param(ParamId::SubstepsPerTick, substeps as f32))
            .is_err()
        {
            continue;
        }
        restart(&mut fl);
        let mut st = Stats::default();
        let mut contact_max = 0;
        // Ticks that drove the motors: all of them, unless a fault (a sensor jump) switched
        // the forces off and the rest of the run went uncounted.
        let mut forces_on = 0u32;
        let cycles = scope == BenchScope::Cycles;
        if cycles {
            // The slot full, as the bench's ticks always find it: the state fill is traced
            // on its own, after each tick.
            super::SNAPSHOT.take(|_| ());
            super::SNAPSHOT.offer(true, |s| fl.snapshot(0, s));
        }
        for k in 1..=ticks {
            fl.pen.feed(&stroke_pose(k));
            let a = clk.now();
            // Inside the counter's reads: a device read under `-icount` makes QEMU translate
            // its block again, which its log would show as instructions run twice.
            if cycles {
                trace_tick_begin();
            }
            fl.tick();
            if cycles {
                trace_tick_end();
            }
            let b = clk.now();
            if cycles {
                // The state fill of a tick a frame falls due on (1 in about 8 at 120 Hz),
                // here after every tick so that its dearest brush state is among them.
                super::SNAPSHOT.take(|_| ());
                trace_fill_begin();
                super::SNAPSHOT.offer(true, |s| fl.snapshot(k, s));
                trace_fill_end();
            }
            st.add(k, b.wrapping_sub(a).saturating_sub(overhead));
            contact_max = contact_max.max(fl.core.brush().contacts());
            forces_on += u32::from(fl.enabled);
        }
        let _ = writeln!(
            out,
            "BENCH tick integrator={integrator} substeps={substeps} layers={} ticks={} min_counts={} mean_counts={} max_counts={} max_at_tick={} max_contacts={contact_max} exact_solve={} unreachable={} forces_on={forces_on}",
            fl.core.brush().len(),
            st.n,
            st.min,
            st.mean(),
            st.max,
            st.max_at,
            fl.core.brush().solves_exactly() as u8,
            fl.pen.unreachable,
        );
    }

    if scope != BenchScope::Full {
        return;
    }

    // Guided writing: the same stroke at the preset's substeps twice from the same start
    // (brush and forces reset, the output stage ramped in by the runs above): without guide
    // samples, then with one every tick (the moving point 3 mm to the side of the hand and 2
    // ticks ahead, so the guide leads from the first tick on). The difference is the guide's
    // cost on the force path.
    let _ = fl.core.brush_mut().set_params(params);
    let side = Vec3::from_f64([0.0, 3.0, 0.0]);
    let mut base = Stats::default();
    let mut st = Stats::default();
    let mut guiding = 0;
    for guided in [false, true] {
        restart(&mut fl);
        for k in 1..=STROKE_TICKS {
            fl.pen.feed(&stroke_pose(k));
            fl.pen.guide = guided.then(|| GuideInput {
                anchor: stroke_pose(k + 2).pos + side,
                on: true,
            });
            let a = clk.now();
            fl.tick();
            let b = clk.now();
            let stats = if guided { &mut st } else { &mut base };
            stats.add(k, b.wrapping_sub(a).saturating_sub(overhead));
            guiding += fl.core.guide().active() as u32;
        }
    }
    // The guide alone (GuideStream::tick with a sample, at full gain after the run above's
    // fade-in), 100 calls.
    let mut g = Stats::default();
    if let Ok(mut gs) = GuideStream::<Fx>::new(DEFAULT_GUIDE) {
        for k in 1..=400 {
            let hand = stroke_pose(k).pos;
            let sample = Some(GuideInput {
                anchor: stroke_pose(k + 2).pos + side,
                on: true,
            });
            let step = hand - stroke_pose(k - 1).pos;
            let a = clk.now();
            let f = gs.tick(core::hint::black_box(sample), hand, step);
            let b = clk.now();
            core::hint::black_box(f);
            if k > 300 {
                g.add(k, b.wrapping_sub(a).saturating_sub(overhead));
            }
        }
    }
    let _ = writeln!(
        out,
        "BENCH guided substeps={} ticks={} guiding_ticks={guiding} min_counts={} mean_counts={} max_counts={} guide_alone_mean_counts={} guide_alone_max_counts={} unguided_mean_counts={} unguided_max_counts={}",
        params.substeps_per_tick,
        st.n,
        st.min,
        st.mean(),
        st.max,
        g.mean(),
        g.max,
        base.mean(),
        base.max,
    );

    // The parts of a tick, with the preset's integrator and rate, in the pressed-and-dragging
    // state.
    fl.core.reset_brush(stroke_pose(0));
    let brush = fl.core.brush_mut();
    for k in 1..=300 {
        maobi_fast::brush_tick(brush, stroke_pose(k));
    }
    let mut sub = Stats::default();
    let mut end = Stats::default();
    for k in 301..=400 {
        let p = stroke_pose(k);
        let a = clk.now();
        maobi_fast::brush_substep(brush, p);
        let b = clk.now();
        maobi_fast::brush_end_tick(brush);
        let c = clk.now();
        sub.add(k, b.wrapping_sub(a).saturating_sub(overhead));
        end.add(k, c.wrapping_sub(b).saturating_sub(overhead));
    }
    let _ = writeln!(
        out,
        "BENCH parts substep_mean_counts={} substep_max_counts={} end_tick_mean_counts={} end_tick_max_counts={} contacts={}",
        sub.mean(),
        sub.max,
        end.mean(),
        end.max,
        brush.contacts(),
    );
    // The pen's kinematics, as a tick on a physical pen runs them: the pose from the sensors'
    // readings (`Pen::joints`, `Pen::forward`) and the torques for a force (`J^T F`), over
    // the drag.
    let mut pose_cost = Stats::default();
    let mut torque_cost = Stats::default();
    let f = Vec3::from_f64([0.3, -0.2, 1.5]);
    for k in 200..300 {
        let Ok(raw) = fl.pen.readings_at(&stroke_pose(k)) else {
            continue;
        };
        let pen = &fl.pen.synth;
        let a = clk.now();
        let pose = maobi_fast::pen_pose(pen, core::hint::black_box(&raw));
        let b = clk.now();
        if let Ok((_, arm)) = pose {
            let t = maobi_fast::pen_torques(pen, &arm, core::hint::black_box(f));
            let c = clk.now();
            core::hint::black_box(t);
            pose_cost.add(k, b.wrapping_sub(a).saturating_sub(overhead));
            torque_cost.add(k, c.wrapping_sub(b).saturating_sub(overhead));
        }
    }
    let _ = writeln!(
        out,
        "BENCH kinematics poses={} pose_mean_counts={} pose_max_counts={} torques_mean_counts={} torques_max_counts={}",
        pose_cost.n,
        pose_cost.mean(),
        pose_cost.max,
        torque_cost.mean(),
        torque_cost.max,
    );
    // The scalar operations the model is built from: 100 calls each, counts per 100.
    let x = core::hint::black_box(Fx::from_bits(0x0000_0012_3456_789A)); // about 18.2
    let y = core::hint::black_box(Fx::from_bits(0x0000_0003_0000_0001)); // about 3.0
    use maobi_fast::ScalarOp;
    let ops = [
        ("add", ScalarOp::Add),
        ("mul", ScalarOp::Mul),
        ("div", ScalarOp::Div),
        ("sqrt", ScalarOp::Sqrt),
        ("rsqrt", ScalarOp::Rsqrt),
        ("from_f64", ScalarOp::FromF64),
    ];
    for (name, op) in ops {
        let a = clk.now();
        let acc = maobi_fast::repeat_scalar_op(op, x, y, 100);
        let b = clk.now();
        core::hint::black_box(acc);
        let _ = writeln!(out, "BENCH op={name} counts_per_100={}", b.wrapping_sub(a));
    }
    // Calibration: CALIBRATION_NOPS NOPs and the call around them (10 counts at -icount
    // shift=0).
    let a = clk.now();
    calibration_nops();
    let b = clk.now();
    let _ = writeln!(
        out,
        "BENCH calib_nops={CALIBRATION_NOPS} calib_counts={}",
        b.wrapping_sub(a)
    );
    let _ = writeln!(out, "BENCH unit={}", C::UNIT);
}

/// NOPs in [`calibration_nops`]: enough that the counter's resolution (5 instructions at
/// the default shift) is a small part, few enough to cost little flash (2 bytes each).
const CALIBRATION_NOPS: u32 = 400;

/// Exactly [`CALIBRATION_NOPS`] NOPs, plus the call and the return. Out of line: inside
/// `run` a block this long puts its literal pools out of reach of their loads when built for
/// size ("out of range pc-relative fixup value").
#[inline(never)]
fn calibration_nops() {
    // SAFETY: only NOPs.
    unsafe { core::arch::asm!(".rept 400", "nop", ".endr", options(nomem, nostack)) };
}
