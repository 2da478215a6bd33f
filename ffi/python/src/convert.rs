//! Between volver's values and Python's: serialisable reports as plain Python objects (through
//! JSON, the CLI's `--json`), rows as numpy arrays, a machine's commands in file units (mm,
//! degrees) to and from volver's internal ones (mm, rad).

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyReadonlyArray2};
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
    Ok(view.rows().into_iter().map(|r| r.to_vec()).collect())
}

/// The axis letters of a machine, chain order.
pub fn axis_names(m: &Machine) -> Vec<String> {
    m.axes().iter().map(|ax| ax.axis.to_string()).collect()
}

/// A tool point `[x, y, z]` (mm) as the CLI's `X,Y,Z` text.
pub fn tool_text(tool: Option<[f64; 3]>) -> Option<String> {
    tool.map(|t| format!("{},{},{}", t[0], t[1], t[2]))
}
