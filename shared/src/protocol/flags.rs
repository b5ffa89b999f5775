//! The flag sets the messages and the brush state carry: [`Capabilities`], [`Faults`],
//! [`Buttons`].

use core::fmt;

use serde::{Deserialize, Serialize};

/// `Debug` as `Faults(0x5: SENSOR_JUMP | LINK_SILENT)` and `Display` as `SENSOR_JUMP |
/// LINK_SILENT` for a flag set (bits without a name print in hex).
macro_rules! flag_fmt {
    ($name:ident) => {
        impl fmt::Debug for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                write!(f, "{}({:#x}: ", stringify!($name), self.bits())?;
                bitflags::parser::to_writer(self, &mut *f)?;
                f.write_str(")")
            }
        }

        impl fmt::Display for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                bitflags::parser::to_writer(self, f)
            }
        }
    };
}

// Flag sets travel as plain integers (serde-transparent), so bits a newer peer defines are
// kept, not lost.

/// What a board can do, announced in [`DeviceInfo`](super::DeviceInfo).
#[derive(Copy, Clone, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Capabilities(u32);

bitflags::bitflags! {
    impl Capabilities: u32 {
        /// Motors: the board can push back on the hand.
        const FORCE_OUTPUT = 1 << 0;
        /// The pen's pose comes from the board's own sensors.
        const REAL_SENSORS = 1 << 1;
        /// The pen's pose comes from the host as [`HostMsg::Pose`](super::HostMsg::Pose)
        /// (QEMU board, Phantom bridge).
        const VIRTUAL_PEN = 1 << 2;
        /// The sensors need [`Command::Calibrate`](super::Command::Calibrate) before forces
        /// may be enabled, after every power-on (incremental encoders: a stored calibration
        /// does not survive a reset; [`crate::pen_io::ZeroHold::SincePowerOn`]).
        const NEEDS_CALIBRATION = 1 << 3;
        /// The pen has buttons (for a virtual pen: reported in
        /// [`PoseSample::buttons`](super::PoseSample::buttons)).
        const BUTTONS = 1 << 4;
        /// The board keeps a configuration ([`HostMsg::GetConfig`](super::HostMsg::GetConfig),
        /// [`HostMsg::SetConfig`](super::HostMsg::SetConfig); its state in
        /// [`DeviceInfo::config`](super::DeviceInfo::config)) and answers the bring-up
        /// commands that came with it (protocol 3):
        /// [`Command::StreamSensors`](super::Command::StreamSensors),
        /// [`Command::NudgeMotor`](super::Command::NudgeMotor).
        const STORED_CONFIG = 1 << 5;
    }
}
flag_fmt!(Capabilities);

/// Latched faults. A fault stays set until [`Command::ClearFaults`](super::Command::ClearFaults)
/// and its cause is gone; forces stay off while any is set.
#[derive(Copy, Clone, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Faults(u16);

bitflags::bitflags! {
    impl Faults: u16 {
        /// Consecutive sensor readings (or pose samples) further apart than the pen can move
        /// ([`crate::force_loop::SENSOR_JUMP_MM`]).
        const SENSOR_JUMP = 1 << 0;
        /// A 1 ms tick did not finish in time.
        const LOOP_OVERRUN = 1 << 1;
        /// Nothing from the host for longer than the link timeout (forces faded out).
        const LINK_SILENT = 1 << 2;
        /// A parameter write was rejected.
        const PARAM_REJECTED = 1 << 3;
        /// The force loop stopped (caught by the supervisor task), or the watchdog reset
        /// the board: the force loop or thread mode stopped (the firmware feeds it only
        /// while both run).
        const WATCHDOG = 1 << 4;
        /// The sensors are not calibrated: no configuration, none calibrated, or (a pen with
        /// [`Capabilities::NEEDS_CALIBRATION`]) not since power-on. Not latched: set while it
        /// is true (forces refused with
        /// [`CommandError::ConfigNotValid`](super::CommandError::ConfigNotValid)), gone once
        /// [`Command::Calibrate`](super::Command::Calibrate) succeeds;
        /// [`Command::ClearFaults`](super::Command::ClearFaults) does not clear it.
        const NOT_CALIBRATED = 1 << 5;
        /// The force device refused or limited a command on its own: the Phantom bridge's
        /// HD library raised a device warning (force, force impulse, velocity, warm motors).
        /// Forces stay at zero, the brush restarts at rest, until cleared.
        const DEVICE_WARNING = 1 << 6;
    }
}
flag_fmt!(Faults);

/// The pen's buttons, pressed = set.
#[derive(Copy, Clone, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Buttons(u8);

bitflags::bitflags! {
    impl Buttons: u8 {
        const PRIMARY = 1 << 0;
        const SECONDARY = 1 << 1;
    }
}
flag_fmt!(Buttons);
