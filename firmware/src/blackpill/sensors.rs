//! The pen's sensors on the Black Pill: three quadrature encoders on timers in encoder mode,
//! three gimbal angle sensors (potentiometers or analog hall sensors) on ADC1, and the two
//! stylus buttons. Read once per force tick, in the tick ([`JointSensors::read`]); the
//! application unwraps, filters, debounces and calibrates ([`crate::app::SensorPen`]).
//!
//! What one read costs: three counter reads (a few cycles each) and three ADC conversions
//! of 84 + 12 ADC cycles each; but embassy's `blocking_read` switches the ADC off and on
//! around every conversion and waits out its power-up each time, so each read pays that
//! wait on top of its conversion (docs/figures.md has the total). One scan of the three
//! channels with the ADC left on would save the waits.

use embassy_stm32::adc::{Adc, AnyAdcChannel, SampleTime};
use embassy_stm32::gpio::Input;
use embassy_stm32::peripherals::{ADC1, TIM2, TIM3, TIM4};
use embassy_stm32::timer::qei::Qei;

use crate::board::{JointReading, JointSensors};

/// Sample time of each gimbal conversion: 84 ADC cycles (3.5 us at 24 MHz) lets a
/// potentiometer of up to about 10 kOhm charge the sample capacitor to 12 bits (RM0383 /
/// AN2834's source-impedance table).
const GIMBAL_SAMPLE: SampleTime = SampleTime::CYCLES84;

pub struct PenSensors {
    pub(super) enc1: Qei<'static, TIM2>,
    pub(super) enc2: Qei<'static, TIM3>,
    pub(super) enc3: Qei<'static, TIM4>,
    pub(super) adc: Adc<'static, ADC1>,
    pub(super) gimbal: [AnyAdcChannel<'static, ADC1>; 3],
    /// Primary and secondary stylus buttons, to ground with the pull-ups on: low = pressed.
    pub(super) buttons: [Input<'static>; 2],
}

impl JointSensors for PenSensors {
    fn read(&mut self) -> JointReading {
        let encoders = [
            i32::from(self.enc1.count()),
            i32::from(self.enc2.count()),
            i32::from(self.enc3.count()),
        ];
        let [g1, g2, g3] = &mut self.gimbal;
        let gimbal = [
            i32::from(self.adc.blocking_read(g1, GIMBAL_SAMPLE)),
            i32::from(self.adc.blocking_read(g2, GIMBAL_SAMPLE)),
            i32::from(self.adc.blocking_read(g3, GIMBAL_SAMPLE)),
        ];
        let buttons = u8::from(self.buttons[0].is_low()) | u8::from(self.buttons[1].is_low()) << 1;
        JointReading {
            encoders,
            gimbal,
            buttons,
        }
    }
}
