//! `diagnose` states the size of each candidate kind as the hand-set truth: noise-free data of
//! the paper's test 4 from a truth inside the paper's model plus one effect of a known size; the
//! true candidate's size (the column `diagnose` prints and `--json` holds) must be that size.
//! The sizes come from one Gauss–Newton step of the extended model from the current fit, so
//! they match to the step's linearisation: within 3 % here. Each size is checked on five
//! random truths and must hold on at least 4 (`common::found_on_most_seeds`), in a release
//! build (`scripts/test`); debug builds skip them.

mod common;

use volver::core::machine::Machine;
use volver::core::model::{ErrorModelSpec, Model, OneOrMany};
use volver::core::noise::TrackerNoise;
use volver::core::plan::Plan;
use volver::core::problem::Problem;
use volver::core::simulate::{Effect, Magnitudes, Simulation, Truth};
use volver::solvers::candidates::{Score, rank};
use volver::solvers::strategy::fit;

/// The candidates `diagnose` ranks for noise-free test-4 data of `truth` with `effects`, fitted
/// with `model`.
fn ranked(model: &Model, truth: Truth, effects: Vec<Effect>) -> Vec<Score> {
    let m = model.machine();
    let mut sim = Simulation::new(Plan::preset(m, "test4").unwrap(), truth, 5);
    sim.noise = TrackerNoise::NONE;
    sim.effects = effects;
    let data = sim.run().unwrap().measurements;
    let problem = Problem::new(model, &data).unwrap();
    let id = fit(problem.clone());
    assert!(id.termination.converged(), "{}", id.termination);
    rank(
        &problem,
        &id.params,
        volver::solvers::identifiability::RANK_TOLERANCE,
        None,
    )
}

/// A random truth inside the paper's model (default magnitudes).
fn paper_truth(seed: u64) -> Truth {
    let m = Machine::default_xcfz();
    Truth::random(
        &m,
        Model::default_xcfz().spec(),
        &Magnitudes::default(),
        seed,
    )
    .unwrap()
}

fn size_of<'a>(ranked: &'a [Score], id: &str) -> &'a Score {
    ranked
        .iter()
        .find(|s| s.id == id || s.equivalent.iter().any(|e| e == id))
        .unwrap_or_else(|| panic!("{id} is not ranked"))
}

fn check(ranked: &[Score], id: &str, want: f64, unit: &str) {
    let s = size_of(ranked, id);
    println!(
        "{id}: size {} {} (set {want} {unit}), ΔBIC {:.0}",
        s.size, s.size_unit, s.delta_bic
    );
    assert!(
        s.strong(),
        "{id} is not strongly supported: ΔBIC {}",
        s.delta_bic
    );
    assert_eq!(s.size_unit, unit, "{id}");
    assert!(
        (s.size / want - 1.0).abs() < 0.03,
        "{id}: size {} {unit}, set {want} {unit}",
        s.size
    );
}

/// (`tracker-tilt` is not among them: on this machine the tracker stands on the turntable, and
/// its tilt is the same motion as the constant terms of EAC and EBC, which the paper's model
/// has, so the data show no tilt candidate at all.)
#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "release only (scripts/test): 5 seeds per claim"
)]
fn effect_candidates_state_their_hand_set_size() {
    common::found_on_most_seeds("effect candidates' sizes", 3, effect_sizes);
}

/// [`effect_candidates_state_their_hand_set_size`] on the truth of `seed`.
fn effect_sizes(seed: u64) {
    let model = Model::default_xcfz();
    for (effect, id, want, unit) in [
        ("ball-screw=X,175,3", "ball-screw:X:175", 3.0, "µm"),
        ("thermal-drift=0,0,15", "thermal-drift", 15.0, "µm/h"),
        // Along the R1–R2 line (40, 50, 100) mm: a rotation of the tool about R2 moves R1 across
        // that line and can stand in for an offset across it (the rotation errors vanish only
        // at Z = 0), so only this component of an offset is fully determined by test 4.
        (
            "reflector-offset=R1,6.643638,8.304548,16.609096",
            "reflector-offset:R1",
            20.0,
            "µm",
        ),
        ("range-scale=10", "range-scale", 10.0, "ppm"),
    ] {
        let r = ranked(
            &model,
            paper_truth(seed),
            vec![Effect::parse(effect).unwrap()],
        );
        check(&r, id, want, unit);
    }
}

