//! `maobi device check` against fake pens on TCP that speak the bring-up messages (protocol
//! 2): a physical pen (its encoders moved by a scripted "hand" while the sensors stream, by
//! its motors when nudged, with wiring that can be reversed or dead) and a virtual pen (its
//! readings computed from the poses the wizard streams, as the QEMU board does). The whole
//! wizard runs, non-interactively (`--yes`). Not run against a real pen.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use maobi::device::bringup::{run_check, CheckOptions, CheckReport, Operator, Outcome, Scripted};
use maobi::device::endpoint::nothing_to_read_yet;
use maobi::device::{Endpoint, SimDeviceOptions, SimDeviceServer};
use maobi_shared::kinematics::RawReadings;
use maobi_shared::protocol::{
    BrushState, Buttons, Capabilities, Command, CommandError, ConfigRejected, ConfigState,
    DeviceConfig, DeviceInfo, DeviceMsg, DeviceRx, Faults, HostMsg, Message, SensorReport,
    Telemetry, Version,
};
use maobi_shared::{presets, Brush, Fx, Pose, Quat, Vec3};

/// The sensor reports the fake pen's scripted hand shapes: it moves six channels, three
/// reports out and three back each, and a move shows in the report after it.
const HAND_REPORTS: usize = 6 * 6 + 1;

/// What the fake pen is and what happened to it.
#[derive(Clone, Debug)]
struct Pen {
    virtual_pen: bool,
    config: Option<DeviceConfig>,
    /// How each motor is really wired: +1, -1 (reversed), 0 (dead).
    wiring: [i64; 3],
    /// Sensor channels the scripted hand moves (encoders 0..3, gimbal 3..6).
    hand_moves: [bool; 6],
    encoders: [i64; 3],
    gimbal: [u16; 3],
    poses_received: usize,
    nudges: usize,
    /// `Calibrate` succeeded since this (fake) power-on: a physical pen's incremental
    /// encoders make stored zeros meaningless after a reset, so, as the firmware does, the
    /// pen reports `NOT_CALIBRATED` and refuses nudges until then.
    calibrated_since_power_on: bool,
    /// The stored image was of this older format, migrated: the handshake says
    /// `ConfigState::Migrated` (the configuration is in force for the kinematics).
    migrated_from: Option<u16>,
}

