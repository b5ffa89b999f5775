//! The device wire protocol: every message round-trips, a state frame rebuilds the device's
//! footprint bit for bit, frame sizes, and the decoder against garbage (SPEC scenario 6:
//! garbage, truncated and oversized frames are counted and dropped, never a panic, never a
//! stuck loop).

use maobi_shared::footprint::Geometry;
use maobi_shared::params::{BrushParams, ParamId, TickLimits, MAX_LAYERS};
use maobi_shared::protocol::*;
use maobi_shared::{presets, Brush, Fx, Pose, Quat, Scalar, Vec2, Vec3};
use proptest::prelude::*;

fn pose(x: f64, y: f64, z: f64, tilt_deg: f64) -> Pose<Fx> {
    let h = tilt_deg.to_radians() / 2.0;
    Pose::new(
        Vec3::from_f64([x, y, z]),
        Quat::from_f64([h.cos(), 0.0, h.sin(), 0.0]),
    )
}

fn frame<M: Message>(msg: &M) -> Vec<u8> {
    let mut out = vec![0u8; M::MAX_FRAME];
    let n = msg.encode(&mut out).expect("encodes");
    out.truncate(n);
    out
}

fn raw_frame(content: &[u8]) -> Vec<u8> {
    let mut out = vec![0u8; max_frame_len(content.len() + CRC_LEN)];
    let n = encode_raw(content, content.len() + CRC_LEN, &mut out).expect("encodes");
    out.truncate(n);
    out
}

fn decode<M: Message, const N: usize>(
    dec: &mut FrameDecoder<M, N>,
    bytes: &[u8],
) -> Vec<Result<M, ProtocolError>> {
    dec.feed(bytes).collect()
}

/// A brush pressed at 20 degrees until its rest tip would be 10 mm into the paper, then
/// dragged 4 mm, so layers lie on the paper, bend and spread.
fn pressed_brush(params: maobi_shared::BrushParams) -> Brush<Fx> {
    let tilt = 20.0f64;
    let reach = params.length_mm as f64 * tilt.to_radians().cos();
    let mut b = Brush::new(params, pose(0.0, 0.0, reach + 5.0, tilt)).unwrap();
    for k in 1..=200 {
        let z = reach + 5.0 - 15.0 * k as f64 / 200.0;
        b.tick(pose(0.0, 0.0, z, tilt));
    }
    for k in 1..=100 {
        b.tick(pose(4.0 * k as f64 / 100.0, 0.0, reach - 10.0, tilt));
    }
    // Masses within a few micrometres of the paper: whether each counts as touching
    // (`contacts`, a tolerance of micrometres) changes with the ties' stiffness, which the
    // ink sets, as the drag ends.
    let on_paper = b.spine().iter().filter(|s| s.z.to_f64() < 0.02).count();
    assert!(on_paper >= 3, "the press must put hair on the paper");
    b
}

/// Motor commands with every fraction bit in use, as the force loop's would be.
fn motors() -> [Fx; 3] {
    [0.1234567, -0.7654321, 0.0421].map(Fx::from_f64)
}

/// A force loop's output while writing: about 0.8 N up, some drag.
fn haptics() -> Haptics {
    Haptics::new(Vec3::from_f64([0.0512, -0.0233, 0.7911]), motors(), true)
}

fn polygons(g: &Geometry<'_, Fx>) -> Vec<(usize, Vec<Vec2<Fx>>)> {
    let mut out = Vec::new();
    g.for_each_polygon(|band, poly| out.push((band, poly.to_vec())));
    out
}

fn host_samples() -> Vec<HostMsg> {
    let p = pose(12.5, -3.25, 30.0, 17.0);
    let mut v = vec![
        HostMsg::Hello(HostHello::new(
            "maobi-gui",
            Version {
                major: 0,
                minor: 1,
                patch: 2,
            },
        )),
        HostMsg::Ping { seq: 7 },
        HostMsg::Ping { seq: u32::MAX },
        HostMsg::Pose(PoseSample::new(123_456, p, Buttons::PRIMARY)),
        HostMsg::Pose(PoseSample::new(0, Pose::default(), Buttons::empty())),
        HostMsg::GetParam {
            id: ParamId::TieStiffness as u8,
        },
        HostMsg::SetParam {
            id: ParamId::Wetness as u8,
            value: 0.25,
        },
        HostMsg::Guide(GuideSample::new(
            123_456,
            Vec3::from_f64([12.0, -3.5, 0.25]),
            true,
        )),
        HostMsg::Guide(GuideSample::new(u32::MAX, Vec3::ZERO, false)),
        HostMsg::GetConfig,
        HostMsg::SetConfig(calibrated_config()),
    ];
    v.extend(commands().into_iter().map(HostMsg::Command));
    v
}

fn commands() -> Vec<Command> {
    vec![
        Command::EnableForces,
        Command::DisableForces,
        Command::Calibrate,
        Command::DipInk {
            wetness: Fx::from_f64(0.8).to_bits(),
        },
        Command::ChoosePreset(PresetRef::Index(1)),
        Command::ChoosePreset(PresetRef::Name(bounded_str("大楷"))),
        Command::ClearFaults,
        Command::ResetBrush,
        Command::InjectOverrun,
        Command::StreamSensors { rate_hz: 50 },
        Command::NudgeMotor(Nudge {
            channel: 2,
            command_permille: -120,
            duration_ms: 250,
        }),
    ]
}

/// A configuration with every varint at its longest: the longest `SetConfig` / `Config`.
fn longest_config() -> DeviceConfig {
    let mut c = DeviceConfig::DEFAULT;
    c.pen.counts_per_rev = [u32::MAX; 3];
    for d in &mut c.drive {
        d.pwm_hz = u32::MAX;
        d.winding_mohm = u16::MAX;
    }
    c.calibration = Some(maobi_shared::kinematics::RawReadings {
        encoders: [i64::MIN; 3],
        gimbal: [i32::MIN; 3],
    });
    c
}

fn calibrated_config() -> DeviceConfig {
    let mut c = DeviceConfig::DEFAULT;
    c.calibration = Some(maobi_shared::kinematics::RawReadings {
        encoders: [120, -40_000, 7],
        gimbal: [2048, 1999, 2100],
    });
    c
}

