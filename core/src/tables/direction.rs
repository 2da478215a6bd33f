//! The tables' two directions of approach: an axis' positioning error on forward and reverse
//! approach ([`Directional`]), the formats that carry them ([`TableFormat`]) and what the
//! others leave ([`uncarried_in`]).

use super::carry::interpolate;
use super::{ErrorTables, Uncarried, uncarried};
use crate::approach::Approach;
use crate::iso::Axis;
use crate::machine::Commands;
use crate::model::{Model, PointState, Role};
use crate::units::{UM_PER_MM, URAD_PER_RAD};

/// An axis' positioning error at one position on forward and reverse approach (mm, or rad for a
/// rotary axis), as the tables hold errors: the deviation of the axis' slide from its nominal
/// position in the machine frame (ISO 230-1, the forward model's convention), arriving with its
/// command increasing (`forward`, `E↑`) or decreasing (`reverse`, `E↓`). Errors, not
/// corrections.
///
/// In ISO 230-2's terms — the mean positional deviations `x̄↑`, `x̄↓` of the tool relative to the
/// workpiece along the axis' command — these are the same numbers on an axis that moves the
/// tool and their negatives on an axis that moves the workpiece ([`Directional::deviations`]),
/// so ISO 230-2's reversal value `B = x̄↑ − x̄↓` is [`Directional::reversal`] there with the
/// side's sign (negative: lost motion, the axis stops short of its target on the side it comes
/// from).
///
/// ```
/// use volver_core::chain::Side;
/// use volver_core::tables::Directional;
/// let d = Directional { forward: 0.004, reverse: -0.011 };
/// assert!((d.reversal() - 0.015).abs() < 1e-15); // E↑ − E↓: the slide's reversal
/// assert!((d.mean() + 0.0035).abs() < 1e-15);
/// // An axis that moves the workpiece: the tool lands 4 µm short arriving forward, 11 µm
/// // beyond in reverse (ISO 230-2 B = −15 µm); its command takes +4 µm and −11 µm.
/// assert_eq!(d.deviations(Side::Workpiece), Directional { forward: -0.004, reverse: 0.011 });
/// assert_eq!(d.corrections(Side::Workpiece), d);
/// assert_eq!(d.corrections(Side::Tool), Directional { forward: -0.004, reverse: 0.011 });
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Directional {
    /// The error on forward approach, `E + B/2`.
    pub forward: f64,
    /// The error on reverse approach, `E − B/2`.
    pub reverse: f64,
}

impl Directional {
    /// The reversal of the axis' own error `E↑ − E↓`: ISO 230-2's B (the model's
    /// `reversal.X.b`) on an axis that moves the tool, its negative on one that moves the
    /// workpiece.
    pub fn reversal(&self) -> f64 {
        self.forward - self.reverse
    }

    /// The mean of both directions: the value the formats without a direction hold.
    pub fn mean(&self) -> f64 {
        0.5 * (self.forward + self.reverse)
    }

    /// ISO 230-2's mean positional deviations `x̄↑`, `x̄↓` on an axis of `side`: the tool
    /// relative to the workpiece along the axis' command, less its target. The errors
    /// themselves on an axis that moves the tool, their negatives on one that moves the
    /// workpiece ([`crate::chain::Side::sign`]).
    pub fn deviations(&self, side: crate::chain::Side) -> Directional {
        let s = side.sign();
        Directional {
            forward: s * self.forward,
            reverse: s * self.reverse,
        }
    }

    /// What a control adds to the command of an axis of `side` in each direction so that it
    /// lands on its target: the deviations' negatives (for the axis' own positioning error;
    /// what the other axes' errors need is the volumetric compensation's).
    pub fn corrections(&self, side: crate::chain::Side) -> Directional {
        let d = self.deviations(side);
        Directional {
            forward: -d.forward,
            reverse: -d.reverse,
        }
    }
}

