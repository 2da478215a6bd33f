//! `volver identify`: the geometric errors and the tracker pose from measurements.

use super::{Inputs, Progress, print_observability, um};
use anyhow::{Context, Result};
use std::path::PathBuf;
use volver::core::measure::MeasurementSet;
use volver::core::model::Model;
use volver::identification::{Outcome, Settings, identify, noise_error};
use volver::solvers::strategy::Phasing;
use volver::solvers::{Objective, Options};

/// Options of `volver identify`.
#[derive(clap::Args)]
pub struct IdentifyArgs {
    #[command(flatten)]
    inputs: Inputs,
    /// Engine: lm (native Levenberg–Marquardt, always built), lm+clarabel and clarabel (feature
    /// `clarabel`, default), ceres (feature `ceres`), nlopt-lbfgs, nlopt-slsqp, nlopt-mma,
    /// nlopt-bobyqa (feature `nlopt`); `volver compare` runs them all.
    #[arg(long, default_value = "lm")]
    solver: String,
    /// Objective: phi (mean error module, eq. 12), ve (mean squared error, eq. 1), ml (maximum
    /// likelihood: least squares on the residuals whitened by each station's noise, `--noise` or
    /// the machine file's) or phi-w (Φ of the whitened residuals: robust and noise-weighted).
    #[arg(long, default_value = "phi")]
    objective: String,
    /// The tracker's noise for the uncertainty the results file records: paper, none,
    /// normal:AZ_URAD,EL_URAD,RANGE_UM,RANGE_UM_PER_M (σ), uniform:… (bounds) or
    /// mpe:A_UM,B_UM_PER_M (±(a + b·L), k = 2). Default: the machine file's `[tracker] noise`,
    /// else isotropic normal with the residuals' variance; the output says which, and whether
    /// the fit agrees with it.
    #[arg(long)]
    noise: Option<String>,
    /// Prior magnitudes per error kind: `typical` or KIND=VALUE in the kind's unit (the kinds
    /// of `simulate --magnitude`, e.g. straightness=10 µm, angular=20 µrad); repeatable, applied
    /// over the typical ones. With it the result is the maximum a posteriori solution (what the
    /// data do not determine is decided by the priors) instead of the gauge's minimum norm.
    #[arg(long, value_name = "KIND=VALUE")]
    prior: Vec<String>,
    /// Phases: one, two, tr, rt, three-tr, three-rt (table 1 of the paper).
    #[arg(long, default_value = "one")]
    strategy: String,
    /// Sub-loops: how many times the phase sequence may run (fig. 14).
    #[arg(long, default_value_t = 1)]
    subloops: usize,
    /// The true errors (results JSON, e.g. truth.json of `volver simulate`): reports the
    /// noise error, from the simulation.json beside it when there is one (it knows the effects
    /// the results format cannot hold), else the EMM of the measurements against the truth.
    #[arg(long)]
    truth: Option<PathBuf>,
    /// Iteration limit per phase (criterion 3).
    #[arg(long)]
    max_iterations: Option<usize>,
    /// Evaluation limit per phase (criterion 4).
    #[arg(long)]
    max_evaluations: Option<usize>,
    /// Native LM (lm, lm+clarabel): bend each step by geodesic acceleration (for strongly
    /// nonlinear models; one more Jacobian pass per step tried). Sets `[lm]
    /// geodesic_acceleration` over --engine-settings.
    #[arg(long)]
    geodesic_acceleration: bool,
    /// The engines' own settings (TOML, sections [lm], [clarabel], [ceres], [nlopt]; e.g.
    /// `[lm] threads = 2`, `[ceres] linear_solver = "dense-normal-cholesky"`): see the
    /// README's Engines section.
    #[arg(long, value_name = "FILE.toml")]
    engine_settings: Option<PathBuf>,
    /// Extend the model with a candidate of `volver diagnose` before fitting (e.g. add:EAC,
    /// raise-axis:C, tracker-tilt); repeatable, applied in order.
    #[arg(long = "add", value_name = "ID")]
    add: Vec<String>,
    /// Write the error model actually fitted (after --add) as TOML.
    #[arg(long)]
    write_model: Option<PathBuf>,
    /// Write the identified parameters as a results file (JSON).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Append this fit to a history file (default: volver-history.jsonl beside the data).
    #[arg(long)]
    history: Option<PathBuf>,
    /// Do not append this fit to any history file.
    #[arg(long, conflicts_with = "history")]
    no_history: bool,
    /// Keep (and write with --out) a fit that stopped on a limit or whose sizes are
    /// implausible; without it such a run exits non-zero and writes no results.
    #[arg(long)]
    accept: bool,
    /// Print one JSON object instead of the tables.
    #[arg(long)]
    json: bool,
}

