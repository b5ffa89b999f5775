//! The kinetic curve of the double interpolant (Sheu 1989, §2.3 item 8 and §4.2): time ->
//! path parameter, through moving points "at time t be at parameter u".
//!
//! The path is a [`super::bspline::CubicBSpline`] over its chord-length parameter `u`; the
//! kinetic curve says where on it the brush is at each time. Changing the kinetic curve
//! (retiming) therefore never changes the path, only the speed along it.
//!
//! * The moving points `(t_i, u_i)` must have strictly increasing times and non-decreasing
//!   parameters (the brush never runs backwards along its path).
//! * Two consecutive moving points with the same `u` are a **stop** (stop-and-go, §4.2 item 4):
//!   the parameter is held exactly constant between them, so the brush stands still without
//!   any division by a zero speed. The moving parts on either side are separate cubic
//!   B-splines through their moving points (knots at the moving points' times) that arrive
//!   at and leave the stop with zero slope: the speed is C1 across the stop.
//! * The whole curve starts and ends at rest (zero slope), so strokes and the travel between
//!   them join without a velocity jump.
//! * Between moving points the C2 interpolating cubic can overshoot and run backwards when
//!   the timing is very uneven (a crawl, then a dash). The slope is a quadratic on each span,
//!   so this is checked exactly; where it happens, that moving part falls back to a
//!   monotone piecewise-cubic Hermite curve (Fritsch-Carlson / PCHIP slopes, zero at rest):
//!   still through every moving point and C1, never backwards, but no longer C2.
//!   [`Kinetic::is_c2`] tells which one was used.

use core::fmt;

use super::bspline::{CubicBSpline, End, SplineError};

/// Most moving points of one kinetic curve, and so most keyframes of one stroke (a stroke's
/// timing has a moving point per keyframe; `stroke` re-exports it as the stroke's bound).
pub const MAX_KEYS: usize = 64;

/// Most moving parts (stops + 1) of one kinetic curve.
pub const MAX_PIECES: usize = 8;

/// "At time `t` (s) be at path parameter `u`."
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct MovingPoint {
    pub t: f64,
    pub u: f64,
}

/// Why a kinetic curve cannot be built. `index` is a moving point.
#[derive(Copy, Clone, Debug, PartialEq)]
pub enum KineticError {
    TooFewPoints,
    TooManyPoints {
        max: usize,
    },
    TooManyStops {
        max: usize,
    },
    NotFinite {
        index: usize,
    },
    /// Time does not increase from point `index - 1` to `index`.
    TimeNotIncreasing {
        index: usize,
    },
    /// The parameter decreases from point `index - 1` to `index`.
    Backwards {
        index: usize,
    },
    Spline(SplineError),
}

impl fmt::Display for KineticError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            KineticError::TooFewPoints => write!(f, "timing needs at least 2 moving points"),
            KineticError::TooManyPoints { max } => write!(f, "more than {max} moving points"),
            KineticError::TooManyStops { max } => write!(f, "more than {} stops", max - 1),
            KineticError::NotFinite { index } => write!(f, "moving point {index} is not finite"),
            KineticError::TimeNotIncreasing { index } => write!(
                f,
                "time goes backwards (or stands still) from point {} to point {index}",
                index - 1
            ),
            KineticError::Backwards { index } => write!(
                f,
                "point {index} lies before point {} on the path",
                index - 1
            ),
            KineticError::Spline(e) => write!(f, "{e}"),
        }
    }
}

/// One moving part: a 1-D spline over time, or a stop.
// No heap: every variant is stored inline, the size difference is the point.
#[allow(clippy::large_enum_variant)]
#[derive(Copy, Clone, Debug, PartialEq)]
enum Piece {
    Move(CubicBSpline<1, { MAX_KEYS + 2 }>),
    Monotone(Hermite),
    Stop { t0: f64, t1: f64, u: f64 },
}

/// A monotone piecewise-cubic Hermite curve (the fallback of a moving part).
#[derive(Copy, Clone, Debug, PartialEq)]
struct Hermite {
    n: usize,
    t: [f64; MAX_KEYS],
    u: [f64; MAX_KEYS],
    m: [f64; MAX_KEYS],
}

