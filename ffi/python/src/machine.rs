//! Machines, models and data: the embedded machines, a machine and its model described, a
//! measurement file read, a synthetic test simulated (`volver simulate`), the demo's data.

use crate::convert::{Names, array, axis_names, count, file_units, plain, points};
use crate::errors::detached;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;
use volver::core::model::{ErrorModelSpec, Model};
use volver::core::noise::TrackerNoise;
use volver::core::simulate::{Effect, Magnitudes, Simulation, Truth, TruthSource};

/// Adds this file's functions to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(presets, m)?)?;
    m.add_function(wrap_pyfunction!(describe, m)?)?;
    m.add_function(wrap_pyfunction!(measurements, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(demo_data, m)?)?;
    Ok(())
}

/// The embedded machines: name → one line on what it is.
#[pyfunction]
fn presets(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let d = PyDict::new(py);
    for p in volver::core::presets::PRESETS.iter() {
        d.set_item(p.name, p.description)?;
    }
    Ok(d)
}

/// A machine (file or embedded name; the XCFZ grinder when None) and its error model (file;
/// the embedded machine's default when None): chain, axes with their travel (file units),
/// reflectors (mm), the model's parameters and their initial values (mm, rad).
#[pyfunction]
#[pyo3(signature = (machine=None, model=None), text_signature = "(machine=None, model=None)")]
fn describe(
    py: Python<'_>,
    machine: Option<PathBuf>,
    model: Option<PathBuf>,
) -> PyResult<Bound<'_, PyDict>> {
    let (m, model) = detached(py, || {
        volver::inputs::machine_and_model(machine.as_deref(), model.as_deref())
    })?;
    let d = PyDict::new(py);
    d.set_item("name", &m.spec().name)?;
    d.set_item("chain", m.chain().to_string())?;
    let axes = pyo3::types::PyList::empty(py);
    for ax in m.axes() {
        let a = PyDict::new(py);
        a.set_item("axis", ax.axis.to_string())?;
        a.set_item("unit", ax.file_unit())?;
        a.set_item("min", ax.to_file_units(ax.min))?;
        a.set_item("max", ax.to_file_units(ax.max))?;
        axes.append(a)?;
    }
    d.set_item("axes", axes)?;
    let reflectors = PyDict::new(py);
    for r in m.reflectors() {
        reflectors.set_item(&r.id, r.offset.to_vec())?;
    }
    d.set_item("reflector_offsets_mm", reflectors)?;
    d.set_item("model", &model.spec().name)?;
    let names: Vec<&str> = model.params().iter().map(|p| p.name.as_str()).collect();
    d.set_item("parameters", names)?;
    d.set_item("initial_params", model.initial_params())?;
    Ok(d)
}

/// A measurement file read for a machine and model, as `identify` reads it: the commands
/// (N × axes, mm and degrees), the measured points (N × 3, mm, the station's frame), the
/// reflector ids, the time stamps (s, NaN where absent) and each row's line in the file.
#[pyfunction]
#[pyo3(signature = (data, machine=None, model=None, import_profile=None, plan_file=None), text_signature = "(data, machine=None, model=None, import_profile=None, plan_file=None)")]
fn measurements(
    py: Python<'_>,
    data: PathBuf,
    machine: Option<PathBuf>,
    model: Option<PathBuf>,
    import_profile: Option<PathBuf>,
    plan_file: Option<PathBuf>,
) -> PyResult<Bound<'_, PyDict>> {
    let (m, _, set) = detached(py, || {
        volver::inputs::load_taken_by(
            machine.as_deref(),
            model.as_deref(),
            &data,
            import_profile.as_deref(),
            plan_file.as_deref(),
        )
    })?;
    let d = PyDict::new(py);
    let commands: Vec<Vec<f64>> = set
        .points
        .iter()
        .map(|p| file_units(&m, &p.commands))
        .collect();
    d.set_item("axes", axis_names(&m))?;
    d.set_item("commands", array(py, &commands, m.axes().len())?)?;
    let measured: Vec<[f64; 3]> = set.points.iter().map(|p| p.measured).collect();
    d.set_item("points_mm", points(py, &measured)?)?;
    let ids: Vec<&str> = set
        .points
        .iter()
        .map(|p| m.reflectors()[p.reflector].id.as_str())
        .collect();
    d.set_item("reflectors", ids)?;
    let t: Vec<f64> = set
        .points
        .iter()
        .map(|p| p.t_s.unwrap_or(f64::NAN))
        .collect();
    d.set_item("t_s", numpy::PyArray1::from_vec(py, t))?;
    let lines: Vec<usize> = set.points.iter().map(|p| p.line).collect();
    d.set_item("lines", lines)?;
    Ok(d)
}

