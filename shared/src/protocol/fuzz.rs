//! Random protocol traffic for robustness tests (feature `fuzz`, for tests only): well-formed
//! messages of every variant with random fields, each direction, and damaged frames.
//!
//! One place for every test that streams random traffic at a peer: the pen under QEMU (hil),
//! `maobi sim-device`, `maobi bridge`, and the other way round a fake device at the host's
//! link and commands. The values come from [`proptest`] strategies, drawn from a seeded
//! generator ([`Fuzz::new`]): the same seed gives the same stream, and tests print it.
//!
//! Fields mix extreme values (any bits) with plausible ones, so that a stream both probes
//! the decoders' and validators' edges and drives the peer's real paths: poses walk near the
//! paper instead of jumping (a jump latches a fault and would keep the forces off), forces
//! are enabled and faults cleared often enough to have the motors driven part of the time.

// Test support on the host, never on a device: a broken strategy should fail loudly.
#![allow(
    clippy::indexing_slicing,
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic
)]

use std::collections::BTreeSet;

use proptest::prelude::*;
use proptest::strategy::ValueTree;
use proptest::test_runner::{Config, RngAlgorithm, TestRng, TestRunner};

use super::BrushState;
use super::{
    bounded_str, Buttons, Capabilities, Command, CommandError, ConfigError, ConfigRejected,
    ConfigState, DeviceConfig, DeviceInfo, DeviceMsg, Event, EventKind, Faults, GuideSample,
    Haptics, HostHello, HostMsg, InvalidField, LayerState, LinkStats, Message, Nudge,
    ParamRejected, ParamReply, PoseBits, PoseSample, PresetRef, RejectReason, SensorReport,
    Telemetry, Version, DELIMITER, PROTOCOL_VERSION,
};
use crate::kinematics::RawReadings;
use crate::params::{ParamId, TickLimits, MAX_LAYERS};
use crate::pen_io::ZeroPolicy;
use crate::{Fx, Scalar};

/// The seed tests use unless `MAOBI_FUZZ_SEED` says otherwise.
pub const DEFAULT_SEED: u64 = 0x6d61_6f62_6926;

/// A `u64` seed from the environment variable `MAOBI_FUZZ_SEED` (decimal or `0x` hex), else
/// `default`.
pub fn seed_from_env(default: u64) -> u64 {
    std::env::var("MAOBI_FUZZ_SEED")
        .ok()
        .and_then(|s| {
            let s = s.trim();
            match s.strip_prefix("0x") {
                Some(h) => u64::from_str_radix(h, 16).ok(),
                None => s.parse().ok(),
            }
        })
        .unwrap_or(default)
}

/// Fixed-point bits of `mm`.
fn bits(v: f64) -> i64 {
    Fx::from_f64(v).to_bits()
}

/// `f32` values: any bit pattern (NaN, infinities, subnormals) or a plausible magnitude.
pub fn any_f32() -> impl Strategy<Value = f32> {
    prop_oneof![
        2 => prop::num::f32::ANY,
        3 => -100.0f32..100.0,
        1 => Just(0.0f32),
    ]
}

/// Fixed-point bits: any `i64`, or a plausible length (mm) near the paper.
pub fn any_fx_bits() -> impl Strategy<Value = i64> {
    prop_oneof![
        1 => any::<i64>(),
        3 => (-200.0f64..200.0).prop_map(bits),
        1 => Just(0i64),
    ]
}

fn name<const N: usize>() -> impl Strategy<Value = heapless::String<N>> {
    prop_oneof![
        "\\PC{0,30}".prop_map(|s| bounded_str(&s)),
        prop::sample::select(vec!["大楷", "large", "small", "medium", "", "hil"])
            .prop_map(bounded_str),
    ]
}

fn version() -> impl Strategy<Value = Version> {
    (any::<u16>(), any::<u16>(), any::<u16>()).prop_map(|(major, minor, patch)| Version {
        major,
        minor,
        patch,
    })
}

fn protocol_version() -> impl Strategy<Value = u8> {
    prop_oneof![8 => Just(PROTOCOL_VERSION), 1 => any::<u8>()]
}

/// A rotation: a unit quaternion (the identity's neighbourhood: the brush about upright) or
/// any bits.
fn rotation() -> impl Strategy<Value = [i64; 4]> {
    prop_oneof![
        3 => (-0.4f64..0.4, -0.4f64..0.4, -0.4f64..0.4).prop_map(|(x, y, z)| {
            let w = (1.0 - (x * x + y * y + z * z)).max(0.0).sqrt();
            [bits(w), bits(x), bits(y), bits(z)]
        }),
        1 => any::<[i64; 4]>(),
    ]
}

