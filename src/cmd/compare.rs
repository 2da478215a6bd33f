//! `volver compare`: every engine of this build on one problem, side by side.

use super::Inputs;
use anyhow::Result;
use clap::Args;
use std::path::PathBuf;
use volver::comparison::{Comparison, compare};
use volver::core::model::Model;
use volver::solvers::{Objective, Options, Solver};

/// An engine made from its name.
type MakeNamed<'a> = dyn Fn(&str) -> Result<Box<dyn Solver>, volver::solvers::Error> + 'a;

/// Options of `volver compare`.
#[derive(Args, Debug)]
pub struct CompareArgs {
    /// Machine file (TOML) or an embedded machine's name (`volver layout --list`); the embedded
    /// XCFZ grinder when absent.
    #[arg(long)]
    machine: Option<PathBuf>,
    /// Error model (TOML); the embedded machine's default model when absent (the paper's on the
    /// XCFZ grinder).
    #[arg(long)]
    model: Option<PathBuf>,
    /// Measurement file (CSV); when absent, the demo's problem: test 4 simulated on the
    /// embedded machine (seed 7, the paper's noise).
    #[arg(long)]
    data: Option<PathBuf>,
    /// Objective: phi (mean error module), ve (mean squared module), ml (maximum likelihood:
    /// least squares on the residuals whitened by each station's noise) or phi-w (Φ of the
    /// whitened residuals).
    #[arg(long, default_value = "phi")]
    objective: String,
    /// The tracker's noise that ml and phi-w weigh the residuals by: paper, normal:…, uniform:…
    /// or mpe:… (as `identify --noise`). Default: the machine file's `[tracker] noise` (a
    /// station's own noise where its table states one).
    #[arg(long)]
    noise: Option<String>,
    /// Engines to run, comma-separated; every engine of this build when absent.
    #[arg(long, value_delimiter = ',')]
    engines: Vec<String>,
    /// Iteration limit of every engine.
    #[arg(long)]
    max_iterations: Option<usize>,
    /// Evaluation limit of every engine.
    #[arg(long)]
    max_evaluations: Option<usize>,
    /// The engines' own settings (TOML, sections [lm], [clarabel], [ceres], [nlopt], as
    /// `identify --engine-settings`); not with --suite, which sets its own.
    #[arg(long, value_name = "FILE.toml")]
    engine_settings: Option<PathBuf>,
    /// Hold the directions the data cannot identify first (at the native LM's solution), so
    /// that the engines are compared on a well-posed problem.
    #[arg(long)]
    gauge: bool,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    json: bool,
    /// Run a reference suite instead of one problem: `nist` (NIST's 27 StRD nonlinear
    /// regression problems, both starts, scored by the log relative error).
    #[arg(long)]
    suite: Option<String>,
}

impl CompareArgs {
    /// `options` with the limits given on the command line, validated.
    fn limits(&self, mut options: Options) -> Result<Options> {
        if let Some(v) = self.max_iterations {
            options.max_iterations = v;
        }
        if let Some(v) = self.max_evaluations {
            options.max_evaluations = v;
        }
        options.validate()?;
        Ok(options)
    }

    /// The engines asked for (every engine of the build but `skip` when none is named), each
    /// made by `make`.
    fn engines(&self, skip: &[&str], make: &MakeNamed) -> Result<Vec<Box<dyn Solver>>> {
        let names: Vec<String> = if self.engines.is_empty() {
            volver::solvers::engine_names()
                .into_iter()
                .filter(|n| !skip.contains(n))
                .map(str::to_string)
                .collect()
        } else {
            self.engines.clone()
        };
        names
            .iter()
            .map(|n| make(n).map_err(anyhow::Error::from))
            .collect()
    }
}

