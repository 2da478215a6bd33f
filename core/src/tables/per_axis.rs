//! Per-axis compensation tables: what a control without volumetric compensation can apply.
//!
//! Most controls offer only per-axis tables: **leadscrew** tables (LinuxCNC's per-joint
//! `COMP_FILE`, Siemens' `$AA_ENC_COMP`) add a function of an axis' own position to its command,
//! and **cross-axis** tables (Siemens' sag/cross-axis compensation `$AN_CEC`) add a function of
//! one axis' position (the input) to another axis' command (the output). A volumetric error is a
//! function of every axis at once; the per-axis tables that best cancel it over the travel are a
//! least-squares projection, and what they leave is stated beside them.
//!
//! **Sign convention: corrections.** Every value of an [`AxisCorrection`] is what the control
//! adds to the output axis' command (output axis' file units: mm, or degrees for a rotary axis),
//! so that the tool lands where the nominal machine would put it. The writers turn these into
//! each format's own convention and say so where the format allows a comment.

use crate::iso::Axis;
use crate::machine::Commands;

/// One per-axis table: a correction of the `output` axis' command as a function of the `input`
/// axis' position, interpolated linearly between `positions` and held at the end values beyond
/// them (as LinuxCNC and Siemens apply their tables).
#[derive(Clone, Debug, PartialEq)]
pub struct AxisCorrection {
    /// The axis whose position is the table's argument.
    pub input: Axis,
    /// The axis whose command the values correct (the input itself for a leadscrew table).
    pub output: Axis,
    /// The input axis' positions (file units: mm, degrees for a rotary axis), strictly
    /// ascending and equally spaced.
    pub positions: Vec<f64>,
    /// The correction added to the output axis' command at each position when the output axis
    /// arrives in its positive direction (its command increasing); output axis' file units.
    pub forward: Vec<f64>,
    /// The same when the output axis arrives in its negative direction; equal to `forward`
    /// unless the table is the leadscrew table of an axis with a reversal.
    pub reverse: Vec<f64>,
}

impl AxisCorrection {
    /// Whether the table corrects its own axis (a leadscrew table).
    pub fn is_leadscrew(&self) -> bool {
        self.input == self.output
    }

    /// Whether forward and reverse values differ anywhere.
    pub fn is_directional(&self) -> bool {
        self.forward != self.reverse
    }
}

/// Which tables a control offers, and so which the projection may use.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Family {
    /// Leadscrew tables only: each axis corrected as a function of its own position
    /// (LinuxCNC's `COMP_FILE`, Siemens' `$AA_ENC_COMP`).
    Leadscrew,
    /// Leadscrew and cross-axis tables: any axis' command as a function of any one axis'
    /// position (Siemens' `$AA_ENC_COMP` with `$AN_CEC`).
    CrossAxis,
}

/// What the projection is asked for.
#[derive(Clone, Debug, PartialEq)]
pub struct Request {
    /// Which tables the control offers.
    pub family: Family,
    /// The tool points the tables serve (mm, frame of the last tool-side axis): one, or
    /// several spanning a range of tool lengths; the least squares weighs them equally.
    pub tools: Vec<[f64; 3]>,
    /// Spacing of the tables' positions over a linear axis (mm).
    pub linear_step: f64,
    /// Spacing of the tables' positions over a rotary axis (degrees).
    pub rotary_step: f64,
}

/// Per-axis tables found by the projection.
#[derive(Clone, Debug, PartialEq)]
pub struct PerAxisTables {
    /// Which tables the control offers.
    pub family: Family,
    /// The tool points the tables serve (mm, frame of the last tool-side axis).
    pub tools: Vec<[f64; 3]>,
    /// The tables, leadscrew tables first in chain order, then cross-axis tables by output
    /// then input axis in chain order; a table whose values are all zero is left out.
    pub tables: Vec<AxisCorrection>,
}

/// The tool point's error over a set of commands: its mean module (EMM) and largest module
/// (EMax), mm, and where the largest is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ErrorSize {
    /// Mean module of the tool point's error over the commands (mm).
    pub emm_mm: f64,
    /// Largest module (mm).
    pub emax_mm: f64,
    /// The commands (machine units: mm, rad) at which the largest is.
    pub emax_at: Commands,
}

impl ErrorSize {
    /// The size of `errors` — each the index in `grid` of its command and the error vector
    /// (mm) — and where the largest is (the first of equal ones; zeros at `grid[0]` when there
    /// is none).
    pub fn of(grid: &[Commands], errors: impl IntoIterator<Item = (usize, [f64; 3])>) -> ErrorSize {
        let (mut sum, mut count, mut largest) = (0.0, 0usize, (0.0, 0));
        for (command, d) in errors {
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            sum += n;
            count += 1;
            if n > largest.0 {
                largest = (n, command);
            }
        }
        ErrorSize {
            emm_mm: sum / count.max(1) as f64,
            emax_mm: largest.0,
            emax_at: grid.get(largest.1).copied().unwrap_or_default(),
        }
    }
}

// The projection of a model's error on these tables and what they leave (issue 47, item 2).
mod fit;
mod leftover;
pub use fit::{
    GAUSS_NEWTON_PASSES, MAX_UNKNOWNS, RIDGE, SAMPLE_BUDGET, ZERO_VALUE, fit, fit_tables,
};
pub use leftover::{
    EVALUATION_BUDGET, EVALUATION_POSITIONS, Leftover, LeftoverPoint, evaluation_grid, leftover,
};
