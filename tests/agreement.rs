//! The solver agreement suite: every engine of the build minimises the same Φ (and ve) under
//! the same constraints and must reach the same fit.
//!
//! Problems: the paper's tests 1–5 with the paper's model (Legendre cubics for the linear
//! axes, first harmonics for C; tests 1 and 2 with only the axes they move), and test 4 with
//! the linear axes in monomial and Chebyshev bases; each noise-free (the truth is inside the model) and with the
//! paper's tracker noise; and ranges alone from four stations (an L1 fit under Φ: Clarabel's
//! SOCP reaches its optimum, the native LM its vertex by linear programmes, measured 5.7e-11
//! above the SOCP's on the noisy ranges); each objective. Every engine
//! starts from the same point (errors zero, tracker by a rigid fit).
//!
//! The paper's model is not fully identifiable on these plans (test 1 never turns C; on test 4
//! six combinations have a curvature below 1e-10 of the largest). Along such flat directions
//! Φ changes by parts in 10⁴ while the parameters run away, and each engine stops somewhere
//! else in the valley: that is not a disagreement about the fit. So the suite first finds
//! those directions at the native LM's solution and holds them (`identifiability::hold_weak`,
//! gauge fixing); the problem left is well posed and the engines are judged on it, on the
//! objective and on the residual vector — never on raw parameters.
//!
//! Every engine runs; the best objective among the exact engines is the reference, and each
//! engine is judged against it (measured on this suite, release build: Clarabel, Ceres, SLSQP
//! and the polished LM agree with each other to ~1e-11 on noisy Φ):
//! * the floor: a noise-free fit is exact, its optimum at the rounding of the 9-decimal
//!   measurement file (Φ ≈ 1e-7 … 1e-12 mm), where relative differences mean nothing; there an
//!   objective within a fraction `floor` of its start passes (Φ; its square for ve). Noisy fits
//!   get no floor: they are judged relative to the best alone;
//! * `clarabel`, `lm+clarabel`, `ceres`: the objective within 1e-6 relative, floor 1e-6; every
//!   residual within 1 µm of the best's (the noise is ~50 µm);
//! * `lm`: as the exact engines; the optimum of Φ interpolates some points (an L1-type kink
//!   where a residual vanishes), where the damped steps stall (3.4e-4 above it on test 1
//!   noise-free): the Newton polish after convergence closes the gap (measured 5.7e-9 there);
//!   on ranges alone (one scalar residual per point) Φ is an L1 fit, whose vertex the LM
//!   reaches by linear programmes (its continuation in ε stopped 1.27e-5 above the SOCP's
//!   optimum): exact, as the exact engines;
//! * `nlopt-lbfgs`, `nlopt-slsqp` (a smoothed Φ, quasi-Newton) stall on the same kinks, each
//!   bound twice the largest excess measured over this suite's noisy fits (debug build, every
//!   case): L-BFGS Φ 7.4e-3 (test 1; 4.4e-4 … 5.9e-3 on earlier builds, depending on the last
//!   bits of the held values) and 3.9e-3 on ranges, residuals 17 µm (test 1), ve 3e-13;
//!   SLSQP Φ 3.1e-9 (6.2e-5 on ranges), residuals 24 nm (ranges), ve 9e-13; floor 1e-5;
//! * constraints (the model's and the gauge) hold to 1e-9 in their own units;
//! * terminations are honest: a limit is claimed only when the count reached it; a failure is
//!   never accepted.
//!
//! `nlopt-mma` (first-order, no curvature) and `nlopt-bobyqa` (derivative-free) are run for
//! comparison only, with 300 evaluations: they must not fail, must report an honest termination
//! (the evaluation limit) and must not end above the start, but need not reach the optimum. On test 4 (condition ~10⁵ in the
//! scaled coordinates) MMA is still 10⁴ times above the optimum of a noise-free fit after 5000
//! evaluations, where L-BFGS needs ~800.

