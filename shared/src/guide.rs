//! Guided writing: the device leads the hand along a stroke.
//!
//! A keyframed stroke ([`crate::stroke`]) gives, every tick, the *moving point*: where the
//! ferrule should be now. The guide couples the hand to it with a gentle spring-damper,
//!
//! ```text
//! F = g(t) * clamp(k (a - x) + b (v_a - v_x), F_max)
//! ```
//!
//! with `a`, `v_a` the moving point and its velocity, `x`, `v_x` the stylus, and `g` a gain
//! that fades in when guidance starts and out when it stops, so the hand never feels a step.
//! The guide's force is added to the force model's before the [`OutputStage`], so the device's
//! clamps, step limit, ramp and fault handling apply to it as to every other force.
//!
//! # Passivity
//!
//! A spring to a *moving* anchor is meant to put energy into the hand: that is what leading
//! means. The energy comes from the anchor's motion (the stroke's playback) and, during a
//! fade-in, from the gain rising on a stretched spring. [`Guide::tick`] reports both as
//! [`GuideForce::source_mj`]: the work the anchor does on the coupling this tick,
//! `F . (a_k - a_{k-1})`, plus `dg * k |a - x|^2 / 2`, in mJ (N mm: forces in N, positions in
//! mm), in the model's scalar, so that the device's 1 kHz loop does no double-precision
//! arithmetic (the Cortex-M4F has none: each operation is a library call). The output stage's passivity observer
//! is credited with it ([`OutputStage::apply_with_source`]), so it only takes back energy the
//! sampled loop *creates*, and the passivity audit (`tests/guide.rs`) checks the same balance:
//! the energy delivered to the hand over any window never exceeds what the hand put in, plus
//! what the brush, the filters and the coupling store, plus what the moving point supplied.
//!
//! # Defaults, and why
//!
//! `k = 100 N/m`, `b = 0.1 N s/m`, `F_max = 0.8 N`, fades of 0.3 s: 1 N only at 10 mm off
//! the stroke, so a writer can always overpower it; under the Phantom Omni's continuous 0.88
//! N; and within the Colgate-Brown budget at 1 kHz on top of the force model's paper-plane
//! terms (`k T / 2 + b` = 0.15 N s/m, which with the model's 0.63 stays below the Omni's
//! assumed 1 N s/m of physical damping).
//!
//! [`OutputStage`]: crate::force::OutputStage
//! [`OutputStage::apply_with_source`]: crate::force::OutputStage::apply_with_source

use crate::force::{LimitError, TICK_S};
use crate::scalar::Scalar;
use crate::vec::Vec3;

/// The coupling's constants. Validated by [`GuideParams::validate`].
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct GuideParams {
    /// Spring to the moving point (N/m).
    pub stiffness_n_per_m: f32,
    /// Damper on the velocity difference (N s/m).
    pub damping_ns_per_m: f32,
    /// Largest guide force (N), before the device's own limits.
    pub max_force_n: f32,
    /// Time to fade in after [`Guide::start`] and out after [`Guide::stop`] (s).
    pub fade_s: f32,
}

/// Gentle guidance (see the module docs for why these numbers).
pub const DEFAULT_GUIDE: GuideParams = GuideParams {
    stiffness_n_per_m: 100.0,
    damping_ns_per_m: 0.1,
    max_force_n: 0.8,
    fade_s: 0.3,
};

impl GuideParams {
    pub fn validate(&self) -> Result<(), LimitError> {
        let check = |name, value: f32, min, max| {
            if value.is_finite() && value >= min && value <= max {
                Ok(())
            } else {
                Err(LimitError {
                    name,
                    value,
                    min,
                    max,
                })
            }
        };
        // The stiffness bound keeps k T / 2 within a Phantom-class device's damping.
        check(
            "guide_stiffness_n_per_m",
            self.stiffness_n_per_m,
            0.0,
            400.0,
        )?;
        check("guide_damping_ns_per_m", self.damping_ns_per_m, 0.0, 1.0)?;
        check("guide_max_force_n", self.max_force_n, 0.0, 3.3)?;
        check("guide_fade_s", self.fade_s, 0.0, 5.0)
    }
}