/// Runs `volver identify`.
pub fn run(a: IdentifyArgs) -> Result<()> {
    let mut outputs = volver::core::fsio::Outputs::new(a.inputs.paths(&[a.truth.as_deref()]));
    for out in [&a.out, &a.write_model].into_iter().flatten() {
        outputs.claim(out)?;
    }
    if !a.no_history {
        outputs.claim(&history_path(&a))?;
    }
    let (machine, model, data) = a.inputs.load()?;
    let model = volver::inputs::with_candidates(&machine, model, &a.add)?;
    if let Some(path) = &a.write_model {
        let text = toml::to_string(model.spec()).context("writing the error model")?;
        volver::core::fsio::write_atomic(path, text)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    let mut settings = settings(&a)?;
    let (noise_model, noise_used) = volver::inputs::noise_rule(a.noise.as_deref(), &machine)?;
    settings.noise = noise_model;
    let noise = match &a.truth {
        Some(path) => Some(noise_error(path, &machine, &a.inputs.data, &data)?),
        None => None,
    };
    if !a.json {
        announce(&model, &data, &settings)?;
    }
    let mut outcome = identify(
        &model,
        &data,
        &settings,
        &mut Progress {
            quiet: a.json,
            whitened: settings.options.objective.whitened(),
        },
    )?;
    outcome.noise_error = noise;
    if !a.no_history {
        let path = history_path(&a);
        volver::history::append(&path, &history_record(&a, &model, &outcome))?;
    }
    if let Some(out) = &a.out
        && outcome.refusal.is_none()
    {
        outcome
            .results
            .save(out)
            .context("writing the results file")?;
    }
    let noise_used = if outcome.id.termination.failed() {
        noise_used
    } else {
        noise_used.judged(
            noise_model,
            &model,
            &data,
            &outcome.id.params,
            outcome.id.reached.stats.emm_um,
        )
    };
    if a.json {
        let mut value = serde_json::to_value(outcome.report()?)?;
        value["noise_used"] = serde_json::to_value(&noise_used)?;
        println!("{}", serde_json::to_string_pretty(&value)?);
    } else {
        print_outcome(&outcome, a.out.as_deref());
        println!("{}", noise_used.text());
    }
    if let Some(r) = outcome.refusal {
        anyhow::bail!("{r}; no results written");
    }
    Ok(())
}

/// Prints what is fitted, and what these positions can measure with this layout before
/// anything is fitted (the outcome carries the same findings).
fn announce(model: &Model, data: &MeasurementSet, settings: &Settings) -> Result<()> {
    println!(
        "volver identify — {} points, model \"{}\" ({} parameters), solver {}, objective {}, strategy {}",
        data.points.len(),
        model.spec().name,
        model.n_params(),
        volver::solvers::engine(&settings.engine)?.name(),
        settings.options.objective,
        settings.phasing.name()
    );
    let findings = volver::solvers::observability::observe(model, data, &model.initial_params());
    if !findings.is_empty() {
        println!("\nWhat these positions can and cannot measure with this layout:");
        print_observability(&findings);
        println!();
    }
    Ok(())
}

/// The library's settings from the arguments (checked before anything is fitted).
fn settings(a: &IdentifyArgs) -> Result<Settings> {
    let objective: Objective = a.objective.parse()?;
    let mut options = Options {
        objective,
        ..Options::default()
    };
    if let Some(v) = a.max_iterations {
        options.max_iterations = v;
    }
    if let Some(v) = a.max_evaluations {
        options.max_evaluations = v;
    }
    let mut settings = Settings::default();
    settings.engine.clone_from(&a.solver);
    settings.options = options;
    if let Some(path) = &a.engine_settings {
        settings.engines = engine_settings(path)?;
    }
    if a.geodesic_acceleration {
        if !a.solver.starts_with("lm") {
            anyhow::bail!(
                "--geodesic-acceleration is a setting of the native LM (lm, lm+clarabel), not \
                 of {}",
                a.solver
            );
        }
        settings.engines.lm.geodesic_acceleration = true;
    }
    settings.priors = (!a.prior.is_empty())
        .then(|| volver::solvers::prior::Priors::parse(&a.prior))
        .transpose()?;
    settings.phasing = Phasing::parse(&a.strategy)?;
    if a.subloops == 0 {
        anyhow::bail!("--subloops must be at least 1");
    }
    settings.subloops = a.subloops;
    settings.accept = a.accept;
    volver::solvers::engine_with(&settings.engine, &settings.engines)?;
    settings.options.validate()?;
    Ok(settings)
}

/// The engines' settings from a TOML file (`--engine-settings`), validated.
pub(super) fn engine_settings(path: &std::path::Path) -> Result<volver::solvers::Settings> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    volver::solvers::Settings::from_toml_str(&text).with_context(|| format!("{}", path.display()))
}

/// The history file this fit is appended to: `--history`, or the default beside the data.
fn history_path(a: &IdentifyArgs) -> PathBuf {
    a.history
        .clone()
        .unwrap_or_else(|| volver::history::default_path(&a.inputs.data))
}