impl Hermite {
    fn new(pts: &[MovingPoint]) -> Hermite {
        let n = pts.len();
        let mut h = Hermite {
            n,
            t: [0.0; MAX_KEYS],
            u: [0.0; MAX_KEYS],
            m: [0.0; MAX_KEYS],
        };
        for (j, p) in pts.iter().enumerate() {
            h.t[j] = p.t;
            h.u[j] = p.u;
        }
        // Interior slopes: PCHIP's weighted harmonic mean, zero at a local extremum or flat
        // side; the ends are at rest.
        for j in 1..n - 1 {
            let (h0, h1) = (h.t[j] - h.t[j - 1], h.t[j + 1] - h.t[j]);
            let d0 = (h.u[j] - h.u[j - 1]) / h0;
            let d1 = (h.u[j + 1] - h.u[j]) / h1;
            h.m[j] = if d0 <= 0.0 || d1 <= 0.0 {
                0.0
            } else {
                let (w1, w2) = (2.0 * h1 + h0, h1 + 2.0 * h0);
                (w1 + w2) / (w1 / d0 + w2 / d1)
            };
        }
        h
    }

    fn eval(&self, t: f64) -> [f64; 3] {
        let n = self.n;
        let t = t.clamp(self.t[0], self.t[n - 1]);
        let mut j = 0;
        while j + 2 < n && self.t[j + 1] <= t {
            j += 1;
        }
        let h = self.t[j + 1] - self.t[j];
        let s = (t - self.t[j]) / h;
        let (u0, u1, m0, m1) = (self.u[j], self.u[j + 1], self.m[j] * h, self.m[j + 1] * h);
        let (s2, s3) = (s * s, s * s * s);
        let v = (2.0 * s3 - 3.0 * s2 + 1.0) * u0
            + (s3 - 2.0 * s2 + s) * m0
            + (-2.0 * s3 + 3.0 * s2) * u1
            + (s3 - s2) * m1;
        let d = (6.0 * s2 - 6.0 * s) * u0
            + (3.0 * s2 - 4.0 * s + 1.0) * m0
            + (-6.0 * s2 + 6.0 * s) * u1
            + (3.0 * s2 - 2.0 * s) * m1;
        let dd = (12.0 * s - 6.0) * u0
            + (6.0 * s - 4.0) * m0
            + (-12.0 * s + 6.0) * u1
            + (6.0 * s - 2.0) * m1;
        [v, d / h, dd / (h * h)]
    }
}

/// Time -> path parameter through moving points, with stops. See the module documentation.
#[derive(Clone, Debug, PartialEq)]
pub struct Kinetic {
    pieces: [Piece; MAX_PIECES],
    count: usize,
    /// Start and end time of each piece.
    bounds: [(f64, f64); MAX_PIECES],
}

impl Kinetic {
    /// The kinetic curve through `points`.
    pub fn new(points: &[MovingPoint]) -> Result<Self, KineticError> {
        let m = points.len();
        if m < 2 {
            return Err(KineticError::TooFewPoints);
        }
        if m > MAX_KEYS {
            return Err(KineticError::TooManyPoints { max: MAX_KEYS });
        }
        for (i, p) in points.iter().enumerate() {
            if !p.t.is_finite() || !p.u.is_finite() {
                return Err(KineticError::NotFinite { index: i });
            }
            if i > 0 {
                if p.t <= points[i - 1].t {
                    return Err(KineticError::TimeNotIncreasing { index: i });
                }
                if p.u < points[i - 1].u {
                    return Err(KineticError::Backwards { index: i });
                }
            }
        }
        let mut k = Kinetic {
            pieces: [Piece::Stop {
                t0: 0.0,
                t1: 0.0,
                u: 0.0,
            }; MAX_PIECES],
            count: 0,
            bounds: [(0.0, 0.0); MAX_PIECES],
        };
        let push = |k: &mut Kinetic, p: Piece, b: (f64, f64)| {
            if k.count == MAX_PIECES {
                return Err(KineticError::TooManyStops { max: MAX_PIECES });
            }
            k.pieces[k.count] = p;
            k.bounds[k.count] = b;
            k.count += 1;
            Ok(())
        };
        // Split at stops (consecutive equal parameters).
        let mut start = 0;
        let mut i = 0;
        while i + 1 < m {
            if points[i + 1].u == points[i].u {
                if i > start {
                    let piece = Self::moving(&points[start..=i], start)?;
                    push(&mut k, piece, (points[start].t, points[i].t))?;
                }
                let (t0, t1) = (points[i].t, points[i + 1].t);
                push(
                    &mut k,
                    Piece::Stop {
                        t0,
                        t1,
                        u: points[i].u,
                    },
                    (t0, t1),
                )?;
                start = i + 1;
            }
            i += 1;
        }
        if m - 1 > start {
            let piece = Self::moving(&points[start..], start)?;
            push(&mut k, piece, (points[start].t, points[m - 1].t))?;
        }
        Ok(k)
    }

