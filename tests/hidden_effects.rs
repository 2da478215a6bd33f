//! Hidden-effect tests: data carrying one effect that the fitting model leaves out. The
//! diagnosis ranks the true effect first, and after adding it the final EMM is within 5 % of the
//! noise error, under low noise and under the paper's noise. Each "is found" claim holds on at
//! least 4 of 5 seeds (truth and noise drawn anew; `common::found_on_most_seeds`), in a release
//! build (`scripts/test`); debug builds skip them.

mod common;
use common::volver;

use volver::core::machine::Machine;
use volver::core::model::{ErrorModelSpec, Model, OneOrMany};
use volver::core::noise::TrackerNoise;
use volver::core::plan::Plan;
use volver::core::problem::Problem;
use volver::core::simulate::{Effect, Magnitudes, Simulation, Synthetic, Truth};
use volver::solvers::candidates::{carry_over, library, rank};
use volver::solvers::lm::LevenbergMarquardt;
use volver::solvers::strategy::{Strategy, fit, identify};
use volver::solvers::{Options, Silent};

/// `volver simulate` of test 4 under low noise with a hidden second rotary harmonic, into a
/// fresh folder named after `name`.
fn simulate_harmonic_files(name: &str, seed: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("volver-{name}-{}", std::process::id()));
    let out = volver(&[
        "simulate",
        "--plan",
        "test4",
        "--seed",
        seed,
        "--noise",
        "3,3,0.5,0.1",
        "--effect",
        "rotary-harmonics=2,20,40",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    dir
}

const LOW_NOISE: TrackerNoise = TrackerNoise {
    distribution: volver::core::noise::Distribution::Normal,
    azimuth_urad: 3.0,
    elevation_urad: 3.0,
    range_um: 0.5,
    range_um_per_m: 0.1,
};

fn simulate(noise: TrackerNoise, effects: Vec<Effect>, seed: u64) -> Synthetic {
    simulate_with(Magnitudes::default(), noise, effects, seed)
}

fn simulate_with(
    mags: Magnitudes,
    noise: TrackerNoise,
    effects: Vec<Effect>,
    seed: u64,
) -> Synthetic {
    let m = Machine::default_xcfz();
    let truth = Truth::random_complete(&m, &mags, seed).unwrap();
    let mut sim = Simulation::new(Plan::preset(&m, "test4").unwrap(), truth, seed);
    sim.noise = noise;
    sim.effects = effects;
    sim.run().unwrap()
}

/// Fits `spec`, checks the top candidate is `want`, adds it, refits, and checks the final EMM
/// against the noise error.
fn diagnose_and_fix(spec: ErrorModelSpec, sim: &Synthetic, want: &str) {
    let m = Machine::default_xcfz();
    let model = Model::new(m.clone(), spec).unwrap();
    let problem = Problem::new(&model, &sim.measurements).unwrap();
    let before = fit(problem.clone());
    let ranked = rank(
        &problem,
        &before.params,
        volver::solvers::identifiability::RANK_TOLERANCE,
        Some(&sim.record.noise),
    );
    let noise = sim.record.noise_error.emm_um;
    println!(
        "{want}: EMM {:.3} µm, noise error {noise:.3} µm",
        before.reached.stats.emm_um
    );
    for s in ranked.iter().take(4) {
        println!(
            "  {:<16} ΔBIC {:>14.6}  EMM → {:>9.3} µm  +{} dir  size {:.2} {}  {}",
            s.id,
            s.delta_bic,
            s.emm_um,
            s.added,
            s.size,
            s.size_unit,
            if s.equivalent.is_empty() {
                String::new()
            } else {
                format!("(same as {})", s.equivalent.join(", "))
            }
        );
    }
    assert!(
        ranked[0].id == want || ranked[0].equivalent.iter().any(|e| e == want),
        "the true effect is ranked first (or tied with what the data cannot tell from it)"
    );
    assert!(ranked[0].delta_bic < -10.0);
    let candidate = library(&model).into_iter().find(|c| c.id == want).unwrap();
    let extended = Model::new(m, candidate.spec).unwrap();
    let ext_problem = Problem::new(&extended, &sim.measurements).unwrap();
    let start = carry_over(&model, &before.params, &extended);
    let after = identify(
        &LevenbergMarquardt::default(),
        ext_problem,
        &start,
        &Strategy::default(),
        &Options::default(),
        &mut Silent,
    );
    let ratio = after.reached.stats.emm_um / noise;
    println!(
        "  after {want}: EMM {:.3} µm = {ratio:.4} × noise error ({:?})",
        after.reached.stats.emm_um, after.termination
    );
    assert!(!after.termination.failed(), "{:?}", after.termination);
    assert!((ratio - 1.0).abs() <= 0.05, "final / noise = {ratio}");
}

fn paper_spec() -> ErrorModelSpec {
    Model::default_xcfz().spec().clone()
}

/// The paper's model without some errors.
fn paper_spec_without(left_out: &[&str]) -> ErrorModelSpec {
    let mut spec = paper_spec();
    for e in &mut spec.errors {
        let names: Vec<String> = e
            .name
            .names()
            .into_iter()
            .filter(|n| !left_out.contains(n))
            .map(String::from)
            .collect();
        e.name = OneOrMany::Many(names);
    }
    spec
}

#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "release only (scripts/test): 5 seeds per claim"
)]
fn a_left_out_iso_error_is_found() {
    // The fitting model lacks EAC (a tilt motion of the turntable). A tracker standing on the
    // table and tilted is the same to these data (its tilt turns with the table): the diagnosis
    // reports the two as equivalent.
    // Tilt motions of 75–150 µrad stand out of the paper's noise.
    let spec = paper_spec_without(&["EAC"]);
    let mags = Magnitudes {
        tilt_urad: 150.0,
        ..Magnitudes::default()
    };
    for noise in [LOW_NOISE, TrackerNoise::PAPER] {
        common::found_on_most_seeds(&format!("add:EAC under {noise}"), 31, |seed| {
            diagnose_and_fix(
                spec.clone(),
                &simulate_with(mags, noise, vec![], seed),
                "add:EAC",
            );
        });
    }
}

