//! The whole path of a library user: load a machine and its error model, identify them from
//! measurements with the engine the build's Cargo features chose, diagnose the fit, add the
//! candidate the diagnosis ranks first, identify again, and write the HTML report and the
//! results file.
//!
//! ```text
//! cargo run --example whole_path                      # the native LM
//! cargo run --example whole_path --features ceres     # Ceres, when built with it
//! cargo run --example whole_path -- my-machine.toml my-model.toml data.csv
//! ```
//!
//! Without arguments it runs on the demo's synthetic test 4 of the XCFZ grinder, which hides a
//! second harmonic of the turntable C that the paper's model lacks.

use std::path::PathBuf;
use volver::core::model::Model;
use volver::core::results::ResultsFile;
use volver::core::simulate::{Effect, Magnitudes, Simulation, Truth};
use volver::identification::{Settings, identify};
use volver::report::{Fit, ReportInput};
use volver::{Error, Result};

/// The engine this build offers beyond the native LM, by Cargo feature.
fn engine_of_this_build() -> &'static str {
    if cfg!(feature = "ceres") {
        "ceres"
    } else {
        "lm"
    }
}

fn main() -> Result<()> {
    let args: Vec<PathBuf> = std::env::args_os().skip(1).map(PathBuf::from).collect();
    // 1. The machine, the error model and the measurements.
    let (machine, model, data, label) = match &args[..] {
        [machine, model, path] => {
            let (m, model, data) = volver::inputs::load(Some(machine), Some(model), path)?;
            (m, model, data, path.display().to_string())
        }
        [] => {
            let model = Model::default_xcfz();
            let m = model.machine().clone();
            let truth = Truth::random(&m, model.spec(), &Magnitudes::default(), 7)?;
            let mut sim = Simulation::new(volver::core::plan::Plan::preset(&m, "test4")?, truth, 7);
            sim.effects = vec![Effect::parse(volver::inputs::DEMO_EFFECT)?];
            let data = sim.run()?.measurements;
            (m, model, data, "synthetic test 4".to_string())
        }
        _ => {
            return Err(Error::Request(
                "give MACHINE.toml MODEL.toml DATA.csv, or nothing for the demo's data".into(),
            ));
        }
    };
    // 2. Identification with the build's engine.
    let mut settings = Settings::default();
    settings.engine = engine_of_this_build().to_string();
    let first = identify(&model, &data, &settings, &mut volver::solvers::Silent)?;
    println!(
        "{} on {} points with {}: EMM {:.2} → {:.2} µm ({})",
        model.spec().name,
        data.points.len(),
        first.engine,
        first.id.initial.stats.emm_um,
        first.id.reached.stats.emm_um,
        first.id.termination
    );
    // 3. Diagnosis: where the fit fails and what it most likely misses.
    let diagnosis = volver::diagnosis::diagnose(&model, &data)?;
    println!("verdict: {}", diagnosis.verdict);
    let top = diagnosis
        .candidates
        .first()
        .ok_or_else(|| Error::NotSolved("the diagnosis ranks no candidate".into()))?;
    // 4. The model with the top candidate, identified again.
    let extended =
        volver::inputs::with_candidates(&machine, model.clone(), std::slice::from_ref(&top.id))?;
    let second = identify(&extended, &data, &settings, &mut volver::solvers::Silent)?;
    println!(
        "with {}: {} parameters, EMM {:.2} µm",
        top.id,
        extended.n_params(),
        second.id.reached.stats.emm_um
    );
    // 5. The report and the results file (what `volver compensate` and `tables` read).
    let out = std::env::temp_dir().join("volver-whole-path");
    std::fs::create_dir_all(&out)?;
    let fits = vec![
        Fit {
            label: model.spec().name.clone(),
            model: &model,
            id: &first.id,
        },
        Fit {
            label: format!("+ {}", top.id),
            model: &extended,
            id: &second.id,
        },
    ];
    let mut input = ReportInput::new(format!("volver — {label}"), label.clone(), &data, fits);
    input.candidates = volver::solvers::candidates::rank(
        &volver::core::problem::Problem::new(&model, &data)?,
        &first.id.params,
        volver::solvers::identifiability::RANK_TOLERANCE,
        model.machine().default_noise().as_ref(),
    );
    let html = volver::report::html(&input)?;
    volver::core::fsio::write_atomic(&out.join("report.html"), html)?;
    second.results.save(&out.join("fit.json"))?;
    let back = ResultsFile::load(&out.join("fit.json"))?;
    println!(
        "report and {} identified values written to {}",
        back.parameters.len(),
        out.display()
    );
    Ok(())
}