/// A pose sample with any fields (most poses in a stream come from [`Fuzz`]'s walk).
fn pose_sample() -> impl Strategy<Value = PoseSample> {
    (
        any::<u32>(),
        prop::array::uniform3(any_fx_bits()),
        rotation(),
        any::<u8>(),
    )
        .prop_map(|(seq, pos, rot, b)| PoseSample {
            seq,
            pose: PoseBits { pos, rot },
            buttons: Buttons::from_bits_retain(b),
        })
}

fn guide_sample() -> impl Strategy<Value = GuideSample> {
    (
        any::<u32>(),
        prop::array::uniform3(any_fx_bits()),
        any::<bool>(),
    )
        .prop_map(|(seq, anchor, on)| GuideSample { seq, anchor, on })
}

/// A parameter number: one that exists, or any.
fn param_number() -> impl Strategy<Value = u8> {
    prop_oneof![
        3 => prop::sample::select(ParamId::ALL.to_vec()).prop_map(|p| p as u8),
        1 => any::<u8>(),
    ]
}

/// The parameters whose largest value is the dearest tick: the brush's size and its solver's
/// work per tick (the tick's cost grows with each; `docs/firmware-cost.md`).
pub const COSTLY_PARAMS: [ParamId; 4] = [
    ParamId::Layers,
    ParamId::RingNodes,
    ParamId::JacobiIterations,
    ParamId::SubstepsPerTick,
];

/// A value `p` accepts on its own: across [`ParamId::range`], a whole number where the
/// parameter is one (`ring_nodes` a power of two), its range's ends drawn often (for
/// [`COSTLY_PARAMS`] the top is the most expensive tick the pen can be asked for).
pub fn valid_param_value(p: ParamId) -> BoxedStrategy<f32> {
    let (min, max, integral) = p.range();
    let across: BoxedStrategy<f32> = match (p, integral) {
        (ParamId::RingNodes, _) => prop::sample::select(vec![4.0f32, 8.0, 16.0, 32.0])
            .prop_filter("in range", move |v| (min..=max).contains(v))
            .boxed(),
        (_, true) => ((min as i32)..=(max as i32)).prop_map(|v| v as f32).boxed(),
        (_, false) => (min..=max).boxed(),
    };
    prop_oneof![
        4 => Just(max),
        2 => Just(min),
        5 => across,
    ]
    .boxed()
}

/// A value `p` refuses on its own: out of its range either side, not finite, a fraction
/// where a whole number is needed, or any bits (which are almost always out of range).
pub fn invalid_param_value(p: ParamId) -> BoxedStrategy<f32> {
    let (min, max, integral) = p.range();
    let span = (max - min).max(1.0);
    let mut ways: Vec<(u32, BoxedStrategy<f32>)> = vec![
        (
            2,
            (0.0f32..1.0)
                .prop_map(move |f| max + span * (0.001 + f))
                .boxed(),
        ),
        (
            2,
            (0.0f32..1.0)
                .prop_map(move |f| min - span * (0.001 + f))
                .boxed(),
        ),
        (
            1,
            prop::sample::select(vec![f32::NAN, f32::INFINITY, f32::NEG_INFINITY]).boxed(),
        ),
        (1, prop::num::f32::ANY.boxed()),
    ];
    if integral {
        ways.push((
            2,
            ((min as i32)..(max as i32))
                .prop_map(|v| v as f32 + 0.5)
                .boxed(),
        ));
    }
    prop::strategy::Union::new_weighted(ways).boxed()
}

/// A `SetParam`'s number and value: mostly a parameter that exists with a valid value
/// ([`valid_param_value`]), some with an invalid one, a few unknown numbers.
fn set_param() -> impl Strategy<Value = (u8, f32)> {
    let known = prop::sample::select(ParamId::ALL.to_vec()).prop_flat_map(|p| {
        prop_oneof![
            4 => valid_param_value(p),
            1 => invalid_param_value(p),
        ]
        .prop_map(move |v| (p as u8, v))
    });
    prop_oneof![
        8 => known,
        1 => (any::<u8>(), any_f32()),
    ]
}

