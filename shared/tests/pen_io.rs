//! The physical pen's board logic, on the host: H-bridge duty from a motor command, the gimbal
//! sensors' filter, encoder unwrapping, and the stored configuration's image (every bit flip
//! and every truncation of a real image is caught).

use maobi_shared::force::PHANTOM_OMNI;
use maobi_shared::kinematics::{EncoderUnwrap, PenConfig, RawReadings};
use maobi_shared::pen_io::*;
use maobi_shared::protocol::crc32;
use maobi_shared::{Fx, Scalar};

const PERIOD: u16 = 4000; // 100 MHz timer, 25 kHz PWM

fn drive(zero: ZeroPolicy) -> DriveConfig {
    DriveConfig {
        pwm_hz: 25_000,
        deadband: 0.05,
        max_duty: 0.9,
        zero,
        winding_mohm: 2200,
    }
}

// ---------------------------------------------------------------------------------------
// Drive

#[test]
fn duty_spans_deadband_to_clamp() {
    let d = drive(ZeroPolicy::Coast);
    // The smallest command above zero gets the deadband's duty, full command the clamp.
    let tiny = d.output(2.0 * ZERO_COMMAND, PERIOD);
    assert_eq!(tiny.duty, 200 + 1); // 0.05 * 4000, plus 0.0002 * 0.85 * 4000 = 0.68 -> 1
    assert_eq!(tiny.direction, Direction::Forward);
    assert!(!tiny.brake);
    assert_eq!(d.output(1.0f32, PERIOD).duty, 3600);
    // Half command: 0.05 + 0.5 * 0.85 = 0.475 of the period.
    assert_eq!(d.output(0.5f64, PERIOD).duty, 1900);
    assert_eq!(d.output(-0.5f64, PERIOD).duty, 1900);
    assert_eq!(d.output(-0.5f64, PERIOD).direction, Direction::Reverse);
    // Beyond full command: clamped, never above max duty.
    for c in [1.0001f32, 2.0, 1e30, -1e30, f32::MAX, -f32::MAX] {
        let o = d.output(c, PERIOD);
        assert_eq!(o.duty, 3600, "{c}");
        assert_eq!(
            o.direction,
            if c > 0.0 {
                Direction::Forward
            } else {
                Direction::Reverse
            }
        );
    }
}

#[test]
fn duty_is_monotonic_and_bounded_over_the_whole_range() {
    for zero in [ZeroPolicy::Coast, ZeroPolicy::Brake] {
        let d = drive(zero);
        let max_counts = (f32::from(PERIOD) * d.max_duty) as u16;
        let mut last = 0;
        for k in 0..=20_000 {
            let c = k as f64 / 20_000.0;
            let pos = d.output(c, PERIOD);
            let neg = d.output(-c, PERIOD);
            assert_eq!(pos.duty, neg.duty, "symmetric at {c}");
            assert!(pos.duty <= max_counts && pos.duty <= PERIOD);
            assert!(pos.duty >= last, "monotonic at {c}");
            if c >= f64::from(ZERO_COMMAND) {
                assert!(pos.duty >= 200, "at least the deadband at {c}");
                assert_eq!(pos.direction, Direction::Forward);
                assert_eq!(neg.direction, Direction::Reverse);
                assert!(!pos.brake && !neg.brake);
            }
            last = pos.duty;
        }
    }
}

#[test]
fn zero_and_non_finite_commands_brake_or_coast() {
    for zero in [ZeroPolicy::Coast, ZeroPolicy::Brake] {
        let d = drive(zero);
        let expect = DriveOutput {
            duty: 0,
            direction: Direction::Forward,
            brake: zero == ZeroPolicy::Brake,
        };
        for c in [
            0.0f32,
            -0.0,
            ZERO_COMMAND * 0.99,
            -ZERO_COMMAND * 0.99,
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
        ] {
            assert_eq!(d.output(c, PERIOD), expect, "{c} under {zero:?}");
        }
        assert_eq!(d.output(f64::NAN, PERIOD), expect);
        assert_eq!(d.output(Fx::ZERO, PERIOD), expect);
        assert_eq!(d.zero_output(), expect);
    }
}