fn device_samples() -> Vec<DeviceMsg> {
    let brush = Brush::new(presets::SMALL, pose(1.0, 2.0, 40.0, 10.0)).unwrap();
    let state = BrushState::from_brush(
        &brush,
        42,
        40,
        Haptics::new(Vec3::from_f64([0.1, -0.2, 0.9]), motors(), true),
        Faults::empty(),
    );
    let mut params = presets::LARGE;
    let ring = params.set(ParamId::RingNodes, 5.0);
    let tip = presets::SMALL.clone().set(ParamId::TipRadiusMm, 3.0);
    let range = params.set(ParamId::Belly, 9.0);
    let whole = params.set(ParamId::Layers, 7.5);
    let nan = params.set(ParamId::MassG, f32::NAN);
    let over = TickLimits {
        layers: 12,
        ..TickLimits::NONE
    }
    .check(&BrushParams {
        layers: 16,
        ..presets::LARGE
    });
    let wetness = ParamId::Wetness as u8;
    let mut v = vec![
        DeviceMsg::Hello(DeviceInfo::new(
            "qemu-mps2-an386",
            Version {
                major: 1,
                minor: 0,
                patch: 0,
            },
            Capabilities::VIRTUAL_PEN | Capabilities::FORCE_OUTPUT,
            3.3,
            0.88,
        )),
        DeviceMsg::Hello(
            DeviceInfo::new(
                "stm32f411-blackpill",
                Version::default(),
                Capabilities::REAL_SENSORS | Capabilities::STORED_CONFIG,
                3.3,
                0.88,
            )
            .with_config(ConfigState::Corrupt(ConfigError::CrcMismatch {
                stored: 1,
                computed: 2,
            }))
            .with_limits(TickLimits {
                substeps_per_tick: 1,
                layers: 12,
                ring_nodes: 16,
                jacobi_iterations: 4,
            }),
        ),
        DeviceMsg::Pong { seq: 7 },
        DeviceMsg::State(state),
        DeviceMsg::Param(ParamReply::read(&params, wetness)),
        DeviceMsg::Param(ParamReply::read(&params, 200)),
        DeviceMsg::Param(ParamReply::written(wetness, Ok(()), &params)),
    ];
    for outcome in [ring, tip, range, whole, nan, over] {
        v.push(DeviceMsg::Param(ParamReply::written(1, outcome, &params)));
    }
    let results = [
        Ok(()),
        Err(CommandError::Unsupported),
        Err(CommandError::UnknownPreset),
        Err(CommandError::FaultsLatched(
            Faults::NOT_CALIBRATED | Faults::LINK_SILENT,
        )),
        Err(CommandError::ConfigNotValid),
        Err(CommandError::ForcesEnabled),
        Err(CommandError::OutOfRange),
        Err(CommandError::StoreFailed),
        Err(CommandError::OverTickLimit {
            param: ParamId::SubstepsPerTick as u8,
            value: 2,
            max: 1,
        }),
    ];
    for (command, result) in commands().into_iter().zip(results.into_iter().cycle()) {
        v.push(DeviceMsg::CommandDone { command, result });
    }
    for kind in [
        EventKind::FaultRaised(Faults::SENSOR_JUMP | Faults::WATCHDOG),
        EventKind::FaultCleared(Faults::LOOP_OVERRUN),
        EventKind::ForcesEnabled,
        EventKind::ForcesDisabled,
        EventKind::LinkConnected,
        EventKind::LinkReconnected { silent_ms: 250 },
    ] {
        v.push(DeviceMsg::Event(Event {
            tick: 99,
            kind,
            faults: Faults::PARAM_REJECTED,
        }));
    }
    let invalid = {
        let mut c = DeviceConfig::DEFAULT;
        c.drive[1].deadband = 0.9;
        match c.validate() {
            Err(e) => e,
            Ok(()) => panic!("a deadband of 0.9 must be invalid"),
        }
    };
    assert_eq!(invalid.field.as_str(), "drive[1].deadband");
    for reply in [
        Ok(calibrated_config()),
        Err(ConfigRejected::NotStored(ConfigState::Missing)),
        Err(ConfigRejected::Invalid(invalid)),
        Err(ConfigRejected::ForcesEnabled),
        Err(ConfigRejected::StoreFailed),
    ] {
        v.push(DeviceMsg::Config(reply));
    }
    v.push(DeviceMsg::Sensors(SensorReport {
        tick: 12,
        encoders: [-5, 70_000, i64::MIN],
        gimbal: [0, 2048, 4095],
        buttons: Buttons::PRIMARY,
        synthetic: true,
    }));
    v.push(DeviceMsg::Telemetry(Telemetry {
        tick: 1_000_000,
        tick_period_min_us: 990,
        tick_period_mean_us: 1000,
        tick_period_max_us: 1042,
        load_percent: 37,
        frames_dropped: 3,
        pose_gaps: 8,
        rx: LinkStats {
            frames_ok: 5,
            framing_errors: 1,
            crc_errors: 2,
            oversized_frames: 3,
            decode_errors: 4,
            version_errors: 6,
        },
        tick_busy_max_us: 812,
        tick_busy_max_cycles: 77_952,
        overruns: 2,
        brush_ticks: 999_000,
    }));
    v
}

/// Which variant, by an exhaustive match: a new variant fails to compile here until the
/// samples cover it.
fn host_kind(m: &HostMsg) -> &'static str {
    match m {
        HostMsg::Hello(_) => "hello",
        HostMsg::Ping { .. } => "ping",
        HostMsg::Pose(_) => "pose",
        HostMsg::GetParam { .. } => "get",
        HostMsg::SetParam { .. } => "set",
        HostMsg::Command(c) => match c {
            Command::EnableForces => "enable",
            Command::DisableForces => "disable",
            Command::Calibrate => "calibrate",
            Command::DipInk { .. } => "dip",
            Command::ChoosePreset(PresetRef::Index(_)) => "preset index",
            Command::ChoosePreset(PresetRef::Name(_)) => "preset name",
            Command::ClearFaults => "clear",
            Command::ResetBrush => "reset",
            Command::InjectOverrun => "inject overrun",
            Command::StreamSensors { .. } => "stream sensors",
            Command::NudgeMotor(_) => "nudge",
        },
        HostMsg::Guide(_) => "guide",
        HostMsg::GetConfig => "get config",
        HostMsg::SetConfig(_) => "set config",
    }
}