/// Whether `value` is one `p` accepts on its own (its range, whole where it must be;
/// `ring_nodes` a power of two): what [`valid_param_value`] draws. Values valid alone may
/// still be refused together with the others (`Inconsistent`).
pub fn param_value_valid(p: ParamId, value: f32) -> bool {
    let (min, max, integral) = p.range();
    value.is_finite()
        && (min..=max).contains(&value)
        && (!integral || value.fract() == 0.0)
        && (p != ParamId::RingNodes || (value as u32).is_power_of_two())
}

/// A stored configuration: the default with a few fields set to random values (most stay
/// valid, some are not); limits included, so accepted ones change the forces' limits.
pub fn device_config() -> impl Strategy<Value = DeviceConfig> {
    (
        prop::collection::vec((0usize..FIELDS, any_f32(), 0usize..3), 0..4),
        any::<bool>(),
        any::<[i64; 3]>(),
        any::<[i32; 3]>(),
    )
        .prop_map(|(changes, calibrated, encoders, gimbal)| {
            let mut c = DeviceConfig::DEFAULT;
            c.calibration = calibrated.then_some(RawReadings { encoders, gimbal });
            for (field, v, j) in changes {
                set_field(&mut c, field, v, j);
            }
            c
        })
}

/// How many fields [`set_field`] knows.
const FIELDS: usize = 27;

/// Sets field number `field` (of [`FIELDS`]), channel `j` where it has three, from `v`.
fn set_field(c: &mut DeviceConfig, field: usize, v: f32, j: usize) {
    let p = &mut c.pen;
    let l = &mut c.limits;
    let d = &mut c.drive[j];
    // Integer fields take `v` saturated (NaN becomes 0), signs its sign.
    let sign = if v < 0.0 { -1 } else { 1 };
    match field {
        0 => p.upper_arm_mm = v,
        1 => p.forearm_mm = v,
        2 => p.stylus_mm = v,
        3 => p.base_mm[j] = v,
        4 => p.counts_per_rev[j] = v as u32,
        5 => p.ratio[j] = v,
        6 => p.encoder_sign[j] = sign,
        7 => p.torque_constant[j] = v,
        8 => p.max_current[j] = v,
        9 => p.motor_sign[j] = sign,
        10 => p.joint_min[j] = v,
        11 => p.joint_max[j] = v,
        12 => p.gimbal_rad_per_code[j] = v,
        13 => p.gimbal_sign[j] = sign,
        14 => p.inkwell_joints[j] = v,
        15 => p.inkwell_gimbal[j] = v,
        16 => l.peak_n = v,
        17 => l.continuous_n = v,
        18 => l.thermal_time_s = v,
        19 => l.max_step_n = v,
        20 => l.ramp_in_s = v,
        21 => l.ramp_out_s = v,
        22 => l.damping_ns_per_m = v,
        23 => d.pwm_hz = v as u32,
        24 => d.deadband = v,
        25 => d.max_duty = v,
        _ => {
            d.zero = if v < 0.0 {
                ZeroPolicy::Brake
            } else {
                ZeroPolicy::Coast
            }
        }
    }
}

/// Every command, with random fields.
pub fn command() -> impl Strategy<Value = Command> {
    prop_oneof![
        4 => Just(Command::EnableForces),
        1 => Just(Command::DisableForces),
        1 => Just(Command::Calibrate),
        1 => prop_oneof![any::<i64>(), 0i64..(1 << 32)]
            .prop_map(|wetness| Command::DipInk { wetness }),
        1 => prop_oneof![
            // Mostly presets that exist (every one, the dearest included), some that do not.
            3 => (0..crate::presets::PRESETS.len() as u8).prop_map(PresetRef::Index),
            1 => any::<u8>().prop_map(PresetRef::Index),
            2 => prop::sample::select(crate::presets::PRESETS.map(|(n, _)| n).to_vec())
                .prop_map(|n| PresetRef::Name(bounded_str(n))),
            1 => name().prop_map(PresetRef::Name),
        ]
        .prop_map(Command::ChoosePreset),
        4 => Just(Command::ClearFaults),
        1 => Just(Command::ResetBrush),
        1 => Just(Command::InjectOverrun),
        1 => prop_oneof![3 => 0u16..=1000, 1 => any::<u16>()]
            .prop_map(|rate_hz| Command::StreamSensors { rate_hz }),
        1 => (
            prop_oneof![0u8..3, any::<u8>()],
            prop_oneof![-150i16..=150, any::<i16>()],
            prop_oneof![1u16..=300, any::<u16>()],
        )
            .prop_map(|(channel, command_permille, duration_ms)| {
                Command::NudgeMotor(Nudge {
                    channel,
                    command_permille,
                    duration_ms,
                })
            }),
    ]
}

