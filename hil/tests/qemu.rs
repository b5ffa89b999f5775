//! The firmware under QEMU (mps2-an386): boot, force loop, bench, fault paths.
//!
//! Needs `qemu-system-arm` and the `thumbv7em-none-eabihf` target (`.ci/run` installs
//! both, then runs these tests with `MAOBI_REQUIRE_QEMU=1`). Without QEMU the tests are
//! skipped with a message, unless `MAOBI_REQUIRE_QEMU` is set, which makes that a failure.

use std::path::PathBuf;
use std::time::Duration;

use hil::{bench, firmware, selftest};

const TIMEOUT: Duration = Duration::from_secs(300);

/// Builds the firmware once for all tests; `None` when QEMU is missing outside CI.
fn image() -> Option<PathBuf> {
    firmware::qemu_test_image()
}

#[test]
fn bench_reports_instructions_per_tick() {
    let Some(elf) = image() else { return };
    // What `hil bench` runs: the instruction counts, then the traced run's cycle estimate.
    let r = bench::with_cycles(&elf, 3, TIMEOUT).expect("bench runs");
    let text = bench::render(&r);
    println!("{text}");
    let lines: Vec<&str> = text.lines().collect();
    let [.., instr_line, cycles_line] = lines[..] else {
        panic!("too few lines:\n{text}")
    };
    let n: u64 = instr_line
        .strip_prefix("instructions_per_tick=")
        .expect("the line before the last names the instructions")
        .parse()
        .unwrap();
    assert!(n > 1000, "{n}");
    // The estimate is last, a whole number (so finite), and above the instruction count: no
    // instruction takes less than a cycle, and loads, multi-register moves, taken branches and
    // the ADC's waits take more.
    let cycles: u64 = cycles_line
        .strip_prefix("cycles_per_tick_estimate=")
        .expect("the last line names the cycle estimate")
        .parse()
        .expect("a whole number of cycles");
    assert!(cycles > n, "{cycles} cycles for {n} instructions");
    let c = r.cycles.as_ref().expect("an estimate");
    assert_eq!(cycles, c.total());
    assert!(
        text.contains(&format!(
            "cycles breakdown: core={} flash_stalls={} adc={} state_fill={}",
            c.worst.core,
            c.worst.flash_stalls,
            c.adc,
            c.fill.cycles()
        )),
        "{text}"
    );
    // The log is read whole: the traced tick's instructions agree with the firmware's own
    // `-icount` count of the same run's ticks (counted to 5 instructions, around the markers'
    // calls), and every instruction of it is in the model's table.
    let icount = c.icount_max.expect("the traced run's BENCH tick line");
    assert!(
        c.worst.instructions.abs_diff(icount) * 100 <= icount,
        "log {} against -icount {icount}",
        c.worst.instructions
    );
    assert_eq!(c.worst.unknown, 0, "instructions the model does not know");
    // The traced ticks hold the whole stroke's dearest (else the traced run must grow).
    let at = r.worst_at().expect("max_at_tick for the default brush");
    assert!(
        at as usize <= c.ticks,
        "dearest tick {at}, traced {}",
        c.ticks
    );
    assert!(c.fill.instructions > 100 && c.adc > 0, "{c:?}");
    // Fewer substeps never cost more, with either integrator.
    for w in r.ticks.windows(2) {
        if w[0].integrator == w[1].integrator {
            assert!(
                w[0].substeps > w[1].substeps && w[0].max >= w[1].max,
                "{:?}",
                r.ticks
            );
        }
    }
    // The Black Pill runs the default brush, as the desktop does (backward Euler at one
    // substep per tick), on a 96 MHz core, from an image built like this one
    // (`firmware/Cargo.toml`: the same code generation, so these are its instructions). The
    // bench's tick is the whole of the board's: the sensors through the encoder unwrap and
    // ADC filter, forward kinematics, the brush, the force model, the output stage with
    // forces enabled, and the joint torques. It must fit the 50,000 (half of a
    // 100 MHz millisecond at one instruction per cycle): about half of the board's
    // millisecond, the rest left for the link, USB and the flash's wait states (the count
    // today: docs/figures.md; its history: CHANGELOG.md).
    let one = r.per_tick().expect("a line for the default brush");
    assert_eq!(one.substeps, 1, "the pen's rate");
    assert!(one.max <= 50_000, "{one:?}");
    let kinematics = r.kinematics.expect("a kinematics line");
    assert!(kinematics.0 > 1000 && kinematics.1 > 100, "{kinematics:?}");
    // Guided writing's cost on the force path: the guide leads on every tick of its run and
    // costs more than nothing (it ran) and little beside the tick: at most 3% of the tick's
    // budget of 50,000 instructions (a share of the measured tick tightened every time the
    // tick got cheaper, and the guide's own cost is unchanged).
    let g = r.guided.as_ref().expect("a guided line");
    let extra = g.mean as i64 - r.unguided.0 as i64;
    println!(
        "guide: {extra:+} instructions per tick (alone {:?})",
        r.guide_alone
    );
    assert!(extra > 500 && extra < 50_000 * 3 / 100, "{extra}");
    assert!(
        r.guide_alone.0 > 500 && r.guide_alone.1 < 10_000,
        "{:?}",
        r.guide_alone
    );
}