/// A ball-screw candidate's size is its amplitude in µm, not the tilt the step gives the tracker
/// when the model identifies it (issue: every ball-screw candidate printed "6.12 µrad").
#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "release only (scripts/test): 5 seeds per claim"
)]
fn a_ball_screw_size_is_its_amplitude_when_the_model_identifies_the_tracker_tilt() {
    common::found_on_most_seeds("ball-screw size with the tilt identified", 4, screw_size);
}

/// [`a_ball_screw_size_is_its_amplitude_when_the_model_identifies_the_tracker_tilt`] on the
/// truth of `seed`.
fn screw_size(seed: u64) {
    let mut spec = Model::default_xcfz().spec().clone();
    spec.tracker = Default::default(); // all six pose values identified
    let model = Model::new(Machine::default_xcfz(), spec).unwrap();
    let r = ranked(
        &model,
        paper_truth(seed),
        vec![Effect::parse("ball-screw=X,350,4").unwrap()],
    );
    check(&r, "ball-screw:X:350", 4.0, "µm");
    // Every ball-screw candidate is sized in µm.
    for s in r.iter().filter(|s| s.id.starts_with("ball-screw")) {
        assert_eq!(s.size_unit, "µm", "{}", s.id);
    }
}

/// `add:ECX`: the truth's ECX is 10 µrad·(1 + ξ) (zero at X = 0, 20 µrad at X = 1400 mm), which
/// the fitted model leaves out. Its constant 10 µrad is a turn about z of all the X carriage
/// carries, which the model without ECX already makes (the constant of ECC and the tracker's
/// orientation); the size is of what ECX adds beyond that (issue 44): its slope, 10 µrad·ξ,
/// whose largest value is 10 µrad.
#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "release only (scripts/test): 5 seeds per claim"
)]
fn an_added_error_states_its_largest_value() {
    common::found_on_most_seeds("add:ECX size", 6, added_size);
}

/// [`an_added_error_states_its_largest_value`] on the truth of `seed`.
fn added_size(seed: u64) {
    let m = Machine::default_xcfz();
    let full = Model::default_xcfz();
    let mut t = paper_truth(seed);
    for (name, v) in [
        ("ECX.c0", 10e-6),
        ("ECX.c1", 10e-6),
        ("ECX.c2", 0.0),
        ("ECX.c3", 0.0),
    ] {
        t.params[full.param_index(name).unwrap()] = v;
    }
    let mut spec: ErrorModelSpec = full.spec().clone();
    let entry = &mut spec.errors[0];
    let names: Vec<String> = entry
        .name
        .names()
        .iter()
        .filter(|n| **n != "ECX")
        .map(|n| n.to_string())
        .collect();
    entry.name = OneOrMany::Many(names);
    let model = Model::new(m, spec).unwrap();
    let r = ranked(&model, t, vec![]);
    check(&r, "add:ECX", 10.0, "µrad");
    assert_eq!(r[0].id, "add:ECX");
}

