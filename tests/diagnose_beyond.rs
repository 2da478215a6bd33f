//! Diagnosis beyond the candidate list, on plans without a repeated point (C 0–330°): a noise
//! verdict from the tracker's specification, physical candidates that grow with time, generic
//! fields that name the variables of a non-rigid effect, and the loop run to the end.
//!
//! Each effect runs under low noise and under the paper's, on its own magnitude and five seeds
//! (at least 4 of 5 must hold: `common::found_on_most_seeds`; release builds only, run by
//! `scripts/test`). What is checked holds whatever the truth: the top finding names the hidden effect (or the
//! variables it depends on), the noise verdict says "above" before and "at" after the loop,
//! and the final EMM is 0.97–1.05 × the noise error the generator records (the EMM of the noise
//! it drew). Plain data sets (no hidden effect, five seeds, both noises) get "nothing is
//! missing" and no candidate at all, generic or not.

mod common;

use volver::core::machine::Machine;
use volver::core::measure::MeasurementSet;
use volver::core::model::Model;
use volver::core::noise::TrackerNoise;
use volver::core::plan::Plan;
use volver::core::simulate::{Effect, Magnitudes, Simulation, Synthetic, Truth};
use volver::diagnosis::{Round, iterate};

/// Test 4 without its repeated turn (C 0–330°): 960 points, no pose measured twice.
const NO_REPEATS: &str = "X=0:1400:200,C=0:330:30,Z=0:600:150";

fn low_noise() -> TrackerNoise {
    TrackerNoise::from_text("normal:3,3,0.5,0.1").unwrap()
}

/// Data of the complete random truth of `seed` with `effects`, over `hours`.
fn simulate(noise: TrackerNoise, effects: &[&str], seed: u64, hours: f64) -> Synthetic {
    let m = Machine::default_xcfz();
    let truth = Truth::random_complete(&m, &Magnitudes::default(), seed).unwrap();
    let mut sim = Simulation::new(Plan::parse_grid(&m, NO_REPEATS).unwrap(), truth, seed);
    sim.noise = noise;
    sim.effects = effects.iter().map(|e| Effect::parse(e).unwrap()).collect();
    sim.duration_s = Some(hours * 3600.0);
    sim.run().unwrap()
}

/// The loop on the paper's model, every round printed.
fn run_loop(data: &MeasurementSet, noise: &TrackerNoise) -> Vec<Round> {
    let model = Model::default_xcfz();
    let (rounds, _) = iterate(&model, data, Some(noise), 5, |r| {
        let d = &r.diagnosis;
        let n = d.noise.as_ref().unwrap();
        println!(
            "  + {:?}: EMM {:.3} µm = {:.3} × the noise's {:.3} ± {:.3} µm; top {:?}; {}",
            r.added,
            d.emm_um,
            n.ratio,
            n.expected_fit_um,
            n.u95_um,
            d.candidates.first().map(|c| (&c.id, c.delta_bic, &c.flag)),
            d.verdict
        );
    })
    .unwrap();
    rounds
}

