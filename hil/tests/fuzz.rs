//! A hostile or buggy host at the pen under QEMU: random well-formed host messages of every
//! kind with random fields, and a share of damaged frames (`maobi_shared::protocol::fuzz`),
//! streamed into the test image (the one with the fault-injection hook, so injected
//! overruns are part of the stream). Afterwards the pen still answers a handshake and a
//! ping, never printed a FATAL, never commanded a force beyond the limits in force, and its
//! deepest stack stays inside the reserve the RAM budget counts.
//!
//! Bounded: at most `MAOBI_FUZZ_MESSAGES` messages (default below) or `MAOBI_FUZZ_SECS`
//! seconds of streaming, whichever ends first. Seed: `MAOBI_FUZZ_SEED` (printed; the same
//! seed gives the same stream). Needs `qemu-system-arm` (skipped without it, unless
//! `MAOBI_REQUIRE_QEMU` is set, as in CI).

use std::collections::BTreeSet;
use std::time::{Duration, Instant};

use hil::firmware::{self, Board};
use hil::qemu::stack_readings;
use hil::run::QemuDevice;
use hil::session::Session;
use maobi_shared::protocol::fuzz::{self, Fuzz, Piece};
use maobi_shared::protocol::{DeviceMsg, EventKind, HostMsg};
use maobi_shared::{Fx, Scalar};

const TIMEOUT: Duration = Duration::from_secs(900);
const ANSWER: Duration = Duration::from_secs(20);
/// Messages streamed unless `MAOBI_FUZZ_MESSAGES` says otherwise.
const MESSAGES: usize = 6000;
/// Streaming stops after this long (s) unless `MAOBI_FUZZ_SECS` says otherwise, to keep a
/// loaded CI machine within its few minutes.
const STREAM_SECS: u64 = 120;
/// Share of frames damaged.
const DAMAGED: f64 = 0.1;
/// A round trip every this many messages (the host's own pings, [`SYNC_SEQ`] on).
const SYNC_EVERY: usize = 32;
const SYNC_SEQ: u32 = 0x5EC0_0000;

fn env_num(key: &str, default: u64) -> u64 {
    std::env::var(key)
        .ok()
        .and_then(|s| s.trim().parse().ok())
        .unwrap_or(default)
}

/// What the pen said while the stream ran.
#[derive(Default)]
struct Seen {
    faults_raised: u32,
    faults_cleared: u32,
    states: u32,
    /// States with the motors driven, and the largest commanded force (N) among them.
    driven: u32,
    peak_n: f64,
    /// States with forces off and a motor nudged.
    nudged: u32,
    /// The largest peak force the pen was configured for so far (N): its own at the
    /// handshake, then any configuration it accepted.
    limit_n: f64,
    /// States whose commanded force exceeded the limit in force.
    over: Vec<String>,
    fatal: bool,
}

impl Seen {
    fn take(&mut self, m: &DeviceMsg) {
        match m {
            DeviceMsg::Event(e) => match e.kind {
                EventKind::FaultRaised(_) => self.faults_raised += 1,
                EventKind::FaultCleared(_) => self.faults_cleared += 1,
                _ => {}
            },
            // A configuration the pen holds (accepted by SetConfig, or read by GetConfig):
            // its limits may be in force from now on.
            DeviceMsg::Config(Ok(cfg)) => {
                self.limit_n = self.limit_n.max(f64::from(cfg.limits.peak_n));
            }
            DeviceMsg::State(st) => {
                self.states += 1;
                // With forces enabled, the virtual pen's motor commands are the components
                // of the force on the hand (N). With forces off the motors may still run
                // for a bring-up nudge: one motor's torque, capped by the protocol
                // (`Nudge::MAX_PERMILLE` of the configured motor's full torque), not a
                // force the model commands.
                let f = st.haptics.motors.map(|b| Fx::from_bits(b).to_f64());
                let n = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
                if !st.haptics.enabled {
                    if n > 0.0 {
                        self.nudged += 1;
                    }
                    return;
                }
                if n > 0.0 {
                    self.driven += 1;
                }
                self.peak_n = self.peak_n.max(n);
                // One part in a thousand for the fixed point's rounding.
                if n > self.limit_n * 1.001 + 1e-6 && self.over.len() < 10 {
                    self.over.push(format!(
                        "tick {}: {n:.4} N over the limit {:.4} N",
                        st.tick, self.limit_n
                    ));
                }
            }
            _ => {}
        }
    }
}

