//! Every command the link accepts, the pen can run: the production QEMU image (no test
//! hooks), paced like the Black Pill, standing in for the pen (`limits=pen`), writing the
//! bench stroke itself (`poses=script`: a pose every tick, as a pen with sensors has).
//!
//! The pace is the pen's ([`hil::run::QemuDevice::start_paced_like_the_pen`]: 62,500
//! instructions in the board's real 1 ms tick).
//!
//! States at 30 Hz: the emulated UART takes an interrupt per byte (the pen's USB one per
//! 64-byte packet), and at the pen's pace 120 states a second would leave thread mode (the
//! link task) almost no time beside the tick.
//!
//! Nothing is timed by the wall clock: pen ticks are counted from the state frames' ticks,
//! and every wait is for an answer, under a hang guard only.

use std::net::TcpStream;
use std::path::PathBuf;
use std::time::Duration;

use hil::firmware;
use hil::run::QemuDevice;
use hil::session::Session;
use maobi_shared::params::{ParamId, TickLimits};
use maobi_shared::protocol::{
    Command, CommandError, DeviceInfo, DeviceMsg, EventKind, Faults, HostMsg, PresetRef,
    RejectReason,
};
use maobi_shared::{presets, BrushParams};

const TIMEOUT: Duration = Duration::from_secs(900);
/// Only a guard against a hang, far longer than any answer takes on a loaded machine.
const HANG_GUARD: Duration = Duration::from_secs(120);
/// Pen ticks over which the brush's ticks are counted.
const WINDOW_TICKS: u32 = 3000;

struct Pen {
    guest: QemuDevice,
    s: Session<TcpStream>,
    info: DeviceInfo,
    ping: u32,
    pings_answered: u32,
    /// The overruns the last telemetry counted.
    overruns: u32,
}

impl Pen {
    fn start(args: &[&str]) -> Option<Pen> {
        let elf: PathBuf = firmware::qemu_test_image()?;
        let mut all = vec!["poses=script", "state_hz=30", "telemetry_ticks=250"];
        all.extend_from_slice(args);
        let (guest, stream) = QemuDevice::start_paced_like_the_pen(&elf, &all, TIMEOUT).unwrap();
        let mut s = Session::new(stream).unwrap();
        let info = s.handshake(HANG_GUARD, &mut vec![]).unwrap();
        let mut pen = Pen {
            guest,
            s,
            info,
            ping: 0,
            pings_answered: 0,
            overruns: 0,
        };
        let w = pen.watch(500);
        println!("after the handshake: {}, faults {:?}", w.load(), w.faults);
        assert_eq!(pen.command(Command::ClearFaults), Ok(()));
        Some(pen)
    }

    /// The link answers: a ping, its pong.
    fn ping(&mut self) {
        self.ping += 1;
        self.s
            .ping(self.ping, HANG_GUARD, &mut vec![])
            .unwrap_or_else(|e| {
                let log = self.guest.guest.defmt_log();
                let said = self
                    .guest
                    .guest
                    .stop()
                    .map(|(st, out)| format!("{st:?}: {out}"));
                panic!("the link stopped answering: {e}; the pen said: {said:?} {log:?}")
            });
        self.pings_answered += 1;
    }

    fn ask(&mut self, m: HostMsg) -> DeviceMsg {
        self.s.send(&m).unwrap();
        let answer = self
            .s
            .wait_for(HANG_GUARD, &mut vec![], |r| match r {
                DeviceMsg::Param(_) | DeviceMsg::CommandDone { .. } => Some(r.clone()),
                _ => None,
            })
            .unwrap()
            .expect("an answer")
            .0;
        self.ping();
        answer
    }

    fn set(&mut self, id: ParamId, value: f32) -> Result<f32, RejectReason> {
        match self.ask(HostMsg::SetParam {
            id: id as u8,
            value,
        }) {
            DeviceMsg::Param(r) => r.result.map_err(|e| e.reason),
            other => panic!("{other:?}"),
        }
    }

    fn command(&mut self, c: Command) -> Result<(), CommandError> {
        match self.ask(HostMsg::Command(c)) {
            DeviceMsg::CommandDone { result, .. } => result,
            other => panic!("{other:?}"),
        }
    }

    /// The pen's telemetry over the next `ticks` pen ticks (by the reports' own ticks), a
    /// ping answered before and after; also the faults its states and events reported.
    fn watch(&mut self, ticks: u32) -> Watch {
        self.ping();
        let mut w = Watch {
            overruns_before: self.overruns,
            ..Watch::default()
        };
        loop {
            let r = self
                .s
                .recv(HANG_GUARD)
                .unwrap()
                .expect("the pen reports its telemetry");
            match r.msg {
                DeviceMsg::Telemetry(t) => {
                    self.overruns = t.overruns;
                    let start = w.telemetry.first().map_or(t.tick, |f| f.tick);
                    let done = t.tick.wrapping_sub(start) >= ticks;
                    w.telemetry.push(t);
                    if done {
                        break;
                    }
                }
                DeviceMsg::State(st) => w.faults = st.faults,
                DeviceMsg::Event(e) => {
                    w.faults = e.faults;
                    w.events.push(e.kind);
                }
                _ => {}
            }
        }
        self.ping();
        w
    }
}

