//! The Levenberg–Marquardt damping λ and its growth factor ν, updated by Nielsen's rule on the
//! gain ratio ρ (actual over predicted decrease), in the manner of Ceres'
//! `LevenbergMarquardtStrategy` (`StepAccepted` / `StepRejected`; Ceres' radius is 1/λ).
//!
//! * An accepted step scales λ by `max(1/3, 1 − (2ρ − 1)³)`: a step whose model was exact
//!   (ρ = 1) divides it by 3, one that gained half the prediction (ρ = ½) keeps it, and ν goes
//!   back to 2.
//! * A refused step multiplies λ by ν and doubles ν, so refusals in a row grow λ as 2, 8, 64, …
//! * A new IRLS stage (a new cost) restarts both at their initial values.
//!
//! λ is dimensionless: it multiplies Moré's scaling (the largest diagonal of the normal matrix
//! seen in the step's coordinates), so the damped system is `(H' + λ I) y = −g'` in the scaled
//! coordinates.

/// λ past which the damping is of no use ([`Damping::exhausted`]).
const LAMBDA_MAX: f64 = 1e30;

/// ν after an accepted step or a restart (Nielsen's).
const NU_START: f64 = 2.0;

/// The smallest factor an accepted step scales λ by (a step whose model was exact).
const SHRINK_MIN: f64 = 1.0 / 3.0;

/// The damping λ and its growth factor ν (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Damping {
    /// The current λ (dimensionless, relative to Moré's scaling).
    lambda: f64,
    /// The factor the next refusal multiplies λ by.
    nu: f64,
    /// λ at the start and at each restart ([`crate::Options::initial_damping`]).
    initial: f64,
}

impl Damping {
    /// The damping at the start of a run: λ = `initial`, ν = 2.
    pub(crate) fn new(initial: f64) -> Damping {
        Damping {
            lambda: initial,
            nu: NU_START,
            initial,
        }
    }

    /// The current λ.
    pub(crate) fn lambda(&self) -> f64 {
        self.lambda
    }

    /// A step was accepted with gain ratio `rho`: λ scaled by `max(1/3, 1 − (2ρ − 1)³)`, ν back
    /// to 2.
    pub(crate) fn accepted(&mut self, rho: f64) {
        self.lambda *= (1.0 - (2.0 * rho - 1.0).powi(3)).max(SHRINK_MIN);
        self.nu = NU_START;
    }

    /// A step was refused: λ multiplied by ν, ν doubled.
    pub(crate) fn rejected(&mut self) {
        self.lambda *= self.nu;
        self.nu *= 2.0;
    }

    /// A new stage: λ and ν back to their initial values.
    pub(crate) fn restart(&mut self) {
        self.lambda = self.initial;
        self.nu = NU_START;
    }

    /// Whether λ has grown past any use (above 1e30, or not finite).
    pub(crate) fn exhausted(&self) -> bool {
        !self.lambda.is_finite() || self.lambda > LAMBDA_MAX
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_exact_model_divides_lambda_by_three() {
        let mut d = Damping::new(1e-4);
        d.accepted(1.0);
        assert_eq!(d.lambda(), 1e-4 / 3.0);
        // A gain above the prediction (ρ > 1) shrinks no further.
        d.accepted(1.7);
        assert_eq!(d.lambda(), 1e-4 / 3.0 / 3.0);
    }

    #[test]
    fn accepted_steps_follow_nielsen_by_hand() {
        // ρ = ½: 1 − 0³ = 1, λ kept.
        let mut d = Damping::new(0.5);
        d.accepted(0.5);
        assert_eq!(d.lambda(), 0.5);
        // ρ = ¾: 1 − (½)³ = 7/8.
        d.accepted(0.75);
        assert_eq!(d.lambda(), 0.4375);
        // ρ = ¼: 1 − (−½)³ = 9/8.
        d.accepted(0.25);
        assert_eq!(d.lambda(), 0.4375 * 1.125);
        // ρ just above the acceptance threshold: 1 − (−1 + 2e-4)³ ≈ 2, the largest growth.
        let mut d = Damping::new(1.0);
        d.accepted(1e-4);
        assert!((d.lambda() - 2.0).abs() < 2e-3, "{}", d.lambda());
    }

    #[test]
    fn rejections_grow_lambda_by_nu_and_double_nu() {
        let mut d = Damping::new(1e-4);
        d.rejected();
        assert_eq!(d.lambda(), 2e-4);
        d.rejected();
        assert_eq!(d.lambda(), 8e-4);
        d.rejected();
        assert_eq!(d.lambda(), 6.4e-3);
        // An accepted step resets ν: the next refusal doubles λ again.
        d.accepted(0.5);
        assert_eq!(d.lambda(), 6.4e-3);
        d.rejected();
        assert_eq!(d.lambda(), 1.28e-2);
    }

    #[test]
    fn restart_restores_the_start() {
        let mut d = Damping::new(1e-4);
        d.rejected();
        d.rejected();
        d.accepted(0.9);
        d.rejected();
        d.restart();
        assert_eq!(d, Damping::new(1e-4));
    }

    #[test]
    fn bounds_hold() {
        // No accepted step shrinks λ by more than 3, whatever ρ.
        for rho in [1e-4, 0.1, 0.5, 0.9, 1.0, 2.0, 1e6] {
            let mut d = Damping::new(1.0);
            d.accepted(rho);
            assert!(d.lambda() >= 1.0 / 3.0 && d.lambda() <= 2.0, "ρ = {rho}");
        }
        // Refusals in a row exhaust it past 1e30, and an infinite λ is exhausted too.
        let mut d = Damping::new(1e-4);
        let mut refusals = 0;
        while !d.exhausted() {
            d.rejected();
            refusals += 1;
        }
        // λ after k refusals is 1e-4 · 2^(k(k+1)/2), above 1e30 once k(k+1)/2 ≥ 113 (2^113 ≈
        // 1.04e34): k = 15 (k = 14 gives 2^105 ≈ 4e31, λ ≈ 4e27).
        assert_eq!(refusals, 15);
        assert!(d.lambda() > LAMBDA_MAX);
        // 1e30 itself is still of use; one refusal more is not.
        let mut d = Damping::new(LAMBDA_MAX);
        assert!(!d.exhausted());
        d.rejected();
        assert!(d.exhausted());
        let mut d = Damping::new(f64::MAX);
        d.rejected();
        assert!(d.lambda().is_infinite() && d.exhausted());
    }
}
