//! The pen's sensors on the Black Pill: three quadrature encoders on timers in encoder mode,
//! three gimbal angle sensors (potentiometers or analog hall sensors) on ADC1, and the two
//! stylus buttons. Read once per force tick, in the tick ([`JointSensors::read`]); the
//! application unwraps, filters, debounces and calibrates ([`crate::app::SensorPen`]).
//!
//! # The gimbal's ADC: one injected scan per tick
//!
//! The three gimbal channels are ADC1's injected group, converted as one scan. The ADC is
//! switched on once, at boot; each read starts the scan, reads the encoders and the buttons
//! while it converts, and then waits for its end (JEOC). embassy's `blocking_read` instead
//! switches the ADC off and on around every conversion and waits out its power-up (3 us)
//! each time: three of those waits were the single largest item of the tick's cost outside
//! the brush (docs/firmware-cost.md).
//!
//! The wait is bounded ([`SCAN_POLLS_MAX`]): a scan that does not end (an ADC left off, a
//! clock misconfigured) gives no reading for that tick, which the force loop counts as a
//! missing pose and answers with no force, rather than a tick that never ends.

use embassy_stm32::adc::{InjectedAdc, InjectedTrigger, SampleTime};
use embassy_stm32::gpio::Input;
use embassy_stm32::pac;
use embassy_stm32::peripherals::{ADC1, TIM2, TIM3, TIM4};
use embassy_stm32::timer::qei::Qei;

use crate::board::{JointReading, JointSensors};

/// Sample time of each gimbal conversion: 84 ADC cycles (3.5 us at 24 MHz) lets a
/// potentiometer of up to about 10 kOhm charge the sample capacitor to 12 bits (RM0383 /
/// AN2834's source-impedance table).
pub(super) const GIMBAL_SAMPLE: SampleTime = SampleTime::CYCLES84;

/// How many times a read polls for the scan's end before it gives up. One poll is a
/// peripheral-bus read and a branch, at least several core cycles, so this is more than
/// four times the scan's (3 x (84 + 12)) ADC cycles x 4 core cycles each: long enough for
/// any scan that runs, short enough that a scan that never ends costs a fraction of a tick.
pub const SCAN_POLLS_MAX: u32 = 4 * 3 * (84 + 12) * 4;

/// The injected group's trigger: software only (`JSWSTART`). The group is set up with
/// external triggering disabled, so the signal number is never looked at.
pub(super) struct SoftwareStart;

impl InjectedTrigger<ADC1> for SoftwareStart {
    fn signal(&self) -> u8 {
        0
    }
}

pub struct PenSensors {
    pub(super) enc1: Qei<'static, TIM2>,
    pub(super) enc2: Qei<'static, TIM3>,
    pub(super) enc3: Qei<'static, TIM4>,
    /// The gimbal's three channels as ADC1's injected group, in the order g1, g2, g3.
    pub(super) gimbal: InjectedAdc<'static, ADC1, 3>,
    /// Primary and secondary stylus buttons, to ground with the pull-ups on: low = pressed.
    pub(super) buttons: [Input<'static>; 2],
}

impl JointSensors for PenSensors {
    fn read(&mut self) -> Option<JointReading> {
        // The scan converts while the counters and the buttons are read.
        self.gimbal.start_injected_conversions();
        let encoders = [
            i32::from(self.enc1.count()),
            i32::from(self.enc2.count()),
            i32::from(self.enc3.count()),
        ];
        let buttons = u8::from(self.buttons[0].is_low()) | u8::from(self.buttons[1].is_low()) << 1;
        let mut polls = 0;
        while !pac::ADC1.sr().read().jeoc() {
            polls += 1;
            if polls >= SCAN_POLLS_MAX {
                return None;
            }
        }
        let gimbal = self.gimbal.read_injected_samples().map(i32::from);
        Some(JointReading {
            encoders,
            gimbal,
            buttons,
        })
    }
}