impl Pen {
    fn physical(config: Option<DeviceConfig>, wiring: [i64; 3]) -> Self {
        Pen {
            virtual_pen: false,
            config,
            wiring,
            hand_moves: [true; 6],
            encoders: [1000, -500, 20],
            gimbal: [2048; 3],
            poses_received: 0,
            nudges: 0,
            calibrated_since_power_on: false,
            migrated_from: None,
        }
    }
    /// What the firmware reports beside latched faults (`pen_io::Readiness`).
    fn faults(&self) -> Faults {
        if self.virtual_pen || self.calibrated_since_power_on {
            Faults::empty()
        } else {
            Faults::NOT_CALIBRATED
        }
    }
    fn info(&self) -> DeviceInfo {
        if self.virtual_pen {
            // As the QEMU board without a configuration image announces itself.
            return DeviceInfo::new(
                "fake-virtual",
                Version::default(),
                Capabilities::VIRTUAL_PEN
                    | Capabilities::FORCE_OUTPUT
                    | Capabilities::STORED_CONFIG,
                3.3,
                0.88,
            );
        }
        let state = match (self.config, self.migrated_from) {
            (Some(_), Some(from)) => ConfigState::Migrated { from },
            (Some(_), None) => ConfigState::Valid,
            (None, _) => ConfigState::Missing,
        };
        DeviceInfo::new(
            "fake-pen",
            Version::default(),
            Capabilities::REAL_SENSORS
                | Capabilities::FORCE_OUTPUT
                | Capabilities::NEEDS_CALIBRATION
                | Capabilities::STORED_CONFIG
                | Capabilities::BUTTONS,
            3.3,
            0.88,
        )
        .with_config(state)
    }
    /// The scripted hand, after report `k` of the stream (`k` below [`HAND_REPORTS`]):
    /// channel `k / 6` goes out (three reports) and back (three); channel 1 goes the
    /// negative way.
    fn hand(&mut self, k: usize) {
        let ch = k / 6;
        if ch >= 6 || !self.hand_moves[ch] {
            return;
        }
        let out = k % 6 < 3;
        let dir = if ch == 1 { -1 } else { 1 } * if out { 1 } else { -1 };
        if ch < 3 {
            self.encoders[ch] += 20 * dir;
        } else {
            self.gimbal[ch - 3] = (i64::from(self.gimbal[ch - 3]) + 10 * dir) as u16;
        }
    }
    fn command(&mut self, c: &Command) -> Result<(), CommandError> {
        match c {
            Command::StreamSensors { .. } => Ok(()),
            Command::NudgeMotor(n) => {
                if !n.is_within_caps() {
                    return Err(CommandError::OutOfRange);
                }
                let cfg = self.config.as_ref().ok_or(CommandError::ConfigNotValid)?;
                if !self.virtual_pen && !self.calibrated_since_power_on {
                    return Err(CommandError::ConfigNotValid);
                }
                let ch = usize::from(n.channel);
                self.nudges += 1;
                if !self.virtual_pen {
                    let sign = i64::from(n.command_permille.signum())
                        * i64::from(cfg.pen.motor_sign[ch])
                        * self.wiring[ch];
                    self.encoders[ch] += 30 * sign;
                }
                Ok(())
            }
            Command::Calibrate if self.virtual_pen => Err(CommandError::Unsupported),
            Command::Calibrate => {
                let raw = RawReadings {
                    encoders: self.encoders,
                    gimbal: self.gimbal.map(i32::from),
                };
                let cfg = self.config.as_mut().ok_or(CommandError::ConfigNotValid)?;
                cfg.calibration = Some(raw);
                self.calibrated_since_power_on = true;
                Ok(())
            }
            _ => Err(CommandError::Unsupported),
        }
    }
}

fn send(s: &mut TcpStream, m: &DeviceMsg) {
    let mut buf = vec![0u8; DeviceMsg::MAX_FRAME];
    let n = m.encode(&mut buf).unwrap();
    s.write_all(&buf[..n]).unwrap();
}

/// Serves one connection on a loopback port; returns the address and the pen's state.
fn serve(pen: Pen) -> (String, Arc<Mutex<Pen>>) {
    serve_turning_away(pen, 0)
}

