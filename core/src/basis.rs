//! Regression bases for error functions (paper, section 5).
//!
//! Polynomial bases take the axis position mapped to [−1, 1] over its travel range; periodic
//! bases take the rotary axis' angle in rad. Every basis evaluates its value and its derivative
//! with respect to each coefficient; all are linear in their coefficients except the sine series
//! with phases.
//!
//! | basis | parameters | function |
//! |---|---|---|
//! | `monomial` degree n | `c0..cn` | Σ cᵢ ξⁱ (eq. 13) |
//! | `legendre` degree n | `c0..cn` | Σ cᵢ Pᵢ(ξ) (eq. 17) |
//! | `chebyshev` m nodes | `n1..nm` | the degree-(m−1) polynomial through the values nᵢ at the Chebyshev nodes zᵢ = −cos((2i−1)π/2m) (eq. 14–16) |
//! | `fourier` order K | `d, a1, b1 … aK, bK` | d + Σ aₖ sin kθ + bₖ cos kθ (eq. 20 with the harmonic index) |
//! | `sine` order K | `d, a1, phi1 … aK, phiK` | d + Σ aₖ sin(kθ + φₖ) (eq. 21 with the harmonic index) |
//! | `constant` | the error's name | a constant (location and squareness errors) |

use crate::scalar::{Real, legendre_p, three_term};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::fmt;

/// Gauss–Legendre quadrature, re-exported from [`crate::scalar`] where it lives (kept at this
/// path for existing users).
pub use crate::scalar::gauss_legendre;

/// Most coefficients one error function may have.
pub const MAX_COEFFS: usize = 32;

/// Why [`Basis::new`] cannot build a basis.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum BasisError {
    /// A degree or order that alone reaches [`MAX_COEFFS`] (checked before any count is computed).
    #[error("{kind} of degree/order {degree}: at most {MAX_COEFFS} coefficients are supported")]
    DegreeTooHigh {
        /// The basis kind.
        kind: BasisKind,
        /// The degree or order asked for.
        degree: usize,
    },
    /// A degree or order whose number of coefficients exceeds [`MAX_COEFFS`].
    #[error(
        "{kind} of degree/order {degree} has {count} coefficients; at most {MAX_COEFFS} are supported"
    )]
    TooManyCoefficients {
        /// The basis kind.
        kind: BasisKind,
        /// The degree or order asked for.
        degree: usize,
        /// Its number of coefficients.
        count: usize,
    },
    /// A periodic series of order 0.
    #[error("{kind} needs an order of at least 1 (harmonics)")]
    NoHarmonics {
        /// The basis kind (fourier or sine).
        kind: BasisKind,
    },
}

impl From<BasisError> for String {
    fn from(e: BasisError) -> String {
        e.to_string()
    }
}

/// The kind of a basis, as named in error-model files.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[non_exhaustive]
pub enum BasisKind {
    /// A constant value (location and squareness errors).
    Constant,
    /// Simple polynomial in the normalised position (eq. 13).
    Monomial,
    /// Legendre polynomials (eq. 17).
    Legendre,
    /// Chebyshev polynomials parametrised by their values at the Chebyshev nodes (eq. 16).
    Chebyshev,
    /// Fourier series with true harmonics (eq. 20).
    Fourier,
    /// Sine series with phases (eq. 21); non-linear in the phases.
    Sine,
}

impl BasisKind {
    /// `true` for the Fourier and sine series (rotary axes only).
    pub fn is_periodic(self) -> bool {
        matches!(self, BasisKind::Fourier | BasisKind::Sine)
    }
}

impl fmt::Display for BasisKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            BasisKind::Constant => "constant",
            BasisKind::Monomial => "monomial",
            BasisKind::Legendre => "legendre",
            BasisKind::Chebyshev => "chebyshev",
            BasisKind::Fourier => "fourier",
            BasisKind::Sine => "sine",
        })
    }
}

