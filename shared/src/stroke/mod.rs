//! Keyframed strokes (Sheu 1989, §2.3, §4.2, §4.4; SPEC part G): a stroke is a keyframed path
//! of the handle (ferrule position, orientation) and a timing along it.
//!
//! * [`bspline`]: cubic B-spline interpolation through given points, chord-length knots,
//!   natural (zero second derivative) or slope end conditions, evaluation with first and second
//!   derivatives.
//! * [`kinetic`]: the double interpolant's kinetic curve, time -> path parameter, through
//!   moving points; stop-and-go; synchronisation of several paths.
//! * [`orient`]: great-circle direction interpolation at constant angular speed, quaternion
//!   slerp and squad, tilt and azimuth.
//! * [`fit`]: the fewest keyframes that reproduce a recorded pose stream within a tolerance.
//!
//! [`Stroke`] puts them together. Its **path** is one cubic B-spline through the keyframes'
//! positions over the chord-length parameter `u` (the chord measured in pose space: millimetres,
//! with a turn of the handle counted as [`ORIENT_MM_PER_RAD`] mm per radian, so that keyframes
//! that only turn the brush still get distinct knots). Keyframe `k` sits at `u = a_k`. The
//! orientation between keyframes `k` and `k + 1` is squad over `h = (u - a_k) / (a_{k+1} -
//! a_k)`. The **kinetic curve** maps time to `u`; retiming ([`Stroke::retimed`]) swaps it and
//! leaves the path, point for point, unchanged.
//!
//! `no_std`, no allocator: everything is in fixed arrays of at most [`MAX_KEYS`] keyframes,
//! so the device can sample strokes too. `f64` throughout (planning code, not the 1 kHz loop).

// Numerical code indexes parallel fixed arrays (points, parameters, coefficients) by the same
// index; iterator chains would hide the formulas.
#![allow(clippy::needless_range_loop)]

pub mod bspline;
pub mod fit;
pub mod kinetic;
pub mod orient;

use core::fmt;

use bspline::{CubicBSpline, End, SplineError};
use kinetic::{Kinetic, KineticError, MovingPoint};
use orient::Q;

/// Most keyframes of one stroke (and most moving points of its timing).
pub use kinetic::MAX_KEYS;

/// Pose-space weight of orientation in the chord length: mm per radian of handle turn.
pub const ORIENT_MM_PER_RAD: f64 = 10.0;

/// The position path's spline type.
pub type PathSpline = CubicBSpline<3, { MAX_KEYS + 2 }>;

/// A keyframe: where the ferrule is, how the handle is turned, and optionally when (seconds
/// from the stroke's start).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Keyframe {
    pub pos: [f64; 3],
    pub rot: Q,
    pub t: Option<f64>,
}

/// Stop-and-go: the brush stands still at keyframe `key` for `dur` seconds.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Stop {
    pub key: usize,
    pub dur: f64,
}

/// A moving point given by keyframe number: at time `t` (s from the stroke's start) be at
/// `at`, a fractional keyframe number (2.5: halfway along the path from keyframe 2 to 3).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct KeyMovingPoint {
    pub t: f64,
    pub at: f64,
}

/// Where a timing problem comes from.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum Source {
    /// Keyframe `k` (or the end of its stop).
    Key(usize),
    /// The extra moving point `i`.
    MovingPoint(usize),
}

impl fmt::Display for Source {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Source::Key(k) => write!(f, "keyframe {k}"),
            Source::MovingPoint(i) => write!(f, "moving point {i}"),
        }
    }
}

/// Why a stroke cannot be built; keyframes are numbered from 0.
#[derive(Copy, Clone, Debug, PartialEq)]
pub enum StrokeError {
    TooFewKeys {
        found: usize,
    },
    TooManyKeys {
        found: usize,
        max: usize,
    },
    /// A coordinate, angle or time of keyframe `key` is NaN or infinite.
    NotFinite {
        key: usize,
    },
    /// Keyframe `key` has the same pose as the one before it (use a stop to pause).
    Repeated {
        key: usize,
    },
    /// Keyframe `key`'s time is not after the previous keyframe's (plus its stop).
    TimeBackwards {
        key: usize,
        t: f64,
        prev: f64,
    },
    /// A stop names a keyframe that does not exist or has a bad duration.
    BadStop {
        index: usize,
    },
    /// A moving point lies outside the keyframes or is not finite.
    BadMovingPoint {
        index: usize,
    },
    /// The default speed is not positive.
    BadSpeed,
    Path(SplineError),
    Timing {
        at: Source,
        err: KineticError,
    },
}

