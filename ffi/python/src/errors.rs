//! volver's typed errors as Python exceptions: `VolverError` and one subclass per kind, each
//! carrying `file`, `line` and `field` (None when the error does not know them), `kind` (the
//! variant's name) and `context` (what was being done, outermost first).

use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::PyType;
use volver::Error;
use volver::core::Error as CoreError;
use volver::solvers::Error as EngineError;

create_exception!(
    volver,
    VolverError,
    PyException,
    "Any error of volver; attributes file, line, field (None when unknown), kind, context."
);
create_exception!(
    volver,
    InputError,
    VolverError,
    "Bad input in a file: `file`, `line` (1-based) and `field` (TOML key, CSV column) say where."
);
create_exception!(
    volver,
    FileError,
    VolverError,
    "A file that could not be read or written (`file`)."
);
create_exception!(
    volver,
    RequestError,
    VolverError,
    "A request that cannot be served as asked: an argument out of its range, an unknown name."
);
create_exception!(
    volver,
    MismatchError,
    VolverError,
    "Inputs that do not belong together (a measurement the model cannot use: `line`)."
);
create_exception!(
    volver,
    ModelError,
    VolverError,
    "A model that cannot be built or evaluated (too many parameters, non-finite values)."
);
create_exception!(
    volver,
    SolverError,
    VolverError,
    "A failure of an engine or of the solvers' analyses."
);
create_exception!(
    volver,
    NotSolvedError,
    VolverError,
    "An identification that did not converge."
);
create_exception!(
    volver,
    SingularError,
    VolverError,
    "A matrix that could not be factorised or inverted."
);
create_exception!(
    volver,
    ImplausibleError,
    VolverError,
    "Identified sizes beyond the stated physical limits."
);
create_exception!(
    volver,
    RefusedError,
    VolverError,
    "The U gate refused the errors (pass force=True to use them anyway)."
);

/// Adds the exception classes to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("VolverError", py.get_type::<VolverError>())?;
    m.add("InputError", py.get_type::<InputError>())?;
    m.add("FileError", py.get_type::<FileError>())?;
    m.add("RequestError", py.get_type::<RequestError>())?;
    m.add("MismatchError", py.get_type::<MismatchError>())?;
    m.add("ModelError", py.get_type::<ModelError>())?;
    m.add("SolverError", py.get_type::<SolverError>())?;
    m.add("NotSolvedError", py.get_type::<NotSolvedError>())?;
    m.add("SingularError", py.get_type::<SingularError>())?;
    m.add("ImplausibleError", py.get_type::<ImplausibleError>())?;
    m.add("RefusedError", py.get_type::<RefusedError>())?;
    Ok(())
}

/// Where an error points: file, line, field.
#[derive(Default)]
struct Where {
    file: Option<String>,
    line: Option<usize>,
    field: Option<String>,
}

/// The exception class, the variant's name and the place of the core's error `e`.
fn of_core<'py>(py: Python<'py>, e: &CoreError) -> (Bound<'py, PyType>, &'static str, Where) {
    let mut at = Where::default();
    let (class, kind) = match e {
        CoreError::Input { place, .. } => {
            at.file = Some(place.file.clone());
            at.line = place.line;
            at.field.clone_from(&place.field);
            (py.get_type::<InputError>(), "Input")
        }
        CoreError::Io { path, .. } => {
            at.file = Some(path.display().to_string());
            (py.get_type::<FileError>(), "Io")
        }
        CoreError::InvalidOption { name, .. } => {
            at.field = Some((*name).to_string());
            (py.get_type::<RequestError>(), "InvalidOption")
        }
        CoreError::MeasurementMismatch { line, .. } => {
            at.line = Some(*line);
            (py.get_type::<MismatchError>(), "MeasurementMismatch")
        }
        CoreError::MachineMismatch { .. } => (py.get_type::<MismatchError>(), "MachineMismatch"),
        CoreError::Singular { .. } => (py.get_type::<SingularError>(), "Singular"),
        CoreError::UnknownErrorName { name } => {
            at.field = Some(name.clone());
            (py.get_type::<InputError>(), "UnknownErrorName")
        }
        _ => (py.get_type::<ModelError>(), "Model"),
    };
    (class, kind, at)
}