/// A basis ready to evaluate.
///
/// ```
/// use volver_core::basis::{Basis, BasisKind};
/// // Chebyshev by node values: the parameters are the function's values at the nodes.
/// let b = Basis::new(BasisKind::Chebyshev, 3).unwrap(); // 4 nodes, cubic
/// let nodes = b.chebyshev_nodes().unwrap();
/// let values = [0.1, -0.2, 0.3, 0.05];
/// for (z, v) in nodes.iter().zip(values) {
///     assert!((b.value(*z, &values) - v).abs() < 1e-14);
/// }
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct Basis {
    kind: BasisKind,
    /// Degree (polynomials; m − 1 for m Chebyshev nodes) or order (periodic).
    degree: usize,
    /// Chebyshev only: `card[i * m + j]` = coefficient of T_j in the cardinal function of node i.
    card: Vec<f64>,
}

impl Basis {
    /// A basis of a kind and degree (polynomials: degree; Chebyshev: degree = nodes − 1;
    /// periodic: order = number of harmonics; constant: ignored).
    pub fn new(kind: BasisKind, degree: usize) -> Result<Basis, BasisError> {
        let degree = if kind == BasisKind::Constant {
            0
        } else {
            degree
        };
        // Checked before any count is computed: a degree near usize::MAX would wrap
        // `degree + 1` (or `1 + 2 · order`) to a small number.
        if degree >= MAX_COEFFS {
            return Err(BasisError::DegreeTooHigh { kind, degree });
        }
        let b = Basis {
            kind,
            degree,
            card: Vec::new(),
        };
        if b.n_params() > MAX_COEFFS {
            return Err(BasisError::TooManyCoefficients {
                kind,
                degree,
                count: b.n_params(),
            });
        }
        if kind.is_periodic() && degree == 0 {
            return Err(BasisError::NoHarmonics { kind });
        }
        if kind == BasisKind::Chebyshev {
            let m = degree + 1;
            let nodes = chebyshev_nodes(m);
            let mut card = vec![0.0; m * m];
            let mut t = [0.0; MAX_COEFFS];
            for (i, &z) in nodes.iter().enumerate() {
                chebyshev_t(z, &mut t[..m]);
                card[i * m] = 1.0 / m as f64;
                for j in 1..m {
                    card[i * m + j] = 2.0 / m as f64 * t[j];
                }
            }
            return Ok(Basis { card, ..b });
        }
        Ok(b)
    }

    /// The kind.
    pub fn kind(&self) -> BasisKind {
        self.kind
    }

    /// Degree (polynomials), nodes − 1 (Chebyshev) or order (periodic).
    pub fn degree(&self) -> usize {
        self.degree
    }

    /// Number of coefficients.
    pub fn n_params(&self) -> usize {
        match self.kind {
            BasisKind::Constant => 1,
            BasisKind::Monomial | BasisKind::Legendre | BasisKind::Chebyshev => self.degree + 1,
            BasisKind::Fourier | BasisKind::Sine => 1 + 2 * self.degree,
        }
    }

    /// `true` when the value is linear in the coefficients (all but the sine series).
    pub fn is_linear(&self) -> bool {
        self.kind != BasisKind::Sine
    }

    /// Coefficient suffixes used in parameter names (`c0`, `n1`, `d`, `a1`, `b1`, `phi1` …);
    /// empty for a constant (the parameter is named after the error itself).
    pub fn suffixes(&self) -> Vec<String> {
        match self.kind {
            BasisKind::Constant => vec![String::new()],
            BasisKind::Monomial | BasisKind::Legendre => {
                (0..=self.degree).map(|i| format!("c{i}")).collect()
            }
            BasisKind::Chebyshev => (1..=self.degree + 1).map(|i| format!("n{i}")).collect(),
            BasisKind::Fourier | BasisKind::Sine => {
                let second = if self.kind == BasisKind::Fourier {
                    "b"
                } else {
                    "phi"
                };
                let mut v = vec!["d".to_string()];
                for k in 1..=self.degree {
                    v.push(format!("a{k}"));
                    v.push(format!("{second}{k}"));
                }
                v
            }
        }
    }

