//! A fit and its diagnosis do not depend on the origin or the unit of the time stamps (issue
//! 44, item 7). One simulated test with a thermal drift, its `t_s` then given as an epoch time
//! (+1.7e9 s), in microseconds (× 1e6) and in hours (÷ 3600): the model with the drift gives the
//! same EMM (to 1e-9 relative), holds the same number of combinations and finds the same drift
//! (its rate scaled by the unit, to 1e-6 relative); the model without it ranks the same
//! candidate first. The stamps go through [`MeasurementSet::from_file_times`], as a file's do
//! (times counted from the earliest), and the gauge's metric weighs a rate over the test's span.
//!
//! Release only (`scripts/test`): four fits and four diagnoses of test 4.

use volver::core::machine::Machine;
use volver::core::measure::MeasurementSet;
use volver::core::model::{ErrorModelSpec, Model};
use volver::core::noise::{Distribution, TrackerNoise};
use volver::core::plan::Plan;
use volver::core::problem::Problem;
use volver::core::simulate::{Effect, Magnitudes, Simulation, Synthetic, Truth};
use volver::solvers::candidates::rank;
use volver::solvers::identifiability::RANK_TOLERANCE;
use volver::solvers::strategy::fit;

/// Test 4 of the XCFZ grinder measured in a shuffled order (so that time is no axis), under a
/// low noise, with a thermal drift of (10, −5, 60) µm/h; seed 5.
fn drifting_test() -> Synthetic {
    let m = Machine::default_xcfz();
    let mut plan = Plan::preset(&m, "test4").unwrap();
    let mut rng = volver::core::random::Rng::new(9);
    for i in (1..plan.positions.len()).rev() {
        let j = (rng.uniform() * (i + 1) as f64) as usize;
        plan.positions.swap(i, j);
    }
    let truth = Truth::random_complete(&m, &Magnitudes::default(), 5).unwrap();
    let mut sim = Simulation::new(plan, truth, 5);
    sim.noise = TrackerNoise {
        distribution: Distribution::Normal,
        azimuth_urad: 3.0,
        elevation_urad: 3.0,
        range_um: 0.5,
        range_um_per_m: 0.1,
    };
    sim.effects = vec![Effect::parse("thermal-drift=10,-5,60").unwrap()];
    sim.run().unwrap()
}

/// The measurements with every stamp `t` given as `f(t)`, read as a file's stamps are.
fn restamped(data: &MeasurementSet, f: impl Fn(f64) -> f64) -> MeasurementSet {
    let mut points = data.points.clone();
    for p in &mut points {
        p.t_s = p.t_s.map(&f);
    }
    MeasurementSet::from_file_times(points)
}

/// What must not change: the final EMM (µm), the combinations held, the drift's x and z rates
/// (in the stamps' unit per hour of them read as seconds), and the top candidate of the
/// diagnosis without the drift.
struct Answer {
    emm_um: f64,
    held: usize,
    drift: [f64; 2],
    top: String,
    /// The first eight candidates: id, ΔBIC, flagged.
    ranking: Vec<(String, f64, bool)>,
}

fn answer(data: &MeasurementSet) -> Answer {
    let paper = Model::default_xcfz();
    let mut spec: ErrorModelSpec = paper.spec().clone();
    spec.effects.thermal_drift = true;
    let drifting = Model::new(paper.machine().clone(), spec).unwrap();
    let id = fit(Problem::new(&drifting, data).unwrap());
    assert!(!id.termination.failed(), "{:?}", id.termination);
    let rate = |name: &str| id.params[drifting.param_index(name).unwrap()];
    let problem = Problem::new(&paper, data).unwrap();
    let before = fit(problem.clone());
    let ranked = rank(&problem, &before.params, RANK_TOLERANCE, None);
    Answer {
        emm_um: id.reached.stats.emm_um,
        held: id.gauge.as_ref().map_or(usize::MAX, |g| g.held.len()),
        drift: [rate("drift.x"), rate("drift.z")],
        top: ranked[0].id.clone(),
        ranking: ranked
            .iter()
            .take(8)
            .map(|c| (c.id.clone(), c.delta_bic, c.flag.is_some()))
            .collect(),
    }
}

/// A clock: its name, a stamp in it from seconds, and how a rate per its unit compares with
/// one per second.
type Clock = (&'static str, fn(f64) -> f64, f64);

#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "release only (scripts/test): four fits and diagnoses of test 4"
)]
fn the_fit_and_the_diagnosis_do_not_depend_on_the_clock() {
    let sim = drifting_test();
    let base = answer(&sim.measurements);
    println!(
        "seconds: EMM {:.9} µm, {} held, drift x {:.6e} z {:.6e} mm/h, top {}",
        base.emm_um, base.held, base.drift[0], base.drift[1], base.top
    );
    assert_eq!(
        base.top, "thermal-drift",
        "the hidden drift is found at all"
    );
    assert!(
        (base.drift[1] - 0.060).abs() < 0.005,
        "the drift's z rate is found: {} mm/h",
        base.drift[1]
    );
    let clocks: [Clock; 3] = [
        ("epoch", |t| t + 1.7e9, 1.0),
        ("µs", |t| t * 1e6, 1e-6),
        ("hours", |t| t / 3600.0, 3600.0),
    ];
    for (name, stamp, rate_scale) in clocks {
        let data = restamped(&sim.measurements, stamp);
        let a = answer(&data);
        let rel = (a.emm_um - base.emm_um).abs() / base.emm_um;
        println!(
            "{name}: EMM {:.9} µm ({rel:.1e} relative), {} held, drift x {:.6e} z {:.6e}, top {}",
            a.emm_um, a.held, a.drift[0], a.drift[1], a.top
        );
        assert!(
            rel <= 1e-9,
            "{name}: EMM {} against {}",
            a.emm_um,
            base.emm_um
        );
        assert_eq!(a.held, base.held, "{name}: combinations held");
        for (c, (&got, &want)) in a.drift.iter().zip(&base.drift).enumerate() {
            let scaled = got / rate_scale;
            assert!(
                (scaled - want).abs() <= 1e-6 * want.abs(),
                "{name}: drift component {c}: {scaled} against {want} mm/h"
            );
        }
        assert_eq!(a.top, base.top, "{name}: the diagnosis' first candidate");
        // The whole head of the ranking, fields over time included (their plausible size and
        // their columns' scaling once depended on the unit): the same candidates in the same
        // order, ΔBIC to 1e-6 relative, the same flags.
        for (k, (got, want)) in a.ranking.iter().zip(&base.ranking).enumerate() {
            assert!(
                got.0 == want.0
                    && (got.1 - want.1).abs() <= 1e-6 * want.1.abs().max(1.0)
                    && got.2 == want.2,
                "{name}: candidate {k}: {got:?} against {want:?}"
            );
        }
    }
}