/// A format the tables are written in, by whether it carries the direction of approach.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum TableFormat {
    /// The plain CSV, with its `forward` and `reverse` columns.
    PlainCsv,
    /// ISG CSV: one value per position, no direction.
    Isg,
    /// The Etalon exchange style: one value per position, no direction.
    Etalon,
}

impl TableFormat {
    /// Whether the format carries an error's forward and reverse values (and so a reversal).
    pub fn carries_direction(self) -> bool {
        matches!(self, TableFormat::PlainCsv)
    }
}

impl ErrorTables {
    /// Axis `axis`'s positioning error (EXX for X, ECC for C) at `position` (file units: mm, or
    /// degrees for a rotary axis) on forward and reverse approach, interpolated linearly
    /// between the table's positions as a control does (held at the end values beyond them):
    /// what a two-column compensation table (LinuxCNC's `nominal forward reverse`, Siemens'
    /// direction-dependent tables) takes, through [`Directional::corrections`] with the axis'
    /// side ([`crate::machine::MachineAxis::side`]) for the control's sign. Both are the mean
    /// when the axis has no reversal. `None` when the tables have no table of the axis (no
    /// modelled error of it: zero both ways).
    ///
    /// ```
    /// use volver_core::iso::Axis;
    /// use volver_core::machine::Machine;
    /// use volver_core::model::Model;
    /// use volver_core::tables::ErrorTables;
    /// let text = "[[error]]\nname = \"EXX\"\nbasis = \"legendre\"\ndegree = 1\n\n[effects]\nreversal = [\"X\"]";
    /// let model = Model::from_toml_str(Machine::default_xcfz(), text, "m.toml").unwrap();
    /// let mut p = model.initial_params();
    /// p[model.param_index("EXX.c1").unwrap()] = 0.010;
    /// // X carries the workpiece: a lost motion of 15 µm (ISO 230-2 B = −15 µm, the model's
    /// // reversal.X.b) is a slide B of +15 µm.
    /// p[model.param_index("reversal.X.b").unwrap()] = -0.015;
    /// let t = ErrorTables::from_model(&model, &p, 100.0, 10.0).unwrap();
    /// let d = t.directional(Axis::X, 700.0).unwrap();
    /// assert!((d.reversal() - 0.015).abs() < 1e-15);
    /// assert!((d.forward - (d.mean() + 0.0075)).abs() < 1e-15);
    /// let side = Machine::default_xcfz().axes()[0].side;
    /// assert!((d.deviations(side).reversal() + 0.015).abs() < 1e-15);
    /// assert!(t.directional(Axis::Y, 0.0).is_none());
    /// ```
    pub fn directional(&self, axis: Axis, position: f64) -> Option<Directional> {
        let t = self.axes.iter().find(|t| t.axis == axis)?;
        let name = t.positioning();
        let mean = t
            .errors
            .iter()
            .find(|e| e.0 == name)
            .map_or(0.0, |e| interpolate(&t.positions, &e.1, position));
        let b = t
            .reversal
            .as_ref()
            .map_or(0.0, |b| interpolate(&t.positions, b, position));
        Some(Directional {
            forward: mean + 0.5 * b,
            reverse: mean - 0.5 * b,
        })
    }

    /// [`ErrorTables::directional`] at each of the table's positions: `(position, values)`,
    /// positions in file units (mm, degrees), increasing.
    pub fn directional_rows(&self, axis: Axis) -> Option<Vec<(f64, Directional)>> {
        let t = self.axes.iter().find(|t| t.axis == axis)?;
        t.positions
            .iter()
            .map(|&p| self.directional(axis, p).map(|d| (p, d)))
            .collect()
    }

