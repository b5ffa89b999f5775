//! Configuration images of format 1 (before the winding resistances and the power): built
//! byte for byte from that format's layout (postcard's encoding written out by hand below,
//! the CRC computed here too), read by `pen_io::load` into the current configuration with
//! everything kept and no force; damaged the ways a flash image gets damaged.
//!
//! The layout and its hand-written encoder: `common/format_1.rs`.

use maobi_shared::force::{DeviceLimits, PHANTOM_OMNI};
use maobi_shared::kinematics::{PenConfig, RawReadings};
use maobi_shared::pen_io::*;
use proptest::prelude::*;

#[path = "common/format_1.rs"]
mod format_1;
use format_1::{crc32_here, image_of, payload_v1, ConfigV1, DriveV1};

/// A builder's format-1 configuration: every field away from the reference pen's, so that
/// a field read into the wrong place shows.
fn builders_v1() -> ConfigV1 {
    ConfigV1 {
        pen: PenConfig {
            upper_arm_mm: 140.5,
            forearm_mm: 128.25,
            stylus_mm: 42.0,
            base_mm: [3.5, -175.0, 104.0],
            counts_per_rev: [4096, 2000, 48],
            ratio: [12.5, 11.0, 9.75],
            encoder_sign: [1, -1, 1],
            torque_constant: [0.0231, 0.0244, 0.0198],
            max_current: [1.5, 1.25, 0.75],
            motor_sign: [-1, 1, -1],
            joint_min: [-0.9, -0.25, -2.5],
            joint_max: [0.95, 1.55, -0.2],
            gimbal_rad_per_code: [0.0015, -0.0016, 0.00155],
            gimbal_sign: [-1, 1, 1],
            inkwell_joints: [0.1, 0.25, -1.1],
            inkwell_gimbal: [0.05, -0.1, 0.2],
        },
        drive: [
            DriveV1 {
                pwm_hz: 25_000,
                deadband: 0.04,
                max_duty: 0.95,
                zero: 0,
            },
            DriveV1 {
                pwm_hz: 31_250,
                deadband: 0.07,
                max_duty: 0.6,
                zero: 1,
            },
            DriveV1 {
                pwm_hz: 100_000,
                deadband: 0.0,
                max_duty: 0.3,
                zero: 0,
            },
        ],
        limits: DeviceLimits {
            peak_n: 3.0,
            continuous_n: 0.8,
            thermal_time_s: 2.5,
            max_step_n: 0.15,
            ramp_in_s: 0.4,
            ramp_out_s: 0.05,
            damping_ns_per_m: 1.5,
        },
        calibration: Some(RawReadings {
            encoders: [1234, -77_000, 5_000_000_000],
            gimbal: [2048, 1900, -3],
        }),
    }
}

fn zero_policy(index: u32) -> ZeroPolicy {
    match index {
        0 => ZeroPolicy::Coast,
        1 => ZeroPolicy::Brake,
        _ => panic!("format 1 had two zero policies"),
    }
}

/// The migrated configuration of `old`, field by field.
fn check_kept(old: &ConfigV1, new: &DeviceConfig) {
    assert_eq!(new.pen, old.pen);
    for (j, (n, o)) in new.drive.iter().zip(&old.drive).enumerate() {
        assert_eq!(n.pwm_hz, o.pwm_hz, "drive[{j}]");
        assert_eq!(n.deadband.to_bits(), o.deadband.to_bits(), "drive[{j}]");
        assert_eq!(n.max_duty.to_bits(), o.max_duty.to_bits(), "drive[{j}]");
        assert_eq!(n.zero, zero_policy(o.zero), "drive[{j}]");
        // Not in format 1: not given.
        assert_eq!(n.winding_mohm, 0, "drive[{j}]");
    }
    assert_eq!(new.power.supply_v, 0.0);
    assert_eq!(new.power.driver_current_a, 0.0);
    assert_eq!(new.limits, old.limits);
    assert_eq!(new.calibration, old.calibration);
}

fn migrated(img: &[u8]) -> DeviceConfig {
    match load(img) {
        Ok(Loaded::Migrated { from: 1, config }) => config,
        other => panic!("not migrated from format 1: {other:?}"),
    }
}

// ---------------------------------------------------------------------------------------
// Migration

