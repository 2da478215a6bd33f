//! Using identified errors: `predict` (the tool point of a results file), `compensate_points`
//! (the corrected commands, behind the U gate), `tables` (the error tables for controls) and
//! `plan` (an optimal test design), as the CLI's subcommands call the library.

use crate::convert::{
    CommandsArg, array, axis_names, commands_of, count, count_opt, file_units, plain, points,
    tool_text,
};
use crate::errors::{detached, request};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;
use volver::compensation::{Statement, Vouch};
use volver::core::results::ResultsFile;

/// Adds this file's functions to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(predict, m)?)?;
    m.add_function(wrap_pyfunction!(compensate_points, m)?)?;
    m.add_function(wrap_pyfunction!(tables, m)?)?;
    m.add_function(wrap_pyfunction!(plan, m)?)?;
    // The default of `compensate_points(reversal_tolerance_um=…)`, which its text signature
    // spells as a number: the tests compare the two.
    m.add(
        "REVERSAL_TOLERANCE_UM",
        volver::core::compensate::REVERSAL_TOLERANCE_UM,
    )?;
    Ok(())
}

/// `volver predict`: the tool point of a results file in the workpiece frame at each command
/// of `grid` (a plan preset or grid text, mm and degrees) or of `commands` (N × axes, mm and
/// degrees); returns `axes`, `commands` and `tool_points_mm` (N × 3) with `tool_offset_mm`.
#[pyfunction]
#[pyo3(signature = (results, grid=None, commands=None, tool_offset_mm=None), text_signature = "(results, grid=None, commands=None, tool_offset_mm=None)")]
fn predict<'py>(
    py: Python<'py>,
    results: PathBuf,
    grid: Option<String>,
    commands: Option<CommandsArg<'py>>,
    tool_offset_mm: Option<[f64; 3]>,
) -> PyResult<Bound<'py, PyDict>> {
    if grid.is_some() == commands.is_some() {
        return Err(request(
            py,
            "predict: give grid or commands (one of them)".into(),
        ));
    }
    let label = results.display().to_string();
    let (model, params) = detached(py, || {
        let file = ResultsFile::load(&results)?;
        Ok(file.to_model(&label)?)
    })?;
    let m = model.machine();
    let rows: Vec<Vec<f64>> = match &commands {
        Some(c) => commands_of(py, m, c)?,
        None => {
            let plan = detached(py, || volver::inputs::plan(m, None, grid.as_deref()))?;
            plan.positions.iter().map(|c| file_units(m, c)).collect()
        }
    };
    let tool = tool_text(tool_offset_mm);
    let (tool, tips) = detached(py, || {
        let tool = volver::compensation::tool_point_of(tool.as_deref(), None, &model)?;
        let mut tips = Vec::with_capacity(rows.len());
        for r in &rows {
            let mut c = volver::core::machine::Commands::default();
            for (k, ax) in m.axes().iter().enumerate() {
                c.0[k] = ax.from_file_units(r[k]);
            }
            tips.push(model.tool_point(&c.0, &tool, &params));
        }
        Ok((tool, tips))
    })?;
    let d = PyDict::new(py);
    d.set_item("model", &model.spec().name)?;
    d.set_item("axes", axis_names(m))?;
    d.set_item("tool_offset_mm", tool.to_vec())?;
    d.set_item("commands", array(py, &rows, m.axes().len())?)?;
    d.set_item("tool_points_mm", points(py, &tips)?)?;
    Ok(d)
}

/// What `compensate_points` is asked beside the points.
#[derive(Clone, Debug)]
struct CompensateRequest {
    results: PathBuf,
    tool: Option<String>,
    tool_reflector: Option<String>,
    hold: Option<String>,
    tool_axis: Option<String>,
    decimals: usize,
    accept: bool,
    max_u_um: f64,
    force: bool,
    tolerance_mm: f64,
    tolerance_rad: f64,
    reversal_tolerance_um: f64,
}

/// The decimals of written commands: 0 … [`volver::core::gcode::MAX_DECIMALS`].
fn checked_decimals(py: Python<'_>, decimals: i64) -> PyResult<usize> {
    let decimals: usize = count(py, "decimals", decimals)?;
    let most = volver::core::gcode::MAX_DECIMALS;
    if decimals > most {
        return Err(request(py, format!("decimals {decimals}: 0 … {most}")));
    }
    Ok(decimals)
}

