//! Identifiability: the analysis finds the parameters the data cannot separate, and its
//! standard uncertainties match the actual scatter of identified parameters.

use volver::core::machine::Machine;
use volver::core::model::{ErrorModelSpec, Model};
use volver::core::noise::TrackerNoise;
use volver::core::plan::Plan;
use volver::core::problem::Problem;
use volver::core::simulate::{Magnitudes, Simulation, Truth};
use volver::solvers::Task;
use volver::solvers::identifiability::analyse;
use volver::solvers::strategy::fit;

#[test]
fn the_papers_model_on_test_4_has_inseparable_parameters_named() {
    let m = Machine::default_xcfz();
    let truth = Truth::random_complete(&m, &Magnitudes::default(), 7).unwrap();
    let mut sim = Simulation::new(Plan::preset(&m, "test4").unwrap(), truth, 7);
    sim.noise = TrackerNoise::PAPER;
    let data = sim.run().unwrap().measurements;
    let model = Model::default_xcfz();
    let problem = Problem::new(&model, &data).unwrap();
    let id = fit(problem.clone());
    let a = analyse(&Task::new(problem), &id.params, 1e-10, 0.99).unwrap();
    println!(
        "free {} rank {} condition {:.3e} (all {:.3e}) σ {:.4} mm",
        a.free, a.rank, a.condition, a.condition_all, a.sigma_mm
    );
    for w in &a.weak {
        let names: Vec<String> = w
            .parameters
            .iter()
            .map(|(j, x)| format!("{} {x:+.2}", model.params()[*j].name))
            .collect();
        println!("  weak {:.1e}: {}", w.relative_curvature, names.join(", "));
    }
    for (i, j, c) in a.correlations.iter().take(5) {
        println!(
            "  corr {} {} {c:.4}",
            model.params()[*i].name,
            model.params()[*j].name
        );
    }
    assert_eq!(a.free, 57);
    assert!(a.rank < a.free && !a.weak.is_empty());
    assert!(
        a.condition <= 1e5 * 1.001,
        "kept directions within the tolerance: {}",
        a.condition
    );
    // σ per coordinate matches the noise: EMM of a 3-D normal ≈ 1.6 σ for this anisotropy.
    assert!(a.sigma_mm > 0.02 && a.sigma_mm < 0.06, "σ {}", a.sigma_mm);
}

#[test]
fn standard_uncertainties_match_the_scatter_of_identified_parameters() {
    // An identifiable problem: the linear axes on the table-7 mesh, the truth in the fitted
    // structure, the squareness split as in the truth (ISO 230-1), so parameters compare.
    let m = Machine::default_xcfz();
    let text = r#"
        squareness = "separate"
        [[error]]
        name = ["EXX", "EYX", "EZX", "EAX", "EBX", "ECX", "EXZ", "EYZ", "EZZ", "EAZ", "EBZ", "ECZ"]
        basis = "legendre"
        degree = 2
        [[error]]
        name = ["A0Z", "B0Z"]
        [tracker]
        identify = ["x", "y", "z"]
    "#;
    let spec = ErrorModelSpec::from_toml_str(text, "inline").unwrap();
    let model = Model::new(m.clone(), spec.clone()).unwrap();
    let (mut sum_z2, mut count) = (0.0, 0usize);
    for seed in 0..8 {
        let truth = Truth::random(&m, &spec, &Magnitudes::default(), seed).unwrap();
        let mut sim = Simulation::new(Plan::preset(&m, "table7").unwrap(), truth.clone(), seed);
        sim.noise = TrackerNoise::PAPER;
        let data = sim.run().unwrap().measurements;
        let problem = Problem::new(&model, &data).unwrap();
        let id = fit(problem.clone());
        let a = analyse(&Task::new(problem), &id.params, 1e-10, 0.999).unwrap();
        // The problem is identifiable in exact arithmetic, but a direction may fall below the
        // rank tolerance on a draw (ECZ against B0Z, two on seed 1): the parameters it moves get
        // no variance from it, so they are left out of the z-scores.
        assert!(
            a.rank + 2 >= a.free,
            "seed {seed}: {} of {} identified",
            a.rank,
            a.free
        );
        // Parameters the gauge's held combinations move are not determined either: their
        // values carry the reference's component along those combinations, not the truth's.
        let weak: Vec<usize> = a
            .weak
            .iter()
            .flat_map(|w| w.parameters.iter().map(|p| p.0))
            .chain(
                id.gauge
                    .iter()
                    .flat_map(|g| g.held.iter())
                    .flat_map(|h| h.parameters.iter().map(|p| p.0)),
            )
            .collect();
        for (j, info) in model.params().iter().enumerate() {
            let k = truth.model.param_index(&info.name).unwrap();
            if a.uncertainty[j] > 0.0 && !info.name.starts_with("tracker") && !weak.contains(&j) {
                let z = (id.params[j] - truth.params[k]) / a.uncertainty[j];
                sum_z2 += z * z;
                count += 1;
            }
        }
    }
    let rms = (sum_z2 / count as f64).sqrt();
    println!("RMS z-score over {count} parameter estimates: {rms:.3}");
    // Φ is not least squares, so its scatter is a little wider than the ve-based σ.
    assert!((0.7..1.5).contains(&rms), "RMS z {rms}");
}