use volver::core::machine::Machine;
use volver::core::measure::MeasurementSet;
use volver::core::model::{ErrorModelSpec, Model};
use volver::core::noise::TrackerNoise;
use volver::core::plan::Plan;
use volver::core::problem::Problem;
use volver::core::simulate::{Magnitudes, Simulation, Truth};
use volver::solvers::identifiability::hold_weak;
use volver::solvers::init::init_tracker;
use volver::solvers::lm::LevenbergMarquardt;
use volver::solvers::nullspace::NullSpace;
use volver::solvers::{
    Objective, Options, Silent, Solution, Solver, Task, Termination, engine, engine_names,
};
use volver_core::problem::Residuals;

/// Records a failed check (every engine and case is run and printed before the test fails).
macro_rules! check {
    ($errors:expr, $cond:expr, $($fmt:tt)*) => {
        {
            let ok: bool = $cond;
            if !ok {
                $errors.push(format!($($fmt)*));
            }
        }
    };
}

fn data(plan: &str, noisy: bool, seed: u64) -> MeasurementSet {
    let m = Machine::default_xcfz();
    let mags = Magnitudes {
        tracker_mm: 5.0,
        ..Magnitudes::default()
    };
    let truth = Truth::random(&m, &ErrorModelSpec::complete(&m), &mags, seed).unwrap();
    let mut sim = Simulation::new(Plan::preset(&m, plan).unwrap(), truth, seed);
    if !noisy {
        sim.noise = TrackerNoise::NONE;
    }
    sim.run().unwrap().measurements
}

/// The paper's model (`core/data/xcfz-paper-model.toml`) with the linear axes in `basis`, and
/// only the errors a plan can see: test 1 never turns C, test 2 never moves X or Z (the
/// paper's practice for these tests, table 11).
fn paper_model(basis: &str, linear: bool, rotary: bool) -> Model {
    let mut text = String::from("squareness = \"from-straightness\"\n");
    if linear {
        text += &format!(
            "[[error]]\nname = [\"EXX\", \"EYX\", \"EZX\", \"EAX\", \"EBX\", \"ECX\", \"EXZ\", \"EYZ\", \"EZZ\", \"EAZ\", \"EBZ\", \"ECZ\"]\n{basis}\n[[error]]\nname = [\"A0Z\", \"B0Z\"]\n"
        );
    }
    if rotary {
        text += "[[error]]\nname = [\"EXC\", \"EYC\", \"EZC\", \"EAC\", \"EBC\", \"ECC\"]\nbasis = \"fourier\"\norder = 1\n";
    }
    text += "[tracker]\nidentify = [\"x\", \"y\", \"z\"]\n";
    Model::from_toml_str(Machine::default_xcfz(), &text, "inline").unwrap()
}

const LEGENDRE: &str = "basis = \"legendre\"\ndegree = 3";

fn objective_of(s: &Solution, objective: Objective) -> f64 {
    match objective {
        Objective::Phi => s.summary.reached.phi_mm,
        Objective::Ve => s.summary.reached.ve_mm2,
        o => panic!("objective {o} is not in the agreement suite"),
    }
}

/// A claimed limit must have been reached; a failure is never accepted.
fn check_honest(errors: &mut Vec<String>, name: &str, s: &Solution, options: &Options) {
    let t = &s.summary.termination;
    check!(errors, !t.failed(), "{name}: {t}");
    match t {
        Termination::IterationLimit => check!(
            errors,
            s.summary.iterations >= options.max_iterations,
            "{name} claims the iteration limit after {} iterations",
            s.summary.iterations
        ),
        Termination::EvaluationLimit => check!(
            errors,
            s.summary.evaluations >= options.max_evaluations,
            "{name} claims the evaluation limit after {} evaluations",
            s.summary.evaluations
        ),
        _ => {}
    }
    check!(
        errors,
        s.summary.reached.phi_mm.is_finite() && s.params.iter().all(|v| v.is_finite()),
        "{name}: non-finite result"
    );
}

