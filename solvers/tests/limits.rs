//! Limits counted exactly, for every engine of the build: started far from the optimum with
//! small limits, no engine counts more iterations or evaluations than it was allowed, and the
//! termination names the limit that stopped it. The options an engine does not read are
//! stated in its summary; the native LM gives the same bits on one thread and on two.

use volver_core::machine::Machine;
use volver_core::model::{ErrorModelSpec, Model};
use volver_core::plan::Plan;
use volver_core::problem::Problem;
use volver_core::simulate::{Magnitudes, Simulation, Truth};
use volver_solvers::{
    Objective, Options, Settings, Silent, Task, Termination, engine_names, engine_with,
};

/// Test 3 simulated (seed 1, the paper's noise) and the model, started from its initial
/// parameters: errors of tens of µm to identify, far from the optimum.
fn case() -> (Model, volver_core::measure::MeasurementSet) {
    let m = Machine::default_xcfz();
    let truth =
        Truth::random(&m, &ErrorModelSpec::complete(&m), &Magnitudes::default(), 1).unwrap();
    let data = Simulation::new(Plan::preset(&m, "test3").unwrap(), truth, 1)
        .run()
        .unwrap()
        .measurements;
    (Model::default_xcfz(), data)
}

/// Whether an engine reads `max_iterations` (NLopt counts no iterations: it states it).
fn reads_iterations(name: &str) -> bool {
    !name.starts_with("nlopt")
}

