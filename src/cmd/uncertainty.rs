//! `volver uncertainty`: the fit of a data set with its gauge stated and the expanded
//! uncertainty (k = 2) of every parameter and of the tool point over a grid of the volume, raw
//! and after the set-up's rigid transform, linearised and (with `--monte-carlo N`) by Monte
//! Carlo.

use anyhow::Result;
use clap::Args;
use volver::compensation::tool_point_of;
use volver::core::model::Model;
use volver::core::units::UM_PER_MM;
use volver::solvers::uncertainty::{HELD_PRIOR_MM, K, PointUncertainty};
use volver::uncertainty::{Assessment, Request, assess, combination_text, grid_of};

/// Arguments of `volver uncertainty`.
#[derive(Args)]
pub struct UncertaintyArgs {
    #[command(flatten)]
    inputs: super::Inputs,
    /// The tracker's noise: paper, normal:AZ_URAD,EL_URAD,RANGE_UM,RANGE_UM_PER_M (σ),
    /// uniform:… (bounds) or mpe:A_UM,B_UM_PER_M (±(a + b·L), k = 2). Default: the machine
    /// file's `[tracker] noise`, else isotropic normal with the residuals' variance; the output
    /// says which, and whether the fit agrees with it.
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
    /// The estimator fitted and assessed: phi (default), ve, ml or phi-w (as `identify
    /// --objective`); every estimator's expected error is printed beside the Cramér–Rao limit
    /// whatever the choice.
    #[arg(long, default_value = "phi")]
    objective: String,
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
    let mut request = Request::new(&model)?;
    let (noise_model, noise_used) = volver::inputs::noise_rule(a.noise.as_deref(), &machine)?;
    request.noise = noise_model;
    request.engine.clone_from(&a.solver);
    volver::solvers::engine(&a.solver)?;
    request.priors = (!a.prior.is_empty())
        .then(|| volver::solvers::prior::Priors::parse(&a.prior))
        .transpose()?;
    request.monte_carlo = a.monte_carlo.map(|n| (n, a.seed));
    request.objective = a.objective.parse()?;
    request.grid = grid_of(&machine, a.grid.as_deref())?;
    request.tool = tool_point_of(a.tool_offset.as_deref(), None, &model)?;
    let quiet = a.json;
    let n = a.monte_carlo.unwrap_or(0);
    let step = (n / 20).max(1);
    let progress = move |done: usize| {
        if !quiet && (done.is_multiple_of(step) || done == n) {
            eprint!("\r  Monte Carlo: {done}/{n} replicas");
            if done == n {
                eprintln!();
            }
        }
    };
    let assessment = assess(&model, &data, &request, &progress)?;
    let noise_used = noise_used.judged(
        noise_model,
        &model,
        &data,
        &assessment.id.params,
        assessment.id.reached.stats.emm_um,
    );
    if a.json {
        let mut value = serde_json::to_value(assessment.report(&model, &request))?;
        value["noise_used"] = serde_json::to_value(&noise_used)?;
        println!("{}", serde_json::to_string_pretty(&value)?);
        return Ok(());
    }
    print_gauge(&assessment, &model, &request, data.points.len());
    println!("{}", noise_used.text());
    print_parameters(&assessment, &model);
    print_tool_point(&assessment, &model, &request);
    print_reversals(&assessment, &model);
    print_efficiency(&assessment, &request);
    let check = &assessment.model_check;
    let label = if check.above_noise {
        "WARNING"
    } else {
        "model check"
    };
    println!("\n  {label}: {}", check.statement());
    Ok(())
}

/// Every estimator's expected tool-point error beside the Cramér–Rao limit, or why there is
/// none.
fn print_efficiency(a: &Assessment, request: &Request) {
    match &a.efficiency {
        Some(e) => super::print_efficiency(
            &volver::uncertainty::EfficiencyU::from(e),
            Some(request.objective),
        ),
        None => println!(
            "\n  estimators against the Cramér–Rao limit: not stated (it needs the tracker's noise \
             model: --noise or the machine file's [tracker] noise)"
        ),
    }
}