#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "release only (scripts/test): 5 seeds per claim"
)]
fn a_higher_rotary_harmonic_is_found() {
    let effect = Effect::RotaryHarmonics {
        max_order: 2,
        translation_um: 20.0,
        rotation_urad: 40.0,
    };
    for noise in [LOW_NOISE, TrackerNoise::PAPER] {
        common::found_on_most_seeds(&format!("raise-axis:C under {noise}"), 32, |seed| {
            diagnose_and_fix(
                paper_spec(),
                &simulate(noise, vec![effect.clone()], seed),
                "raise-axis:C",
            );
        });
    }
}

#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "release only (scripts/test): 5 seeds per claim"
)]
fn a_tilted_tracker_is_found() {
    let effect = Effect::TrackerTilt {
        rx_urad: 200.0,
        ry_urad: -150.0,
    };
    // A turntable without tilt motion (modelled without EAC, EBC) measured by a tilted tracker.
    // (With EAC and EBC in the model the tilt is absorbed by their first harmonics: a tilt fixed
    // to the table is a tilt turning with C.)
    let mags = Magnitudes {
        tilt_urad: 0.0,
        ..Magnitudes::default()
    };
    for noise in [LOW_NOISE, TrackerNoise::PAPER] {
        common::found_on_most_seeds(&format!("tracker-tilt under {noise}"), 33, |seed| {
            diagnose_and_fix(
                paper_spec_without(&["EAC", "EBC"]),
                &simulate_with(mags, noise, vec![effect.clone()], seed),
                "tracker-tilt",
            );
        });
    }
}