impl fmt::Display for StrokeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            StrokeError::TooFewKeys { found } => {
                write!(f, "a stroke needs at least 2 keyframes, found {found}")
            }
            StrokeError::TooManyKeys { found, max } => {
                write!(f, "{found} keyframes, more than the {max} a stroke holds")
            }
            StrokeError::NotFinite { key } => write!(f, "keyframe {key}: a value is not finite"),
            StrokeError::Repeated { key } => write!(
                f,
                "keyframe {key}: same pose as keyframe {} (to pause, use a stop)",
                key - 1
            ),
            StrokeError::TimeBackwards { key, t, prev } => write!(
                f,
                "keyframe {key}: time {t} s is not after the previous keyframe's {prev} s \
                 (times must increase)"
            ),
            StrokeError::BadStop { index } => {
                write!(f, "stop {index}: no such keyframe or bad duration")
            }
            StrokeError::BadMovingPoint { index } => {
                write!(
                    f,
                    "moving point {index}: not finite or outside the keyframes"
                )
            }
            StrokeError::BadSpeed => write!(f, "the speed must be a positive number"),
            StrokeError::Path(e) => write!(f, "path: {e}"),
            StrokeError::Timing { at, err } => write!(f, "{at}: timing: {err}"),
        }
    }
}

/// A keyframed stroke: path, orientation keys and kinetic curve.
#[derive(Clone, Debug)]
pub struct Stroke {
    n: usize,
    pos: [[f64; 3]; MAX_KEYS],
    rot: [Q; MAX_KEYS],
    /// Squad inner controls.
    ctl: [Q; MAX_KEYS],
    path: PathSpline,
    /// Each keyframe's time after timing was resolved (its arrival, before any stop).
    times: [f64; MAX_KEYS],
    kinetic: Kinetic,
}