/// One tick of guidance.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct GuideForce<S> {
    /// The force on the hand (N, paper frame).
    pub force: Vec3<S>,
    /// How far the stylus is from the moving point (mm).
    pub distance_mm: S,
    /// Energy the moving point and the fade supplied this tick (mJ; may be negative).
    pub source_mj: S,
}

/// The spring-damper coupling to the moving point, with its fade.
#[derive(Clone, Debug)]
pub struct Guide<S> {
    params: GuideParams,
    /// k in N per mm (positions are in mm).
    k: S,
    b: S,
    max: S,
    /// Where the spring's force reaches `max` (mm; zero without a spring), and the energy it
    /// holds there at full gain (mJ): the kink of [`Guide::potential_mj`].
    clamp_mm: S,
    clamp_mj: S,
    fade_step: S,
    gain: S,
    on: bool,
    /// The moving point at the last tick, and the force then (for the anchor's work).
    last_anchor: Option<Vec3<S>>,
    last_force: Vec3<S>,
}

impl<S: Scalar> Guide<S> {
    pub fn new(params: GuideParams) -> Result<Self, LimitError> {
        params.validate()?;
        // Single precision, like the parameters (the pen has no double-precision hardware).
        let fade = params.fade_s;
        let (k_n_per_mm, f_max) = (params.stiffness_n_per_m * 1e-3, params.max_force_n);
        let clamp_mm = if k_n_per_mm > 0.0 {
            f_max / k_n_per_mm
        } else {
            0.0
        };
        Ok(Guide {
            params,
            k: S::from_f32(k_n_per_mm),
            b: S::from_f32(params.damping_ns_per_m),
            max: S::from_f32(params.max_force_n),
            clamp_mm: S::from_f32(clamp_mm),
            clamp_mj: S::from_f32(0.5 * k_n_per_mm * clamp_mm * clamp_mm),
            fade_step: S::from_f32(if fade > 0.0 {
                (TICK_S as f32 / fade).min(1.0)
            } else {
                1.0
            }),
            gain: S::ZERO,
            on: false,
            last_anchor: None,
            last_force: Vec3::ZERO,
        })
    }

    pub fn params(&self) -> &GuideParams {
        &self.params
    }

    /// Starts leading (fades in from the current gain).
    pub fn start(&mut self) {
        self.on = true;
    }
    /// Stops leading (fades out); the moving point should keep coming until
    /// [`Guide::active`] is false.
    pub fn stop(&mut self) {
        self.on = false;
    }
    /// Stops at once: the gain and the force are zero from the next tick (faults, link loss;
    /// the output stage's own ramp-out still smooths the command).
    pub fn cut(&mut self) {
        self.on = false;
        self.gain = S::ZERO;
        self.last_anchor = None;
        self.last_force = Vec3::ZERO;
    }
    /// Leading, or still fading out.
    pub fn active(&self) -> bool {
        self.on || self.gain > S::ZERO
    }
    pub fn gain(&self) -> S {
        self.gain
    }

    /// One tick: the moving point `anchor` and its step since the last tick `anchor_step`
    /// (mm; mm per tick is m/s), the stylus `hand` and its step `hand_step`.
    pub fn tick(
        &mut self,
        anchor: Vec3<S>,
        anchor_step: Vec3<S>,
        hand: Vec3<S>,
        hand_step: Vec3<S>,
    ) -> GuideForce<S> {
        let d = anchor - hand;
        let d2 = d.norm2();
        let distance_mm = d2.sqrt();
        // The anchor's work on the coupling over the last tick, with the force held then.
        let mut source_mj = match self.last_anchor {
            Some(_) => self.last_force.dot(anchor_step),
            None => S::ZERO,
        };
        let old = self.gain;
        self.gain = if self.on {
            (self.gain + self.fade_step).min(S::ONE)
        } else {
            (self.gain - self.fade_step).max(S::ZERO)
        };
        // A rising gain stretches the spring's energy with no work from anyone: a source.
        source_mj += (self.gain - old) * self.potential_mj(distance_mm);
        let force = if self.gain > S::ZERO {
            let raw = d.scale(self.k) + (anchor_step - hand_step).scale(self.b);
            clamp_norm(raw, self.max).scale(self.gain)
        } else {
            Vec3::ZERO
        };
        self.last_anchor = Some(anchor);
        self.last_force = force;
        GuideForce {
            force,
            distance_mm,
            source_mj,
        }
    }

