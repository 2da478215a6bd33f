//! Identification with the native Levenberg–Marquardt on synthetic data: noise-free recovery,
//! fit to the noise level, equal Φ across equivalent bases, constraints at the solution.

use volver::core::machine::Machine;
use volver::core::measure::MeasurementSet;
use volver::core::model::{ErrorModelSpec, Model};
use volver::core::noise::TrackerNoise;
use volver::core::plan::Plan;
use volver::core::problem::Problem;
use volver::core::simulate::{Magnitudes, Simulation, Synthetic, Truth};
use volver::solvers::lm::LevenbergMarquardt;
use volver::solvers::strategy::{Strategy, identify};
use volver::solvers::{Objective, Options, Silent};

fn simulate(plan: &str, noise: TrackerNoise, seed: u64) -> Synthetic {
    let m = Machine::default_xcfz();
    let mags = Magnitudes {
        tracker_mm: 5.0,
        ..Magnitudes::default()
    };
    let truth = Truth::random(&m, &ErrorModelSpec::complete(&m), &mags, seed).unwrap();
    let mut sim = Simulation::new(Plan::preset(&m, plan).unwrap(), truth, seed);
    sim.noise = noise;
    sim.run().unwrap()
}

fn fit(
    model: &Model,
    data: &MeasurementSet,
    objective: Objective,
) -> volver::solvers::strategy::Identification {
    let problem = Problem::new(model, data).unwrap();
    let options = Options {
        objective,
        ..Options::default()
    };
    identify(
        &LevenbergMarquardt,
        problem,
        &model.initial_params(),
        &Strategy::default(),
        &options,
        &mut Silent,
    )
}

#[test]
fn noise_free_test4_is_recovered_to_1e_6_of_the_initial_error() {
    let sim = simulate("test4", TrackerNoise::NONE, 7);
    let model = Model::default_xcfz();
    for objective in [Objective::Phi, Objective::Ve] {
        let id = fit(&model, &sim.measurements, objective);
        println!(
            "{objective}: {:?} EMM {} → {} µm, {} iterations, {} evaluations",
            id.termination,
            id.initial.stats.emm_um,
            id.final_.stats.emm_um,
            id.iterations(),
            id.evaluations()
        );
        assert!(id.termination.converged(), "{:?}", id.termination);
        assert!(id.final_.stats.emm_um <= 1e-6 * id.initial.stats.emm_um);
        assert!(model.constraints().max_violation(&id.params) < 1e-12);
    }
}

#[test]
fn with_the_papers_noise_the_fit_reaches_the_noise_error() {
    let sim = simulate("test4", TrackerNoise::PAPER, 8);
    let model = Model::default_xcfz();
    let id = fit(&model, &sim.measurements, Objective::Phi);
    let noise = sim.record.noise_error.emm_um;
    let ratio = id.final_.stats.emm_um / noise;
    println!(
        "{:?} EMM {} → {} µm, noise {noise} µm, ratio {ratio}, {} iterations",
        id.termination,
        id.initial.stats.emm_um,
        id.final_.stats.emm_um,
        id.iterations()
    );
    assert!(id.termination.converged(), "{:?}", id.termination);
    assert!((0.97..=1.02).contains(&ratio), "final/noise = {ratio}");
}

fn model_with(linear: &str, rotary: &str) -> Model {
    let rotary_block = if rotary.is_empty() {
        String::new()
    } else {
        format!(
            "[[error]]\nname = [\"EXC\", \"EYC\", \"EZC\", \"EAC\", \"EBC\", \"ECC\"]\n{rotary}\n"
        )
    };
    let text = format!(
        r#"
        squareness = "from-straightness"
        [[error]]
        name = ["EXX", "EYX", "EZX", "EAX", "EBX", "ECX", "EXZ", "EYZ", "EZZ", "EAZ", "EBZ", "ECZ"]
        {linear}
        {rotary_block}
        [[error]]
        name = ["A0Z", "B0Z"]
        [tracker]
        identify = ["x", "y", "z"]
        "#
    );
    Model::from_toml_str(Machine::default_xcfz(), &text, "inline").unwrap()
}

#[test]
fn equivalent_polynomial_bases_reach_the_same_phi() {
    // The linear axes on the table-7 mesh (C = 0): an identifiable problem.
    let sim = simulate("table7", TrackerNoise::PAPER, 9);
    let mut phis = vec![];
    for linear in [
        "basis = \"monomial\"\ndegree = 3",
        "basis = \"legendre\"\ndegree = 3",
        "basis = \"chebyshev\"\nnodes = 4",
    ] {
        let model = model_with(linear, "");
        let id = fit(&model, &sim.measurements, Objective::Phi);
        println!(
            "{linear:?}: {:?} Φ {:.15e} mm, {} iterations, {} held",
            id.termination,
            id.final_.phi_mm,
            id.iterations(),
            id.phases[0].unidentifiable
        );
        assert!(id.termination.converged());
        assert!(model.constraints().max_violation(&id.params) < 1e-12);
        phis.push(id.final_.phi_mm);
    }
    for phi in &phis {
        assert!((phi / phis[1] - 1.0).abs() < 1e-9, "{phis:?}");
    }
}

/// The rotary axis alone on the table-4 mesh (X = Z = 0): table 5's study.
fn rotary_model(basis: &str) -> Model {
    let text = format!(
        "[[error]]\nname = [\"EXC\", \"EYC\", \"EZC\", \"EAC\", \"EBC\", \"ECC\"]\n{basis}\n[tracker]\nidentify = [\"x\", \"y\", \"z\"]\n"
    );
    Model::from_toml_str(Machine::default_xcfz(), &text, "inline").unwrap()
}

#[test]
fn fourier_and_sine_series_of_equal_order_reach_the_same_phi() {
    let sim = simulate("table4", TrackerNoise::PAPER, 10);
    let fourier = rotary_model("basis = \"fourier\"\norder = 2");
    let f = fit(&fourier, &sim.measurements, Objective::Phi);
    // A reasonable start for the sine series: the Fourier solution as amplitudes and phases,
    // a·sin θ + b·cos θ = A·sin(θ + φ) with A = √(a² + b²), φ = atan2(b, a).
    let sine = rotary_model("basis = \"sine\"\norder = 2");
    let mut start = sine.initial_params();
    for (j, info) in sine.params().iter().enumerate() {
        let name = &info.name;
        let get = |s: &str| f.params[fourier.param_index(s).unwrap()];
        start[j] = if let Some((e, h)) = name.split_once(".a") {
            get(&format!("{e}.a{h}")).hypot(get(&format!("{e}.b{h}")))
        } else if let Some((e, h)) = name.split_once(".phi") {
            get(&format!("{e}.b{h}")).atan2(get(&format!("{e}.a{h}")))
        } else {
            f.params[fourier.param_index(name).unwrap()]
        };
    }
    let problem = Problem::new(&sine, &sim.measurements).unwrap();
    let s = identify(
        &LevenbergMarquardt,
        problem,
        &start,
        &Strategy {
            init_tracker: false,
            ..Strategy::default()
        },
        &Options::default(),
        &mut Silent,
    );
    println!(
        "fourier {:?} Φ {:.15e}; sine {:?} Φ {:.15e}",
        f.termination, f.final_.phi_mm, s.termination, s.final_.phi_mm
    );
    assert!(f.termination.converged() && s.termination.converged());
    assert!((s.final_.phi_mm / f.final_.phi_mm - 1.0).abs() < 1e-9);
}