/// A `RequestError` naming `name` unless `value` is finite and above zero (or zero, when
/// `zero` is allowed).
fn positive(py: Python<'_>, name: &'static str, value: f64, zero: bool) -> PyResult<()> {
    if value.is_finite() && (value > 0.0 || (zero && value == 0.0)) {
        return Ok(());
    }
    let bound = if zero { "≥ 0" } else { "> 0" };
    let message = format!("{name} = {value}: expected a finite number {bound}");
    Err(crate::errors::invalid(py, name, message))
}

/// The U gate as `volver compensate` applies it: the notes, a refusal unless `force`.
fn gate(v: &Vouch, force: bool) -> volver::Result<Vec<String>> {
    let mut notes = Vec::new();
    for statement in &v.statements {
        match statement {
            Statement::Note(text) => notes.push(text.clone()),
            Statement::Refusal {
                reason,
                override_text,
            } => {
                if !force {
                    return Err(volver::Error::Refused(format!(
                        "{reason}; {}",
                        override_text.replace("--force", "force=True")
                    )));
                }
                notes.push(format!("warning: {reason} (used anyway: force=True)"));
            }
            _ => {}
        }
    }
    Ok(notes)
}

/// The point list `text` compensated as `volver compensate --points` does: its output CSV, the
/// figures, the gate's notes.
fn run_compensate(
    r: &CompensateRequest,
    text: &str,
    label: &str,
) -> volver::Result<(volver::compensation::Compensated, Vec<String>)> {
    use volver::compensation as c;
    let (model, params, record) = c::load_results(&r.results, r.accept)?;
    let tool = c::tool_point_of(r.tool.as_deref(), r.tool_reflector.as_deref(), &model)?;
    let axis = match &r.tool_axis {
        Some(t) => Some(c::tool_axis_of(Some(t))?),
        None => None,
    };
    let comp = c::compensator(&model, &params, tool, r.hold.as_deref(), axis)?;
    c::check_max_u(r.max_u_um)?;
    let notes = gate(
        &c::vouch(&model, &params, record.as_ref(), tool, r.max_u_um)?,
        r.force,
    )?;
    let done = c::compensate_points(
        &comp,
        model.machine(),
        text,
        label,
        r.decimals,
        r.reversal_tolerance_um,
    )?;
    if done.worst_solved_mm.is_nan() || done.worst_solved_mm > r.tolerance_mm {
        return Err(volver::Error::NotSolved(format!(
            "a corrected command misses its target by {:.3e} mm, above the tolerance {:.1e} mm",
            done.worst_solved_mm, r.tolerance_mm
        )));
    }
    if let Some(o) = &done.orientation
        && (o.worst_solved_rad.is_nan() || o.worst_solved_rad > r.tolerance_rad)
    {
        return Err(volver::Error::NotSolved(format!(
            "a corrected command's tool direction misses its target by {:.3e} rad, above the \
             tolerance {:.1e} rad",
            o.worst_solved_rad, r.tolerance_rad
        )));
    }
    Ok((done, notes))
}

/// The commands (N × axes, mm and degrees) as the CSV point list `volver compensate --points`
/// reads (one column per axis).
fn points_csv(names: &[String], rows: &[Vec<f64>]) -> String {
    let mut text = names.join(",");
    text.push('\n');
    for r in rows {
        let cells: Vec<String> = r.iter().map(|v| format!("{v:?}")).collect();
        text.push_str(&cells.join(","));
        text.push('\n');
    }
    text
}