fn device_kind(m: &DeviceMsg) -> &'static str {
    match m {
        DeviceMsg::Hello(_) => "hello",
        DeviceMsg::Pong { .. } => "pong",
        DeviceMsg::State(_) => "state",
        DeviceMsg::Param(r) => match &r.result {
            Ok(_) => "param ok",
            Err(e) => match e.reason {
                RejectReason::UnknownParam => "unknown",
                RejectReason::NotFinite => "not finite",
                RejectReason::OutOfRange { .. } => "range",
                RejectReason::NotWholeNumber { .. } => "whole",
                RejectReason::Inconsistent { .. } => "inconsistent",
                RejectReason::RingNodesNotPowerOfTwo { .. } => "ring",
                RejectReason::OverTickLimit { .. } => "over tick limit",
            },
        },
        DeviceMsg::CommandDone { result, .. } => match result {
            Ok(()) => "done",
            Err(CommandError::Unsupported) => "unsupported",
            Err(CommandError::UnknownPreset) => "no preset",
            Err(CommandError::FaultsLatched(_)) => "latched",
            Err(CommandError::ConfigNotValid) => "config not valid",
            Err(CommandError::ForcesEnabled) => "forces enabled",
            Err(CommandError::OutOfRange) => "out of range",
            Err(CommandError::StoreFailed) => "store failed",
            Err(CommandError::OverTickLimit { .. }) => "preset over tick limit",
        },
        DeviceMsg::Event(e) => match e.kind {
            EventKind::FaultRaised(_) => "raised",
            EventKind::FaultCleared(_) => "cleared",
            EventKind::ForcesEnabled => "on",
            EventKind::ForcesDisabled => "off",
            EventKind::LinkConnected => "connected",
            EventKind::LinkReconnected { .. } => "reconnected",
        },
        DeviceMsg::Telemetry(_) => "telemetry",
        DeviceMsg::Config(r) => match r {
            Ok(_) => "config",
            Err(ConfigRejected::NotStored(_)) => "config not stored",
            Err(ConfigRejected::Invalid(_)) => "config invalid",
            Err(ConfigRejected::ForcesEnabled) => "config forces on",
            Err(ConfigRejected::StoreFailed) => "config store failed",
        },
        DeviceMsg::Sensors(_) => "sensors",
    }
}

#[test]
fn every_message_round_trips() {
    let hosts = host_samples();
    let kinds: std::collections::BTreeSet<_> = hosts.iter().map(host_kind).collect();
    assert_eq!(kinds.len(), 19, "host samples cover {kinds:?}");
    let mut rx = DeviceRx::new();
    let mut stream = Vec::new();
    for m in &hosts {
        let f = frame(m);
        assert!(f.len() <= HostMsg::MAX_FRAME);
        assert_eq!(f.iter().position(|&b| b == 0), Some(f.len() - 1));
        assert_eq!(decode(&mut rx, &f), vec![Ok(m.clone())]);
        stream.extend(f);
    }
    // All at once, too.
    let all: Vec<_> = decode(&mut rx, &stream);
    assert_eq!(all, hosts.iter().cloned().map(Ok).collect::<Vec<_>>());
    assert_eq!(rx.stats().frames_ok as usize, 2 * hosts.len());
    assert_eq!(rx.stats().dropped(), 0);

    let devices = device_samples();
    let kinds: std::collections::BTreeSet<_> = devices.iter().map(device_kind).collect();
    assert_eq!(kinds.len(), 33, "device samples cover {kinds:?}");
    let mut rx = HostRx::new();
    for m in &devices {
        assert_eq!(decode(&mut rx, &frame(m)), vec![Ok(m.clone())]);
    }
    assert_eq!(rx.stats().dropped(), 0);
}

#[test]
fn pose_samples_are_exactly_the_host_pose() {
    let p = pose(123.456, -7.5, 0.001, 33.0);
    let m = HostMsg::Pose(PoseSample::new(5, p, Buttons::SECONDARY));
    let mut rx = DeviceRx::new();
    match decode(&mut rx, &frame(&m)).pop() {
        Some(Ok(HostMsg::Pose(s))) => {
            assert_eq!(s.pose(), p);
            assert_eq!(s.seq, 5);
            assert_eq!(s.buttons, Buttons::SECONDARY);
        }
        other => panic!("expected a pose sample, got {other:?}"),
    }
}

#[test]
fn parameter_errors_keep_the_parameter_and_the_reason() {
    let mut params = presets::LARGE;
    let err = params.set(ParamId::TipRadiusMm, 7.0).unwrap_err();
    let reply = ParamReply::written(ParamId::TipRadiusMm as u8, Err(err), &params);
    let rejected = reply.result.clone().unwrap_err();
    assert_eq!(rejected.param, ParamId::TipRadiusMm as u8);
    assert!(matches!(rejected.reason, RejectReason::OutOfRange { value, .. } if value == 7.0));
    assert_eq!(rejected.to_string(), err.to_string());

    // Valid alone, not with the small brush's 2.5 mm root.
    let err = presets::SMALL
        .clone()
        .set(ParamId::TipRadiusMm, 3.0)
        .unwrap_err();
    assert!(matches!(err, maobi_shared::ParamError::Inconsistent { .. }));
    let rejected = ParamRejected::from(err);
    assert_eq!(param_id(rejected.param), Some(ParamId::TipRadiusMm));
    assert_eq!(rejected.to_string(), err.to_string());

    let ok = ParamReply::read(&params, ParamId::LengthMm as u8);
    assert_eq!(ok.result, Ok(40.0));
    for id in ParamId::ALL {
        assert_eq!(param_id(id as u8), Some(id));
    }
    assert_eq!(param_id(ParamId::ALL.len() as u8), None);
    assert_eq!(
        ParamReply::read(&params, 77)
            .result
            .unwrap_err()
            .to_string(),
        "parameter #77: no such parameter"
    );
}

