//! `volver layout`: a machine and error model in words and tables.

use super::print_observability;
use anyhow::{Context, Result};
use std::path::PathBuf;
use volver::core::machine::TrackerMount;
use volver::core::model::{ConstraintKind, Model};
use volver::solvers::nullspace::NullSpace;

/// Options of `volver layout`.
#[derive(clap::Args)]
pub struct LayoutArgs {
    /// Names every embedded machine, one per line: name, chain, what it is.
    #[arg(long, conflicts_with_all = ["machine", "model", "plan"])]
    list: bool,
    /// Machine file (TOML) or an embedded machine's name; the embedded XCFZ grinder when absent.
    #[arg(long)]
    machine: Option<PathBuf>,
    /// Error-model file (TOML); the embedded machine's default model when absent (the paper's
    /// model on the XCFZ grinder).
    #[arg(long)]
    model: Option<PathBuf>,
    /// A test plan (a preset name such as test4, an embedded machine's name for its preset
    /// plan, or grids such as X=0:1400:200,C=0:330:30,Z=0:600:150): also states in words what
    /// this layout can and cannot measure, and what would fix it.
    #[arg(long)]
    plan: Option<String>,
    /// With --plan: the parameters to hold so that the model is identifiable on the plan (chosen
    /// greedily: rotary-axis component errors before location errors, the tracker's pose last),
    /// each with the motion it makes with the others, and the `[fixed]` table that holds them.
    #[arg(long, requires = "plan")]
    redundant: bool,
}

/// Runs `volver layout`.
pub fn run(a: LayoutArgs) -> Result<()> {
    if a.list {
        for p in &volver::core::presets::PRESETS {
            let m = p.machine()?;
            println!(
                "{:<12} {:<7} {}",
                p.name,
                m.chain().to_string(),
                p.description
            );
        }
        return Ok(());
    }
    let (_, preset) = volver::inputs::machine(a.machine.as_deref())?;
    let (_, model) = volver::inputs::machine_and_model(a.machine.as_deref(), a.model.as_deref())?;
    print_layout(&model)?;
    if let Some(text) = a.plan {
        let plan = volver::inputs::plan(model.machine(), preset, Some(&text))?;
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
        print_reversals(&model, &data);
        if a.redundant {
            print_redundant(&model, &data)?;
        }
    }
    Ok(())
}

/// What the plan's measuring order lets a fit say of each axis' reversal, whatever the model.
fn print_reversals(model: &Model, data: &volver::core::measure::MeasurementSet) {
    let lines = volver::solvers::observability::reversal_lines(model.machine(), data);
    if lines.is_empty() {
        return;
    }
    println!(
        "\nReversals (ISO 230-2's B, backlash) this plan's order can measure: only positions \
         reached from both sides separate an axis' reversal from its positioning error"
    );
    for (words, _) in &lines {
        println!("  - {words}");
    }
}

/// The parameters to hold for an identifiable model, and the `[fixed]` table.
fn print_redundant(model: &Model, data: &volver::core::measure::MeasurementSet) -> Result<()> {
    use volver::solvers::observability::{hold_order, redundant_parameters};
    let task = volver::solvers::Task::new(volver::core::problem::Problem::new(model, data)?);
    let p = model.initial_params();
    let held = redundant_parameters(&task, &p, &hold_order(model))
        .context("the design's analysis failed (a Jacobian that is not finite)")?;
    let name = |j: usize| model.params()[j].name.as_str();
    if held.is_empty() {
        println!("\nNo parameter is redundant on this plan: the model is identifiable.");
        return Ok(());
    }
    println!(
        "\n{} parameter(s) to hold for a model this plan identifies (moving each by 1 and the \
         others by the factors shown changes no measured point, to first order):",
        held.len()
    );
    for r in &held {
        let with: Vec<String> = r
            .with
            .iter()
            .take(4)
            .map(|&(k, c)| format!("{c:+.4} {}", name(k)))
            .collect();
        let more = r.with.len().saturating_sub(4);
        println!(
            "  {:<14} with {}{}",
            name(r.param),
            if with.is_empty() {
                "nothing (no measured point sees it)".to_string()
            } else {
                with.join(", ")
            },
            if more > 0 {
                format!(" and {more} more")
            } else {
                String::new()
            }
        );
    }
    println!("\n[fixed]");
    for r in &held {
        println!("\"{}\" = {}", name(r.param), p[r.param]);
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
    let mount = |t: &volver::core::machine::TrackerSetup| match t.mount {
        TrackerMount::Workpiece => "workpiece end of the chain",
        TrackerMount::Frame => "machine frame",
        _ => "another mount",
    };
    if m.has_stations() {
        println!("\nStations (multilateration; each measurement names its own):");
        println!("  station  observes  mount                       nominal position (mm)");
        for st in m.stations() {
            let p = st.setup.position;
            println!(
                "  {:<8} {:<9} {:<27} ({}, {}, {})",
                st.id,
                format!("{:?}", st.observes).to_lowercase(),
                mount(&st.setup),
                p[0],
                p[1],
                p[2]
            );
        }
    } else {
        let t = m.tracker();
        println!(
            "\nTracker: on the {} · nominal T_LT ({}, {}, {}) mm",
            mount(t),
            t.position[0],
            t.position[1],
            t.position[2]
        );
    }

    print_model(model)
}

/// The error model: terms and bases, parameter layout, constraints and free parameters.
fn print_model(model: &Model) -> Result<()> {
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

fn letters(v: &[volver::core::iso::Axis]) -> String {
    if v.is_empty() {
        "(none)".into()
    } else {
        v.iter().map(|a| a.letter()).collect()
    }
}