#[test]
fn the_hand_written_layout_is_formats_1s_header_and_crc() {
    // The CRC here is the crate's (the standard check value, and the same on an image).
    assert_eq!(crc32_here(b"123456789"), 0xCBF4_3926);
    let img = image_of(1, &payload_v1(&builders_v1()));
    assert_eq!(&img[..6], b"MBCF\x01\x00");
    let n = img.len() - 4;
    assert_eq!(
        maobi_shared::protocol::crc32(&img[..n]).to_le_bytes(),
        img[n..]
    );
    assert!(img.len() - IMAGE_HEADER_LEN - 4 <= FORMAT_1_PAYLOAD_MAX);
}

#[test]
fn a_format_1_image_is_migrated_with_everything_it_has() {
    let old = builders_v1();
    let img = image_of(1, &payload_v1(&old));
    let cfg = migrated(&img);
    check_kept(&old, &cfg);
    // What it has is valid; the whole is not, by name, until the builder gives the rest.
    assert_eq!(cfg.validate_migrated(), Ok(()));
    let err = cfg.validate().unwrap_err();
    assert_eq!(err.field.as_str(), "drive[0].winding_mohm");
    // `decode` reads this format only: what the pen reads back after a save.
    assert_eq!(
        decode(&img),
        Err(ConfigError::UnsupportedVersion { found: 1 })
    );
    // A flash page larger than the image: what follows is ignored, as for format 2.
    for fill in [0xFFu8, 0x00, 0x5A] {
        let mut page = img.clone();
        page.resize(512, fill);
        assert_eq!(migrated(&page), cfg);
    }
}

#[test]
fn a_migrated_configuration_gives_kinematics_but_no_force() {
    let old = builders_v1();
    let loaded = load(&image_of(1, &payload_v1(&old)));
    let state = ConfigState::of_loaded(&loaded);
    assert_eq!(state, ConfigState::Migrated { from: 1 });
    assert!(!state.allows_forces());
    let said = state.to_string();
    for part in [
        "configuration migrated from format 1",
        "set the motors' winding resistance, supply voltage and driver rating",
        "maobi device config set",
        "to enable force",
    ] {
        assert!(said.contains(part), "{part}: {said}");
    }
    let cfg = *loaded.as_ref().unwrap().config();
    // Zeros stored (absolute sensors): calibrated, still no force.
    let r = Readiness::of(&state, Some(&cfg), ZeroHold::Stored);
    assert_eq!(
        r,
        Readiness {
            allows_forces: false,
            not_calibrated: false
        }
    );
    // Incremental encoders: the stored zeros are from another power-on; a Calibrate since
    // counts, and still gives no force.
    let r = Readiness::of(&state, Some(&cfg), ZeroHold::SincePowerOn(None));
    assert!(!r.allows_forces && r.not_calibrated);
    let r = Readiness::of(&state, Some(&cfg), ZeroHold::SincePowerOn(cfg.calibration));
    assert!(!r.allows_forces && !r.not_calibrated);
    // Not even a configuration that happens to validate gets force in this state.
    let mut whole = cfg;
    complete(&mut whole);
    assert_eq!(whole.validate(), Ok(()));
    assert!(!Readiness::of(&state, Some(&whole), ZeroHold::Stored).allows_forces);
    // Without a calibration in the image: not calibrated either.
    let mut uncal = old;
    uncal.calibration = None;
    let cfg = migrated(&image_of(1, &payload_v1(&uncal)));
    check_kept(&uncal, &cfg);
    let r = Readiness::of(&state, Some(&cfg), ZeroHold::Stored);
    assert!(!r.allows_forces && r.not_calibrated);
}

/// What the builder gives: each winding's resistance, the supply, the driver's rating, and
/// each duty clamp within that rating.
fn complete(cfg: &mut DeviceConfig) {
    cfg.power = PowerConfig::DEFAULT;
    for d in &mut cfg.drive {
        d.winding_mohm = 2200;
        d.max_duty = d.max_duty.min(0.2);
    }
    for j in 0..3 {
        cfg.pen.max_current[j] = cfg.pen.max_current[j].min(cfg.stall_current_a(j));
    }
}