#[test]
fn presets_resolve_by_index_and_name() {
    assert_eq!(PresetRef::Index(0).resolve(), Some(presets::LARGE));
    assert_eq!(PresetRef::Index(1).resolve(), Some(presets::SMALL));
    assert_eq!(PresetRef::Index(2).resolve(), Some(presets::WOLF));
    assert_eq!(PresetRef::Index(3).resolve(), Some(presets::GOAT));
    assert_eq!(PresetRef::Index(4).resolve(), Some(presets::MIXED));
    assert_eq!(PresetRef::Index(5).resolve(), None);
    assert_eq!(
        PresetRef::Name(bounded_str("小楷")).resolve(),
        Some(presets::SMALL)
    );
    assert_eq!(
        PresetRef::Name(bounded_str("羊毫")).resolve(),
        Some(presets::GOAT)
    );
    assert_eq!(PresetRef::Name(bounded_str("huge")).resolve(), None);
    // Names are cut on a character boundary.
    let cut: heapless::String<4> = bounded_str("大楷");
    assert_eq!(cut.as_str(), "大");
}

/// The device fills its state slot in place and encodes the state where it lies: the same
/// state and the same bytes as building the owned message.
#[test]
fn borrowed_state_encodes_as_the_message() {
    let brush = pressed_brush(presets::LARGE);
    let haptics = Haptics::new(Vec3::from_f64([0.01, 0.0, 0.6]), motors(), true);
    let state = BrushState::from_brush(&brush, 300, 250, haptics, Faults::SENSOR_JUMP);
    // Over a stale state with more layers than this brush has, as the slot may hold.
    let mut slot = BrushState::from_brush(
        &Brush::<Fx>::new(
            BrushParams {
                layers: MAX_LAYERS as u8,
                ..presets::LARGE
            },
            pose(1.0, 2.0, 40.0, 10.0),
        )
        .unwrap(),
        9,
        9,
        Haptics::default(),
        Faults::all(),
    );
    assert!(slot.layers.len() > state.layers.len());
    slot.fill_from_brush(&brush, 300, 250, haptics, Faults::SENSOR_JUMP);
    assert_eq!(slot, state);
    let mut out = vec![0u8; DeviceMsg::MAX_FRAME];
    let n = DeviceMsg::encode_state(&state, &mut out).unwrap();
    assert_eq!(out[..n], frame(&DeviceMsg::State(state.clone()))[..]);
    // Empty and too small a buffer behave as the owned message's encoding does.
    let n = DeviceMsg::encode_state(&BrushState::EMPTY, &mut out).unwrap();
    assert_eq!(out[..n], frame(&DeviceMsg::State(BrushState::EMPTY))[..]);
    assert!(DeviceMsg::encode_state(&state, &mut out[..64]).is_err());
}

#[test]
fn brush_state_rebuilds_the_footprint_bit_for_bit() {
    let brush = pressed_brush(presets::LARGE);
    let haptics = Haptics::new(Vec3::from_f64([0.01, 0.0, 0.6]), motors(), true);
    let state = BrushState::from_brush(&brush, 300, 250, haptics, Faults::empty());
    let mut rx = HostRx::new();
    let got = match decode(&mut rx, &frame(&DeviceMsg::State(state.clone()))).pop() {
        Some(Ok(DeviceMsg::State(s))) => s,
        other => panic!("expected a state, got {other:?}"),
    };
    assert_eq!(got, state);
    assert_eq!(got.haptics.force(), haptics.force());
    assert_eq!(got.haptics.motors(), motors());
    assert_eq!(got.pose_seq, 250);
    let shape = got.shape();
    assert_eq!(shape.handle(), brush.handle());
    assert_eq!(shape.spine(), brush.spine());
    assert_eq!(shape.skeleton(), brush.skeleton());
    assert_eq!(shape.layers(), brush.layers());
    for (i, &c) in brush.in_contact().iter().enumerate() {
        assert_eq!(got.in_contact(i), c, "layer {i}");
    }
    assert!(!got.in_contact(MAX_LAYERS) && !got.in_contact(usize::MAX));

    let live = polygons(&Geometry::of(&brush));
    let rebuilt = polygons(&shape.geometry());
    assert!(live.len() >= 3, "the pressed brush leaves ink");
    assert_eq!(rebuilt, live, "polygons differ");
}

#[test]
fn state_frame_size_and_link_share() {
    const LINK_BYTES_PER_S: f64 = 1.0e6; // USB full-speed CDC, in practice
    const STATE_HZ: f64 = 120.0;
    let mut large = 0;
    for (name, params) in presets::PRESETS {
        for (how, brush) in [
            (
                "at rest",
                Brush::new(*params, pose(150.0, 120.0, 60.0, 20.0)).unwrap(),
            ),
            ("pressed", pressed_brush(*params)),
        ] {
            let state =
                BrushState::from_brush(&brush, 123_456, 100_000, haptics(), Faults::empty());
            let n = frame(&DeviceMsg::State(state)).len();
            let share = n as f64 * STATE_HZ / LINK_BYTES_PER_S;
            println!(
                "{name} brush ({} layers) {how}: state frame {n} bytes, {:.0} B/layer; \
                 {:.1} kB/s = {:.1}% of a 1 MB/s link at 120 Hz",
                brush.len(),
                n as f64 / brush.len() as f64,
                n as f64 * STATE_HZ / 1e3,
                100.0 * share
            );
            if name == "large" {
                large = large.max(n);
            }
        }
    }
    // Under a kilobyte, an eighth of the link (the sizes themselves: docs/figures.md).
    assert!(large < 1024, "large state frame {large} bytes");
    assert!(large as f64 * STATE_HZ / LINK_BYTES_PER_S < 0.125);
    let p = HostMsg::Pose(PoseSample::new(
        1_000_000,
        pose(150.0, 120.0, 30.0, 20.0),
        Buttons::empty(),
    ));
    let n = frame(&p).len();
    println!(
        "pose sample: {n} bytes, {:.1}% of the link at 1 kHz",
        n as f64 * 1e3 / LINK_BYTES_PER_S * 100.0
    );
    assert!(n < 64);
    let g = HostMsg::Guide(GuideSample::new(
        1_000_000,
        Vec3::from_f64([150.0, 120.0, 30.0]),
        true,
    ));
    let n = frame(&g).len();
    println!(
        "guide sample: {n} bytes, {:.1}% of the link at 1 kHz",
        n as f64 * 1e3 / LINK_BYTES_PER_S * 100.0
    );
    assert!(n < 32);
}