#[test]
fn volver_diagnose_ranks_the_hidden_effect_first_in_json() {
    let dir = simulate_harmonic_files("diagnose", "32");
    let data = dir.join("measurements.csv");
    let out = volver(&[
        "diagnose",
        "--data",
        data.to_str().unwrap(),
        "--json",
        "--top",
        "5",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let c = &v["candidates"];
    assert_eq!(c.as_array().unwrap().len(), 5);
    assert_eq!(c[0]["id"], "raise-axis:C");
    for key in [
        "id",
        "description",
        "delta_bic",
        "emm_um",
        "size",
        "size_unit",
    ] {
        assert!(!c[0][key].is_null(), "{key}");
    }
    assert!(c[0]["delta_bic"].as_f64().unwrap() < -10.0);
    assert_eq!(v["outliers"].as_array().unwrap().len(), 5);
    assert!(v["outliers"][0]["line"].as_u64().unwrap() >= 2);
    // Test 4's C = 0° and 360° points are reached from opposite sides of C (0° after the turn
    // back): not repeats, but the two sides of C, which show no reversal (none is hidden).
    assert!(v["noise_estimate_um"].is_null() && v["repeat_pairs"].is_null());
    let c_split = v["directions"]
        .as_array()
        .unwrap()
        .iter()
        .find(|d| d["axis"] == "C")
        .unwrap();
    assert_eq!(c_split["positions_both"], 1, "{c_split}");
    assert_eq!(c_split["significant"], false, "{c_split}");
    // The harmonic shows in C's periodogram at order 2 (machine frame).
    let c_lines = v["periodograms"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["axis"] == "C")
        .unwrap()["lines"]
        .clone();
    let amp = |k: usize| {
        let a = c_lines[k]["amplitude_um"].as_array().unwrap();
        a.iter()
            .map(|x| x.as_f64().unwrap().powi(2))
            .sum::<f64>()
            .sqrt()
    };
    assert!(amp(1) > 5.0 * amp(0) && amp(1) > 5.0 * amp(2), "{c_lines}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn volver_identify_add_refits_with_the_candidate_and_writes_the_model() {
    let dir = simulate_harmonic_files("add", "33");
    let data = dir.join("measurements.csv");
    let truth = dir.join("truth.json");
    let model = dir.join("model.toml");
    let json = |extra: &[&str]| -> serde_json::Value {
        let mut args = vec![
            "identify",
            "--data",
            data.to_str().unwrap(),
            "--truth",
            truth.to_str().unwrap(),
            "--json",
        ];
        args.extend(extra);
        let out = volver(&args);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        serde_json::from_slice(&out.stdout).unwrap()
    };
    let before = json(&[]);
    let after = json(&[
        "--add",
        "raise-axis:C",
        "--write-model",
        model.to_str().unwrap(),
    ]);
    let noise = after["noise_error_um"].as_f64().unwrap();
    let (b, a) = (
        before["emm_final_um"].as_f64().unwrap(),
        after["emm_final_um"].as_f64().unwrap(),
    );
    println!("EMM {b} → {a} µm, noise {noise} µm");
    assert!(b > 5.0 * noise && (a / noise - 1.0).abs() < 0.05);
    // The written model is the extended one: fitting it gives the same EMM.
    let again = json(&["--model", model.to_str().unwrap()]);
    assert!((again["emm_final_um"].as_f64().unwrap() - a).abs() < 1e-6 * a);
    let out = volver(&[
        "identify",
        "--data",
        data.to_str().unwrap(),
        "--add",
        "add:EQQ",
    ]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("not a candidate for this model"));
    // Every fit went into the session's history, beside the data.
    let history = dir.join("volver-history.jsonl");
    let chart = dir.join("history.svg");
    let out = volver(&[
        "history",
        "--file",
        history.to_str().unwrap(),
        "--svg",
        chart.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("3 fits") && text.contains("raise-axis:C"),
        "{text}"
    );
    let svg = std::fs::read_to_string(&chart).unwrap();
    assert_eq!(svg.matches("class=\"revision\"").count(), 3);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "release only (scripts/test): 5 seeds per claim"
)]
fn effects_outside_the_iso_model_are_found() {
    // Sizes that stand out of each noise level; the plan's order (X slowest) lets part of a
    // drift hide in the X errors, so the drift is fast enough to show within each X block.
    for (effect, want) in [
        ("reflector-offset=R1,60,-40,50", "reflector-offset:R1"),
        ("ball-screw=X,700,30", "ball-screw:X:700"),
    ] {
        for noise in [LOW_NOISE, TrackerNoise::PAPER] {
            common::found_on_most_seeds(&format!("{want} under {noise}"), 34, |seed| {
                let sim = simulate(noise, vec![Effect::parse(effect).unwrap()], seed);
                diagnose_and_fix(paper_spec(), &sim, want);
            });
        }
    }
}

#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "release only (scripts/test): 5 seeds per claim"
)]
fn thermal_drift_is_found_when_the_measuring_order_does_not_follow_an_axis() {
    // Measured in plan order (X slowest), time is X: a drift hides in the X errors. Measured in
    // a shuffled order, it stands out.
    let m = Machine::default_xcfz();
    let mut plan = Plan::preset(&m, "test4").unwrap();
    let mut rng = volver::core::random::Rng::new(9);
    for i in (1..plan.positions.len()).rev() {
        let j = (rng.uniform() * (i + 1) as f64) as usize;
        plan.positions.swap(i, j);
    }
    for noise in [LOW_NOISE, TrackerNoise::PAPER] {
        common::found_on_most_seeds(&format!("thermal-drift under {noise}"), 35, |seed| {
            let truth = Truth::random_complete(&m, &Magnitudes::default(), seed).unwrap();
            let mut sim = Simulation::new(plan.clone(), truth, seed);
            sim.noise = noise;
            sim.effects = vec![Effect::parse("thermal-drift=10,-5,60").unwrap()];
            diagnose_and_fix(paper_spec(), &sim.run().unwrap(), "thermal-drift");
        });
    }
}