/// Runs `volver compare`.
pub fn compare_command(a: CompareArgs) -> Result<()> {
    if let Some(suite) = &a.suite {
        if suite != "nist" {
            anyhow::bail!("unknown suite '{suite}': the suite is `nist`");
        }
        if a.data.is_some() || a.machine.is_some() || a.model.is_some() || a.gauge {
            anyhow::bail!(
                "--suite runs its own problems: drop --data, --machine, --model, --gauge"
            );
        }
        if a.noise.is_some() {
            anyhow::bail!("--suite runs its own problems (objective ve): drop --noise");
        }
        if a.engine_settings.is_some() {
            anyhow::bail!("--suite runs the engines with its own settings: drop --engine-settings");
        }
        return nist_suite(&a);
    }
    let (model, data, source) = match &a.data {
        Some(path) => {
            let inputs = Inputs {
                machine: a.machine.clone(),
                model: a.model.clone(),
                data: path.clone(),
                import: None,
                plan_file: None,
            };
            let (_, model, data) = inputs.load()?;
            (model, data, path.display().to_string())
        }
        None => {
            if a.machine.is_some() || a.model.is_some() {
                anyhow::bail!("--machine and --model need --data");
            }
            let model = Model::default_xcfz();
            let out = volver::inputs::demo_test4(&model)?;
            (
                model,
                out.measurements,
                "test 4 simulated (seed 7, paper noise)".to_string(),
            )
        }
    };
    let objective: Objective = a.objective.parse()?;
    if a.noise.is_some() && !objective.whitened() {
        anyhow::bail!(
            "--noise weighs the residuals of --objective ml or phi-w; objective {objective} \
             does not use it"
        );
    }
    let options = a.limits(Options {
        objective,
        ..Options::default()
    })?;
    let (noise, _) = volver::inputs::noise_rule(a.noise.as_deref(), model.machine())?;
    let settings = match &a.engine_settings {
        Some(path) => super::identify::engine_settings(path)?,
        None => volver::solvers::Settings::default(),
    };
    let engines = a.engines(&[], &|name| volver::solvers::engine_with(name, &settings))?;
    let c = compare(&model, &data, &source, &engines, &options, a.gauge, noise)?;
    if a.json {
        let v = serde_json::to_value(&c)?;
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    print_table(&c, a.gauge);
    Ok(())
}

/// The comparison as a table: Φ, ve and EMM in mm and µm, and for the noise-weighted
/// objectives their own (dimensionless) value, which the best is judged on.
fn print_table(c: &Comparison, gauge: bool) {
    let (objective, held, rows) = (c.objective, c.gauge_directions_held, &c.engines);
    let source = &c.data;
    println!(
        "volver compare — {source}: {} points, {} parameters, objective {objective}{}{}",
        c.points,
        c.parameters,
        match &c.noise {
            Some(n) => format!(" (residuals whitened by {n})"),
            None => String::new(),
        },
        if gauge {
            format!(", {held} unidentifiable direction(s) held")
        } else {
            String::new()
        }
    );
    // The objective's own column when it is neither Φ nor ve.
    let own = objective.whitened();
    let own_header = if own {
        format!(" {:>17}", objective.to_string())
    } else {
        String::new()
    };
    println!(
        "\n  {:<12}{own_header} {:>17} {:>17} {:>10} {:>6} {:>6} {:>9}  termination",
        "engine", "Φ mm", "ve mm²", "EMM µm", "iter", "eval", "time s"
    );
    let best = rows.iter().map(|r| r.value).fold(f64::INFINITY, f64::min);
    for r in rows {
        let own_value = if own {
            format!(" {:>17.12}", r.value)
        } else {
            String::new()
        };
        println!(
            "  {:<12}{own_value} {:>17.12} {:>17.14} {:>10.4} {:>6} {:>6} {:>9.3}  {}",
            r.engine,
            r.phi_mm,
            r.ve_mm2,
            r.emm_um,
            r.iterations,
            r.evaluations,
            r.time_s,
            r.termination
        );
    }
    let unit = match objective {
        Objective::Phi => " mm",
        Objective::Ve => " mm²",
        _ => " (whitened, dimensionless)",
    };
    println!(
        "\n  best {objective}: {best:.12e}{unit}; NLopt counts objective calls as iterations; lm+clarabel adds both runs."
    );
}

/// `volver compare --suite nist`.
fn nist_suite(a: &CompareArgs) -> Result<()> {
    use volver::solvers::nist_suite;
    let options = a.limits(nist_suite::options())?;
    // Every engine that minimises a sum of squares; BOBYQA (derivative-free) is left out.
    let engines = a.engines(&["nlopt-bobyqa"], &nist_suite::engine)?;
    let names: Vec<&str> = engines.iter().map(|e| e.name()).collect();
    let datasets = volver::core::nist::all()?;
    let mut runs = Vec::new();
    for ds in &datasets {
        for start in 0..2 {
            for e in &engines {
                runs.push(nist_suite::run(ds, start, e.as_ref(), &options));
            }
        }
    }
    let mean = |engine: &str, f: fn(&nist_suite::StrdRun) -> f64| {
        let v: Vec<f64> = runs.iter().filter(|r| r.engine == engine).map(f).collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    };
    if a.json {
        let means: Vec<serde_json::Value> = names
            .iter()
            .map(|n| {
                serde_json::json!({
                    "engine": n,
                    "mean_lre_params": mean(n, |r| r.lre_params),
                    "mean_lre_rss": mean(n, |r| r.lre_rss),
                })
            })
            .collect();
        let v = serde_json::json!({ "suite": "nist", "runs": runs, "means": means });
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    print_suite(&runs, &names, &options)
}

/// The suite's table: each problem and start, then the means.
fn print_suite(
    runs: &[volver::solvers::nist_suite::StrdRun],
    names: &[&str],
    options: &volver::solvers::Options,
) -> Result<()> {
    let mean = |engine: &str, f: fn(&volver::solvers::nist_suite::StrdRun) -> f64| {
        let v: Vec<f64> = runs.iter().filter(|r| r.engine == engine).map(f).collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    };
    println!(
        "volver compare --suite nist — NIST StRD nonlinear regression, 27 problems × 2 starts; LRE = correct digits (0–11) of the worst parameter and of the residual sum of squares\n"
    );
    print!("  {:<9} {:<8} st", "problem", "level");
    for n in names {
        print!("  {:>17}", n);
    }
    println!(
        "\n  {:<9} {:<8}   {}",
        "",
        "",
        "   LRE b/RSS   it".repeat(names.len())
    );
    for (k, chunk) in runs.chunks(names.len()).enumerate() {
        let r0 = &chunk[0];
        let level = format!("{:?}", r0.difficulty).to_lowercase();
        print!("  {:<9} {:<8} {:>2}", r0.problem, level, k % 2 + 1);
        for r in chunk {
            let flag = if r.termination.failed() { "!" } else { " " };
            print!(
                "  {:>4.1}/{:>4.1} {:>5}{flag}",
                r.lre_params, r.lre_rss, r.iterations
            );
        }
        println!();
    }
    print!("\n  {:<9} {:<8}   ", "mean", "");
    for n in names {
        print!(
            "  {:>4.2}/{:>5.2}       ",
            mean(n, |r| r.lre_params),
            mean(n, |r| r.lre_rss)
        );
    }
    println!();
    if runs.iter().any(|r| r.termination.failed()) {
        println!("\n  ! the engine reported a failure.");
    }
    println!(
        "\n  Options: objective ve, tolerances 1e-15, {} iterations, {} evaluations, nothing held as unidentifiable{}.",
        options.max_iterations,
        options.max_evaluations,
        if volver::solvers::nist_suite::lm().geodesic_acceleration {
            "; the native LM with geodesic acceleration"
        } else {
            ""
        }
    );
    Ok(())
}