    /// `true` when a coefficient is an angle (the phases of the sine series), whose unit is rad
    /// whatever the error's unit.
    pub fn is_phase(&self, coeff: usize) -> bool {
        self.kind == BasisKind::Sine && coeff > 0 && coeff.is_multiple_of(2)
    }

    /// The Chebyshev nodes (for a Chebyshev basis).
    pub fn chebyshev_nodes(&self) -> Option<Vec<f64>> {
        (self.kind == BasisKind::Chebyshev).then(|| chebyshev_nodes(self.degree + 1))
    }

    /// Value at `x` (normalised position or angle) and its derivative with respect to every
    /// coefficient, written to `grad` (`grad.len() == n_params()`).
    #[inline]
    pub fn eval(&self, x: f64, coeffs: &[f64], grad: &mut [f64]) -> f64 {
        self.eval_at(x, coeffs, grad)
    }

    /// [`Basis::eval`] with the argument a scalar of the forward model: with `x` a dual number,
    /// the value carries its exact derivative with respect to the position (the inverse model
    /// differentiates the errors along the commands this way). `grad` holds the basis functions
    /// at `x` (for the sine series, the derivatives with respect to amplitudes and phases).
    #[inline]
    pub fn eval_at<S: Real>(&self, x: S, coeffs: &[f64], grad: &mut [S]) -> S {
        debug_assert_eq!(coeffs.len(), self.n_params());
        debug_assert_eq!(grad.len(), self.n_params());
        match self.kind {
            BasisKind::Constant => {
                grad[0] = S::one();
                S::from(coeffs[0])
            }
            BasisKind::Monomial => {
                let mut p = S::one();
                for g in grad.iter_mut() {
                    *g = p;
                    p *= x;
                }
                dot(coeffs, grad)
            }
            BasisKind::Legendre => {
                legendre_p(x, grad);
                dot(coeffs, grad)
            }
            BasisKind::Chebyshev => {
                let m = self.degree + 1;
                let mut t = [S::zero(); MAX_COEFFS];
                chebyshev_t(x, &mut t[..m]);
                for (i, g) in grad.iter_mut().enumerate() {
                    *g = dot(&self.card[i * m..(i + 1) * m], &t[..m]);
                }
                dot(coeffs, grad)
            }
            BasisKind::Fourier => {
                grad[0] = S::one();
                let (s1, c1) = x.sin_cos();
                let (mut s, mut c) = (S::zero(), S::one());
                for k in 0..self.degree {
                    (s, c) = (s * c1 + c * s1, c * c1 - s * s1);
                    grad[1 + 2 * k] = s;
                    grad[2 + 2 * k] = c;
                }
                dot(coeffs, grad)
            }
            BasisKind::Sine => {
                grad[0] = S::one();
                let mut v = S::from(coeffs[0]);
                for k in 0..self.degree {
                    let (a, phi) = (coeffs[1 + 2 * k], coeffs[2 + 2 * k]);
                    let (s, c) = (x * (k + 1) as f64 + phi).sin_cos();
                    grad[1 + 2 * k] = s;
                    grad[2 + 2 * k] = c * a;
                    v += s * a;
                }
                v
            }
        }
    }

    /// Second derivative of the value at `x` along the coefficient direction `dir`:
    /// `d²/dt² value(x, coeffs + t·dir)` at t = 0. Zero for a basis linear in its coefficients;
    /// for the sine series, `Σ 2 da dφ cos(kx + φ) − a dφ² sin(kx + φ)` over its harmonics.
    pub fn second_directional(&self, x: f64, coeffs: &[f64], dir: &[f64]) -> f64 {
        debug_assert_eq!(coeffs.len(), self.n_params());
        debug_assert_eq!(dir.len(), self.n_params());
        if self.kind != BasisKind::Sine {
            return 0.0;
        }
        (0..self.degree)
            .map(|k| {
                let (a, phi) = (coeffs[1 + 2 * k], coeffs[2 + 2 * k]);
                let (da, dphi) = (dir[1 + 2 * k], dir[2 + 2 * k]);
                let (s, c) = ((k + 1) as f64 * x + phi).sin_cos();
                2.0 * da * dphi * c - a * dphi * dphi * s
            })
            .sum()
    }

