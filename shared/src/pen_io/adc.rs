//! The gimbal sensors' filter: potentiometers or hall sensors on a 12-bit ADC, sampled once
//! per force tick (1 kHz).
//!
//! Two stages, integers only:
//!
//! 1. **Median of the last three samples.** A single-sample spike (a wiper lifting off its
//!    track for a moment, a conversion hit by a motor's switching edge) never gets through,
//!    whatever its size; a real step passes with one sample of delay.
//! 2. **First-order low-pass** `y += (x - y) / 2^SHIFT` with `SHIFT` = [`AdcFilter::SHIFT`]
//!    = 3, i.e. `alpha = 1/8`, in Q16 fixed point (16 fraction bits in a `u32`). At 1 kHz its
//!    cut-off (-3 dB) is `-ln(1 - alpha) fs / (2 pi)` = **21.3 Hz**, its time constant
//!    `-1 / ln(1 - alpha)` = 7.5 samples: hand motion (below 10 Hz) passes, sensor noise and
//!    PWM pick-up (kHz) are cut.
//!
//! **Step response** from a settled value to another (both stages): the output first moves
//! on the 2nd sample after the step (the median's delay); after the step has been in for
//! `n >= 2` samples the output has covered `1 - (7/8)^(n-1)` of it: 63% after 9 samples,
//! 95% after 24, 99% after 36; it then settles on the input exactly (rounded, no offset).
//!
//! **No overflow for any `u16` input**: the state is at most `0xFFFF << 16`, which fits a
//! `u32`, and each update moves it by a fraction of the distance to the input, computed
//! on the side where the difference is non-negative.

/// Median-of-three and first-order low-pass filter of one ADC channel.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq)]
pub struct AdcFilter {
    /// The last three samples, oldest first (valid once `primed`).
    window: [u16; 3],
    /// The low-pass output in Q16.
    acc: u32,
    primed: bool,
}

impl AdcFilter {
    /// The low-pass coefficient is `1 / 2^SHIFT`.
    pub const SHIFT: u32 = 3;
    /// Its cut-off at the 1 kHz force-loop rate (Hz), `-ln(7/8) 1000 / (2 pi)`.
    pub const CUTOFF_HZ_AT_1KHZ: f32 = 21.25;
    const FRAC: u32 = 16;

    pub const fn new() -> Self {
        AdcFilter {
            window: [0; 3],
            acc: 0,
            primed: false,
        }
    }

    /// Takes one sample, returns the filtered code. The first sample after [`Self::new`] or
    /// [`Self::reset`] fills the whole window and the low-pass state: the output starts at the
    /// first reading instead of ramping up from zero.
    pub fn update(&mut self, sample: u16) -> u16 {
        if !self.primed {
            self.primed = true;
            self.window = [sample; 3];
            self.acc = u32::from(sample) << Self::FRAC;
            return sample;
        }
        let [_, b, c] = self.window;
        self.window = [b, c, sample];
        let target = u32::from(median3(b, c, sample)) << Self::FRAC;
        if target >= self.acc {
            self.acc += (target - self.acc) >> Self::SHIFT;
        } else {
            self.acc -= (self.acc - target) >> Self::SHIFT;
        }
        self.output()
    }

    /// The filtered code now (rounded to the nearest code).
    pub fn output(&self) -> u16 {
        // acc <= 0xFFFF_0000, so adding a half does not overflow and the result fits a u16.
        ((self.acc + (1 << (Self::FRAC - 1))) >> Self::FRAC) as u16
    }

    /// Forget the history: the next sample starts afresh.
    pub fn reset(&mut self) {
        *self = Self::new();
    }
}

fn median3(a: u16, b: u16, c: u16) -> u16 {
    a.max(b).min(a.min(b).max(c))
}

#[cfg(test)]
mod tests {
    use super::median3;

    #[test]
    fn median_of_every_order() {
        for (a, b, c) in [
            (1, 2, 3),
            (1, 3, 2),
            (2, 1, 3),
            (2, 3, 1),
            (3, 1, 2),
            (3, 2, 1),
        ] {
            assert_eq!(median3(a, b, c), 2);
        }
        assert_eq!(median3(5, 5, 0), 5);
        assert_eq!(median3(0, 5, 0), 0);
    }
}
