//! Fitting a recorded pose stream with the fewest keyframes (greedy insertion).
//!
//! Start with the first and last sample as keyframes (with their recorded times). Build the
//! [`Stroke`] they define, measure the position error (mm) and orientation error (degrees) at
//! every sample's time, and insert the sample with the worst error relative to its tolerance;
//! repeat until every sample is within both tolerances or [`MAX_KEYS`] keyframes are used.
//! Keyframes whose poses coincide become a stop (the recording paused there).

use super::orient::{self, Q};
use super::{bspline, Keyframe, Stop, Stroke, StrokeError, MAX_KEYS, ORIENT_MM_PER_RAD};

/// One recorded pose.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Sample {
    pub t: f64,
    pub pos: [f64; 3],
    pub rot: Q,
}

/// The result of [`fit`].
#[derive(Clone, Debug)]
pub struct Fit {
    /// Indices of the samples used as keyframes, in order (`keys[..n]`).
    pub keys: [usize; MAX_KEYS],
    pub n: usize,
    /// Stops at keyframes (by their index in `keys`), when the recording paused.
    pub stops: [Stop; MAX_KEYS],
    pub n_stops: usize,
    /// The stroke, timed so that its time 0 is the first sample's time.
    pub stroke: Stroke,
    /// Largest position error over the samples (mm).
    pub max_mm: f64,
    /// Largest orientation error over the samples (degrees).
    pub max_deg: f64,
    /// Whether both tolerances were met (false: [`MAX_KEYS`] keyframes were not enough).
    pub within: bool,
}

/// Why a pose stream cannot be fitted.
#[derive(Copy, Clone, Debug, PartialEq)]
pub enum FitError {
    TooFewSamples,
    /// Sample `index` is not finite or goes back in time.
    BadSample {
        index: usize,
    },
    BadTolerance,
    /// The stream never moves.
    Static,
    Stroke(StrokeError),
}

impl core::fmt::Display for FitError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            FitError::TooFewSamples => write!(f, "at least 2 samples are needed"),
            FitError::BadSample { index } => {
                write!(f, "sample {index} is not finite or goes back in time")
            }
            FitError::BadTolerance => write!(f, "tolerances must be positive"),
            FitError::Static => write!(f, "the pose stream never moves"),
            FitError::Stroke(e) => write!(f, "{e}"),
        }
    }
}

const SAME_POSE: f64 = 1e-4;

fn pose_dist(a: &Sample, b: &Sample) -> f64 {
    let dp = bspline::dist(&a.pos, &b.pos);
    let dth = orient::angle_between(a.rot, b.rot) * ORIENT_MM_PER_RAD;
    libm::sqrt(dp * dp + dth * dth)
}

/// Builds the stroke for the chosen sample indices, merging repeated poses into stops.
fn build(
    samples: &[Sample],
    idx: &[usize],
) -> Result<(Stroke, [Stop; MAX_KEYS], usize), StrokeError> {
    let t0 = samples[0].t;
    let mut keys = [Keyframe {
        pos: [0.0; 3],
        rot: [1.0, 0.0, 0.0, 0.0],
        t: None,
    }; MAX_KEYS];
    let mut stops = [Stop { key: 0, dur: 0.0 }; MAX_KEYS];
    let (mut n, mut ns) = (0, 0);
    let mut last: Option<usize> = None;
    for &i in idx {
        let s = &samples[i];
        if let Some(l) = last {
            if pose_dist(&samples[l], s) < SAME_POSE {
                // A pause: extend (or start) a stop at the previous keyframe.
                let dur = s.t - samples[l].t;
                if ns > 0 && stops[ns - 1].key == n - 1 {
                    stops[ns - 1].dur += dur;
                } else {
                    stops[ns] = Stop { key: n - 1, dur };
                    ns += 1;
                }
                last = Some(i);
                continue;
            }
        }
        keys[n] = Keyframe {
            pos: s.pos,
            rot: s.rot,
            t: Some(s.t - t0),
        };
        n += 1;
        last = Some(i);
    }
    // A stop at the last keyframe (the recording ends at rest) stays: the stroke then lasts
    // as long as the recording, so whatever follows it starts on time.
    let st = Stroke::new(&keys[..n], &stops[..ns], &[], 100.0)?;
    Ok((st, stops, ns))
}

