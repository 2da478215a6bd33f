//! The `volver` command-line tool.

mod compare;
mod compensation;
mod demo;
mod history;
mod plot;
mod report;
mod study;
mod uncertainty;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use std::path::PathBuf;
use volver::core::machine::{Machine, TrackerMount};
use volver::core::measure::MeasurementSet;
use volver::core::model::{ConstraintKind, ErrorModelSpec, Model};
use volver::core::noise::TrackerNoise;
use volver::core::plan::Plan;
use volver::core::problem::Problem;
use volver::core::results::ResultsFile;
use volver::core::simulate::{
    Effect, Magnitudes, Simulation, SimulationRecord, Truth, TruthSource,
};
use volver::solvers::nullspace::NullSpace;
use volver::solvers::strategy::{Phasing, Strategy, identify};
use volver::solvers::{Iteration, Objective, Observer, Options, Solver};

/// Volumetric verification of multi-axis machine tools with a laser tracker.
#[derive(Parser)]
#[command(name = "volver", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// The main job on the embedded default: a synthetic verification of the paper's XCFZ
    /// grinder with an effect the paper's model lacks — identify, diagnose, add the missing
    /// effect, cross-validate, compensate; writes the HTML report and controller tables.
    Demo {
        /// Output folder.
        #[arg(long, default_value = demo::DEMO_DIR)]
        out: PathBuf,
    },
    /// Identifies, diagnoses and writes one self-contained HTML report (inline SVG): machine,
    /// model, summary, colour maps and vector diagrams before/after, error functions with
    /// uncertainty bands, residual breakdowns, candidates, identifiability, cross-validation.
    Report(ReportArgs),
    /// Shows a machine and error model: chain, axes, reflectors, parameter layout, constraints.
    Layout {
        /// Machine file (TOML); the embedded XCFZ grinder when absent.
        #[arg(long)]
        machine: Option<PathBuf>,
        /// Error-model file (TOML); the paper's model when absent (needs the default machine).
        #[arg(long)]
        model: Option<PathBuf>,
        /// A test plan (preset name or grid such as X=0:1400:200,C=0:330:30,Z=0:600:150): also
        /// states in words what this layout can and cannot measure, and what would fix it.
        #[arg(long)]
        plan: Option<String>,
    },
    /// Fits the model, then shows where it fails and ranks the effects it most likely misses.
    ///
    /// Prints the residuals by axis position, reflector, time and tracker distance, the noise
    /// estimated from repeated points, the parameter combinations the data cannot separate,
    /// and the candidate effects ranked by ΔBIC with the EMM each would give.
    Diagnose {
        #[command(flatten)]
        inputs: Inputs,
        /// How many candidates to list.
        #[arg(long, default_value_t = 10)]
        top: usize,
        /// Print one JSON object instead of the tables.
        #[arg(long)]
        json: bool,
    },
    /// Runs every engine of this build on one problem and prints Φ, ve, EMM, iterations,
    /// evaluations, wall time and termination per engine (or --json).
    Compare(compare::CompareArgs),
    /// Shows the fits of a diagnosis session: EMM per model revision as a table, and as an SVG
    /// chart with --svg.
    History {
        /// History file written by `volver identify`.
        #[arg(long, default_value = history::DEFAULT_NAME)]
        file: PathBuf,
        /// Write the chart here (SVG).
        #[arg(long)]
        svg: Option<PathBuf>,
    },
    /// Reruns the paper's studies (tables 5, 6, 8, 9, 10, 11, 12) on synthetic data and prints
    /// our figures beside the paper's, with a note per table on why they differ.
    Study {
        /// Which study: paper.
        which: String,
        /// Seed of the true errors and the noise.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Also draw table 12 (cross-validation: residual % on the reference test 4 after
        /// compensation with each test's errors, ours beside the paper's) as an SVG chart here.
        #[arg(long)]
        svg: Option<PathBuf>,
    },
    /// Identifies the geometric errors and the tracker pose from measurements.
    ///
    /// Minimises Φ (or ve) under the model's constraints, starting from zero errors and a rigid
    /// best fit of the tracker pose; prints a summary table (or one JSON object with --json) and
    /// writes the parameters with --out. Progress goes to stderr.
    Identify(IdentifyArgs),
    /// Generates a synthetic test: measurements, the true errors and the machine file.
    ///
    /// Writes DIR/measurements.csv, DIR/truth.json (the true error functions and tracker pose,
    /// as a results file), DIR/machine.toml and DIR/simulation.json (inputs and figures), and
    /// prints the noise error (EMM, EMax of the noise alone, tables 9–10 of the paper).
    #[command(after_help = SIMULATE_HELP)]
    Simulate(SimulateArgs),
    /// Corrects a point list (CSV) or a G-code program with identified errors: each command
    /// becomes the one that puts the tool where the nominal machine would (inverse model,
    /// Newton with the exact Jacobian), verified through the forward model.
    Compensate(compensation::CompensateArgs),
    /// Exports identified errors as controller tables over each axis' positions: ISG CSV,
    /// Etalon exchange style and plain CSV (errors, not corrections).
    Tables(compensation::TablesArgs),
    /// The tool point of a results file at each command of a grid, in the workpiece frame (CSV,
    /// or --json): to put an identified model beside another (a simulation's truth, a second
    /// fit).
    Predict(compensation::PredictArgs),
    /// The fit with its gauge stated and the expanded uncertainty (k = 2) of every parameter
    /// and of the tool point over the volume, raw and after the set-up's rigid transform:
    /// linearised (GUM) and, with --monte-carlo N, by Monte Carlo (GUM Supplement 1).
    Uncertainty(uncertainty::UncertaintyArgs),
}