#[test]
fn fixed_point_commands_agree_with_float() {
    let d = DriveConfig::DEFAULT;
    for k in -1000..=1000 {
        let c = k as f64 / 1000.0;
        assert_eq!(
            d.output(Fx::from_f64(c), PERIOD),
            d.output(c, PERIOD),
            "{c}"
        );
    }
    // Fx saturates at its extremes: still clamped.
    assert_eq!(d.output(Fx::from_bits(i64::MAX), PERIOD).duty, 800);
    assert_eq!(d.output(Fx::from_bits(i64::MIN), PERIOD).duty, 800);
}

#[test]
fn a_bad_drive_config_still_never_exceeds_the_period() {
    for (deadband, max_duty) in [
        (0.0, 7.0),
        (2.0, 3.0),
        (f32::NAN, 0.9),
        (0.1, f32::NAN),
        (-1.0, f32::INFINITY),
    ] {
        let d = DriveConfig {
            deadband,
            max_duty,
            ..DriveConfig::DEFAULT
        };
        assert!(d.validate().is_err());
        for c in [-1.0f32, -0.3, 0.3, 1.0] {
            for period in [0, 1, 100, PERIOD, u16::MAX] {
                assert!(d.output(c, period).duty <= period);
            }
        }
    }
}

#[test]
fn drive_config_validation_and_period() {
    assert_eq!(DriveConfig::DEFAULT.validate(), Ok(()));
    let bad = |f: fn(&mut DriveConfig)| {
        let mut d = DriveConfig::DEFAULT;
        f(&mut d);
        d.validate().unwrap_err().name
    };
    assert_eq!(bad(|d| d.pwm_hz = 19_999), "pwm_hz");
    assert_eq!(bad(|d| d.pwm_hz = 100_001), "pwm_hz");
    assert_eq!(bad(|d| d.deadband = -0.01), "deadband");
    assert_eq!(bad(|d| d.deadband = 0.51), "deadband");
    assert_eq!(bad(|d| d.max_duty = 1.01), "max_duty");
    assert_eq!(bad(|d| d.max_duty = 0.06), "max_duty"); // not 0.05 above the deadband
    assert_eq!(bad(|d| d.winding_mohm = 0), "winding_mohm");
    assert_eq!(bad(|d| d.winding_mohm = 99), "winding_mohm");
    assert_eq!(DriveConfig::DEFAULT.winding_ohm(), 2.2);
    assert_eq!(DriveConfig::DEFAULT.period_counts(100_000_000), Some(4000));
    let fast = DriveConfig {
        pwm_hz: 100_000,
        ..DriveConfig::DEFAULT
    };
    assert_eq!(fast.period_counts(8_000_000), None); // 80 counts: too coarse
    let slow = DriveConfig {
        pwm_hz: 20_000,
        ..DriveConfig::DEFAULT
    };
    assert_eq!(slow.period_counts(2_000_000_000), None); // 100,000 counts: not 16-bit
    let zero = DriveConfig {
        pwm_hz: 0,
        ..DriveConfig::DEFAULT
    };
    assert_eq!(zero.period_counts(100_000_000), None);
}

// ---------------------------------------------------------------------------------------
// ADC filter

#[test]
fn filter_starts_at_the_first_reading_and_holds_a_constant() {
    for v in [0u16, 1, 2048, 4095, u16::MAX] {
        let mut f = AdcFilter::new();
        for _ in 0..100 {
            assert_eq!(f.update(v), v);
        }
    }
}

#[test]
fn filter_rejects_single_sample_spikes_of_any_size() {
    let mut f = AdcFilter::new();
    for _ in 0..50 {
        f.update(2000);
    }
    for spike in [0u16, 4095, u16::MAX, 2001] {
        for _ in 0..5 {
            assert_eq!(f.update(spike), 2000, "spike {spike}");
            assert_eq!(f.update(2000), 2000);
            assert_eq!(f.update(2000), 2000);
        }
    }
}