/// The hidden effect `effect` is found first as `want`, the noise verdict is "above" without
/// repeats, and the loop adds `want` and ends at the noise.
fn finds(effect: &str, noise: TrackerNoise, seed: u64, hours: f64, want: &str) {
    let sim = simulate(noise, &[effect], seed, hours);
    let noise_error = sim.record.noise_error.emm_um;
    println!("{effect} under {noise} (seed {seed}): noise error {noise_error:.3} µm");
    let rounds = run_loop(&sim.measurements, &noise);
    let first = &rounds[0].diagnosis;
    assert!(
        first.repeat_pairs.is_none(),
        "the plan has no repeated pose"
    );
    let verdict = first.noise.as_ref().unwrap();
    assert!(
        !verdict.at_noise && !verdict.below && verdict.ratio > 1.03,
        "{effect}: the first fit is above the noise ({})",
        verdict.ratio
    );
    let top = &first.candidates[0];
    assert!(
        top.id == want || top.equivalent.iter().any(|e| e == want),
        "{effect}: the top finding is {} (want {want})",
        top.id
    );
    assert!(top.flag.is_none() && top.delta_bic.unwrap() < -10.0);
    // The misfit exceeds the noise somewhere, and the verdict says what is missing.
    assert!(
        !verdict.above.is_empty(),
        "{effect}: no bin above the noise"
    );
    assert!(first.verdict.contains(want), "{}", first.verdict);
    if let Some((a, b)) = want.strip_prefix("field:").and_then(|v| v.split_once('*')) {
        let words = format!("depends jointly on {a} and {b}: a non-rigid effect");
        assert!(first.verdict.contains(&words), "{}", first.verdict);
    }
    let last = rounds.last().unwrap();
    assert_eq!(last.added.first().map(String::as_str), Some(want));
    let end = last.diagnosis.noise.as_ref().unwrap();
    assert!(end.at_noise, "{effect}: the loop ends at the noise");
    let ratio = last.diagnosis.emm_um / noise_error;
    println!("  final EMM / noise error = {ratio:.4}");
    assert!((0.97..=1.05).contains(&ratio), "{effect}: {ratio}");
}

/// A straightness of X along z that grows with the position of Z: no rigid-body error of
/// this chain makes a z displacement proportional to z, so it is non-rigid, and the top
/// finding is the generic field over X and Z.
#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "release only (scripts/test): 5 seeds per claim"
)]
fn a_non_rigid_coupling_is_named_by_its_two_variables() {
    on_most_seeds("coupling=X,Z,Z,30", low_noise(), 3, 8.0, "field:X*Z");
    on_most_seeds(
        "coupling=X,Z,Z,150",
        TrackerNoise::PAPER,
        11,
        8.0,
        "field:X*Z",
    );
}

/// The scale of X growing with time is found as the physical candidate, not as a field.
#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "release only (scripts/test): 5 seeds per claim"
)]
fn a_scale_growing_with_time_is_found_as_thermal_scale() {
    on_most_seeds("thermal-scale=X,30", low_noise(), 4, 8.0, "thermal-scale:X");
    on_most_seeds(
        "thermal-scale=X,40",
        TrackerNoise::PAPER,
        12,
        24.0,
        "thermal-scale:X",
    );
}

/// The line of C drifting with time is found as the physical candidate.
#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "release only (scripts/test): 5 seeds per claim"
)]
fn a_drifting_rotary_axis_line_is_found_as_location_drift() {
    on_most_seeds(
        "location-drift=C,15,-10",
        low_noise(),
        5,
        8.0,
        "location-drift:C",
    );
}

/// The tracker's stand turning as it warms is found as the tracker's drift.
#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "release only (scripts/test): 5 seeds per claim"
)]
fn a_turning_tracker_is_found_as_tracker_drift() {
    on_most_seeds("tracker-drift=2,-1,4", low_noise(), 6, 8.0, "tracker-drift");
}

/// [`finds`] on the seeds `first + 100 k`, k = 0 … 4, holding on at least 4 of them
/// (`common::found_on_most_seeds`).
fn on_most_seeds(effect: &str, noise: TrackerNoise, first: u64, hours: f64, want: &str) {
    common::found_on_most_seeds(&format!("{effect} under {noise}"), first, |seed| {
        finds(effect, noise, seed, hours, want);
    });
}