/// As [`serve`], after closing the first `turn_away` connections as soon as they arrive (as
/// QEMU's UART socket does to a client that comes before it has seen the last one leave).
fn serve_turning_away(pen: Pen, turn_away: usize) -> (String, Arc<Mutex<Pen>>) {
    let l = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = l.local_addr().unwrap().to_string();
    let shared = Arc::new(Mutex::new(pen));
    let pen = shared.clone();
    std::thread::spawn(move || {
        for _ in 0..turn_away {
            drop(l.accept().unwrap());
        }
        let (mut s, _) = l.accept().unwrap();
        s.set_read_timeout(Some(Duration::from_millis(5))).unwrap();
        let mut rx = DeviceRx::new();
        let mut buf = [0u8; 1024];
        let mut streaming = false;
        let mut last_report = Instant::now();
        let mut tick = 0u32;
        let mut last_tick = 0u32;
        let mut reports = 0usize;
        let mut last_seq = 0u32;
        let mut queued = std::collections::VecDeque::new();
        let clock = Instant::now();
        let mut ms = 0u32;
        // A virtual pen's states say which pose it consumed last (the wizard paces its poses
        // by them); the brush itself stays at rest at the start pose.
        let start = Pose::new(Vec3::new(0.0, 0.0, 30.0), Quat::IDENTITY).cast::<Fx>();
        let brush = Brush::<Fx>::new(presets::LARGE, start).unwrap();
        loop {
            let n = match s.read(&mut buf) {
                Ok(0) => return,
                Ok(n) => n,
                Err(e) if nothing_to_read_yet(&e) => 0,
                Err(_) => return,
            };
            let msgs: Vec<HostMsg> = rx.feed(&buf[..n]).filter_map(Result::ok).collect();
            let mut p = pen.lock().unwrap();
            for m in msgs {
                let reply = match m {
                    HostMsg::Hello(_) => DeviceMsg::Hello(p.info()),
                    HostMsg::Ping { seq } => DeviceMsg::Pong { seq },
                    HostMsg::Pose(sample) => {
                        p.poses_received += 1;
                        queued.push_back(sample);
                        continue;
                    }
                    HostMsg::Command(c) => {
                        if let Command::StreamSensors { rate_hz } = c {
                            streaming = rate_hz > 0;
                        }
                        let result = p.command(&c);
                        DeviceMsg::CommandDone { command: c, result }
                    }
                    HostMsg::GetConfig => DeviceMsg::Config(match &p.config {
                        Some(c) => Ok(*c),
                        None => Err(ConfigRejected::NotStored(ConfigState::Missing)),
                    }),
                    HostMsg::SetConfig(c) => DeviceMsg::Config(match c.validate() {
                        Ok(()) => {
                            // Zeros hold only if they are the ones taken since power-on.
                            p.calibrated_since_power_on &=
                                p.config.is_some_and(|old| old.calibration == c.calibration);
                            p.config = Some(c);
                            Ok(c)
                        }
                        Err(f) => Err(ConfigRejected::Invalid(f)),
                    }),
                    _ => continue,
                };
                send(&mut s, &reply);
            }
            // One pose per millisecond, as a 1 kHz pen consumes them.
            let mut consumed = false;
            while clock.elapsed() > Duration::from_millis(u64::from(ms)) {
                ms += 1;
                let Some(sample) = queued.pop_front() else {
                    continue;
                };
                consumed = true;
                last_seq = sample.seq;
                // Synthetic readings, linear in the pose (the QEMU board uses the pen's
                // inverse kinematics).
                let pose = sample.pose().cast::<f64>();
                let pos = pose.pos;
                p.encoders = [pos.x, pos.y, pos.z].map(|v| (v * 10.0).round() as i64);
                let q = pose.rot;
                p.gimbal = [q.x, q.y, q.z].map(|v| (2048.0 + v * 2000.0) as u16);
            }
            // A physical pen's states carry its faults (the brush stays at rest).
            if consumed || last_report.elapsed() >= Duration::from_millis(20) {
                let st =
                    BrushState::from_brush(&brush, tick, last_seq, Default::default(), p.faults());
                send(&mut s, &DeviceMsg::State(st));
            }
            if last_report.elapsed() >= Duration::from_millis(20) {
                last_report = Instant::now();
                tick += 20;
                // Its timing once a second, as the firmware reports it: a tick well inside
                // its millisecond.
                if tick.is_multiple_of(1000) {
                    let t = Telemetry {
                        tick,
                        tick_period_min_us: 998,
                        tick_period_mean_us: 1000,
                        tick_period_max_us: 1003,
                        load_percent: 70,
                        tick_busy_max_us: 760,
                        tick_busy_max_cycles: 72_960,
                        brush_ticks: tick,
                        ..Telemetry::default()
                    };
                    send(&mut s, &DeviceMsg::Telemetry(t));
                }
            }
            if streaming && tick > last_tick {
                last_tick = tick;
                reports += 1;
                let r = SensorReport {
                    tick,
                    encoders: p.encoders,
                    gimbal: p.gimbal,
                    buttons: if reports == 3 {
                        Buttons::PRIMARY
                    } else if reports > HAND_REPORTS {
                        // The scripted hand is done: button 2 held down says so.
                        Buttons::SECONDARY
                    } else {
                        Buttons::empty()
                    },
                    synthetic: p.virtual_pen,
                };
                send(&mut s, &DeviceMsg::Sensors(r));
                if !p.virtual_pen {
                    p.hand(reports - 1);
                }
            }
        }
    });
    (addr, shared)
}

