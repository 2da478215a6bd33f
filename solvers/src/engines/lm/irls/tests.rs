use super::*;

fn phi_options() -> Options {
    Options::default()
}

fn ve_options() -> Options {
    Options {
        objective: Objective::Ve,
        ..Options::default()
    }
}

#[test]
fn least_squares_starts_and_stays_in_newton() {
    let mut irls = Irls::new(&ve_options(), false, 2.0);
    assert_eq!(irls.stage(), Stage::Newton);
    // ve's weight is 2/n whatever ε, with no radial reduction.
    assert_eq!(irls.weight(0.3, 4), (0.5, 0.0));
    assert!(!irls.follow(1.0));
    assert!(!irls.shrink(1.0));
    irls.refused(1.0, 1.0);
    irls.refused(1.0, 1.0);
    assert!(!irls.newton_failed());
}

#[test]
fn majorising_epsilon_follows_phi() {
    let mut irls = Irls::new(&phi_options(), false, 2.0);
    assert_eq!(irls.stage(), Stage::Majorising);
    assert_eq!(irls.eps(), 0.1 * 2.0);
    assert!(irls.follow(0.5));
    assert_eq!(irls.eps(), 0.1 * 0.5);
    // The majorising model has no radial reduction: w = 1/(n √(r² + ε²)).
    let (w, c) = irls.weight(0.12, 2);
    assert_eq!(c, 0.0);
    assert!((w - 1.0 / (2.0 * 0.13)).abs() < 1e-12);
    // An exact fit's ε is floored, not zero.
    assert_eq!(Irls::new(&phi_options(), false, 0.0).eps(), TINY);
}

#[test]
fn hand_over_at_the_final_fraction() {
    let mut irls = Irls::new(&phi_options(), false, 2.0);
    irls.hand_over(0.5);
    assert_eq!(irls.stage(), Stage::Newton);
    assert_eq!(irls.eps(), 1e-9 * 0.5);
    assert!(!irls.follow(0.25), "the Newton stage's ε does not follow Φ");
    assert_eq!(irls.eps(), 1e-9 * 0.5);
    // Newton's weight carries the radial reduction r²/(r² + ε²).
    let (_, c) = irls.weight(3.0, 1);
    assert!((c - 9.0 / (9.0 + 0.25e-18)).abs() < 1e-15);
    // No continuation without scalar residuals.
    assert!(!irls.shrink(0.5));
    assert_eq!(irls.objective_tolerance(1e-12), 1e-12);
}

#[test]
fn scalar_residuals_continue_tenfold_down_to_1e_6() {
    let mut irls = Irls::new(&phi_options(), true, 1.0);
    irls.hand_over(1.0);
    // 0.1 × CONTINUATION of Φ.
    assert!((irls.eps() - 1e-2).abs() < 1e-17);
    assert!((irls.objective_tolerance(1e-12) - 1e-5).abs() < 1e-20);
    let mut fractions = Vec::new();
    while irls.shrink(1.0) {
        fractions.push(irls.eps());
    }
    // The products round up (0.1 × 0.1 = 0.010000000000000002), so the stage at 1e-6 comes
    // twice: once at 1.0000000000000004e-6, once at the floor 1e-6 itself.
    let expected = [1e-3, 1e-4, 1e-5, 1e-6, 1e-6];
    assert_eq!(fractions.len(), expected.len(), "{fractions:?}");
    for (f, e) in fractions.iter().zip(expected) {
        assert!((f / e - 1.0).abs() < 1e-12, "{fractions:?}");
    }
    // The last stage's tolerance: 1e-3 of its ε fraction.
    assert!((irls.objective_tolerance(1e-12) - 1e-9).abs() < 1e-21);
    // A final ε above 1e-6 ends the continuation there instead.
    let options = Options {
        irls_final_epsilon: 5e-4,
        ..Options::default()
    };
    let mut irls = Irls::new(&options, true, 1.0);
    irls.hand_over(1.0);
    assert!(irls.shrink(1.0));
    assert!((irls.eps() - 1e-3).abs() < 1e-18);
    assert!(irls.shrink(1.0));
    assert_eq!(irls.eps(), 5e-4);
    assert!(!irls.shrink(1.0));
}

