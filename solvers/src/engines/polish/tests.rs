//! [`settle`] on a location problem whose optima are known: the mean (ve) and the median (Φ).

use super::*;
use crate::engines::test_problems::Location;
use volver_core::model::{Constraint, ConstraintKind};

fn task(y: &[f64]) -> Task<'static> {
    Task::new(Location {
        y: y.to_vec(),
        scalar: false,
    })
}

#[test]
fn least_squares_settles_on_the_mean() {
    let (p, report) = settle(&task(&[1.0, 2.0, 4.0, 5.0]), &[2.5], Objective::Ve, 1e-9)
        .unwrap_or_else(|e| panic!("{e}"));
    assert!((p[0] - 3.0).abs() < 1e-12, "{}", p[0]);
    assert!(report.steps >= 1, "{report:?}");
    assert_ne!(report.stop, SettleStop::StepLimit, "{report:?}");
    assert!(report.decrement < 1e-20, "{report:?}");
}

#[test]
fn phi_settles_on_the_median() {
    // Φ_ε's optimum is within ~ε = 1e-9 Φ of the median (Φ = 20.4 there, ε ≈ 2e-8): from
    // within ε of it, where the smoothed kink's curvature is seen, Newton steps go there.
    let y = [1.0, 2.0, 4.0, 5.0, 100.0];
    let (p, report) =
        settle(&task(&y), &[4.0 + 1e-8], Objective::Phi, 1e-9).unwrap_or_else(|e| panic!("{e}"));
    assert!((p[0] - 4.0).abs() < 1e-8, "{} {report:?}", p[0]);
    assert_ne!(report.stop, SettleStop::StepLimit, "{report:?}");
    // Far from the kink (0.3 against ε ≈ 2e-8) the model sees no curvature: its step lowers
    // nothing, the point is kept and the reason says so.
    let (p, report) =
        settle(&task(&y), &[4.3], Objective::Phi, 1e-9).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(p, vec![4.3]);
    assert_eq!(report.stop, SettleStop::NoDecrease, "{report:?}");
    assert_eq!(report.steps, 0);
}

#[test]
fn a_held_parameter_has_nothing_to_settle() {
    let mut task = task(&[1.0, 2.0]);
    task.constraints.rows.push(Constraint {
        kind: ConstraintKind::Fixed,
        label: "p = 3.5".into(),
        coeffs: vec![(0, 1.0)],
        rhs: 3.5,
    });
    let (p, report) = settle(&task, &[3.5], Objective::Ve, 1e-9).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(p, vec![3.5]);
    assert_eq!(report.stop, SettleStop::NoFreeParameters);
    assert_eq!((report.steps, report.decrement), (0, 0.0));
}

#[test]
fn a_residual_not_finite_is_a_reason() {
    let outcome = settle(&task(&[1.0, f64::NAN]), &[0.0], Objective::Phi, 1e-9);
    assert_eq!(outcome.err(), Some(Unsettled::NotFinite));
}