/// A step's detail, by its name (an uncalibrated pen is calibrated before the nudges).
fn detail<'a>(r: &'a CheckReport, step: &str) -> &'a str {
    &r.steps
        .iter()
        .find(|s| s.step == step)
        .unwrap_or_else(|| panic!("no step {step}:\n{}", r.table()))
        .detail
}

/// The longest the wizard may take over a step that ends on an event (here: the scripted
/// hand done), or over a refused connection: only a hang gets near it.
const HANG_GUARD: Duration = Duration::from_secs(60);

fn opts(addr: &str) -> CheckOptions {
    let mut o = CheckOptions::new(Endpoint::Tcp(addr.to_string()));
    // The sensor step of a physical pen ends when the operator presses Enter
    // ([`UntilHandDone`]); its own time limit only guards a hang.
    o.sensor_time = HANG_GUARD;
    o
}

/// `--yes`, and Enter in the sensor step once the wizard has shown a reading of the fake
/// pen's with button 2 down: its scripted hand is done and every reading of it was read (the
/// readings come in order), however fast the machine is.
#[derive(Default)]
struct UntilHandDone {
    script: Scripted,
    hand_done: bool,
}

impl Operator for UntilHandDone {
    fn say(&mut self, text: &str) {
        self.script.say(text);
    }
    fn live(&mut self, text: &str) {
        // The live line ends with the buttons down ("1", "2", "1+2" or "-").
        let buttons = text.rsplit("buttons ").next().unwrap_or("");
        self.hand_done |= buttons.split('+').any(|b| b == "2");
        self.script.live(text);
    }
    fn confirm(&mut self, question: &str) -> bool {
        self.script.confirm(question)
    }
    fn wait_enter(&mut self, prompt: &str) {
        self.script.wait_enter(prompt);
    }
    fn enter_pressed(&mut self) -> bool {
        self.hand_done
    }
}

fn run(pen: Pen) -> (CheckReport, Pen, Vec<String>) {
    let (addr, state) = serve(pen);
    let mut op = UntilHandDone::default();
    let r = run_check(&opts(&addr), &mut op);
    println!("{}\n{}", op.script.transcript.join("\n"), r.table());
    let p = state.lock().unwrap().clone();
    (r, p, op.script.transcript)
}

#[test]
fn a_connection_turned_away_before_the_handshake_is_tried_again() {
    let (addr, _) = serve_turning_away(Pen::physical(Some(DeviceConfig::DEFAULT), [1; 3]), 2);
    let mut op = UntilHandDone::default();
    let r = run_check(&opts(&addr), &mut op);
    assert_eq!(
        r.outcome("1 handshake"),
        Some(Outcome::Pass),
        "{}",
        r.table()
    );
    assert!(r.passed(), "{}", r.table());
}

#[test]
fn a_refused_handshake_is_not_retried() {
    // Nothing listens: the open fails at once, with the address in the message.
    let addr = {
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        l.local_addr().unwrap().to_string()
    };
    // Given the hang guard as its reply timeout: retried, it would take all of it.
    let mut o = opts(&addr);
    o.reply_timeout = HANG_GUARD;
    let started = Instant::now();
    let r = run_check(&o, &mut Scripted::default());
    let took = started.elapsed();
    assert_eq!(
        r.outcome("1 handshake"),
        Some(Outcome::Fail),
        "{}",
        r.table()
    );
    assert!(detail(&r, "1 handshake").contains(&addr), "{}", r.table());
    assert!(took < HANG_GUARD / 2, "{took:?}: retried until the timeout");
}