/// The largest message of each direction, with every value at its longest varint, fits the
/// bound its receiver enforces: no reachable state can fail to encode.
#[test]
fn largest_messages_fit_their_bounds() {
    let worst_layer = LayerState {
        spine: [i64::MIN; 3],
        skeleton: [i64::MIN; 3],
        short_axis: [i64::MIN; 3],
        long_axis: [i64::MIN; 3],
        long_radius: i64::MIN,
        short_radius: i64::MIN,
        wetness: i64::MIN,
        deposited: i64::MIN,
    };
    let worst_pose = PoseBits {
        pos: [i64::MIN; 3],
        rot: [i64::MIN; 4],
    };
    let state = BrushState {
        tick: u32::MAX,
        pose_seq: u32::MAX,
        spine_index: u8::MAX,
        spine_count: u8::MAX,
        handle: worst_pose,
        haptics: Haptics {
            force_n: [i64::MIN; 3],
            motors: [i64::MIN; 3],
            enabled: true,
        },
        faults: Faults::from_bits_retain(u16::MAX),
        contacts: u32::MAX,
        ring_nodes: u8::MAX,
        footprint_eps: i64::MIN,
        layers: heapless::Vec::from_slice(&[worst_layer; MAX_LAYERS]).unwrap(),
    };
    let n = frame(&DeviceMsg::State(state)).len();
    println!(
        "worst-case state frame ({MAX_LAYERS} layers): {n} bytes of {}",
        DeviceMsg::MAX_FRAME
    );
    assert!(n <= DeviceMsg::MAX_FRAME);

    let long_name = "x".repeat(NAME_LEN);
    let worst_host = [
        HostMsg::Guide(GuideSample {
            seq: u32::MAX,
            anchor: [i64::MIN; 3],
            on: true,
        }),
        HostMsg::Pose(PoseSample {
            seq: u32::MAX,
            pose: worst_pose,
            buttons: Buttons::from_bits_retain(u8::MAX),
        }),
        HostMsg::Hello(HostHello::new(
            &long_name,
            Version {
                major: u16::MAX,
                minor: u16::MAX,
                patch: u16::MAX,
            },
        )),
        HostMsg::Command(Command::ChoosePreset(PresetRef::Name(bounded_str(
            &long_name,
        )))),
        HostMsg::SetParam {
            id: u8::MAX,
            value: f32::MAX,
        },
        HostMsg::SetConfig(longest_config()),
        HostMsg::Command(Command::NudgeMotor(Nudge {
            channel: u8::MAX,
            command_permille: i16::MIN,
            duration_ms: u16::MAX,
        })),
    ];
    let n = worst_host.iter().map(|m| frame(m).len()).max().unwrap();
    println!("worst-case host frame: {n} bytes of {}", HostMsg::MAX_FRAME);
    assert!(n <= HostMsg::MAX_FRAME);
    // The decoded SetConfig: header 2, tag 1, the longest config image payload, CRC 4.
    let mut buf = vec![0u8; HostMsg::MAX_FRAME];
    let set = HostMsg::SetConfig(longest_config());
    let payload = postcard::to_slice(&set, &mut buf).unwrap().len();
    assert_eq!(payload, 1 + maobi_shared::pen_io::CONFIG_PAYLOAD_MAX);
    assert_eq!(2 + payload + CRC_LEN, 284);
    assert!(2 + payload + CRC_LEN <= HOST_MSG_MAX);
    // The device's longest config reply and sensor report fit too.
    for m in [
        DeviceMsg::Config(Ok(longest_config())),
        DeviceMsg::Sensors(SensorReport {
            tick: u32::MAX,
            encoders: [i64::MIN; 3],
            gimbal: [u16::MAX; 3],
            buttons: Buttons::from_bits_retain(u8::MAX),
            synthetic: true,
        }),
    ] {
        assert!(frame(&m).len() <= DeviceMsg::MAX_FRAME);
    }
}

#[test]
fn encoding_never_overruns_its_buffer() {
    let m = DeviceMsg::State(BrushState::from_brush(
        &pressed_brush(presets::SMALL),
        1,
        1,
        haptics(),
        Faults::empty(),
    ));
    let full = frame(&m);
    let mut out = vec![0u8; full.len()];
    for len in 0..full.len() {
        assert_eq!(
            m.encode(&mut out[..len]),
            Err(ProtocolError::BufferTooSmall),
            "{len}"
        );
    }
    assert_eq!(m.encode(&mut out), Ok(full.len()));
    assert_eq!(out, full);
    // A message beyond the receiver's bound is refused, whatever the buffer.
    let mut big = vec![0u8; 2 * HOST_MSG_MAX];
    let content = vec![7u8; HOST_MSG_MAX];
    assert_eq!(
        encode_raw(&content, HOST_MSG_MAX, &mut big),
        Err(ProtocolError::Oversized)
    );
}