impl Stroke {
    /// Builds a stroke. Keyframes without a time are placed by chord length between the
    /// nearest anchors around them (timed keyframes, extra moving points), or at `speed`
    /// (pose-space mm/s) after the last one. The first keyframe's time defaults to 0. A stop
    /// at a keyframe delays only the untimed keyframes after it; timed ones keep their time.
    pub fn new(
        keys: &[Keyframe],
        stops: &[Stop],
        moving: &[KeyMovingPoint],
        speed: f64,
    ) -> Result<Stroke, StrokeError> {
        let mut s = Self::path_only(keys)?;
        if !(speed.is_finite() && speed > 0.0) {
            return Err(StrokeError::BadSpeed);
        }
        let n = s.n;
        let mut stop_dur = [0.0; MAX_KEYS];
        for (i, st) in stops.iter().enumerate() {
            if st.key >= n || !(st.dur.is_finite() && st.dur > 0.0) {
                return Err(StrokeError::BadStop { index: i });
            }
            stop_dur[st.key] += st.dur;
        }
        // Resolve times. Anchors are the timed keyframes and the extra moving points, as
        // (u, arrival, departure); untimed keyframes share out the time between the anchors
        // around them in proportion to chord length, or go at `speed` after the last one.
        let a = s.path.params();
        let mut extra_u = [0.0; MAX_KEYS];
        for (i, mp) in moving.iter().enumerate().take(MAX_KEYS) {
            extra_u[i] = s
                .param_of(mp.at)
                .ok_or(StrokeError::BadMovingPoint { index: i })?;
            if !mp.t.is_finite() {
                return Err(StrokeError::BadMovingPoint { index: i });
            }
        }
        let mut anchors = [(0.0f64, 0.0f64, 0.0f64); 2 * MAX_KEYS];
        let mut na = 0;
        if keys[0].t.is_none() {
            anchors[0] = (0.0, 0.0, stop_dur[0]);
            na = 1;
        }
        for k in 0..n {
            if let Some(tk) = keys[k].t {
                anchors[na] = (a[k], tk, tk + stop_dur[k]);
                na += 1;
            }
        }
        for (i, mp) in moving.iter().enumerate().take(MAX_KEYS) {
            anchors[na] = (extra_u[i], mp.t, mp.t);
            na += 1;
        }
        let anchors = &mut anchors[..na];
        anchors.sort_unstable_by(|x, y| x.0.total_cmp(&y.0).then(x.1.total_cmp(&y.1)));
        let mut t = [0.0; MAX_KEYS];
        for k in 0..n {
            if let Some(tk) = keys[k].t {
                t[k] = tk;
                continue;
            }
            if let Some(on) = anchors.iter().find(|x| x.0 == a[k]) {
                t[k] = on.1;
                continue;
            }
            let p = anchors
                .iter()
                .rev()
                .find(|x| x.0 < a[k])
                .copied()
                .unwrap_or(anchors[0]);
            let next = anchors.iter().find(|x| x.0 > a[k]).copied();
            let untimed_stops = |lo: f64, hi: f64| -> f64 {
                (0..n)
                    .filter(|&j| keys[j].t.is_none() && a[j] > lo && a[j] < hi)
                    .map(|j| stop_dur[j])
                    .sum()
            };
            let before = untimed_stops(p.0, a[k]);
            t[k] = match next {
                Some(nx) => {
                    let avail = nx.1 - p.2 - untimed_stops(p.0, nx.0);
                    if avail <= 0.0 {
                        return Err(StrokeError::TimeBackwards {
                            key: k,
                            t: nx.1,
                            prev: p.2,
                        });
                    }
                    p.2 + avail * (a[k] - p.0) / (nx.0 - p.0) + before
                }
                None => p.2 + (a[k] - p.0) / speed + before,
            };
        }
        for k in 1..n {
            let prev = t[k - 1] + stop_dur[k - 1];
            if t[k] <= prev {
                return Err(StrokeError::TimeBackwards {
                    key: k,
                    t: t[k],
                    prev,
                });
            }
        }
        s.times = t;
        // Moving points: each keyframe (and the end of its stop), plus the extra ones.
        let mut mps = [MovingPoint { t: 0.0, u: 0.0 }; MAX_KEYS];
        let mut src = [Source::Key(0); MAX_KEYS];
        let mut m = 0;
        let mut push = |p: MovingPoint, so: Source, mps: &mut [MovingPoint], src: &mut [Source]| {
            if m == MAX_KEYS {
                return Err(StrokeError::Timing {
                    at: so,
                    err: KineticError::TooManyPoints { max: MAX_KEYS },
                });
            }
            mps[m] = p;
            src[m] = so;
            m += 1;
            Ok(())
        };
        for k in 0..n {
            push(
                MovingPoint { t: t[k], u: a[k] },
                Source::Key(k),
                &mut mps,
                &mut src,
            )?;
            if stop_dur[k] > 0.0 {
                let p = MovingPoint {
                    t: t[k] + stop_dur[k],
                    u: a[k],
                };
                push(p, Source::Key(k), &mut mps, &mut src)?;
            }
        }
        for (i, mp) in moving.iter().enumerate() {
            let u = s
                .param_of(mp.at)
                .ok_or(StrokeError::BadMovingPoint { index: i })?;
            push(
                MovingPoint { t: mp.t, u },
                Source::MovingPoint(i),
                &mut mps,
                &mut src,
            )?;
        }
        // Sort by time (insertion sort; stable, so a keyframe stays before its stop's end).
        for i in 1..m {
            let mut j = i;
            while j > 0 && mps[j - 1].t > mps[j].t {
                mps.swap(j - 1, j);
                src.swap(j - 1, j);
                j -= 1;
            }
        }
        s.kinetic = Kinetic::new(&mps[..m]).map_err(|err| {
            let idx = match err {
                KineticError::NotFinite { index }
                | KineticError::TimeNotIncreasing { index }
                | KineticError::Backwards { index } => index,
                _ => 0,
            };
            StrokeError::Timing {
                at: src[idx.min(m - 1)],
                err,
            }
        })?;
        Ok(s)
    }

