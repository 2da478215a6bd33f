//! The gauge is a rule, not a neighbourhood: on test 4, where the paper's model leaves seven
//! combinations unidentified, every engine of the build, from different starts and with the
//! linear axes written in different bases, ends at the same error functions and tracker pose
//! (to 1e-9 relative; measured 1e-11 … 3e-11), and so does the native LM on tests 2 and 3.
//!
//! Agreement is judged on the *functions* (their values over the travel, angles × 1000 mm) and
//! the tracker's pose, never on raw coefficients: the bases differ.

use volver::core::machine::Machine;
use volver::core::measure::MeasurementSet;
use volver::core::model::Model;
use volver::core::noise::TrackerNoise;
use volver::core::plan::Plan;
use volver::core::problem::Problem;
use volver::core::simulate::{Magnitudes, Simulation, Truth};
use volver::solvers::gauge::LEVER_MM;
use volver::solvers::strategy::{Identification, Strategy, identify};
use volver::solvers::{Options, Silent, engine, engine_names};

/// The paper's model with the linear axes in `basis` (tracker position identified).
fn paper_model(basis: &str) -> Model {
    let text = format!(
        "squareness = \"from-straightness\"\n[[error]]\nname = [\"EXX\", \"EYX\", \"EZX\", \"EAX\", \
         \"EBX\", \"ECX\", \"EXZ\", \"EYZ\", \"EZZ\", \"EAZ\", \"EBZ\", \"ECZ\"]\n{basis}\n\
         [[error]]\nname = [\"A0Z\", \"B0Z\"]\n[[error]]\nname = [\"EXC\", \"EYC\", \"EZC\", \
         \"EAC\", \"EBC\", \"ECC\"]\nbasis = \"fourier\"\norder = 1\n[tracker]\nidentify = [\"x\", \
         \"y\", \"z\"]\n"
    );
    Model::from_toml_str(Machine::default_xcfz(), &text, "inline").unwrap()
}

/// Data of `plan` for a random truth inside the paper's model, with the paper's tracker noise.
fn measured(plan: &str, seed: u64) -> MeasurementSet {
    let m = Machine::default_xcfz();
    let truth = Truth::random(
        &m,
        paper_model("basis = \"legendre\"\ndegree = 3").spec(),
        &Magnitudes::default(),
        seed,
    )
    .unwrap();
    let mut sim = Simulation::new(Plan::preset(&m, plan).unwrap(), truth, seed);
    sim.noise = TrackerNoise::PAPER;
    sim.run().unwrap().measurements
}

/// Every error function's values at 65 positions of its travel (mm, angles × [`LEVER_MM`]),
/// in the order of `reference`'s terms, then the tracker's position (mm).
fn functions(reference: &Model, model: &Model, params: &[f64]) -> Vec<f64> {
    let mut v = Vec::new();
    for t in reference.terms() {
        let ax = &model.machine().axes()[t.axis];
        let scale = if t.id.unit() == volver::core::iso::Unit::Mm {
            1.0
        } else {
            LEVER_MM
        };
        for s in 0..65 {
            let u = ax.min + (ax.max - ax.min) * s as f64 / 64.0;
            v.push(scale * model.error_value(t.id, u, params).unwrap());
        }
    }
    for name in ["tracker.x", "tracker.y", "tracker.z"] {
        v.push(params[model.param_index(name).unwrap()]);
    }
    v
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
}