/// What [`host_draw`] draws: a message as it is, or a step of [`Fuzz`]'s pose walk.
#[derive(Clone, Debug)]
enum HostDraw {
    Msg(HostMsg),
    /// The walk moves by this step (mm) and sends the pose, with a guide sample first when
    /// `guide` is given (its anchor's offset from the pose, mm, and `on`).
    Walk {
        step: [f64; 3],
        rot: [i64; 4],
        buttons: u8,
        guide: Option<([f64; 3], bool)>,
    },
}

fn host_draw() -> impl Strategy<Value = HostDraw> {
    let msg = prop_oneof![
        1 => (protocol_version(), version(), name()).prop_map(|(protocol_version, software, name)| {
            HostMsg::Hello(HostHello {
                protocol_version,
                software,
                name,
            })
        }),
        2 => any::<u32>().prop_map(|seq| HostMsg::Ping { seq }),
        2 => pose_sample().prop_map(HostMsg::Pose),
        1 => param_number().prop_map(|id| HostMsg::GetParam { id }),
        6 => set_param().prop_map(|(id, value)| HostMsg::SetParam { id, value }),
        6 => command().prop_map(HostMsg::Command),
        1 => guide_sample().prop_map(HostMsg::Guide),
        1 => Just(HostMsg::GetConfig),
        1 => device_config().prop_map(HostMsg::SetConfig),
    ];
    let walk = (
        prop::array::uniform3(-0.6f64..0.6),
        rotation(),
        prop_oneof![8 => Just(0u8), 1 => any::<u8>()],
        prop::option::weighted(0.3, (prop::array::uniform3(-5.0f64..5.0), any::<bool>())),
    )
        .prop_map(|(step, rot, buttons, guide)| HostDraw::Walk {
            step,
            rot,
            buttons,
            guide,
        });
    prop_oneof![
        3 => msg.prop_map(HostDraw::Msg),
        5 => walk,
    ]
}

/// Every host message kind, a command counting as its own kind: what a stream covers.
pub const HOST_KINDS: &[&str] = &[
    "Hello",
    "Ping",
    "Pose",
    "GetParam",
    "SetParam",
    "Guide",
    "GetConfig",
    "SetConfig",
    "Command::EnableForces",
    "Command::DisableForces",
    "Command::Calibrate",
    "Command::DipInk",
    "Command::ChoosePreset",
    "Command::ClearFaults",
    "Command::ResetBrush",
    "Command::InjectOverrun",
    "Command::StreamSensors",
    "Command::NudgeMotor",
];

/// `m`'s kind, one of [`HOST_KINDS`]. Exhaustive: a new variant does not compile until it
/// is named here (and generated above).
pub fn host_kind(m: &HostMsg) -> &'static str {
    match m {
        HostMsg::Hello(_) => "Hello",
        HostMsg::Ping { .. } => "Ping",
        HostMsg::Pose(_) => "Pose",
        HostMsg::GetParam { .. } => "GetParam",
        HostMsg::SetParam { .. } => "SetParam",
        HostMsg::Guide(_) => "Guide",
        HostMsg::GetConfig => "GetConfig",
        HostMsg::SetConfig(_) => "SetConfig",
        HostMsg::Command(c) => command_kind(c),
    }
}

fn command_kind(c: &Command) -> &'static str {
    match c {
        Command::EnableForces => "Command::EnableForces",
        Command::DisableForces => "Command::DisableForces",
        Command::Calibrate => "Command::Calibrate",
        Command::DipInk { .. } => "Command::DipInk",
        Command::ChoosePreset(_) => "Command::ChoosePreset",
        Command::ClearFaults => "Command::ClearFaults",
        Command::ResetBrush => "Command::ResetBrush",
        Command::InjectOverrun => "Command::InjectOverrun",
        Command::StreamSensors { .. } => "Command::StreamSensors",
        Command::NudgeMotor(_) => "Command::NudgeMotor",
    }
}

fn faults() -> impl Strategy<Value = Faults> {
    any::<u16>().prop_map(Faults::from_bits_retain)
}