/// The machine, error model and measurements that `identify` and `diagnose` read.
#[derive(clap::Args)]
struct Inputs {
    /// Machine file (TOML); the embedded XCFZ grinder when absent.
    #[arg(long)]
    machine: Option<PathBuf>,
    /// Error model (TOML); the paper's model when absent (with the embedded machine).
    #[arg(long)]
    model: Option<PathBuf>,
    /// Measurement file (CSV).
    #[arg(long)]
    data: PathBuf,
}

impl Inputs {
    /// The input files given, with `more`.
    fn paths<'a>(&'a self, more: &[Option<&'a std::path::Path>]) -> Vec<&'a std::path::Path> {
        [
            self.machine.as_deref(),
            self.model.as_deref(),
            Some(self.data.as_path()),
        ]
        .into_iter()
        .chain(more.iter().copied())
        .flatten()
        .collect()
    }

    /// Reads the three files.
    fn load(&self) -> Result<(Machine, Model, MeasurementSet)> {
        let m = match &self.machine {
            Some(p) => Machine::load(p).context("reading the machine file")?,
            None => Machine::default_xcfz(),
        };
        let model = match (&self.model, &self.machine) {
            (Some(p), _) => Model::load(m.clone(), p).context("reading the error model")?,
            (None, None) => Model::default_xcfz(),
            (None, Some(_)) => anyhow::bail!(
                "--model is needed with --machine (the embedded model is for the embedded machine)"
            ),
        };
        let set = MeasurementSet::load(&m, &self.data).context("reading the measurements")?;
        Problem::new(&model, &set)?.check_scale(&self.data.display().to_string())?;
        Ok((m, model, set))
    }
}

/// Options of `volver identify`.
#[derive(clap::Args)]
struct IdentifyArgs {
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

const SIMULATE_HELP: &str = "\
Magnitude kinds (--magnitude KIND=VALUE; defaults in brackets):
  positioning µm [50]           EXX, EYY, EZZ
  straightness µm [30]          EYX, EZX, EXZ …
  angular µrad [50]             EAX, EBX, ECX … of linear axes
  squareness µrad [50]          A0Z, B0Z, C0Y …
  radial µm [20]                EXC, EYC
  axial µm [10]                 EZC
  tilt µrad [30]                EAC, EBC
  angular-positioning µrad [50] ECC
  location µm [30]              X0C, Y0C (when the truth model has them)
  location-tilt µrad [30]       A0C, B0C (when the truth model has them)
  tracker mm [0]                distance of the true tracker from its nominal position

Effects (--effect, repeatable):
  thermal-drift=VX,VY,VZ              tool point drifts in the machine frame, µm/h
  rotary-harmonics=H[,AMP_UM,AMP_URAD] rotary errors get harmonics up to H (default 5 µm, 10 µrad)
  tracker-tilt=RX,RY                  tracker mounted tilted, µrad
  ball-screw=AXIS,PERIOD_MM,AMP_UM    periodic positioning error A·sin(2π(u − u_ref)/P)
  reflector-offset=ID,DX,DY,DZ        reflector off its nominal offset, µm
  range-scale=PPM                     tracker range scale error

Example:
  volver simulate --plan test4 --seed 7 --out sim --effect thermal-drift=0,0,15";

fn main() -> Result<()> {
    quiet_on_broken_pipe();
    // An interrupted write leaves no hidden temporary file (a simulation's can be 100 MB).
    let _ = ctrlc::set_handler(|| {
        volver::core::fsio::remove_temporaries();
        std::process::exit(130);
    });
    let cli = Cli::parse();
    match cli.command {
        Command::Demo { out } => demo::run(&out)?,
        Command::Report(args) => report_command(args)?,
        Command::Layout {
            machine,
            model,
            plan,
        } => {
            let m = match &machine {
                Some(p) => Machine::load(p).with_context(|| "reading the machine file")?,
                None => Machine::default_xcfz(),
            };
            let model = match (&model, &machine) {
                (Some(p), _) => Model::load(m, p).with_context(|| "reading the error model")?,
                (None, None) => Model::default_xcfz(),
                (None, Some(_)) => anyhow::bail!(
                    "--model is needed with --machine (the embedded model is for the embedded machine)"
                ),
            };
            print_layout(&model)?;
            if let Some(text) = plan {
                let plan = if text.contains('=') {
                    Plan::parse_grid(model.machine(), &text)?
                } else {
                    Plan::preset(model.machine(), &text)?
                };
                let data = volver::solvers::observability::nominal_data(&model, &plan);
                println!(
                    "\nWhat plan {} ({} points) can measure with this layout:",
                    plan.name,
                    data.points.len()
                );
                print_observability(&volver::solvers::observability::observe(
                    &model,
                    &data,
                    &model.initial_params(),
                ));
            }
        }
        Command::Identify(args) => identify_command(args)?,
        Command::Compare(args) => compare::compare_command(args)?,
        Command::Diagnose { inputs, top, json } => diagnose_command(inputs, top, json)?,
        Command::History { file, svg } => {
            let records = history::read(&file)?;
            println!(
                "volver history — {} fits in {}\n",
                records.len(),
                file.display()
            );
            print!("{}", history::table(&records));
            if let Some(path) = svg {
                volver::core::fsio::write_atomic(&path, history::svg(&records))
                    .with_context(|| format!("writing {}", path.display()))?;
                println!("\n  chart written to {}", path.display());
            }
        }
        Command::Study { which, seed, svg } => {
            if which != "paper" {
                anyhow::bail!("unknown study '{which}': the study is `paper`");
            }
            println!(
                "volver study paper — the paper's studies on synthetic data (seed {seed}; each \
                 table's true errors scaled to its initial EMM in the paper; the paper's noise \
                 read as bounds, {})",
                volver::core::noise::TrackerNoise::PAPER
            );
            let tables = study::paper(seed)?;
            study::print(&tables);
            if let Some(path) = svg {
                let t12 = tables
                    .iter()
                    .find(|t| t.title.starts_with("Table 12"))
                    .ok_or_else(|| anyhow::anyhow!("the study has no table 12"))?;
                volver::core::fsio::write_atomic(&path, study::table12_svg(t12))
                    .with_context(|| format!("writing {}", path.display()))?;
                println!("\n  table 12 drawn in {}", path.display());
            }
        }
        Command::Simulate(args) => simulate(args)?,
        Command::Compensate(args) => compensation::compensate_command(args)?,
        Command::Tables(args) => compensation::tables_command(args)?,
        Command::Predict(args) => compensation::predict_command(args)?,
        Command::Uncertainty(args) => uncertainty::uncertainty_command(args)?,
    }
    Ok(())
}

/// A reader that closes the pipe early (`volver layout | head -1`) is not an error of volver:
/// Rust's `println!` panics on the broken pipe, so the panic is turned into the quiet exit a
/// process killed by SIGPIPE would make (status 141). Every other panic is reported as before.
fn quiet_on_broken_pipe() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let message = info
            .payload()
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| info.payload().downcast_ref::<&str>().copied())
            .unwrap_or("");
        if message.contains("failed printing to stdout") && message.contains("Broken pipe") {
            std::process::exit(141);
        }
        default(info);
    }));
}