#[test]
fn a_reversed_motor_is_flipped_and_every_step_passes() {
    let (r, pen, _) = run(Pen::physical(Some(DeviceConfig::DEFAULT), [1, 1, -1]));
    assert!(r.passed(), "{}", r.table());
    for s in [
        "1 handshake",
        "2 sensors",
        "3 motor 0 (base (yaw))",
        "3 motor 1 (shoulder)",
        "3 motor 2 (elbow)",
        "4 calibration",
        "5 tick",
    ] {
        assert_eq!(r.outcome(s), Some(Outcome::Pass), "{s}\n{}", r.table());
    }
    let tick = &r.steps.last().unwrap().detail;
    assert!(tick.contains("worst tick busy 760 us (76.0%"), "{tick}");
    let sensors = &r.steps[1].detail;
    assert!(sensors.contains("shoulder: PASS -60 counts"), "{sensors}");
    assert!(sensors.contains("base (yaw): PASS +60 counts"), "{sensors}");
    assert!(sensors.contains("gimbal 3: PASS +30 codes"), "{sensors}");
    let elbow = detail(&r, "3 motor 2 (elbow)");
    assert!(elbow.contains("was reversed (-30 counts)"), "{elbow}");
    assert!(elbow.contains("again: +30 counts"), "{elbow}");
    // The reference configuration is not calibrated: calibration ran before the nudges.
    let order: Vec<&str> = r.steps.iter().map(|s| s.step.as_str()).collect();
    assert_eq!(order[2], "4 calibration", "{order:?}");
    let cfg = pen.config.unwrap();
    assert_eq!(cfg.pen.motor_sign, [1, 1, -1]);
    assert!(cfg.calibration.is_some());
    // Four nudges: one per motor and the elbow's again.
    assert_eq!(pen.nudges, 4);
}

/// A pen calibrated at an earlier power-on: its stored zeros do not hold (incremental
/// encoders), it reports NOT_CALIBRATED and refuses nudges, so the wizard calibrates first.
#[test]
fn zeros_from_an_earlier_power_on_are_taken_again_before_the_nudges() {
    let mut cfg = DeviceConfig::DEFAULT;
    cfg.calibration = Some(RawReadings {
        encoders: [7, 7, 7],
        gimbal: [2000; 3],
    });
    let (r, pen, said) = run(Pen::physical(Some(cfg), [1, 1, 1]));
    assert!(r.passed(), "{}", r.table());
    let order: Vec<&str> = r.steps.iter().map(|s| s.step.as_str()).collect();
    assert_eq!(order[2], "4 calibration", "{order:?}");
    assert!(
        said.iter().any(|l| l.contains("not calibrated yet")),
        "{said:?}"
    );
    assert!(pen.calibrated_since_power_on);
    assert_ne!(pen.config.unwrap().calibration, cfg.calibration);
    assert_eq!(pen.nudges, 3);
}

#[test]
fn a_missing_configuration_is_written_before_anything_moves() {
    let (r, pen, said) = run(Pen::physical(None, [1, 1, 1]));
    assert!(r.passed(), "{}", r.table());
    assert!(
        r.steps[0]
            .detail
            .contains("the reference configuration was written"),
        "{}",
        r.table()
    );
    assert!(said.iter().any(|l| l.contains("missing (never written)")));
    let cfg = pen.config.unwrap();
    assert!(cfg.calibration.is_some());
}

