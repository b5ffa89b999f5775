//! `hil bench`: the firmware's own instruction count of its 1 kHz tick.
//!
//! The firmware (boot mode `bench SHIFT`) reads the 25 MHz dual-timer count around each
//! force-loop tick with interrupts masked and prints `BENCH` lines of raw counts. Under
//! `-icount shift=N` a count is exactly 40 / 2^N instructions (the firmware's calibration
//! line checks it with a block of NOPs), so the default shift 3 resolves 5 instructions.
//!
//! Instructions are not cycles: [`with_cycles`] adds the tick's cycle estimate on the
//! Black Pill ([`crate::cycles`]), which `hil bench` prints last.

use std::collections::BTreeMap;
use std::path::Path;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use maobi_shared::params::{INTEGRATOR_BACKWARD_EULER, INTEGRATOR_KANG_CHO};
use maobi_shared::presets;

use crate::cycles;
use crate::qemu::{Clock, Run};

/// The instruction budget of one 1 kHz tick (the goal).
pub const BUDGET: u64 = 50_000;

/// One `BENCH tick ...` line, converted to instructions.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TickCost {
    /// `params::INTEGRATOR_*` (images that predate the choice ran the thesis's).
    pub integrator: u64,
    pub substeps: u64,
    pub min: u64,
    pub mean: u64,
    pub max: u64,
}

/// Everything the bench measured, in instructions.
#[derive(Clone, Debug)]
pub struct Report {
    pub shift: u32,
    pub ticks: Vec<TickCost>,
    pub substep: u64,
    pub end_tick: u64,
    /// The pen's kinematics in a tick (mean instructions): pose from the readings, torques.
    pub kinematics: Option<(u64, u64)>,
    /// The preset's substeps with guided writing on every tick (a guide sample per tick).
    pub guided: Option<TickCost>,
    /// `GuideStream::tick` alone, mean and max (instructions).
    pub guide_alone: (u64, u64),
    /// The same stroke from the same start without guide samples, mean and max.
    pub unguided: (u64, u64),
    /// Per call of each scalar operation.
    pub ops: BTreeMap<String, f64>,
    pub raw: String,
    /// The default brush's tick in Black Pill cycles ([`with_cycles`]).
    pub cycles: Option<cycles::Estimate>,
}

impl Report {
    /// The default brush as the desktop runs it (the large preset's integrator and rate):
    /// the number the budget is for.
    pub fn per_tick(&self) -> Option<&TickCost> {
        let p = presets::LARGE;
        self.ticks.iter().find(|t| {
            t.integrator == u64::from(p.integrator) && t.substeps == u64::from(p.substeps_per_tick)
        })
    }
    /// The stroke's tick (1-based) where [`Report::per_tick`]'s worst fell, as the firmware
    /// reports it (`max_at_tick=`).
    pub fn worst_at(&self) -> Option<u64> {
        let p = presets::LARGE;
        self.raw.lines().find_map(|l| {
            let m = fields(l.strip_prefix("BENCH tick ")?);
            let is =
                |k: &str, v: u8| m.get(k).and_then(|x| x.parse::<u64>().ok()) == Some(v.into());
            (is("integrator", p.integrator) && is("substeps", p.substeps_per_tick))
                .then(|| m.get("max_at_tick")?.parse().ok())
                .flatten()
        })
    }
    /// The largest measured substep rate whose worst tick fits [`BUDGET`], with `integrator`.
    pub fn largest_fitting(&self, integrator: u8) -> Option<u64> {
        self.ticks
            .iter()
            .filter(|t| t.integrator == u64::from(integrator) && t.max <= BUDGET)
            .map(|t| t.substeps)
            .max()
    }
}

fn fields(line: &str) -> BTreeMap<&str, &str> {
    line.split_whitespace()
        .filter_map(|w| w.split_once('='))
        .collect()
}