fn config_state() -> impl Strategy<Value = ConfigState> {
    prop_oneof![
        Just(ConfigState::Valid),
        Just(ConfigState::Missing),
        Just(ConfigState::NotApplicable),
        any::<u16>().prop_map(|from| ConfigState::Migrated { from }),
        prop_oneof![
            Just(ConfigError::Erased),
            Just(ConfigError::BadMagic),
            any::<u16>().prop_map(|found| ConfigError::UnsupportedVersion { found }),
            any::<u16>().prop_map(|len| ConfigError::BadLength { len }),
            Just(ConfigError::Truncated),
            (any::<u32>(), any::<u32>())
                .prop_map(|(stored, computed)| ConfigError::CrcMismatch { stored, computed }),
        ]
        .prop_map(ConfigState::Corrupt),
    ]
}

fn invalid_field() -> impl Strategy<Value = InvalidField> {
    (name(), any_f32(), any_f32(), any_f32()).prop_map(|(f, value, min, max)| {
        let f: heapless::String<24> = f;
        InvalidField {
            field: bounded_str(&f),
            value,
            min,
            max,
        }
    })
}

fn command_error() -> impl Strategy<Value = CommandError> {
    prop_oneof![
        Just(CommandError::Unsupported),
        Just(CommandError::UnknownPreset),
        faults().prop_map(CommandError::FaultsLatched),
        Just(CommandError::ConfigNotValid),
        Just(CommandError::ForcesEnabled),
        Just(CommandError::OutOfRange),
        Just(CommandError::StoreFailed),
        (any::<u8>(), any::<u32>(), any::<u32>())
            .prop_map(|(param, value, max)| CommandError::OverTickLimit { param, value, max }),
    ]
}

fn reject_reason() -> impl Strategy<Value = RejectReason> {
    prop_oneof![
        Just(RejectReason::UnknownParam),
        Just(RejectReason::NotFinite),
        (any_f32(), any_f32(), any_f32()).prop_map(|(value, min, max)| RejectReason::OutOfRange {
            value,
            min,
            max
        }),
        any_f32().prop_map(|value| RejectReason::NotWholeNumber { value }),
        name::<24>().prop_map(|w| RejectReason::Inconsistent {
            why: bounded_str(&w)
        }),
        any_f32().prop_map(|value| RejectReason::RingNodesNotPowerOfTwo { value }),
        (any_f32(), any_f32()).prop_map(|(value, max)| RejectReason::OverTickLimit { value, max }),
    ]
}

fn layer() -> impl Strategy<Value = LayerState> {
    (
        prop::array::uniform3(any_fx_bits()),
        prop::array::uniform3(any_fx_bits()),
        prop::array::uniform3(any_fx_bits()),
        prop::array::uniform3(any_fx_bits()),
        prop::array::uniform4(any_fx_bits()),
    )
        .prop_map(|(spine, skeleton, short_axis, long_axis, r)| LayerState {
            spine,
            skeleton,
            short_axis,
            long_axis,
            long_radius: r[0],
            short_radius: r[1],
            wetness: r[2],
            deposited: r[3],
        })
}

/// A brush state with any fields: any layer count up to the most a frame carries, any
/// values, faults, haptics.
pub fn brush_state() -> impl Strategy<Value = BrushState> {
    (
        (any::<u32>(), any::<u32>(), any::<u8>(), any::<u8>()),
        (prop::array::uniform3(any_fx_bits()), rotation()),
        (
            prop::array::uniform3(any_fx_bits()),
            prop::array::uniform3(any_fx_bits()),
            any::<bool>(),
        ),
        (faults(), any::<u32>(), any::<u8>(), any_fx_bits()),
        prop::collection::vec(layer(), 0..=MAX_LAYERS),
    )
        .prop_map(
            |(
                (tick, pose_seq, spine_index, spine_count),
                (pos, rot),
                (force_n, motors, enabled),
                (faults, contacts, ring_nodes, footprint_eps),
                layers,
            )| {
                let mut st = BrushState::EMPTY;
                st.tick = tick;
                st.pose_seq = pose_seq;
                st.spine_index = spine_index;
                st.spine_count = spine_count;
                st.handle = PoseBits { pos, rot };
                st.haptics = Haptics {
                    force_n,
                    motors,
                    enabled,
                };
                st.faults = faults;
                st.contacts = contacts;
                st.ring_nodes = ring_nodes;
                st.footprint_eps = footprint_eps;
                for l in layers {
                    let _ = st.layers.push(l);
                }
                st
            },
        )
}

fn event() -> impl Strategy<Value = Event> {
    (
        any::<u32>(),
        prop_oneof![
            faults().prop_map(EventKind::FaultRaised),
            faults().prop_map(EventKind::FaultCleared),
            Just(EventKind::ForcesEnabled),
            Just(EventKind::ForcesDisabled),
            Just(EventKind::LinkConnected),
            any::<u32>().prop_map(|silent_ms| EventKind::LinkReconnected { silent_ms }),
        ],
        faults(),
    )
        .prop_map(|(tick, kind, faults)| Event { tick, kind, faults })
}

