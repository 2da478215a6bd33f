//! The scalar of the forward model and the numerical rules every layer shares: the trait
//! [`Real`] (`f64` or a forward-mode dual number), the Legendre recurrence and Gauss–Legendre
//! quadrature.
//!
//! This module imports nothing else of the crate, so that the basis functions, the kinematics,
//! the machine and the noise models can all use it without importing one another.

use num_dual::DualNum;
use std::f64::consts::PI;

/// The scalar of the forward model: `f64` or a forward-mode dual number over `f64`.
pub trait Real: DualNum<Primitive = f64> + Copy {}
impl<T: DualNum<Primitive = f64> + Copy> Real for T {}

#[inline]
/// Legendre P_0..P_{n−1} at x into `out`.
pub(crate) fn legendre_p<S: Real>(x: S, out: &mut [S]) {
    // Bonnet's recursion (k + 1)·P_{k+1} = (2k + 1)·x·P_k − k·P_{k−1}.
    three_term(x, out, |k, prev, cur| {
        let kf = (k - 1) as f64;
        (x * (2.0 * kf + 1.0) * cur - prev * kf) / (kf + 1.0)
    });
}

/// A polynomial family by its three-term recurrence: `out[0] = 1`, `out[1] = x`, and
/// `out[k] = next(k, out[k − 2], out[k − 1])`. The two previous values are kept in registers:
/// reading them back from `out` right after writing them stalls store-to-load forwarding and
/// cost most of a polynomial's evaluation.
#[inline]
pub(crate) fn three_term<S: Real>(x: S, out: &mut [S], next: impl Fn(usize, S, S) -> S) {
    let n = out.len();
    if n == 0 {
        return;
    }
    out[0] = S::one();
    if n == 1 {
        return;
    }
    out[1] = x;
    let (mut prev, mut cur) = (S::one(), x);
    for (k, o) in out.iter_mut().enumerate().skip(2) {
        let v = next(k, prev, cur);
        *o = v;
        (prev, cur) = (cur, v);
    }
}

/// Gauss–Legendre nodes and weights on [−1, 1] (Newton on P_n), exact for degree 2n − 1.
///
/// ```
/// let rule = volver_core::scalar::gauss_legendre(4);
/// let integral: f64 = rule.iter().map(|(x, w)| w * x.powi(6)).sum();
/// assert!((integral - 2.0 / 7.0).abs() < 1e-14);
/// ```
pub fn gauss_legendre(n: usize) -> Vec<(f64, f64)> {
    let mut out = Vec::with_capacity(n);
    let mut p = vec![0.0; n + 1];
    for i in 1..=n {
        let mut x = (PI * (i as f64 - 0.25) / (n as f64 + 0.5)).cos();
        let mut dp = 0.0;
        for _ in 0..100 {
            legendre_p(x, &mut p);
            dp = n as f64 * (x * p[n] - p[n - 1]) / (x * x - 1.0);
            let dx = p[n] / dp;
            x -= dx;
            if dx.abs() < 1e-16 {
                break;
            }
        }
        out.push((x, 2.0 / ((1.0 - x * x) * dp * dp)));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn legendre_values_match_closed_forms() {
        let x = 0.3_f64;
        let mut p = [0.0; 4];
        legendre_p(x, &mut p);
        let expected = [
            1.0,
            x,
            (3.0 * x * x - 1.0) / 2.0,
            (5.0 * x * x * x - 3.0 * x) / 2.0,
        ];
        for (got, want) in p.iter().zip(expected) {
            assert!((got - want).abs() < 1e-15, "{got} vs {want}");
        }
    }

    #[test]
    fn gauss_legendre_weights_sum_to_two_and_nodes_are_symmetric() {
        let rule = gauss_legendre(5);
        let total: f64 = rule.iter().map(|(_, w)| w).sum();
        assert!((total - 2.0).abs() < 1e-14);
        // The middle node of an odd rule is 0; its weight is 128/225.
        let (x, w) = rule[2];
        assert!(x.abs() < 1e-15);
        assert!((w - 128.0 / 225.0).abs() < 1e-14);
    }
}