/// The exception class, the variant's name and the field of the solvers' error `e`.
fn of_solver<'py>(py: Python<'py>, e: &EngineError) -> (Bound<'py, PyType>, &'static str, Where) {
    let mut at = Where::default();
    let (class, kind) = match e {
        EngineError::UnknownEngine { .. } => (py.get_type::<RequestError>(), "UnknownEngine"),
        EngineError::OutOfRange { field, .. } => {
            at.field = Some((*field).to_string());
            (py.get_type::<RequestError>(), "OutOfRange")
        }
        EngineError::SettingOutOfRange { field, .. } => {
            at.field = Some((*field).to_string());
            (py.get_type::<RequestError>(), "SettingOutOfRange")
        }
        EngineError::SettingCount { field, .. } => {
            at.field = Some((*field).to_string());
            (py.get_type::<RequestError>(), "SettingCount")
        }
        EngineError::CountOutOfRange { .. } => (py.get_type::<RequestError>(), "CountOutOfRange"),
        EngineError::NoLimit => {
            at.field = Some("max_iterations".to_string());
            (py.get_type::<RequestError>(), "NoLimit")
        }
        EngineError::EpsilonOrder { .. } => (py.get_type::<RequestError>(), "EpsilonOrder"),
        EngineError::UnknownObjective(_) => {
            at.field = Some("objective".to_string());
            (py.get_type::<RequestError>(), "UnknownObjective")
        }
        EngineError::UnknownPhasing { .. } => {
            at.field = Some("strategy".to_string());
            (py.get_type::<RequestError>(), "UnknownPhasing")
        }
        EngineError::SettingsFile(_) => (py.get_type::<RequestError>(), "SettingsFile"),
        EngineError::TooFewEvaluations { .. } => {
            at.field = Some("max_evaluations".to_string());
            (py.get_type::<RequestError>(), "TooFewEvaluations")
        }
        _ => (py.get_type::<SolverError>(), "Solver"),
    };
    (class, kind, at)
}

/// The Python exception of volver's error `e`: its class by the innermost error's kind, its
/// message the whole chain (`reading the machine file: m.toml:3: …`), its attributes set.
pub fn to_py(py: Python<'_>, e: Error) -> PyErr {
    let mut context = Vec::new();
    let mut inner = &e;
    while let Error::Context { context: c, source } = inner {
        context.push(c.clone());
        inner = source;
    }
    let (class, kind, at) = match inner {
        Error::Core(c) => of_core(py, c),
        Error::Solver(s) => of_solver(py, s),
        Error::Os(_) => (py.get_type::<FileError>(), "Os", Where::default()),
        Error::Json(j) => {
            let at = Where {
                line: Some(j.line()),
                ..Where::default()
            };
            (py.get_type::<InputError>(), "Json", at)
        }
        Error::Request(_) => (py.get_type::<RequestError>(), "Request", Where::default()),
        Error::Mismatch(_) => (py.get_type::<MismatchError>(), "Mismatch", Where::default()),
        Error::NotSolved(_) => (
            py.get_type::<NotSolvedError>(),
            "NotSolved",
            Where::default(),
        ),
        Error::Singular(_) => (py.get_type::<SingularError>(), "Singular", Where::default()),
        Error::Implausible(_) => (
            py.get_type::<ImplausibleError>(),
            "Implausible",
            Where::default(),
        ),
        Error::Refused(_) => (py.get_type::<RefusedError>(), "Refused", Where::default()),
        _ => (py.get_type::<VolverError>(), "Volver", Where::default()),
    };
    let mut message = context.clone();
    message.push(inner.to_string());
    let err = PyErr::from_type(class, pythonic(&message.join(": ")));
    let value = err.value(py);
    let set = || -> PyResult<()> {
        // A file named after an option (a spec string's, `--noise`) reads as the argument; a
        // path stays as it is.
        let file = at
            .file
            .map(|f| if f.starts_with("--") { pythonic(&f) } else { f });
        value.setattr("file", file)?;
        value.setattr("line", at.line)?;
        value.setattr("field", at.field.as_deref().map(pythonic))?;
        value.setattr("kind", kind)?;
        value.setattr("context", context)?;
        Ok(())
    };
    match set() {
        Ok(()) => err,
        Err(e) => e,
    }
}