fn telemetry() -> impl Strategy<Value = Telemetry> {
    (
        any::<[u32; 4]>(),
        any::<u8>(),
        any::<[u32; 2]>(),
        any::<[u32; 6]>(),
        any::<[u32; 4]>(),
    )
        .prop_map(|(t, load_percent, f, rx, busy)| Telemetry {
            tick: t[0],
            tick_period_min_us: t[1],
            tick_period_mean_us: t[2],
            tick_period_max_us: t[3],
            load_percent,
            frames_dropped: f[0],
            pose_gaps: f[1],
            rx: LinkStats {
                frames_ok: rx[0],
                framing_errors: rx[1],
                crc_errors: rx[2],
                oversized_frames: rx[3],
                decode_errors: rx[4],
                version_errors: rx[5],
            },
            tick_busy_max_us: busy[0],
            tick_busy_max_cycles: busy[1],
            overruns: busy[2],
            brush_ticks: busy[3],
        })
}

/// Every device message, with random fields.
pub fn device_msg() -> impl Strategy<Value = DeviceMsg> {
    prop_oneof![
        1 => (
            protocol_version(),
            version(),
            name(),
            any::<u32>(),
            any_f32(),
            any_f32(),
            config_state(),
            any::<[u8; 4]>(),
        )
            .prop_map(|(protocol_version, firmware, board, caps, peak, cont, config, caps4)| {
                DeviceMsg::Hello(DeviceInfo {
                    protocol_version,
                    firmware,
                    board,
                    capabilities: Capabilities::from_bits_retain(caps),
                    force_peak_n: peak,
                    force_continuous_n: cont,
                    config,
                    limits: TickLimits {
                        substeps_per_tick: caps4[0],
                        layers: caps4[1],
                        ring_nodes: caps4[2],
                        jacobi_iterations: caps4[3],
                    },
                })
            }),
        2 => any::<u32>().prop_map(|seq| DeviceMsg::Pong { seq }),
        6 => brush_state().prop_map(DeviceMsg::State),
        1 => (
            param_number(),
            prop_oneof![
                any_f32().prop_map(Ok),
                (param_number(), reject_reason())
                    .prop_map(|(param, reason)| Err(ParamRejected { param, reason })),
            ]
        )
            .prop_map(|(id, result)| DeviceMsg::Param(ParamReply { id, result })),
        2 => (command(), prop_oneof![Just(Ok(())), command_error().prop_map(Err)])
            .prop_map(|(command, result)| DeviceMsg::CommandDone { command, result }),
        2 => event().prop_map(DeviceMsg::Event),
        1 => telemetry().prop_map(DeviceMsg::Telemetry),
        1 => prop_oneof![
            device_config().prop_map(Ok),
            prop_oneof![
                config_state().prop_map(ConfigRejected::NotStored),
                invalid_field().prop_map(ConfigRejected::Invalid),
                Just(ConfigRejected::ForcesEnabled),
                Just(ConfigRejected::StoreFailed),
            ]
            .prop_map(Err),
        ]
        .prop_map(DeviceMsg::Config),
        1 => (
            any::<u32>(),
            any::<[i64; 3]>(),
            any::<[u16; 3]>(),
            any::<u8>(),
            any::<bool>()
        )
            .prop_map(|(tick, encoders, gimbal, b, synthetic)| {
                DeviceMsg::Sensors(SensorReport {
                    tick,
                    encoders,
                    gimbal,
                    buttons: Buttons::from_bits_retain(b),
                    synthetic,
                })
            }),
    ]
}

/// Every device message kind.
pub const DEVICE_KINDS: &[&str] = &[
    "Hello",
    "Pong",
    "State",
    "Param",
    "CommandDone",
    "Event",
    "Telemetry",
    "Config",
    "Sensors",
];

/// `m`'s kind, one of [`DEVICE_KINDS`] (exhaustive, as [`host_kind`]).
pub fn device_kind(m: &DeviceMsg) -> &'static str {
    match m {
        DeviceMsg::Hello(_) => "Hello",
        DeviceMsg::Pong { .. } => "Pong",
        DeviceMsg::State(_) => "State",
        DeviceMsg::Param(_) => "Param",
        DeviceMsg::CommandDone { .. } => "CommandDone",
        DeviceMsg::Event(_) => "Event",
        DeviceMsg::Telemetry(_) => "Telemetry",
        DeviceMsg::Config(_) => "Config",
        DeviceMsg::Sensors(_) => "Sensors",
    }
}

