//! Between volver's values and Python's: serialisable reports as plain Python objects (through
//! JSON, the CLI's `--json`), rows as numpy arrays, a machine's commands in file units (mm,
//! degrees) to and from volver's internal ones (mm, rad).

use numpy::ndarray::Array2;
use numpy::{AllowTypeChange, IntoPyArray, PyArrayLike2, PyReadonlyArray2};
use pyo3::prelude::*;
use volver::core::machine::{Commands, Machine};

/// `value` as the plain Python object `json.loads` makes of its JSON (dicts, lists, floats).
pub fn plain<'py>(py: Python<'py>, value: &impl serde::Serialize) -> PyResult<Bound<'py, PyAny>> {
    let text = serde_json::to_string(value)
        .map_err(|e| super::errors::to_py(py, volver::Error::Json(e)))?;
    py.import("json")?.call_method1("loads", (text,))
}

/// Rows of equal length as an N × `width` numpy array (float64).
pub fn array<'py>(py: Python<'py>, rows: &[Vec<f64>], width: usize) -> PyResult<Bound<'py, PyAny>> {
    let flat: Vec<f64> = rows.iter().flat_map(|r| r.iter().copied()).collect();
    let a = Array2::from_shape_vec((rows.len(), width), flat)
        .map_err(|e| super::errors::request(py, format!("rows of unequal length: {e}")))?;
    Ok(a.into_pyarray(py).into_any())
}

/// Points (mm) as an N × 3 numpy array.
pub fn points<'py>(py: Python<'py>, points: &[[f64; 3]]) -> PyResult<Bound<'py, PyAny>> {
    let rows: Vec<Vec<f64>> = points.iter().map(|p| p.to_vec()).collect();
    array(py, &rows, 3)
}

/// A command in the machine's file units (mm, degrees), chain order.
pub fn file_units(m: &Machine, c: &Commands) -> Vec<f64> {
    m.axes()
        .iter()
        .enumerate()
        .map(|(k, ax)| ax.to_file_units(c.0[k]))
        .collect()
}

/// The rows of an N × (number of axes) array of commands in file units (mm, degrees, chain
/// order), checked against the machine's axes.
pub fn commands_of(
    py: Python<'_>,
    m: &Machine,
    commands: &PyReadonlyArray2<'_, f64>,
) -> PyResult<Vec<Vec<f64>>> {
    let view = commands.as_array();
    let axes = m.axes().len();
    if view.ncols() != axes {
        return Err(super::errors::request(
            py,
            format!(
                "commands: {} columns, expected one per axis of the machine ({axes}: {}, mm and \
                 degrees)",
                view.ncols(),
                m.chain()
            ),
        ));
    }
    if view.nrows() == 0 {
        return Err(super::errors::request(py, "commands: no rows".into()));
    }
    if let Some(bad) = view.iter().position(|v| !v.is_finite()) {
        let (row, col) = (bad / axes, bad % axes);
        return Err(super::errors::request(
            py,
            format!("commands[{row}, {col}] is not a finite number (mm or degrees)"),
        ));
    }
    Ok(view.rows().into_iter().map(|r| r.to_vec()).collect())
}

/// Commands as Python passes them: any two-dimensional array-like of numbers (a float or
/// integer numpy array, nested lists), converted to float64.
pub type CommandsArg<'py> = PyArrayLike2<'py, f64, AllowTypeChange>;

/// The integer argument `name` as a count: a `RequestError` naming it (its `field`) when it is
/// negative or beyond the target type.
pub fn count<T: TryFrom<i64>>(py: Python<'_>, name: &'static str, value: i64) -> PyResult<T> {
    T::try_from(value).map_err(|_| {
        let message = if value < 0 {
            format!("{name} = {value}: expected an integer ≥ 0")
        } else {
            format!("{name} = {value}: too large")
        };
        super::errors::invalid(py, name, message)
    })
}

/// [`count`] of an optional argument.
pub fn count_opt<T: TryFrom<i64>>(
    py: Python<'_>,
    name: &'static str,
    value: Option<i64>,
) -> PyResult<Option<T>> {
    value.map(|v| count(py, name, v)).transpose()
}

/// A list of names as Python passes it: a list (or tuple) of strings, or one string for a
/// list of one (`add="raise-axis:C"` as `add=["raise-axis:C"]`).
#[derive(Clone, Debug, Default)]
pub struct Names(pub Vec<String>);

impl<'a, 'py> FromPyObject<'a, 'py> for Names {
    type Error = PyErr;

    fn extract(ob: Borrowed<'a, 'py, PyAny>) -> PyResult<Self> {
        if let Ok(one) = ob.extract::<String>() {
            return Ok(Names(vec![one]));
        }
        ob.extract::<Vec<String>>().map(Names).map_err(|_| {
            pyo3::exceptions::PyTypeError::new_err("expected a string or a list of strings")
        })
    }
}

/// The axis letters of a machine, chain order.
pub fn axis_names(m: &Machine) -> Vec<String> {
    m.axes().iter().map(|ax| ax.axis.to_string()).collect()
}

/// A tool point `[x, y, z]` (mm) as the CLI's `X,Y,Z` text.
pub fn tool_text(tool: Option<[f64; 3]>) -> Option<String> {
    tool.map(|t| format!("{},{},{}", t[0], t[1], t[2]))
}