    /// Energy the coupling's spring holds now (J): part of the stored energy in an audit.
    pub fn stored_energy(&self, anchor: Vec3<S>, hand: Vec3<S>) -> f64 {
        let d = (anchor - hand).norm2().sqrt();
        (self.gain * self.potential_mj(d)).to_f64() * 1e-3
    }

    /// The potential of the saturating spring at `d_mm` at full gain (mJ): `k d^2 / 2` up to
    /// the clamp at `d0 = F_max / k`, then growing by `F_max` per mm.
    fn potential_mj(&self, d_mm: S) -> S {
        if self.k <= S::ZERO {
            S::ZERO
        } else if d_mm <= self.clamp_mm {
            (self.k * d_mm * d_mm).halve()
        } else {
            self.clamp_mj + self.max * (d_mm - self.clamp_mm)
        }
    }
}

/// A guide sample as the device's force loop takes it: the moving point (mm) and whether
/// to lead.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct GuideInput<S> {
    pub anchor: Vec3<S>,
    pub on: bool,
}

/// Ticks with a new pose but no guide sample after which a stream fades out on its own,
/// holding the last point (50 ms of the pen's time: a host that stopped guiding without
/// saying so; a host that stopped sending altogether is the link watchdog's, which cuts it).
pub const GUIDE_TIMEOUT_TICKS: u32 = 50;

/// [`Guide`] fed by a stream of samples, one per tick, as the device receives them: the
/// firmware's force loop and the host's mirror of it (`maobi sim-device`, the HIL check)
/// run this same code, so the guide force is bit-identical on both.
///
/// Each tick: a sample sets the moving point (its step is the difference to the previous
/// point) and starts (`on`) or stops the guide; with no sample the point is held (step zero)
/// and after [`GUIDE_TIMEOUT_TICKS`] silent ticks the guide stops (fades out). [`Self::cut`]
/// drops it at once (faults, link loss).
///
/// The stream runs in pose time: a virtual pen's tick that got no new pose (the host fell
/// behind) calls [`Self::hold`] instead, which keeps the last force and neither fades nor
/// counts toward the timeout, so the device's guide is the host mirror's however the poses
/// were paced. (With no poses at all the link watchdog cuts the guide.)
#[derive(Clone, Debug)]
pub struct GuideStream<S> {
    guide: Guide<S>,
    anchor: Option<Vec3<S>>,
    silent: u32,
    last: Vec3<S>,
}

impl<S: Scalar> GuideStream<S> {
    pub fn new(params: GuideParams) -> Result<Self, LimitError> {
        Ok(GuideStream {
            guide: Guide::new(params)?,
            anchor: None,
            silent: 0,
            last: Vec3::ZERO,
        })
    }

    pub fn guide(&self) -> &Guide<S> {
        &self.guide
    }

    /// The moving point in force (the last sample's).
    pub fn anchor(&self) -> Option<Vec3<S>> {
        self.anchor
    }

    /// Leading or fading out.
    pub fn active(&self) -> bool {
        self.guide.active()
    }

    /// Drops the guidance at once: zero force from this tick; a later sample with `on`
    /// fades in again from zero.
    pub fn cut(&mut self) {
        self.guide.cut();
        self.anchor = None;
        self.silent = 0;
        self.last = Vec3::ZERO;
    }

