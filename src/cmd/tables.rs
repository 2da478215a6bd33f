//! `volver tables`: the identified errors as tables for controls — the error tables of a
//! volumetric compensation (ISG, Etalon, plain CSV) and the per-axis tables most controls take
//! (LinuxCNC, Siemens leadscrew and cross-axis compensation), with what each leaves.

use super::compensate::apply;
use anyhow::{Context, Result, bail};
use std::path::PathBuf;
use volver::compensation::{
    Format, PerAxisComparison, check_max_u, controller_files, load_results, parse_formats,
    point_mm, table_uncertainty, tool_point_of, vouch,
};
use volver::core::fsio::write_atomic;
use volver::core::model::Model;
use volver::core::tables::ErrorTables;
use volver::core::tables::siemens::{CecSign, SiemensOptions};
use volver::core::units::{UM_PER_MM, URAD_PER_RAD};

/// Options of `volver tables`.
#[derive(clap::Args)]
pub struct TablesArgs {
    /// Results file of `volver identify`.
    #[arg(long)]
    results: PathBuf,
    /// Output folder: writes the files of each format of --format, and
    /// per-axis-leftover.csv / .txt (what per-axis tables leave).
    #[arg(long)]
    out: PathBuf,
    /// The formats to write, comma-separated (default all): isg (errors-isg.csv), etalon
    /// (errors-etalon.txt), csv (errors.csv and errors-u95.csv), linuxcnc (compX.txt per axis
    /// and linuxcnc-ini.txt), siemens-lec (siemens-lec-AX_EEC.INI: leadscrew tables alone;
    /// with a reversal also siemens-lec-NC_CEC.INI, its direction halves), siemens-cec
    /// (siemens-cec-AX_EEC.INI and siemens-cec-NC_CEC.INI: leadscrew and cross-axis tables,
    /// loaded together). With the default, a control format whose limits the tables exceed is
    /// left out with a warning; named, it is an error.
    #[arg(long, value_name = "LIST")]
    format: Option<String>,
    /// Siemens machine axis names, e.g. X=AX1,C=AX4,Z=AX3 (default: the letter and 1, X1 …).
    #[arg(long, value_name = "AXIS=NAME,…")]
    siemens_axes: Option<String>,
    /// The most points a Siemens table may hold: MD38000 $MA_MM_ENC_COMP_MAX_POINTS (LEC) and
    /// MD18342 $MN_MM_CEC_MAX_POINTS (CEC) of the control.
    #[arg(long, default_value_t = 200)]
    siemens_max_points: usize,
    /// The sign of the Siemens CEC values, which no public source volver found states: `lec`
    /// (like $AA_ENC_COMP, minus the correction) or `correction`. Check it on the machine
    /// first (README, "Controller files").
    #[arg(long, default_value = "lec")]
    siemens_cec_sign: String,
    /// How many CEC tables the Siemens control offers (the 828D has 8; an 840D sl as its
    /// option and MD18340 $MN_MM_CEC_MAX_TABLES say).
    #[arg(long, default_value_t = 8)]
    siemens_max_tables: usize,
    /// Step over linear axes (mm).
    #[arg(long, default_value_t = 10.0)]
    step: f64,
    /// Step over rotary axes (degrees).
    #[arg(long, default_value_t = 5.0)]
    rotary_step: f64,
    /// Use a results file whose errors are implausible (see `volver identify --accept`).
    #[arg(long)]
    accept: bool,
    /// The tool point the tables serve, mm in the frame of the last tool-side axis; default:
    /// the reflectors' centroid.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
    tool_offset: Option<String>,
    /// Refuse when the expanded uncertainty (k = 2) of the compensated tool point over the
    /// travel, after the set-up's rigid transform, exceeds this (µm).
    #[arg(long, default_value_t = 25.0)]
    max_u_um: f64,
    /// Write the tables even when the uncertainty exceeds --max-u-um, or when the model has
    /// parts per-axis tables cannot carry (a field over the axes, a part that grows with time).
    #[arg(long)]
    force: bool,
    /// The tool lengths the per-axis tables serve, MIN:MAX mm along the tool's axis (0,0,-1:
    /// down the spindle) from the tool point: three tool points (MIN, the middle, MAX) weighed
    /// equally; default: the tool point alone.
    #[arg(long, value_name = "MIN:MAX", allow_hyphen_values = true)]
    tool_length: Option<String>,
}

