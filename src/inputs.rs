//! Reading what a fit needs: the machine, the error model and the measurements (the embedded
//! XCFZ grinder and the paper's model when no file is given), a model extended by candidates of
//! the diagnosis, and the demo's synthetic data.

use anyhow::{Context, Result, bail};
use std::path::Path;
use volver_core::machine::Machine;
use volver_core::measure::MeasurementSet;
use volver_core::model::Model;
use volver_core::plan::Plan;
use volver_core::problem::Problem;
use volver_core::simulate::{Magnitudes, Simulation, Synthetic, Truth};

/// Seed of the demo's synthetic test.
pub const DEMO_SEED: u64 = 7;

/// The effect hidden in the demo's data: a second harmonic in every error of the turntable C
/// (10 µm, 20 µrad), which the paper's model (first harmonics) cannot describe.
pub const DEMO_EFFECT: &str = "rotary-harmonics=2,10,20";

/// Where the demo writes its files.
pub const DEMO_DIR: &str = "volver-demo";

/// The machine of `machine` (TOML) and the error model of `model` (TOML): the embedded XCFZ
/// grinder and the paper's model when absent. A model file needs its machine: the embedded
/// model is for the embedded machine.
///
/// ```
/// let (machine, model) = volver::inputs::machine_and_model(None, None).unwrap();
/// assert_eq!(machine.chain().to_string(), "XCFZ");
/// assert_eq!(model.n_params(), 74);
/// ```
pub fn machine_and_model(machine: Option<&Path>, model: Option<&Path>) -> Result<(Machine, Model)> {
    let m = match machine {
        Some(p) => Machine::load(p).context("reading the machine file")?,
        None => Machine::default_xcfz(),
    };
    let model = match (model, machine) {
        (Some(p), _) => Model::load(m.clone(), p).context("reading the error model")?,
        (None, None) => Model::default_xcfz(),
        (None, Some(_)) => bail!(
            "--model is needed with --machine (the embedded model is for the embedded machine)"
        ),
    };
    Ok((m, model))
}

/// [`machine_and_model`] and the measurements of `data` (CSV), whose scale is checked against
/// the machine (a file in metres or inches is refused with the reason).
pub fn load(
    machine: Option<&Path>,
    model: Option<&Path>,
    data: &Path,
) -> Result<(Machine, Model, MeasurementSet)> {
    load_with(machine, model, data, None)
}

/// [`load`], the measurements read through the import profile `import` when given
/// ([`volver_core::import::Profile`]: a tracker software's export as it is written).
pub fn load_with(
    machine: Option<&Path>,
    model: Option<&Path>,
    data: &Path,
    import: Option<&Path>,
) -> Result<(Machine, Model, MeasurementSet)> {
    let (m, model) = machine_and_model(machine, model)?;
    let set = match import {
        Some(profile) => volver_core::import::Profile::load(profile)
            .context("reading the import profile")?
            .load_export(&m, data)
            .context("reading the measurements through the import profile")?,
        None => MeasurementSet::load(&m, data).context("reading the measurements")?,
    };
    Problem::new(&model, &set)?.check_scale(&data.display().to_string())?;
    Ok((m, model, set))
}

/// `model` with the candidates `ids` (from `volver diagnose`) added in turn.
pub fn with_candidates(machine: &Machine, mut model: Model, ids: &[String]) -> Result<Model> {
    for id in ids {
        let library = volver_solvers::candidates::library(&model);
        let Some(c) = library.iter().find(|c| &c.id == id) else {
            let ids: Vec<&str> = library.iter().map(|c| c.id.as_str()).collect();
            bail!(
                "--add {id}: not a candidate for this model; candidates are {}",
                ids.join(", ")
            );
        };
        model = Model::new(machine.clone(), c.spec.clone())?;
    }
    Ok(model)
}

/// The demo's synthetic test 4 on `model`'s machine: random true errors in the model (default
/// magnitudes), the paper's tracker noise, seed [`DEMO_SEED`], no hidden effect. `volver
/// compare` uses it.
pub fn demo_test4(model: &Model) -> Result<Synthetic> {
    let m = model.machine();
    let truth = Truth::random(m, model.spec(), &Magnitudes::default(), DEMO_SEED)?;
    Ok(Simulation::new(Plan::preset(m, "test4")?, truth, DEMO_SEED).run()?)
}