/// `volver simulate` with random true errors: the machine (file or embedded name), the plan
/// (preset or grid; the machine's preset plan when None), seed, noise, magnitudes and effects
/// as the CLI takes them; writes measurements.csv, truth.json, machine.toml and simulation.json
/// into `out` and returns the simulation's record (machine and noise error in µm …).
#[pyfunction]
#[pyo3(signature = (out, machine=None, plan=None, seed=1, noise=None, magnitudes=Names::default(), effects=Names::default(), duration_h=None, truth_model=None), text_signature = "(out, machine=None, plan=None, seed=1, noise=None, magnitudes=(), effects=(), duration_h=None, truth_model=None)")]
#[allow(clippy::too_many_arguments)]
fn simulate<'py>(
    py: Python<'py>,
    out: PathBuf,
    machine: Option<PathBuf>,
    plan: Option<String>,
    seed: i64,
    noise: Option<String>,
    magnitudes: Names,
    effects: Names,
    duration_h: Option<f64>,
    truth_model: Option<PathBuf>,
) -> PyResult<Bound<'py, PyAny>> {
    let seed: u64 = count(py, "seed", seed)?;
    let (magnitudes, effects) = (magnitudes.0, effects.0);
    let record = detached(py, || {
        let (m, preset) = match &machine {
            Some(p) => volver::inputs::machine(Some(p))?,
            None => volver::inputs::machine(None)?,
        };
        let structure = match (&truth_model, preset) {
            (Some(p), _) => Model::load(m.clone(), p)?.spec().clone(),
            (None, Some(p)) if p.name != "xcfz" => p.model()?.spec().clone(),
            _ => ErrorModelSpec::complete(&m),
        };
        let mut sizes = Magnitudes::default();
        for text in &magnitudes {
            sizes.set_from_text(text)?;
        }
        let truth = Truth::random(&m, &structure, &sizes, seed)?;
        let plan = volver::inputs::plan(&m, preset, plan.as_deref())?;
        let mut sim = Simulation::new(plan, truth, seed);
        sim.truth_source = TruthSource::Random {
            structure: structure.name.clone(),
            magnitudes: sizes,
        };
        sim.noise = match (&noise, m.default_noise()) {
            (Some(text), _) => TrackerNoise::from_text(text)?,
            (None, Some(n)) => n,
            (None, None) => TrackerNoise::PAPER,
        };
        sim.effects = effects
            .iter()
            .map(|t| Effect::parse(t))
            .collect::<volver::core::Result<_>>()?;
        sim.duration_s = duration_h.map(|h| h * volver::core::units::S_PER_H);
        let done = sim.run()?;
        done.write(&out)?;
        Ok(done.record)
    })?;
    plain(py, &record)
}

/// The demo's synthetic test (`volver demo`, step 1): the embedded machine's default model's
/// true errors at the default magnitudes, seed 7, its preset plan (test 4 on the XCFZ grinder)
/// and the effect it hides; written into `out`; returns the simulation's record.
#[pyfunction]
#[pyo3(signature = (out, machine="xcfz"), text_signature = "(out, machine='xcfz')")]
fn demo_data<'py>(py: Python<'py>, out: PathBuf, machine: &str) -> PyResult<Bound<'py, PyAny>> {
    let name = machine.to_string();
    let record = detached(py, || {
        let preset = volver::core::presets::named(&name).ok_or_else(|| {
            volver::Error::Request(format!(
                "machine {name}: not an embedded machine (they are {})",
                volver::core::presets::names().join(", ")
            ))
        })?;
        let xcfz = preset.name == "xcfz";
        let model = if xcfz {
            Model::default_xcfz()
        } else {
            preset.model()?
        };
        let m = model.machine();
        let truth = Truth::random(
            m,
            model.spec(),
            &Magnitudes::default(),
            volver::inputs::DEMO_SEED,
        )?;
        let plan = if xcfz {
            volver::core::plan::Plan::preset(m, "test4")?
        } else {
            preset.plan_on(m)?
        };
        let mut sim = Simulation::new(plan, truth, volver::inputs::DEMO_SEED);
        sim.effects = vec![Effect::parse(preset.demo_effect)?];
        let done = sim.run()?;
        done.write(&out)?;
        Ok(done.record)
    })?;
    plain(py, &record)
}
