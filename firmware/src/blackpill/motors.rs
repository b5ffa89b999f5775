//! Three DC motors through TB6612FNG-class H-bridges (two carriers: A drives motors 1 and 2,
//! B drives motor 3): one PWM per channel on TIM1 (25 kHz by default, above hearing), two
//! direction inputs per channel (IN1/IN2: forward, reverse, short brake, coast), one
//! standby pin per carrier (low = every output off, high impedance).
//!
//! A tick's torques become motor commands through the pen's torque constants and ratios
//! (`Pen::motor_commands`, clamped to full current) and then the bridge's inputs through
//! the channel's [`DriveConfig`] (deadband, duty clamp, brake or coast at zero:
//! `DriveConfig::output`, tested on the host).
//!
//! [`motors_off`] writes the registers directly (no driver object, no lock), so the fault
//! paths (panic, HardFault, the supervisor) can call it from any context, at once.
//!
//! A debugger's halt (a breakpoint, `probe-rs` attaching or flashing with forces on) stops
//! the core with every pin as it was: standby high, the direction inputs as they were.
//! What TIM1's PWM does meanwhile is set by [`configure_debug_halt`]: it keeps running at
//! the duty last commanded, which the channel's `max_duty` caps, so that a halt can never
//! hold a motor at full duty. Why not stop TIM1 in the halt (`DBG_TIM1_STOP`): see there.

use core::sync::atomic::{AtomicBool, Ordering};

use embassy_stm32::gpio::Output;
use embassy_stm32::pac;
use embassy_stm32::peripherals::TIM1;
use embassy_stm32::timer::simple_pwm::SimplePwm;
use embassy_stm32::timer::Channel;
use maobi_shared::kinematics::Pen;
use maobi_shared::pen_io::{DeviceConfig, Direction, DriveConfig, DriveOutput};
use maobi_shared::{Fx, Scalar};

use super::pins;
use crate::board::Motors;

/// The motors are being driven (cleared by [`motors_off`] from any context).
static MOTORS_ON: AtomicBool = AtomicBool::new(false);

/// All bridges off now: standby low on both carriers, every direction input low (coast),
/// every duty zero. Callable from any context, also before the board is set up (the writes
/// then go to unclocked peripherals and change nothing, which is the reset state: off).
pub fn motors_off() {
    MOTORS_ON.store(false, Ordering::SeqCst);
    for pin in pins::STBY.iter().chain(pins::DIR.iter().flatten()) {
        pin.set_low();
    }
    for ch in 0..3 {
        pac::TIM1.ccr(ch).write(|w| w.set_ccr(0));
    }
}

/// What TIM1, the only timer with motor outputs, does while a debugger halts the core: it
/// runs on (`DBG_TIM1_STOP` cleared), each channel at the duty last commanded. Called once
/// TIM1 is set up.
///
/// Why not stop it. `DBGMCU_APB2_FZ.DBG_TIM1_STOP` is, in ST's register description for
/// the F4 (the SVD, as stm32-metapac carries it), "TIM1 counter stopped when core is
/// halted": a stopped counter. What the outputs then do is not settled for the F411: the
/// newer reference manuals (the G4's RM0440 and other families') say that for safety the
/// outputs of a timer stopped by the debug halt are disabled as if `MOE` were reset, and
/// then `OSSI` chooses between the idle level (`OISx`) and release to the GPIO; that
/// sentence could not be found in RM0383 (the F411's), whose TIM1 "Debug mode" paragraph,
/// as far as it could be read here, says only that the counter continues or stops with
/// `DBG_TIMx_STOP`, and the chip has not been watched on a scope. If the outputs are only
/// frozen, a halt that falls inside a pulse (at duty d, with probability d) holds that
/// channel high: 100% duty for as long as the halt lasts, past the `max_duty` that keeps a
/// stalled motor's current under the driver's rating (`pen_io`'s power check). Running
/// on, the PWM stays at the commanded duty, never above `max_duty`: the behaviour that
/// cannot drive a motor at full duty whichever reading of the manual holds. The motors
/// then hold the last torque while halted (as the direction and standby pins hold theirs);
/// resume with the hand on the pen, or halt with forces off.
///
/// `OSSI` is set, with every `OISx` at its reset value (low), so that anything that does
/// clear `MOE` (a break input, should one be wired) drives the PWM inputs low, where the
/// TB6612 brakes (its low sides on: no current from the supply), rather than releasing them
/// to float.
pub fn configure_debug_halt() {
    pac::DBGMCU.apb2fzr().modify(|w| w.set_tim1(false));
    pac::TIM1.cr2().modify(|w| {
        for ch in 0..3 {
            w.set_ois(ch, false);
        }
    });
    pac::TIM1
        .bdtr()
        .modify(|w| w.set_ossi(pac::timer::vals::Ossi::IDLE_LEVEL));
}