fn check_case(label: &str, model: &Model, data: &MeasurementSet, noisy: bool) -> Vec<String> {
    let mut errors = Vec::new();
    let problem = Problem::new(model, data).unwrap();
    let start = init_tracker(&problem, &model.initial_params()).unwrap();
    for objective in [Objective::Phi, Objective::Ve] {
        let options = Options {
            objective,
            max_iterations: 500,
            max_evaluations: 5000,
            ..Options::default()
        };
        let (gauge, initial) = gauged(&problem, &start, &options, label);
        // Every engine first; the best objective of the exact engines is the reference.
        let runs = run_every_engine(&gauge, &start, &options);
        let (best_name, best) = runs
            .iter()
            .filter(|(name, _, s)| tolerance(name).is_some() && !s.summary.termination.failed())
            .map(|(name, _, s)| (*name, s))
            .min_by(|a, b| objective_of(a.1, objective).total_cmp(&objective_of(b.1, objective)))
            .unwrap();
        let best_value = objective_of(best, objective);
        // Every engine starts from the start projected onto the constraints (the gauge moves it;
        // each engine projects in its own scaled metric, so this is one such projection).
        let ns = NullSpace::from_constraints(&gauge.constraints, &start).unwrap();
        let p0 = ns.expand(&vec![0.0; ns.n_free()]);
        let projected_start = match objective {
            Objective::Phi => problem.phi(&p0),
            Objective::Ve => problem.ve(&p0),
            o => panic!("objective {o} is not in the agreement suite"),
        };
        let best_res = problem.residuals(&best.params);
        println!("  best: {best_name} {best_value:.12e}");
        for (name, options, s) in &runs {
            let value = objective_of(s, objective);
            let res = problem.residuals(&s.params);
            let dr = res
                .iter()
                .zip(&best_res)
                .map(|(a, b)| {
                    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
                })
                .fold(0.0, f64::max);
            let viol_model = model.constraints().max_violation(&s.params);
            let viol_gauge = gauge.constraints.max_violation(&s.params);
            println!(
                "  {name:<12} {value:.12e}  rel {:+.2e}  max Δr {:.2e} mm  viol {:.1e}/{:.1e}  {} it {} ev {:.2} s  held {}  {}",
                value / best_value - 1.0,
                dr,
                viol_model,
                viol_gauge,
                s.summary.iterations,
                s.summary.evaluations,
                s.summary.time_s,
                s.summary.unidentifiable,
                s.summary.termination
            );
            let tag = format!("{label} {objective} {name}");
            check_honest(&mut errors, &tag, s, options);
            check!(
                errors,
                viol_model < 1e-9 && viol_gauge < 1e-9,
                "{tag}: constraints violated"
            );
            let case = Case {
                objective,
                noisy,
                scalar: problem.scalar(0),
                initial,
                projected_start,
                best_value,
                best_name,
            };
            judge(&mut errors, &tag, name, &case, value, dr);
        }
    }
    errors
}

/// `problem`'s task with the weak directions of a first LM fit from `start` held (gauge
/// fixing), and the objective at the start; printed under `label`.
fn gauged<'a>(
    problem: &Problem<'a>,
    start: &[f64],
    options: &Options,
    label: &str,
) -> (Task<'a>, f64) {
    let objective = options.objective;
    let task = Task::new(problem.clone());
    let first = LevenbergMarquardt::default().solve(&task, start, options, &mut Silent);
    let gauge = hold_weak(
        &task,
        &first.params,
        100.0 * volver::solvers::identifiability::RANK_TOLERANCE,
    )
    .unwrap();
    let held = gauge.constraints.rows.len() - task.constraints.rows.len();
    let initial = objective_of_initial(&first, objective);
    println!(
        "{label} {objective}: {held} weak directions held; start {initial:.3e}; LM without them held {:.12e} ({})",
        objective_of(&first, objective),
        first.summary.termination
    );
    (gauge, initial)
}