    /// The comment lines a format without a direction starts with when the tables carry a
    /// reversal: which axes, how large, and that their values are the mean of both directions.
    pub(super) fn no_direction_note(&self) -> String {
        let parts: Vec<String> = self
            .axes
            .iter()
            .filter_map(|t| {
                let b = t.reversal.as_ref()?;
                let largest = b.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
                let (scale, unit) = if t.axis.is_rotary() {
                    (URAD_PER_RAD, "µrad")
                } else {
                    (UM_PER_MM, "µm")
                };
                Some(format!(
                    "{} (ISO 230-2 B up to {:.3} {unit} in magnitude)",
                    t.axis,
                    largest * scale
                ))
            })
            .collect();
        if parts.is_empty() {
            return String::new();
        }
        format!(
            "// the reversal of {} is NOT carried: this format has no direction of approach, \
             each error is the mean of both directions (the plain CSV carries forward and \
             reverse values)\n",
            parts.join(", ")
        )
    }
}

/// The reversal of chain axis `k`'s own positioning error at `commands` (mm or rad): its error
/// on forward approach less the one on reverse approach, `σ·B` ([`Model::reversal_at`]'s ISO
/// 230-2 B times the axis' side sign).
pub(super) fn reversal_at(model: &Model, params: &[f64], commands: &Commands, k: usize) -> f64 {
    let sigma = model.machine().axes()[k].side.sign();
    sigma
        * model
            .reversal_at(k, commands.0[k], params, None)
            .unwrap_or(0.0)
}

/// [`uncarried`] for tables written in `format`: the parts no per-axis table carries, and for a
/// format without a direction ([`TableFormat::carries_direction`]) each axis' reversal too
/// ([`Role::Geometry`], named `reversal of X`), sized as the largest displacement of the tool
/// point `tool` between the axis arriving forward and the mean of both directions (every other
/// axis' direction unknown) over `commands`: half its B, carried into the tool point.
///
/// ```
/// use volver_core::machine::{Commands, Machine};
/// use volver_core::model::Model;
/// use volver_core::tables::{TableFormat, uncarried_in};
/// let model = Model::from_toml_str(Machine::default_xcfz(), "[effects]\nreversal = [\"X\"]", "m.toml").unwrap();
/// let mut p = model.initial_params();
/// p[model.param_index("reversal.X.b").unwrap()] = 0.016;
/// let grid = [Commands::default()];
/// assert!(uncarried_in(TableFormat::PlainCsv, &model, &p, &[0.0; 3], &grid).is_empty());
/// let isg = uncarried_in(TableFormat::Isg, &model, &p, &[0.0; 3], &grid);
/// assert_eq!(isg[0].name, "reversal of X");
/// assert!((isg[0].largest_mm - 0.008).abs() < 1e-12);
/// ```
pub fn uncarried_in(
    format: TableFormat,
    model: &Model,
    params: &[f64],
    tool: &[f64; 3],
    commands: &[Commands],
) -> Vec<Uncarried> {
    let mut out = uncarried(model, params, tool, commands);
    if format.carries_direction() {
        return out;
    }
    let m = model.machine();
    for k in crate::compensate::reversal_axes(model) {
        let prefix = format!("reversal.{}.", m.axes()[k].axis.letter());
        let js: Vec<usize> = (0..model.n_params())
            .filter(|&j| model.params()[j].name.starts_with(&prefix))
            .collect();
        let Some(&first) = js.first() else { continue };
        let mut forward = Approach::UNKNOWN;
        forward.0[k] = 1;
        let state = PointState {
            t_s: 0.0,
            approach: forward,
        };
        let (largest_mm, at) = commands
            .iter()
            .enumerate()
            .map(|(i, c)| {
                let a = model.tool_point_in(&c.0, tool, state, params);
                let b = model.tool_point(&c.0, tool, params);
                let d = (0..3).map(|q| (a[q] - b[q]).powi(2)).sum::<f64>().sqrt();
                (d, i)
            })
            .fold((0.0, 0), |a, b| if b.0 > a.0 { b } else { a });
        out.push(Uncarried {
            name: model.part_name(first),
            role: Role::Geometry,
            parameters: js.iter().map(|&j| model.params()[j].name.clone()).collect(),
            largest_mm,
            at,
        });
    }
    out
}