/// The fit, the noise model and the gauge, in words.
fn print_gauge(a: &Assessment, model: &Model, request: &Request, points: usize) {
    let noise = request.noise;
    println!(
        "volver uncertainty — {} points, model \"{}\", EMM {:.2} µm, residual σ {:.2} µm per \
         coordinate",
        points,
        model.spec().name,
        a.id.reached.stats.emm_um,
        a.covariance.sigma_mm * UM_PER_MM
    );
    println!("  noise model: {noise}");
    match (&a.id.gauge, a.rule.clone()) {
        (g, Some(rule)) if a.with_priors => {
            println!("  gauge: {rule}");
            if let Some(g) = g.as_ref().filter(|g| !g.held.is_empty()) {
                println!(
                    "  combinations these data do not determine (decided by the priors; U is \
                     the posterior's, in the \"U data\" column):"
                );
                for c in 0..g.held.len() {
                    println!("    {}: {}", c + 1, combination_text(model, g, c));
                }
            }
        }
        (Some(g), Some(rule)) if !g.held.is_empty() => {
            println!("  gauge: {rule}");
            println!(
                "  held combinations (not determined by these data; a prior of {:.0} µm RMS \
                 each in U):",
                HELD_PRIOR_MM * UM_PER_MM
            );
            for c in 0..g.held.len() {
                println!("    {}: {}", c + 1, combination_text(model, g, c));
            }
        }
        _ => println!("  gauge: nothing held (every combination is identified)"),
    }
}

/// Every parameter with its expanded uncertainty: the data's part, Monte Carlo's, the held part.
fn print_parameters(a: &Assessment, model: &Model) {
    let u_parts = a.covariance.parameter_parts();
    let u_params_mc = a.parameters_monte_carlo(model);
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
        if ud == 0.0 && uh == 0.0 && a.id.params[j] == 0.0 {
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
            a.id.params[j] * s,
            unit,
            K * ud * s,
            K * uh * s
        );
    }
}

/// Each axis' reversal B ± U (k = 2) at the middle of its travel: the tool point above is the
/// mean of both directions of approach; approached from one side it moves by ±B/2 along the
/// axis, with U(B)/2 beside its U.
fn print_reversals(a: &Assessment, model: &Model) {
    let axes = model.reversal_axes();
    if axes.is_empty() {
        return;
    }
    let parts: Vec<String> = axes
        .iter()
        .map(|(k, range)| {
            let ax = &model.machine().axes()[*k];
            let mid = 0.5 * (ax.min + ax.max);
            let mut g = vec![0.0; a.id.params.len()];
            let b = model.reversal_at(*k, mid, &a.id.params, Some(&mut g));
            let u = K * a.covariance.u(&g);
            let (s, unit) = model.params()[range.start].unit.micro();
            format!(
                "{} {:.3} ± {:.3} {unit}",
                ax.axis,
                b.unwrap_or(0.0) * s,
                u * s
            )
        })
        .collect();
    println!(
        "\n  reversal B ± U (k = 2) at mid-travel: {}. The tool point above is the mean of both \
         directions of approach; reached moving one way it moves by ±B/2 along the axis (the \
         compensation applies it by each move's direction), U(B)/2 beside the U above",
        parts.join("; ")
    );
}

/// The tool point's largest U over the grid, after the transform and raw, with Monte Carlo's.
fn print_tool_point(a: &Assessment, model: &Model, request: &Request) {
    let mc = a.monte_carlo.as_ref().map(|(mc, _, _)| mc);
    let mc_aligned = &a.monte_carlo.as_ref().map(|(_, m, _)| m.clone());
    let mc_raw = &a.monte_carlo.as_ref().map(|(_, _, m)| m.clone());
    let tool_text = volver::compensation::point_mm(request.tool);
    for (label, us, mcu) in [
        ("after the set-up's rigid transform", &a.aligned, mc_aligned),
        ("raw, in the workpiece frame", &a.raw, mc_raw),
    ] {
        let (d, h, t, k) = largest(us);
        println!(
            "\n  tool point {tool_text} over {} commands, {label}: U95 up to {:.2} µm (data \
             {:.2} µm, held combinations {:.2} µm) at {:?}",
            us.len(),
            t * UM_PER_MM,
            d * UM_PER_MM,
            h * UM_PER_MM,
            Assessment::commands(model, &request.grid, k)
        );
        if let (Some(g), Some(c)) = (&a.id.gauge, us[k].worst_held)
            && h > 0.1 * t
        {
            println!(
                "    mostly from held combination {}: {}",
                c + 1,
                combination_text(model, g, c)
            );
        }
        if let (Some(m), Some(mc)) = (mcu, mc)
            && us.iter().any(|u| u.u95_data_mm.iter().any(|v| *v > 0.0))
        {
            let mean = volver::uncertainty::monte_carlo_ratio(us, m);
            let mmax = m.iter().copied().fold(0.0, f64::max);
            println!(
                "    Monte Carlo ({} replicas, {:.1} s): U95 up to {:.2} µm; Monte Carlo / \
                 linearised (data) {:.3} on average (where the linearised U exceeds 0.1 % of its \
                 largest)",
                mc.samples.len(),
                mc.time_s,
                mmax * UM_PER_MM,
                mean
            );
        }
    }
}
