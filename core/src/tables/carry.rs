//! What per-axis tables carry of a model, computed rather than assumed: the tool point as a
//! control applies the tables ([`ErrorTables::tool_point`]), and each part of the model the
//! tables cannot carry with the error it leaves ([`uncarried`]).

use super::ErrorTables;
use crate::approach::Approach;
use crate::error::{Error, Result};
use crate::iso::ErrorId;
use crate::kinematics::{PointErrors, tool_in_workpiece};
use crate::machine::Commands;
use crate::model::{Model, Role};
use serde::Serialize;

/// The time after the test's start at which a part that grows with time ([`Role::Thermal`]) is
/// sized: one hour (s), so that its size reads as a rate (mm per hour).
pub const THERMAL_SIZE_AFTER_S: f64 = 3600.0;

impl ErrorTables {
    /// The tool point `tool` (mm, in the frame of the last tool-side axis) relative to the
    /// workpiece at `commands` as a control that applies these tables moves it: each axis'
    /// component errors interpolated linearly between the table's positions (held at the end
    /// value beyond them), the constants as they are, nothing else. The same chain as
    /// [`Model::tool_point`], so at the tables' positions the two agree exactly for every part
    /// the tables carry; what they do not carry is the difference.
    ///
    /// ```
    /// use volver_core::machine::Commands;
    /// use volver_core::model::Model;
    /// use volver_core::tables::ErrorTables;
    /// let model = Model::default_xcfz();
    /// let mut p = model.initial_params();
    /// p[model.param_index("EXX.c1").unwrap()] = 0.01;
    /// let t = ErrorTables::from_model(&model, &p, 100.0, 10.0).unwrap();
    /// let mut c = Commands::default();
    /// c.0[0] = 700.0; // X at a table position
    /// let tool = [0.0, 0.0, -100.0];
    /// let (a, b) = (t.tool_point(&model, &c, &tool).unwrap(), model.tool_point(&c.0, &tool, &p));
    /// assert!((0..3).all(|i| (a[i] - b[i]).abs() < 1e-12));
    /// ```
    ///
    /// # Errors
    /// When a table names an axis or an error the model's machine does not have.
    pub fn tool_point(
        &self,
        model: &Model,
        commands: &Commands,
        tool: &[f64; 3],
    ) -> Result<[f64; 3]> {
        self.tool_point_in(model, commands, tool, Approach::UNKNOWN)
    }

    /// [`ErrorTables::tool_point`] with each axis arriving from the side `approach` gives: a
    /// control applying the forward values to an axis arriving in its positive direction and
    /// the reverse ones to an axis arriving in its negative direction (the mean where the
    /// direction is unknown), as [`Model::tool_point_in`] does.
    ///
    /// # Errors
    /// As [`ErrorTables::tool_point`].
    pub fn tool_point_in(
        &self,
        model: &Model,
        commands: &Commands,
        tool: &[f64; 3],
        approach: Approach,
    ) -> Result<[f64; 3]> {
        let m = model.machine();
        let mut e = PointErrors::<f64>::zero();
        let chain_index = |axis| {
            m.axes()
                .iter()
                .position(|a| a.axis == axis)
                .ok_or_else(|| Error::MachineMismatch {
                    message: format!("the tables name axis {axis}, which the machine lacks"),
                })
        };
        for (name, v) in &self.constants {
            let id: ErrorId = name
                .parse()
                .map_err(|_| Error::UnknownErrorName { name: name.clone() })?;
            let k = chain_index(id.axis())?;
            // The tables hold ISO 230-1's sign; the chain takes the model's.
            e.location[k][id.component().index()] = *v * id.iso_sign();
            e.has_location[k] = true;
        }
        for t in &self.axes {
            let k = chain_index(t.axis)?;
            let at = m.axes()[k].to_file_units(commands.0[k]);
            for (name, values) in &t.errors {
                let id: ErrorId = name
                    .parse()
                    .map_err(|_| Error::UnknownErrorName { name: name.clone() })?;
                e.component[k][id.component().index()] = interpolate(&t.positions, values, at);
            }
            if let Some(b) = &t.reversal {
                let half = 0.5 * approach.sign(k) * interpolate(&t.positions, b, at);
                e.component[k][t.axis.index()] += half;
            }
        }
        Ok(tool_in_workpiece(m, &commands.0, tool, &e))
    }
}

/// Linear interpolation of `values` over increasing `positions` at `at`, the end values beyond.
pub(super) fn interpolate(positions: &[f64], values: &[f64], at: f64) -> f64 {
    let n = positions.len().min(values.len());
    if n == 0 {
        return 0.0;
    }
    if at <= positions[0] {
        return values[0];
    }
    if at >= positions[n - 1] {
        return values[n - 1];
    }
    let i = positions[..n].partition_point(|p| *p <= at).max(1);
    let (x0, x1) = (positions[i - 1], positions[i]);
    let w = (at - x0) / (x1 - x0);
    values[i - 1] + w * (values[i] - values[i - 1])
}