#[test]
fn small_limits_are_never_exceeded_and_the_termination_names_them() {
    let (model, data) = case();
    let task = Task::new(Problem::new(&model, &data).unwrap());
    let start = model.initial_params();
    let mut failures = Vec::new();
    let (mut runs, mut limited) = (0, 0);
    for name in engine_names() {
        let solver = engine_with(name, &Settings::default()).unwrap();
        for objective in [Objective::Phi, Objective::Ve] {
            for max_iterations in [1, 3] {
                let options = Options {
                    objective,
                    max_iterations,
                    ..Options::default()
                };
                let s = solver.solve(&task, &start, &options, &mut Silent).summary;
                let what = format!("{name} {objective} max_iterations {max_iterations}");
                runs += 1;
                limited += usize::from(s.termination == Termination::IterationLimit);
                // Converged within the limit, or stopped by it and saying so.
                let honest =
                    s.termination.converged() || s.termination == Termination::IterationLimit;
                if reads_iterations(name) {
                    if s.iterations > max_iterations || !honest {
                        failures.push(format!(
                            "{what}: {} iterations, {}",
                            s.iterations, s.termination
                        ));
                    }
                    if !s.ignored_options.is_empty() {
                        failures.push(format!("{what}: ignored {:?}", s.ignored_options));
                    }
                } else if s.ignored_options != ["max_iterations"] {
                    failures.push(format!("{what}: ignored {:?}", s.ignored_options));
                }
                if s.evaluations > options.max_evaluations {
                    failures.push(format!("{what}: {} evaluations", s.evaluations));
                }
            }
            for max_evaluations in [3, 5, 8] {
                let options = Options {
                    objective,
                    max_evaluations,
                    ..Options::default()
                };
                let s = solver.solve(&task, &start, &options, &mut Silent).summary;
                let what = format!("{name} {objective} max_evaluations {max_evaluations}");
                runs += 1;
                limited += usize::from(s.termination == Termination::EvaluationLimit);
                let honest =
                    s.termination.converged() || s.termination == Termination::EvaluationLimit;
                if s.evaluations > max_evaluations || !honest {
                    failures.push(format!(
                        "{what}: {} evaluations, {}",
                        s.evaluations, s.termination
                    ));
                }
                if s.iterations > options.max_iterations {
                    failures.push(format!("{what}: {} iterations", s.iterations));
                }
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    // The limits bind: from this start most runs stop on them (least squares converges in a
    // few steps of the LM).
    assert!(
        2 * limited > runs,
        "{limited} of {runs} runs stopped by a limit"
    );
}

#[test]
fn an_evaluation_limit_below_what_a_start_takes_is_refused() {
    let options = Options {
        max_evaluations: 2,
        ..Options::default()
    };
    let e = options.validate().unwrap_err();
    assert_eq!(
        e,
        volver_solvers::Error::TooFewEvaluations { value: 2, min: 3 }
    );
    assert!(e.to_string().contains("give at least 3"), "{e}");
}

#[test]
fn the_native_lm_gives_the_same_bits_on_one_thread_and_on_two() {
    let (model, data) = case();
    let task = Task::new(Problem::new(&model, &data).unwrap());
    let start = model.initial_params();
    for objective in [Objective::Phi, Objective::Ve] {
        let options = Options {
            objective,
            ..Options::default()
        };
        let run = |threads: usize| {
            let mut settings = Settings::default();
            settings.lm = settings.lm.with_threads(threads);
            let solver = engine_with("lm", &settings).unwrap();
            solver.solve(&task, &start, &options, &mut Silent)
        };
        let (one, two) = (run(1), run(2));
        assert!(
            one.summary.termination.converged(),
            "{}",
            one.summary.termination
        );
        let same = one.params.len() == two.params.len()
            && one
                .params
                .iter()
                .zip(&two.params)
                .all(|(a, b)| a.to_bits() == b.to_bits());
        assert!(
            same,
            "{objective}: the parameters differ between 1 and 2 threads"
        );
        assert_eq!(
            one.summary.reached.phi_mm.to_bits(),
            two.summary.reached.phi_mm.to_bits()
        );
        assert_eq!(one.summary.iterations, two.summary.iterations);
    }
}

#[test]
fn the_lm_on_its_own_pool_reports_every_iteration_to_the_observer() {
    struct Count(usize);
    impl volver_solvers::Observer for Count {
        fn iteration(&mut self, _: &volver_solvers::Iteration) {
            self.0 += 1;
        }
    }
    let (model, data) = case();
    let task = Task::new(Problem::new(&model, &data).unwrap());
    let mut settings = Settings::default();
    settings.lm = settings.lm.with_threads(2);
    let solver = engine_with("lm", &settings).unwrap();
    let mut count = Count(0);
    let s = solver.solve(
        &task,
        &model.initial_params(),
        &Options::default(),
        &mut count,
    );
    // One report per step tried (the LM's), at least one per iteration counted before the polish.
    assert!(
        count.0 > 0 && count.0 <= s.summary.iterations,
        "{} of {}",
        count.0,
        s.summary.iterations
    );
}

#[test]
fn options_an_engine_does_not_read_are_stated_only_when_set() {
    let (model, data) = case();
    let task = Task::new(Problem::new(&model, &data).unwrap());
    let start = model.initial_params();
    let changed = Options {
        gradient_tolerance: 1e-12,
        max_iterations: 2,
        ..Options::default()
    };
    for name in engine_names() {
        let solver = engine_with(name, &Settings::default()).unwrap();
        let expected: &[&str] = match name {
            "clarabel" => &["gradient_tolerance"],
            n if n.starts_with("nlopt") => &["max_iterations", "gradient_tolerance"],
            _ => &[],
        };
        let s = solver.solve(&task, &start, &changed, &mut Silent).summary;
        assert_eq!(s.ignored_options, expected, "{name}");
        if !expected.is_empty() {
            assert!(s.full_report().contains("options not read"), "{name}");
            let json = serde_json::to_string(&s).unwrap();
            assert!(json.contains("\"ignored_options\""), "{name}: {json}");
        }
        let defaults = Options {
            max_iterations: 2,
            ..Options::default()
        };
        let s = solver.solve(&task, &start, &defaults, &mut Silent).summary;
        let at_default = s.ignored_options.iter().any(|f| f == "gradient_tolerance");
        assert!(!at_default, "{name}: {:?}", s.ignored_options);
    }
}
