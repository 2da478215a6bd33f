//! The native module `volver._volver` of the Python package `volver`: the facade library's
//! workflows (identify, diagnose, uncertainty, predict, compensate, plan, tables, simulate)
//! called from Python, as the CLI's subcommands call them, so that the results are the CLI's.
//!
//! Python sees plain objects (dicts, lists, floats) built from the same serialisable reports
//! the CLI prints with `--json`, and numpy arrays for points and commands, with the units in
//! their names (`points_mm`, `tool_points_mm`, `emm_um`). Every error is a `volver.VolverError`
//! (subclasses by kind, see the `errors` module); the GIL is released while volver works.

#![deny(missing_docs)]

mod convert;
mod errors;
mod fitting;
mod machine;
mod using;

use pyo3::prelude::*;

/// The native module: the functions and the exception classes.
#[pymodule]
fn _volver(m: &Bound<'_, PyModule>) -> PyResult<()> {
    errors::register(m)?;
    machine::register(m)?;
    fitting::register(m)?;
    using::register(m)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