#[test]
fn a_migrated_configuration_stops_the_check_and_says_what_to_set() {
    let mut old = DeviceConfig::DEFAULT;
    old.pen.upper_arm_mm = 140.0;
    old.drive.iter_mut().for_each(|d| d.winding_mohm = 0);
    let mut pen = Pen::physical(Some(old), [1, 1, 1]);
    pen.migrated_from = Some(1);
    let (r, pen, said) = run(pen);
    assert!(!r.passed(), "{}", r.table());
    let d = detail(&r, "1 handshake");
    for part in [
        "configuration migrated from format 1: set the motors' winding resistance, supply \
         voltage and driver rating",
        "to enable force",
        "stopped",
        "maobi device config get",
        "maobi device config set",
    ] {
        assert!(d.contains(part), "{part}: {}", r.table());
    }
    assert!(
        said.iter()
            .any(|l| l.contains("configuration migrated from format 1")),
        "{said:?}"
    );
    // Nothing written over the migrated configuration, nothing moved.
    assert_eq!(pen.config, Some(old));
    assert_eq!(pen.nudges, 0);
}

#[test]
fn a_dead_motor_and_a_joint_that_never_moves_fail() {
    let mut pen = Pen::physical(Some(DeviceConfig::DEFAULT), [1, 0, 1]);
    pen.hand_moves[5] = false; // gimbal 3 stuck
    let (r, _, _) = run(pen);
    assert!(!r.passed(), "{}", r.table());
    assert_eq!(r.outcome("2 sensors"), Some(Outcome::Fail));
    assert!(r.steps[1].detail.contains("gimbal 3: FAIL +0 codes"));
    assert_eq!(r.outcome("3 motor 1 (shoulder)"), Some(Outcome::Fail));
    assert!(
        detail(&r, "3 motor 1 (shoulder)").contains("did not move"),
        "{}",
        r.table()
    );
    assert_eq!(r.outcome("3 motor 0 (base (yaw))"), Some(Outcome::Pass));
    assert_eq!(r.outcome("4 calibration"), Some(Outcome::Pass));
}

#[test]
fn a_virtual_pen_is_moved_by_the_wizard_and_says_what_it_cannot_show() {
    let mut pen = Pen::physical(None, [1, 1, 1]);
    pen.virtual_pen = true;
    // The readings of the pose the wizard starts from (no state from this fake: its
    // default, 30 mm above the paper's origin, upright).
    pen.encoders = [0, 0, 300];
    // A virtual pen refuses nudges without a configuration in the real boards; this fake
    // accepts them when it has one.
    pen.config = Some(DeviceConfig::DEFAULT);
    let (r, pen, said) = run(pen);
    assert!(r.passed(), "{}", r.table());
    assert_eq!(r.outcome("2 sensors"), Some(Outcome::Pass));
    let sensors = &r.steps[1].detail;
    // The fake samples the poses at 50 Hz, the wizard streams them at 200 Hz: the peak
    // (150 counts, 261 codes) may fall between two samples.
    for ch in [
        "base (yaw)",
        "shoulder",
        "elbow",
        "gimbal 1",
        "gimbal 2",
        "gimbal 3",
    ] {
        assert!(sensors.contains(&format!("{ch}: PASS +")), "{sensors}");
    }
    for ch in [
        "3 motor 0 (base (yaw))",
        "3 motor 1 (shoulder)",
        "3 motor 2 (elbow)",
    ] {
        assert_eq!(r.outcome(ch), Some(Outcome::Skip), "{}", r.table());
    }
    assert_eq!(r.outcome("4 calibration"), Some(Outcome::Skip));
    assert!(said.iter().any(|l| l.contains("virtual pen")));
    // The whole motion, then the last pose held while the nudges ran.
    let motion = maobi::device::bringup::virtual_motion(Pose::new(
        Vec3::new(0.0, 0.0, 30.0),
        Quat::IDENTITY,
    ));
    assert!(pen.poses_received > motion.len(), "{}", pen.poses_received);
}