/// Parses the firmware's bench output.
pub fn parse(out: &str, shift: u32) -> Result<Report> {
    let to_instr = |counts: u64| (counts * 40) >> shift;
    let num = |m: &BTreeMap<&str, &str>, k: &str| -> Result<u64> {
        m.get(k)
            .with_context(|| format!("bench output lacks `{k}`"))?
            .parse::<u64>()
            .with_context(|| format!("bench field `{k}` is not a number"))
    };
    let mut r = Report {
        shift,
        ticks: vec![],
        substep: 0,
        end_tick: 0,
        kinematics: None,
        guided: None,
        guide_alone: (0, 0),
        unguided: (0, 0),
        ops: BTreeMap::new(),
        raw: out.to_string(),
        cycles: None,
    };
    let mut calibrated = false;
    let mut overhead = 0;
    for line in out.lines() {
        let Some(rest) = line.strip_prefix("BENCH ") else {
            continue;
        };
        let m = fields(rest);
        if rest.starts_with("tick ") {
            // Images before the kinematics were timed do not report it.
            let unreachable = m
                .get("unreachable")
                .map_or(Ok(0), |_| num(&m, "unreachable"))?;
            if unreachable > 0 {
                bail!(
                    "the bench stroke left the reference linkage's reach on {unreachable} ticks \
                     (their kinematics were not timed):\n{line}"
                );
            }
            let ticks = num(&m, "ticks")?;
            let forces_on = m
                .get("forces_on")
                .map_or(Ok(ticks), |_| num(&m, "forces_on"))?;
            if forces_on < ticks {
                bail!(
                    "the forces were off on {} of {ticks} bench ticks (a fault switched them \
                     off), so the output stage and the torques went uncounted:\n{line}",
                    ticks - forces_on
                );
            }
            r.ticks.push(TickCost {
                integrator: m
                    .get("integrator")
                    .map_or(Ok(u64::from(INTEGRATOR_KANG_CHO)), |_| {
                        num(&m, "integrator")
                    })?,
                substeps: num(&m, "substeps")?,
                min: to_instr(num(&m, "min_counts")?),
                mean: to_instr(num(&m, "mean_counts")?),
                max: to_instr(num(&m, "max_counts")?),
            });
        } else if rest.starts_with("guided ") {
            r.guided = Some(TickCost {
                integrator: u64::from(presets::LARGE.integrator),
                substeps: num(&m, "substeps")?,
                min: to_instr(num(&m, "min_counts")?),
                mean: to_instr(num(&m, "mean_counts")?),
                max: to_instr(num(&m, "max_counts")?),
            });
            r.guide_alone = (
                to_instr(num(&m, "guide_alone_mean_counts")?),
                to_instr(num(&m, "guide_alone_max_counts")?),
            );
            r.unguided = (
                to_instr(num(&m, "unguided_mean_counts")?),
                to_instr(num(&m, "unguided_max_counts")?),
            );
        } else if rest.starts_with("parts ") {
            r.substep = to_instr(num(&m, "substep_mean_counts")?);
            r.end_tick = to_instr(num(&m, "end_tick_mean_counts")?);
        } else if rest.starts_with("kinematics ") {
            if num(&m, "poses")? == 0 {
                bail!("the bench timed no pen pose (the stroke is out of the linkage's reach):\n{line}");
            }
            r.kinematics = Some((
                to_instr(num(&m, "pose_mean_counts")?),
                to_instr(num(&m, "torques_mean_counts")?),
            ));
        } else if let Some(name) = m.get("op") {
            r.ops.insert(
                name.to_string(),
                to_instr(num(&m, "counts_per_100")?) as f64 / 100.0,
            );
        } else if m.contains_key("overhead_counts") {
            overhead = num(&m, "overhead_counts")?;
        } else if m.contains_key("calib_nops") {
            let nops = num(&m, "calib_nops")?;
            // Like the ticks, less the cost of reading the counter twice.
            let got = to_instr(num(&m, "calib_counts")?.saturating_sub(overhead));
            // One count of resolution (40 / 2^shift instructions).
            if got.abs_diff(nops) > 40 >> shift {
                bail!(
                    "calibration failed: {nops} NOPs measured as {got} instructions (shift {shift})"
                );
            }
            calibrated = true;
        }
    }
    if !calibrated || r.per_tick().is_none() {
        bail!("incomplete bench output:\n{out}");
    }
    Ok(r)
}