#[test]
fn completed_and_saved_it_is_a_format_2_image_with_force() {
    let old = builders_v1();
    let mut cfg = migrated(&image_of(1, &payload_v1(&old)));
    // Saved as it is: refused by name (the pen answers `SetConfig` the same way).
    let mut buf = [0u8; CONFIG_IMAGE_MAX];
    assert!(matches!(
        encode(&cfg, &mut buf),
        Err(ConfigError::Invalid(f)) if f.field.as_str() == "drive[0].winding_mohm"
    ));
    complete(&mut cfg);
    let n = encode(&cfg, &mut buf).unwrap();
    assert_eq!(&buf[4..6], &CONFIG_FORMAT_VERSION.to_le_bytes());
    assert_eq!(CONFIG_FORMAT_VERSION, 2);
    let loaded = load(&buf[..n]);
    assert_eq!(loaded, Ok(Loaded::Current(cfg)));
    assert_eq!(decode(&buf[..n]), Ok(cfg));
    let state = ConfigState::of_loaded(&loaded);
    assert_eq!(state, ConfigState::Valid);
    assert!(Readiness::of(&state, Some(&cfg), ZeroHold::Stored).allows_forces);
    // The pen's geometry, limits and calibration came through.
    assert_eq!(cfg.pen.upper_arm_mm, old.pen.upper_arm_mm);
    assert_eq!(cfg.limits, old.limits);
    assert_eq!(cfg.calibration, old.calibration);
}

#[test]
fn a_format_1_value_out_of_range_is_named() {
    type Spoil = fn(&mut ConfigV1);
    let cases: [(Spoil, &str); 5] = [
        (|c| c.pen.ratio[1] = 0.0, "pen.ratio"),
        (|c| c.pen.encoder_sign[2] = 0, "pen.encoder_sign"),
        (|c| c.drive[2].pwm_hz = 1000, "drive[2].pwm_hz"),
        (|c| c.drive[1].max_duty = 1.5, "drive[1].max_duty"),
        (|c| c.limits.peak_n = f32::NAN, "limits.peak_n"),
    ];
    for (spoil, field) in cases {
        let mut c = builders_v1();
        spoil(&mut c);
        let loaded = load(&image_of(1, &payload_v1(&c)));
        match &loaded {
            Err(ConfigError::Invalid(f)) => assert_eq!(f.field.as_str(), field),
            other => panic!("{field}: {other:?}"),
        }
        assert!(matches!(
            ConfigState::of_loaded(&loaded),
            ConfigState::Corrupt(ConfigError::Invalid(_))
        ));
    }
}

#[test]
fn a_format_1_payload_that_does_not_parse_is_undecodable() {
    let p = payload_v1(&builders_v1());
    // A byte left over; a payload cut short (with a CRC that matches); a zero policy
    // format 1 did not have; format 2's payload under format 1's number.
    let mut longer = p.clone();
    longer.push(0);
    let mut bad_policy = builders_v1();
    bad_policy.drive[0].zero = 2;
    let mut buf = [0u8; 512];
    let v2 = postcard::to_slice(&DeviceConfig::DEFAULT, &mut buf).unwrap();
    for (name, payload) in [
        ("a byte over", longer),
        ("cut short", p[..p.len() - 3].to_vec()),
        ("zero policy 2", payload_v1(&bad_policy)),
        ("format 2's payload", v2.to_vec()),
    ] {
        assert_eq!(
            load(&image_of(1, &payload)),
            Err(ConfigError::Undecodable),
            "{name}"
        );
    }
}

#[test]
fn the_longest_format_1_payload_is_the_bound() {
    let mut c = builders_v1();
    c.pen.counts_per_rev = [u32::MAX; 3];
    for d in &mut c.drive {
        d.pwm_hz = u32::MAX;
    }
    c.calibration = Some(RawReadings {
        encoders: [i64::MIN; 3],
        gimbal: [i32::MIN; 3],
    });
    let p = payload_v1(&c);
    assert_eq!(p.len(), FORMAT_1_PAYLOAD_MAX);
    // Parsed (and refused for its values, not its length); a length field beyond the bound
    // is refused before anything else.
    assert!(matches!(
        load(&image_of(1, &p)),
        Err(ConfigError::Invalid(_))
    ));
    let mut img = image_of(1, &payload_v1(&builders_v1()));
    let over = FORMAT_1_PAYLOAD_MAX as u16 + 1;
    img[6..8].copy_from_slice(&over.to_le_bytes());
    assert_eq!(load(&img), Err(ConfigError::BadLength { len: over }));
}