#[test]
fn the_command_line_exits_non_zero_when_a_step_fails() {
    let ok = serve(Pen::physical(Some(DeviceConfig::DEFAULT), [1, 1, 1])).0;
    let bad = serve(Pen::physical(Some(DeviceConfig::DEFAULT), [0, 1, 1])).0;
    let run = |addr: &str| {
        std::process::Command::new(env!("CARGO_BIN_EXE_maobi"))
            .args(["device", "check", "--yes", "--sensor-seconds", "3"])
            .args(["--connect", addr])
            .output()
            .unwrap()
    };
    let out = run(&ok);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}");
    assert!(text.contains("4 calibration") && text.contains("All steps passed"));
    let out = run(&bad);
    assert!(!out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("FAIL"), "{text}");
}

#[test]
fn a_missing_configuration_is_written_from_the_builders_file() {
    let file = std::env::temp_dir().join(format!("maobi-check-{}-pen.toml", std::process::id()));
    let mut mine = DeviceConfig::DEFAULT;
    mine.pen.upper_arm_mm = 150.0;
    mine.drive[1].deadband = 0.08;
    std::fs::write(
        &file,
        maobi::device::config_file::to_toml(&mine, "a builder's pen"),
    )
    .unwrap();
    let (addr, pen) = serve(Pen::physical(None, [1, 1, 1]));
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_maobi"))
        .args(["device", "check", "--yes", "--sensor-seconds", "3"])
        .args(["--connect", &addr, "--config", file.to_str().unwrap()])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}");
    assert!(
        text.contains("the configuration given with --config was written"),
        "{text}"
    );
    let stored = pen.lock().unwrap().config.unwrap();
    // The builder's values, then the calibration step's readings.
    assert_eq!(stored.pen.upper_arm_mm, 150.0);
    assert_eq!(stored.drive[1].deadband, 0.08);
    assert!(stored.calibration.is_some());
    // A file that does not validate stops the check before it connects.
    std::fs::write(&file, "[pen]\nupper_arm_mm = -1\n").unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_maobi"))
        .args(["device", "check", "--yes", "--connect", &addr])
        .args(["--config", file.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("missing field"), "{err}");
    let _ = std::fs::remove_file(&file);
}

/// `maobi sim-device` (in process, the same server) is a virtual pen that keeps no
/// configuration and answers no bring-up command: the check skips what it does not offer,
/// says why, and passes.
#[test]
fn the_simulator_passes_with_the_steps_it_does_not_offer_skipped() {
    let server = SimDeviceServer::spawn("127.0.0.1:0", SimDeviceOptions::default()).unwrap();
    let addr = server.addr().to_string();
    let mut op = Scripted::default();
    let r = run_check(&opts(&addr), &mut op);
    let said = op.transcript.join("\n");
    println!("{said}\n{}", r.table());
    assert_eq!(
        r.outcome("1 handshake"),
        Some(Outcome::Pass),
        "{}",
        r.table()
    );
    for step in [
        "2 sensors",
        "3 motor 0 (base (yaw))",
        "3 motor 1 (shoulder)",
        "3 motor 2 (elbow)",
        "4 calibration",
    ] {
        assert_eq!(
            r.outcome(step),
            Some(Outcome::Skip),
            "{step}\n{}",
            r.table()
        );
    }
    assert!(r.passed(), "{}", r.table());
    for line in [
        "2 sensors: skipped: the device streams no raw sensor readings (capabilities \
         FORCE_OUTPUT | VIRTUAL_PEN: no STORED_CONFIG",
        "3 motors: skipped: the device takes no motor nudge (capabilities",
        "4 calibration: skipped: this device keeps no configuration (a virtual pen needs no \
         calibration",
    ] {
        assert!(said.contains(line), "{line}\n{said}");
    }
    // The command line: exit 0, the skips said, no FAIL.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_maobi"))
        .args(["device", "check", "--yes", "--connect", &addr])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}");
    assert!(!text.contains("FAIL"), "{text}");
    assert!(text.contains("2 sensors: skipped: "), "{text}");
    assert!(text.contains("No step failed; 5 skipped"), "{text}");
}