#[test]
fn random_host_traffic_never_takes_the_pen_down() {
    let Some(elf) = firmware::qemu_test_hooks_image() else {
        return;
    };
    let seed = fuzz::seed_from_env(fuzz::DEFAULT_SEED);
    let max_messages = env_num("MAOBI_FUZZ_MESSAGES", MESSAGES as u64) as usize;
    let budget = Duration::from_secs(env_num("MAOBI_FUZZ_SECS", STREAM_SECS));
    println!("fuzz seed {seed:#x} (MAOBI_FUZZ_SEED to repeat)");
    let mut fz = Fuzz::new(seed);

    let (mut dev, stream) = QemuDevice::start(&elf, &["telemetry_ticks=100"], TIMEOUT).unwrap();
    let mut s = Session::new(stream).unwrap();
    let info = s.handshake(ANSWER, &mut vec![]).unwrap();
    let mut seen = Seen {
        limit_n: f64::from(info.force_peak_n),
        ..Default::default()
    };

    let start = Instant::now();
    let (mut sent, mut damaged, mut syncs) = (0usize, 0usize, 0usize);
    while sent < max_messages && start.elapsed() < budget {
        for p in fz.host_pieces(DAMAGED) {
            match &p {
                Piece::Damaged(_) => damaged += 1,
                // A valid configuration sent may be in force from the next tick on, before
                // its answer comes back: its limits count from now.
                Piece::Frame(HostMsg::SetConfig(cfg), _) if cfg.validate().is_ok() => {
                    seen.limit_n = seen.limit_n.max(f64::from(cfg.limits.peak_n));
                }
                _ => {}
            }
            s.write_raw(p.bytes()).unwrap();
            sent += 1;
        }
        for r in s.poll().unwrap() {
            seen.take(&r.msg);
        }
        // Every so often a round trip, as a host keeps in step with its device: the pen
        // under emulation reads slower than a host can write, and without it the stream
        // would pile up in the socket ahead of the pen. It also shows the link still
        // serving all along.
        if sent / SYNC_EVERY > syncs {
            syncs += 1;
            let mut skipped = vec![];
            let r = s.ping(SYNC_SEQ.wrapping_add(syncs as u32), ANSWER, &mut skipped);
            for m in &skipped {
                seen.take(&m.msg);
            }
            r.unwrap_or_else(|e| panic!("after {sent} messages: {e}"));
        }
    }
    let streamed = start.elapsed();

    // The pen serves the next client: a handshake (its decoder flushed by the delimiter),
    // a ping; then it idles past the supervisor's next stack reading.
    let info = s
        .handshake(ANSWER, &mut vec![])
        .expect("a handshake after the fuzz");
    s.ping(1, ANSWER, &mut vec![])
        .expect("a ping after the fuzz");
    for seq in 0..40 {
        s.send(&HostMsg::Ping { seq }).unwrap();
        std::thread::sleep(Duration::from_millis(100));
        for r in s.poll().unwrap() {
            seen.take(&r.msg);
        }
    }
    drop(s);
    let (exited, out) = dev.guest.stop().unwrap();
    seen.fatal = out.contains("FATAL");
    let deepest = stack_readings(&out).first().copied();

    let kinds: BTreeSet<_> = fz.host_kinds().iter().copied().collect();
    let missing: Vec<_> = fuzz::HOST_KINDS
        .iter()
        .filter(|k| !kinds.contains(*k))
        .collect();
    println!(
        "FUZZ pen: seed={seed:#x} messages={sent} damaged={damaged} kinds={}/{} \
         faults_raised={} faults_cleared={} states={} driven={} nudged={} peak_force_n={:.3} \
         limit_n={:.3} deepest_stack_bytes={} reserve_bytes={} streamed_s={:.1}",
        kinds.len(),
        fuzz::HOST_KINDS.len(),
        seen.faults_raised,
        seen.faults_cleared,
        seen.states,
        seen.driven,
        seen.nudged,
        seen.peak_n,
        seen.limit_n,
        deepest.map_or("none".into(), |d| d.to_string()),
        Board::STACK_RESERVE,
        streamed.as_secs_f64(),
    );

    assert!(exited.is_none(), "QEMU exited ({exited:?}):\n{out}");
    assert!(!seen.fatal, "the pen printed a FATAL:\n{out}");
    assert_eq!(info.board.as_str(), "qemu-mps2-an386");
    assert!(missing.is_empty(), "kinds never sent: {missing:?}");
    assert!(
        seen.over.is_empty(),
        "forces over the limit: {:?}",
        seen.over
    );
    // The stream did drive the pen: the motors ran, and faults came and went.
    assert!(seen.driven > 0, "the motors were never driven");
    assert!(seen.faults_raised > 0 && seen.faults_cleared > 0);
    let deepest = deepest.expect("the firmware reports its stack");
    assert!(
        deepest <= Board::STACK_RESERVE,
        "the stack reached {deepest} bytes, over the {} reserved in the RAM budget",
        Board::STACK_RESERVE
    );
}