#[test]
fn filter_step_response_is_the_documented_one() {
    let (from, to) = (1000u16, 3000u16);
    let mut f = AdcFilter::new();
    for _ in 0..10 {
        f.update(from);
    }
    let mut out = Vec::new();
    for _ in 0..200 {
        out.push(f.update(to));
    }
    // The median holds the first sample of the step back.
    assert_eq!(out[0], from);
    let step = f64::from(to - from);
    for (n, &y) in out.iter().enumerate().skip(1) {
        let samples_in = n + 1;
        let ideal = f64::from(from) + step * (1.0 - (7.0f64 / 8.0).powi(samples_in as i32 - 1));
        assert!(
            (f64::from(y) - ideal).abs() <= 1.0,
            "sample {samples_in}: {y} vs {ideal:.1}"
        );
        assert!(y >= out[n - 1], "monotonic");
    }
    let covered = |n: usize| f64::from(out[n - 1] - from) / step;
    assert!(
        covered(9) >= 0.63 && covered(8) < 0.63,
        "63% after 9 samples"
    );
    assert!(covered(24) >= 0.95 && covered(23) < 0.95, "95% after 24");
    assert!(covered(36) >= 0.99 && covered(35) < 0.99, "99% after 36");
    // It settles on the input exactly, both ways.
    assert_eq!(*out.last().unwrap(), to);
    for _ in 0..200 {
        f.update(from);
    }
    assert_eq!(f.output(), from);
}

#[test]
fn filter_extremes_do_not_overflow() {
    let mut f = AdcFilter::new();
    f.update(0);
    for _ in 0..300 {
        f.update(u16::MAX);
    }
    assert_eq!(f.output(), u16::MAX);
    for _ in 0..300 {
        f.update(0);
    }
    assert_eq!(f.output(), 0);
    // Alternating extremes: the median follows the majority, the output stays in range.
    let mut seed = 0x1234_5678u32;
    for _ in 0..100_000 {
        seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        let v = (seed >> 16) as u16;
        let y = f.update(if seed & 1 == 0 { v } else { u16::MAX - v });
        let _ = y; // any u16 is in range; the point is no overflow panic in debug builds
    }
    f.reset();
    assert_eq!(f.update(77), 77);
}

// ---------------------------------------------------------------------------------------
// Encoder unwrapping

#[test]
fn encoder_unwraps_both_ways_across_zero() {
    let mut e = EncoderUnwrap::default();
    assert_eq!(e.update(65_530), 65_530);
    assert_eq!(e.update(5), 65_541); // +11 across 65535 -> 0
    assert_eq!(e.update(65_530), 65_530); // -11 back
    let mut e = EncoderUnwrap::default();
    e.update(3);
    assert_eq!(e.update(65_533), -3); // -6 across 0 -> 65535
    assert_eq!(e.update(0), 0);
    // Many turns one way, then back: exact.
    let mut raw = 0u16;
    for _ in 0..10 * 65_536 / 1000 {
        raw = raw.wrapping_add(1000);
        e.update(raw);
    }
    assert_eq!(e.total(), 655 * 1000);
    for _ in 0..655 {
        raw = raw.wrapping_sub(1000);
        e.update(raw);
    }
    assert_eq!(e.total(), 0);
}

#[test]
fn encoder_half_range_limit() {
    // Up to 32767 counts either way between reads is followed; 32768 reads as backwards.
    let mut e = EncoderUnwrap::default();
    e.update(0);
    assert_eq!(e.update(32_767), 32_767);
    assert_eq!(e.update(0), 0);
    assert_eq!(e.update(0u16.wrapping_sub(32_767)), -32_767);
    let mut e = EncoderUnwrap::default();
    e.update(0);
    assert_eq!(e.update(32_768), -32_768);
}