/// Through the CLI: `diagnose --json` holds the size of the hidden ball-screw error, and the
/// verdict names it.
#[test]
fn diagnose_json_states_the_ball_screw_amplitude() {
    let dir = std::env::temp_dir().join(format!("volver-sizes-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let d = dir.to_str().unwrap();
    common::simulate(
        d,
        &[
            "--plan",
            "test4",
            "--seed",
            "3",
            "--noise",
            "none",
            "--truth-model",
            "core/data/xcfz-paper-model.toml",
            "--effect",
            "ball-screw=X,175,3",
        ],
    );
    let data = dir.join("measurements.csv");
    let out = common::volver(&["diagnose", "--data", data.to_str().unwrap(), "--json"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let c = &v["candidates"][0];
    assert_eq!(c["id"], "ball-screw:X:175", "{v}");
    assert_eq!(c["size_unit"], "µm");
    let size = c["size"].as_f64().unwrap();
    assert!((size / 3.0 - 1.0).abs() < 0.03, "{size}");
    assert!(
        v["verdict"]
            .as_str()
            .unwrap()
            .starts_with("add ball-screw:X:175"),
        "{v}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// `raise:EXX`: the truth's EXX has a fourth-degree Legendre term c₄(P₄(ξ) − 1) with c₄ = 5 µm
/// (zero at X = 0, ξ = −1), which the paper's cubic cannot follow. The fitted cubic is close to
/// the least-squares cubic g through the plan's X positions that vanishes at X = 0 (EXX moves
/// every point along x alike); the size is the largest change the next degree brings,
/// max |f − g| over the travel, computed here independently by a 3 × 3 least-squares solve.
/// 10 % allowed: the model's other errors take a little of the quartic too (measured: 4.02 µm
/// against 3.81 µm; with the constant free, 3.25 µm, so the data do not let the constant go).
#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "release only (scripts/test): 5 seeds per claim"
)]
fn a_raised_degree_states_the_change_it_brings() {
    common::found_on_most_seeds("raise:EXX size", 8, raised_size);
}

/// [`a_raised_degree_states_the_change_it_brings`] on the truth of `seed`.
fn raised_size(seed: u64) {
    let m = Machine::default_xcfz();
    let paper = Model::default_xcfz();
    let mut spec: ErrorModelSpec = paper.spec().clone();
    let entry = &mut spec.errors[0];
    let names: Vec<String> = entry
        .name
        .names()
        .iter()
        .filter(|n| **n != "EXX")
        .map(|n| n.to_string())
        .collect();
    entry.name = OneOrMany::Many(names);
    let mut exx = spec.errors[0].clone();
    exx.name = OneOrMany::One("EXX".into());
    exx.degree = Some(4);
    spec.errors.push(exx);
    let truth_model = Model::new(m.clone(), spec).unwrap();
    let base = paper_truth(seed);
    let mut params = truth_model.initial_params();
    for (j, info) in truth_model.params().iter().enumerate() {
        if let Some(i) = paper.param_index(&info.name) {
            params[j] = base.params[i];
        }
    }
    let c4 = 5e-3;
    params[truth_model.param_index("EXX.c4").unwrap()] = c4;
    params[truth_model.param_index("EXX.c0").unwrap()] -= c4;
    let truth = Truth {
        model: truth_model,
        params,
    };
    let r = ranked(&paper, truth, vec![]);
    let s = size_of(&r, "raise:EXX");
    println!(
        "raise:EXX: size {} {}, ΔBIC {:.0}",
        s.size, s.size_unit, s.delta_bic
    );
    assert!(s.strong() && s.size_unit == "µm");
    let want = quartic_left_by_a_cubic(c4);
    assert!(
        (s.size / want - 1.0).abs() < 0.1,
        "{} µm vs {want} µm",
        s.size
    );
}

/// The largest value (µm) of what a cubic with EXX's constraint (zero at X = 0) leaves of
/// `c4 · (P₄(ξ) − 1)`, fitted by least squares over test 4's X positions.
#[allow(clippy::needless_range_loop)] // a textbook elimination reads best with indices
fn quartic_left_by_a_cubic(c4: f64) -> f64 {
    // Independently: g(ξ) = a₁(ξ + 1) + a₂(ξ² − 1) + a₃(ξ³ + 1), least squares over test 4's
    // X positions (0 … 1400 mm every 200, each measured alike), f = c₄(P₄(ξ) − 1).
    let p4 = |t: f64| (35.0 * t.powi(4) - 30.0 * t * t + 3.0) / 8.0;
    let f = |t: f64| c4 * (p4(t) - 1.0);
    let basis = |t: f64| [t + 1.0, t * t - 1.0, t.powi(3) + 1.0];
    let (mut n, mut b) = ([[0.0; 3]; 3], [0.0; 3]);
    for i in 0..=7 {
        let xi = 2.0 * (200.0 * i as f64) / 1400.0 - 1.0;
        let phi = basis(xi);
        for r in 0..3 {
            b[r] += phi[r] * f(xi);
            for c in 0..3 {
                n[r][c] += phi[r] * phi[c];
            }
        }
    }
    // Gaussian elimination (the normal matrix is well conditioned here).
    for k in 0..3 {
        for r in k + 1..3 {
            let m = n[r][k] / n[k][k];
            for c in k..3 {
                n[r][c] -= m * n[k][c];
            }
            b[r] -= m * b[k];
        }
    }
    let mut a = [0.0; 3];
    for k in (0..3).rev() {
        a[k] = (b[k] - (k + 1..3).map(|c| n[k][c] * a[c]).sum::<f64>()) / n[k][k];
    }
    (0..=64)
        .map(|i| {
            let t = -1.0 + 2.0 * i as f64 / 64.0;
            let g: f64 = basis(t).iter().zip(&a).map(|(p, a)| p * a).sum();
            (f(t) - g).abs() * 1e3
        })
        .fold(0.0, f64::max)
}