    /// A tick without a new pose: the hand and the point have not moved, the last force
    /// holds (no work done, no energy supplied).
    pub fn hold(&self) -> GuideForce<S> {
        GuideForce {
            force: self.last,
            distance_mm: S::ZERO,
            source_mj: S::ZERO,
        }
    }

    /// One tick: this tick's sample, if one came, and the stylus `hand` with its step since
    /// the last tick (mm). Zero force (and no work) while the guide is idle.
    pub fn tick(
        &mut self,
        sample: Option<GuideInput<S>>,
        hand: Vec3<S>,
        hand_step: Vec3<S>,
    ) -> GuideForce<S> {
        let step = match sample {
            Some(s) => {
                self.silent = 0;
                if s.on {
                    self.guide.start();
                } else {
                    self.guide.stop();
                }
                let step = match self.anchor {
                    Some(a) => s.anchor - a,
                    None => Vec3::ZERO,
                };
                self.anchor = Some(s.anchor);
                step
            }
            None => {
                self.silent = self.silent.saturating_add(1);
                if self.silent > GUIDE_TIMEOUT_TICKS {
                    self.guide.stop();
                }
                Vec3::ZERO
            }
        };
        let f = match self.anchor {
            Some(a) if self.guide.active() => self.guide.tick(a, step, hand, hand_step),
            _ => GuideForce {
                force: Vec3::ZERO,
                distance_mm: S::ZERO,
                source_mj: S::ZERO,
            },
        };
        self.last = f.force;
        f
    }
}

/// A stroke's moving point played into a device's guide, one point per tick: each point in
/// turn (the last one lets go: `on = false`), then the point reached, held with `on = false`
/// while the guide fades out. The Phantom bridge's servo loop, the GUI's built-in device and
/// the host streaming to a device play their strokes with it.
#[derive(Clone, Debug)]
pub struct GuidePlay<P> {
    points: P,
    next: usize,
}

impl<P> GuidePlay<P> {
    /// Plays `points` (one per tick) from the next tick.
    pub fn new(points: P) -> Self {
        GuidePlay { points, next: 0 }
    }
}

impl<P> GuidePlay<P> {
    /// Stops playing: the point reached is held while the guide fades out.
    pub fn stop<S>(&mut self)
    where
        P: AsRef<[Vec3<S>]>,
    {
        self.next = self.points.as_ref().len();
    }

    /// This tick's sample for a guide now in the state `stream`; `None` once the stroke is
    /// over and the guide has faded out (the play is done).
    pub fn next_sample<S: Scalar>(&mut self, stream: &GuideStream<S>) -> Option<GuideInput<S>>
    where
        P: AsRef<[Vec3<S>]>,
    {
        self.next_sample_as(stream, |p| p)
    }

    /// [`Self::next_sample`] of a stroke held in another number type than the guide's,
    /// each point converted by `convert` as it is played (no copy of the stroke).
    pub fn next_sample_as<Q: Copy, S: Scalar>(
        &mut self,
        stream: &GuideStream<S>,
        convert: impl Fn(Q) -> Vec3<S>,
    ) -> Option<GuideInput<S>>
    where
        P: AsRef<[Q]>,
    {
        let points = self.points.as_ref();
        let k = self.next;
        if let Some(&anchor) = points.get(k) {
            self.next += 1;
            return Some(GuideInput {
                anchor: convert(anchor),
                on: k + 1 < points.len(),
            });
        }
        match stream.anchor() {
            Some(anchor) if stream.active() => Some(GuideInput { anchor, on: false }),
            _ => None,
        }
    }

    /// [`Self::next_sample`] of a play that may be absent, which ends (becomes `None`) when
    /// it is done: what a device that plays strokes into its guide calls every tick.
    pub fn next_sample_of<S: Scalar>(
        play: &mut Option<Self>,
        stream: &GuideStream<S>,
    ) -> Option<GuideInput<S>>
    where
        P: AsRef<[Vec3<S>]>,
    {
        Self::next_sample_of_as(play, stream, |p| p)
    }