/// The history line of this fit.
fn history_record(
    a: &IdentifyArgs,
    model: &volver::core::model::Model,
    outcome: &Outcome,
) -> volver::history::Record {
    let id = &outcome.id;
    volver::history::Record {
        data: a.inputs.data.display().to_string(),
        model: model.spec().name.clone(),
        added: a.add.clone(),
        parameters: model.n_params(),
        free: id.phases.last().map_or(0, |s| s.free_parameters),
        emm_initial_um: id.initial.stats.emm_um,
        emm_final_um: id.reached.stats.emm_um,
        emax_final_um: id.reached.stats.emax_um,
        phi_mm: id.reached.phi_mm,
        noise_error_um: outcome.noise_error.map(|s| s.emm_um),
        termination: id.termination.to_string(),
    }
}

/// The summary table of an identification.
fn print_outcome(outcome: &Outcome, out: Option<&std::path::Path>) {
    let id = &outcome.id;
    println!(
        "\n  {:<32} {:>12} {:>12} {:>10} {:>6} {:>6}  termination",
        "phase", "EMM µm", "EMax µm", "residual", "iter", "eval"
    );
    for s in &id.phases {
        println!(
            "  {:<32} {:>12} {:>12} {:>9.3}% {:>6} {:>6}  {}",
            s.phase,
            um(s.reached.stats.emm_um),
            um(s.reached.stats.emax_um),
            s.residual_percent(),
            s.iterations,
            s.evaluations,
            s.termination
        );
    }
    println!(
        "\n  initial (errors zero, tracker fitted):  EMM {:>10.4} µm   EMax {:>10.4} µm",
        id.initial.stats.emm_um, id.initial.stats.emax_um
    );
    println!(
        "  final:                                 EMM {:>10} µm   EMax {:>10} µm   residual {} %",
        um(id.reached.stats.emm_um),
        um(id.reached.stats.emax_um),
        um(id.residual_percent())
    );
    if let Some(n) = outcome.noise_error {
        println!(
            "  noise error (of the measurements):      EMM {:>10} µm   EMax {:>10} µm   final / noise {:.4}",
            um(n.emm_um),
            um(n.emax_um),
            id.reached.stats.emm_um / n.emm_um
        );
    }
    print_verdict(outcome, out);
}

/// The run's counts, what the data do not determine, implausible sizes and what was written.
/// Each reversal among the combinations the data leave open whose axis no position reached
/// from both sides separates from its positioning error, with why: `held: reversal.X.b — the
/// data approach X from one side only`.
fn print_held_reversals(outcome: &Outcome) {
    use volver::solvers::observability::Kind;
    for f in &outcome.observability {
        let Some(axis) = f.axis.filter(|_| f.kind == Kind::OneSided) else {
            continue;
        };
        let prefix = format!("reversal.{axis}.");
        let open = outcome
            .unidentified
            .iter()
            .any(|u| u.parameters.iter().any(|s| s.name.starts_with(&prefix)));
        if open {
            let why = f.what.split(" (").next().unwrap_or(&f.what);
            println!("    held: reversal.{axis} — {why}");
        }
    }
}

fn print_verdict(outcome: &Outcome, out: Option<&std::path::Path>) {
    let id = &outcome.id;
    let weak = &outcome.unidentified;
    let held = weak.len();
    println!(
        "  {} iterations, {} evaluations, {:.2} s; {}{}",
        id.iterations(),
        id.evaluations(),
        id.time_s,
        id.termination,
        if held > 0 {
            format!(
                "; {held} combination(s) not identifiable from these data {}",
                if outcome.with_priors {
                    "decided by the priors"
                } else {
                    "held by the gauge"
                }
            )
        } else {
            String::new()
        }
    );
    if !weak.is_empty() {
        println!(
            "  not identifiable from these data ({}; the parameters each combination moves):",
            if outcome.with_priors {
                "decided by the priors"
            } else {
                "held at the reference"
            }
        );
        for u in weak {
            let list: Vec<String> = u
                .parameters
                .iter()
                .map(|s| format!("{} {:+.2}", s.name, s.share))
                .collect();
            println!(
                "    {}   (relative curvature {:.1e})",
                list.join(", "),
                u.relative_curvature
            );
        }
        print_held_reversals(outcome);
    }
    if held > 0 || outcome.with_priors {
        println!("  gauge: {}", outcome.rule);
    }
    for i in &outcome.implausible {
        println!("  implausible: {i}");
    }
    if let Some(out) = out
        && outcome.refusal.is_none()
    {
        println!("  parameters written to {}", out.display());
        if let Some(check) = outcome
            .results
            .uncertainty
            .as_ref()
            .and_then(|u| u.model_check.as_ref())
        {
            let label = if check.above_noise {
                "WARNING: the uncertainty it carries"
            } else {
                "the uncertainty it carries"
            };
            println!("  {label}: {}", check.statement());
        }
    }
}