#[test]
fn version_mismatch_is_a_typed_error_on_both_ends() {
    // A frame of another version: the decoder says so, whichever end reads it.
    let mut dev = DeviceRx::new();
    let ping_next = raw_frame(&[PROTOCOL_VERSION + 1, HOST_TO_DEVICE, 1, 5]);
    let mismatch = ProtocolError::VersionMismatch {
        ours: PROTOCOL_VERSION,
        theirs: PROTOCOL_VERSION + 1,
    };
    assert_eq!(decode(&mut dev, &ping_next), vec![Err(mismatch)]);
    assert_eq!(dev.stats().version_errors, 1);
    let mut host = HostRx::new();
    let pong_v0 = raw_frame(&[0, DEVICE_TO_HOST, 1, 5]);
    assert_eq!(
        decode(&mut host, &pong_v0),
        vec![Err(ProtocolError::VersionMismatch {
            ours: PROTOCOL_VERSION,
            theirs: 0
        })]
    );
    assert_eq!(host.stats().version_errors, 1);
    // The same content at our version is a good frame: only the version byte was wrong.
    let ping = raw_frame(&[PROTOCOL_VERSION, HOST_TO_DEVICE, 1, 5]);
    assert_eq!(decode(&mut dev, &ping), vec![Ok(HostMsg::Ping { seq: 5 })]);

    // The handshakes say so too.
    let mut hello = HostHello::new("gui", Version::default());
    assert_eq!(hello.check(), Ok(()));
    hello.protocol_version = PROTOCOL_VERSION + 1;
    assert_eq!(hello.check(), Err(mismatch));
    let mut info = DeviceInfo::new("pen", Version::default(), Capabilities::empty(), 3.3, 0.88);
    assert_eq!(info.check(), Ok(()));
    info.protocol_version = PROTOCOL_VERSION + 1;
    assert_eq!(info.check(), Err(mismatch));
    let text = mismatch.to_string();
    let theirs = (PROTOCOL_VERSION + 1).to_string();
    assert!(text.contains("version") && text.contains(&theirs), "{text}");
}

#[test]
fn echoed_and_malformed_messages_are_decode_errors() {
    // Our own frame coming back (an echoing link): named, counted, not obeyed.
    let mut host = HostRx::new();
    let echo = frame(&HostMsg::Ping { seq: 3 });
    assert_eq!(
        decode(&mut host, &echo),
        vec![Err(ProtocolError::WrongDirection)]
    );
    let mut dev = DeviceRx::new();
    let cases = [
        vec![PROTOCOL_VERSION, HOST_TO_DEVICE, 1, 5, 0x55], // bytes left over
        vec![PROTOCOL_VERSION, HOST_TO_DEVICE, 99],         // no such variant
        vec![PROTOCOL_VERSION, HOST_TO_DEVICE, 1],          // message cut short
        vec![PROTOCOL_VERSION, HOST_TO_DEVICE],             // no message at all
    ];
    for c in &cases {
        assert_eq!(
            decode(&mut dev, &raw_frame(c)),
            vec![Err(ProtocolError::Decode)]
        );
    }
    assert_eq!(dev.stats().decode_errors, cases.len() as u32);
    assert_eq!(host.stats().decode_errors, 1);
    // Too short to hold a header and a CRC; empty frames are ignored.
    assert_eq!(
        decode(&mut dev, &[0x03, 0x11, 0x22, 0x00]),
        vec![Err(ProtocolError::Framing)]
    );
    assert_eq!(decode(&mut dev, &[0, 0, 0]), vec![]);
    assert_eq!(dev.stats().framing_errors, 1);
}

/// A few valid host frames to mix into garbage.
fn valid_host_msg() -> impl Strategy<Value = HostMsg> {
    prop_oneof![
        any::<u32>().prop_map(|seq| HostMsg::Ping { seq }),
        (
            any::<u32>(),
            any::<[i64; 3]>(),
            any::<[i64; 4]>(),
            any::<u8>()
        )
            .prop_map(|(seq, pos, rot, b)| HostMsg::Pose(PoseSample {
                seq,
                pose: PoseBits { pos, rot },
                buttons: Buttons::from_bits_retain(b),
            })),
        (any::<u8>(), -1e6f32..1e6).prop_map(|(id, value)| HostMsg::SetParam { id, value }),
        (any::<u32>(), any::<[i64; 3]>(), any::<bool>())
            .prop_map(|(seq, anchor, on)| { HostMsg::Guide(GuideSample { seq, anchor, on }) }),
        Just(HostMsg::Command(Command::EnableForces)),
    ]
}