/// `volver compensate --points`: the commands that bring the tool point (and, on a five-axis
/// machine, the tool's direction) where `commands` (N × axes, mm and degrees) or the point
/// file `points` (CSV) program it, with the errors of `results`, behind the U gate (a refusal
/// raises RefusedError unless `force=True`). Returns `csv` (what the CLI writes with `--out`),
/// `points`, `max_error_um`, `worst_solved_mm`, `worst_written_mm`, `outside` and `notes`.
#[pyfunction]
#[pyo3(signature = (results, commands=None, *, points=None, tool_offset_mm=None, tool_reflector=None, hold=None, tool_axis=None, decimals=4, accept=false, max_u_um=25.0, force=false, tolerance_mm=1e-9, tolerance_rad=1e-9, reversal_tolerance_um=volver::core::compensate::REVERSAL_TOLERANCE_UM), text_signature = "(results, commands=None, *, points=None, tool_offset_mm=None, tool_reflector=None, hold=None, tool_axis=None, decimals=4, accept=False, max_u_um=25.0, force=False, tolerance_mm=1e-9, tolerance_rad=1e-9, reversal_tolerance_um=1.0)")]
#[allow(clippy::too_many_arguments)]
fn compensate_points<'py>(
    py: Python<'py>,
    results: PathBuf,
    commands: Option<CommandsArg<'py>>,
    points: Option<PathBuf>,
    tool_offset_mm: Option<[f64; 3]>,
    tool_reflector: Option<String>,
    hold: Option<String>,
    tool_axis: Option<[f64; 3]>,
    decimals: i64,
    accept: bool,
    max_u_um: f64,
    force: bool,
    tolerance_mm: f64,
    tolerance_rad: f64,
    reversal_tolerance_um: f64,
) -> PyResult<Bound<'py, PyDict>> {
    let decimals = checked_decimals(py, decimals)?;
    positive(py, "tolerance_mm", tolerance_mm, false)?;
    positive(py, "tolerance_rad", tolerance_rad, false)?;
    positive(py, "reversal_tolerance_um", reversal_tolerance_um, true)?;
    let r = CompensateRequest {
        results,
        tool: tool_text(tool_offset_mm),
        tool_reflector,
        hold,
        tool_axis: tool_text(tool_axis),
        decimals,
        accept,
        max_u_um,
        force,
        tolerance_mm,
        tolerance_rad,
        reversal_tolerance_um,
    };
    let (text, label) = match (&commands, &points) {
        (Some(c), None) => {
            let label = r.results.display().to_string();
            let (model, _) = detached(py, || Ok(ResultsFile::load(&r.results)?.to_model(&label)?))?;
            let rows = commands_of(py, model.machine(), c)?;
            (
                points_csv(&axis_names(model.machine()), &rows),
                "<commands>".to_string(),
            )
        }
        (None, Some(p)) => {
            let label = p.display().to_string();
            let text = detached(py, || {
                Ok(
                    std::fs::read_to_string(p).map_err(|e| volver::core::Error::Io {
                        path: p.clone(),
                        source: e,
                    })?,
                )
            })?;
            (text, label)
        }
        _ => {
            return Err(request(
                py,
                "compensate_points: give commands or points (one of them)".into(),
            ));
        }
    };
    let (done, notes) = detached(py, || run_compensate(&r, &text, &label))?;
    let d = PyDict::new(py);
    d.set_item("csv", done.text)?;
    d.set_item("points", done.points)?;
    d.set_item(
        "max_error_um",
        done.max_error_mm * volver::core::units::UM_PER_MM,
    )?;
    d.set_item("worst_solved_mm", done.worst_solved_mm)?;
    d.set_item("worst_written_mm", done.worst_written_mm)?;
    d.set_item("outside", done.outside)?;
    d.set_item("notes", notes)?;
    Ok(d)
}

/// The error tables of a results file (`volver tables`' ErrorTables, ERRORS not corrections, mm
/// and rad): `constants` (name → value) and `axes` (a list of dicts: `axis`, `positions` in mm
/// or degrees, `errors` name → numpy array, `reversal`), behind the U gate as `volver tables`
/// (RefusedError unless `force=True`); with `out`, the ISG, Etalon and plain CSV files written
/// there (`files`).
#[pyfunction]
#[pyo3(signature = (results, out=None, *, step_mm=10.0, rotary_step_deg=5.0, tool_offset_mm=None, accept=false, max_u_um=25.0, force=false), text_signature = "(results, out=None, *, step_mm=10.0, rotary_step_deg=5.0, tool_offset_mm=None, accept=False, max_u_um=25.0, force=False)")]
#[allow(clippy::too_many_arguments)]
fn tables<'py>(
    py: Python<'py>,
    results: PathBuf,
    out: Option<PathBuf>,
    step_mm: f64,
    rotary_step_deg: f64,
    tool_offset_mm: Option<[f64; 3]>,
    accept: bool,
    max_u_um: f64,
    force: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let tool = tool_text(tool_offset_mm);
    let (t, notes, files) = detached(py, || {
        use volver::compensation as c;
        let (model, params, record) = c::load_results(&results, accept)?;
        let tool = c::tool_point_of(tool.as_deref(), None, &model)?;
        c::check_max_u(max_u_um)?;
        let notes = gate(
            &c::vouch(&model, &params, record.as_ref(), tool, max_u_um)?,
            force,
        )?;
        let t = volver::core::tables::ErrorTables::from_model(
            &model,
            &params,
            step_mm,
            rotary_step_deg,
        )?;
        let files = match &out {
            Some(dir) => c::write_tables(&t, dir)?,
            None => Vec::new(),
        };
        Ok((t, notes, files))
    })?;
    let d = PyDict::new(py);
    let constants = PyDict::new(py);
    for (name, v) in &t.constants {
        constants.set_item(name, v)?;
    }
    d.set_item("constants", constants)?;
    let axes = pyo3::types::PyList::empty(py);
    for a in &t.axes {
        let one = PyDict::new(py);
        one.set_item("axis", a.axis.to_string())?;
        one.set_item(
            "positions",
            numpy::PyArray1::from_vec(py, a.positions.clone()),
        )?;
        let errors = PyDict::new(py);
        for (name, v) in &a.errors {
            errors.set_item(name, numpy::PyArray1::from_vec(py, v.clone()))?;
        }
        one.set_item("errors", errors)?;
        one.set_item(
            "reversal",
            a.reversal.clone().map(|v| numpy::PyArray1::from_vec(py, v)),
        )?;
        axes.append(one)?;
    }
    d.set_item("axes", axes)?;
    d.set_item("notes", notes)?;
    let files: Vec<String> = files.iter().map(|p| p.display().to_string()).collect();
    d.set_item("files", files)?;
    Ok(d)
}

