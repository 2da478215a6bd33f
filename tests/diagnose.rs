//! Where a model fails: breakdowns, periodograms and the noise from repeated points find what
//! the generator hid.

use volver::core::diagnose::{
    axis_periodogram, by_axis, by_reflector, by_time, largest, repeat_noise, to_machine_frame,
};
use volver::core::machine::Machine;
use volver::core::noise::TrackerNoise;
use volver::core::plan::Plan;
use volver::core::problem::Problem;
use volver::core::simulate::{Effect, Magnitudes, Simulation, Synthetic, Truth};
use volver_core::problem::Residuals;

fn truth(seed: u64) -> Truth {
    let m = Machine::default_xcfz();
    Truth::random_complete(&m, &Magnitudes::default(), seed).unwrap()
}

fn run(plan: Plan, t: Truth, noise: TrackerNoise, effects: Vec<Effect>) -> Synthetic {
    let mut sim = Simulation::new(plan, t, 5);
    sim.noise = noise;
    sim.effects = effects;
    sim.run().unwrap()
}

#[test]
fn the_periodogram_finds_hidden_rotary_harmonics() {
    let m = Machine::default_xcfz();
    let t = truth(1);
    let plan = Plan::preset(&m, "table4").unwrap();
    let out = run(
        plan,
        t.clone(),
        TrackerNoise::NONE,
        vec![Effect::RotaryHarmonics {
            max_order: 3,
            translation_um: 20.0,
            rotation_urad: 0.0,
        }],
    );
    // Residuals against the truth without the harmonics are the harmonics alone.
    let problem = Problem::new(&t.model, &out.measurements).unwrap();
    let r = to_machine_frame(&problem, &t.params, &problem.residuals(&t.params));
    let (k, _) = m.axis(volver::core::iso::Axis::C).unwrap();
    let lines = axis_periodogram(&problem, &r, k, 6);
    for l in &lines {
        println!("order {}: {:?} µm", l.frequency, l.amplitude_um);
    }
    // In the machine frame, orders 2 and 3 carry the 20 µm of EXC, EYC, EZC; orders 1, 4, 5,
    // 6 nothing. (In the tracker frame, which turns with the table, x and y would show h ± 1.)
    for l in &lines {
        let order = l.frequency as usize;
        if order == 2 || order == 3 {
            assert!(l.total_um() > 15.0, "order {order}: {}", l.total_um());
        } else {
            // Leakage only: C = 360° repeats C = 0°, so the 73 samples are not exactly
            // orthogonal for single-frequency fits (≈ 20 µm / 73 per line).
            assert!(l.total_um() < 1.0, "order {order}: {}", l.total_um());
        }
    }
}

#[test]
fn drift_shows_in_the_time_breakdown_and_not_by_reflector() {
    let m = Machine::default_xcfz();
    let t = truth(2);
    let out = run(
        Plan::preset(&m, "test4").unwrap(),
        t.clone(),
        TrackerNoise::NONE,
        vec![Effect::ThermalDrift {
            rate_um_per_h: [0.0, 0.0, 20.0],
        }],
    );
    let problem = Problem::new(&t.model, &out.measurements).unwrap();
    let r = problem.residuals(&t.params);
    let time = by_time(&problem, &r, 6).unwrap();
    // EMM grows with time: 20 µm/h over 2.9 h, bin means ≈ rate × bin centre.
    for w in time.bins.windows(2) {
        assert!(w[1].stats.emm_um > w[0].stats.emm_um);
    }
    let last = time.bins.last().unwrap();
    let centre_h = 0.5 * (last.from + last.to) / 3600.0;
    // Residual = predicted − measured: the model misses the drift, so it shows negative.
    assert!(
        (last.mean_um[2] + 20.0 * centre_h).abs() < 2.5,
        "{:?}",
        last.mean_um
    );
    let refl = by_reflector(&problem, &r);
    assert_eq!(refl.bins.len(), 2);
    assert!(
        refl.spread() < 1.1,
        "reflectors see the drift alike: {}",
        refl.spread()
    );
    // Mesh positions make one bin per distinct X.
    assert_eq!(by_axis(&problem, &r, 0, 20).bins.len(), 8);
    assert_eq!(largest(&r, 3).len(), 3);
}