/// The CLI's options that volver's messages name, and the Python argument each stands for
/// (a switch as `name=True`): the library's messages are the CLI's.
const ARGUMENTS: [(&str, &str); 39] = [
    ("--accept", "accept=True"),
    ("--add", "add"),
    ("--criterion", "criterion"),
    ("--data", "data"),
    ("--decimals", "decimals"),
    ("--effect", "effects"),
    ("--force", "force=True"),
    ("--geodesic-acceleration", "geodesic_acceleration=True"),
    ("--grid", "grid"),
    ("--hold", "hold"),
    ("--import", "import_profile"),
    ("--machine", "machine"),
    ("--magnitude", "magnitudes"),
    ("--max-evaluations", "max_evaluations"),
    ("--max-iterations", "max_iterations"),
    ("--max-u-um", "max_u_um"),
    ("--model", "model"),
    ("--monte-carlo", "monte_carlo"),
    ("--noise", "noise"),
    ("--objective", "objective"),
    ("--out", "out"),
    ("--per-axis", "per_axis"),
    ("--plan", "plan"),
    ("--plan-file", "plan_file"),
    ("--points", "points"),
    ("--prior", "priors"),
    ("--repeats", "repeats"),
    ("--results", "results"),
    ("--reversal-tolerance-um", "reversal_tolerance_um"),
    ("--rotary-step", "rotary_step_deg"),
    ("--seed", "seed"),
    ("--solver", "engine"),
    ("--step", "step_mm"),
    ("--strategy", "strategy"),
    ("--subloops", "subloops"),
    ("--tool-axis", "tool_axis"),
    ("--tool-offset", "tool_offset_mm"),
    ("--tool-reflector", "tool_reflector"),
    ("--top", "top"),
];

/// Phrases of volver's messages that point to the CLI where Python has its own way, replaced
/// before the options are: (the CLI's words, Python's).
const PHRASES: [(&str, &str); 2] = [
    (
        "`volver layout --list` names them",
        "`volver.presets()` names them",
    ),
    (
        "(--points, or --hours × 3600 / --seconds-per-point per station)",
        "(points)",
    ),
];

/// `text` with each phrase of [`PHRASES`] and each CLI option of [`ARGUMENTS`] spelt as its
/// Python argument (`--max-iterations` → `max_iterations`, `--accept` → `accept=True`); other
/// text, options without a Python argument among them, unchanged. An option is a `--` at the
/// start or after a space, bracket, quote or comma: a `--` inside a path (`runs/a--data.csv`)
/// is left alone.
pub fn pythonic(text: &str) -> String {
    let mut text = text.to_string();
    for (cli, python) in PHRASES {
        text = text.replace(cli, python);
    }
    let mut out = String::with_capacity(text.len());
    let mut rest = text.as_str();
    while let Some(at) = rest.find("--") {
        out.push_str(&rest[..at]);
        let tail = &rest[at..];
        let before = out.chars().last();
        if before.is_some_and(|c| !(c.is_whitespace() || "([`'\",".contains(c))) {
            out.push_str("--");
            rest = &tail[2..];
            continue;
        }
        let len = 2 + tail[2..]
            .find(|c: char| !(c.is_ascii_lowercase() || c.is_ascii_digit() || c == '-'))
            .unwrap_or(tail.len() - 2);
        let option = &tail[..len];
        match ARGUMENTS.iter().find(|(cli, _)| *cli == option) {
            Some((_, python)) => out.push_str(python),
            None => out.push_str(option),
        }
        rest = &tail[len..];
    }
    out.push_str(rest);
    out
}

/// Runs volver's work `f` with the GIL released; its error becomes the Python exception.
pub fn detached<T: Send>(
    py: Python<'_>,
    f: impl FnOnce() -> volver::Result<T> + Send,
) -> PyResult<T> {
    py.detach(f).map_err(|e| to_py(py, e))
}

/// A `RequestError` on the argument `name` (its `field`), raised from the bindings themselves.
pub fn invalid(py: Python<'_>, name: &'static str, message: String) -> PyErr {
    to_py(py, Error::Core(CoreError::InvalidOption { name, message }))
}

/// A request error raised from the bindings themselves (an argument of the wrong shape).
pub fn request(py: Python<'_>, message: String) -> PyErr {
    to_py(py, Error::Request(message))
}