/// `volver plan --json`: an optimal test of `points` measurements for the machine and model
/// (criterion i, v or d), its report as a dict and `commands` (N × axes, mm and degrees) and
/// `reflector_ids` in measuring order; with `out`, the plan file (CSV) written as `--out` writes it.
#[pyfunction]
#[pyo3(signature = (machine=None, model=None, *, points=1040, criterion="i".to_string(), noise=None, tool_offset_mm=None, per_axis=None, repeats=8, seed=1, out=None), text_signature = "(machine=None, model=None, *, points=1040, criterion='i', noise=None, tool_offset_mm=None, per_axis=None, repeats=8, seed=1, out=None)")]
#[allow(clippy::too_many_arguments)]
fn plan<'py>(
    py: Python<'py>,
    machine: Option<PathBuf>,
    model: Option<PathBuf>,
    points: i64,
    criterion: String,
    noise: Option<String>,
    tool_offset_mm: Option<[f64; 3]>,
    per_axis: Option<i64>,
    repeats: i64,
    seed: i64,
    out: Option<PathBuf>,
) -> PyResult<Bound<'py, PyAny>> {
    let points: usize = count(py, "points", points)?;
    let per_axis: Option<usize> = count_opt(py, "per_axis", per_axis)?;
    let repeats: usize = count(py, "repeats", repeats)?;
    let seed: u64 = count(py, "seed", seed)?;
    let tool = tool_text(tool_offset_mm);
    let (planned, noise) = detached(py, || {
        use volver::core::noise::TrackerNoise;
        let (_, model) = volver::inputs::machine_and_model(machine.as_deref(), model.as_deref())?;
        let noise = match &noise {
            Some(t) => TrackerNoise::from_text(t)?,
            None => model
                .machine()
                .tracker()
                .noise
                .unwrap_or(TrackerNoise::PAPER),
        };
        let tool = volver::compensation::tool_point_of(tool.as_deref(), None, &model)?;
        let request = volver::planning::Request {
            points,
            criterion: criterion.parse().map_err(volver::Error::Request)?,
            tool,
            noise,
            per_axis: match per_axis {
                Some(n) => n,
                None => volver::planning::default_per_axis(
                    model.machine(),
                    model.machine().reflectors().len(),
                )?,
            },
            seed,
            repeats,
            ..volver::planning::Request::default()
        };
        let planned = volver::planning::plan(&model, &request)?;
        Ok((planned, noise))
    })?;
    let m = planned.model.machine();
    if let Some(path) = &out {
        let title = format!(
            "{} ({} noise, tool at {:?} mm, seed {})",
            planned.plan.name, noise, planned.report.tool_mm, seed
        );
        let text = volver::core::plan::file::to_csv(&planned.plan, m, &title);
        detached(py, || {
            volver::core::fsio::write_atomic(path, text)
                .map_err(|e| volver::Error::Os(e).context(format!("writing {}", path.display())))
        })?;
    }
    let result = plain(py, &planned.report)?;
    let steps = planned.plan.steps();
    let rows: Vec<Vec<f64>> = steps
        .iter()
        .map(|s| file_units(m, &planned.plan.positions[s.position]))
        .collect();
    result.set_item("axes", axis_names(m))?;
    result.set_item("commands", array(py, &rows, m.axes().len())?)?;
    let ids: Vec<&str> = steps
        .iter()
        .map(|s| m.reflectors()[s.reflector].id.as_str())
        .collect();
    result.set_item("reflector_ids", ids)?;
    Ok(result)
}
