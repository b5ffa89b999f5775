//! The Black Pill's pin map: every pin the pen uses, named by what it does, and the
//! peripheral each one belongs to. The board takes them here ([`take`]) and nowhere else;
//! firmware/README.md's pin table mirrors this module.
//!
//! Pins with a peripheral function (PWM, encoders, ADC, USB) are embassy's typed singletons:
//! a pin without the named timer channel or ADC input does not compile. Pins used as plain
//! GPIO are [`Gpio`] constants, because the fault paths ([`super::motors::motors_off`],
//! [`super::led_on`]) drive them through raw registers from any context, without a driver
//! object: the drivers and the fault paths then name each of them once, here.

use embassy_stm32::gpio::AnyPin;
use embassy_stm32::pac;
use embassy_stm32::peripherals::{
    ADC1, FLASH, IWDG, PA1, PA10, PA11, PA12, PA15, PA2, PA3, PA8, PA9, PB3, PB4, PB5, PB6, PB7,
    TIM1, TIM2, TIM3, TIM4, TIM9, USB_OTG_FS,
};
use embassy_stm32::{Peri, PeripheralType, Peripherals};

/// A GPIO port with pins the pen uses as plain GPIO, by embassy's number (port A is 0).
#[derive(Copy, Clone)]
pub enum Port {
    B = 1,
    C = 2,
}

/// A pin used as plain GPIO: its port and number.
#[derive(Copy, Clone)]
pub struct Gpio {
    port: Port,
    n: u8,
}

impl Gpio {
    const fn new(port: Port, n: u8) -> Self {
        Gpio { port, n }
    }

    fn block(self) -> pac::gpio::Gpio {
        match self.port {
            Port::B => pac::GPIOB,
            Port::C => pac::GPIOC,
        }
    }

    /// Drives the pin low from any context: one write to its port's BSRR, no driver (an
    /// output's level; nothing happens while the port is unclocked or the pin an input).
    pub fn set_low(self) {
        self.block()
            .bsrr()
            .write(|w| w.set_br(usize::from(self.n), true));
    }

    /// Drives the pin high from any context, as [`Self::set_low`].
    pub fn set_high(self) {
        self.block()
            .bsrr()
            .write(|w| w.set_bs(usize::from(self.n), true));
    }

    /// The pin for a driver (`Output`, `Input`).
    ///
    /// # Safety
    /// Once per pin, and only by [`take`], which consumes embassy's `Peripherals`: that
    /// pin's singleton is then gone with them, and this is the pin's only owner.
    unsafe fn take(self) -> Peri<'static, AnyPin> {
        // SAFETY: as above; `port * 16 + n` is embassy's numbering of the pin.
        unsafe { AnyPin::steal(self.port as u8 * 16 + self.n) }
    }
}

/// Standby of motor carrier A (motors 1, 2): PB10; of carrier B (motor 3): PB2, a pin with
/// no peripheral function on this chip (PA4, its earlier pin, is the chip select of the
/// Black Pill's optional SPI-flash footprint). Low = every output of the carrier off.
pub const STBY: [Gpio; 2] = [Gpio::new(Port::B, 10), Gpio::new(Port::B, 2)];
/// IN1, IN2 of motors 1 (PB12, PB13: carrier A's AIN1/AIN2), 2 (PB14, PB15: carrier A's
/// BIN1/BIN2), 3 (PB8, PB9: carrier B's AIN1/AIN2).
pub const DIR: [[Gpio; 2]; 3] = [
    [Gpio::new(Port::B, 12), Gpio::new(Port::B, 13)],
    [Gpio::new(Port::B, 14), Gpio::new(Port::B, 15)],
    [Gpio::new(Port::B, 8), Gpio::new(Port::B, 9)],
];
/// The stylus buttons, primary PB0 and secondary PB1, to ground (pull-ups on).
pub const BUTTONS: [Gpio; 2] = [Gpio::new(Port::B, 0), Gpio::new(Port::B, 1)];
/// The fault LED, PC13, lit when low (the Black Pill's blue LED).
pub const LED: Gpio = Gpio::new(Port::C, 13);