// ---------------------------------------------------------------------------------------
// Configuration image

fn calibrated() -> DeviceConfig {
    let mut c = DeviceConfig::DEFAULT;
    c.drive[2].zero = ZeroPolicy::Brake;
    c.drive[1].deadband = 0.07;
    c.calibration = Some(RawReadings {
        encoders: [1234, -77_000, 5],
        gimbal: [2048, 1900, 2200],
    });
    c
}

fn image(cfg: &DeviceConfig) -> Vec<u8> {
    let mut buf = vec![0u8; CONFIG_IMAGE_MAX];
    let n = encode(cfg, &mut buf).unwrap();
    buf.truncate(n);
    buf
}

/// An image of arbitrary payload bytes with a correct header and CRC: how an invalid
/// configuration (which `encode` refuses) or a future version would look.
fn forged(version: u16, payload: &[u8]) -> Vec<u8> {
    let mut v = CONFIG_MAGIC.to_vec();
    v.extend(version.to_le_bytes());
    v.extend((payload.len() as u16).to_le_bytes());
    v.extend(payload);
    let crc = crc32(&v);
    v.extend(crc.to_le_bytes());
    v
}

#[test]
fn image_round_trips_and_ignores_what_follows() {
    for cfg in [DeviceConfig::DEFAULT, calibrated()] {
        let img = image(&cfg);
        assert!(img.len() <= CONFIG_IMAGE_MAX);
        assert_eq!(&img[..4], b"MBCF");
        assert_eq!(decode(&img), Ok(cfg));
        // A flash page is larger than the image: erased or zeroed bytes after it are ignored.
        for fill in [0xFFu8, 0x00, 0x5A] {
            let mut page = img.clone();
            page.resize(1024, fill);
            assert_eq!(decode(&page), Ok(cfg));
        }
    }
    println!(
        "image: default {} bytes, calibrated {} bytes, at most {CONFIG_IMAGE_MAX}",
        image(&DeviceConfig::DEFAULT).len(),
        image(&calibrated()).len()
    );
}

#[test]
fn longest_payload_is_the_bound() {
    let mut c = calibrated();
    c.pen.counts_per_rev = [u32::MAX; 3];
    for d in &mut c.drive {
        d.pwm_hz = u32::MAX;
        d.winding_mohm = u16::MAX;
    }
    c.calibration = Some(RawReadings {
        encoders: [i64::MIN; 3],
        gimbal: [i32::MIN; 3],
    });
    let mut buf = [0u8; 1024];
    let n = postcard::to_slice(&c, &mut buf).unwrap().len();
    assert_eq!(n, CONFIG_PAYLOAD_MAX);
    // (Such a config does not validate, so `encode` refuses it; the bound still holds for
    // every config that does.)
    assert!(matches!(encode(&c, &mut buf), Err(ConfigError::Invalid(_))));
}

