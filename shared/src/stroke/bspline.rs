//! Cubic B-spline interpolation through given points (Sheu 1989, §2.3 item 6).
//!
//! For points `P_0 .. P_n` at strictly increasing parameters `a_0 < a_1 < .. < a_n` (the chord
//! lengths by default, [`chord_params`]), the knot vector is
//! `a_0, a_0, a_0, a_0, a_1, .., a_{n-1}, a_n, a_n, a_n, a_n` and the `n + 3` control points
//! `Q_0 .. Q_{n+2}` solve the `n + 1` interpolation conditions `C(a_j) = P_j` plus one end
//! condition at each end: zero second derivative (the thesis's natural ends, [`End::Natural`])
//! or a given first derivative ([`End::Slope`], used by the kinetic curve to start and stop at
//! rest). The system is tridiagonal and is solved without pivoting (Thomas algorithm).
//!
//! Everything lives in fixed arrays: `N` is the largest number of control points, so a spline
//! holds at most `N - 2` points. No allocation, no panics for valid input.

use core::fmt;

/// An end condition of an interpolating spline.
#[derive(Copy, Clone, Debug, PartialEq)]
pub enum End<const D: usize> {
    /// Zero second derivative (a natural spline end).
    Natural,
    /// The first derivative with respect to the parameter.
    Slope([f64; D]),
}

/// Why an interpolant cannot be built.
#[derive(Copy, Clone, Debug, PartialEq)]
pub enum SplineError {
    /// Fewer than two points.
    TooFewPoints { found: usize },
    /// More points than the fixed capacity holds.
    TooManyPoints { found: usize, max: usize },
    /// `params` and `points` differ in length.
    LengthMismatch { params: usize, points: usize },
    /// A parameter or coordinate is NaN or infinite; `index` is the point.
    NotFinite { index: usize },
    /// Parameter `index` is not greater than the one before it (for chord lengths: point
    /// `index` coincides with point `index - 1`).
    NotIncreasing { index: usize },
    /// The linear system turned out singular (cannot happen for increasing parameters).
    Singular,
}

impl fmt::Display for SplineError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SplineError::TooFewPoints { found } => {
                write!(f, "an interpolant needs at least 2 points, found {found}")
            }
            SplineError::TooManyPoints { found, max } => {
                write!(f, "{found} points is more than the capacity of {max}")
            }
            SplineError::LengthMismatch { params, points } => {
                write!(f, "{params} parameters for {points} points")
            }
            SplineError::NotFinite { index } => write!(f, "point {index} is not finite"),
            SplineError::NotIncreasing { index } => write!(
                f,
                "point {index} does not advance past point {} (parameters must increase)",
                index - 1
            ),
            SplineError::Singular => write!(f, "singular interpolation system"),
        }
    }
}

/// Chord-length parameters of `points` into `out[..points.len()]`: `a_0 = 0`,
/// `a_{i+1} = a_i + |P_{i+1} - P_i|`. Returns the total length.
pub fn chord_params<const D: usize>(points: &[[f64; D]], out: &mut [f64]) -> f64 {
    let mut acc = 0.0;
    for (i, p) in points.iter().enumerate() {
        if i > 0 {
            acc += dist(&points[i - 1], p);
        }
        if let Some(o) = out.get_mut(i) {
            *o = acc;
        }
    }
    acc
}

/// Euclidean distance.
pub fn dist<const D: usize>(a: &[f64; D], b: &[f64; D]) -> f64 {
    let mut s = 0.0;
    for k in 0..D {
        let d = a[k] - b[k];
        s += d * d;
    }
    libm::sqrt(s)
}

/// A cubic B-spline in `D` dimensions with at most `N` control points (`N - 2` data points).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct CubicBSpline<const D: usize, const N: usize> {
    /// Number of data points minus one (`n`); the spline has `n + 3` control points.
    n: usize,
    /// The distinct knots `a_0 .. a_n` (the data points' parameters).
    a: [f64; N],
    /// Control points `Q_0 .. Q_{n+2}`.
    q: [[f64; D]; N],
}

