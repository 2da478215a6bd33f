//! `volver identify`: the geometric errors and the tracker pose from measurements.

use super::{Inputs, Progress, print_observability, um};
use anyhow::{Context, Result};
use std::path::PathBuf;
use volver::core::problem::Problem;
use volver::core::results::ResultsFile;
use volver::core::simulate::{SimulationRecord, Truth};
use volver::solvers::strategy::{Phasing, Strategy, identify};
use volver::solvers::{Objective, Options, Solver};

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
    /// Objective: phi (mean error module, eq. 12) or ve (mean squared error, eq. 1).
    #[arg(long, default_value = "phi")]
    objective: String,
    /// The tracker's noise for the uncertainty the results file records (`paper`,
    /// `normal:AZ,EL,R,R_PER_M`, … as `simulate --noise`); default: isotropic normal with the
    /// residuals' variance.
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
    /// Native LM: bend each step by geodesic acceleration (for strongly nonlinear models; one
    /// more Jacobian pass per step tried).
    #[arg(long)]
    geodesic_acceleration: bool,
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
    let inputs = a.inputs.paths(&[a.truth.as_deref()]);
    for out in [&a.out, &a.write_model, &a.history].into_iter().flatten() {
        volver::core::fsio::check_not_an_input(out, &inputs)?;
    }
    let (machine, model, data) = a.inputs.load()?;
    let model = volver::inputs::with_candidates(&machine, model, &a.add)?;
    if let Some(path) = &a.write_model {
        let text = toml::to_string(model.spec()).context("writing the error model")?;
        volver::core::fsio::write_atomic(path, text)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    let objective: Objective = a.objective.parse().map_err(anyhow::Error::msg)?;
    // The noise model of the uncertainty the results file records (checked before the fit).
    let noise_model = volver::uncertainty::noise_of(a.noise.as_deref())?;
    let priors = (!a.prior.is_empty())
        .then(|| volver::solvers::prior::Priors::parse(&a.prior))
        .transpose()?;
    let phasing = Phasing::parse(&a.strategy).map_err(anyhow::Error::msg)?;
    if a.subloops == 0 {
        anyhow::bail!("--subloops must be at least 1");
    }
    let solver: Box<dyn Solver> = volver::solvers::engine(&a.solver).map_err(anyhow::Error::msg)?;
    let mut options = Options {
        objective,
        geodesic_acceleration: a.geodesic_acceleration,
        ..Options::default()
    };
    if let Some(v) = a.max_iterations {
        options.max_iterations = v;
    }
    if let Some(v) = a.max_evaluations {
        options.max_evaluations = v;
    }
    options.validate().map_err(anyhow::Error::msg)?;
    let problem = Problem::new(&model, &data)?;
    let noise_error = match &a.truth {
        Some(path) => {
            let label = path.display().to_string();
            let truth = Truth::from_results(
                &ResultsFile::load(path).context("reading the truth file")?,
                &label,
            )?;
            if truth.model.machine().spec() != machine.spec() {
                anyhow::bail!("the machine of {label} is not the machine of the measurements");
            }
            // Effects outside the results format (drift, reflector offsets …) are not in the
            // truth file; the generator's own record beside it has the exact noise error — when
            // it belongs to these data: the measurements the generator wrote beside it, with
            // its number of points.
            let dir = path.parent().unwrap_or(std::path::Path::new("."));
            let belongs =
                volver::core::fsio::same_file(&dir.join("measurements.csv"), &a.inputs.data);
            let record = belongs
                .then(|| std::fs::read_to_string(dir.join("simulation.json")).ok())
                .flatten()
                .and_then(|t| serde_json::from_str::<SimulationRecord>(&t).ok())
                .filter(|r| r.points == data.points.len());
            match record {
                Some(r) => Some(r.noise_error),
                None => Some(Problem::new(&truth.model, &data)?.stats(&truth.params)),
            }
        }
        None => None,
    };
    let strategy = Strategy {
        phasing,
        subloops: a.subloops,
        ..Strategy::default()
    };
    if !a.json {
        println!(
            "volver identify — {} points, model \"{}\" ({} parameters), solver {}, objective {}, strategy {}",
            data.points.len(),
            model.spec().name,
            model.n_params(),
            solver.name(),
            objective,
            phasing.name()
        );
    }
    // What these positions can measure with this layout, before anything is fitted.
    let observability =
        volver::solvers::observability::observe(&model, &data, &model.initial_params());
    if !a.json && !observability.is_empty() {
        println!("\nWhat these positions can and cannot measure with this layout:");
        print_observability(&observability);
        println!();
    }
    let mut id = identify(
        solver.as_ref(),
        problem.clone(),
        &model.initial_params(),
        &strategy,
        &options,
        &mut Progress { quiet: a.json },
    );
    // The uncertainty the results carry, so that compensate, tables and report state the U of
    // what they derive; with --prior, the maximum a posteriori solution and its covariance.
    let mut covariance = if id.termination.failed() {
        None
    } else {
        volver::solvers::uncertainty::linear(
            &problem,
            id.gauge.as_ref(),
            &id.params,
            objective,
            noise_model,
        )
    };
    let rule = match (&priors, &id.gauge) {
        (Some(p), _) => p.rule(),
        (None, Some(_)) => volver::solvers::gauge::RULE.to_string(),
        (None, None) => "none".to_string(),
    };
    if let (Some(p), Some(cov)) = (&priors, &covariance) {
        let post = volver::solvers::prior::maximum_a_posteriori(
            &model,
            id.gauge.as_ref(),
            &id.params,
            cov,
            p,
        )
        .context("the maximum a posteriori solution (a decomposition failed)")?;
        id.params = post.params;
        id.final_ = volver::solvers::evaluate(&problem, &id.params);
        covariance = Some(post.covariance);
    } else if priors.is_some() {
        anyhow::bail!(
            "--prior: the fit has no covariance ({}), so the priors cannot be combined with it",
            id.termination
        );
    }
    if !a.no_history {
        let path = a
            .history
            .clone()
            .unwrap_or_else(|| volver::history::default_path(&a.inputs.data));
        volver::history::append(
            &path,
            &volver::history::Record {
                data: a.inputs.data.display().to_string(),
                model: model.spec().name.clone(),
                added: a.add.clone(),
                parameters: model.n_params(),
                free: id.phases.last().map_or(0, |s| s.free_parameters),
                emm_initial_um: id.initial.stats.emm_um,
                emm_final_um: id.final_.stats.emm_um,
                emax_final_um: id.final_.stats.emax_um,
                phi_mm: id.final_.phi_mm,
                noise_error_um: noise_error.map(|s| s.emm_um),
                termination: id.termination.to_string(),
            },
        )?;
    }
    let mut results = ResultsFile::from_model(&model, &id.params)?;
    if let Some(cov) = &covariance {
        // One name per column of the held factor: none when the priors decided them.
        let held = id
            .gauge
            .as_ref()
            .filter(|_| priors.is_none())
            .map(|g| {
                (0..g.held.len())
                    .map(|c| volver::uncertainty::combination_text(&model, g, c))
                    .collect()
            })
            .unwrap_or_default();
        results.uncertainty = Some(cov.to_record(&rule, held));
    }
    // Honest exits: a failed run, a run stopped by a limit and a run with implausible sizes exit
    // non-zero and write no results (a later `compensate` or `tables` must not use them),
    // unless --accept keeps the last two.
    // Plausibility of what the data determine: the fit moved to the minimum-norm point along
    // the directions the data cannot identify (whose values are arbitrary), each value allowed
    // its expanded uncertainty.
    let tracker_start = volver::solvers::init::init_tracker(&problem, &model.initial_params()).ok();
    let determined = volver::solvers::identifiability::analyse(
        &volver::solvers::Task::new(problem),
        &id.params,
        options.rank_tolerance,
        1.0,
    );
    // Each value is allowed its uncertainty from the data: the fit's covariance (the gauge's,
    // its held combinations at the reference need no allowance), else the analysis'.
    let data_columns: Option<Vec<Vec<f64>>> = covariance.as_ref().map(|c| {
        (0..c.data.ncols())
            .map(|k| (0..c.data.nrows()).map(|j| c.data[(j, k)]).collect())
            .collect()
    });
    // The fit is on the gauge (values along the unidentified combinations at the reference),
    // unless the gauge could not be computed: then the minimum-norm point of the analysis.
    let representative = match (&id.gauge, &determined, &tracker_start) {
        (Some(_), _, _) => id.params.clone(),
        (None, Some(a), Some(start)) => a.minimum_norm(&id.params, start),
        _ => id.params.clone(),
    };
    let implausible = volver::core::plausibility::check(
        &model,
        &representative,
        &volver::core::plausibility::Context {
            tracker_start: tracker_start.as_deref(),
            covariance_factor: data_columns
                .as_deref()
                .or(determined.as_ref().map(|a| a.covariance_factor.as_slice())),
            emm_um: Some(id.final_.stats.emm_um),
            relaxed: false,
        },
    );
    let refusal = if id.termination.failed() {
        Some(format!("identification {}", id.termination))
    } else if !a.accept && !implausible.is_empty() {
        let list: Vec<String> = implausible
            .iter()
            .take(4)
            .map(ToString::to_string)
            .collect();
        Some(format!(
            "implausible sizes ({}): {}; {} (--accept keeps the fit anyway)",
            id.termination,
            list.join("; "),
            volver::core::plausibility::WHERE_TO_LOOK
        ))
    } else if !a.accept && !id.termination.converged() {
        Some(format!(
            "{}, not converged: raise --max-iterations or --max-evaluations, or pass --accept \
             to keep this fit",
            id.termination
        ))
    } else {
        None
    };
    if let Some(out) = &a.out
        && refusal.is_none()
    {
        results.save(out).context("writing the results file")?;
    }
    let params = serde_json::to_value(&results.parameters)?;
    // The combinations the data cannot identify, by the parameters they move: the gauge held
    // them at the reference (a metrologist needs to know which errors are therefore not
    // determined, and by which rule their values were chosen).
    let weak: Vec<(f64, Vec<(String, f64)>)> = id
        .gauge
        .as_ref()
        .map(|g| {
            g.held
                .iter()
                .map(|h| {
                    let names = h
                        .parameters
                        .iter()
                        .take(4)
                        .map(|&(j, share)| (model.params()[j].name.clone(), share))
                        .collect();
                    (h.relative_curvature, names)
                })
                .collect()
        })
        .unwrap_or_default();
    let held = weak.len();
    if a.json {
        let obj = serde_json::json!({
            "solver": solver.name(),
            "objective": objective.to_string(),
            "strategy": phasing.name(),
            "subloops": a.subloops,
            "points": data.points.len(),
            "emm_initial_um": id.initial.stats.emm_um,
            "emm_final_um": id.final_.stats.emm_um,
            "emax_initial_um": id.initial.stats.emax_um,
            "emax_final_um": id.final_.stats.emax_um,
            "phi_final_mm": id.final_.phi_mm,
            "ve_final_mm2": id.final_.ve_mm2,
            "residual_percent": id.residual_percent(),
            "noise_error_um": noise_error.map(|s| s.emm_um),
            "noise_emax_um": noise_error.map(|s| s.emax_um),
            "iterations": id.iterations(),
            "evaluations": id.evaluations(),
            "time_s": id.time_s,
            "termination": id.termination.to_string(),
            "converged": id.termination.converged(),
            "phases": id.phases,
            "parameters": params,
            "gauge": (rule != "none").then_some(&rule),
            "unidentifiable": weak.iter().map(|(c, names)| serde_json::json!({
                "relative_curvature": c,
                "parameters": names.iter().map(|(n, s)| serde_json::json!({"name": n, "share": s})).collect::<Vec<_>>(),
            })).collect::<Vec<_>>(),
            "implausible": implausible.iter().map(ToString::to_string).collect::<Vec<_>>(),
            "refused": refusal,
            "observability": observability.iter().map(|f| serde_json::json!({
                "kind": format!("{:?}", f.kind).to_lowercase(),
                "what": f.what, "fix": f.fix,
            })).collect::<Vec<_>>(),
        });
        println!("{}", serde_json::to_string_pretty(&obj)?);
    } else {
        println!(
            "\n  {:<32} {:>12} {:>12} {:>10} {:>6} {:>6}  termination",
            "phase", "EMM µm", "EMax µm", "residual", "iter", "eval"
        );
        for s in &id.phases {
            println!(
                "  {:<32} {:>12} {:>12} {:>9.3}% {:>6} {:>6}  {}",
                s.phase,
                um(s.final_.stats.emm_um),
                um(s.final_.stats.emax_um),
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
            um(id.final_.stats.emm_um),
            um(id.final_.stats.emax_um),
            um(id.residual_percent())
        );
        if let Some(n) = noise_error {
            println!(
                "  noise error (of the measurements):      EMM {:>10} µm   EMax {:>10} µm   final / noise {:.4}",
                um(n.emm_um),
                um(n.emax_um),
                id.final_.stats.emm_um / n.emm_um
            );
        }
        println!(
            "  {} iterations, {} evaluations, {:.2} s; {}{}",
            id.iterations(),
            id.evaluations(),
            id.time_s,
            id.termination,
            if held > 0 {
                format!(
                    "; {held} combination(s) not identifiable from these data {}",
                    if priors.is_some() {
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
                if priors.is_some() {
                    "decided by the priors"
                } else {
                    "held at the reference"
                }
            );
            for (c, names) in &weak {
                let list: Vec<String> = names.iter().map(|(n, s)| format!("{n} {s:+.2}")).collect();
                println!("    {}   (relative curvature {c:.1e})", list.join(", "));
            }
        }
        if held > 0 || priors.is_some() {
            println!("  gauge: {rule}");
        }
        for i in &implausible {
            println!("  implausible: {i}");
        }
        if let Some(out) = &a.out
            && refusal.is_none()
        {
            println!("  parameters written to {}", out.display());
        }
    }
    if let Some(r) = refusal {
        anyhow::bail!("{r}; no results written");
    }
    Ok(())
}