fn diagnose_command(inputs: Inputs, top: usize, json: bool) -> Result<()> {
    use volver::core::diagnose;
    use volver::solvers::candidates::rank;
    use volver::solvers::identifiability::analyse;
    let (m, model, set) = inputs.load()?;
    let problem = Problem::new(&model, &set)?;
    let id = volver::solvers::strategy::fit(problem.clone());
    if id.termination.failed() {
        anyhow::bail!("the fit failed: {}", id.termination);
    }
    let r = problem.residuals(&id.params);
    let rm = diagnose::to_machine_frame(&problem, &id.params, &r);
    let breakdowns = diagnose::breakdowns(&problem, &r);
    let periodograms: Vec<(String, Vec<diagnose::Line>)> = m
        .axes()
        .iter()
        .enumerate()
        .map(|(k, ax)| {
            (
                ax.axis.to_string(),
                diagnose::axis_periodogram(&problem, &rm, k, 6),
            )
        })
        .collect();
    let repeat = diagnose::repeat_noise(&problem);
    let outliers = diagnose::largest(&r, 5);
    let describe = |i: usize| {
        let p = &set.points[i];
        let pos: Vec<String> = m
            .axes()
            .iter()
            .enumerate()
            .map(|(k, ax)| {
                let v = (ax.to_file_units(p.commands.0[k]) * 1e6).round() / 1e6;
                format!("{}={v}", ax.axis)
            })
            .collect();
        format!(
            "line {} ({} {})",
            p.line,
            pos.join(" "),
            m.reflectors()[p.reflector].id
        )
    };
    let options = Options::default();
    let ident = analyse(
        &volver::solvers::Task::new(problem.clone()),
        &id.params,
        options.rank_tolerance,
        0.99,
    );
    let ranked = rank(&problem, &id.params, options.rank_tolerance);
    let name = |j: usize| model.params()[j].name.clone();
    if json {
        let obj = serde_json::json!({
            "emm_um": id.final_.stats.emm_um,
            "emax_um": id.final_.stats.emax_um,
            "termination": id.termination.to_string(),
            "noise_estimate_um": repeat.map(|(s, _)| s.emm_um),
            "repeat_pairs": repeat.map(|(_, n)| n),
            "breakdowns": breakdowns.iter().map(|b| serde_json::json!({
                "by": b.by, "unit": b.unit, "spread": b.spread(),
                "bins": b.bins.iter().map(|x| serde_json::json!({
                    "label": x.label, "count": x.count, "emm_um": x.stats.emm_um,
                    "emax_um": x.stats.emax_um, "mean_um": x.mean_um,
                })).collect::<Vec<_>>(),
            })).collect::<Vec<_>>(),
            "periodograms": periodograms.iter().map(|(a, lines)| serde_json::json!({
                "axis": a,
                "lines": lines.iter().map(|l| serde_json::json!({
                    "order": l.frequency, "amplitude_um": l.amplitude_um,
                })).collect::<Vec<_>>(),
            })).collect::<Vec<_>>(),
            "outliers": outliers.iter().map(|(i, e)| serde_json::json!({
                "line": set.points[*i].line, "error_um": e, "where": describe(*i),
            })).collect::<Vec<_>>(),
            "identifiability": ident.as_ref().map(|a| serde_json::json!({
                "free": a.free, "rank": a.rank, "condition": a.condition,
                "weak": a.weak.iter().map(|w| w.parameters.iter().map(|(j, x)| serde_json::json!({"name": name(*j), "share": x})).collect::<Vec<_>>()).collect::<Vec<_>>(),
            })),
            "verdict": volver::solvers::candidates::verdict(&ranked, id.final_.stats.emm_um),
            "candidates": ranked.iter().take(top).map(|s| serde_json::json!({
                "id": s.id, "description": s.description, "seen": s.seen(),
                "delta_bic": s.seen().then_some(s.delta_bic),
                "emm_um": s.seen().then_some(s.emm_um),
                "size": s.seen().then_some(s.size), "size_unit": s.size_unit,
                "added": s.added, "equivalent": s.equivalent,
            })).collect::<Vec<_>>(),
        });
        println!("{}", serde_json::to_string_pretty(&obj)?);
        return Ok(());
    }
    println!(
        "volver diagnose — {} points, model \"{}\": EMM {} µm, EMax {} µm ({})",
        set.points.len(),
        model.spec().name,
        um(id.final_.stats.emm_um),
        um(id.final_.stats.emax_um),
        id.termination
    );
    match repeat {
        Some((s, n)) => println!(
            "  noise estimated from {n} repeated points: EMM {} µm — the fit is {:.2} × that",
            um(s.emm_um),
            id.final_.stats.emm_um / s.emm_um
        ),
        None => println!("  no repeated points: the noise cannot be estimated from these data"),
    }
    println!("\nWhere it fails (EMM per bin, µm; spread = largest / smallest bin):");
    for b in &breakdowns {
        let cells: Vec<String> = b
            .bins
            .iter()
            .map(|x| format!("{}:{:.1}", x.label, x.stats.emm_um))
            .collect();
        println!(
            "  {:<10} spread {:>5.2}  {}",
            format!("{} {}", b.by, b.unit).trim(),
            b.spread(),
            cells.join("  ")
        );
    }
    let worst: Vec<String> = outliers
        .iter()
        .map(|(i, e)| format!("{} {:.1} µm", describe(*i), e))
        .collect();
    println!("  largest residuals: {}", worst.join("; "));
    println!("\nPeriodograms of the residuals in the machine frame (amplitude µm of orders 1–6):");
    for (a, lines) in &periodograms {
        let cells: Vec<String> = lines
            .iter()
            .map(|l| format!("{:.1}", l.total_um()))
            .collect();
        println!("  {a}: {}", cells.join("  "));
    }
    if let Some(a) = &ident {
        println!(
            "\nIdentifiability: {} of {} free directions identified, condition {:.2e}",
            a.rank, a.free, a.condition
        );
        for w in a.weak.iter().take(4) {
            let parts: Vec<String> = w
                .parameters
                .iter()
                .take(4)
                .map(|(j, x)| format!("{} {x:+.2}", name(*j)))
                .collect();
            println!("  cannot separate: {}", parts.join(", "));
        }
    }
    println!(
        "\nVerdict: {}",
        volver::solvers::candidates::verdict(&ranked, id.final_.stats.emm_um)
    );
    println!("\nWhat is most likely missing (ranked by ΔBIC; below −10 is strong evidence):");
    println!(
        "  {:<3} {:<18} {:>10} {:>12} {:>12}  meaning",
        "#", "candidate", "ΔBIC", "EMM µm", "size"
    );
    for (i, s) in ranked.iter().take(top).enumerate() {
        let (bic, emm, size) = if s.seen() {
            (
                format!("{:.1}", s.delta_bic),
                um(s.emm_um),
                format!("{:>8.2} {:<4}", s.size, s.size_unit),
            )
        } else {
            ("—".into(), "—".into(), format!("{:>8} {:<4}", "—", ""))
        };
        println!(
            "  {:<3} {:<18} {:>10} {:>12} {size}  {}{}{}",
            i + 1,
            s.id,
            bic,
            emm,
            if s.seen() {
                ""
            } else {
                "not seen in these data: "
            },
            s.description,
            if s.equivalent.is_empty() {
                String::new()
            } else {
                format!(" (indistinguishable here from {})", s.equivalent.join(", "))
            }
        );
    }
    Ok(())
}

