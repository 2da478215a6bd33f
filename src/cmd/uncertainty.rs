//! `volver uncertainty`: the fit of a data set with its gauge stated and the expanded
//! uncertainty (k = 2) of every parameter and of the tool point over a grid of the volume, raw
//! and after the set-up's rigid transform, linearised and (with `--monte-carlo N`) by Monte
//! Carlo.

use anyhow::{Context, Result, bail};
use clap::Args;
use volver::compensation::tool_point_of;
use volver::core::problem::Problem;
use volver::solvers::gauge::RULE;
use volver::solvers::strategy::{Strategy, identify};
use volver::solvers::uncertainty::{
    HELD_PRIOR_MM, K, PointUncertainty, ToolGrid, linear, monte_carlo,
};
use volver::solvers::{Options, Silent};
use volver::uncertainty::{combination_text, grid_of, noise_of};

/// Arguments of `volver uncertainty`.
#[derive(Args)]
pub struct UncertaintyArgs {
    #[command(flatten)]
    inputs: super::Inputs,
    /// The tracker's noise: `paper`, `none`, `normal:AZ,EL,R,R_PER_M` or `uniform:…` (µrad,
    /// µrad, µm, µm/m), as `simulate --noise`; default: isotropic normal with the residuals'
    /// variance.
    #[arg(long)]
    noise: Option<String>,
    /// Monte Carlo replicas (GUM Supplement 1), besides the linearised uncertainty.
    #[arg(long, value_name = "N")]
    monte_carlo: Option<usize>,
    /// Seed of the Monte Carlo replicas.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// The tool point, mm in the frame of the last tool-side axis; default: the reflectors'
    /// centroid.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
    tool_offset: Option<String>,
    /// The commands whose tool points are judged: a plan preset or a grid such as
    /// X=0:1400:200,C=0:330:30,Z=0:600:150 (mm, degrees); default: 5 positions over each axis.
    #[arg(long)]
    grid: Option<String>,
    /// Prior magnitudes per error kind (`typical` or KIND=VALUE, as `identify --prior`): the
    /// maximum a posteriori solution and its posterior U instead of the gauge's.
    #[arg(long, value_name = "KIND=VALUE")]
    prior: Vec<String>,
    /// Engine (`lm`, …).
    #[arg(long, default_value = "lm")]
    solver: String,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

/// The largest value of each figure over the grid: (data, held, total, worst point index).
fn largest(us: &[PointUncertainty]) -> (f64, f64, f64, usize) {
    let mut out = (0.0_f64, 0.0_f64, 0.0_f64, 0);
    for (i, u) in us.iter().enumerate() {
        let d = u.u95_data_mm.iter().copied().fold(0.0, f64::max);
        let h = u.u95_held_mm.iter().copied().fold(0.0, f64::max);
        out.0 = out.0.max(d);
        out.1 = out.1.max(h);
        if u.u95_max_mm() > out.2 {
            out.2 = u.u95_max_mm();
            out.3 = i;
        }
    }
    out
}

/// Runs `volver uncertainty`.
pub fn uncertainty_command(a: UncertaintyArgs) -> Result<()> {
    let (machine, model, data) = a.inputs.load()?;
    let noise = noise_of(a.noise.as_deref())?;
    let solver = volver::solvers::engine(&a.solver)?;
    let problem = Problem::new(&model, &data)?;
    let options = Options::default();
    let priors = (!a.prior.is_empty())
        .then(|| volver::solvers::prior::Priors::parse(&a.prior))
        .transpose()?;
    if priors.is_some() && a.monte_carlo.is_some() {
        bail!(
            "--monte-carlo with --prior: the Monte Carlo replicas re-fit the data's estimator; \
             the posterior of the priors is stated linearised only (run them apart)"
        );
    }
    let mut id = identify(
        solver.as_ref(),
        problem.clone(),
        &model.initial_params(),
        &Strategy::default(),
        &options,
        &mut Silent,
    );
    if id.termination.failed() {
        bail!("identification {}", id.termination);
    }
    let cov = linear(
        &problem,
        id.gauge.as_ref(),
        &id.params,
        options.objective,
        noise,
    )
    .context("the Jacobian at the solution is not finite or a decomposition failed")?;
    let cov = match &priors {
        Some(p) => {
            let post = volver::solvers::prior::maximum_a_posteriori(
                &model,
                id.gauge.as_ref(),
                &id.params,
                &cov,
                p,
            )
            .context("the maximum a posteriori solution (a decomposition failed)")?;
            id.params = post.params;
            id.final_ = volver::solvers::evaluate(&problem, &id.params);
            post.covariance
        }
        None => cov,
    };
    let plan = grid_of(&machine, a.grid.as_deref())?;
    let tool = tool_point_of(a.tool_offset.as_deref(), None, &model)?;
    let grid = ToolGrid {
        commands: plan.positions.clone(),
        tool,
    };
    let aligned = grid.uncertainty(&model, &id.params, &cov, true);
    let raw = grid.uncertainty(&model, &id.params, &cov, false);
    let base = grid.points(&model, &id.params);
    let mc = match a.monte_carlo {
        Some(0) => bail!("--monte-carlo 0: give at least 2 replicas"),
        Some(n) => {
            let quiet = a.json;
            let step = (n / 20).max(1);
            let progress = move |done: usize| {
                if !quiet && (done.is_multiple_of(step) || done == n) {
                    eprint!("\r  Monte Carlo: {done}/{n} replicas");
                    if done == n {
                        eprintln!();
                    }
                }
            };
            let mc = monte_carlo(
                &a.solver,
                &model,
                &data,
                &id.params,
                noise,
                cov.sigma_mm,
                id.gauge.as_ref(),
                &options,
                n,
                a.seed,
                &progress,
            )?;
            if mc.samples.len() < 2 {
                bail!("Monte Carlo: {} of {n} replicas failed to solve", mc.failed);
            }
            Some(mc)
        }
        None => None,
    };
    let mc_aligned = mc
        .as_ref()
        .map(|mc| grid.monte_carlo_u95(&model, mc, &base, true));
    let mc_raw = mc
        .as_ref()
        .map(|mc| grid.monte_carlo_u95(&model, mc, &base, false));
    let u_parts = cov.parameter_parts();
    let u_params_mc: Option<Vec<f64>> = mc
        .as_ref()
        .map(|mc| (0..model.n_params()).map(|j| mc.std_of(|p| p[j])).collect());
    let files = |k: usize| -> Vec<f64> {
        machine
            .axes()
            .iter()
            .enumerate()
            .map(|(i, ax)| ax.to_file_units(plan.positions[k].0[i]))
            .collect()
    };
    let gauge_rule: Option<String> = match &priors {
        Some(p) => Some(p.rule()),
        None => id.gauge.as_ref().map(|_| RULE.to_string()),
    };
    if a.json {
        let um3 = |v: [f64; 3]| v.map(|x| x * 1e3);
        let obj = serde_json::json!({
            "gauge": gauge_rule,
            "held_prior_mm": if priors.is_some() { None } else { Some(HELD_PRIOR_MM) },
            "noise": noise.to_string(),
            "sigma_mm": cov.sigma_mm,
            "coverage_factor": K,
            "emm_um": id.final_.stats.emm_um,
            "tool_offset_mm": tool,
            "parameters": model.params().iter().enumerate().map(|(j, info)| serde_json::json!({
                "name": info.name,
                "unit": info.unit.to_string(),
                "value": id.params[j],
                "u": u_parts[j].0.hypot(u_parts[j].1),
                "u_data": u_parts[j].0,
                "u_monte_carlo": u_params_mc.as_ref().map(|u| u[j]),
            })).collect::<Vec<_>>(),
            "combinations": id.gauge.as_ref().map(|g| g.held.iter().map(|h| serde_json::json!({
                "held": priors.is_none(),
                "relative_curvature": h.relative_curvature,
                "parameters": h.parameters.iter().map(|&(j, s)| serde_json::json!({
                    "name": model.params()[j].name, "share": s,
                })).collect::<Vec<_>>(),
            })).collect::<Vec<_>>()).unwrap_or_default(),
            "points": aligned.iter().zip(&raw).enumerate().map(|(k, (u, r))| serde_json::json!({
                "commands": files(k),
                "tool_point_mm": u.tool_point_mm,
                "u95_um": um3(u.u95_mm()),
                "u95_data_um": um3(u.u95_data_mm),
                "u95_held_um": um3(u.u95_held_mm),
                "u95_raw_um": um3(r.u95_mm()),
                "u95_monte_carlo_um": mc_aligned.as_ref().map(|m| [m[3 * k] * 1e3, m[3 * k + 1] * 1e3, m[3 * k + 2] * 1e3]),
            })).collect::<Vec<_>>(),
            "monte_carlo": mc.as_ref().map(|mc| serde_json::json!({
                "replicas": mc.samples.len(),
                "failed": mc.failed,
                "time_s": mc.time_s,
                "seed": a.seed,
            })),
        });
        println!("{}", serde_json::to_string_pretty(&obj)?);
        return Ok(());
    }
    println!(
        "volver uncertainty — {} points, model \"{}\", EMM {:.2} µm, residual σ {:.2} µm per \
         coordinate",
        data.points.len(),
        model.spec().name,
        id.final_.stats.emm_um,
        cov.sigma_mm * 1e3
    );
    println!("  noise model: {noise}");
    match (&id.gauge, gauge_rule) {
        (g, Some(rule)) if priors.is_some() => {
            println!("  gauge: {rule}");
            if let Some(g) = g.as_ref().filter(|g| !g.held.is_empty()) {
                println!(
                    "  combinations these data do not determine (decided by the priors; U is \
                     the posterior's, in the \"U data\" column):"
                );
                for c in 0..g.held.len() {
                    println!("    {}: {}", c + 1, combination_text(&model, g, c));
                }
            }
        }
        (Some(g), Some(rule)) if !g.held.is_empty() => {
            println!("  gauge: {rule}");
            println!(
                "  held combinations (not determined by these data; a prior of {:.0} µm RMS \
                 each in U):",
                HELD_PRIOR_MM * 1e3
            );
            for c in 0..g.held.len() {
                println!("    {}: {}", c + 1, combination_text(&model, g, c));
            }
        }
        _ => println!("  gauge: nothing held (every combination is identified)"),
    }
    println!(
        "\n  parameter        value        U data{}    U held (prior)",
        if u_params_mc.is_some() {
            "   U Monte Carlo"
        } else {
            ""
        }
    );
    for (j, info) in model.params().iter().enumerate() {
        let (ud, uh) = u_parts[j];
        if ud == 0.0 && uh == 0.0 && id.params[j] == 0.0 {
            continue; // held by a constraint at zero (a reference coefficient)
        }
        let (s, unit) = info.unit.micro();
        let mc = u_params_mc
            .as_ref()
            .map(|u| format!("   {:>13.3}", K * u[j] * s))
            .unwrap_or_default();
        println!(
            "  {:<14} {:>11.3} {:<5} {:>8.3}{mc}   {:>10.3}",
            info.name,
            id.params[j] * s,
            unit,
            K * ud * s,
            K * uh * s
        );
    }
    let tool_text = volver::compensation::point_mm(tool);
    for (label, us, mcu) in [
        ("after the set-up's rigid transform", &aligned, &mc_aligned),
        ("raw, in the workpiece frame", &raw, &mc_raw),
    ] {
        let (d, h, t, k) = largest(us);
        println!(
            "\n  tool point {tool_text} over {} commands, {label}: U95 up to {:.2} µm (data \
             {:.2} µm, held combinations {:.2} µm) at {:?}",
            us.len(),
            t * 1e3,
            d * 1e3,
            h * 1e3,
            files(k)
        );
        if let (Some(g), Some(c)) = (&id.gauge, us[k].worst_held)
            && h > 0.1 * t
        {
            println!(
                "    mostly from held combination {}: {}",
                c + 1,
                combination_text(&model, g, c)
            );
        }
        if let (Some(m), Some(mc)) = (mcu, &mc)
            && us.iter().any(|u| u.u95_data_mm.iter().any(|v| *v > 0.0))
        {
            let ratio: Vec<f64> = us
                .iter()
                .enumerate()
                .flat_map(|(i, u)| (0..3).map(move |c| m[3 * i + c] / u.u95_data_mm[c]))
                .filter(|r| r.is_finite())
                .collect();
            let mean = ratio.iter().sum::<f64>() / ratio.len().max(1) as f64;
            let mmax = m.iter().copied().fold(0.0, f64::max);
            println!(
                "    Monte Carlo ({} replicas, {:.1} s): U95 up to {:.2} µm; Monte Carlo / \
                 linearised (data) {:.3} on average",
                mc.samples.len(),
                mc.time_s,
                mmax * 1e3,
                mean
            );
        }
    }
    Ok(())
}