#[test]
fn repeated_points_estimate_the_noise_error() {
    let m = Machine::default_xcfz();
    let t = truth(3);
    let mut plan = Plan::preset(&m, "test3").unwrap();
    let again = plan.positions.clone();
    plan.positions.extend(again); // the whole mesh measured twice
    let out = run(plan, t, TrackerNoise::PAPER, vec![]);
    let problem = Problem::new(&out.truth.model, &out.measurements).unwrap();
    let (est, pairs) = repeat_noise(&problem).unwrap();
    // Each point and its reading in the second pass are repeats when every axis arrived from the
    // same side both times: all but the first pass' points at X's first position (X, the
    // slowest axis, had not moved yet: their direction is assumed, and assumed directions
    // repeat nothing). C = 0° and 360° are reached from opposite sides of C (0° after the turn
    // back): not repeats.
    let pts = &out.measurements.points;
    let n = pts.len() / 2;
    // Six positions of X (0, 300 … 1200, 1400).
    assert_eq!(pairs, n - n / 6, "{pairs} pairs of {n} points");
    let ratio = est.emm_um / out.record.noise_error.emm_um;
    println!(
        "repeat estimate {} µm vs noise error {} µm",
        est.emm_um, out.record.noise_error.emm_um
    );
    assert!((ratio - 1.0).abs() < 0.1, "ratio {ratio}");
}

/// No silent drop: a candidate that cannot be scored is listed with the reason; when the
/// current model's own step fails (here: a solution that is not a number), every candidate
/// says so and the verdict says that none could be scored — not that none lowers the error.
#[test]
fn candidates_that_cannot_be_scored_are_reported() {
    use volver::core::model::Model;
    use volver::solvers::candidates::{offered, rank, verdict};
    let model = Model::default_xcfz();
    let m = model.machine();
    let plan = Plan::parse_grid(m, "X=0:1400:350,C=0:330:30,Z=0:600:150").unwrap();
    let data = run(plan, truth(2), TrackerNoise::PAPER, vec![]).measurements;
    let problem = Problem::new(&model, &data).unwrap();
    let nan = vec![f64::NAN; model.n_params()];
    let tolerance = volver::solvers::identifiability::RANK_TOLERANCE;
    let ranked = rank(&problem, &nan, tolerance, None);
    // Every candidate the data can identify at all (not X's reversal: X only moves forward).
    assert_eq!(
        ranked.len(),
        offered(&model, &data).len(),
        "every candidate listed"
    );
    assert!(ranked.iter().all(|s| s.failed.is_some()));
    let v = verdict(&ranked, 50.0);
    assert!(v.starts_with("no candidate could be scored"), "{v}");
    assert!(!v.contains("lowers the error"), "{v}");
    // At a real solution every candidate is scored.
    let id = volver::solvers::strategy::fit(problem.clone());
    let ranked = rank(&problem, &id.params, tolerance, None);
    assert!(ranked.iter().all(|s| s.failed.is_none()));
}

/// No silent fallback: a `simulation.json` beside the truth and the measurements that cannot be
/// read is an error naming it (it was ignored, and the noise error silently computed another
/// way).
#[test]
fn a_corrupt_simulation_record_is_an_error() {
    let dir = std::env::temp_dir().join(format!("volver-corrupt-record-{}", std::process::id()));
    let d = dir.display().to_string();
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_volver"))
        .args([
            "simulate",
            "--plan",
            "X=0:1400:350,C=0:330:30,Z=0:600:150",
            "--out",
            &d,
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let identify = || {
        std::process::Command::new(env!("CARGO_BIN_EXE_volver"))
            .args(["identify", "--data", &format!("{d}/measurements.csv")])
            .args(["--truth", &format!("{d}/truth.json")])
            .output()
            .unwrap()
    };
    assert!(identify().status.success());
    std::fs::write(dir.join("simulation.json"), "{\"points\": 12, \"torn").unwrap();
    let o = identify();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("simulation.json"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}