/// Prints how closely the tables give the model's tool point and every part of the model they
/// cannot carry with the error it leaves; refuses when one leaves more than
/// [`volver::compensation::CARRY_TOLERANCE_MM`] unless `force`. Returns what the tables carry.
fn judge_carry(
    model: &Model,
    params: &[f64],
    tables: &ErrorTables,
    tool: [f64; 3],
    force: bool,
) -> Result<volver::compensation::Carry> {
    let c = volver::compensation::carry(model, params, tables, tool)?;
    println!(
        "  the tables against the model's tool point {} mm over {} commands of the travel: up to \
         {:.3} µm apart (at {})",
        point_mm(tool),
        c.commands.len(),
        c.departure_mm * UM_PER_MM,
        c.place(c.departure_at)
    );
    let lines = c.lines();
    if lines.is_empty() {
        return Ok(c);
    }
    let msg = format!(
        "per-axis tables cannot carry {} part(s) of the model: {}; a control given these tables \
         leaves that error (`volver compensate` applies the whole model)",
        lines.len(),
        lines.join("; ")
    );
    if !force {
        bail!("{msg}; --force writes the tables anyway");
    }
    println!("  warning: {msg} (written anyway: --force)");
    Ok(c)
}

/// Prints which reversals the tables carry: errors.csv has each axis' forward and reverse
/// values, the ISG and Etalon files (no direction) only their mean, which leaves the error
/// printed.
fn direction_note(
    machine: &volver::core::machine::Machine,
    tables: &ErrorTables,
    carry: &volver::compensation::Carry,
) {
    let reversals: Vec<String> = tables
        .axes
        .iter()
        .filter_map(|t| {
            let b = t.reversal.as_ref()?;
            // ISO 230-2's B: the tool relative to the workpiece along the axis' command.
            let sign = machine.axis(t.axis).map_or(1.0, |(_, a)| a.side.sign());
            let (lo, hi) = b
                .iter()
                .map(|v| sign * v)
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
                    (l.min(v), h.max(v))
                });
            let (scale, unit) = if t.axis.is_rotary() {
                (URAD_PER_RAD, "µrad")
            } else {
                (UM_PER_MM, "µm")
            };
            Some(if (hi - lo) * scale < 5e-4 {
                format!("{} (ISO 230-2 B = {:.3} {unit})", t.axis, hi * scale)
            } else {
                format!(
                    "{} (ISO 230-2 B from {:.3} to {:.3} {unit})",
                    t.axis,
                    lo * scale,
                    hi * scale
                )
            })
        })
        .collect();
    if reversals.is_empty() {
        return;
    }
    println!(
        "  reversal of {}: errors.csv carries each axis' positioning error on forward and \
         reverse approach (its forward and reverse columns: errors of the slide, whose \
         difference is ISO 230-2's B on an axis that moves the tool and its negative on one \
         that moves the workpiece)",
        reversals.join(", ")
    );
    println!(
        "  warning: errors-isg.csv and errors-etalon.txt do NOT carry the reversal (the formats \
         have no direction of approach): their values are the mean of both directions, which \
         leaves {}",
        carry.direction_lines().join("; ")
    );
}