    fn moving(pts: &[MovingPoint], offset: usize) -> Result<Piece, KineticError> {
        let mut ts = [0.0; MAX_KEYS];
        let mut us = [[0.0]; MAX_KEYS];
        for (j, p) in pts.iter().enumerate() {
            ts[j] = p.t;
            us[j] = [p.u];
        }
        let n = pts.len();
        let s = CubicBSpline::<1, { MAX_KEYS + 2 }>::interpolate(
            &ts[..n],
            &us[..n],
            End::Slope([0.0]),
            End::Slope([0.0]),
        )
        .map_err(|e| match e {
            SplineError::NotIncreasing { index } => KineticError::TimeNotIncreasing {
                index: index + offset,
            },
            e => KineticError::Spline(e),
        })?;
        // The slope is a quadratic on each span: check its minimum.
        for j in 0..n - 1 {
            let (t0, t1) = (ts[j], ts[j + 1]);
            let a = s.eval_on_span(j, t0);
            let b = s.eval_on_span(j, t1);
            let (d0, d1, s0, s1) = (a[1][0], b[1][0], a[2][0], b[2][0]);
            let mut min = d0.min(d1);
            if s0 < 0.0 && s1 > 0.0 {
                let tv = t0 + (t1 - t0) * s0 / (s0 - s1);
                min = min.min(s.eval_on_span(j, tv)[1][0]);
            }
            let scale = (us[n - 1][0] - us[0][0]) / (ts[n - 1] - ts[0]);
            if min < -1e-9 * scale.max(1e-9) {
                return Ok(Piece::Monotone(Hermite::new(pts)));
            }
        }
        Ok(Piece::Move(s))
    }

    /// Whether every moving part is the C2 B-spline (no monotone fallback was needed).
    pub fn is_c2(&self) -> bool {
        !self.pieces[..self.count]
            .iter()
            .any(|p| matches!(p, Piece::Monotone(_)))
    }

    /// First and last time.
    pub fn domain(&self) -> (f64, f64) {
        (self.bounds[0].0, self.bounds[self.count - 1].1)
    }

    /// The path parameter at time `t` (clamped to the domain).
    pub fn param(&self, t: f64) -> f64 {
        self.param_derivs(t)[0]
    }

    /// The path parameter and its first and second time derivatives at `t`.
    pub fn param_derivs(&self, t: f64) -> [f64; 3] {
        let mut idx = self.count - 1;
        for j in 0..self.count {
            if t <= self.bounds[j].1 {
                idx = j;
                break;
            }
        }
        match &self.pieces[idx] {
            Piece::Stop { u, .. } => [*u, 0.0, 0.0],
            Piece::Move(s) => {
                let d = s.eval_derivs(t);
                [d[0][0], d[1][0], d[2][0]]
            }
            Piece::Monotone(h) => h.eval(t),
        }
    }
}

/// A moving point shared by several paths (§4.2 item 3): at one instant every path `p` is at
/// its own parameter `u[p]`. `t` is that instant, or `None` to let [`synchronise`] choose it.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct SyncPoint<const P: usize> {
    pub t: Option<f64>,
    pub u: [f64; P],
}

/// Kinetic curves for `P` paths that pass their shared moving points together.
///
/// Missing times are chosen so that the slowest path keeps its nominal speed
/// (`speed[p]`, parameter units per second): `t_i = t_{i-1} + max_p (u_i[p] - u_{i-1}[p]) /
/// speed[p]`, or `min_dt` when every path stands still there (a shared stop). The first point's
/// time defaults to 0.
pub fn synchronise<const P: usize>(
    points: &[SyncPoint<P>],
    speed: [f64; P],
    min_dt: f64,
) -> Result<[Kinetic; P], KineticError> {
    let m = points.len();
    if m < 2 {
        return Err(KineticError::TooFewPoints);
    }
    if m > MAX_KEYS {
        return Err(KineticError::TooManyPoints { max: MAX_KEYS });
    }
    let mut times = [0.0; MAX_KEYS];
    for i in 0..m {
        times[i] = match points[i].t {
            Some(t) => t,
            None if i == 0 => 0.0,
            None => {
                let mut dt: f64 = 0.0;
                for p in 0..P {
                    let du = points[i].u[p] - points[i - 1].u[p];
                    if speed[p] > 0.0 {
                        dt = dt.max(du / speed[p]);
                    }
                }
                times[i - 1] + dt.max(min_dt)
            }
        };
    }
    let mut out: [Option<Kinetic>; P] = [const { None }; P];
    for (p, slot) in out.iter_mut().enumerate() {
        let mut mps = [MovingPoint { t: 0.0, u: 0.0 }; MAX_KEYS];
        for i in 0..m {
            mps[i] = MovingPoint {
                t: times[i],
                u: points[i].u[p],
            };
        }
        *slot = Some(Kinetic::new(&mps[..m])?);
    }
    Ok(out.map(|k| k.expect("every path built")))
}
