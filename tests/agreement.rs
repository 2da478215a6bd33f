//! The solver agreement suite: every engine of the build minimises the same Φ (and ve, and the
//! noise-weighted `ml` and `phi-w`) under the same constraints and must reach the same fit.
//!
//! Problems: the paper's tests 1–5 with the paper's model (Legendre cubics for the linear
//! axes, first harmonics for C; tests 1 and 2 with only the axes they move), and test 4 with
//! the linear axes in monomial and Chebyshev bases; each noise-free (the truth is inside the model) and with the
//! paper's tracker noise; and ranges alone from four stations (an L1 fit under Φ: Clarabel's
//! SOCP reaches its optimum, the native LM its vertex by linear programmes, measured 5.7e-11
//! above the SOCP's on the noisy ranges); Φ and ve on each. The noise-weighted objectives run
//! on the noisy data of test 4 (whitened by the paper's tracker noise they carry) and of the
//! four stations' ranges (each range by the interferometer's σ at its length): every engine
//! gets the whitened residuals (`Problem::whitened`), is judged on the objective's own value
//! (`Evaluation::cost`: ml as ve, phi-w as Φ, with their tolerances) and on the residuals in
//! mm. Every engine starts from the same point (errors zero, tracker by a rigid fit).
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

/// The value of `objective` an engine reached (Φ mm, ve mm², ml's and phi-w's dimensionless).
fn objective_of(s: &Solution, objective: Objective) -> f64 {
    s.summary.reached.cost(objective)
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
    check_objectives(
        label,
        model,
        data,
        noisy,
        &[Objective::Phi, Objective::Ve],
        None,
    )
}

/// [`check_objectives`] on the noise-weighted objectives `ml` and `phi-w`: every engine given
/// the residuals whitened by `noise` (each station's noise, `Problem::whitened`), judged on the
/// objective's own (dimensionless) value and on the residuals in mm.
fn check_weighted(
    label: &str,
    model: &Model,
    data: &MeasurementSet,
    noise: &TrackerNoise,
) -> Vec<String> {
    check_objectives(
        label,
        model,
        data,
        true,
        &[Objective::Ml, Objective::PhiW],
        Some(noise),
    )
}

/// Every engine on every objective of `objectives` (whitened by `noise` when the objective
/// weighs by it), each judged against the best exact engine.
fn check_objectives(
    label: &str,
    model: &Model,
    data: &MeasurementSet,
    noisy: bool,
    objectives: &[Objective],
    noise: Option<&TrackerNoise>,
) -> Vec<String> {
    let mut errors = Vec::new();
    let problem = Problem::new(model, data).unwrap();
    let start = init_tracker(&problem, &model.initial_params()).unwrap();
    for &objective in objectives {
        let options = Options {
            objective,
            max_iterations: 500,
            max_evaluations: 5000,
            ..Options::default()
        };
        // The residuals the objective weighs: whitened by each station's noise for ml and
        // phi-w, in mm for Φ and ve.
        let fitted = if objective.whitened() {
            problem.whitened(noise).unwrap()
        } else {
            problem.clone()
        };
        let (gauge, initial) = gauged(&fitted, &start, &options, label);
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
        let projected_start = match objective.loss() {
            Objective::Phi => fitted.phi(&p0),
            _ => fitted.ve(&p0),
        };
        // Residuals are compared in mm whatever the objective weighs.
        let best_res = problem.residuals(&best.params);
        println!("  best: {best_name} {best_value:.12e}");
        for (name, options, s) in &runs {
            let value = objective_of(s, objective);
            let dr = largest_difference(&problem.residuals(&s.params), &best_res);
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

/// The largest distance between corresponding residuals of `a` and `b` (mm).
fn largest_difference(a: &[[f64; 3]], b: &[[f64; 3]]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(a, b)| {
            ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
        })
        .fold(0.0, f64::max)
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
    // The noise-weighted objectives are judged as their loss: ml as ve, phi-w as Φ.
    let loss = c.objective.loss();
    let floor = match (c.noisy, loss) {
        (true, _) => 0.0,
        (false, Objective::Phi) => tol.floor * c.initial,
        (false, _) => tol.floor * tol.floor * c.initial,
    };
    let rel = match loss {
        Objective::Phi if c.scalar => tol.phi_scalar,
        Objective::Phi => tol.phi,
        _ => tol.ve,
    };
    let (rel, residual_mm) = match (c.objective.whitened(), c.scalar) {
        (true, true) => (
            rel.max(tol.weighted_scalar),
            tol.residual_mm.max(tol.weighted_residual_mm),
        ),
        (true, false) => (
            rel.max(tol.weighted),
            tol.residual_mm.max(tol.weighted_residual_mm),
        ),
        (false, _) => (rel, tol.residual_mm),
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
        dr < residual_mm,
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
    /// Relative excess allowed on the noise-weighted objectives (ml, phi-w) on points, when
    /// larger than the loss' own (0: the loss' own).
    weighted: f64,
    /// The same on ranges alone.
    weighted_scalar: f64,
    /// Largest residual difference (mm) on the noise-weighted objectives, when larger than
    /// `residual_mm`.
    weighted_residual_mm: f64,
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
        weighted: 0.0,
        weighted_scalar: 0.0,
        weighted_residual_mm: 0.0,
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
            // ml on ranges: 4.1e-9 measured (its ve bound is 1e-9).
            weighted: 1e-8,
            weighted_scalar: 1e-8,
            ..exact
        }),
        // SQP on the smoothed Φ: 3.1e-9 on points, 6.2e-5 on ranges, residuals 24 nm. On the
        // whitened residuals it creeps and stops on NLopt's objective-change test early
        // (restarted where it stopped it ends there again; with that test off it reaches the
        // optimum after 20 000 evaluations): measured 3.7e-7 (ml) and 1.5e-6 (phi-w) on test
        // 4, 4.1e-3 on the ranges' phi-w, residuals 217 nm.
        "nlopt-slsqp" => Some(Tolerance {
            phi: 1e-8,
            phi_scalar: 1.5e-4,
            ve: 1e-9,
            floor: 1e-5,
            residual_mm: 5e-5,
            weighted: 3e-6,
            weighted_scalar: 1e-2,
            weighted_residual_mm: 5e-4,
        }),
        _ => None,
    }
}

