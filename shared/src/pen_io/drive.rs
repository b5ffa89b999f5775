//! From a motor command to an H-bridge's inputs.
//!
//! DRV8833 / TB6612-class drivers take, per motor, a PWM duty, a direction and a choice
//! between *brake* (both low-side switches on: the winding is shorted, slow decay) and *coast*
//! (all switches off: the winding floats). [`DriveConfig::output`] maps a command in [-1, 1]
//! (a fraction of full current, what [`crate::kinematics::Pen::motor_commands`] returns) to
//! those three, as timer counts:
//!
//! * `|c| < ZERO_COMMAND` (and any non-finite command): duty 0, brake or coast per
//!   [`ZeroPolicy`].
//! * otherwise `duty = period * (deadband + |c| (max_duty - deadband))`, rounded, and never
//!   above `floor(period * max_duty)` nor `period`. The deadband lifts the smallest command
//!   out of the bridge's and the motor's dead zone (a duty below it moves no current through
//!   the winding's inductance and the brushes' friction), so that small forces are felt at
//!   all; the clamp keeps the duty, and so the current, within what the motor and supply take.
//!   The clamp is bounded in turn by the motor's winding resistance, the supply and the
//!   driver's rating ([`super::PowerConfig::duty_limit`], checked by
//!   [`super::DeviceConfig::validate`]): at stall the winding carries `supply * duty / R`.
//! * the sign of `c` is the direction (`c > 0`: [`Direction::Forward`]).

use serde::{Deserialize, Serialize};

use crate::force::LimitError;
use crate::scalar::Scalar;

/// Commands smaller than this (fraction of full current) are zero: brake or coast per the
/// policy. A ten-thousandth of full scale is below one duty count of any period
/// [`DriveConfig::period_counts`] accepts once the deadband is added, and well below what a
/// hand feels; it keeps fixed-point dust from switching the bridge on at the deadband duty.
pub const ZERO_COMMAND: f32 = 1.0e-4;

/// What a channel does when its command is zero.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum ZeroPolicy {
    /// The winding floats: the motor turns freely. Right for a haptic pen: zero force must
    /// feel like no motor at all.
    Coast,
    /// The winding is shorted: back-EMF brakes the motor (felt as viscous drag).
    Brake,
}

/// Which way the bridge drives current.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Direction {
    /// Positive command.
    Forward,
    /// Negative command.
    Reverse,
}

/// One H-bridge channel's settings. Defaults: [`DriveConfig::DEFAULT`].
#[derive(Copy, Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DriveConfig {
    /// PWM frequency (Hz): at least 20 kHz (inaudible), at most 100 kHz (the TB6612's limit;
    /// the DRV8833 takes 250 kHz but switching losses grow with it).
    pub pwm_hz: u32,
    /// Duty (fraction of the period) the smallest non-zero command gets: the bridge's and
    /// the motor's dead zone. 0 ..= 0.5.
    pub deadband: f32,
    /// Largest duty (fraction of the period) any command gets; above `deadband`, at most 1,
    /// and at most what keeps this motor's stall current within the driver's rating
    /// ([`super::PowerConfig::duty_limit`]).
    pub max_duty: f32,
    /// What a zero command does.
    pub zero: ZeroPolicy,
    /// The motor's winding (terminal) resistance in milliohms: at stall, with no back-EMF,
    /// it alone sets the current a duty drives (`supply * duty / R`). At least 100 (0.1 Ohm),
    /// at most 65,535 (65.5 Ohm). Milliohms in a `u16` rather than ohms in an `f32`: the
    /// channel's settings keep their size (the firmware holds several copies in RAM).
    pub winding_mohm: u16,
}

/// The bridge's inputs for one channel for one tick.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct DriveOutput {
    /// Timer compare value, `0 ..= period`.
    pub duty: u16,
    pub direction: Direction,
    /// Zero command under [`ZeroPolicy::Brake`]: short the winding (duty is 0).
    pub brake: bool,
}