    /// The path and orientation keys, with a placeholder timing.
    fn path_only(keys: &[Keyframe]) -> Result<Stroke, StrokeError> {
        let n = keys.len();
        if n < 2 {
            return Err(StrokeError::TooFewKeys { found: n });
        }
        if n > MAX_KEYS {
            return Err(StrokeError::TooManyKeys {
                found: n,
                max: MAX_KEYS,
            });
        }
        let mut pos = [[0.0; 3]; MAX_KEYS];
        let mut rot = [[1.0, 0.0, 0.0, 0.0]; MAX_KEYS];
        for (k, kf) in keys.iter().enumerate() {
            let finite = kf.pos.iter().chain(kf.rot.iter()).all(|c| c.is_finite())
                && kf.t.is_none_or(|t| t.is_finite());
            let norm2: f64 = kf.rot.iter().map(|c| c * c).sum();
            if !finite || norm2 < 1e-12 {
                return Err(StrokeError::NotFinite { key: k });
            }
            pos[k] = kf.pos;
            rot[k] = orient::normalize(kf.rot);
        }
        orient::make_continuous(&mut rot[..n]);
        let mut a = [0.0; MAX_KEYS];
        for k in 1..n {
            let dp = bspline::dist(&pos[k - 1], &pos[k]);
            let dth = orient::angle_between(rot[k - 1], rot[k]) * ORIENT_MM_PER_RAD;
            let c = libm::sqrt(dp * dp + dth * dth);
            if c < 1e-6 {
                return Err(StrokeError::Repeated { key: k });
            }
            a[k] = a[k - 1] + c;
        }
        let path = PathSpline::interpolate(&a[..n], &pos[..n], End::Natural, End::Natural)
            .map_err(StrokeError::Path)?;
        let mut ctl = [[1.0, 0.0, 0.0, 0.0]; MAX_KEYS];
        for k in 0..n {
            ctl[k] = orient::squad_control(&rot[..n], k);
        }
        let kinetic = Kinetic::new(&[
            MovingPoint { t: 0.0, u: 0.0 },
            MovingPoint {
                t: 1.0,
                u: a[n - 1],
            },
        ])
        .map_err(|err| StrokeError::Timing {
            at: Source::Key(0),
            err,
        })?;
        Ok(Stroke {
            n,
            pos,
            rot,
            ctl,
            path,
            times: [0.0; MAX_KEYS],
            kinetic,
        })
    }

    /// The same path with another timing: moving points `(t, u)` on this stroke's parameter.
    pub fn retimed(&self, moving: &[MovingPoint]) -> Result<Stroke, KineticError> {
        Ok(self.with_kinetic(Kinetic::new(moving)?))
    }

    /// The same path with the kinetic curve `kinetic` (e.g. from [`kinetic::synchronise`]).
    pub fn with_kinetic(&self, kinetic: Kinetic) -> Stroke {
        let mut s = self.clone();
        s.kinetic = kinetic;
        for k in 0..self.n {
            s.times[k] = s.time_of(s.path.params()[k]);
        }
        s
    }

    /// Path parameter `u` of fractional keyframe number `at`, if it lies within the keyframes.
    pub fn param_of(&self, at: f64) -> Option<f64> {
        if !at.is_finite() || at < 0.0 || at > (self.n - 1) as f64 {
            return None;
        }
        let a = self.path.params();
        let k = (libm::floor(at) as usize).min(self.n - 2);
        Some(a[k] + (at - k as f64) * (a[k + 1] - a[k]))
    }

    /// Earliest time at which the kinetic curve reaches `u` (bisection).
    fn time_of(&self, u: f64) -> f64 {
        let (mut lo, mut hi) = self.kinetic.domain();
        for _ in 0..100 {
            let mid = 0.5 * (lo + hi);
            if self.kinetic.param(mid) < u {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        hi
    }

    /// Number of keyframes.
    pub fn len(&self) -> usize {
        self.n
    }

    /// Always false: a stroke has at least two keyframes.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Keyframe `k`'s position and (sign-continuous) orientation.
    pub fn key(&self, k: usize) -> ([f64; 3], Q) {
        (self.pos[k], self.rot[k])
    }

    /// Each keyframe's resolved time.
    pub fn key_times(&self) -> &[f64] {
        &self.times[..self.n]
    }

    /// The keyframes' path parameters.
    pub fn key_params(&self) -> &[f64] {
        self.path.params()
    }

    pub fn path(&self) -> &PathSpline {
        &self.path
    }

    pub fn kinetic(&self) -> &Kinetic {
        &self.kinetic
    }

    /// First and last time of the stroke.
    pub fn domain(&self) -> (f64, f64) {
        self.kinetic.domain()
    }

    /// The pose at path parameter `u`.
    pub fn pose_at_param(&self, u: f64) -> ([f64; 3], Q) {
        let p = self.path.eval(u);
        let a = self.path.params();
        let (lo, hi) = self.path.domain();
        let u = u.clamp(lo, hi);
        let mut k = 0;
        while k + 2 < self.n && a[k + 1] <= u {
            k += 1;
        }
        let h = ((u - a[k]) / (a[k + 1] - a[k])).clamp(0.0, 1.0);
        let q = orient::squad(
            self.rot[k],
            self.rot[k + 1],
            self.ctl[k],
            self.ctl[k + 1],
            h,
        );
        (p, q)
    }

    /// The pose at time `t` (clamped to the stroke's time span).
    pub fn pose_at(&self, t: f64) -> ([f64; 3], Q) {
        self.pose_at_param(self.kinetic.param(t))
    }
}
