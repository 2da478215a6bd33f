//! The U gate: what vouches for identified errors before they reach a machine (`volver
//! compensate` and `volver tables` apply it; a library user applies the same).

use super::{ToolPointU, point_mm, tool_point_u};
use crate::error::{Error, Result};
use serde::Serialize;
use volver_core::model::Model;
use volver_core::results::UncertaintyRecord;
use volver_core::units::UM_PER_MM;

/// One statement of the gate, in the order it is made.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[non_exhaustive]
pub enum Statement {
    /// Something to state (the fit's check, the U reached).
    Note(String),
    /// A reason the errors must not reach a machine: refused unless the user overrides it
    /// (`--force`), then stated as a warning.
    Refusal {
        /// What is wrong.
        reason: String,
        /// What overriding does (`--force uses the errors anyway`).
        override_text: String,
    },
}

/// What the gate found for one tool point.
#[derive(Clone, Debug, Serialize)]
#[non_exhaustive]
pub struct Vouch {
    /// The statements, in order.
    pub statements: Vec<Statement>,
    /// The tool point's U over the travel, when the results record an uncertainty.
    pub u: Option<ToolPointU>,
}

impl Vouch {
    /// The first refusal as an [`Error::Refused`] (its reason and what overriding does), or
    /// `Ok` when nothing refuses the errors.
    pub fn enforce(&self) -> Result<()> {
        match self.statements.iter().find_map(|s| match s {
            Statement::Refusal {
                reason,
                override_text,
            } => Some(format!("{reason}; {override_text}")),
            Statement::Note(_) => None,
        }) {
            Some(text) => Err(Error::Refused(text)),
            None => Ok(()),
        }
    }
}

/// The U gate for the compensated tool point `tool` of `model` at `params` with the results'
/// uncertainty `record`: the U (k = 2) over the machine's travel (5 positions per axis) after
/// the set-up's rigid transform and raw, with its gauge and noise; refused when the former
/// exceeds `max_u_um`, with the held combination that makes it and the measurement that would
/// identify it; refused as well when the record says the fit was above the noise, where no
/// interval holds, or when there is no record (a simulation's truth, a file edited by hand):
/// nothing then vouches for the errors. The U is not computed without a record. An error, not a
/// refusal: a `max_u_um` that is not a positive length, parameters that are not the model's, a
/// tool point or a U that is not finite, a record of another model.
///
/// ```
/// use volver::compensation::{Statement, vouch};
/// let model = volver::core::model::Model::default_xcfz();
/// let v = vouch(&model, &model.initial_params(), None, [0.0; 3], 50.0)?;
/// assert!(matches!(v.statements[0], Statement::Refusal { .. }));
/// assert!(v.enforce().is_err());
/// # Ok::<(), volver::Error>(())
/// ```
pub fn vouch(
    model: &Model,
    params: &[f64],
    record: Option<&UncertaintyRecord>,
    tool: [f64; 3],
    max_u_um: f64,
) -> Result<Vouch> {
    super::check_max_u(max_u_um)?;
    let mut statements = Vec::new();
    let Some(record) = record else {
        statements.push(Statement::Refusal {
            reason: "U unknown: the results file records no uncertainty (`volver identify \
                     --out`, `report` and `diagnose --out` write it; a simulation's truth has \
                     none), so nothing vouches for these errors"
                .into(),
            override_text: "--force uses them anyway".into(),
        });
        return Ok(Vouch {
            statements,
            u: None,
        });
    };
    let refusal = |reason: String| Statement::Refusal {
        reason,
        override_text: "--force uses the errors anyway".into(),
    };
    statements.push(match record.model_check.as_ref() {
        Some(check) if check.above_noise => {
            refusal(format!("U is not valid here: {}", check.statement()))
        }
        Some(check) => Statement::Note(format!("model check: {}", check.statement())),
        None => Statement::Note(
            "model check: the results file does not say whether the fit was at the noise (it \
             predates the check); the U below assumes a complete model"
                .into(),
        ),
    });
    let u = tool_point_u(model, params, record, tool)?;
    statements.push(Statement::Note(format!(
        "U (k = 2) of the compensated tool point {} mm over the travel: up to {:.2} µm after the \
         set-up's rigid transform, {:.2} µm raw in the workpiece frame (gauge: {}; noise: {}, \
         as the fit recorded it)",
        point_mm(tool),
        u.aligned_mm * UM_PER_MM,
        u.raw_mm * UM_PER_MM,
        u.gauge,
        record.noise
    )));
    if u.aligned_mm * UM_PER_MM > max_u_um {
        statements.push(refusal(format!(
            "U of the compensated tool point reaches {:.1} µm (limit --max-u-um {max_u_um}): {}",
            u.aligned_mm * UM_PER_MM,
            u.why
        )));
    }
    Ok(Vouch {
        statements,
        u: Some(u),
    })
}