/// Options of `volver report`.
#[derive(clap::Args)]
struct ReportArgs {
    #[command(flatten)]
    inputs: Inputs,
    /// Candidates to add to the model before the final fit (ids from `volver diagnose`); the
    /// report shows the fit without and with them.
    #[arg(long)]
    add: Vec<String>,
    /// True errors (results file), for synthetic data: overlaid on the error functions.
    #[arg(long)]
    truth: Option<PathBuf>,
    /// A reference measurement file: the identified errors compensate it (cross-validation).
    #[arg(long)]
    reference: Option<PathBuf>,
    /// The HTML file to write.
    #[arg(long, default_value = "volver-report.html")]
    out: PathBuf,
    /// The results file of the final fit (JSON) that `volver compensate` and `volver tables`
    /// read; default: beside the report, with the extension `.json`.
    #[arg(long)]
    results: Option<PathBuf>,
    /// The tool point whose compensated position's uncertainty the report maps, mm in the frame
    /// of the last tool-side axis (like a reflector offset); default the reflectors' centroid.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
    tool_offset: Option<String>,
    /// The U (µm, k = 2) above which `compensate` and `tables` refuse; the report says whether
    /// the tool point passes.
    #[arg(long, default_value_t = 25.0)]
    max_u_um: f64,
}