/// Errors that damage on the link (not a wrong peer) may produce.
fn is_damage(e: &ProtocolError) -> bool {
    matches!(e, ProtocolError::Framing | ProtocolError::Crc)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, .. ProptestConfig::default() })]

    /// Any bytes: no panic, every reported error counted once, and after the next delimiter a
    /// valid frame comes through.
    #[test]
    fn garbage_is_counted_and_the_decoder_resynchronises(
        garbage in proptest::collection::vec(any::<u8>(), 0..1200),
        msg in valid_host_msg(),
    ) {
        let mut rx = DeviceRx::new();
        let out = decode(&mut rx, &garbage);
        let errors = out.iter().filter(|r| r.is_err()).count();
        let s = rx.stats();
        prop_assert_eq!(s.dropped() as usize, errors);
        prop_assert_eq!(s.frames_ok as usize, out.len() - errors);
        let mut tail = vec![DELIMITER];
        tail.extend(frame(&msg));
        let out = decode(&mut rx, &tail);
        prop_assert_eq!(out.last(), Some(&Ok(msg)));
    }

    /// A frame cut short (the sender stopped mid-frame, then delimited): a framing or CRC
    /// error, once; the next frame is fine.
    #[test]
    fn truncated_frames_are_dropped(msg in valid_host_msg(), next in valid_host_msg(), cut in 0.0..1.0f64) {
        let f = frame(&msg);
        let keep = ((f.len() - 1) as f64 * cut) as usize; // never the whole frame
        let mut bytes = f[..keep].to_vec();
        bytes.push(DELIMITER);
        bytes.extend(frame(&next));
        let mut rx = DeviceRx::new();
        let out = decode(&mut rx, &bytes);
        if keep == 0 {
            prop_assert_eq!(out, vec![Ok(next)]); // an empty frame is ignored
        } else {
            prop_assert_eq!(out.len(), 2);
            prop_assert!(matches!(&out[0], Err(e) if is_damage(e)), "{:?}", out[0]);
            prop_assert_eq!(&out[1], &Ok(next));
            prop_assert_eq!(rx.stats().dropped(), 1);
        }
    }

    /// One flipped bit anywhere in a frame: never a wrong message, only framing or CRC errors,
    /// and the frame after the next delimiter is fine.
    #[test]
    fn bit_flipped_frames_are_dropped(msg in valid_host_msg(), next in valid_host_msg(), bit in any::<prop::sample::Index>()) {
        let mut f = frame(&msg);
        let b = bit.index(f.len() * 8);
        f[b / 8] ^= 1 << (b % 8);
        f.push(DELIMITER);
        f.extend(frame(&next));
        let mut rx = DeviceRx::new();
        let out = decode(&mut rx, &f);
        let (last, before) = out.split_last().unwrap();
        prop_assert_eq!(last, &Ok(next));
        prop_assert!(!before.is_empty(), "the damage went unnoticed");
        for r in before {
            prop_assert!(matches!(r, Err(e) if is_damage(e)), "{:?}", r);
        }
        prop_assert_eq!(rx.stats().dropped() as usize, before.len());
    }

    /// Frames longer than the receiver's buffer, garbage or well-formed: one oversized error
    /// each, skipped to their delimiter, and the next frame is fine.
    #[test]
    fn oversized_frames_are_skipped(
        junk in proptest::collection::vec(1u8..=255, 2 * HOST_MSG_MAX..6 * HOST_MSG_MAX),
        extra in 1usize..600,
        next in valid_host_msg(),
    ) {
        let mut rx = DeviceRx::new();
        let mut bytes = junk;
        bytes.push(DELIMITER);
        // A well-formed frame whose content is `extra` bytes too long.
        let mut content = vec![PROTOCOL_VERSION, HOST_TO_DEVICE];
        content.resize(HOST_MSG_MAX - CRC_LEN + extra, 0xA5);
        bytes.extend(raw_frame(&content));
        bytes.extend(frame(&next));
        let out = decode(&mut rx, &bytes);
        prop_assert_eq!(
            out,
            vec![Err(ProtocolError::Oversized), Err(ProtocolError::Oversized), Ok(next)]
        );
        prop_assert_eq!(rx.stats().oversized_frames, 2);
        prop_assert_eq!(rx.stats().dropped(), 2);
    }

    /// However the stream is cut into chunks, the decoder yields the same results as for the
    /// whole stream at once.
    #[test]
    fn chunk_boundaries_do_not_matter(
        msgs in proptest::collection::vec(valid_host_msg(), 1..12),
        garbage in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..40), 12),
        cuts in proptest::collection::vec(any::<prop::sample::Index>(), 0..30),
    ) {
        let mut stream = Vec::new();
        for (m, g) in msgs.iter().zip(&garbage) {
            stream.extend(g);
            stream.push(DELIMITER);
            stream.extend(frame(m));
        }
        let whole = decode(&mut DeviceRx::new(), &stream);
        let oks: Vec<_> = whole.iter().filter_map(|r| r.clone().ok()).collect();
        prop_assert_eq!(&oks, &msgs);

        let mut at: Vec<usize> = cuts.iter().map(|c| c.index(stream.len() + 1)).collect();
        at.sort_unstable();
        let mut rx = DeviceRx::new();
        let mut pieces = Vec::new();
        let mut start = 0;
        for &end in at.iter().chain(std::iter::once(&stream.len())) {
            pieces.extend(decode(&mut rx, &stream[start..end]));
            start = end;
        }
        prop_assert_eq!(pieces, whole);
    }

    /// Random pose samples and brush states survive the trip bit for bit, and the wire length
    /// respects the COBS bound.
    #[test]
    fn random_states_round_trip(
        layers in proptest::collection::vec(
            (any::<[i64; 3]>(), any::<[i64; 3]>(), any::<[i64; 3]>(), any::<[i64; 3]>(), any::<[i64; 4]>()),
            0..=MAX_LAYERS,
        ),
        tick in any::<u32>(),
        handle in (any::<[i64; 3]>(), any::<[i64; 4]>()),
        contacts in any::<u32>(),
    ) {
        let layers = layers.into_iter().map(|(spine, skeleton, short_axis, long_axis, r)| LayerState {
            spine, skeleton, short_axis, long_axis,
            long_radius: r[0], short_radius: r[1], wetness: r[2], deposited: r[3],
        });
        let state = BrushState {
            tick,
            pose_seq: tick.wrapping_mul(3),
            spine_index: 0,
            spine_count: 1,
            handle: PoseBits { pos: handle.0, rot: handle.1 },
            haptics: Haptics::default(),
            faults: Faults::empty(),
            contacts,
            ring_nodes: 16,
            footprint_eps: 1 << 28,
            layers: layers.collect(),
        };
        let msg = DeviceMsg::State(state);
        let f = frame(&msg);
        prop_assert!(f.len() <= DeviceMsg::MAX_FRAME);
        prop_assert_eq!(decode(&mut HostRx::new(), &f), vec![Ok(msg)]);
    }

    /// COBS never needs more than `max_frame_len` bytes, whatever the content.
    #[test]
    fn frames_respect_the_cobs_bound(content in proptest::collection::vec(any::<u8>(), 0..1100), ones in any::<bool>()) {
        let content = if ones { vec![0xFF; content.len()] } else { content };
        let max = content.len() + CRC_LEN;
        let mut out = vec![0u8; max_frame_len(max)];
        let n = encode_raw(&content, max, &mut out).unwrap();
        prop_assert!(n <= max_frame_len(max));
        prop_assert_eq!(out[..n].iter().filter(|&&b| b == 0).count(), 1);
    }
}

#[test]
fn reset_drops_a_partial_frame() {
    let mut rx = DeviceRx::new();
    let f = frame(&HostMsg::Ping { seq: 9 });
    let mut feed = rx.feed(&f[..3]);
    assert_eq!(feed.next(), None);
    assert!(feed.remaining().is_empty());
    rx.reset();
    assert_eq!(decode(&mut rx, &f), vec![Ok(HostMsg::Ping { seq: 9 })]);
    assert_eq!(rx.stats().dropped(), 0);
}

#[test]
fn shape_of_a_decoded_state_is_usable_without_the_brush() {
    // A host that never had the brush: the state alone gives geometry and the handle.
    let brush = pressed_brush(presets::SMALL);
    let state = BrushState::from_brush(&brush, 7, 0, Haptics::default(), Faults::LINK_SILENT);
    let shape = state.shape();
    assert_eq!(shape.spine().len(), brush.len());
    assert_eq!(shape.geometry().ring_nodes, brush.ring_nodes());
    assert_eq!(
        shape.geometry().eps,
        Fx::from_f32(brush.params().footprint_eps_mm)
    );
    assert_eq!(state.faults, Faults::LINK_SILENT);
    assert_eq!(
        format!("{}", Faults::LINK_SILENT | Faults::WATCHDOG),
        "LINK_SILENT | WATCHDOG"
    );
}