/// Runs the bench in QEMU (deterministic clock) and parses it.
pub fn run(elf: &Path, shift: u32, timeout: Duration) -> Result<Report> {
    let shift_arg = shift.to_string();
    let run = Run::new(
        elf,
        &["bench", &shift_arg],
        Clock::Deterministic { shift },
        timeout,
    );
    let (status, out) = run.output()?;
    if !status.success() {
        bail!("the bench firmware failed ({status}):\n{out}");
    }
    parse(&out, shift)
}

/// [`run`], then the cycle estimate from a traced run of the default brush's ticks
/// ([`cycles::trace`]): what `hil bench` prints.
pub fn with_cycles(elf: &Path, shift: u32, timeout: Duration) -> Result<Report> {
    let mut r = run(elf, shift, timeout)?;
    r.cycles = Some(cycles::trace(elf, timeout).context("the cycle estimate")?);
    Ok(r)
}

/// The human-readable report; its last line is `instructions_per_tick=<N>`, or with a cycle
/// estimate `cycles_per_tick_estimate=<N>` after it.
pub fn render(r: &Report) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(s, "force-loop tick, large brush, 16 layers, bench stroke (hang, press, drag, lift), -icount shift={}", r.shift);
    let _ = writeln!(
        s,
        "{:>16} {:>9} {:>12} {:>12} {:>12}  fits {} ?",
        "integrator", "substeps", "min", "mean", "max", BUDGET
    );
    for t in &r.ticks {
        let name = if t.integrator == u64::from(INTEGRATOR_KANG_CHO) {
            "thesis"
        } else {
            "backward-euler"
        };
        let _ = writeln!(
            s,
            "{:>16} {:>9} {:>12} {:>12} {:>12}  {}",
            name,
            t.substeps,
            t.min,
            t.mean,
            t.max,
            if t.max <= BUDGET { "yes" } else { "no" }
        );
    }
    if let Some(g) = &r.guided {
        let _ = writeln!(
            s,
            "guided writing ({} substeps, a guide sample every tick): min {} mean {} max {}; \
             the same stroke unguided from the same start: mean {} max {}; extra per tick: \
             mean {:+}, max {:+}; GuideStream::tick alone: mean {} max {}",
            g.substeps,
            g.min,
            g.mean,
            g.max,
            r.unguided.0,
            r.unguided.1,
            g.mean as i64 - r.unguided.0 as i64,
            g.max as i64 - r.unguided.1 as i64,
            r.guide_alone.0,
            r.guide_alone.1
        );
    }
    let _ = writeln!(
        s,
        "one substep: {} instructions; once-per-tick surface update (end_tick): {}",
        r.substep, r.end_tick
    );
    if let Some((pose, torques)) = r.kinematics {
        let _ = writeln!(
            s,
            "pen kinematics in every tick: pose from the sensor readings {pose}, joint torques {torques}"
        );
    }
    let ops: Vec<String> = r.ops.iter().map(|(k, v)| format!("{k} {v:.0}")).collect();
    let _ = writeln!(
        s,
        "instructions per scalar operation (incl. loop overhead): {}",
        ops.join(", ")
    );
    for (integrator, name) in [
        (INTEGRATOR_BACKWARD_EULER, "backward Euler"),
        (INTEGRATOR_KANG_CHO, "the thesis's integrator"),
    ] {
        match r.largest_fitting(integrator) {
            Some(n) => {
                let _ = writeln!(
                    s,
                    "largest measured substeps_per_tick within {BUDGET} with {name}: {n}"
                );
            }
            None => {
                let _ = writeln!(
                    s,
                    "no measured substep rate fits {BUDGET} instructions per tick with {name}"
                );
            }
        }
    }
    if let Some(c) = &r.cycles {
        render_cycles(&mut s, c, r.worst_at());
    }
    let worst = r.per_tick().map(|t| t.max).unwrap_or(0);
    let _ = write!(s, "instructions_per_tick={worst}");
    if let Some(c) = &r.cycles {
        let _ = write!(s, "\ncycles_per_tick_estimate={}", c.total());
    }
    s
}