/// `model` with the candidates `ids` (from `volver diagnose`) added in turn.
fn with_candidates(machine: &Machine, mut model: Model, ids: &[String]) -> Result<Model> {
    for id in ids {
        let library = volver::solvers::candidates::library(&model);
        let Some(c) = library.iter().find(|c| &c.id == id) else {
            let ids: Vec<&str> = library.iter().map(|c| c.id.as_str()).collect();
            anyhow::bail!(
                "--add {id}: not a candidate for this model; candidates are {}",
                ids.join(", ")
            );
        };
        model = Model::new(machine.clone(), c.spec.clone())?;
    }
    Ok(model)
}

fn report_command(a: ReportArgs) -> Result<()> {
    let (machine, model, data) = a.inputs.load()?;
    compensation::check_max_u(a.max_u_um)?;
    let tool = compensation::tool_point_of(a.tool_offset.as_deref(), None, &model)?;
    let problem = Problem::new(&model, &data)?;
    let id1 = volver::solvers::strategy::fit(problem.clone());
    if id1.termination.failed() {
        anyhow::bail!("the fit failed: {}", id1.termination);
    }
    let options = Options::default();
    let candidates =
        volver::solvers::candidates::rank(&problem, &id1.params, options.rank_tolerance);
    let extended = with_candidates(&machine, model.clone(), &a.add)?;
    let id2 = if a.add.is_empty() {
        None
    } else {
        let id = volver::solvers::strategy::fit(Problem::new(&extended, &data)?);
        if id.termination.failed() {
            anyhow::bail!(
                "the fit with {} failed: {}",
                a.add.join(", "),
                id.termination
            );
        }
        Some(id)
    };
    let truth = match &a.truth {
        Some(p) => Some(
            ResultsFile::load(p)
                .context("reading the truth file")?
                .to_model(&p.display().to_string())?,
        ),
        None => None,
    };
    let (last_model, last_params) = match &id2 {
        Some(id) => (&extended, &id.params),
        None => (&model, &id1.params),
    };
    let mut cross = Vec::new();
    if let Some(path) = &a.reference {
        let set =
            MeasurementSet::load(&machine, path).context("reading the reference measurements")?;
        Problem::new(&model, &set)?.check_scale(&path.display().to_string())?;
        let lm = volver::solvers::lm::LevenbergMarquardt;
        let reference = Problem::new(last_model, &set)?;
        let cv = volver::solvers::strategy::cross_validate(
            &lm,
            reference.clone(),
            last_params,
            &options,
            &mut volver::solvers::Silent,
        );
        let model_label = if a.add.is_empty() {
            format!("model \"{}\"", model.spec().name)
        } else {
            format!("model \"{}\" + {}", model.spec().name, a.add.join(" + "))
        };
        cross.push(report::CrossRow::new(
            format!("{} ({model_label})", a.inputs.data.display()),
            &reference,
            &cv,
        ));
    }
    let mut fits = vec![report::Fit {
        label: model.spec().name.clone(),
        model: &model,
        id: &id1,
    }];
    if let Some(id) = &id2 {
        fits.push(report::Fit {
            label: format!("+ {}", a.add.join(" + ")),
            model: &extended,
            id,
        });
    }
    let (last_model, last_params) = (last_model.clone(), last_params.clone());
    let input = report::ReportInput {
        title: format!("volver report — {}", a.inputs.data.display()),
        data_label: a.inputs.data.display().to_string(),
        data: &data,
        fits,
        truth: truth.as_ref().map(|(m, p)| (m, p.as_slice())),
        noise_um: None,
        candidates,
        engines: Vec::new(),
        cross,
        notes: Vec::new(),
        tool,
        max_u_um: a.max_u_um,
    };
    let html = report::html(&input)?;
    let results_path = a
        .results
        .clone()
        .unwrap_or_else(|| a.out.with_extension("json"));
    let inputs = a
        .inputs
        .paths(&[a.reference.as_deref(), a.truth.as_deref()]);
    for out in [&a.out, &results_path] {
        volver::core::fsio::check_not_an_input(out, &inputs)?;
    }
    volver::core::fsio::write_atomic(&a.out, html)
        .with_context(|| format!("writing {}", a.out.display()))?;
    ResultsFile::from_model(&last_model, &last_params)?
        .save(&results_path)
        .context("writing the results file")?;
    println!(
        "volver report — written to {}; the final fit's errors to {} (for compensate and tables)",
        a.out.display(),
        results_path.display()
    );
    Ok(())
}