/// Every engine of the build on `task` from `start` under `options` (300 evaluations for the
/// engines run for comparison only): (name, options, solution).
fn run_every_engine<'a>(
    task: &Task,
    start: &[f64],
    options: &Options,
) -> Vec<(&'a str, Options, Solution)> {
    engine_names()
        .into_iter()
        .map(|name| {
            let options = if comparison_only(name) {
                Options {
                    max_evaluations: 300,
                    ..options.clone()
                }
            } else {
                options.clone()
            };
            let s = engine(name)
                .unwrap()
                .solve(task, start, &options, &mut Silent);
            (name, options, s)
        })
        .collect()
}

/// What one engine's run is judged against: the case and the best exact engine's objective.
struct Case<'a> {
    objective: Objective,
    noisy: bool,
    /// Scalar residuals (ranges alone: Φ is an L1 fit).
    scalar: bool,
    /// The objective at the start.
    initial: f64,
    /// The objective at the start projected onto the constraints.
    projected_start: f64,
    best_value: f64,
    best_name: &'a str,
}

/// Judges engine `name`'s objective `value` and largest residual difference from the best's
/// `dr` (mm) by its tolerance (see the module documentation), recording failures under `tag`.
fn judge(errors: &mut Vec<String>, tag: &str, name: &str, c: &Case, value: f64, dr: f64) {
    let Some(tol) = tolerance(name) else {
        // Comparison only: finite, honest (checked by the caller), and no worse than the start.
        check!(
            errors,
            value <= c.initial.max(c.projected_start) * (1.0 + 1e-9),
            "{tag}: the objective rose above the start"
        );
        return;
    };
    // Relative to the best, or to the start when the fit is exact (noise-free data only:
    // the optimum is then at the rounding of the measurement file, where relative
    // differences mean nothing); ve is a square, hence the squared floor. A noisy fit is
    // judged relative to the best alone.
    let floor = match (c.noisy, c.objective) {
        (true, _) => 0.0,
        (false, Objective::Phi) => tol.floor * c.initial,
        (false, Objective::Ve) => tol.floor * tol.floor * c.initial,
        (false, o) => panic!("objective {o} is not in the agreement suite"),
    };
    let rel = match c.objective {
        Objective::Phi if c.scalar => tol.phi_scalar,
        Objective::Phi => tol.phi,
        Objective::Ve => tol.ve,
        o => panic!("objective {o} is not in the agreement suite"),
    };
    check!(
        errors,
        value - c.best_value <= rel * c.best_value + floor,
        "{tag}: objective {value} vs best {} ({})",
        c.best_value,
        c.best_name
    );
    check!(
        errors,
        dr < tol.residual_mm,
        "{tag}: residuals differ from the best's by {dr} mm"
    );
}

/// How close an engine must come to the best engine.
struct Tolerance {
    /// Relative excess of Φ.
    phi: f64,
    /// Relative excess of Φ on scalar residuals (ranges alone: an L1 fit).
    phi_scalar: f64,
    /// Relative excess of ve.
    ve: f64,
    /// Excess as a fraction of the start (noise-free fits only): Φ, and its square for ve.
    floor: f64,
    /// Largest difference of a residual from the best's (mm).
    residual_mm: f64,
}

fn comparison_only(name: &str) -> bool {
    tolerance(name).is_none()
}