/// The Siemens writers' options from the flags.
fn siemens_options(a: &TablesArgs, model: &Model) -> Result<SiemensOptions> {
    if a.siemens_max_points < 2 || a.siemens_max_tables < 1 {
        bail!(
            "--siemens-max-points {} / --siemens-max-tables {}: a table needs at least 2 points \
             and the control at least 1 table",
            a.siemens_max_points,
            a.siemens_max_tables
        );
    }
    let mut o = SiemensOptions {
        enc_comp_max_points: a.siemens_max_points,
        cec_max_points: a.siemens_max_points,
        cec_max_tables: a.siemens_max_tables,
        ..SiemensOptions::default()
    };
    o.cec_sign = match a.siemens_cec_sign.trim() {
        "lec" => CecSign::AsLec,
        "correction" => CecSign::Correction,
        other => bail!("--siemens-cec-sign {other}: expected lec or correction"),
    };
    for pair in a.siemens_axes.iter().flat_map(|s| s.split(',')) {
        let (axis, name) = pair
            .split_once('=')
            .map(|(x, n)| (x.trim(), n.trim()))
            .filter(|(_, n)| !n.is_empty())
            .with_context(|| format!("--siemens-axes: {pair:?} is not AXIS=NAME"))?;
        let letter = axis
            .chars()
            .next()
            .and_then(volver::core::iso::Axis::from_letter);
        let Some(letter) = letter
            .filter(|l| axis.len() == 1 && model.machine().axes().iter().any(|m| m.axis == *l))
        else {
            bail!("--siemens-axes: {axis} is not an axis of the machine");
        };
        // A Siemens identifier: letters, digits and underscores, a letter first (`;` would
        // start a comment, `=`, `$`, spaces break the assignment).
        let identifier = name.chars().next().is_some_and(|c| c.is_ascii_alphabetic())
            && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
        if !identifier {
            bail!("--siemens-axes: {name:?} is not a Siemens axis name (letters, digits, _)");
        }
        if o.axis_names.iter().any(|(l, n)| *l == letter || n == name) {
            bail!("--siemens-axes: axis {letter} or the name {name} is given twice");
        }
        o.axis_names.push((letter, name.to_string()));
    }
    Ok(o)
}

/// Every file `volver tables` may write for `formats` on the results' machine, claimed before
/// anything is read or written (an output may not be an input).
fn claim_outputs(a: &TablesArgs, formats: &[Format]) -> Result<()> {
    let mut names: Vec<String> = vec![
        "per-axis-leftover.csv".into(),
        "per-axis-leftover.txt".into(),
    ];
    names.extend(formats.iter().flat_map(|f| f.file_names()));
    let refs: Vec<&str> = names.iter().map(String::as_str).collect();
    volver::core::fsio::Outputs::new([&a.results]).claim_in(&a.out, &refs)?;
    Ok(())
}

/// Runs `volver tables`.
pub fn tables_command(a: TablesArgs) -> Result<()> {
    let named = a.format.is_some();
    let formats = parse_formats(a.format.as_deref().unwrap_or("all"))?;
    claim_outputs(&a, &formats)?;
    let (model, params, record) = load_results(&a.results, a.accept)?;
    check_max_u(a.max_u_um)?;
    let siemens = siemens_options(&a, &model)?;
    let tool = tool_point_of(a.tool_offset.as_deref(), None, &model)?;
    let tools = volver::compensation::tool_points(
        tool,
        volver::compensation::tool_axis_of(None)?,
        a.tool_length.as_deref(),
    )?;
    let tables = ErrorTables::from_model(&model, &params, a.step, a.rotary_step)?;
    println!(
        "volver tables — the errors of {} as controller tables (ERRORS, not corrections; mm, rad)",
        a.results.display()
    );
    // The U gate at every tool point the tables serve (--tool-length gives several).
    for t in &tools {
        apply(
            vouch(&model, &params, record.as_ref(), *t, a.max_u_um)?,
            a.force,
        )?;
    }
    let carry = judge_carry(&model, &params, &tables, tool, a.force)?;
    direction_note(model.machine(), &tables, &carry);
    for t in &tables.axes {
        let names: Vec<&str> = t.errors.iter().map(|e| e.0.as_str()).collect();
        println!(
            "  axis {}: {} positions, {}",
            t.axis,
            t.positions.len(),
            names.join(" ")
        );
    }
    let consts: Vec<&str> = tables.constants.iter().map(|c| c.0.as_str()).collect();
    println!("  constants: {}", consts.join(" "));
    // Every file's text first: nothing is written when one cannot be.
    let mut files = error_table_files(&a, &formats, &model, &params, record.as_ref(), &tables)?;
    files.extend(per_axis_files(
        &a, &formats, named, &model, &params, &tables, &tools, &siemens,
    )?);
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    for (name, text) in files {
        let p = a.out.join(&name);
        write_atomic(&p, text).with_context(|| format!("writing {}", p.display()))?;
        println!("  written {}", p.display());
    }
    Ok(())
}