impl<const D: usize, const N: usize> CubicBSpline<D, N> {
    /// The most data points a spline holds.
    pub const MAX_POINTS: usize = N - 2;

    /// A constant spline at the origin on [0, 1]; a placeholder for fixed arrays.
    pub const EMPTY: Self = CubicBSpline {
        n: 1,
        a: {
            let mut a = [0.0; N];
            a[1] = 1.0;
            a
        },
        q: [[0.0; D]; N],
    };

    /// The interpolant through `points` at chord-length parameters with natural ends.
    pub fn through(points: &[[f64; D]]) -> Result<Self, SplineError> {
        let mut params = [0.0; N];
        if points.len() > N - 2 {
            return Err(SplineError::TooManyPoints {
                found: points.len(),
                max: N - 2,
            });
        }
        chord_params(points, &mut params);
        Self::interpolate(&params[..points.len()], points, End::Natural, End::Natural)
    }

    /// The interpolant through `points[i]` at parameter `params[i]` with the given ends.
    pub fn interpolate(
        params: &[f64],
        points: &[[f64; D]],
        start: End<D>,
        end: End<D>,
    ) -> Result<Self, SplineError> {
        let m = points.len();
        if params.len() != m {
            return Err(SplineError::LengthMismatch {
                params: params.len(),
                points: m,
            });
        }
        if m < 2 {
            return Err(SplineError::TooFewPoints { found: m });
        }
        if m > N - 2 {
            return Err(SplineError::TooManyPoints {
                found: m,
                max: N - 2,
            });
        }
        for i in 0..m {
            if !params[i].is_finite() || points[i].iter().any(|c| !c.is_finite()) {
                return Err(SplineError::NotFinite { index: i });
            }
            if i > 0 && params[i] <= params[i - 1] {
                return Err(SplineError::NotIncreasing { index: i });
            }
        }
        for e in [&start, &end] {
            if let End::Slope(v) = e {
                if v.iter().any(|c| !c.is_finite()) {
                    return Err(SplineError::NotFinite {
                        index: if core::ptr::eq(e, &start) { 0 } else { m - 1 },
                    });
                }
            }
        }
        let n = m - 1;
        let mut s = CubicBSpline {
            n,
            a: [0.0; N],
            q: [[0.0; D]; N],
        };
        s.a[..m].copy_from_slice(params);

        // Tridiagonal rows 0 ..= n + 2 over the control points Q_0 .. Q_{n+2}.
        let rows = n + 3;
        let mut sub = [0.0; N];
        let mut diag = [0.0; N];
        let mut sup = [0.0; N];
        let mut rhs = [[0.0; D]; N];
        diag[0] = 1.0;
        rhs[0] = points[0];
        // Start condition, span 0 (control points Q_0..Q_3).
        let d0 = s.basis_ders(0, s.a[0]);
        match start {
            End::Natural => {
                sub[1] = d0[2][0];
                diag[1] = d0[2][1];
                sup[1] = d0[2][2];
            }
            End::Slope(v) => {
                sub[1] = d0[1][0];
                diag[1] = d0[1][1];
                sup[1] = d0[1][2];
                rhs[1] = v;
            }
        }
        // Interior points j = 1 .. n-1: span j, control points Q_j..Q_{j+3}.
        for j in 1..n {
            let b = s.basis_ders(j, s.a[j]);
            sub[j + 1] = b[0][0];
            diag[j + 1] = b[0][1];
            sup[j + 1] = b[0][2];
            rhs[j + 1] = points[j];
        }
        // End condition, span n-1 (control points Q_{n-1}..Q_{n+2}).
        let dn = s.basis_ders(n - 1, s.a[n]);
        match end {
            End::Natural => {
                sub[n + 1] = dn[2][1];
                diag[n + 1] = dn[2][2];
                sup[n + 1] = dn[2][3];
            }
            End::Slope(v) => {
                sub[n + 1] = dn[1][1];
                diag[n + 1] = dn[1][2];
                sup[n + 1] = dn[1][3];
                rhs[n + 1] = v;
            }
        }
        diag[n + 2] = 1.0;
        rhs[n + 2] = points[n];

        // Thomas algorithm.
        for r in 1..rows {
            let piv = diag[r - 1];
            if piv == 0.0 || !piv.is_finite() {
                return Err(SplineError::Singular);
            }
            let w = sub[r] / piv;
            diag[r] -= w * sup[r - 1];
            for k in 0..D {
                rhs[r][k] -= w * rhs[r - 1][k];
            }
        }
        if diag[rows - 1] == 0.0 {
            return Err(SplineError::Singular);
        }
        for k in 0..D {
            s.q[rows - 1][k] = rhs[rows - 1][k] / diag[rows - 1];
        }
        for r in (0..rows - 1).rev() {
            for k in 0..D {
                s.q[r][k] = (rhs[r][k] - sup[r] * s.q[r + 1][k]) / diag[r];
            }
        }
        if s.q[..rows].iter().flatten().any(|c| !c.is_finite()) {
            return Err(SplineError::Singular);
        }
        Ok(s)
    }