// ---------------------------------------------------------------------------------------
// Damage, as `pen_io.rs` does to format 2

#[test]
fn every_single_bit_flip_of_a_format_1_image_is_detected() {
    let img = image_of(1, &payload_v1(&builders_v1()));
    let mut kinds = std::collections::BTreeMap::new();
    for byte in 0..img.len() {
        for bit in 0..8 {
            let mut bad = img.clone();
            bad[byte] ^= 1 << bit;
            let err = load(&bad).expect_err("a flipped bit must be detected");
            let kind = match err {
                ConfigError::BadMagic => "magic",
                ConfigError::UnsupportedVersion { .. } => "version",
                ConfigError::BadLength { .. } => "length",
                ConfigError::Truncated => "truncated",
                ConfigError::CrcMismatch { .. } => "crc",
                other => panic!("byte {byte} bit {bit}: unexpected {other:?}"),
            };
            *kinds.entry(kind).or_insert(0) += 1;
        }
    }
    println!(
        "single-bit flips of a {}-byte format-1 image: {kinds:?}",
        img.len()
    );
    assert_eq!(kinds["magic"], 32);
    // No single flip of 1 is 2: every one is a version this firmware does not read.
    assert_eq!(kinds["version"], 16);
}

#[test]
fn every_truncation_of_a_format_1_image_is_detected() {
    let img = image_of(1, &payload_v1(&builders_v1()));
    for len in 0..img.len() {
        let cut = &img[..len];
        assert_eq!(load(cut), Err(ConfigError::Truncated), "cut to {len}");
        for fill in [0xFFu8, 0x00] {
            let mut page = cut.to_vec();
            page.resize(512, fill);
            let err = load(&page).expect_err("a cut image must be detected");
            if len >= IMAGE_HEADER_LEN {
                assert_eq!(
                    err,
                    ConfigError::Truncated,
                    "cut to {len}, filled {fill:#x}"
                );
            } else if len == 0 && fill == 0xFF {
                assert_eq!(err, ConfigError::Erased);
            } else {
                assert!(
                    matches!(
                        err,
                        ConfigError::BadMagic
                            | ConfigError::Truncated
                            | ConfigError::BadLength { .. }
                    ),
                    "cut to {len}, filled {fill:#x}: {err:?}"
                );
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4000))]

    /// Any payload under format 1's header with a matching CRC: never a panic, and what
    /// loads is a migrated configuration whose kept values are valid and whose force stays
    /// off.
    #[test]
    fn any_format_1_payload_loads_safely(payload in proptest::collection::vec(any::<u8>(), 0..=FORMAT_1_PAYLOAD_MAX)) {
        let loaded = load(&image_of(1, &payload));
        if let Ok(l) = &loaded {
            let from_1 = matches!(l, Loaded::Migrated { from: 1, .. });
            prop_assert!(from_1);
            prop_assert_eq!(l.config().validate_migrated(), Ok(()));
            prop_assert!(l.config().validate().is_err());
        }
        let state = ConfigState::of_loaded(&loaded);
        prop_assert!(!state.allows_forces());
    }

    /// A real format-1 image with bytes changed anywhere (CRC left as it was): never a
    /// panic, never in force.
    #[test]
    fn a_damaged_format_1_image_never_panics(
        at in 0usize..256, value in any::<u8>(), cut in 0usize..300
    ) {
        let mut img = image_of(1, &payload_v1(&builders_v1()));
        if let Some(b) = img.get_mut(at) {
            *b = value;
        }
        img.truncate(cut);
        let loaded = load(&img);
        prop_assert!(!ConfigState::of_loaded(&loaded).allows_forces());
    }
}

#[test]
fn the_reference_limits_are_formats_1s_too() {
    // The reference configuration's parts format 1 carried read back through it.
    let c = DeviceConfig::DEFAULT;
    let old = ConfigV1 {
        pen: c.pen,
        drive: c.drive.map(|d| DriveV1 {
            pwm_hz: d.pwm_hz,
            deadband: d.deadband,
            max_duty: d.max_duty,
            zero: 0,
        }),
        limits: PHANTOM_OMNI,
        calibration: None,
    };
    check_kept(&old, &migrated(&image_of(1, &payload_v1(&old))));
}