#[derive(Default)]
struct Watch {
    /// The pen's overrun count when the watch began.
    overruns_before: u32,
    telemetry: Vec<maobi_shared::protocol::Telemetry>,
    events: Vec<EventKind>,
    faults: Faults,
}

impl Watch {
    /// Brush ticks per 1,000 pen ticks between the first and the last report.
    fn brush_per_1000(&self) -> u64 {
        let (Some(a), Some(b)) = (self.telemetry.first(), self.telemetry.last()) else {
            return 0;
        };
        let pen = u64::from(b.tick.wrapping_sub(a.tick));
        let brush = u64::from(b.brush_ticks.wrapping_sub(a.brush_ticks));
        (brush * 1000).checked_div(pen).unwrap_or(0)
    }
    /// Overruns since the watch began: the last report's count against the count before
    /// it ([`Pen::overruns_before`]).
    fn overruns(&self) -> u32 {
        self.telemetry
            .last()
            .map_or(0, |b| b.overruns.wrapping_sub(self.overruns_before))
    }
    /// The last report's mean load and worst tick, and the overruns meanwhile.
    fn load(&self) -> String {
        match self.telemetry.last() {
            None => "no telemetry".into(),
            Some(t) => format!(
                "load {}%, worst tick {} us ({:.1}%), {} overruns meanwhile",
                t.load_percent,
                t.tick_busy_max_us,
                t.worst_busy_percent(),
                self.overruns()
            ),
        }
    }
}

/// The most expensive value the parameter's range allows (its top: more layers, nodes,
/// sweeps and substeps cost more; the others cost the same at any value).
fn most_expensive(id: ParamId) -> f32 {
    id.range().1
}

#[test]
fn the_pen_refuses_what_its_tick_cannot_run_and_ticks_every_tick() {
    let Some(mut pen) = Pen::start(&["limits=pen"]) else {
        return;
    };
    let limits = pen.info.limits;
    println!("pen: {} tick limits: {limits}", pen.info.board);
    assert_ne!(
        limits,
        TickLimits::NONE,
        "limits=pen announces the pen's caps"
    );
    let base = presets::LARGE;
    // The brush as the pen starts, at the pen's limits.
    assert_eq!(limits.check(&limits.brush(base)), Ok(()));

    // Every parameter at its most expensive valid value, one at a time, then back.
    let mut refused = 0;
    let mut overran = vec![];
    for id in ParamId::ALL {
        let top = most_expensive(id);
        let answer = pen.set(id, top);
        match (limits.cap(id), &answer) {
            (Some(max), Err(RejectReason::OverTickLimit { value, max: m })) => {
                assert!(top > f32::from(max), "{id}: {top} refused at cap {max}");
                assert_eq!((*value, *m), (top, f32::from(max)), "{id}");
                refused += 1;
            }
            (Some(max), Ok(_)) => assert!(top <= f32::from(max), "{id} {top} over its cap taken"),
            (None, Err(RejectReason::OverTickLimit { .. })) => {
                panic!("{id} has no cap but was refused for the tick")
            }
            (_, Err(RejectReason::UnknownParam)) => panic!("{id} unknown to the pen"),
            _ => {}
        }
        match &answer {
            Ok(v) => {
                // Taken: the brush runs it within the tick, the tick that takes it included.
                let w = pen.watch(500);
                println!(
                    "{id} = {top}: taken ({v}); {} brush ticks per 1000, {}",
                    w.brush_per_1000(),
                    w.load()
                );
                if w.overruns() > 0 || w.brush_per_1000() < 950 {
                    overran.push(format!("{id} = {top}: {}", w.load()));
                }
            }
            Err(why) => println!("{id} = {top}: refused: {why:?}"),
        }
        // Its cap itself is taken.
        if let Some(max) = limits.cap(id) {
            assert_eq!(pen.set(id, f32::from(max)), Ok(f32::from(max)), "{id}");
        }
        // Back to the pen's brush.
        let back = limits.brush(base).get(id);
        assert_eq!(pen.set(id, back), Ok(back), "{id} back to {back}");
        assert_eq!(pen.command(Command::ClearFaults), Ok(()));
    }
    assert!(
        overran.is_empty(),
        "values the pen took but could not run: {overran:#?}"
    );
    assert_eq!(refused, 4, "every capped parameter refused at its top");

    // The two: 16 layers and two substeps, refused with the reason.
    for (id, v) in [(ParamId::Layers, 16.0), (ParamId::SubstepsPerTick, 2.0)] {
        let answer = pen.set(id, v);
        assert!(
            matches!(answer, Err(RejectReason::OverTickLimit { value, .. }) if value == v),
            "{id} {v}: {answer:?}"
        );
        println!(
            "{id} = {v}: refused: {}",
            reason_text(id, answer.unwrap_err())
        );
    }
    // A preset that asks for more substeps runs at the pen's.
    assert_eq!(
        pen.command(Command::ChoosePreset(PresetRef::Index(2))),
        Ok(())
    );
    assert_eq!(
        match pen.ask(HostMsg::GetParam {
            id: ParamId::SubstepsPerTick as u8
        }) {
            DeviceMsg::Param(r) => r.result.ok(),
            _ => None,
        },
        Some(f32::from(limits.substeps_per_tick))
    );
    assert_eq!(
        pen.command(Command::ChoosePreset(PresetRef::Index(0))),
        Ok(())
    );
    let w = pen.watch(500);
    println!("presets chosen: {}", w.load());
    assert_eq!(w.overruns(), 0, "choosing a preset overran");

    // The most expensive brush it takes: every cap at once, and every uncapped parameter's
    // value at its most expensive is the same cost. Its brush must tick every tick.
    let mut brush: BrushParams = limits.brush(base);
    for (id, max) in limits.caps() {
        assert_eq!(pen.set(id, f32::from(max)), Ok(f32::from(max)), "{id}");
        brush.set(id, f32::from(max)).unwrap();
    }
    // Settle, then count.
    pen.watch(200);
    let w = pen.watch(WINDOW_TICKS);
    let per_1000 = w.brush_per_1000();
    println!(
        "most expensive valid brush ({limits}): brush ticks per 1000 pen ticks {per_1000}, {}; {} reports, faults {:?}; pings answered {}/{}",
        w.load(),
        w.telemetry.len(),
        w.faults,
        pen.pings_answered,
        pen.ping
    );
    assert!(per_1000 >= 950, "{per_1000} brush ticks per 1000");
    assert!(!w.faults.contains(Faults::LOOP_OVERRUN), "{:?}", w.faults);
    assert_eq!(w.overruns(), 0, "{:?}", w.telemetry);
    assert_eq!(pen.pings_answered, pen.ping);
}

