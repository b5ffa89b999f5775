//! Self-contained firmware runs: the boot self-test and the crash hooks.

use std::path::Path;
use std::process::ExitStatus;
use std::time::Duration;

use anyhow::{bail, Result};

use crate::qemu::{Clock, Run};

/// Force-loop period for emulated runs (us). A tick with the link's work beside it (a state
/// every tick, damaged frames, commands) can cost more than the million instructions a
/// virtual millisecond holds at `-icount` shift 0 with a brush set dearer than the presets
/// (`hil bench`), so emulated runs pace the loop slower; the model still advances 1 ms per
/// tick. A tick of 4 ms at shift 0 holds four million instructions, some 64 times the pen's
/// budget: at this pace no brush the protocol allows overruns, which suits the tests that
/// compare states or cut the link, and hides what a dear brush does to the pen. The tests
/// that judge the pen's timing run at its own pace ([`crate::run::PEN_ICOUNT_SHIFT`]).
pub const EMULATED_TICK_US: u32 = 4000;

/// Runs `selftest TICKS` and returns its summary line.
pub fn selftest(elf: &Path, ticks: u32, timeout: Duration) -> Result<String> {
    let t = ticks.to_string();
    let tick = format!("tick_us={EMULATED_TICK_US}");
    let run = Run::new(
        elf,
        &["selftest", &t, &tick],
        Clock::Deterministic { shift: 0 },
        timeout,
    );
    let (status, out) = run.output()?;
    if !status.success() {
        bail!("selftest failed ({status}):\n{out}");
    }
    match out.lines().find(|l| l.starts_with("selftest:")) {
        Some(l) => Ok(l.to_string()),
        None => bail!("selftest printed no summary:\n{out}"),
    }
}

/// Runs `arith` (the fixed-point operators' inline assembly against their references on the
/// emulated core) and returns QEMU's status and output.
pub fn arith(elf: &Path, timeout: Duration) -> Result<(ExitStatus, String)> {
    Run::new(elf, &["arith"], Clock::Deterministic { shift: 0 }, timeout).output()
}

/// Runs `crash HOW` (panic, hardfault, stall, starve) and returns QEMU's status and output.
pub fn crash(elf: &Path, how: &str, timeout: Duration) -> Result<(ExitStatus, String)> {
    let tick = format!("tick_us={EMULATED_TICK_US}");
    Run::new(
        elf,
        &["crash", how, &tick],
        Clock::Deterministic { shift: 0 },
        timeout,
    )
    .output()
}