    /// [`Self::next_sample_of`] with the points converted as [`Self::next_sample_as`] does.
    pub fn next_sample_of_as<Q: Copy, S: Scalar>(
        play: &mut Option<Self>,
        stream: &GuideStream<S>,
        convert: impl Fn(Q) -> Vec3<S>,
    ) -> Option<GuideInput<S>>
    where
        P: AsRef<[Q]>,
    {
        let sample = play.as_mut()?.next_sample_as(stream, convert);
        if sample.is_none() {
            *play = None;
        }
        sample
    }
}

/// Stay in the lane: a virtual fixture around a stroke's path in the paper plane. The hand
/// feels nothing while its ferrule is within `radius_mm` of the path (x-y), and outside it the
/// guide's spring-damper pulls it back toward the tube's wall, in the paper plane only.
///
/// It feeds the same [`GuideStream`] as guided writing, with the moving point put where the
/// force must come from: the hand itself inside the tube (no stretch, no relative velocity:
/// exactly zero force), else the point of the tube's wall nearest the hand, at the hand's
/// height. The path is fixed, so the wall point is a function of the hand's position: the
/// spring's potential `k (d - r)^2 / 2` is the hand's alone and the fixture passive; the
/// stream accounts the wall point's motion as a source all the same (its work over a closed
/// path is zero), and the passivity audit (`tests/guide.rs`) holds it to the guide's
/// tolerance.
///
/// `pieces` are the path's pieces (mm, x-y; a piece of one point is a dot), each a polyline:
/// no segment joins one piece to the next (the brush lifted between them). Geometry in `f64`:
/// the fixture runs on the host, which has the hand's position every tick where it runs the
/// force loop (the built-in pen, the Phantom) or supplies the poses (a virtual pen, the
/// sample riding with its pose).
#[derive(Clone, Debug, PartialEq)]
pub struct Lane<P, Q> {
    pieces: P,
    radius_mm: f64,
    on: bool,
    /// The stream has a moving point from this fixture: its first sample only places it
    /// (the stream takes a first point's step as zero, which against a moving hand would
    /// be a damping force), and the fade-in starts with the second.
    primed: bool,
    piece: core::marker::PhantomData<Q>,
}