fn objective_of_initial(s: &Solution, objective: Objective) -> f64 {
    s.summary.initial.cost(objective)
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

/// `volver compare --objective ml` (and phi-w) gives the engines the residuals whitened by the
/// noise (`--noise`, else the machine file's `[tracker] noise`), says so, and prints the
/// objective's own value beside Φ and ve, the best judged on it; without any noise it is a
/// clear error naming `--noise`, and `--noise` with an objective that does not weigh by it is
/// refused.
#[test]
fn volver_compare_weighs_ml_and_phi_w_by_the_noise() {
    let out = common::volver(&[
        "compare",
        "--objective",
        "ml",
        "--engines",
        "lm,clarabel",
        "--gauge",
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
    assert_eq!(v["objective"], "ml");
    // The embedded machine file's noise: the paper's tracker.
    let noise = v["noise"].as_str().unwrap();
    assert!(noise.contains("uniform:30,30,4,0.8"), "{noise}");
    let rows = v["engines"].as_array().unwrap();
    let values: Vec<f64> = rows.iter().map(|r| r["value"].as_f64().unwrap()).collect();
    // ve of the whitened residuals: ~1 per coordinate, 3 per point at the optimum (the
    // start is far above), not ve in mm² (~3e-3).
    for (r, value) in rows.iter().zip(&values) {
        assert!((1.0..10.0).contains(value), "{r}");
        assert!(r["ve_mm2"].as_f64().unwrap() < 0.1, "{r}");
    }
    // On the gauge the two reach the same optimum.
    assert!((values[0] / values[1] - 1.0).abs() < 1e-6, "{values:?}");
    let out = common::volver(&[
        "compare",
        "--objective",
        "phi-w",
        "--noise",
        "normal:20,20,5,1",
        "--engines",
        "lm",
        "--max-iterations",
        "30",
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains("residuals whitened by tracker normal:20,20,5,1"),
        "{text}"
    );
    assert!(
        text.contains("phi-w") && text.contains("best phi-w: "),
        "{text}"
    );
    // --noise with an objective that does not weigh by it.
    let out = common::volver(&["compare", "--objective", "ve", "--noise", "paper"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--noise") && err.contains("objective ve"),
        "{err}"
    );
    // A machine file without a noise, and no --noise: ml cannot weigh the points.
    let dir = std::env::temp_dir().join(format!("volver-compare-ml-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let d = |f: &str| dir.join(f).display().to_string();
    common::simulate(&d("sim"), &["--plan", "test3", "--seed", "5"]);
    let machine: String = volver::core::machine::DEFAULT_MACHINE_TOML
        .lines()
        .filter(|l| !l.starts_with("noise ="))
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(d("bare.toml"), machine).unwrap();
    std::fs::write(d("model.toml"), volver::core::model::DEFAULT_MODEL_TOML).unwrap();
    let out = common::volver(&[
        "compare",
        "--objective",
        "ml",
        "--machine",
        &d("bare.toml"),
        "--model",
        &d("model.toml"),
        "--data",
        &d("sim/measurements.csv"),
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--objective ml")
            && err.contains("no stated noise")
            && err.contains("--noise"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
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

/// A noise-weighted objective on residuals in mm is refused by every engine before it steps:
/// invalid input naming the objective and the cause (not whitened), the start returned as it
/// was — never a panic, never a silent ve or Φ fit. The same engines accept the whitened
/// residuals.
#[test]
fn every_engine_refuses_a_weighted_objective_on_unwhitened_residuals() {
    let model = Model::default_xcfz();
    let data = data("test3", true, 3);
    let problem = Problem::new(&model, &data).unwrap();
    let plain = Task::new(problem.clone());
    let whitened = Task::new(problem.whitened(Some(&TrackerNoise::PAPER)).unwrap());
    let start = init_tracker(&problem, &model.initial_params()).unwrap();
    for name in engine_names() {
        let e = engine(name).unwrap();
        for objective in [Objective::Ml, Objective::PhiW] {
            let options = Options {
                objective,
                max_iterations: 2,
                max_evaluations: 20,
                ..Options::default()
            };
            let s = e.solve(&plain, &start, &options, &mut Silent);
            let t = &s.summary.termination;
            let text = t.to_string();
            assert!(
                matches!(t, Termination::InvalidInput(_))
                    && text.contains(&format!("objective {objective}"))
                    && text.contains("not whitened"),
                "{name} {objective} on residuals in mm: {text}"
            );
            assert_eq!(s.params, start, "{name} {objective}: moved the parameters");
            assert_eq!(s.summary.iterations, 0, "{name} {objective}: iterated");
            // The whitened residuals are taken (a step or two within the limits above).
            let s = e.solve(&whitened, &start, &options, &mut Silent);
            assert!(
                !s.summary.termination.failed(),
                "{name} {objective} on whitened residuals: {}",
                s.summary.termination
            );
            assert!(
                s.summary.reached.cost(objective).is_finite(),
                "{name} {objective}: no whitened value"
            );
        }
    }
}

/// Ranges alone from four stations (120 poses, a tracing interferometer's noise, the
/// stations' positions and range offsets identified): every engine takes the scalar residuals
/// as it takes points, and they agree as on the tracker's points.
#[test]
fn engines_agree_on_ranges_from_four_stations() {
    let mut errors = Vec::new();
    for noisy in [false, true] {
        let (model, data, _) = ranges_case(noisy);
        let label = format!("ranges {}", if noisy { "noisy" } else { "noise-free" });
        errors.extend(check_case(&label, &model, &data, noisy));
    }
    assert!(errors.is_empty(), "{}", errors.join("\n"));
}

/// The noise-weighted objectives on test 4 with the paper's tracker noise (the data's own,
/// seed 24 as `engines_agree_on_test4`): every engine on the residuals whitened by it, the same
/// optimum to the tolerances of ve (ml) and Φ (phi-w).
#[test]
fn engines_agree_on_ml_and_phi_w_on_test4() {
    let model = paper_model(LEGENDRE, true, true);
    let data = data("test4", true, 24);
    let errors = check_weighted("test4 noisy", &model, &data, &TrackerNoise::PAPER);
    assert!(errors.is_empty(), "{}", errors.join("\n"));
}

/// The noise-weighted objectives on the four stations' noisy ranges, each range weighed by
/// the interferometer's σ at its length: whitened Φ is a weighted L1 fit, judged as Φ on
/// ranges.
#[test]
fn engines_agree_on_ml_and_phi_w_on_ranges_from_four_stations() {
    let (model, data, noise) = ranges_case(true);
    let errors = check_weighted("ranges noisy", &model, &data, &noise);
    assert!(errors.is_empty(), "{}", errors.join("\n"));
}

/// The four-station range case: the model (stations' positions and range offsets identified),
/// the ranges of 120 poses (X 5, C 6, Z 4 positions: enough for the cubics and first
/// harmonics; seed 26) and the interferometer noise they carry when `noisy`.
fn ranges_case(noisy: bool) -> (Model, MeasurementSet, TrackerNoise) {
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
    let plan = Plan::parse_grid(&multi, "X=0:1400:350,C=0:300:60,Z=0:600:200").unwrap();
    let mut sim = Simulation::new(plan, truth, 26);
    let noise = TrackerNoise::from_text("normal:0,0,0.1,0.15").unwrap();
    sim.noise = if noisy { noise } else { TrackerNoise::NONE };
    sim.observe = Observation::Range;
    (model, sim.run().unwrap().measurements, noise)
}