/// The test hook was appended: every earlier command keeps its wire tag, and the hook's tag
/// follows them.
#[test]
fn inject_overrun_is_appended_after_the_existing_commands() {
    let tag = |c: Command| {
        let mut b = [0u8; 8];
        postcard::to_slice(&HostMsg::Command(c), &mut b)
            .unwrap()
            .to_vec()
    };
    assert_eq!(tag(Command::EnableForces), [5, 0]);
    assert_eq!(tag(Command::ClearFaults), [5, 5]);
    assert_eq!(tag(Command::ResetBrush), [5, 6]);
    assert_eq!(tag(Command::InjectOverrun), [5, 7]);
    let mut buf = [0u8; HostMsg::MAX_FRAME];
    let n = HostMsg::Command(Command::InjectOverrun)
        .encode(&mut buf)
        .unwrap();
    let mut rx = DeviceRx::new();
    let got: Vec<_> = rx.feed(&buf[..n]).collect();
    assert_eq!(got, [Ok(HostMsg::Command(Command::InjectOverrun))]);
}

/// Guide samples were appended in protocol version 2: every earlier host message keeps its
/// wire tag, the guide's follows them, and its point crosses the link bit for bit.
#[test]
fn guide_samples_are_appended_and_exact() {
    const { assert!(PROTOCOL_VERSION >= 2) };
    let tag = |m: &HostMsg| {
        let mut b = [0u8; 64];
        postcard::to_slice(m, &mut b).unwrap()[0]
    };
    assert_eq!(tag(&HostMsg::Ping { seq: 1 }), 1);
    assert_eq!(tag(&HostMsg::Pose(PoseSample::default())), 2);
    assert_eq!(tag(&HostMsg::Command(Command::EnableForces)), 5);
    let a = Vec3::<Fx>::from_f64([123.456, -7.5, 0.001]);
    let m = HostMsg::Guide(GuideSample::new(77, a, true));
    assert_eq!(tag(&m), 6);
    let mut rx = DeviceRx::new();
    match decode(&mut rx, &frame(&m)).pop() {
        Some(Ok(HostMsg::Guide(g))) => {
            assert_eq!(g.anchor(), a);
            assert_eq!(g.seq, 77);
            assert!(g.on);
        }
        other => panic!("expected a guide sample, got {other:?}"),
    }
    // The longest guide sample is well inside the host bound.
    let worst = HostMsg::Guide(GuideSample {
        seq: u32::MAX,
        anchor: [i64::MIN; 3],
        on: true,
    });
    let n = frame(&worst).len();
    println!(
        "worst-case guide frame: {n} bytes of {}",
        HostMsg::MAX_FRAME
    );
    assert!(n < 64, "{n} bytes of {}", HostMsg::MAX_FRAME);
}

/// Protocol 3 appended its variants after protocol 2's guide sample: every earlier message
/// keeps its encoding, the new ones take the next tags.
#[test]
fn protocol_3_variants_are_appended() {
    let bytes = |m: &dyn Fn(&mut [u8]) -> usize| {
        let mut buf = [0u8; 600];
        let n = m(&mut buf);
        buf[..n].to_vec()
    };
    let host = |m: HostMsg| bytes(&|b| postcard::to_slice(&m, b).unwrap().len());
    let dev = |m: DeviceMsg| bytes(&|b| postcard::to_slice(&m, b).unwrap().len());
    // Earlier encodings, as protocols 1 and 2 wrote them.
    assert_eq!(host(HostMsg::Ping { seq: 5 }), [1, 5]);
    assert_eq!(host(HostMsg::Command(Command::InjectOverrun)), [5, 7]);
    assert_eq!(dev(DeviceMsg::Pong { seq: 5 }), [1, 5]);
    // The new tags follow.
    assert_eq!(host(HostMsg::GetConfig), [7]);
    assert_eq!(host(HostMsg::SetConfig(DeviceConfig::DEFAULT))[0], 8);
    assert_eq!(
        host(HostMsg::Command(Command::StreamSensors { rate_hz: 3 })),
        [5, 8, 3]
    );
    assert_eq!(
        host(HostMsg::Command(Command::NudgeMotor(Nudge {
            channel: 1,
            command_permille: -1,
            duration_ms: 2,
        }))),
        [5, 9, 1, 1, 2] // zigzag: -1 is 1
    );
    assert_eq!(
        dev(DeviceMsg::Config(Ok(DeviceConfig::DEFAULT)))[..2],
        [7, 0]
    );
    assert_eq!(
        dev(DeviceMsg::CommandDone {
            command: Command::EnableForces,
            result: Err(CommandError::ConfigNotValid)
        }),
        [4, 0, 1, 3]
    );
    // DeviceInfo's config state comes just before its tick limits (protocol 6: four bytes,
    // `TickLimits::NONE` here), its last field.
    let info = DeviceInfo::new("p", Version::default(), Capabilities::empty(), 0.0, 0.0);
    let encoded = dev(DeviceMsg::Hello(
        info.clone().with_config(ConfigState::Missing),
    ));
    let tail = |e: &[u8]| e[e.len() - 5..].to_vec();
    assert_eq!(tail(&encoded), [1, 100, 24, 32, 16]);
    assert_eq!(tail(&dev(DeviceMsg::Hello(info))), [3, 100, 24, 32, 16]);
}

#[test]
fn nudge_caps() {
    let ok = Nudge {
        channel: 2,
        command_permille: -150,
        duration_ms: 300,
    };
    assert!(ok.is_within_caps());
    for bad in [
        Nudge {
            channel: 3,
            ..ok.clone()
        },
        Nudge {
            command_permille: 151,
            ..ok.clone()
        },
        Nudge {
            command_permille: i16::MIN,
            ..ok.clone()
        },
        Nudge {
            duration_ms: 301,
            ..ok.clone()
        },
        Nudge {
            duration_ms: 0,
            ..ok.clone()
        },
    ] {
        assert!(!bad.is_within_caps(), "{bad:?}");
    }
}
