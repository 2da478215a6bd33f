//! The native LM on problems whose iterates and optima are known by hand.

use super::*;
use crate::Silent;
use crate::engines::test_problems::Location;

/// Every trial's report.
#[derive(Default)]
struct Record(Vec<Iteration>);

impl Observer for Record {
    fn iteration(&mut self, it: &Iteration) {
        self.0.push(*it);
    }
}

fn task(y: &[f64], scalar: bool) -> Task<'static> {
    Task::new(Location {
        y: y.to_vec(),
        scalar,
    })
}

fn ve() -> Options {
    Options {
        objective: Objective::Ve,
        ..Options::default()
    }
}

/// ve at p of the observations y.
fn ve_at(p: f64, y: &[f64]) -> f64 {
    y.iter().map(|v| (p - v) * (p - v)).sum::<f64>() / y.len() as f64
}

fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * b.abs().max(volver_core::units::TINY)
}

#[test]
fn least_squares_iterates_are_known_by_hand() {
    // On a linear problem the scaled damped step is the Gauss–Newton step shrunk by 1/(1 + λ):
    // p_{k+1} = p_k − (p_k − ȳ)/(1 + λ_k), every gain ratio is 1, so λ is divided by 3 at
    // each step (Nielsen).
    let y = [1.0, 2.0, 4.0, 5.0];
    let mean = 3.0;
    let mut record = Record::default();
    let sol = LevenbergMarquardt::default().solve(&task(&y, false), &[0.0], &ve(), &mut record);
    let trials = &record.0;
    let lambda0 = Options::default().initial_damping;
    let p1 = 0.0 - (0.0 - mean) / (1.0 + lambda0);
    let p2 = p1 - (p1 - mean) / (1.0 + lambda0 / 3.0);
    assert!(trials[0].accepted && trials[1].accepted);
    assert_eq!(trials[0].damping, lambda0);
    assert!(close(trials[1].damping, lambda0 / 3.0, 1e-9), "{trials:?}");
    assert!(close(trials[0].cost, ve_at(p1, &y), 1e-12), "{trials:?}");
    assert!(close(trials[1].cost, ve_at(p2, &y), 1e-12), "{trials:?}");
    // EMM of p1 in µm: mean |p1 − y_i|.
    let emm1 = y.iter().map(|v| (p1 - v).abs()).sum::<f64>() / 4.0 * UM_PER_MM;
    assert!(close(trials[0].emm_um, emm1, 1e-12));
    assert!(sol.summary.termination.converged(), "{:?}", sol.summary);
    assert!((sol.params[0] - mean).abs() < 1e-12, "{}", sol.params[0]);
    assert!(close(sol.summary.reached.ve_mm2, 2.5, 1e-12));
}

#[test]
fn phi_reaches_the_median() {
    // Φ's optimum is the median whatever the outlier; the polish (points) or the vertex
    // (ranges alone) take the LM there from the mean's side.
    let y = [1.0, 2.0, 4.0, 5.0, 100.0];
    for scalar in [false, true] {
        let sol = LevenbergMarquardt::default().solve(
            &task(&y, scalar),
            &[30.0],
            &Options::default(),
            &mut Silent,
        );
        assert!(sol.summary.termination.converged(), "{:?}", sol.summary);
        assert!(
            (sol.params[0] - 4.0).abs() < 1e-4,
            "{scalar}: {}",
            sol.params[0]
        );
        assert!(close(sol.summary.reached.phi_mm, 102.0 / 5.0, 1e-5));
    }
}

#[test]
fn ranges_alone_end_at_the_vertex_exactly() {
    // Scalar residuals alone: Φ is an L1 fit, and the LM ends at its vertex (the median itself,
    // not within ε of it) on the parameter-change test, polished or not.
    let y = [1.0, 2.0, 4.0, 5.0, 100.0];
    for polish in [true, false] {
        let lm = LevenbergMarquardt {
            polish,
            ..LevenbergMarquardt::default()
        };
        let sol = lm.solve(&task(&y, true), &[30.0], &Options::default(), &mut Silent);
        assert_eq!(sol.summary.termination, Termination::ParameterChange);
        assert_eq!(sol.params, vec![4.0], "{:?}", sol.summary);
        assert!(sol.summary.polished);
        assert!(sol.summary.iterations <= 20, "{:?}", sol.summary);
    }
}

#[test]
fn an_iteration_limit_stops_the_run() {
    let options = Options {
        max_iterations: 1,
        ..ve()
    };
    let sol = LevenbergMarquardt::default().solve(
        &task(&[1.0, 2.0], false),
        &[0.0],
        &options,
        &mut Silent,
    );
    assert_eq!(sol.summary.termination, Termination::IterationLimit);
    assert_eq!(sol.summary.iterations, 1);
}

/// The state at the start of a solve of `y` from 0.
fn started<'t>(task: &'t Task<'static>, options: &'t Options) -> Lm<'t, 'static, 't> {
    let begun = begin("lm", task, &[0.0], options).unwrap_or_else(|_| panic!("cannot start"));
    Lm::new(begun, task, options, LevenbergMarquardt::default())
}

#[test]
fn stopping_predicates() {
    let options = ve();
    let task = task(&[1.0, 2.0, 4.0, 5.0], false);
    let mut lm = started(&task, &options);
    // Criterion 1: a step below 1e-10 (‖z‖ + 1e-10).
    lm.z = vec![3.0];
    assert!(lm.small_step(1e-10 * (3.0 + 1e-10)));
    assert!(!lm.small_step(1e-9));
    // Criterion 2: a gain of at most 1e-12 of the old cost.
    lm.cost = 1.0;
    assert!(lm.small_change(1.0 + 0.5e-12));
    assert!(!lm.small_change(1.0 + 3e-12));
    // A refused step within the cost's rounding: prediction and change both below 1e-12.
    assert!(lm.within_rounding(5e-13, -5e-13));
    assert!(!lm.within_rounding(5e-12, 0.0));
    assert!(!lm.within_rounding(0.0, -5e-12));
    // The gradient test at 1e-13 of the first cost (ve at 0: 11.5), or at a zero cost.
    assert_eq!(lm.cost0, 11.5);
    assert!(lm.gradient_converged(1e-13 * 11.5));
    assert!(!lm.gradient_converged(2e-13 * 11.5));
    lm.cost = 0.0;
    assert!(lm.gradient_converged(1.0));
}

#[test]
fn the_majorising_stage_neither_stops_on_the_gradient_nor_on_a_refusal() {
    let options = Options::default();
    let task = task(&[1.0, 2.0, 4.0, 5.0, 100.0], false);
    let mut lm = started(&task, &options);
    assert_eq!(lm.irls.stage(), Stage::Majorising);
    assert!(!lm.gradient_converged(0.0));
    // A refusal with a small step hands over to the Newton stage (damping restarted) instead
    // of stopping the run.
    lm.damping.rejected();
    let verdict = lm.refuse(1.0, f64::INFINITY, 0.0, true, &mut Silent);
    assert!(matches!(verdict, Ok(Verdict::NextPass)));
    assert_eq!(lm.irls.stage(), Stage::Newton);
    assert_eq!(lm.damping.lambda(), options.initial_damping);
    assert!(lm.refresh && lm.reset_scale);
    // Φ_ε at ε = 1e-9 Φ.
    let phi = lm.phi();
    assert!(close(lm.cost, phi, 1e-12));
    // The same refusal in the Newton stage stops the run on the parameter change.
    let verdict = lm.refuse(1e-30, f64::INFINITY, 0.0, true, &mut Silent);
    assert!(matches!(verdict, Err(Termination::ParameterChange)));
}