/// The tolerances per engine (see the module documentation); `None`: comparison only.
fn tolerance(name: &str) -> Option<Tolerance> {
    let exact = Tolerance {
        phi: 1e-6,
        phi_scalar: 1e-6,
        ve: 1e-6,
        floor: 1e-6,
        residual_mm: 1e-3,
    };
    match name {
        // The SOCP and Ceres reach the exact optimum, and the LM polished by the SOCP.
        "clarabel" | "lm+clarabel" | "ceres" => Some(exact),
        // The native LM, polished by Newton steps at the kinks of Φ; on ranges alone it ends
        // at the L1 vertex by linear programmes (measured 5.7e-11 above the SOCP).
        "lm" => Some(exact),
        // Quasi-Newton on a smoothed Φ, stalling on its kinks: twice the largest excess
        // measured on the noisy fits (7.4e-3 on test 1, 3.9e-3 on ranges; residuals 17 µm).
        "nlopt-lbfgs" => Some(Tolerance {
            phi: 1.5e-2,
            phi_scalar: 1e-2,
            ve: 1e-9,
            floor: 1e-5,
            residual_mm: 3.5e-2,
        }),
        // SQP on the smoothed Φ: 3.1e-9 on points, 6.2e-5 on ranges, residuals 24 nm.
        "nlopt-slsqp" => Some(Tolerance {
            phi: 1e-8,
            phi_scalar: 1.5e-4,
            ve: 1e-9,
            floor: 1e-5,
            residual_mm: 5e-5,
        }),
        _ => None,
    }
}

fn objective_of_initial(s: &Solution, objective: Objective) -> f64 {
    match objective {
        Objective::Phi => s.summary.initial.phi_mm,
        Objective::Ve => s.summary.initial.ve_mm2,
        o => panic!("objective {o} is not in the agreement suite"),
    }
}

fn check_plan(plan: &str, seed: u64) {
    let model = match plan {
        "test1" => paper_model(LEGENDRE, true, false),
        "test2" => paper_model(LEGENDRE, false, true),
        _ => paper_model(LEGENDRE, true, true),
    };
    if plan == "test4" {
        // The paper's model exactly.
        let paper = Model::default_xcfz();
        assert_eq!(model.params().len(), paper.params().len());
    }
    let mut errors = Vec::new();
    for noisy in [false, true] {
        let label = format!("{plan} {}", if noisy { "noisy" } else { "noise-free" });
        errors.extend(check_case(&label, &model, &data(plan, noisy, seed), noisy));
    }
    assert!(errors.is_empty(), "{}", errors.join("\n"));
}

#[test]
fn engines_agree_on_test1() {
    check_plan("test1", 21);
}

#[test]
fn engines_agree_on_test2() {
    check_plan("test2", 22);
}

#[test]
fn engines_agree_on_test3() {
    check_plan("test3", 23);
}

#[test]
fn engines_agree_on_test4() {
    check_plan("test4", 24);
}

#[test]
fn engines_agree_on_test5() {
    check_plan("test5", 25);
}

#[test]
fn engines_agree_in_monomial_and_chebyshev_bases() {
    let mut errors = Vec::new();
    for (basis, text) in [
        ("monomial", "basis = \"monomial\"\ndegree = 3"),
        ("chebyshev", "basis = \"chebyshev\"\nnodes = 4"),
    ] {
        let model = paper_model(text, true, true);
        for noisy in [false, true] {
            let label = format!(
                "test4 {basis} {}",
                if noisy { "noisy" } else { "noise-free" }
            );
            errors.extend(check_case(&label, &model, &data("test4", noisy, 26), noisy));
        }
    }
    assert!(errors.is_empty(), "{}", errors.join("\n"));
}

mod common;