impl DriveConfig {
    /// 25 kHz, 4% deadband, coast at zero, a 2.2 Ohm winding (a 12 V motor that stalls at
    /// about 5.5 A, such as the bill of materials' Pololu 37D) and a duty clamp of 20%,
    /// which keeps that motor's stall current at 12 V within a TB6612's continuous rating
    /// ([`super::PowerConfig::DEFAULT`]). The deadband is a starting point; the bring-up
    /// procedure measures it (the smallest nudge that turns the motor).
    pub const DEFAULT: DriveConfig = DriveConfig {
        pwm_hz: 25_000,
        deadband: 0.04,
        max_duty: 0.2,
        zero: ZeroPolicy::Coast,
        winding_mohm: 2200,
    };

    /// Smallest winding resistance accepted (milliohms).
    pub const MIN_WINDING_MOHM: u16 = 100;

    /// Smallest PWM frequency accepted (Hz): above hearing.
    pub const MIN_PWM_HZ: u32 = 20_000;
    /// Largest PWM frequency accepted (Hz).
    pub const MAX_PWM_HZ: u32 = 100_000;
    /// Fewest timer counts per PWM period accepted by [`Self::period_counts`]: below this the
    /// duty's resolution (1%) would be coarser than the forces it renders.
    pub const MIN_PERIOD_COUNTS: u32 = 100;

    pub fn validate(&self) -> Result<(), LimitError> {
        let check = |name, v: f32, lo: f32, hi: f32| {
            if v.is_finite() && v >= lo && v <= hi {
                Ok(())
            } else {
                Err(LimitError {
                    name,
                    value: v,
                    min: lo,
                    max: hi,
                })
            }
        };
        check(
            "pwm_hz",
            self.pwm_hz as f32,
            Self::MIN_PWM_HZ as f32,
            Self::MAX_PWM_HZ as f32,
        )?;
        check("deadband", self.deadband, 0.0, 0.5)?;
        // Some range must be left between the deadband and the clamp, or every command would
        // get the same duty.
        check("max_duty", self.max_duty, self.deadband + 0.05, 1.0)?;
        check(
            "winding_mohm",
            f32::from(self.winding_mohm),
            f32::from(Self::MIN_WINDING_MOHM),
            f32::from(u16::MAX),
        )
    }

    /// The winding resistance in ohms.
    pub const fn winding_ohm(&self) -> f32 {
        // `as`, not `f32::from`: a const fn (the reference configuration's currents are
        // computed from it); every u16 is exact in an f32.
        self.winding_mohm as f32 / 1000.0
    }

    /// Timer counts per PWM period for a timer counting at `timer_hz`: `timer_hz / pwm_hz`,
    /// if that fits the 16-bit compare registers and gives at least
    /// [`Self::MIN_PERIOD_COUNTS`] steps.
    pub fn period_counts(&self, timer_hz: u32) -> Option<u16> {
        if self.pwm_hz == 0 {
            return None;
        }
        let n = timer_hz / self.pwm_hz;
        if n < Self::MIN_PERIOD_COUNTS {
            return None;
        }
        u16::try_from(n).ok()
    }

    /// The bridge's inputs for `command` (fraction of full current, clamped to [-1, 1]) with
    /// a PWM period of `period` timer counts. Never panics; the duty never exceeds
    /// `floor(period * max_duty)` or `period`, whatever the command and even for a config
    /// that would not validate.
    pub fn output<S: Scalar>(&self, command: S, period: u16) -> DriveOutput {
        let c = command.to_f32();
        if !c.is_finite() || c.abs() < ZERO_COMMAND {
            // A non-finite command means the computation upstream went wrong: no force is
            // the only safe answer (clamping +inf would be full force).
            return self.zero_output();
        }
        let direction = if c > 0.0 {
            Direction::Forward
        } else {
            Direction::Reverse
        };
        let p = f32::from(period);
        // Float-to-int `as` saturates (NaN gives 0), so a bad config cannot overflow here.
        let max_counts = ((p * self.max_duty) as u32).min(u32::from(period));
        let fraction = self.deadband + c.abs().min(1.0) * (self.max_duty - self.deadband);
        let duty = ((fraction * p + 0.5) as u32).min(max_counts);
        DriveOutput {
            duty: duty as u16, // <= period, a u16
            direction,
            brake: false,
        }
    }

    /// The output for a zero command.
    pub fn zero_output(&self) -> DriveOutput {
        DriveOutput {
            duty: 0,
            direction: Direction::Forward,
            brake: self.zero == ZeroPolicy::Brake,
        }
    }
}

impl Default for DriveConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}