/// One piece of a stream on the wire.
#[derive(Clone, Debug)]
pub enum Piece<M> {
    /// A well-formed frame (its bytes end with the delimiter) of this message.
    Frame(M, Vec<u8>),
    /// Damaged bytes: a frame with a flipped bit, cut short, with bytes spliced in, or
    /// garbage; followed by a delimiter, so the frame after it decodes.
    Damaged(Vec<u8>),
}

impl<M> Piece<M> {
    pub fn bytes(&self) -> &[u8] {
        match self {
            Piece::Frame(_, b) | Piece::Damaged(b) => b,
        }
    }
}

/// A seeded source of random traffic. Poses mostly follow a random walk near the paper
/// (with increasing `seq`), so a stream writes as well as it probes.
pub struct Fuzz {
    seed: u64,
    runner: TestRunner,
    /// The walk's position (mm) and the next walk pose's `seq`.
    pos: [f64; 3],
    seq: u32,
    /// Host and device kinds drawn so far.
    host_kinds: BTreeSet<&'static str>,
    /// Parameters drawn in a `SetParam` with a value valid on its own, and at their range's
    /// top.
    params_valid: BTreeSet<u8>,
    params_at_max: BTreeSet<u8>,
    device_kinds: BTreeSet<&'static str>,
}

impl Fuzz {
    pub fn new(seed: u64) -> Self {
        let mut key = [0u8; 32];
        key[..8].copy_from_slice(&seed.to_le_bytes());
        let rng = TestRng::from_seed(RngAlgorithm::ChaCha, &key);
        Fuzz {
            seed,
            runner: TestRunner::new_with_rng(Config::default(), rng),
            pos: [0.0, 0.0, 20.0],
            seq: 1,
            host_kinds: BTreeSet::new(),
            params_valid: BTreeSet::new(),
            params_at_max: BTreeSet::new(),
            device_kinds: BTreeSet::new(),
        }
    }

    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// One value of `s`.
    pub fn draw<S: Strategy>(&mut self, s: S) -> S::Value {
        s.new_tree(&mut self.runner)
            .expect("the strategies never reject")
            .current()
    }

    /// The next host messages: one, or a guide sample and its pose.
    pub fn host_msgs(&mut self) -> Vec<HostMsg> {
        let out = match self.draw(host_draw()) {
            HostDraw::Msg(m) => vec![m],
            HostDraw::Walk {
                step,
                rot,
                buttons,
                guide,
            } => {
                for (p, (d, (lo, hi))) in self.pos.iter_mut().zip(step.iter().zip([
                    (-60.0, 60.0),
                    (-60.0, 60.0),
                    (-8.0, 40.0),
                ])) {
                    *p = (*p + d).clamp(lo, hi);
                }
                let seq = self.seq;
                self.seq = self.seq.wrapping_add(1);
                let pose = HostMsg::Pose(PoseSample {
                    seq,
                    pose: PoseBits {
                        pos: self.pos.map(bits),
                        rot,
                    },
                    buttons: Buttons::from_bits_retain(buttons),
                });
                match guide {
                    Some((off, on)) => {
                        let anchor = [0, 1, 2].map(|i| bits(self.pos[i] + off[i]));
                        vec![HostMsg::Guide(GuideSample { seq, anchor, on }), pose]
                    }
                    None => vec![pose],
                }
            }
        };
        for m in &out {
            self.host_kinds.insert(host_kind(m));
            if let HostMsg::SetParam { id, value } = *m {
                if let Some(p) = ParamId::ALL.into_iter().find(|p| *p as u8 == id) {
                    if param_value_valid(p, value) {
                        self.params_valid.insert(id);
                    }
                    if value == p.range().1 {
                        self.params_at_max.insert(id);
                    }
                }
            }
        }
        out
    }

    /// The next device message.
    pub fn device_msg(&mut self) -> DeviceMsg {
        let m = self.draw(device_msg());
        self.device_kinds.insert(device_kind(&m));
        m
    }

    /// The next pieces of a host-to-device stream: well-formed frames, and about one in
    /// `1 / damaged` damaged.
    pub fn host_pieces(&mut self, damaged: f64) -> Vec<Piece<HostMsg>> {
        let msgs = self.host_msgs();
        self.pieces(msgs, damaged)
    }