/// No hidden effect, five seeds, both noises: the verdict is "at the noise, nothing is
/// missing" and the loop adds nothing (no generic field fits the noise).
#[test]
fn plain_data_get_nothing_missing_and_no_field() {
    for noise in [low_noise(), TrackerNoise::PAPER] {
        for seed in 21..26 {
            let sim = simulate(noise, &[], seed, 8.0);
            println!("plain under {noise} (seed {seed})");
            let rounds = run_loop(&sim.measurements, &noise);
            assert_eq!(rounds.len(), 1, "seed {seed}: the loop added something");
            let d = &rounds[0].diagnosis;
            assert!(d.noise.as_ref().unwrap().at_noise, "seed {seed}");
            assert!(
                d.verdict.contains("nothing is missing"),
                "seed {seed}: {}",
                d.verdict
            );
            let ratio = d.emm_um / sim.record.noise_error.emm_um;
            assert!((0.97..=1.05).contains(&ratio), "seed {seed}: {ratio}");
            // No candidate at all: every physical candidate and every generic field was tried
            // (both kinds are listed) and none has the evidence the loop adds on (ΔBIC < −10),
            // whether or not the noise verdict would have stopped it first.
            assert!(
                d.candidates.iter().any(|c| c.id.starts_with("field:"))
                    && d.candidates.iter().any(|c| !c.id.starts_with("field:")),
                "seed {seed}: both kinds tried"
            );
            let strong: Vec<(&str, f64)> = d
                .candidates
                .iter()
                .filter_map(|c| Some((c.id.as_str(), c.delta_bic?)))
                .filter(|(_, b)| *b < -10.0)
                .collect();
            assert!(strong.is_empty(), "seed {seed}: {strong:?}");
            assert!(d.finding().is_none(), "seed {seed}");
        }
    }
}

/// With repeats, the repeated points and the specification are both shown; a specification
/// that understates the tracker's noise fourfold is reported as disagreeing with them, and
/// the fit as far above it. The mesh is measured twice in a row: a point and its second
/// reading are repeats when every axis arrived from the same side both times (all but the
/// first pass' points at X's first position, where X had not moved yet).
#[test]
fn repeats_are_checked_against_the_specification() {
    let m = Machine::default_xcfz();
    let truth = Truth::random_complete(&m, &Magnitudes::default(), 8).unwrap();
    let mut plan = Plan::parse_grid(&m, "X=0:1400:400,C=0:330:30,Z=0:600:150").unwrap();
    let again = plan.positions.clone();
    plan.positions.extend(again);
    let mut sim = Simulation::new(plan, truth, 8);
    sim.noise = low_noise();
    let data = sim.run().unwrap().measurements;
    let model = Model::default_xcfz();
    let d = volver::diagnosis::diagnose_with(&model, &data, Some(&low_noise())).unwrap();
    let r = d.noise.as_ref().unwrap().repeats.as_ref().unwrap();
    println!("{r:?}");
    let (pts, n) = (&data.points, data.points.len() / 2);
    let same_sides = (0..n)
        .filter(|&i| pts[i].approach == pts[i + n].approach)
        .count();
    assert_eq!(r.pairs, same_sides);
    // Five positions of X (0, 400, 800, 1200, 1400).
    assert_eq!(r.pairs, n - n / 5, "{} pairs of {n} points", r.pairs);
    assert!(r.agree, "{r:?}");
    let understated = TrackerNoise::from_text("normal:0.75,0.75,0.125,0.025").unwrap();
    let d = volver::diagnosis::diagnose_with(&model, &data, Some(&understated)).unwrap();
    let n = d.noise.as_ref().unwrap();
    assert!(!n.repeats.as_ref().unwrap().agree && !n.at_noise && n.ratio > 3.0);
}