    /// Value at `x` (normalised position or angle).
    pub fn value(&self, x: f64, coeffs: &[f64]) -> f64 {
        let mut g = [0.0; MAX_COEFFS];
        self.eval(x, coeffs, &mut g[..self.n_params()])
    }

    /// For a basis linear in its coefficients: the coefficients' weights in the Legendre P1
    /// component of the function over [−1, 1], `(3/2)∫ f(ξ) ξ dξ` — the slope of its best-fit line
    /// per normalised unit. Used by the squareness-from-straightness rule.
    pub fn linear_component(&self) -> Vec<f64> {
        let n = self.n_params();
        let mut w = vec![0.0; n];
        let mut g = [0.0; MAX_COEFFS];
        let zeros = [0.0; MAX_COEFFS];
        for (x, wq) in gauss_legendre(MAX_COEFFS) {
            self.eval(x, &zeros[..n], &mut g[..n]);
            for i in 0..n {
                w[i] += 1.5 * wq * x * g[i];
            }
        }
        w
    }
}

/// `Σ aᵢ bᵢ` with constant weights `a`.
#[inline]
fn dot<S: Real>(a: &[f64], b: &[S]) -> S {
    a.iter().zip(b).fold(S::zero(), |acc, (x, y)| acc + *y * *x)
}

/// Chebyshev T_0..T_{n−1} at x into `out` (eq. 15).
fn chebyshev_t<S: Real>(x: S, out: &mut [S]) {
    // T_{k+1} = 2x·T_k − T_{k−1}.
    three_term(x, out, |_, prev, cur| x * cur * 2.0 - prev);
}

/// The m Chebyshev nodes zᵢ = −cos((2i−1)π/2m), i = 1..m, in increasing order (eq. 16).
pub fn chebyshev_nodes(m: usize) -> Vec<f64> {
    (1..=m)
        .map(|i| -((2 * i - 1) as f64 * PI / (2 * m) as f64).cos())
        .collect()
}

#[cfg(test)]
mod tests {

    #[test]
    fn basis_errors_say_what_is_wrong() {
        assert_eq!(
            Basis::new(BasisKind::Fourier, 0),
            Err(BasisError::NoHarmonics {
                kind: BasisKind::Fourier
            })
        );
        let e = Basis::new(BasisKind::Legendre, 40).unwrap_err();
        assert_eq!(
            e,
            BasisError::DegreeTooHigh {
                kind: BasisKind::Legendre,
                degree: 40
            }
        );
        assert_eq!(
            e.to_string(),
            "legendre of degree/order 40: at most 32 coefficients are supported"
        );
        // 2 · 16 + 1 = 33 coefficients for a Fourier series of order 16.
        assert_eq!(
            Basis::new(BasisKind::Fourier, 16).unwrap_err().to_string(),
            "fourier of degree/order 16 has 33 coefficients; at most 32 are supported"
        );
    }
    use super::*;

    fn fd_check(b: &Basis, x: f64, coeffs: &[f64]) {
        let n = b.n_params();
        let mut g = vec![0.0; n];
        b.eval(x, coeffs, &mut g);
        for i in 0..n {
            let h = 1e-6;
            let mut cp = coeffs.to_vec();
            let mut cm = coeffs.to_vec();
            cp[i] += h;
            cm[i] -= h;
            let fd = (b.value(x, &cp) - b.value(x, &cm)) / (2.0 * h);
            assert!(
                (fd - g[i]).abs() <= 1e-8 * (1.0 + g[i].abs()),
                "{:?} coeff {i}: {fd} vs {}",
                b.kind,
                g[i]
            );
        }
    }