    /// Number of data points.
    pub fn len(&self) -> usize {
        self.n + 1
    }

    /// Always false: a spline has at least two points.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// The data points' parameters (the distinct knots).
    pub fn params(&self) -> &[f64] {
        &self.a[..=self.n]
    }

    /// The parameter range `[a_0, a_n]`.
    pub fn domain(&self) -> (f64, f64) {
        (self.a[0], self.a[self.n])
    }

    /// The control points.
    pub fn control_points(&self) -> &[[f64; D]] {
        &self.q[..self.n + 3]
    }

    /// Knot `i` of the full (clamped) knot vector.
    #[inline]
    fn knot(&self, i: usize) -> f64 {
        let j = i.saturating_sub(3);
        self.a[if j > self.n { self.n } else { j }]
    }

    /// The span `k` (0 ..= n-1) with `a_k <= u < a_{k+1}`; clamps outside the domain.
    fn span(&self, u: f64) -> usize {
        let n = self.n;
        if u >= self.a[n - 1] || n == 1 {
            return n - 1;
        }
        if u <= self.a[1] {
            return 0;
        }
        // Binary search for the last a_k <= u.
        let (mut lo, mut hi) = (1, n - 1);
        while hi - lo > 1 {
            let mid = (lo + hi) / 2;
            if self.a[mid] <= u {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        lo
    }

    /// Values, first and second derivatives of the four cubic basis functions that are
    /// non-zero on span `k` (control points `Q_k .. Q_{k+3}`) at `u` (The NURBS Book, A2.3).
    fn basis_ders(&self, k: usize, u: f64) -> [[f64; 4]; 3] {
        const P: usize = 3;
        let i = k + 3; // knot span index in the full knot vector
        let mut ndu = [[0.0f64; 4]; 4];
        let mut left = [0.0f64; 4];
        let mut right = [0.0f64; 4];
        ndu[0][0] = 1.0;
        for j in 1..=P {
            left[j] = u - self.knot(i + 1 - j);
            right[j] = self.knot(i + j) - u;
            let mut saved = 0.0;
            for r in 0..j {
                ndu[j][r] = right[r + 1] + left[j - r];
                let temp = ndu[r][j - 1] / ndu[j][r];
                ndu[r][j] = saved + right[r + 1] * temp;
                saved = left[j - r] * temp;
            }
            ndu[j][j] = saved;
        }
        let mut ders = [[0.0f64; 4]; 3];
        for j in 0..=P {
            ders[0][j] = ndu[j][P];
        }
        for r in 0..=P as isize {
            let mut a = [[0.0f64; 4]; 2];
            let (mut s1, mut s2) = (0usize, 1usize);
            a[0][0] = 1.0;
            for kk in 1..=2isize {
                let mut d = 0.0;
                let rk = r - kk;
                let pk = P as isize - kk;
                if r >= kk {
                    a[s2][0] = a[s1][0] / ndu[(pk + 1) as usize][rk as usize];
                    d = a[s2][0] * ndu[rk as usize][pk as usize];
                }
                let j1 = if rk >= -1 { 1 } else { -rk };
                let j2 = if r - 1 <= pk { kk - 1 } else { P as isize - r };
                let mut j = j1;
                while j <= j2 {
                    let ju = j as usize;
                    a[s2][ju] =
                        (a[s1][ju] - a[s1][ju - 1]) / ndu[(pk + 1) as usize][(rk + j) as usize];
                    d += a[s2][ju] * ndu[(rk + j) as usize][pk as usize];
                    j += 1;
                }
                if r <= pk {
                    let ku = kk as usize;
                    a[s2][ku] = -a[s1][ku - 1] / ndu[(pk + 1) as usize][r as usize];
                    d += a[s2][ku] * ndu[r as usize][pk as usize];
                }
                ders[kk as usize][r as usize] = d;
                core::mem::swap(&mut s1, &mut s2);
            }
        }
        let mut f = P as f64;
        for (kk, row) in ders.iter_mut().enumerate().skip(1) {
            for v in row.iter_mut() {
                *v *= f;
            }
            f *= (P - kk) as f64;
        }
        ders
    }

    /// The point at `u` (clamped to the domain).
    pub fn eval(&self, u: f64) -> [f64; D] {
        self.eval_derivs(u)[0]
    }

    /// The point, first and second derivatives at `u` (clamped to the domain).
    pub fn eval_derivs(&self, u: f64) -> [[f64; D]; 3] {
        let (lo, hi) = self.domain();
        let u = if u < lo {
            lo
        } else if u > hi {
            hi
        } else {
            u
        };
        self.eval_on_span(self.span(u), u)
    }

    /// As [`Self::eval_derivs`], but on span `k` (`a_k <= u <= a_{k+1}`): evaluating both
    /// neighbouring spans at a knot checks continuity there.
    pub fn eval_on_span(&self, k: usize, u: f64) -> [[f64; D]; 3] {
        let k = if k >= self.n { self.n - 1 } else { k };
        let b = self.basis_ders(k, u);
        let mut out = [[0.0; D]; 3];
        for (d, row) in b.iter().enumerate() {
            for (j, w) in row.iter().enumerate() {
                for c in 0..D {
                    out[d][c] += w * self.q[k + j][c];
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_points_give_a_straight_line() {
        let s = CubicBSpline::<2, 8>::through(&[[0.0, 0.0], [3.0, 4.0]]).unwrap();
        assert_eq!(s.domain(), (0.0, 5.0));
        let p = s.eval(2.5);
        assert!((p[0] - 1.5).abs() < 1e-12 && (p[1] - 2.0).abs() < 1e-12);
        let d = s.eval_derivs(1.0);
        assert!((d[1][0] - 0.6).abs() < 1e-12 && d[2][0].abs() < 1e-12);
    }

    #[test]
    fn reproduces_a_cubic_with_exact_slopes() {
        // f(u) = u^3 - 2u: a clamped interpolant with the true end slopes reproduces it.
        let f = |u: f64| u * u * u - 2.0 * u;
        let df = |u: f64| 3.0 * u * u - 2.0;
        let us = [0.0, 0.3, 1.1, 1.5, 2.6, 3.0];
        let ps: [[f64; 1]; 6] = us.map(|u| [f(u)]);
        let s = CubicBSpline::<1, 8>::interpolate(
            &us,
            &ps,
            End::Slope([df(0.0)]),
            End::Slope([df(3.0)]),
        )
        .unwrap();
        for i in 0..=60 {
            let u = i as f64 * 0.05;
            let d = s.eval_derivs(u);
            assert!((d[0][0] - f(u)).abs() < 1e-9, "u {u}");
            assert!((d[1][0] - df(u)).abs() < 1e-9);
            assert!((d[2][0] - 6.0 * u).abs() < 1e-8);
        }
    }
}