#[test]
fn volver_compare_prints_every_engine_and_json() {
    let out = common::volver(&[
        "compare",
        "--objective",
        "ve",
        "--engines",
        "lm,lm",
        "--max-iterations",
        "30",
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let rows = v["engines"].as_array().unwrap();
    assert_eq!(rows.len(), 2);
    assert_eq!(v["points"], 1040); // test 4: 520 positions × 2 reflectors
    for r in rows {
        assert_eq!(r["engine"], "lm");
        assert!(r["phi_mm"].as_f64().unwrap() > 0.0);
        assert!(r["termination"].as_str().unwrap().contains(':'));
    }
    // Deterministic: the same engine twice gives the same fit.
    assert_eq!(rows[0]["ve_mm2"], rows[1]["ve_mm2"]);
    // The table names every engine of the build.
    let out = common::volver(&["compare", "--objective", "ve", "--max-iterations", "3"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    for name in engine_names() {
        assert!(text.contains(name), "{name} missing from\n{text}");
    }
    // An unknown engine, or one this build lacks, is a clear error.
    let out = common::volver(&["compare", "--engines", "simplex"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("unknown solver 'simplex'") && err.contains("lm"),
        "{err}"
    );
}

#[test]
fn every_engine_reports_invalid_input_instead_of_panicking() {
    let model = Model::default_xcfz();
    let data = data("test3", true, 3);
    let problem = Problem::new(&model, &data).unwrap();
    let task = Task::new(problem);
    let mut bad = task.clone();
    // Two contradicting constraints on one parameter.
    for rhs in [0.0, 1.0] {
        bad.constraints.rows.push(volver::core::model::Constraint {
            kind: volver::core::model::ConstraintKind::Fixed,
            label: format!("p0 = {rhs}"),
            coeffs: vec![(0, 1.0)],
            rhs,
        });
    }
    for name in engine_names() {
        let e = engine(name).unwrap();
        let short = e.solve(&task, &[0.0; 3], &Options::default(), &mut Silent);
        assert!(
            matches!(short.summary.termination, Termination::InvalidInput(_)),
            "{name}: {}",
            short.summary.termination
        );
        let mut nan = model.initial_params();
        nan[0] = f64::NAN;
        let s = e.solve(&task, &nan, &Options::default(), &mut Silent);
        assert!(s.summary.termination.failed(), "{name}: NaN start accepted");
        let s = e.solve(
            &bad,
            &model.initial_params(),
            &Options::default(),
            &mut Silent,
        );
        assert!(
            matches!(s.summary.termination, Termination::InvalidInput(_)),
            "{name}: contradicting constraints gave {}",
            s.summary.termination
        );
    }
}

/// Ranges alone from four stations (120 poses, a tracing interferometer's noise, the
/// stations' positions and range offsets identified): every engine takes the scalar residuals
/// as it takes points, and they agree as on the tracker's points.
#[test]
fn engines_agree_on_ranges_from_four_stations() {
    use volver::core::machine::{Observes, StationSpec};
    use volver::core::measure::Observation;
    let xcfz = Machine::default_xcfz();
    let multi = xcfz
        .with_stations(StationSpec::default_layout(&xcfz, 4, Observes::Range))
        .unwrap();
    let text = volver::core::model::DEFAULT_MODEL_TOML.replace(
        "identify = [\"x\", \"y\", \"z\"]",
        "identify = [\"x\", \"y\", \"z\"]\nrange_offset = true",
    );
    let model = Model::from_toml_str(multi.clone(), &text, "ranges").unwrap();
    let truth = Truth::random(
        &multi,
        Model::default_xcfz().spec(),
        &Magnitudes::default(),
        26,
    )
    .unwrap();
    let mut errors = Vec::new();
    for noisy in [false, true] {
        // 120 poses (X 5, C 6, Z 4 positions: enough for the cubics and first harmonics).
        let plan = Plan::parse_grid(&multi, "X=0:1400:350,C=0:300:60,Z=0:600:200").unwrap();
        let mut sim = Simulation::new(plan, truth.clone(), 26);
        sim.noise = if noisy {
            TrackerNoise::from_text("normal:0,0,0.1,0.15").unwrap()
        } else {
            TrackerNoise::NONE
        };
        sim.observe = Observation::Range;
        let data = sim.run().unwrap().measurements;
        let label = format!("ranges {}", if noisy { "noisy" } else { "noise-free" });
        errors.extend(check_case(&label, &model, &data, noisy));
    }
    assert!(errors.is_empty(), "{}", errors.join("\n"));
}