impl<P, Q> Lane<P, Q>
where
    P: AsRef<[Q]>,
    Q: AsRef<[[f64; 2]]>,
{
    /// The fixture around `pieces` with a tube `radius_mm` wide on each side, on from the
    /// next tick.
    pub fn new(pieces: P, radius_mm: f64) -> Self {
        Lane {
            pieces,
            radius_mm: radius_mm.max(0.0),
            on: true,
            primed: false,
            piece: core::marker::PhantomData,
        }
    }

    pub fn radius_mm(&self) -> f64 {
        self.radius_mm
    }

    /// The nearest point of the path to `xy` (mm) and its distance, if the path has a point.
    pub fn nearest(&self, xy: [f64; 2]) -> Option<([f64; 2], f64)> {
        let mut best: Option<([f64; 2], f64)> = None;
        let mut consider = |p: [f64; 2]| {
            let d = libm::hypot(p[0] - xy[0], p[1] - xy[1]);
            if best.is_none_or(|(_, b)| d < b) {
                best = Some((p, d));
            }
        };
        for piece in self.pieces.as_ref() {
            let pts = piece.as_ref();
            if let [only] = pts {
                consider(*only);
            }
            for w in pts.windows(2) {
                let (a, b) = (w[0], w[1]);
                let ab = [b[0] - a[0], b[1] - a[1]];
                let len2 = ab[0] * ab[0] + ab[1] * ab[1];
                let t = if len2 > 0.0 {
                    (((xy[0] - a[0]) * ab[0] + (xy[1] - a[1]) * ab[1]) / len2).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                consider([a[0] + ab[0] * t, a[1] + ab[1] * t]);
            }
        }
        best
    }

    /// Where the guide's moving point goes for a hand at `hand` (mm): the hand itself within
    /// the tube (or with no path), else the tube's wall nearest it, at the hand's height.
    pub fn anchor(&self, hand: [f64; 3]) -> [f64; 3] {
        match self.nearest([hand[0], hand[1]]) {
            Some((p, d)) if d > self.radius_mm => {
                let f = self.radius_mm / d;
                [
                    p[0] + (hand[0] - p[0]) * f,
                    p[1] + (hand[1] - p[1]) * f,
                    hand[2],
                ]
            }
            _ => hand,
        }
    }

    /// Lets go: the point reached is held while the guide fades out.
    pub fn stop(&mut self) {
        self.on = false;
    }

    /// This tick's sample for a guide now in the state `stream`, the hand at `hand` (`None`:
    /// no new pose this tick, no sample); `None` once stopped and faded out.
    pub fn next_sample<S: Scalar>(
        &mut self,
        hand: Option<[f64; 3]>,
        stream: &GuideStream<S>,
    ) -> Option<GuideInput<S>> {
        if self.on {
            let primed = self.primed;
            return hand.map(|h| {
                self.primed = true;
                GuideInput {
                    anchor: Vec3::from_f64(self.anchor(h)),
                    on: primed,
                }
            });
        }
        match stream.anchor() {
            Some(anchor) if stream.active() => Some(GuideInput { anchor, on: false }),
            _ => None,
        }
    }

    /// Whether the fixture is done: stopped, and the guide faded out.
    pub fn done<S: Scalar>(&self, stream: &GuideStream<S>) -> bool {
        !self.on && !stream.active()
    }
}

/// `v` scaled down to length `max` if it is longer.
fn clamp_norm<S: Scalar>(v: Vec3<S>, max: S) -> Vec3<S> {
    let n2 = v.norm2();
    if n2 > max * max {
        v.scale(max * n2.rsqrt())
    } else {
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Fx;

    #[test]
    fn fades_in_and_out_without_steps_and_never_exceeds_its_limit() {
        let mut g = Guide::<Fx>::new(DEFAULT_GUIDE).unwrap();
        let hand = Vec3::<Fx>::ZERO;
        let anchor = Vec3::<Fx>::from_f64([30.0, 0.0, 0.0]); // far: the clamp holds
        let z = Vec3::<Fx>::ZERO;
        assert_eq!(
            g.tick(anchor, z, hand, z).force,
            Vec3::ZERO,
            "off until started"
        );
        g.start();
        let mut last = 0.0;
        for k in 0..400 {
            let f = g.tick(anchor, z, hand, z).force.to_f64()[0];
            assert!(
                f - last <= 0.8 / 300.0 + 1e-6,
                "tick {k}: step {}",
                f - last
            );
            assert!(f <= 0.8 + 1e-6);
            last = f;
        }
        assert!(
            (last - 0.8).abs() < 1e-6,
            "full gain clamps to 0.8 N: {last}"
        );
        g.stop();
        for _ in 0..301 {
            let f = g.tick(anchor, z, hand, z).force.to_f64()[0];
            assert!(last - f <= 0.8 / 300.0 + 1e-6);
            last = f;
        }
        assert_eq!(last, 0.0);
        assert!(!g.active());
    }

    #[test]
    fn pulls_toward_the_point_with_the_stated_stiffness() {
        let mut g = Guide::<f64>::new(GuideParams {
            fade_s: 0.0,
            ..DEFAULT_GUIDE
        })
        .unwrap();
        g.start();
        let z = Vec3::ZERO;
        let f = g.tick(Vec3::new(0.0, 5.0, 0.0), z, z, z);
        // 100 N/m over 5 mm (the stiffness in N/mm is derived in single precision: 0.1 to
        // within 1.5e-9).
        assert!((f.force.y - 0.5).abs() < 1e-7 && f.force.x == 0.0);
        assert!((f.distance_mm - 5.0).abs() < 1e-12);
        // Moving the anchor 1 mm further along the pull does 0.5 N x 1 mm of work.
        let f2 = g.tick(Vec3::new(0.0, 6.0, 0.0), Vec3::new(0.0, 1.0, 0.0), z, z);
        assert!((f2.source_mj - 0.5).abs() < 1e-7, "{}", f2.source_mj);
    }

    #[test]
    fn a_stream_follows_its_samples_and_fades_out_when_they_stop() {
        let mut g = GuideStream::<Fx>::new(DEFAULT_GUIDE).unwrap();
        let z = Vec3::<Fx>::ZERO;
        let at = |x: f64| {
            Some(GuideInput {
                anchor: Vec3::<Fx>::from_f64([x, 0.0, 0.0]),
                on: true,
            })
        };
        assert_eq!(g.tick(None, z, z).force, Vec3::ZERO, "idle without samples");
        assert!(!g.active());
        // Led toward a point moving 0.01 mm per tick: the force grows with the fade.
        let mut last = 0.0;
        for k in 0..300 {
            let f = g.tick(at(5.0 + 0.01 * k as f64), z, z);
            assert!(f.force.to_f64()[0] > last);
            last = f.force.to_f64()[0];
        }
        assert_eq!(g.anchor(), Some(Vec3::from_f64([7.99, 0.0, 0.0])));
        // Samples stop: the point is held, and after the timeout the guide fades out.
        for _ in 0..GUIDE_TIMEOUT_TICKS {
            let f = g.tick(None, z, z).force.to_f64()[0];
            // (Less only the damper's share of the point's former motion, 0.1 N s/m x 10 mm/s.)
            assert!(
                f >= last - 1.1e-3,
                "held at full gain until the timeout: {f} {last}"
            );
        }
        for _ in 0..400 {
            g.tick(None, z, z);
        }
        assert!(!g.active());
        assert_eq!(g.tick(None, z, z).force, Vec3::ZERO);
        // A cut drops the force at once.
        for k in 0..100 {
            g.tick(at(5.0 + 0.01 * k as f64), z, z);
        }
        assert!(g.active());
        g.cut();
        assert!(!g.active());
        assert_eq!(g.hold().force, Vec3::ZERO);
        assert_eq!(g.tick(None, z, z).force, Vec3::ZERO);
    }

    #[test]
    fn a_hold_keeps_the_force_and_the_fade_where_they_are() {
        let mut g = GuideStream::<Fx>::new(DEFAULT_GUIDE).unwrap();
        let mut h = g.clone();
        let z = Vec3::<Fx>::ZERO;
        let s = |x: f64| {
            Some(GuideInput {
                anchor: Vec3::<Fx>::from_f64([x, 0.0, 0.0]),
                on: true,
            })
        };
        // Same samples; `h` gets many pose-less ticks between them (longer than the timeout).
        for k in 0..100 {
            let a = g.tick(s(5.0 + 0.01 * k as f64), z, z);
            let b = h.tick(s(5.0 + 0.01 * k as f64), z, z);
            assert_eq!(a, b);
            for _ in 0..2 * GUIDE_TIMEOUT_TICKS {
                let held = h.hold();
                assert_eq!(held.force, b.force);
                assert_eq!(held.source_mj, Fx::ZERO);
            }
        }
        assert_eq!(g.guide().gain(), h.guide().gain());
        assert!(h.active());
    }

    #[test]
    fn bad_parameters_are_rejected() {
        for p in [
            GuideParams {
                stiffness_n_per_m: f32::NAN,
                ..DEFAULT_GUIDE
            },
            GuideParams {
                max_force_n: -1.0,
                ..DEFAULT_GUIDE
            },
            GuideParams {
                stiffness_n_per_m: 5000.0,
                ..DEFAULT_GUIDE
            },
        ] {
            assert!(Guide::<Fx>::new(p).is_err());
        }
    }
}