/// The pen's three motor channels.
pub struct PenMotors {
    pub(super) pwm: SimplePwm<'static, TIM1>,
    /// IN1, IN2 of each channel.
    pub(super) dir: [[Output<'static>; 2]; 3],
    /// Standby of carrier A (motors 1, 2) and B (motor 3).
    pub(super) stby: [Output<'static>; 2],
    /// Torque to command (`None`: no valid configuration; the motors stay off).
    pub(super) pen: Option<Pen<Fx>>,
    pub(super) drive: [DriveConfig; 3],
    /// TIM1's period in counts at the configured PWM frequency.
    pub(super) period: u16,
    pub(super) applied: [Fx; 3],
}

impl PenMotors {
    /// Standby high on both carriers (once after anything turned the motors off).
    fn wake(&mut self) {
        if !MOTORS_ON.swap(true, Ordering::SeqCst) {
            for s in &mut self.stby {
                s.set_high();
            }
        }
    }

    fn set_channel(&mut self, ch: usize, out: DriveOutput) {
        let [in1, in2] = &mut self.dir[ch];
        // TB6612: IN1 high / IN2 low forward, low / high reverse, both high short brake,
        // both low stop (coast). During PWM's off phase the bridge brakes (slow decay).
        let (a, b) = match (out.brake, out.duty, out.direction) {
            (true, _, _) => (true, true),
            (false, 0, _) => (false, false),
            (false, _, Direction::Forward) => (true, false),
            (false, _, Direction::Reverse) => (false, true),
        };
        in1.set_level(a.into());
        in2.set_level(b.into());
        let channel = [Channel::Ch1, Channel::Ch2, Channel::Ch3][ch];
        self.pwm
            .channel(channel)
            .set_duty_cycle(u32::from(out.duty));
    }
}

impl Motors for PenMotors {
    fn command(&mut self, torque_nm: [Fx; 3]) {
        let Some(pen) = &self.pen else {
            self.disable();
            return;
        };
        let commands = pen.motor_commands(&torque_nm);
        for (ch, c) in commands.into_iter().enumerate() {
            let out = self.drive[ch].output(c, self.period);
            self.set_channel(ch, out);
        }
        self.wake();
        self.applied = torque_nm;
    }

    fn configure(&mut self, cfg: &DeviceConfig) {
        motors_off();
        self.pen = Pen::new(cfg.pen).ok();
        self.drive = cfg.drive;
        // One timer drives all three channels: the first channel's frequency sets it.
        self.pwm
            .set_frequency(embassy_stm32::time::Hertz(cfg.drive[0].pwm_hz));
        self.period = u16::try_from(self.pwm.max_duty_cycle()).unwrap_or(u16::MAX);
    }

    fn disable(&mut self) {
        motors_off();
        self.applied = [Fx::ZERO; 3];
    }

    fn applied(&self) -> [Fx; 3] {
        if MOTORS_ON.load(Ordering::SeqCst) {
            self.applied
        } else {
            [Fx::ZERO; 3]
        }
    }
}