#[test]
fn refusals_that_count_hand_back_to_majorising() {
    let mut irls = Irls::new(&phi_options(), false, 1.0);
    irls.hand_over(1.0);
    // Refusals within the cost's rounding do not count.
    irls.refused(1e-12, 1.0);
    irls.refused(1e-12, 1.0);
    assert!(!irls.newton_failed());
    irls.refused(1e-6, 1.0);
    irls.accepted();
    irls.refused(1e-6, 1.0);
    assert!(!irls.newton_failed(), "an accepted step resets the count");
    irls.refused(1e-6, 1.0);
    assert!(irls.newton_failed());
    // The majorising stage resumes at irls_initial_epsilon × Φ, to hand over at 1e-5, then 1e-6,
    // from which the Newton stage runs to the end.
    irls.back_to_majorising(0.5);
    assert_eq!(irls.stage(), Stage::Majorising);
    assert_eq!(irls.eps(), 0.05);
    assert!(irls.majorising_slowed(1.0, 1.0 - 0.9e-5));
    assert!(!irls.majorising_slowed(1.0, 1.0 - 1.1e-5));
    let mut resumed = 1;
    loop {
        irls.hand_over(0.5);
        irls.refused(1.0, 1.0);
        irls.refused(1.0, 1.0);
        if !irls.newton_failed() {
            break;
        }
        irls.back_to_majorising(0.5);
        resumed += 1;
    }
    assert_eq!(resumed, 2);
    assert!(irls.majorising_slowed(1.0, 1.0 - 0.9e-6));
    assert!(!irls.majorising_slowed(1.0, 1.0 - 1.1e-6));
}

#[test]
fn first_hand_over_at_a_thousandth() {
    let irls = Irls::new(&phi_options(), false, 1.0);
    assert!(irls.majorising_slowed(2.0, 2.0 - 1.9e-3));
    assert!(!irls.majorising_slowed(2.0, 2.0 - 2.1e-3));
}

/// The solves a continuation makes from Φ₀ with Φ following `phi` after each.
fn solves(options: &Options, phi0: f64, phi: impl Fn(usize) -> f64) -> Vec<f64> {
    let mut c = Continuation::new(options, phi0);
    let mut eps = vec![c.eps()];
    while !c.is_final() && eps.len() < 50 {
        c.shrink(phi(eps.len()));
        eps.push(c.eps());
    }
    eps
}

#[test]
fn continuation_shrinks_tenfold_to_the_final_epsilon() {
    // Defaults 0.1 → 1e-9: nine solves, whatever the rounding of eight divisions by ten.
    for phi0 in [0.37, 1.0, 3.3e-3, std::f64::consts::FRAC_1_SQRT_2, 12.9] {
        let eps = solves(&phi_options(), phi0, |k| phi0 / (k + 1) as f64);
        assert_eq!(eps.len(), 9, "Φ₀ = {phi0}: {eps:?}");
        assert!((eps[8] / (1e-9 * phi0) - 1.0).abs() < 1e-14);
    }
    // The floor irls_final_epsilon × Φ: at a Φ a hair above Φ₀ it ends the schedule too.
    let phi0 = 0.37;
    let eps = solves(&phi_options(), phi0, |_| phi0 * (1.0 + 1e-9));
    assert_eq!(eps.len(), 9, "{eps:?}");
    // A ratio that is not a power of ten: the floor ends it.
    let options = Options {
        irls_final_epsilon: 3e-4,
        ..Options::default()
    };
    let eps = solves(&options, 1.0, |_| 0.5);
    assert_eq!(eps.len(), 4, "{eps:?}");
    assert_eq!(eps[3], 1.5e-4);
}

#[test]
fn continuation_tolerances() {
    let mut c = Continuation::new(&phi_options(), 1.0);
    assert!(!c.is_final());
    assert_eq!(c.tolerance(1e-12), STAGE_TOLERANCE);
    for _ in 0..8 {
        c.shrink(1.0);
    }
    assert!(c.is_final());
    assert_eq!(c.tolerance(1e-12), 1e-12);
    // Least squares: one solve.
    let c = Continuation::new(&ve_options(), 1.0);
    assert!(c.is_final());
    assert_eq!(c.tolerance(1e-12), 1e-12);
}