/// Without the pen's limits (the QEMU board's own: no deadline), two substeps at the pen's
/// pace overrun: the brush stands by (motors off), the link answers, and once the fault is
/// cleared at a rate the core holds, the brush ticks every tick again.
#[test]
fn an_overrun_stands_the_brush_by_and_clearing_the_fault_resumes_it() {
    let Some(mut pen) = Pen::start(&[]) else {
        return;
    };
    assert_eq!(pen.info.limits, TickLimits::NONE);
    pen.watch(200);
    let before = pen.watch(1000);
    println!(
        "one substep: {} brush ticks per 1000, {}",
        before.brush_per_1000(),
        before.load()
    );
    assert!(before.brush_per_1000() >= 950);

    assert_eq!(pen.set(ParamId::SubstepsPerTick, 2.0), Ok(2.0));
    let over = pen.watch(WINDOW_TICKS);
    println!(
        "two substeps: faults {:?}, {} brush ticks per 1000 pen ticks, {}; pings answered {}/{}",
        over.faults,
        over.brush_per_1000(),
        over.load(),
        pen.pings_answered,
        pen.ping
    );
    assert!(
        over.faults.contains(Faults::LOOP_OVERRUN),
        "{:?}",
        over.faults
    );
    assert!(over.telemetry.iter().all(|t| t.overruns >= 1));
    // Standing by: once the overrun latched, the brush takes no pose while the pen ticks.
    let tail = &over.telemetry[over.telemetry.len() / 2..];
    assert!(tail.len() >= 2, "{} reports", tail.len());
    assert!(
        tail.windows(2)
            .all(|p| p[0].brush_ticks == p[1].brush_ticks && p[1].tick > p[0].tick),
        "the brush ticked while the overrun was latched: {tail:?}"
    );
    // Forces were refused meanwhile.
    assert!(matches!(
        pen.command(Command::EnableForces),
        Err(CommandError::FaultsLatched(f)) if f.contains(Faults::LOOP_OVERRUN)
    ));

    assert_eq!(pen.set(ParamId::SubstepsPerTick, 1.0), Ok(1.0));
    assert_eq!(pen.command(Command::ClearFaults), Ok(()));
    pen.watch(200);
    let after = pen.watch(WINDOW_TICKS);
    println!(
        "cleared at one substep: faults {:?}, {} brush ticks per 1000 pen ticks, {}; pings answered {}/{}",
        after.faults,
        after.brush_per_1000(),
        after.load(),
        pen.pings_answered,
        pen.ping
    );
    assert!(after.brush_per_1000() >= 950, "{}", after.brush_per_1000());
    assert!(!after.faults.contains(Faults::LOOP_OVERRUN));
    assert_eq!(pen.pings_answered, pen.ping);
}

/// The refusal as the host shows it.
fn reason_text(id: ParamId, reason: RejectReason) -> String {
    maobi_shared::protocol::ParamRejected {
        param: id as u8,
        reason,
    }
    .to_string()
}
