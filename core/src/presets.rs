//! The embedded machines: the paper's XCFZ grinder and one five-axis machine of each classic
//! family, each with its default error model and a preset plan that identifies it.
//!
//! | name | chain | family |
//! |---|---|---|
//! | `xcfz` | `XCFZ` | the paper's grinder (the default machine) |
//! | `table-table` | `ACFXYZ` | trunnion A carrying a rotary table C; X, Y, Z move the spindle |
//! | `head-head` | `FXYZCA` | gantry over a fixed table; fork head C (about z) carrying A (about x) |
//! | `head-table` | `CFXYZB` | rotary table C; swivel head B (about y) moved in X, Y, Z |
//!
//! The five-axis presets carry their tracker on the workpiece side (on the rotary table where
//! there is one) and three reflectors on the spindle, off one line. Their default models hold
//! every ISO 230-1 error of the five axes — the rotary axes' location errors among them — with
//! the coefficients the data cannot tell from the others held at zero (see each model file's
//! header, and [`crate::plan::Plan::parse_grid`] for the plans' `;`-joined grids).
//!
//! ```
//! use volver_core::presets;
//! let p = presets::named("head-table").unwrap();
//! let model = p.model().unwrap();
//! assert_eq!(model.machine().chain().to_string(), "CFXYZB");
//! let plan = p.plan().unwrap();
//! assert_eq!(plan.n_points(), 3 * plan.positions.len());
//! assert!(presets::named("five-axis").is_none());
//! ```

use crate::error::Result;
use crate::machine::Machine;
use crate::model::{ErrorModelSpec, Model};
use crate::plan::Plan;

/// One embedded machine with its default model and plan.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Preset {
    /// The name `--machine` takes.
    pub name: &'static str,
    /// One line on what it is.
    pub description: &'static str,
    /// The machine file (TOML).
    pub machine_toml: &'static str,
    /// The default error model (TOML).
    pub model_toml: &'static str,
    /// The preset plan: a preset name of [`Plan::preset`] or grids for [`Plan::parse_grid`].
    pub plan: &'static str,
    /// The effect the demo hides in its data on this machine (`volver simulate --effect`).
    pub demo_effect: &'static str,
}

/// Every embedded machine, the default (`xcfz`) first.
pub const PRESETS: [Preset; 4] = [
    Preset {
        name: "xcfz",
        description: "the paper's XCFZ grinder: X carrying the turntable C, Z carrying the tool",
        machine_toml: crate::machine::DEFAULT_MACHINE_TOML,
        model_toml: crate::model::DEFAULT_MODEL_TOML,
        plan: "test4",
        demo_effect: "rotary-harmonics=2,10,20",
    },
    Preset {
        name: "table-table",
        description: "five-axis, trunnion A carrying a rotary table C; X, Y, Z move the spindle",
        machine_toml: include_str!("../data/machines/table-table.toml"),
        model_toml: include_str!("../data/machines/table-table-model.toml"),
        plan: "X=-300:300:150,Y=-300:300:150,Z=0:400:100,A=0,C=0; \
               X=0,Y=0,Z=200,A=-110:110:27.5,C=0:330:30; \
               X=-300:300:600,Y=-300:300:600,Z=0:400:400,A=-110:110:55,C=0:270:90",
        demo_effect: "location-drift=A,10,15",
    },
    Preset {
        name: "head-head",
        description: "five-axis, gantry over a fixed table; fork head C (about z) carrying A (about x)",
        machine_toml: include_str!("../data/machines/head-head.toml"),
        model_toml: include_str!("../data/machines/head-head-model.toml"),
        plan: "X=0:2000:500,Y=0:1200:300,Z=0:600:150,C=0,A=0; \
               X=1000,Y=600,Z=300,C=-180:150:30,A=-100:100:25; \
               X=0:2000:2000,Y=0:1200:1200,Z=0:600:600,C=-180:90:90,A=-100:100:50",
        demo_effect: "location-drift=A,20,30",
    },
    Preset {
        name: "head-table",
        description: "five-axis, rotary table C; swivel head B (about y) moved in X, Y, Z",
        machine_toml: include_str!("../data/machines/head-table.toml"),
        model_toml: include_str!("../data/machines/head-table-model.toml"),
        plan: "X=-350:350:175,Y=-300:300:150,Z=0:450:112.5,C=0,B=0; \
               X=0,Y=0,Z=225,C=0:330:30,B=-120:30:18.75; \
               X=-350:350:700,Y=-300:300:600,Z=0:450:450,C=0:270:90,B=-120:30:37.5",
        demo_effect: "location-drift=B,10,15",
    },
];

/// The names of the embedded machines, as `--machine` takes them.
pub fn names() -> Vec<&'static str> {
    PRESETS.iter().map(|p| p.name).collect()
}

/// The embedded machine named `name` (case-insensitive), if there is one.
pub fn named(name: &str) -> Option<&'static Preset> {
    PRESETS.iter().find(|p| p.name.eq_ignore_ascii_case(name))
}

impl Preset {
    /// The label of its files in messages, e.g. `<embedded head-head machine>`.
    pub fn label(&self) -> String {
        format!("<embedded {} machine>", self.name)
    }

    /// The machine.
    pub fn machine(&self) -> Result<Machine> {
        Machine::from_toml_str(self.machine_toml, &self.label())
    }

    /// The default error model on the machine.
    pub fn model(&self) -> Result<Model> {
        let spec = ErrorModelSpec::from_toml_str(
            self.model_toml,
            &format!("<embedded {} model>", self.name),
        )?;
        Model::new(self.machine()?, spec)
    }

    /// The preset plan on the machine.
    pub fn plan(&self) -> Result<Plan> {
        self.plan_on(&self.machine()?)
    }

    /// The preset plan on `machine` (this machine with stations added, say), named after the
    /// preset.
    pub fn plan_on(&self, machine: &Machine) -> Result<Plan> {
        let mut plan = if self.plan.contains('=') {
            Plan::parse_grid(machine, self.plan)?
        } else {
            Plan::preset(machine, self.plan)?
        };
        plan.name = self.name.to_string();
        Ok(plan)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_preset_builds_with_its_model_and_plan() {
        for p in &PRESETS {
            let model = p.model().unwrap_or_else(|e| panic!("{}: {e}", p.name));
            let plan = p.plan().unwrap_or_else(|e| panic!("{}: {e}", p.name));
            assert!(plan.positions.len() >= 300, "{}", p.name);
            assert_eq!(
                model.machine().axes().len(),
                if p.name == "xcfz" { 3 } else { 5 }
            );
            // Every position inside the travel.
            for q in &plan.positions {
                for (k, a) in model.machine().axes().iter().enumerate() {
                    assert!(
                        q.0[k] >= a.min - 1e-9 && q.0[k] <= a.max + 1e-9,
                        "{}",
                        p.name
                    );
                }
            }
        }
        assert_eq!(named("XCFZ").unwrap().name, "xcfz");
        assert_eq!(
            Model::default_xcfz().n_params(),
            named("xcfz").unwrap().model().unwrap().n_params()
        );
    }
}