/// A start away from zero errors: every coefficient of an error moved by a seeded amount
/// (up to 10 µm or 10 µrad); the tracker is fitted rigidly from there.
fn perturbed(model: &Model, seed: u64) -> Vec<f64> {
    let mut p = model.initial_params();
    let mut state = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
    for (j, info) in model.params().iter().enumerate() {
        if info.name.starts_with("tracker.") {
            continue;
        }
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        let u = (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
        p[j] += u * match info.unit {
            volver::core::iso::Unit::Rad => 2e-5,
            _ => 2e-2,
        };
    }
    p
}

#[test]
fn on_test_4_engines_starts_and_bases_end_on_the_same_functions() {
    agree("test4", 7, true);
}

#[test]
fn on_test_3_starts_and_bases_end_on_the_same_functions() {
    agree("test3", 1, false);
}

/// Test 2 leaves 59 combinations to the gauge: from a start off zero errors its rows, scaled by
/// that start's Jacobian, once differed in size by 10¹¹ and the constraint elimination called
/// them contradictory (seed 1).
#[test]
fn on_test_2_starts_and_bases_end_on_the_same_functions() {
    agree("test2", 1, false);
}

/// Fits `plan`'s data (seed `seed`) with the native LM from zero errors (the reference), from
/// two perturbed starts and in the monomial basis, and with `all_engines` every other engine of
/// the build; each must end on the reference's functions to 1e-9 relative.
fn agree(plan: &str, seed: u64, all_engines: bool) {
    let data = measured(plan, seed);
    let legendre = paper_model("basis = \"legendre\"\ndegree = 3");
    let monomial = paper_model("basis = \"monomial\"\ndegree = 3");
    let options = Options {
        max_iterations: 2000,
        ..Options::default()
    };
    let strategy = Strategy::default();
    let run = |model: &Model, name: &str, start: &[f64]| -> Identification {
        let problem = Problem::new(model, &data).unwrap();
        let t0 = std::time::Instant::now();
        let id = identify(
            engine(name).unwrap().as_ref(),
            problem,
            start,
            &strategy,
            &options,
            &mut Silent,
        );
        assert!(!id.termination.failed(), "{name}: {}", id.termination);
        eprintln!(
            "{name}: {:.1} s, {} iterations, Φ {:.12} mm, {}",
            t0.elapsed().as_secs_f64(),
            id.iterations(),
            id.reached.phi_mm,
            id.termination
        );
        id
    };
    let base = run(&legendre, "lm", &legendre.initial_params());
    let g = base.gauge.as_ref().expect("the paper's model has a gauge");
    assert!(g.held.len() >= 6, "held {}", g.held.len());
    let reference = functions(&legendre, &legendre, &base.params);
    let size = rms(&reference);
    let mut cases: Vec<(String, Identification, &Model)> = Vec::new();
    // Engines that fit Φ exactly or nearly (MMA and BOBYQA are first-order or derivative-free
    // and stop far from the optimum).
    for name in engine_names()
        .into_iter()
        .filter(|n| all_engines && !matches!(*n, "lm" | "nlopt-mma" | "nlopt-bobyqa"))
    {
        cases.push((
            name.to_string(),
            run(&legendre, name, &legendre.initial_params()),
            &legendre,
        ));
    }
    for seed in [1, 2] {
        cases.push((
            format!("lm from start {seed}"),
            run(&legendre, "lm", &perturbed(&legendre, seed)),
            &legendre,
        ));
    }
    cases.push((
        "lm, monomial basis".into(),
        run(&monomial, "lm", &monomial.initial_params()),
        &monomial,
    ));
    let mut failures = Vec::new();
    for (name, id, model) in &cases {
        let f = functions(&legendre, model, &id.params);
        let diff: Vec<f64> = f.iter().zip(&reference).map(|(a, b)| a - b).collect();
        let rel = rms(&diff) / size;
        let dphi = (id.reached.phi_mm - base.reached.phi_mm) / base.reached.phi_mm;
        let held = id.gauge.as_ref().map_or(0, |g| g.held.len());
        println!("{name}: functions differ by {rel:.2e} relative, Φ by {dphi:.2e}, {held} held");
        if rel > 1e-9 {
            for (k, t) in legendre.terms().iter().enumerate() {
                let seg = &diff[65 * k..65 * k + 65];
                let r = &reference[65 * k..65 * k + 65];
                eprintln!("  {}: diff {:.3e} of {:.3e}", t.id, rms(seg), rms(r));
            }
            eprintln!("  tracker {:?}", &diff[diff.len() - 3..]);
            failures.push(format!("{name}: {rel:.2e}"));
        }
    }
    assert!(failures.is_empty(), "{failures:?}");
}

/// The gauge keeps its meaning under the noise's weighting. Whitening multiplies each point's
/// Jacobian rows by an invertible matrix, which leaves the null space of the design unchanged,
/// and the gauge's reference is the fit to the points in mm (zero errors and the tracker's
/// rigid fit): on test 4 (seed 7, the paper's noise, whitened by it) the fits by `ml` and
/// `phi-w` hold as many combinations as the fit by Φ (7), spanning the same directions (the
/// largest component of a whitened fit's unit held direction outside the Φ fit's span, in the
/// function metric: measured 1.6e-11, bound 1e-8), at the same reference (measured identical,
/// bound 1e-12), and each whitened fit sits at that reference along the Φ fit's held
/// combinations (its offsets along them, mm RMS of the error functions: measured 5e-13 and
/// 9e-13 mm, bound 1e-9 mm).
#[test]
fn a_whitened_fit_holds_the_same_combinations_at_the_same_reference() {
    use volver::solvers::Objective;
    use volver::solvers::lm::LevenbergMarquardt;
    let data = measured("test4", 7);
    let model = paper_model("basis = \"legendre\"\ndegree = 3");
    let problem = Problem::new(&model, &data).unwrap();
    let fit = |problem: Problem, objective: Objective| -> Identification {
        let id = identify(
            &LevenbergMarquardt::default(),
            problem,
            &model.initial_params(),
            &Strategy::default(),
            &Options {
                objective,
                max_iterations: 2000,
                ..Options::default()
            },
            &mut Silent,
        );
        assert!(
            id.termination.converged(),
            "{objective}: {}",
            id.termination
        );
        id
    };
    let plain = fit(problem.clone(), Objective::Phi);
    let g = plain.gauge.as_ref().expect("the paper's model has a gauge");
    assert!(g.held.len() >= 6, "held {}", g.held.len());
    let whitened = problem.whitened(Some(&TrackerNoise::PAPER)).unwrap();
    let n = model.n_params();
    // ⟨a, b⟩ in the function metric of the Φ fit's gauge.
    let inner = |a: &[f64], b: &[f64]| -> f64 {
        (0..n)
            .map(|i| a[i] * (0..n).map(|j| g.metric[(i, j)] * b[j]).sum::<f64>())
            .sum()
    };
    for objective in [Objective::Ml, Objective::PhiW] {
        let id = fit(whitened.clone(), objective);
        let gw = id.gauge.as_ref().expect("the whitened fit has a gauge");
        assert_eq!(
            gw.held.len(),
            g.held.len(),
            "{objective}: held combinations"
        );
        let dref = gw
            .reference
            .iter()
            .zip(&g.reference)
            .fold(0.0_f64, |m, (a, b)| m.max((a - b).abs()));
        // The held directions are M-orthonormal: the part of each whitened one outside the
        // Φ fit's span is what is left after subtracting its components along them.
        let mut outside = 0.0_f64;
        for h in &gw.held {
            let mut rest = h.direction.clone();
            for d in &g.held {
                let c = inner(&d.direction, &h.direction);
                for (r, v) in rest.iter_mut().zip(&d.direction) {
                    *r -= c * v;
                }
            }
            outside = outside.max(inner(&rest, &rest).max(0.0).sqrt());
        }
        let along = g
            .offsets(&id.params)
            .into_iter()
            .fold(0.0_f64, |m, v| m.max(v.abs()));
        let own = gw
            .offsets(&id.params)
            .into_iter()
            .fold(0.0_f64, |m, v| m.max(v.abs()));
        println!(
            "{objective}: {} held (Φ: {}), reference differs by {dref:.1e}, directions outside \
             Φ's span {outside:.2e}, offsets along Φ's held combinations {along:.2e} mm (own \
             {own:.2e} mm)",
            gw.held.len(),
            g.held.len()
        );
        assert!(dref < 1e-12, "{objective}: reference moved by {dref}");
        assert!(
            outside < 1e-8,
            "{objective}: held directions differ by {outside}"
        );
        assert!(
            along < 1e-9,
            "{objective}: offsets {along} mm along Φ's held combinations"
        );
    }
}