/// The three motors' bridges (TB6612FNG carriers).
pub struct MotorPins {
    /// The PWM timer: TIM1, channels 1-3.
    pub pwm_timer: Peri<'static, TIM1>,
    /// PWM of motor 1 (carrier A's PWMA): PA8, TIM1_CH1.
    pub pwm1: Peri<'static, PA8>,
    /// PWM of motor 2 (carrier A's PWMB): PA9, TIM1_CH2.
    pub pwm2: Peri<'static, PA9>,
    /// PWM of motor 3 (carrier B's PWMA): PA10, TIM1_CH3.
    pub pwm3: Peri<'static, PA10>,
    /// IN1, IN2 of each motor ([`DIR`]).
    pub dir: [[Peri<'static, AnyPin>; 2]; 3],
    /// Standby of carriers A and B ([`STBY`]).
    pub stby: [Peri<'static, AnyPin>; 2],
}

/// One quadrature encoder: its timer in encoder mode and its A and B inputs (channels 1, 2).
pub struct EncoderPins<
    T: PeripheralType + 'static,
    A: PeripheralType + 'static,
    B: PeripheralType + 'static,
> {
    pub timer: Peri<'static, T>,
    pub a: Peri<'static, A>,
    pub b: Peri<'static, B>,
}

/// The gimbal's three angle sensors (potentiometer wipers or analog hall outputs).
pub struct GimbalPins {
    /// ADC1, 12 bits.
    pub adc: Peri<'static, ADC1>,
    /// Gimbal 1: PA1, ADC1_IN1.
    pub g1: Peri<'static, PA1>,
    /// Gimbal 2: PA2, ADC1_IN2.
    pub g2: Peri<'static, PA2>,
    /// Gimbal 3: PA3, ADC1_IN3.
    pub g3: Peri<'static, PA3>,
}

/// The link: USB OTG_FS.
pub struct UsbPins {
    pub otg: Peri<'static, USB_OTG_FS>,
    /// D+: PA12.
    pub dp: Peri<'static, PA12>,
    /// D-: PA11.
    pub dm: Peri<'static, PA11>,
}

/// Every pin the pen uses, and the peripherals the board needs besides.
pub struct PenPins {
    pub motors: MotorPins,
    /// Encoder 1: TIM2, A on PA15 (TIM2_CH1), B on PB3 (TIM2_CH2).
    pub enc1: EncoderPins<TIM2, PA15, PB3>,
    /// Encoder 2: TIM3, A on PB4 (TIM3_CH1), B on PB5 (TIM3_CH2).
    pub enc2: EncoderPins<TIM3, PB4, PB5>,
    /// Encoder 3: TIM4, A on PB6 (TIM4_CH1), B on PB7 (TIM4_CH2).
    pub enc3: EncoderPins<TIM4, PB6, PB7>,
    pub gimbal: GimbalPins,
    /// The stylus buttons ([`BUTTONS`]).
    pub buttons: [Peri<'static, AnyPin>; 2],
    pub usb: UsbPins,
    /// The fault LED ([`LED`]).
    pub led: Peri<'static, AnyPin>,
    /// The force tick's timer (no pins).
    pub tick_timer: Peri<'static, TIM9>,
    /// The configuration's flash sectors.
    pub flash: Peri<'static, FLASH>,
    /// The hardware watchdog.
    pub iwdg: Peri<'static, IWDG>,
}

/// Takes the pen's pins and peripherals from embassy's, all of which it consumes: no pin
/// can be taken twice, nor elsewhere.
pub fn take(p: Peripherals) -> PenPins {
    // SAFETY: `take` runs once (embassy's `init`, the only source of `Peripherals`, runs
    // once) and consumes every singleton; each `Gpio` constant is taken once below.
    let gpio = |pin: Gpio| unsafe { pin.take() };
    PenPins {
        motors: MotorPins {
            pwm_timer: p.TIM1,
            pwm1: p.PA8,
            pwm2: p.PA9,
            pwm3: p.PA10,
            dir: DIR.map(|d| d.map(gpio)),
            stby: STBY.map(gpio),
        },
        enc1: EncoderPins {
            timer: p.TIM2,
            a: p.PA15,
            b: p.PB3,
        },
        enc2: EncoderPins {
            timer: p.TIM3,
            a: p.PB4,
            b: p.PB5,
        },
        enc3: EncoderPins {
            timer: p.TIM4,
            a: p.PB6,
            b: p.PB7,
        },
        gimbal: GimbalPins {
            adc: p.ADC1,
            g1: p.PA1,
            g2: p.PA2,
            g3: p.PA3,
        },
        buttons: BUTTONS.map(gpio),
        usb: UsbPins {
            otg: p.USB_OTG_FS,
            dp: p.PA12,
            dm: p.PA11,
        },
        led: gpio(LED),
        tick_timer: p.TIM9,
        flash: p.FLASH,
        iwdg: p.IWDG,
    }
}
