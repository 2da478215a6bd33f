//! The `volver` command-line tool.

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use std::path::PathBuf;
use volver::core::machine::{Machine, TrackerMount};
use volver::core::model::{ConstraintKind, Model};
use volver::solvers::nullspace::NullSpace;

/// Volumetric verification of multi-axis machine tools with a laser tracker.
#[derive(Parser)]
#[command(name = "volver", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// The main job on the embedded default: the paper's XCFZ grinder and its error model.
    Demo,
    /// Shows a machine and error model: chain, axes, reflectors, parameter layout, constraints.
    Layout {
        /// Machine file (TOML); the embedded XCFZ grinder when absent.
        #[arg(long)]
        machine: Option<PathBuf>,
        /// Error-model file (TOML); the paper's model when absent (needs the default machine).
        #[arg(long)]
        model: Option<PathBuf>,
    },
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Demo => {
            println!(
                "volver demo — the embedded XCFZ grinder of Aguado et al. (2014) and the paper's error model\n"
            );
            let model = Model::default_xcfz();
            print_layout(&model)?;
            print_nominal_points(&model);
        }
        Command::Layout { machine, model } => {
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
        }
    }
    Ok(())
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

/// Nominal predicted points (every error zero) at a few commands, with the Jacobian's size.
fn print_nominal_points(model: &Model) {
    let m = model.machine();
    let p = model.initial_params();
    let mut jac = vec![0.0; 3 * model.n_params()];
    println!("\nForward model (eq. 11), every error zero, tracker at its nominal pose:");
    let header: Vec<String> = m
        .axes()
        .iter()
        .map(|a| format!("{} ({})", a.axis, a.file_unit()))
        .collect();
    println!(
        "  {:<28} refl.  predicted point in the tracker frame (mm)   |∂x/∂p| (largest column)",
        header.join(" ")
    );
    for pos in [
        [0.0, 0.0, 0.0],
        [700.0, 90.0, 300.0],
        [1400.0, 225.0, 600.0],
    ] {
        let cmd = m.commands_from_file_units(&pos);
        for r in 0..m.reflectors().len() {
            let x = model.predict_with_jacobian(&cmd, r, &p, &mut jac);
            let n = model.n_params();
            let (best, norm) = (0..n)
                .map(|j| {
                    (
                        j,
                        (jac[j].powi(2) + jac[n + j].powi(2) + jac[2 * n + j].powi(2)).sqrt(),
                    )
                })
                .fold((0, 0.0), |a, b| if b.1 > a.1 { b } else { a });
            let cmd_text: Vec<String> = pos.iter().map(|v| format!("{v}")).collect();
            println!(
                "  {:<28} {:<5}  ({:>10.3}, {:>10.3}, {:>10.3})   {} = {:.1} mm/{}",
                cmd_text.join(", "),
                m.reflectors()[r].id,
                x[0],
                x[1],
                x[2],
                model.params()[best].name,
                norm,
                model.params()[best].unit
            );
        }
    }
    println!(
        "\nThis version builds and evaluates the model; simulation, identification and diagnosis come next (README, roadmap)."
    );
}

fn letters(v: &[volver::core::iso::Axis]) -> String {
    if v.is_empty() {
        "(none)".into()
    } else {
        v.iter().map(|a| a.letter()).collect()
    }
}
