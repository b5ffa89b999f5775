//! Small dense linear algebra for the spine's solver: Cholesky factors of fixed-size
//! symmetric matrices, and the bound-constrained quadratic program its constraint
//! multipliers come from.

// Triangular solves walk rows and columns of one array by index.
#![allow(clippy::needless_range_loop)]

/// Factors the leading `n x n` block of the symmetric `a` (its lower triangle is read) into
/// `L L^T`, in place in the lower triangle. `false` when it is not numerically positive
/// definite (a pivot below `tiny` times the largest diagonal entry, or not finite).
pub(crate) fn cholesky<const N: usize>(a: &mut [[f64; N]; N], n: usize) -> bool {
    let mut biggest = 0.0f64;
    for i in 0..n {
        biggest = biggest.max(a[i][i].abs());
    }
    let floor = 1e-14 * biggest.max(f64::MIN_POSITIVE);
    for j in 0..n {
        let mut d = a[j][j];
        for k in 0..j {
            d -= a[j][k] * a[j][k];
        }
        // Also refuses a NaN pivot.
        if d.is_nan() || d <= floor {
            return false;
        }
        let d = libm::sqrt(d);
        a[j][j] = d;
        for i in j + 1..n {
            let mut s = a[i][j];
            for k in 0..j {
                s -= a[i][k] * a[j][k];
            }
            a[i][j] = s / d;
        }
    }
    true
}

/// Solves `L y = b` in place (`L` from [`cholesky`]).
pub(crate) fn forward<const N: usize>(l: &[[f64; N]; N], n: usize, b: &mut [f64; N]) {
    for i in 0..n {
        let mut s = b[i];
        for k in 0..i {
            s -= l[i][k] * b[k];
        }
        b[i] = s / l[i][i];
    }
}

/// Solves `L^T x = y` in place.
pub(crate) fn backward<const N: usize>(l: &[[f64; N]; N], n: usize, b: &mut [f64; N]) {
    for i in (0..n).rev() {
        let mut s = b[i];
        for k in i + 1..n {
            s -= l[k][i] * b[k];
        }
        b[i] = s / l[i][i];
    }
}

/// Solves `L L^T x = b` in place.
pub(crate) fn solve<const N: usize>(l: &[[f64; N]; N], n: usize, b: &mut [f64; N]) {
    forward(l, n, b);
    backward(l, n, b);
}