/// `Fx`'s add, subtract and coefficient multiply are inline assembly on the Cortex-M4F
/// (`maobi_shared::scalar::raw`), its multiply the 32-bit partial-product path: checked on
/// the emulated core against their portable references, every pair of edge values and a
/// million pseudo-random operands each.
#[test]
fn fixed_point_assembly_matches_its_reference_on_the_core() {
    let Some(elf) = image() else { return };
    let (status, out) = selftest::arith(&elf, TIMEOUT).unwrap();
    println!("{out}");
    for op in ["add", "sub", "mul", "mul_coef"] {
        let line = out
            .lines()
            .find(|l| l.starts_with(&format!("ARITH op={op} ")))
            .unwrap_or_else(|| panic!("no line for {op}:\n{out}"));
        let field = |k: &str| -> u64 {
            line.split_whitespace()
                .find_map(|w| w.strip_prefix(k)?.strip_prefix('='))
                .and_then(|v| v.parse().ok())
                .unwrap_or_else(|| panic!("no {k} in {line}"))
        };
        assert!(field("cases") >= 1_000_000, "{line}");
        assert_eq!(field("mismatches"), 0, "{line}");
    }
    assert!(status.success(), "{status}\n{out}");
}

#[test]
fn bench_is_deterministic() {
    let Some(elf) = image() else { return };
    let a = bench::run(&elf, 3, TIMEOUT).unwrap();
    let b = bench::run(&elf, 3, TIMEOUT).unwrap();
    assert_eq!(a.ticks, b.ticks);
}

#[test]
fn selftest_ticks_the_brush_through_the_force_loop() {
    let Some(elf) = image() else { return };
    let line = selftest::selftest(&elf, 600, TIMEOUT).expect("selftest passes");
    println!("{line}");
    assert!(line.contains("brush_ticks=600"), "{line}");
    assert!(line.contains("faults=0x0 "), "{line}");
    assert!(line.contains("overruns=0"), "{line}");
}

#[test]
fn panic_hardfault_and_stall_turn_motors_off_and_exit_nonzero() {
    // The crash modes are test hooks: only the image built with them has them.
    let Some(elf) = firmware::qemu_test_hooks_image() else {
        return;
    };
    for (how, code, text) in [
        ("panic", 1, "FATAL panic"),
        ("hardfault", 2, "FATAL HardFault"),
        ("stall", 3, "FATAL watchdog"),
    ] {
        let (status, out) = selftest::crash(&elf, how, Duration::from_secs(60)).unwrap();
        assert_eq!(status.code(), Some(code), "{how}: {out}");
        assert!(
            out.contains(text) && out.contains("motors off"),
            "{how}: {out}"
        );
    }
}

/// The force loop holds no panicking index: no index or range check the compiler could not
/// prove is reachable from the interrupt handler that runs the tick, in the QEMU image
/// (`DefaultHandler`, which dispatches TIMER0 to the tick and the UART's and the timer
/// driver's interrupts) and in the Black Pill's (`TIM1_BRK_TIM9`; built here if it is not
/// yet). A failure names the functions.
#[test]
fn the_force_path_holds_no_index_panic() {
    let Some(elf) = image() else { return };
    let Some(pen) = firmware::blackpill_test_image() else {
        return;
    };
    for (elf, root) in [(elf, "DefaultHandler"), (pen, "TIM1_BRK_TIM9")] {
        let (calls, visited) = hil::panics::reachable_index_panics(&elf, root).unwrap();
        println!(
            "{}: {visited} functions reachable from {root}",
            elf.display()
        );
        // The walk reached the brush, the force model and the kinematics.
        assert!(visited > 20, "{visited}");
        assert!(calls.is_empty(), "{}: {calls:#?}", elf.display());
    }
}

/// The virtual pen's image is held to its own stated budget ([`firmware::Board::budget`]:
/// the pen's, plus the thesis's step that only it carries); `.ci/run` checks the Black
/// Pill's with `hil size --board blackpill --check`.
#[test]
fn image_fits_the_budget() {
    let Some(elf) = image() else { return };
    let s = firmware::size(&elf, 0x2000_0000).unwrap();
    let budget = firmware::Board::Qemu.budget();
    println!("{}", s.report(budget));
    assert_eq!(s.over_budget(budget), None, "{s:?}");
}

/// The image carries its boot line at info level (firmware/.cargo/config.toml's DEFMT_LOG):
/// without it a probe's log never shows the firmware come up.
#[test]
fn the_image_logs_its_boot_line_at_info() {
    let Some(elf) = image() else { return };
    let level = firmware::check_boot_line(&elf, firmware::Board::Qemu).unwrap();
    assert_eq!(level, "info");
}

/// flip-link's layout: the stack from the RAM's start up to the statics, so an overflow
/// faults (HardFault: motors off) instead of overwriting the force loop's state.
#[test]
fn the_stack_lies_below_the_statics() {
    let Some(elf) = image() else { return };
    let bytes = firmware::check_stack_layout(&elf, firmware::Board::Qemu).unwrap();
    assert!(bytes >= firmware::Board::STACK_RESERVE, "{bytes}");
}