/// The estimate's lines (before the two final ones).
fn render_cycles(s: &mut String, c: &cycles::Estimate, bench_worst_at: Option<u64>) {
    use std::fmt::Write;
    let w = &c.worst;
    let _ = writeln!(
        s,
        "cycles on the Black Pill (estimate: QEMU's log of the default brush's ticks 1-{} weighed \
         with Cortex-M4 timings, {} MHz, {} flash wait states, ART prefetch, {}-line I-cache, \
         {}-line D-cache; docs/firmware-cost.md, \"Cycles\"):",
        c.ticks,
        cycles::SYSCLK_HZ / 1_000_000,
        cycles::WAIT_STATES,
        cycles::ICACHE_LINES,
        cycles::DCACHE_LINES,
    );
    let icount = c.icount_max.map_or(String::new(), |n| {
        format!(" (-icount: dearest of these ticks {n})")
    });
    let _ = writeln!(
        s,
        "  dearest tick {}: {} instructions{icount}, {} core cycles ({} taken branches) + {} flash \
         stall cycles ({} instruction lines, {} literal lines from flash); {:.2} cycles per instruction",
        c.worst_at,
        w.instructions,
        w.core,
        w.taken_branches,
        w.flash_stalls,
        w.icache_misses,
        w.dcache_misses,
        w.cycles() as f64 / w.instructions.max(1) as f64,
    );
    if let Some(k) = bench_worst_at {
        let _ = writeln!(
            s,
            "  the bench's dearest tick of the whole stroke (-icount): tick {k}, {} the traced ones",
            if k as usize <= c.ticks { "among" } else { "NOT among" }
        );
    }
    if w.unknown > 0 {
        let _ = writeln!(
            s,
            "  {} instructions of that tick are not in the model's table (counted as 1 cycle)",
            w.unknown
        );
    }
    let _ = writeln!(
        s,
        "  state fill (a frame due, 1 tick in 8 at 120 Hz), dearest: {} instructions, {} cycles; \
         ADC, three blocking gimbal reads: {} cycles",
        c.fill.instructions,
        c.fill.cycles(),
        c.adc
    );
    let _ = writeln!(s, "  top functions of the dearest tick (own cycles):");
    for (name, cyc) in c.top.iter().take(10) {
        let _ = writeln!(
            s,
            "  {:>8} {:>5.1}%  {name}",
            cyc,
            100.0 * *cyc as f64 / w.cycles().max(1) as f64
        );
    }
    let _ = writeln!(
        s,
        "cycles breakdown: core={} flash_stalls={} adc={} state_fill={}",
        w.core,
        w.flash_stalls,
        c.adc,
        c.fill.cycles()
    );
    let total = c.total();
    let (lo, hi) = w.refill_range();
    let _ = writeln!(
        s,
        "  every taken branch's refill at the TRM's least (1) / most (3): total {} / {}",
        total - w.cycles() + lo,
        total - w.cycles() + hi
    );
    let _ = writeln!(
        s,
        "cycles goal: <= {} (80% of {} cycles per 1 ms tick): {}",
        cycles::GOAL_CYCLES,
        cycles::SYSCLK_HZ / cycles::TICK_HZ,
        if c.fits() {
            format!("fits, {} to spare", cycles::GOAL_CYCLES - total)
        } else {
            format!(
                "OVER by {} ({:.1}% of the tick)",
                total - cycles::GOAL_CYCLES,
                100.0 * total as f64 / (cycles::SYSCLK_HZ / cycles::TICK_HZ) as f64
            )
        }
    );
}
