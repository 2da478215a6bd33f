//! The expert Ceres program models the same machine as volver (its eq. 11, written
//! independently in C++, gives the same EMM at the start and at any parameters) and its fit
//! meets the native engine's. No timing is judged.
#![cfg(feature = "ceres")]

use volver_benchmarks::expert::Expert;
use volver_core::machine::Machine;
use volver_core::measure::MeasurementSet;
use volver_core::model::Model;
use volver_core::plan::Plan;
use volver_core::problem::{Problem, Residuals};
use volver_core::random::Rng;
use volver_core::simulate::{Magnitudes, Simulation, Truth};
use volver_solvers::strategy::{Strategy, identify};
use volver_solvers::{Objective, Options, Silent, Solver, Task};

fn data(plan: &str, seed: u64) -> (Model, MeasurementSet) {
    let machine = Machine::default_xcfz();
    let model = Model::default_xcfz();
    let truth = Truth::random(&machine, model.spec(), &Magnitudes::default(), seed).unwrap();
    let plan = Plan::preset(&machine, plan).unwrap();
    (
        model,
        Simulation::new(plan, truth, seed)
            .run()
            .unwrap()
            .measurements,
    )
}

fn phi_options() -> Options {
    Options {
        objective: Objective::Phi,
        ..Options::default()
    }
}

#[test]
fn the_programs_model_is_volvers_at_any_parameters() {
    for (plan, seed) in [("test4", 7), ("test3", 3), ("test2", 11)] {
        let (model, data) = data(plan, seed);
        let problem = Problem::new(&model, &data).unwrap();
        let start = volver_solvers::init::init_tracker(&problem, &model.initial_params()).unwrap();
        let expert = Expert::new(&problem, &start).unwrap();
        let mut rng = Rng::new(seed);
        let z0 = expert.coefficients(&start);
        for scale in [0.0, 1e-4, 1e-2] {
            // Any free coefficients, the constrained parameters following (the constraints hold).
            let z: Vec<f64> = z0.iter().map(|v| v + scale * rng.normal()).collect();
            let p = expert.params(&z);
            let violation = problem.constraints().max_violation(&p);
            assert!(
                violation < 1e-12,
                "{plan}: constraints violated by {violation}"
            );
            let (ours, theirs) = (problem.phi(&p), expert.emm(&p));
            assert!(
                (ours - theirs).abs() <= 1e-12 * ours,
                "{plan}, scale {scale}: volver {ours} mm, expert {theirs} mm"
            );
        }
    }
}

/// On the bench's test 4 both fits end within 0.01 µm of each other (the bench's "time to the
/// final EMM" target). On any data, the native engine started where Ceres stopped ends no higher
/// (Ceres may wander along combinations the data cannot identify into another basin: on test 3,
/// seed 5, it ends 1.5e-3 below volver's gauged fit with rotation errors of milliradians).
#[test]
fn the_program_and_the_native_engine_meet() {
    for (plan, seed) in [("test4", 7), ("test3", 5), ("test5", 2)] {
        let (model, data) = data(plan, seed);
        let problem = Problem::new(&model, &data).unwrap();
        let start = volver_solvers::init::init_tracker(&problem, &model.initial_params()).unwrap();
        let expert = Expert::new(&problem, &start).unwrap();
        let fit = expert.fit(&start, 1, 1e-6).unwrap();
        let theirs = problem.phi(&fit.params);
        assert!(
            (fit.final_emm_mm - theirs).abs() <= 1e-12 * theirs,
            "{plan}: the program's EMM {} vs volver's at its parameters {theirs}",
            fit.final_emm_mm
        );
        assert!(
            fit.trace.len() >= 2 && fit.iterations > 0,
            "{plan}: {fit:?}"
        );
        let from_theirs = volver_solvers::lm::LevenbergMarquardt::default().solve(
            &Task::new(problem.clone()),
            &fit.params,
            &phi_options(),
            &mut Silent,
        );
        let again = problem.phi(&from_theirs.params);
        eprintln!(
            "{plan}: expert {theirs} mm in {} iterations ({}); native engine from there {again} mm",
            fit.iterations, fit.message
        );
        assert!(
            again <= theirs * (1.0 + 1e-12),
            "{plan}: from the program's end {theirs} mm the native engine ends at {again} mm"
        );
        if plan == "test4" {
            let id = identify(
                &volver_solvers::lm::LevenbergMarquardt::default(),
                problem,
                &model.initial_params(),
                &Strategy::default(),
                &phi_options(),
                &mut Silent,
            );
            let ours = id.reached.phi_mm;
            assert!(
                (theirs - ours).abs() <= 1e-5,
                "{plan}: volver {ours} mm, expert {theirs} mm"
            );
        }
    }
}