/// A part of a model that per-axis tables cannot carry, with the error it leaves.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[non_exhaustive]
pub struct Uncarried {
    /// The part, as [`Model::part_name`] names it (`field X*Z`, `thermal scale of X` …).
    pub name: String,
    /// What it is ([`Role::Field`] or [`Role::Thermal`]; [`Role::Geometry`] for a reversal in
    /// a format without a direction, [`super::uncarried_in`]).
    pub role: Role,
    /// Its parameters' names.
    pub parameters: Vec<String>,
    /// The largest displacement of the tool point it makes over the commands judged (mm): at
    /// the test's start for a field, [`THERMAL_SIZE_AFTER_S`] after it for a thermal part.
    pub largest_mm: f64,
    /// Index of the command where it is largest.
    pub at: usize,
}

/// Every machine part of `model` at `params` that per-axis tables cannot carry ([`Role::Field`],
/// [`Role::Thermal`]; a reversal is carried, by the forward and reverse values of
/// [`ErrorTables`] and the plain CSV: [`super::uncarried_in`] lists it for the formats without
/// a direction), each with the largest displacement of the tool point `tool` it makes
/// over `commands`: the tool point with the part against the tool point with its parameters at
/// zero, every other parameter as it is (computed through [`Model::tool_point`]'s chain, not
/// estimated from the coefficients). Parts of the measurement ([`Role::Measurement`]) are not
/// the machine's and are not listed; parts whose parameters are all zero are.
///
/// ```
/// use volver_core::machine::{Commands, Machine};
/// use volver_core::model::Model;
/// use volver_core::tables::uncarried;
/// let text = format!("{}\n[effects]\nfield = [\"X*Z\"]\n", volver_core::model::DEFAULT_MODEL_TOML);
/// let model = Model::from_toml_str(Machine::default_xcfz(), &text, "m.toml").unwrap();
/// let mut p = model.initial_params();
/// p[model.param_index("field.X*Z.z_1_1").unwrap()] = 0.004; // 4 µm × P₁(x)P₁(z)
/// let mut corner = Commands::default();
/// corner.0[0] = 1400.0; // X at the end of its travel, Z at its start: P₁P₁ = −1
/// let u = uncarried(&model, &p, &[0.0, 0.0, -100.0], &[Commands::default(), corner]);
/// assert_eq!(u.len(), 1);
/// assert_eq!(u[0].name, "field X*Z");
/// assert!((u[0].largest_mm - 0.004).abs() < 1e-12);
/// ```
pub fn uncarried(
    model: &Model,
    params: &[f64],
    tool: &[f64; 3],
    commands: &[Commands],
) -> Vec<Uncarried> {
    let mut parts: Vec<(String, Role, Vec<usize>)> = Vec::new();
    for j in 0..model.n_params() {
        let role = model.role(j);
        if !matches!(role, Role::Field | Role::Thermal) {
            continue;
        }
        let name = model.part_name(j);
        match parts.iter_mut().find(|p| p.0 == name) {
            Some(p) => p.2.push(j),
            None => parts.push((name, role, vec![j])),
        }
    }
    parts
        .into_iter()
        .map(|(name, role, js)| {
            let mut without = params.to_vec();
            for &j in &js {
                without[j] = 0.0;
            }
            let t_s = if role == Role::Thermal {
                THERMAL_SIZE_AFTER_S
            } else {
                0.0
            };
            let (largest_mm, at) = commands
                .iter()
                .enumerate()
                .map(|(i, c)| {
                    let a = model.tool_point_at(&c.0, tool, t_s, params);
                    let b = model.tool_point_at(&c.0, tool, t_s, &without);
                    let d = (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt();
                    (d, i)
                })
                .fold((0.0, 0), |a, b| if b.0 > a.0 { b } else { a });
            Uncarried {
                name,
                role,
                parameters: js.iter().map(|&j| model.params()[j].name.clone()).collect(),
                largest_mm,
                at,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::interpolate;

    #[test]
    fn interpolation_is_linear_and_held_beyond_the_ends() {
        let (p, v) = ([0.0, 10.0, 30.0], [1.0, 3.0, -1.0]);
        assert_eq!(interpolate(&p, &v, -5.0), 1.0);
        assert_eq!(interpolate(&p, &v, 0.0), 1.0);
        assert_eq!(interpolate(&p, &v, 5.0), 2.0);
        assert_eq!(interpolate(&p, &v, 10.0), 3.0);
        assert_eq!(interpolate(&p, &v, 20.0), 1.0);
        assert_eq!(interpolate(&p, &v, 30.0), -1.0);
        assert_eq!(interpolate(&p, &v, 99.0), -1.0);
    }
}