    #[test]
    fn gradients_match_finite_differences() {
        let coeffs: Vec<f64> = (0..7).map(|i| 0.3 - 0.11 * i as f64).collect();
        for (kind, deg) in [
            (BasisKind::Monomial, 6),
            (BasisKind::Legendre, 6),
            (BasisKind::Chebyshev, 6),
            (BasisKind::Fourier, 3),
            (BasisKind::Sine, 3),
            (BasisKind::Constant, 0),
        ] {
            let b = Basis::new(kind, deg).unwrap();
            let xs: &[f64] = if kind.is_periodic() {
                &[-0.3, 0.2, 2.5, 5.9]
            } else {
                &[-1.0, -0.3, 0.2, 0.9, 1.0]
            };
            for &x in xs {
                fd_check(&b, x, &coeffs[..b.n_params()]);
            }
        }
    }

    #[test]
    fn equal_degree_polynomial_bases_span_the_same_functions() {
        // f(ξ) = 1 − 2ξ + 0.5ξ³ in three bases.
        let mono = Basis::new(BasisKind::Monomial, 3).unwrap();
        let leg = Basis::new(BasisKind::Legendre, 3).unwrap();
        let cheb = Basis::new(BasisKind::Chebyshev, 3).unwrap();
        let m = [1.0, -2.0, 0.0, 0.5];
        // ξ³ = (2 P3 + 3 P1)/5
        let l = [1.0, -2.0 + 0.3, 0.0, 0.2];
        let nodes: Vec<f64> = cheb
            .chebyshev_nodes()
            .unwrap()
            .iter()
            .map(|&z| mono.value(z, &m))
            .collect();
        for x in [-1.0, -0.5, 0.1, 0.77, 1.0] {
            let v = mono.value(x, &m);
            assert!((leg.value(x, &l) - v).abs() < 1e-14);
            assert!((cheb.value(x, &nodes) - v).abs() < 1e-13);
        }
    }

    #[test]
    fn fourier_has_true_harmonics_and_sine_phase_matches() {
        let f = Basis::new(BasisKind::Fourier, 2).unwrap();
        let s = Basis::new(BasisKind::Sine, 2).unwrap();
        let th = 0.7_f64;
        let v = f.value(th, &[0.1, 0.2, 0.3, 0.4, 0.5]);
        let expect =
            0.1 + 0.2 * th.sin() + 0.3 * th.cos() + 0.4 * (2.0 * th).sin() + 0.5 * (2.0 * th).cos();
        assert!((v - expect).abs() < 1e-15);
        // a sin(kθ + φ) = a cos φ sin kθ + a sin φ cos kθ
        let (a, phi) = (0.25_f64, 0.6_f64);
        let sv = s.value(th, &[0.1, 0.0, 0.0, a, phi]);
        let fv = f.value(th, &[0.1, 0.0, 0.0, a * phi.cos(), a * phi.sin()]);
        assert!((sv - fv).abs() < 1e-15);
    }

    #[test]
    fn linear_component_is_the_best_fit_slope() {
        let leg = Basis::new(BasisKind::Legendre, 4).unwrap();
        let w = leg.linear_component();
        let expect = [0.0, 1.0, 0.0, 0.0, 0.0];
        for (a, b) in w.iter().zip(expect) {
            assert!((a - b).abs() < 1e-13, "{w:?}");
        }
        let mono = Basis::new(BasisKind::Monomial, 3).unwrap();
        // ξ³ = (2 P3 + 3 P1)/5 → slope 3/5
        assert!((mono.linear_component()[3] - 0.6).abs() < 1e-13);
    }

    #[test]
    fn names_and_limits() {
        assert_eq!(
            Basis::new(BasisKind::Sine, 1).unwrap().suffixes(),
            ["d", "a1", "phi1"]
        );
        assert_eq!(
            Basis::new(BasisKind::Chebyshev, 2).unwrap().suffixes(),
            ["n1", "n2", "n3"]
        );
        assert!(Basis::new(BasisKind::Fourier, 0).is_err());
        assert!(Basis::new(BasisKind::Legendre, 40).is_err());
    }
}