#[test]
fn every_single_bit_flip_is_detected() {
    let img = image(&calibrated());
    let mut kinds = std::collections::BTreeMap::new();
    for byte in 0..img.len() {
        for bit in 0..8 {
            let mut bad = img.clone();
            bad[byte] ^= 1 << bit;
            let err = decode(&bad).expect_err("a flipped bit must be detected");
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
    println!("single-bit flips of a {}-byte image: {kinds:?}", img.len());
    assert_eq!(kinds["magic"], 32);
    assert_eq!(kinds["version"], 16);
}

#[test]
fn every_truncation_is_detected_and_so_is_every_blank_tail() {
    let img = image(&calibrated());
    for len in 0..img.len() {
        let cut = &img[..len];
        assert_eq!(decode(cut), Err(ConfigError::Truncated), "cut to {len}");
        // The same cut in a page: the rest erased (flash) or zero (QEMU's RAM).
        for fill in [0xFFu8, 0x00] {
            let mut page = cut.to_vec();
            page.resize(512, fill);
            let err = decode(&page).expect_err("a cut image must be detected");
            if len >= IMAGE_HEADER_LEN {
                assert_eq!(
                    err,
                    ConfigError::Truncated,
                    "cut to {len}, filled {fill:#x}"
                );
            } else if len == 0 && fill == 0xFF {
                assert_eq!(err, ConfigError::Erased);
            } else {
                // Cut inside the header: whatever the header now looks like.
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

#[test]
fn erased_flash_is_missing_not_corrupt() {
    for len in [1usize, 8, 300, 4096] {
        assert_eq!(decode(&vec![0xFF; len]), Err(ConfigError::Erased));
    }
    assert_eq!(decode(&[]), Err(ConfigError::Truncated));
    assert_eq!(decode(&[0u8; 512]), Err(ConfigError::BadMagic));
    let state = ConfigState::of(&decode(&[0xFF; 512]));
    assert_eq!(state, ConfigState::Missing);
    assert!(!state.allows_forces());
}

#[test]
fn another_version_is_unsupported() {
    let mut buf = [0u8; 512];
    let payload = postcard::to_slice(&calibrated(), &mut buf)
        .unwrap()
        .to_vec();
    assert_eq!(
        decode(&forged(CONFIG_FORMAT_VERSION, &payload)),
        Ok(calibrated())
    );
    for v in [0u16, CONFIG_FORMAT_VERSION + 1, 0xFFFF, 0x0100] {
        assert_eq!(
            decode(&forged(v, &payload)),
            Err(ConfigError::UnsupportedVersion { found: v })
        );
    }
}

#[test]
fn length_beyond_the_bound_and_undecodable_payloads() {
    let mut img = image(&calibrated());
    img[6..8].copy_from_slice(&((CONFIG_PAYLOAD_MAX + 1) as u16).to_le_bytes());
    assert_eq!(
        decode(&img),
        Err(ConfigError::BadLength {
            len: CONFIG_PAYLOAD_MAX as u16 + 1
        })
    );
    // Intact images whose payload is not a config: too short, or bytes left over.
    let mut buf = [0u8; 512];
    let payload = postcard::to_slice(&calibrated(), &mut buf)
        .unwrap()
        .to_vec();
    let v = CONFIG_FORMAT_VERSION;
    assert_eq!(
        decode(&forged(v, &payload[..payload.len() - 1])),
        Err(ConfigError::Undecodable)
    );
    let mut longer = payload.clone();
    longer.push(0);
    assert_eq!(decode(&forged(v, &longer)), Err(ConfigError::Undecodable));
    // An empty payload reads as a write that stopped at the length field.
    assert_eq!(decode(&forged(v, &[])), Err(ConfigError::Truncated));
    assert_eq!(decode(&forged(1, &[])), Err(ConfigError::Truncated));
}

#[test]
fn invalid_values_are_named_and_never_written() {
    type Spoil = fn(&mut DeviceConfig);
    let cases: [(Spoil, &str); 10] = [
        (|c| c.pen.upper_arm_mm = f32::NAN, "pen.upper_arm_mm"),
        (|c| c.pen.ratio[2] = 0.0, "pen.ratio"),
        (|c| c.pen.motor_sign[0] = 0, "pen.motor_sign"),
        (|c| c.drive[2].pwm_hz = 1000, "drive[2].pwm_hz"),
        (|c| c.drive[0].max_duty = 1.5, "drive[0].max_duty"),
        (|c| c.drive[1].winding_mohm = 0, "drive[1].winding_mohm"),
        // In range for the bridge, but over the driver's rating for this motor.
        (|c| c.drive[1].winding_mohm = 500, "drive[1].max_duty"),
        (|c| c.power.supply_v = 14.0, "power.supply_v"),
        (
            |c| c.power.driver_current_a = -1.0,
            "power.driver_current_a",
        ),
        (|c| c.limits.continuous_n = 9.0, "limits.continuous_n"),
    ];
    for (spoil, field) in cases {
        let mut c = calibrated();
        spoil(&mut c);
        let e = c.validate().unwrap_err();
        assert_eq!(e.field.as_str(), field);
        // encode refuses it: nothing would be written.
        let mut buf = [0u8; CONFIG_IMAGE_MAX];
        let named = |r: Option<&ConfigError>| matches!(r, Some(ConfigError::Invalid(f)) if f.field == e.field);
        assert!(named(encode(&c, &mut buf).err().as_ref()), "{field}");
        assert_eq!(buf, [0u8; CONFIG_IMAGE_MAX], "nothing written");
        // An intact image holding it (written by something else) is rejected on load.
        let mut pbuf = [0u8; 512];
        let payload = postcard::to_slice(&c, &mut pbuf).unwrap().to_vec();
        let loaded = decode(&forged(CONFIG_FORMAT_VERSION, &payload));
        assert!(named(loaded.as_ref().err()), "{field}: {loaded:?}");
        let state = ConfigState::of(&loaded);
        assert!(matches!(
            state,
            ConfigState::Corrupt(ConfigError::Invalid(_))
        ));
        assert!(!state.allows_forces());
    }
    assert!(calibrated().ready_for_forces());
    assert!(!DeviceConfig::DEFAULT.ready_for_forces()); // not calibrated

    // The reference linkage, with full command at the current its duty clamp allows.
    let stall = [0, 1, 2].map(|j| DeviceConfig::DEFAULT.stall_current_a(j));
    assert_eq!(
        DeviceConfig::DEFAULT.pen,
        PenConfig {
            max_current: stall,
            ..PenConfig::OMNI_LIKE
        }
    );
    assert!((stall[0] - 12.0 * 0.2 / 2.2).abs() < 1e-6, "{stall:?}");
    assert_eq!(DeviceConfig::DEFAULT.limits, PHANTOM_OMNI);
}

#[test]
fn encode_never_overruns_its_buffer() {
    let full = image(&calibrated());
    for len in 0..full.len() {
        let mut buf = vec![0u8; len];
        assert_eq!(
            encode(&calibrated(), &mut buf),
            Err(ConfigError::BufferTooSmall),
            "{len}"
        );
    }
}

#[test]
fn random_bytes_never_panic_and_never_decode() {
    let mut seed = 0x9E37_79B9u32;
    let mut img = image(&calibrated());
    for round in 0..20_000 {
        seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        let i = (seed >> 8) as usize % img.len();
        img[i] = (seed >> 24) as u8;
        // Corrupted more and more: must never come back as a different valid config.
        if let Ok(c) = decode(&img) {
            assert_eq!(c, calibrated(), "round {round}");
        }
    }
}

#[test]
fn config_state_says_what_the_handshake_says() {
    assert_eq!(ConfigState::of(&Ok(calibrated())), ConfigState::Valid);
    assert!(ConfigState::Valid.allows_forces());
    assert!(ConfigState::NotApplicable.allows_forces());
    assert!(!ConfigState::Corrupt(ConfigError::Truncated).allows_forces());
    assert_eq!(
        ConfigState::Corrupt(ConfigError::UnsupportedVersion { found: 7 }).to_string(),
        "corrupt: configuration format version 7, this firmware reads 2 (and migrates 1)"
    );
}

// ---------------------------------------------------------------------------------------
// No force before calibration

#[test]
fn forces_wait_for_zeros_that_hold() {
    let zeros = RawReadings {
        encoders: [120, -4, 9],
        gimbal: [2000, 2100, 2048],
    };
    let mut calibrated = DeviceConfig::DEFAULT;
    calibrated.calibration = Some(zeros);
    let uncalibrated = DeviceConfig::DEFAULT;
    let mut invalid = calibrated;
    invalid.limits.peak_n = -1.0;
    let earlier = RawReadings {
        encoders: [0, 0, 0],
        ..zeros
    };
    let ready = Readiness {
        allows_forces: true,
        not_calibrated: false,
    };
    let not = Readiness {
        allows_forces: false,
        not_calibrated: true,
    };
    let valid = ConfigState::Valid;
    let cases: [(&str, ConfigState, Option<DeviceConfig>, ZeroHold, Readiness); 12] = [
        // The virtual pen without a store: calibrated by construction.
        (
            "virtual",
            ConfigState::NotApplicable,
            None,
            ZeroHold::Stored,
            ready,
        ),
        ("missing", ConfigState::Missing, None, ZeroHold::Stored, not),
        (
            "corrupt",
            ConfigState::Corrupt(ConfigError::Truncated),
            None,
            ZeroHold::Stored,
            not,
        ),
        (
            "uncalibrated",
            valid.clone(),
            Some(uncalibrated),
            ZeroHold::Stored,
            not,
        ),
        (
            "calibrated",
            valid.clone(),
            Some(calibrated),
            ZeroHold::Stored,
            ready,
        ),
        // A state that says valid with nothing in force, or a value out of range: no.
        (
            "valid, no config",
            valid.clone(),
            None,
            ZeroHold::Stored,
            not,
        ),
        (
            "invalid",
            valid.clone(),
            Some(invalid),
            ZeroHold::Stored,
            not,
        ),
        // Incremental encoders: stored zeros from an earlier power-on do not count.
        (
            "stored, not since power-on",
            valid.clone(),
            Some(calibrated),
            ZeroHold::SincePowerOn(None),
            not,
        ),
        (
            "zeroed since power-on",
            valid.clone(),
            Some(calibrated),
            ZeroHold::SincePowerOn(Some(zeros)),
            ready,
        ),
        // A configuration written since, carrying other zeros (copied from an earlier
        // session), or none.
        (
            "other zeros written since",
            valid.clone(),
            Some(calibrated),
            ZeroHold::SincePowerOn(Some(earlier)),
            not,
        ),
        (
            "uncalibrated written since",
            valid.clone(),
            Some(uncalibrated),
            ZeroHold::SincePowerOn(Some(zeros)),
            not,
        ),
        (
            "missing, zeroed",
            ConfigState::Missing,
            None,
            ZeroHold::SincePowerOn(Some(zeros)),
            not,
        ),
    ];
    for (name, state, cfg, hold, want) in cases {
        assert_eq!(Readiness::of(&state, cfg.as_ref(), hold), want, "{name}");
    }
}

// ---------------------------------------------------------------------------------------
// Motor current bounded by the configuration

#[test]
fn the_duty_limit_comes_from_resistance_supply_and_rating() {
    let p = PowerConfig::DEFAULT;
    assert_eq!((p.supply_v, p.driver_current_a), (12.0, 1.2));
    // 1.2 A x 2.2 Ohm / 12 V.
    let limit = p.duty_limit(2.2);
    assert!((limit - 0.22).abs() < 1e-6, "{limit}");
    // At the limit a stalled motor draws the rating, no more.
    assert!((p.stall_current_a(limit, 2.2) - 1.2).abs() < 1e-5);
    // Half the supply, twice the duty; a winding that cannot draw the rating: no limit.
    let six = PowerConfig { supply_v: 6.0, ..p };
    assert!((six.duty_limit(2.2) - 0.44).abs() < 1e-6);
    assert_eq!(p.duty_limit(20.0), 1.0);
    // A stronger driver allows more.
    let strong = PowerConfig {
        driver_current_a: 2.4,
        ..p
    };
    assert!((strong.duty_limit(2.2) - 0.44).abs() < 1e-6);
}

#[test]
fn a_configuration_that_would_overload_the_driver_is_refused() {
    let ok = DeviceConfig::DEFAULT;
    assert_eq!(ok.validate(), Ok(()));
    assert_eq!(ok.over_current(), None);
    // The old default: 95% of 12 V into a 2.2 Ohm winding is about 5.2 A at stall.
    let mut c = DeviceConfig::DEFAULT;
    c.drive[2].max_duty = 0.95;
    let over = c.over_current().expect("over the rating");
    assert_eq!(over.channel, 2);
    assert!((over.stall_a - 12.0 * 0.95 / 2.2).abs() < 1e-4, "{over:?}");
    assert_eq!(over.rating_a, 1.2);
    assert!((over.duty_limit - 0.22).abs() < 1e-6);
    let e = c.validate().unwrap_err();
    assert_eq!(e.field.as_str(), "drive[2].max_duty");
    assert_eq!((e.value, e.max), (0.95, over.duty_limit));
    let said = over.to_string();
    for part in [
        "drive[2].max_duty = 0.95",
        "5.18 A",
        "1.2 A",
        "at most 0.22",
    ] {
        assert!(said.contains(part), "{part}: {said}");
    }
    // The suggested duty passes.
    c.drive[2].max_duty = 0.22;
    assert_eq!(c.validate(), Ok(()));
    // Just over it does not; a lower supply makes room again.
    c.drive[2].max_duty = 0.221;
    assert!(c.validate().is_err());
    c.power.supply_v = 9.0;
    assert_eq!(c.validate(), Ok(()));
    // A non-finite duty or supply never passes as within the rating.
    let mut nan = DeviceConfig::DEFAULT;
    nan.drive[0].max_duty = f32::NAN;
    assert!(nan.over_current().is_some());
    // encode refuses to write it, decode refuses to load it.
    let mut c = DeviceConfig::DEFAULT;
    c.drive[0].winding_mohm = 1000;
    let mut buf = [0u8; CONFIG_IMAGE_MAX];
    assert!(
        matches!(encode(&c, &mut buf), Err(ConfigError::Invalid(f)) if f.field.as_str() == "drive[0].max_duty")
    );
    let mut pbuf = [0u8; 512];
    let payload = postcard::to_slice(&c, &mut pbuf).unwrap().to_vec();
    assert!(matches!(
        decode(&forged(CONFIG_FORMAT_VERSION, &payload)),
        Err(ConfigError::Invalid(f)) if f.field.as_str() == "drive[0].max_duty"
    ));
}

// A format-1 image (migrated): `shared/tests/config_format_1.rs`.

// ---------------------------------------------------------------------------------------
// The flash accelerator (FLASH_ACR)

#[test]
fn the_flash_caches_restart_with_the_latency_kept() {
    use maobi_shared::pen_io::flash_acr::*;
    // What embassy-stm32's clock setup leaves at 96 MHz: three wait states, nothing else.
    let after_rcc = 3;
    assert!(!is_accelerated(after_rcc));
    assert_eq!(
        cache_restart(after_rcc),
        [3, 3 | ICRST | DCRST, 3, 3 | PRFTEN | ICEN | DCEN]
    );
    assert_eq!(cache_restart(after_rcc)[3], 0x703);
    // From any state (every latency, every combination of the five bits: at boot, after a
    // flash write with the caches on, after a reset left held).
    for latency in 0..=15u32 {
        for bits in 0..32u32 {
            let acr = latency | bits << 8;
            let steps = cache_restart(acr);
            let mut before = acr;
            for (k, &v) in steps.iter().enumerate() {
                assert_eq!(v & LATENCY_MASK, latency, "{acr:#x} step {k}");
                // A cache is reset only while it is off, and it was off before.
                if v & ICRST != 0 {
                    assert_eq!((v | before) & ICEN, 0, "{acr:#x} step {k}");
                }
                if v & DCRST != 0 {
                    assert_eq!((v | before) & DCEN, 0, "{acr:#x} step {k}");
                }
                before = v;
            }
            // Both caches were reset on the way.
            assert!(steps.iter().any(|v| v & (ICRST | DCRST) == ICRST | DCRST));
            assert!(is_accelerated(steps[3]), "{acr:#x}");
            assert_eq!(steps[3], latency | ACCELERATED);
        }
    }
}