/// Minimises `lam^T M lam / 2 + h^T lam` over `0 <= lam_i <= hi` for the leading `m x m` block
/// of the symmetric positive semidefinite `M`, by a primal active-set method from `lam = 0`
/// (a feasible start: the bounds are the only constraints). Each pass solves the free
/// variables' equations exactly (with a relative `1e-12` ridge, so dependent rows still
/// factor); a pass either adds a bound that blocks the step to that solution or frees the
/// bound variable whose gradient most wants in. At most `4 m + 4` passes; `false` if they
/// ran out or a factorisation failed, with `lam` the feasible point reached.
pub(crate) fn box_qp<const N: usize>(
    m: usize,
    mm: &[[f64; N]; N],
    h: &[f64; N],
    hi: f64,
    lam: &mut [f64; N],
) -> bool {
    // 0: at the lower bound, 1: free, 2: at the upper bound.
    let mut state = [0u8; N];
    *lam = [0.0; N];
    let mut scale = 0.0f64;
    for i in 0..m {
        scale = scale.max(mm[i][i].abs()).max(h[i].abs());
    }
    let tol = 1e-13 * scale.max(1e-300);
    let ridge = 1e-12 * scale.max(1e-300);
    for _ in 0..4 * m + 4 {
        // The free variables' index list and equations M_FF x = -(h_F + M_FB lam_B).
        let mut idx = [0usize; N];
        let mut nf = 0;
        for i in 0..m {
            if state[i] == 1 {
                idx[nf] = i;
                nf += 1;
            }
        }
        let mut a = [[0.0; N]; N];
        let mut rhs = [0.0; N];
        for r in 0..nf {
            let i = idx[r];
            let mut s = -h[i];
            for j in 0..m {
                if state[j] != 1 {
                    s -= mm[i][j] * lam[j];
                }
            }
            rhs[r] = s;
            for c in 0..nf {
                a[r][c] = mm[i][idx[c]];
            }
            a[r][r] += ridge;
        }
        if nf > 0 {
            if !cholesky(&mut a, nf) {
                return false;
            }
            solve(&a, nf, &mut rhs);
        }
        // The longest step toward the free solution that keeps every bound.
        let mut t = 1.0f64;
        let mut block = usize::MAX;
        let mut block_upper = false;
        for r in 0..nf {
            let i = idx[r];
            let (from, to) = (lam[i], rhs[r]);
            if to < 0.0 && from - to > 0.0 {
                let s = from / (from - to);
                if s < t {
                    t = s;
                    block = i;
                    block_upper = false;
                }
            } else if to > hi && to - from > 0.0 {
                let s = (hi - from) / (to - from);
                if s < t {
                    t = s;
                    block = i;
                    block_upper = true;
                }
            }
        }
        for r in 0..nf {
            let i = idx[r];
            lam[i] = (lam[i] + t * (rhs[r] - lam[i])).clamp(0.0, hi);
        }
        if block != usize::MAX {
            (state[block], lam[block]) = if block_upper { (2, hi) } else { (0, 0.0) };
            continue;
        }
        // At the free optimum: a bound variable whose gradient points into the box frees.
        let mut worst = tol;
        let mut enter = usize::MAX;
        for i in 0..m {
            if state[i] == 1 {
                continue;
            }
            let mut g = h[i];
            for j in 0..m {
                g += mm[i][j] * lam[j];
            }
            let want = if state[i] == 0 { -g } else { g };
            if want > worst {
                worst = want;
                enter = i;
            }
        }
        if enter == usize::MAX {
            return true;
        }
        state[enter] = 1;
    }
    false
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cholesky_solves() {
        let mut a = [[4.0, 0.0, 0.0], [2.0, 5.0, 0.0], [0.4, 1.0, 3.0]];
        // Mirror the lower triangle for the check.
        let full = [[4.0, 2.0, 0.4], [2.0, 5.0, 1.0], [0.4, 1.0, 3.0]];
        assert!(cholesky(&mut a, 3));
        let mut b = [1.0, -2.0, 0.5];
        solve(&a, 3, &mut b);
        for i in 0..3 {
            let r: f64 = (0..3).map(|j| full[i][j] * b[j]).sum();
            assert!((r - [1.0, -2.0, 0.5][i]).abs() < 1e-14);
        }
        let mut indefinite = [[1.0, 0.0], [2.0, 1.0]];
        assert!(!cholesky(&mut indefinite, 2));
    }

    /// The active-set answer against every sign pattern's KKT check, on small problems.
    #[test]
    fn box_qp_meets_the_kkt_conditions() {
        let mut seed = 0x9E37_79B9_7F4A_7C15u64;
        let mut rnd = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for case in 0..500usize {
            let m = 1 + case % 5;
            // M = B B^T, sometimes rank deficient (B with fewer columns than rows).
            let cols = if case % 3 == 0 {
                m.saturating_sub(1).max(1)
            } else {
                m
            };
            let mut b = [[0.0; 5]; 5];
            for r in b.iter_mut().take(m) {
                for v in r.iter_mut().take(cols) {
                    *v = rnd();
                }
            }
            let mut mm = [[0.0; 5]; 5];
            for i in 0..m {
                for j in 0..m {
                    mm[i][j] = (0..cols).map(|k| b[i][k] * b[j][k]).sum();
                }
            }
            let mut h = [0.0; 5];
            for v in h.iter_mut().take(m) {
                *v = 3.0 * rnd();
            }
            let hi = 2.0;
            let mut lam = [0.0; 5];
            assert!(box_qp(m, &mm, &h, hi, &mut lam), "case {case}");
            for i in 0..m {
                let g: f64 = h[i] + (0..m).map(|j| mm[i][j] * lam[j]).sum::<f64>();
                assert!((0.0..=hi).contains(&lam[i]));
                if lam[i] <= 1e-12 {
                    assert!(g >= -1e-8, "case {case}: {g}");
                } else if lam[i] >= hi - 1e-12 {
                    assert!(g <= 1e-8, "case {case}: {g}");
                } else {
                    assert!(g.abs() < 1e-8, "case {case}: {g}");
                }
            }
        }
    }
}
