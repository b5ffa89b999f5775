//! Format 1 of the configuration image, written out by hand from its layout (the commit
//! before format 2, e77facc^), for the tests that need a real format-1 image: the shared
//! crate's (`shared/tests/config_format_1.rs`) and the QEMU board's (`hil/tests/config.rs`,
//! through `#[path]`). Nothing here comes from the crate under test: postcard's encoding
//! and the CRC are written out.
//!
//! The payload, in order: `PenConfig` (unchanged since), three drive channels of
//! `pwm_hz: u32`, `deadband: f32`, `max_duty: f32`, `zero: ZeroPolicy`, then `DeviceLimits`
//! (unchanged), then `calibration: Option<RawReadings>` (unchanged). postcard writes an
//! `f32` as 4 bytes little-endian, an `i8` as its byte, a `u32` as a LEB128 varint, an
//! `i32` / `i64` as the varint of its zigzag, an enum's variant index and an `Option`'s tag
//! as a varint, arrays without a length.

#![allow(dead_code)] // each test uses its part

use maobi_shared::force::DeviceLimits;
use maobi_shared::kinematics::{PenConfig, RawReadings};

/// A format-1 drive channel.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct DriveV1 {
    pub pwm_hz: u32,
    pub deadband: f32,
    pub max_duty: f32,
    /// `ZeroPolicy`'s variant index: 0 coast, 1 brake.
    pub zero: u32,
}

/// A format-1 configuration.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct ConfigV1 {
    pub pen: PenConfig,
    pub drive: [DriveV1; 3],
    pub limits: DeviceLimits,
    pub calibration: Option<RawReadings>,
}

fn varint(out: &mut Vec<u8>, mut v: u64) {
    loop {
        let byte = (v & 0x7F) as u8;
        v >>= 7;
        if v == 0 {
            out.push(byte);
            return;
        }
        out.push(byte | 0x80);
    }
}

fn zigzag(v: i64) -> u64 {
    ((v << 1) ^ (v >> 63)) as u64
}

fn f32s(out: &mut Vec<u8>, vs: &[f32]) {
    for v in vs {
        out.extend(v.to_le_bytes());
    }
}

fn i8s(out: &mut Vec<u8>, vs: &[i8]) {
    out.extend(vs.iter().map(|&v| v as u8));
}

/// Format 1's payload for `c`.
pub fn payload_v1(c: &ConfigV1) -> Vec<u8> {
    let mut out = Vec::new();
    let p = &c.pen;
    f32s(&mut out, &[p.upper_arm_mm, p.forearm_mm, p.stylus_mm]);
    f32s(&mut out, &p.base_mm);
    for n in p.counts_per_rev {
        varint(&mut out, u64::from(n));
    }
    f32s(&mut out, &p.ratio);
    i8s(&mut out, &p.encoder_sign);
    f32s(&mut out, &p.torque_constant);
    f32s(&mut out, &p.max_current);
    i8s(&mut out, &p.motor_sign);
    f32s(&mut out, &p.joint_min);
    f32s(&mut out, &p.joint_max);
    f32s(&mut out, &p.gimbal_rad_per_code);
    i8s(&mut out, &p.gimbal_sign);
    f32s(&mut out, &p.inkwell_joints);
    f32s(&mut out, &p.inkwell_gimbal);
    for d in &c.drive {
        varint(&mut out, u64::from(d.pwm_hz));
        f32s(&mut out, &[d.deadband, d.max_duty]);
        varint(&mut out, u64::from(d.zero));
    }
    let l = &c.limits;
    f32s(
        &mut out,
        &[
            l.peak_n,
            l.continuous_n,
            l.thermal_time_s,
            l.max_step_n,
            l.ramp_in_s,
            l.ramp_out_s,
            l.damping_ns_per_m,
        ],
    );
    match &c.calibration {
        None => out.push(0),
        Some(r) => {
            out.push(1);
            for e in r.encoders {
                varint(&mut out, zigzag(e));
            }
            for g in r.gimbal {
                varint(&mut out, zigzag(i64::from(g)));
            }
        }
    }
    out
}

/// CRC-32/ISO-HDLC, bit by bit: written here, not taken from the crate under test.
pub fn crc32_here(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// An image: `MBCF`, the version, the payload's length, the payload, the CRC of all that.
pub fn image_of(version: u16, payload: &[u8]) -> Vec<u8> {
    let mut v = b"MBCF".to_vec();
    v.extend(version.to_le_bytes());
    v.extend((payload.len() as u16).to_le_bytes());
    v.extend(payload);
    let crc = crc32_here(&v);
    v.extend(crc.to_le_bytes());
    v
}