/// The per-axis projections' files: what they leave (per-axis-leftover.csv / .txt) and the
/// controller formats among `formats`. A projection or a control that cannot take the tables
/// (too many values, a limit of the control) is an error when `named` (the user chose the
/// formats), else a warning and no such file.
#[allow(clippy::too_many_arguments)]
fn per_axis_files(
    a: &TablesArgs,
    formats: &[Format],
    named: bool,
    model: &Model,
    params: &[f64],
    tables: &ErrorTables,
    tools: &[[f64; 3]],
    siemens: &SiemensOptions,
) -> Result<Vec<(String, String)>> {
    let controls = formats.iter().any(|f| f.is_controller());
    let c = match per_axis_comparison(a, model, params, tables, tools) {
        Ok(c) => c,
        Err(e) if named && controls => return Err(e.context("the per-axis projection")),
        Err(e) => {
            println!("  warning: per-axis tables not fitted, none written: {e:#}");
            return Ok(Vec::new());
        }
    };
    let mut files = leftover_files(a, model, &c);
    for (f, result) in controller_files(&c, model.machine(), formats, siemens) {
        match result {
            Ok(texts) => files.extend(texts),
            Err(why) if named => bail!("--format {f}: {why}"),
            Err(why) => println!(
                "  warning: {f} not written: {why} (another --step{}, or --format without {f})",
                if f == Format::Linuxcnc {
                    ""
                } else {
                    ", --siemens-max-points or --siemens-max-tables"
                }
            ),
        }
    }
    Ok(files)
}

/// The error tables' files among `formats` (with errors.csv, its U companion when the results
/// record an uncertainty): (file name, text).
fn error_table_files(
    a: &TablesArgs,
    formats: &[Format],
    model: &Model,
    params: &[f64],
    record: Option<&volver::core::results::UncertaintyRecord>,
    tables: &ErrorTables,
) -> Result<Vec<(String, String)>> {
    let mut files = Vec::new();
    for f in formats {
        match f {
            Format::Isg => files.push(("errors-isg.csv".into(), tables.to_isg_csv())),
            Format::Etalon => files.push(("errors-etalon.txt".into(), tables.to_etalon())),
            Format::Csv => {
                files.push(("errors.csv".into(), tables.to_plain_csv()));
                if let Some(r) = record {
                    // The formats have no place for U: a companion in errors.csv's layout
                    // whose values are the expanded uncertainty (k = 2) of each error.
                    let u = table_uncertainty(model, params, r, tables, a.step, a.rotary_step)?;
                    files.push(("errors-u95.csv".into(), u.to_plain_csv()));
                }
            }
            _ => {}
        }
    }
    Ok(files)
}

/// What per-axis tables leave beside the other ways of compensating, printed one line each.
fn per_axis_comparison(
    a: &TablesArgs,
    model: &Model,
    params: &[f64],
    tables: &ErrorTables,
    tools: &[[f64; 3]],
) -> Result<PerAxisComparison> {
    let m = model.machine();
    let c = volver::compensation::compare_per_axis(
        model,
        params,
        tables,
        tools,
        a.step,
        a.rotary_step,
    )?;
    let points: Vec<String> = tools.iter().map(|t| point_mm(*t)).collect();
    println!(
        "  what each leaves of the tool point's error over {} commands of the travel at tool \
         point(s) {} mm:",
        c.leadscrew.1.grid.len(),
        points.join(", ")
    );
    for line in c.lines(m) {
        println!("    {line}");
    }
    Ok(c)
}

/// per-axis-leftover.csv (per grid point) and per-axis-leftover.txt (the summary).
fn leftover_files(a: &TablesArgs, model: &Model, c: &PerAxisComparison) -> Vec<(String, String)> {
    let m = model.machine();
    let source = a.results.display().to_string();
    vec![
        ("per-axis-leftover.csv".into(), c.to_csv(m)),
        ("per-axis-leftover.txt".into(), c.summary(m, &source)),
    ]
}