/// Fits `samples` (times increasing) within `tol_mm` and `tol_deg`. See the module docs.
pub fn fit(samples: &[Sample], tol_mm: f64, tol_deg: f64) -> Result<Fit, FitError> {
    let m = samples.len();
    if m < 2 {
        return Err(FitError::TooFewSamples);
    }
    if !(tol_mm > 0.0 && tol_deg > 0.0 && tol_mm.is_finite() && tol_deg.is_finite()) {
        return Err(FitError::BadTolerance);
    }
    for (i, s) in samples.iter().enumerate() {
        let ok = s.t.is_finite()
            && s.pos.iter().chain(s.rot.iter()).all(|c| c.is_finite())
            && (i == 0 || s.t > samples[i - 1].t);
        if !ok {
            return Err(FitError::BadSample { index: i });
        }
    }
    if samples
        .iter()
        .all(|s| pose_dist(s, &samples[0]) < SAME_POSE)
    {
        return Err(FitError::Static);
    }
    let mut idx = [0usize; MAX_KEYS];
    idx[0] = 0;
    idx[1] = m - 1;
    let mut n = 2;
    // If the ends coincide (a closed or paused recording), start with the farthest sample too.
    if pose_dist(&samples[0], &samples[m - 1]) < SAME_POSE {
        let far = (1..m - 1)
            .max_by(|&a, &b| {
                pose_dist(&samples[a], &samples[0]).total_cmp(&pose_dist(&samples[b], &samples[0]))
            })
            .unwrap_or(m / 2);
        idx = insert(idx, n, far);
        n += 1;
    }
    loop {
        let (stroke, stops, ns) = build(samples, &idx[..n]).map_err(FitError::Stroke)?;
        let t0 = samples[0].t;
        let (mut worst, mut worst_i, mut max_mm, mut max_deg) = (0.0f64, 0usize, 0.0f64, 0.0f64);
        for (i, s) in samples.iter().enumerate() {
            let (p, q) = stroke.pose_at(s.t - t0);
            let e_mm = bspline::dist(&p, &s.pos);
            let e_deg = orient::angle_between(q, s.rot).to_degrees();
            max_mm = max_mm.max(e_mm);
            max_deg = max_deg.max(e_deg);
            let e = (e_mm / tol_mm).max(e_deg / tol_deg);
            if e > worst {
                worst = e;
                worst_i = i;
            }
        }
        let within = worst <= 1.0;
        let chosen = idx[..n].contains(&worst_i);
        if within || n == MAX_KEYS || chosen {
            let mut keys = [0usize; MAX_KEYS];
            // Report the keyframes actually used (repeated poses merged into stops).
            let mut kn = 0;
            let mut last: Option<usize> = None;
            for &i in &idx[..n] {
                if let Some(l) = last {
                    if pose_dist(&samples[l], &samples[i]) < SAME_POSE {
                        last = Some(i);
                        continue;
                    }
                }
                keys[kn] = i;
                kn += 1;
                last = Some(i);
            }
            return Ok(Fit {
                keys,
                n: kn,
                stops,
                n_stops: ns,
                stroke,
                max_mm,
                max_deg,
                within,
            });
        }
        idx = insert(idx, n, worst_i);
        n += 1;
    }
}

/// `idx[..n]` (sorted) with `v` inserted in order.
fn insert(mut idx: [usize; MAX_KEYS], n: usize, v: usize) -> [usize; MAX_KEYS] {
    let mut j = n;
    while j > 0 && idx[j - 1] > v {
        idx[j] = idx[j - 1];
        j -= 1;
    }
    idx[j] = v;
    idx
}