/// `diagnose --iterate` through the CLI: the rounds are printed, the field is added, and the
/// history file gets one record per round.
#[test]
fn diagnose_iterate_prints_every_round_and_writes_the_history() {
    let dir = std::env::temp_dir().join(format!("volver-iterate-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let d = dir.to_str().unwrap();
    common::simulate(
        d,
        &[
            "--plan",
            NO_REPEATS,
            "--seed",
            "3",
            "--noise",
            "normal:3,3,0.5,0.1",
            "--effect",
            "coupling=X,Z,Z,30",
            "--duration-h",
            "8",
        ],
    );
    // The machine file the simulation wrote states the tracker's noise.
    let machine = std::fs::read_to_string(dir.join("machine.toml")).unwrap();
    assert!(
        machine.contains("noise = \"normal:3,3,0.5,0.1\""),
        "{machine}"
    );
    let data = dir.join("measurements.csv");
    let history = dir.join("h.jsonl");
    let (final_model, final_fit) = (dir.join("final.toml"), dir.join("final.json"));
    let out = common::volver(&[
        "diagnose",
        "--data",
        data.to_str().unwrap(),
        "--noise",
        "normal:3,3,0.5,0.1",
        "--iterate",
        "--history",
        history.to_str().unwrap(),
        "--write-model",
        final_model.to_str().unwrap(),
        "--out",
        final_fit.to_str().unwrap(),
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    println!("{text}");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains("round 1:") && text.contains("→ add field:X*Z"),
        "{text}"
    );
    assert!(text.contains("round 2:") && text.contains("→ stop: the fit is at the noise"));
    let lines = std::fs::read_to_string(&history).unwrap();
    let records: Vec<serde_json::Value> = lines
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(records.len(), 2);
    // With no addition allowed, the loop says what it would add and stops.
    let out = common::volver(&[
        "diagnose",
        "--data",
        data.to_str().unwrap(),
        "--noise",
        "normal:3,3,0.5,0.1",
        "--iterate",
        "--max-added",
        "0",
        "--no-history",
    ]);
    let capped = String::from_utf8_lossy(&out.stdout);
    assert!(
        capped.contains("→ stop: --max-added reached; the loop would add field:X*Z next"),
        "{capped}"
    );
    assert_eq!(records[1]["added"][0], "field:X*Z");
    assert!(records[1]["emm_final_um"].as_f64() < records[0]["emm_final_um"].as_f64());
    final_model_reloads(&dir, &records[1]);
    let _ = std::fs::remove_dir_all(&dir);
}

/// `diagnose --iterate --write-model final.toml --out final.json` left the loop's final model
/// and its fit (issue 44): `identify --model final.toml` fits it to the final round's EMM
/// (1e-9 relative) and writes the same results file (parameters equal to 1e-12 mm or rad).
fn final_model_reloads(dir: &std::path::Path, last: &serde_json::Value) {
    let text = std::fs::read_to_string(dir.join("final.toml")).unwrap();
    assert!(text.contains("X*Z"), "{text}");
    let again = dir.join("again.json");
    let out = common::volver(&[
        "identify",
        "--data",
        dir.join("measurements.csv").to_str().unwrap(),
        "--model",
        dir.join("final.toml").to_str().unwrap(),
        "--no-history",
        "--json",
        "--out",
        again.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let (emm, want) = (
        report["emm_final_um"].as_f64().unwrap(),
        last["emm_final_um"].as_f64().unwrap(),
    );
    println!("identify --model final.toml: EMM {emm} µm, the loop's final round {want} µm");
    assert!((emm / want - 1.0).abs() < 1e-9, "{emm} vs {want}");
    let read = |p: &std::path::Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
    };
    let (written, refit) = (read(&dir.join("final.json")), read(&again));
    assert_eq!(written["error_model"], refit["error_model"]);
    let values = |v: &serde_json::Value| -> Vec<f64> {
        let mut out = Vec::new();
        collect_numbers(&v["parameters"], &mut out);
        out
    };
    let (a, b) = (values(&written), values(&refit));
    assert!(!a.is_empty() && a.len() == b.len());
    for (x, y) in a.iter().zip(&b) {
        assert!((x - y).abs() <= 1e-12, "{x} vs {y}");
    }
}

/// Every number in a JSON value, in order.
fn collect_numbers(v: &serde_json::Value, out: &mut Vec<f64>) {
    match v {
        serde_json::Value::Number(n) => out.extend(n.as_f64()),
        serde_json::Value::Array(a) => a.iter().for_each(|x| collect_numbers(x, out)),
        serde_json::Value::Object(o) => o.values().for_each(|x| collect_numbers(x, out)),
        _ => {}
    }
}

/// Plausibility, for any truth: every size listed is within its kind's physical bound unless
/// the candidate is flagged, and a flagged candidate is never first. A tracker whose range
/// scale is beyond any tracker's (5 000 ppm against a bound of 1 000) gets its candidate
/// flagged with the reason.
#[test]
fn implausible_candidates_are_marked_and_never_first() {
    let model = Model::default_xcfz();
    let bound = |unit: &str| match unit {
        "ppm/h" => 100.0,
        _ => 1000.0, // µm, µrad, µm/h, ppm
    };
    for (effects, seed) in [(vec![], 31), (vec!["range-scale=5000"], 32)] {
        let sim = simulate(low_noise(), &effects, seed, 8.0);
        let d = volver::diagnosis::diagnose_with(&model, &sim.measurements, Some(&low_noise()))
            .unwrap();
        for c in &d.candidates {
            println!(
                "  {:<20} ΔBIC {:?} size {:?} {} {:?}",
                c.id, c.delta_bic, c.size, c.size_unit, c.flag
            );
            if let (Some(size), None) = (c.size, &c.flag) {
                assert!(
                    size <= bound(c.size_unit),
                    "{}: {size} {}",
                    c.id,
                    c.size_unit
                );
            }
        }
        assert!(
            d.candidates[0].flag.is_none(),
            "a flagged candidate is first"
        );
        if !effects.is_empty() {
            let range = d.candidates.iter().find(|c| c.id == "range-scale").unwrap();
            let why = range.flag.as_deref().expect("the range scale is flagged");
            assert!(why.contains("plausible 1000 ppm"), "{why}");
            assert!(!d.verdict.starts_with("add range-scale"), "{}", d.verdict);
        }
    }
}

/// Issue 44: a non-rigid coupling of a few hundred µm under low noise. The generic field over
/// its two variables has by far the best evidence, and its size — measured on what it adds
/// beyond the rigid-body model, not on its raw coefficients (which carry metres traded against
/// the angular errors of X and the lever arm of Z) — is plausible: it is ranked first, the
/// verdict recommends it with the physical candidates over X and Z beside it, and adding it
/// brings the fit to within 1.12 × what the tracker's noise leaves. Two couplings (EXX and EZX
/// of X growing with Z), two seeds each; every case must hold.
#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "release only (scripts/test): four diagnoses with refits"
)]
fn a_non_rigid_coupling_is_sized_on_what_is_new_and_brings_the_fit_to_the_noise() {
    let noise = TrackerNoise::from_text("normal:3,3,1,0.2").unwrap();
    let model = Model::default_xcfz();
    for effect in ["coupling=X,X,Z,300", "coupling=X,Z,Z,300"] {
        for seed in [3, 4] {
            let sim = simulate(noise, &[effect], seed, 8.0);
            let d =
                volver::diagnosis::diagnose_with(&model, &sim.measurements, Some(&noise)).unwrap();
            let top = &d.candidates[0];
            println!(
                "{effect}, seed {seed}: EMM {:.3} µm; top {} ΔBIC {:.0}, size {:.1} {}, EMM \
                 after {:.3}; physical {:?}\n  {}",
                d.emm_um,
                top.id,
                top.delta_bic.unwrap(),
                top.size.unwrap(),
                top.size_unit,
                top.emm_um.unwrap(),
                top.physical,
                d.verdict
            );
            assert_eq!(top.id, "field:X*Z", "{effect}, seed {seed}");
            assert!(top.flag.is_none() && top.delta_bic.unwrap() < -10.0);
            assert!(top.size.unwrap() < 1000.0 && top.size_unit == "µm");
            assert_eq!(d.finding().map(|c| c.id.as_str()), Some("field:X*Z"));
            assert!(d.verdict.contains("--add field:X*Z"), "{}", d.verdict);
            assert!(
                d.verdict
                    .contains("the physical candidates over X and Z are"),
                "{}",
                d.verdict
            );
            assert!(!top.physical.is_empty());
            let with = volver::inputs::with_candidates(
                model.machine(),
                model.clone(),
                &["field:X*Z".to_string()],
            )
            .unwrap();
            let after =
                volver::diagnosis::diagnose_with(&with, &sim.measurements, Some(&noise)).unwrap();
            let ratio = after.noise.as_ref().unwrap().ratio;
            println!(
                "  with field:X*Z: EMM {:.3} µm = {ratio:.3} × what the noise leaves",
                after.emm_um
            );
            assert!(ratio <= 1.12, "{effect}, seed {seed}: {ratio}");
            assert!(after.emm_um < d.emm_um);
        }
    }
}
