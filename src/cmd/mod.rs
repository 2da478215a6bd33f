//! The subcommands: each file parses its arguments, calls the library and prints.

pub mod compare;
pub mod compensate;
pub mod demo;
pub mod diagnose;
pub mod history;
pub mod identify;
pub mod layout;
pub mod plan;
pub mod report;
pub mod simulate;
pub mod study;
pub mod tables;
pub mod uncertainty;

use anyhow::Result;
use std::path::PathBuf;
use volver::core::machine::Machine;
use volver::core::measure::MeasurementSet;
use volver::core::model::Model;
use volver::solvers::{Iteration, Observer};

/// The machine, error model and measurements that `identify` and `diagnose` read.
#[derive(clap::Args)]
pub struct Inputs {
    /// Machine file (TOML) or an embedded machine's name (`volver layout --list`); the embedded
    /// XCFZ grinder when absent.
    #[arg(long)]
    pub machine: Option<PathBuf>,
    /// Error model (TOML); the embedded machine's default model when absent (the paper's on the
    /// XCFZ grinder).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Measurement file (CSV), or a tracker software's export with `--import`.
    #[arg(long)]
    pub data: PathBuf,
    /// Import profile (TOML): read `--data` as a tracker software's export (its columns,
    /// units, and the point names that give the axis positions and the reflector; see
    /// `volver_core::import`).
    #[arg(long, value_name = "PROFILE")]
    pub import: Option<PathBuf>,
    /// The plan file the data were taken by (CSV, as `volver plan` writes it): each
    /// measurement's direction of approach (for a reversal) from the plan — the directions a
    /// bidirectional plan states, else its order — instead of the data's own order; the rows
    /// must be the plan's in its order (once per station), and `approach_<AXIS>` columns of the
    /// measurement file win (a contradiction is refused).
    #[arg(long, value_name = "PLAN")]
    pub plan_file: Option<PathBuf>,
}

impl Inputs {
    /// The input files given, with `more`.
    pub fn paths<'a>(&'a self, more: &[Option<&'a std::path::Path>]) -> Vec<&'a std::path::Path> {
        [
            self.machine.as_deref(),
            self.model.as_deref(),
            Some(self.data.as_path()),
            self.import.as_deref(),
            self.plan_file.as_deref(),
        ]
        .into_iter()
        .chain(more.iter().copied())
        .flatten()
        .collect()
    }

    /// Reads the three files.
    pub fn load(&self) -> Result<(Machine, Model, MeasurementSet)> {
        Ok(volver::inputs::load_taken_by(
            self.machine.as_deref(),
            self.model.as_deref(),
            &self.data,
            self.import.as_deref(),
            self.plan_file.as_deref(),
        )?)
    }
}

/// Prints one line per accepted step to stderr.
pub struct Progress {
    pub quiet: bool,
    /// The engine is given whitened residuals (objectives ml, phi-w): its "EMM" is their mean
    /// module, in units of the noise.
    pub whitened: bool,
}

impl Observer for Progress {
    fn iteration(&mut self, it: &Iteration) {
        if !self.quiet && it.accepted && self.whitened {
            eprintln!(
                "  iteration {:>4}  evaluations {:>5}  mean whitened module {:>10.6}  λ {:.1e}",
                it.iteration,
                it.evaluations,
                it.emm_um / volver::core::units::UM_PER_MM,
                it.damping
            );
        } else if !self.quiet && it.accepted {
            eprintln!(
                "  iteration {:>4}  evaluations {:>5}  EMM {:>12.6} µm  λ {:.1e}",
                it.iteration, it.evaluations, it.emm_um, it.damping
            );
        }
    }
}

/// Every estimator's expected tool-point error `e` beside the Cramér–Rao limit, the one
/// `fitted` marked.
pub fn print_efficiency(
    e: &volver::uncertainty::EfficiencyU,
    fitted: Option<volver::solvers::Objective>,
) {
    println!(
        "\n  estimators on this plan and noise: expected RMS tool-point error over the grid (3-D, \
         after the set-up's transform, k = 1)"
    );
    let (limit, ml) = if e.normal {
        (
            "Cramér–Rao limit (of unbiased estimators)",
            "ml (maximum likelihood)",
        )
    } else {
        (
            "Gauss–Markov limit (bounded noise: of linear ones)",
            "ml (noise-weighted least squares)",
        )
    };
    println!("    {limit:<50} {:>9.3} µm", e.cramer_rao_um);
    for (name, v) in &e.estimators {
        let what = match name.as_str() {
            "phi" => "phi (the paper's Φ)",
            "ve" => "ve (least squares)",
            "ml" => ml,
            "phi-w" => "phi-w (Φ of whitened residuals)",
            other => other,
        };
        let mark = match fitted {
            Some(o) if o.to_string() == *name => "  ← fitted",
            _ => "",
        };
        println!(
            "    {what:<50} {v:>9.3} µm  {:>5.2} × the limit{mark}",
            v / e.cramer_rao_um
        );
    }
}

/// A length in µm for tables: fixed-point, or scientific when below 0.01 µm.
pub fn um(v: f64) -> String {
    if v != 0.0 && v.abs() < 0.01 {
        format!("{v:.3e}")
    } else {
        format!("{v:.4}")
    }
}

/// Prints the findings of [`volver::solvers::observability::observe`], or that there are none.
pub fn print_observability(findings: &[volver::solvers::observability::Finding]) {
    if findings.is_empty() {
        println!("  everything the model describes can be identified from these positions");
    }
    for f in findings {
        println!("  - {}\n      fix: {}", f.what, f.fix);
    }
}