    /// As [`Self::host_pieces`], device to host.
    pub fn device_pieces(&mut self, damaged: f64) -> Vec<Piece<DeviceMsg>> {
        let m = self.device_msg();
        self.pieces(vec![m], damaged)
    }

    fn pieces<M: Message + serde::Serialize>(
        &mut self,
        msgs: Vec<M>,
        damaged: f64,
    ) -> Vec<Piece<M>> {
        let mut out = Vec::new();
        for m in msgs {
            let f = frame(&m);
            if self.draw(prop::bool::weighted(damaged.clamp(0.0, 1.0))) {
                let d = self.damage(f);
                out.push(Piece::Damaged(d));
            } else {
                out.push(Piece::Frame(m, f));
            }
        }
        out
    }

    /// `f` damaged one way or another, then delimited.
    fn damage(&mut self, mut f: Vec<u8>) -> Vec<u8> {
        let how = self.draw(0u8..4);
        let at = self.draw(any::<prop::sample::Index>());
        match how {
            0 => {
                let b = at.index(f.len() * 8);
                f[b / 8] ^= 1 << (b % 8);
            }
            1 => f.truncate(at.index(f.len())),
            2 => {
                let junk = self.draw(prop::collection::vec(any::<u8>(), 1..16));
                let i = at.index(f.len());
                f.splice(i..i, junk);
            }
            _ => f = self.draw(prop::collection::vec(any::<u8>(), 0..600)),
        }
        f.push(DELIMITER);
        f
    }

    /// Host message kinds drawn so far, of [`HOST_KINDS`].
    pub fn host_kinds(&self) -> &BTreeSet<&'static str> {
        &self.host_kinds
    }

    /// The parameters no `SetParam` drawn so far wrote with a valid value, and those never
    /// written at their range's top: both empty once a stream covers every parameter.
    pub fn params_not_covered(&self) -> (Vec<ParamId>, Vec<ParamId>) {
        let missing = |set: &BTreeSet<u8>| -> Vec<ParamId> {
            ParamId::ALL
                .into_iter()
                .filter(|p| !set.contains(&(*p as u8)))
                .collect()
        };
        (missing(&self.params_valid), missing(&self.params_at_max))
    }

    /// Device message kinds drawn so far, of [`DEVICE_KINDS`].
    pub fn device_kinds(&self) -> &BTreeSet<&'static str> {
        &self.device_kinds
    }
}

/// `m`'s frame, delimiter included.
pub fn frame<M: Message>(m: &M) -> Vec<u8> {
    let mut buf = vec![0u8; M::MAX_FRAME];
    let n = m.encode(&mut buf).expect("a message fits its frame");
    buf.truncate(n);
    buf
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::ParamError;
    use crate::presets;

    /// The pen fuzz's parameter writes: mostly valid, every parameter covered with a valid
    /// value and at its most expensive, and what the generator calls valid is what the
    /// brush's own check accepts (it may still find the whole brush inconsistent).
    #[test]
    fn set_params_are_mostly_valid_and_cover_every_parameter() {
        let mut fz = Fuzz::new(DEFAULT_SEED);
        let (mut known, mut valid) = (0u32, 0u32);
        for _ in 0..6000 {
            for m in fz.host_msgs() {
                let HostMsg::SetParam { id, value } = m else {
                    continue;
                };
                let Some(p) = ParamId::ALL.into_iter().find(|p| *p as u8 == id) else {
                    continue;
                };
                known += 1;
                let mut params = presets::LARGE;
                let r = params.set(p, value);
                if param_value_valid(p, value) {
                    valid += 1;
                    assert!(
                        matches!(r, Ok(()) | Err(ParamError::Inconsistent { .. })),
                        "{p} = {value}: {r:?}"
                    );
                    let (_, _, integral) = p.range();
                    assert!(!integral || value.fract() == 0.0, "{p} = {value}");
                } else {
                    assert!(r.is_err(), "{p} = {value} accepted but drawn as invalid");
                }
            }
        }
        assert!(known > 400, "{known} SetParams of known parameters");
        let share = f64::from(valid) / f64::from(known);
        assert!(share > 0.6 && share < 0.95, "valid share {share:.2}");
        let (never_valid, never_max) = fz.params_not_covered();
        assert!(never_valid.is_empty(), "never valid: {never_valid:?}");
        assert!(never_max.is_empty(), "never at the top: {never_max:?}");
    }
}
