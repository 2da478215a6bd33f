//! The `volver` command-line tool: the argument definitions and the dispatch. Each subcommand
//! parses its arguments, calls the library and prints, in `cmd/<verb>.rs`.

mod cmd;

use anyhow::Result;
use clap::{Parser, Subcommand};
use cmd::{
    compare, compensate, demo, diagnose, history, identify, layout, plan, report, simulate, study,
    tables, uncertainty,
};

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
    Demo(demo::DemoArgs),
    /// Identifies, diagnoses and writes one self-contained HTML report (inline SVG): machine,
    /// model, summary, colour maps and vector diagrams before/after, error functions with
    /// uncertainty bands, residual breakdowns, candidates, identifiability, cross-validation.
    Report(report::ReportArgs),
    /// Shows a machine and error model: chain, axes, reflectors, parameter layout, constraints.
    Layout(layout::LayoutArgs),
    /// Fits the model, then shows where it fails and ranks the effects it most likely misses.
    ///
    /// Prints the residuals by axis position, reflector, time and tracker distance, the noise
    /// estimated from repeated points, the parameter combinations the data cannot separate,
    /// and the candidate effects ranked by ΔBIC with the EMM each would give.
    Diagnose(diagnose::DiagnoseArgs),
    /// Runs every engine of this build on one problem and prints Φ, ve, EMM, iterations,
    /// evaluations, wall time and termination per engine (or --json).
    Compare(compare::CompareArgs),
    /// Shows the fits of a diagnosis session: EMM per model revision as a table, and as an SVG
    /// chart with --svg.
    History(history::HistoryArgs),
    /// Reruns the paper's studies (tables 5, 6, 8, 9, 10, 11, 12) on synthetic data and prints
    /// our figures beside the paper's, with a note per table on why they differ.
    Study(study::StudyArgs),
    /// Identifies the geometric errors and the tracker pose from measurements.
    ///
    /// Minimises Φ (or ve) under the model's constraints, starting from zero errors and a rigid
    /// best fit of the tracker pose; prints a summary table (or one JSON object with --json) and
    /// writes the parameters with --out. Progress goes to stderr.
    Identify(identify::IdentifyArgs),
    /// Generates a synthetic test: measurements, the true errors and the machine file.
    ///
    /// Writes DIR/measurements.csv, DIR/truth.json (the true error functions and tracker pose,
    /// as a results file), DIR/machine.toml and DIR/simulation.json (inputs and figures), and
    /// prints the noise error (EMM, EMax of the noise alone, tables 9–10 of the paper).
    #[command(after_help = simulate::SIMULATE_HELP)]
    Simulate(simulate::SimulateArgs),
    /// Corrects a point list (CSV) or a G-code program with identified errors: each command
    /// becomes the one that puts the tool where the nominal machine would (inverse model,
    /// Newton with the exact Jacobian), verified through the forward model.
    Compensate(compensate::CompensateArgs),
    /// Exports identified errors as controller tables over each axis' positions: ISG CSV,
    /// Etalon exchange style and plain CSV (errors, not corrections).
    Tables(tables::TablesArgs),
    /// The tool point of a results file at each command of a grid, in the workpiece frame (CSV,
    /// or --json): to put an identified model beside another (a simulation's truth, a second
    /// fit).
    Predict(compensate::PredictArgs),
    /// The fit with its gauge stated and the expanded uncertainty (k = 2) of every parameter
    /// and of the tool point over the volume, raw and after the set-up's rigid transform:
    /// linearised (GUM) and, with --monte-carlo N, by Monte Carlo (GUM Supplement 1).
    Uncertainty(uncertainty::UncertaintyArgs),
    /// Designs a verification: the poses and reflectors that identify the tool point
    /// compensation needs (I- or D-optimal), in an order that keeps drift separable, written as
    /// a plan file (`simulate --plan-file`) and a measuring program; `--compare` runs plans on
    /// simulated truths.
    Plan(plan::PlanArgs),
}

fn main() -> std::process::ExitCode {
    quiet_on_broken_pipe();
    // The passes of the engines start on this thread instead of being handed over.
    volver::solvers::share_calling_thread();
    // An interrupted write leaves no hidden temporary file (a simulation's can be 100 MB).
    let _ = ctrlc::set_handler(|| {
        volver::core::fsio::remove_temporaries();
        std::process::exit(130);
    });
    match dispatch(Cli::parse().command) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("{}", user_error(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// An error of the input (a file, an option) as anyhow's `Error: …` / `Caused by:` text, without
/// the stack backtrace anyhow captures when `RUST_BACKTRACE` is set: a user error is not a bug of
/// volver, and the backtrace only hides the message. Panics (real bugs) keep their backtrace.
fn user_error(e: &anyhow::Error) -> String {
    let mut text = format!("Error: {e}");
    let causes: Vec<String> = e.chain().skip(1).map(ToString::to_string).collect();
    if !causes.is_empty() {
        text.push_str("\n\nCaused by:");
        for (i, c) in causes.iter().enumerate() {
            if causes.len() == 1 {
                text.push_str(&format!("\n    {c}"));
            } else {
                text.push_str(&format!("\n    {i}: {c}"));
            }
        }
    }
    text
}

/// Runs one subcommand.
fn dispatch(command: Command) -> Result<()> {
    match command {
        Command::Demo(a) => demo::run(a),
        Command::Report(a) => report::run(a),
        Command::Layout(a) => layout::run(a),
        Command::Identify(a) => identify::run(a),
        Command::Compare(a) => compare::compare_command(a),
        Command::Diagnose(a) => diagnose::run(a),
        Command::History(a) => history::run(a),
        Command::Study(a) => study::run(a),
        Command::Simulate(a) => simulate::run(a),
        Command::Compensate(a) => compensate::compensate_command(a),
        Command::Tables(a) => tables::tables_command(a),
        Command::Predict(a) => compensate::predict_command(a),
        Command::Uncertainty(a) => uncertainty::uncertainty_command(a),
        Command::Plan(a) => plan::run(a),
    }
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