/// Prints one line per accepted step to stderr.
struct Progress {
    quiet: bool,
}

impl Observer for Progress {
    fn iteration(&mut self, it: &Iteration) {
        if !self.quiet && it.accepted {
            eprintln!(
                "  iteration {:>4}  evaluations {:>5}  EMM {:>12.6} µm  λ {:.1e}",
                it.iteration, it.evaluations, it.emm_um, it.damping
            );
        }
    }
}

fn identify_command(a: IdentifyArgs) -> Result<()> {
    let inputs = a.inputs.paths(&[a.truth.as_deref()]);
    for out in [&a.out, &a.write_model, &a.history].into_iter().flatten() {
        volver::core::fsio::check_not_an_input(out, &inputs)?;
    }
    let (machine, model, data) = a.inputs.load()?;
    let model = with_candidates(&machine, model, &a.add)?;
    if let Some(path) = &a.write_model {
        let text = toml::to_string(model.spec()).context("writing the error model")?;
        volver::core::fsio::write_atomic(path, text)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    let objective: Objective = a.objective.parse().map_err(anyhow::Error::msg)?;
    // The noise model of the uncertainty the results file records (checked before the fit).
    let noise_model = uncertainty::noise_of(a.noise.as_deref())?;
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
            .unwrap_or_else(|| history::default_path(&a.inputs.data));
        history::append(
            &path,
            &history::Record {
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
                    .map(|c| uncertainty::combination_text(&model, g, c))
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

/// A length in µm for tables: fixed-point, or scientific when below 0.01 µm.
fn um(v: f64) -> String {
    if v != 0.0 && v.abs() < 0.01 {
        format!("{v:.3e}")
    } else {
        format!("{v:.4}")
    }
}

/// Options of `volver simulate`.
#[derive(clap::Args)]
struct SimulateArgs {
    /// Test plan: table4, table7, test1 … test5, or a grid such as X=0:1400:100,Z=0:600:50,C=0
    /// (file units: mm, degrees).
    #[arg(long, default_value = "test4")]
    plan: String,
    /// Seed of the true errors, the harmonics' phases and the noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Output folder (created if missing; files of the same names are replaced).
    #[arg(long)]
    out: PathBuf,
    /// Machine file (TOML); the embedded XCFZ grinder when absent.
    #[arg(long)]
    machine: Option<PathBuf>,
    /// True errors from a results file (JSON) instead of random ones.
    #[arg(long, conflicts_with_all = ["truth_model", "magnitude"])]
    truth: Option<PathBuf>,
    /// Error model (TOML) giving the structure of the random true errors; every error of the
    /// machine (cubic / first harmonic) when absent.
    #[arg(long)]
    truth_model: Option<PathBuf>,
    /// Size of the random true errors of one kind, e.g. straightness=20 (see below).
    #[arg(long = "magnitude", value_name = "KIND=VALUE")]
    magnitude: Vec<String>,
    /// Tracker noise: paper (uniform on ±30 µrad, ±30 µrad, ±(4 µm + 0.8 µm/m): the paper's
    /// "±" values read as bounds, which reproduces its tables 9–10), none, or a distribution and
    /// four values: normal:AZ_URAD,EL_URAD,RANGE_UM,RANGE_UM_PER_M (σ) or uniform:… (bounds).
    #[arg(long, default_value = "paper")]
    noise: String,
    /// An effect outside the standard model, hidden in the data (see below); repeatable.
    #[arg(long = "effect", value_name = "EFFECT=VALUES")]
    effect: Vec<String>,
    /// Test duration in hours (time stamps t_s); 10 s per point when absent.
    #[arg(long)]
    duration_h: Option<f64>,
    /// Reflectors measured at each position, ids comma-separated; all when absent.
    #[arg(long)]
    reflectors: Option<String>,
}

fn simulate(a: SimulateArgs) -> Result<()> {
    let given_machine = match &a.machine {
        Some(p) => Some(Machine::load(p).context("reading the machine file")?),
        None => None,
    };
    let (truth, source) = match &a.truth {
        Some(path) => {
            let label = path.display().to_string();
            let results = ResultsFile::load(path).context("reading the truth file")?;
            let truth = Truth::from_results(&results, &label).context("reading the truth file")?;
            if let Some(m) = &given_machine
                && m.spec() != truth.model.machine().spec()
            {
                anyhow::bail!(
                    "the machine of {label} differs from --machine {}; leave --machine out to use the truth's machine",
                    a.machine
                        .as_ref()
                        .map(|p| p.display().to_string())
                        .unwrap_or_default()
                );
            }
            (truth, TruthSource::File { path: label })
        }
        None => {
            let m = given_machine.unwrap_or_else(Machine::default_xcfz);
            let structure = match &a.truth_model {
                Some(p) => Model::load(m.clone(), p)
                    .context("reading the truth model")?
                    .spec()
                    .clone(),
                None => ErrorModelSpec::complete(&m),
            };
            let mut magnitudes = Magnitudes::default();
            for text in &a.magnitude {
                magnitudes.set_from_text(text)?;
            }
            let truth = Truth::random(&m, &structure, &magnitudes, a.seed)
                .context("drawing the true errors")?;
            let source = TruthSource::Random {
                structure: structure.name.clone(),
                magnitudes,
            };
            (truth, source)
        }
    };
    let machine = truth.model.machine().clone();
    let mut plan = if a.plan.contains('=') {
        Plan::parse_grid(&machine, &a.plan)?
    } else {
        Plan::preset(&machine, &a.plan)? // an unknown name gets the list of presets
    };
    if let Some(list) = &a.reflectors {
        plan.reflectors = list
            .split(',')
            .map(|id| {
                machine.reflector_index(id.trim()).ok_or_else(|| {
                    anyhow::anyhow!(
                        "--reflectors: no reflector '{}' in the machine (it has {})",
                        id.trim(),
                        machine
                            .reflectors()
                            .iter()
                            .map(|r| r.id.as_str())
                            .collect::<Vec<_>>()
                            .join(", ")
                    )
                })
            })
            .collect::<Result<_>>()?;
    }
    let mut sim = Simulation::new(plan, truth, a.seed);
    sim.truth_source = source;
    sim.noise = TrackerNoise::from_text(&a.noise)?;
    sim.effects = a
        .effect
        .iter()
        .map(|t| Effect::parse(t))
        .collect::<volver::core::Result<_>>()?;
    if let Some(h) = a.duration_h {
        sim.duration_s = Some(h * 3600.0);
    }
    let out = sim.run()?;
    let files = out.write(&a.out)?;
    let r = &out.record;
    println!(
        "volver simulate — plan {} ({} positions × {} reflectors = {} points), seed {}",
        r.plan,
        r.positions,
        r.reflectors.len(),
        r.points,
        r.seed
    );
    println!("  machine: {} ({})", machine.spec().name, machine.chain());
    match &r.truth {
        TruthSource::Random { structure, .. } => {
            println!("  true errors: random, structure \"{structure}\"")
        }
        TruthSource::File { path } => println!("  true errors: from {path}"),
        TruthSource::Given => println!("  true errors: given"),
    }
    let n = &r.noise;
    println!(
        "  noise: {:?} in azimuth {} µrad, elevation {} µrad, range {} µm + {} µm/m ({}; --noise {n})",
        n.distribution,
        n.azimuth_urad,
        n.elevation_urad,
        n.range_um,
        n.range_um_per_m,
        match n.distribution {
            volver::core::noise::Distribution::Normal => "σ",
            volver::core::noise::Distribution::Uniform => "bounds ±a, σ = a/√3",
        }
    );
    if r.effects.is_empty() {
        println!("  hidden effects: none");
    } else {
        let list: Vec<String> = r.effects.iter().map(ToString::to_string).collect();
        println!("  hidden effects: {}", list.join("  "));
    }
    println!(
        "  duration: {:.2} h (t_s from 0 to {:.0} s)",
        r.duration_s / 3600.0,
        r.duration_s
    );
    println!(
        "\nMachine error (noise-free vs nominal points): EMM {:>8.2} µm   EMax {:>8.2} µm",
        r.machine_error.emm_um, r.machine_error.emax_um
    );
    println!(
        "Noise error (measured vs noise-free points):  EMM {:>8.2} µm   EMax {:>8.2} µm",
        r.noise_error.emm_um, r.noise_error.emax_um
    );
    println!("\nWrote:");
    let what = [
        format!("{} points", r.points),
        format!("{} parameters", out.truth.model.n_params()),
        format!("chain {}", machine.chain()),
        "inputs and figures".to_string(),
    ];
    for (path, what) in files.iter().zip(what) {
        println!("  {}  ({what})", path.display());
    }
    Ok(())
}

/// Prints the findings of [`volver::solvers::observability::observe`], or that there are none.
fn print_observability(findings: &[volver::solvers::observability::Finding]) {
    if findings.is_empty() {
        println!("  everything the model describes can be identified from these positions");
    }
    for f in findings {
        println!("  - {}\n      fix: {}", f.what, f.fix);
    }
}

fn print_layout(model: &Model) -> Result<()> {
    let m = model.machine();
    println!("Machine: {}", m.spec().name);
    println!(
        "Chain {}: workpiece side {} (from the frame out), tool side {}",
        m.chain(),
        letters(&m.chain().workpiece),
        letters(&m.chain().tool)
    );
    println!("\n  axis  side       range                     reference   offset (mm)");
    for a in m.axes() {
        println!(
            "  {:<4}  {:<9}  [{:>8.1}, {:>8.1}] {:<4}  {:>8.1} {:<3}  ({}, {}, {})",
            a.axis.letter(),
            format!("{:?}", a.side).to_lowercase(),
            a.to_file_units(a.min),
            a.to_file_units(a.max),
            a.file_unit(),
            a.to_file_units(a.reference),
            a.file_unit(),
            a.offset[0],
            a.offset[1],
            a.offset[2]
        );
    }
    println!("\n  reflector  offset (mm)");
    for r in m.reflectors() {
        println!(
            "  {:<9}  ({}, {}, {})",
            r.id, r.offset[0], r.offset[1], r.offset[2]
        );
    }
    let t = m.tracker();
    println!(
        "\nTracker: on the {} · nominal T_LT ({}, {}, {}) mm",
        match t.mount {
            TrackerMount::Workpiece => "workpiece end of the chain",
            TrackerMount::Frame => "machine frame",
        },
        t.position[0],
        t.position[1],
        t.position[2]
    );

    let spec = model.spec();
    println!(
        "\nError model: {} (squareness rule: {})",
        spec.name, spec.squareness
    );
    println!("\n  error  basis                   parameters");
    for term in model.terms() {
        let b = &term.basis;
        let basis = match b.kind() {
            k if k.is_periodic() => format!("{k}, order {}", b.degree()),
            volver::core::basis::BasisKind::Chebyshev => {
                format!("chebyshev, {} nodes", b.degree() + 1)
            }
            volver::core::basis::BasisKind::Constant => "constant".to_string(),
            k => format!("{k}, degree {}", b.degree()),
        };
        let names: Vec<&str> = model.params()[term.params.clone()]
            .iter()
            .map(|p| p.name.as_str())
            .collect();
        println!(
            "  {:<5}  {:<22}  {}",
            term.id.to_string(),
            basis,
            names.join(" ")
        );
    }
    println!("\nParameter layout ({} parameters):", model.n_params());
    println!(
        "  {:>3}  {:<12} {:<4} {:<12} {:>12}",
        "#", "name", "unit", "group", "start value"
    );
    let p0 = model.initial_params();
    for (i, p) in model.params().iter().enumerate() {
        println!(
            "  {:>3}  {:<12} {:<4} {:<12} {:>12}",
            i,
            p.name,
            p.unit.to_string(),
            p.group.to_string(),
            p0[i]
        );
    }
    let rows = &model.constraints().rows;
    println!("\nConstraints A p = b ({} rows):", rows.len());
    for kind in [
        ConstraintKind::Reference,
        ConstraintKind::Squareness,
        ConstraintKind::Fixed,
    ] {
        for r in rows.iter().filter(|r| r.kind == kind) {
            println!("  {:<10}  {}", format!("{kind:?}").to_lowercase(), r.label);
        }
    }
    let ns = NullSpace::for_model(model).context("eliminating the constraints")?;
    println!(
        "\nFree parameters after the constraints: {} of {} (constraint rank {}, {} redundant rows)",
        ns.n_free(),
        model.n_params(),
        ns.rank(),
        ns.redundant()
    );
    Ok(())
}

/// The demo's synthetic test 4 on `model`'s machine: random true errors in the model (default
/// magnitudes), the paper's tracker noise, seed [`demo::DEMO_SEED`], no hidden effect.
/// `volver compare` uses it.
fn demo_test4(model: &Model) -> Result<volver::core::simulate::Synthetic> {
    let m = model.machine();
    let truth = Truth::random(m, model.spec(), &Magnitudes::default(), demo::DEMO_SEED)?;
    Ok(Simulation::new(Plan::preset(m, "test4")?, truth, demo::DEMO_SEED).run()?)
}

fn letters(v: &[volver::core::iso::Axis]) -> String {
    if v.is_empty() {
        "(none)".into()
    } else {
        v.iter().map(|a| a.letter()).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use volver::core::simulate::{EFFECTS, MAGNITUDE_KINDS};

    /// The help text lists every magnitude kind with its real default, and every effect.
    #[test]
    fn simulate_help_matches_the_library() {
        let defaults = serde_json::to_value(Magnitudes::default()).unwrap();
        for (kind, unit, _) in MAGNITUDE_KINDS {
            let field = format!(
                "{}_{}",
                kind.replace('-', "_"),
                match unit {
                    "µm" => "um",
                    "µrad" => "urad",
                    _ => "mm",
                }
            );
            let v = defaults[&field]
                .as_f64()
                .unwrap_or_else(|| panic!("{field}"));
            let entry = format!("{kind} {unit} [{v}]");
            assert!(SIMULATE_HELP.contains(&entry), "help lacks '{entry}'");
        }
        for (_, syntax, _) in EFFECTS {
            assert!(SIMULATE_HELP.contains(syntax), "help lacks '{syntax}'");
        }
    }
}
