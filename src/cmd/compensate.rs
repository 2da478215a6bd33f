//! `volver compensate` and `volver tables`: using the identified errors on the machine.

use anyhow::{Context, Result, bail};
use std::path::{Path, PathBuf};
use volver::compensation::{
    Compensated, Statement, Vouch, check_max_u, compensate_points, compensator,
    distance_from_reflector_line, load_results, point_mm, tool_point_of, vouch,
};
use volver::core::compensate::Compensator;
use volver::core::fsio::write_atomic;
use volver::core::gcode::{Setup, Tooling, WriteOptions};
use volver::core::model::Model;
use volver::core::results::ResultsFile;
use volver::core::results::UncertaintyRecord;
use volver::core::units::{UM_PER_MM, URAD_PER_RAD};
use volver::machining::{self, ToolPoints};

/// Options of `volver compensate`.
#[derive(clap::Args)]
pub struct CompensateArgs {
    /// Results file of `volver identify` (machine, error model and identified errors).
    #[arg(long)]
    results: PathBuf,
    /// A point list to correct: CSV with one column per axis (mm, degrees) and an optional id.
    #[arg(long, conflicts_with = "gcode", required_unless_present = "gcode")]
    points: Option<PathBuf>,
    /// A G-code program to correct (G0/G1 moves, G2/G3 arcs linearised; mm).
    #[arg(long)]
    gcode: Option<PathBuf>,
    /// Where to write the corrected points or program.
    #[arg(long)]
    out: PathBuf,
    /// The tool point, mm in the frame of the last tool-side axis (like a reflector offset);
    /// default: the centroid of the reflectors, where the measurement sees best.
    #[arg(
        long,
        value_name = "X,Y,Z",
        conflicts_with = "tool_reflector",
        visible_alias = "tool-offset",
        allow_hyphen_values = true
    )]
    tool: Option<String>,
    /// Use a reflector's offset as the tool point.
    #[arg(long, value_name = "ID")]
    tool_reflector: Option<String>,
    /// Axes kept at their programmed value (letters, e.g. `AC`: the tool point alone is
    /// compensated, as controllers' volumetric compensation does); default: none on a five-axis
    /// machine (the tool's point and direction are both compensated), the rotary axes on a
    /// machine with three linear ones and fewer rotary ones, else none.
    #[arg(long, value_name = "AXES")]
    hold: Option<String>,
    /// The tool's axis, from the holder to the tip, in the frame of the last tool-side axis:
    /// its direction is compensated with every axis of a five-axis machine (default 0,0,-1:
    /// the tool points down its spindle).
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
    tool_axis: Option<String>,
    /// Largest accepted angle between a corrected command's tool direction and its target, as
    /// solved (rad; five-axis compensation, away from the singularity, where what is left is
    /// reported).
    #[arg(long, default_value_t = 1e-9)]
    tolerance_rad: f64,
    /// Largest distance between an arc and its chords (mm).
    #[arg(long, default_value_t = 0.001)]
    chord_tolerance: f64,
    /// Split linear moves longer than this (mm) so the corrected path follows the bent one.
    #[arg(long)]
    max_segment: Option<f64>,
    /// Decimals of the written commands (mm, degrees), 0–12.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u8).range(0..=volver::core::gcode::MAX_DECIMALS as i64))]
    decimals: u8,
    /// Largest accepted deviation of a corrected command from its target, as solved (mm).
    #[arg(long, default_value_t = 1e-9)]
    tolerance: f64,
    /// Use a results file whose errors are implausible (see `volver identify --accept`).
    #[arg(long)]
    accept: bool,
    /// Refuse when the expanded uncertainty (k = 2) of the compensated tool point over the
    /// travel, after the set-up's rigid transform, exceeds this (µm).
    #[arg(long, default_value_t = 25.0)]
    max_u_um: f64,
    /// Compensate even when the uncertainty exceeds --max-u-um.
    #[arg(long)]
    force: bool,
    /// The control's offsets for --gcode: LinuxCNC's parameter file (.var: G54–G59.3, G92,
    /// G28/G30 positions) or volver's TOML offsets file (.toml: work, g92, home and tool
    /// tables).
    #[arg(long, requires = "gcode")]
    offsets: Option<PathBuf>,
    /// The control's tool table for --gcode (LinuxCNC .tbl): G43 Hn applies its lengths, and
    /// each tool is compensated at its own tool point (--gauge-point plus its length along the
    /// tool axis).
    #[arg(long, requires = "gcode")]
    tool_table: Option<PathBuf>,
    /// Units of the .var and .tbl files (LinuxCNC keeps them in the machine's units): mm or inch.
    #[arg(long, default_value = "mm")]
    offset_units: String,
    /// The machine's position when the program starts (machine coordinates, mm and degrees,
    /// e.g. X=0,Y=0,Z=500): every axis must be known before the first compensated move.
    #[arg(long, value_name = "AXIS=VALUE,…", allow_hyphen_values = true)]
    start: Option<String>,
    /// The tool in the spindle when the program starts.
    #[arg(long, value_name = "N")]
    start_tool: Option<i64>,
    /// The point tool lengths are measured from (the spindle's gauge line), mm in the frame of
    /// the last tool-side axis; default: the tool point (--tool).
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
    gauge_point: Option<String>,
    /// Without a tool table, compensate every tool of a program that changes tools at the one
    /// tool point (--tool).
    #[arg(long)]
    same_tool_point: bool,
    /// Write compensated points beyond an axis' travel, each marked on its line, instead of
    /// refusing them.
    #[arg(long)]
    allow_outside_travel: bool,
    /// The dialect of --gcode: linuxcnc (RS274NGC) or fanuc (G04 X in seconds, a decimal point
    /// on every axis value, cycles refused).
    #[arg(long, default_value = "linuxcnc")]
    dialect: String,
    /// With a reversal in the model (each point compensated in the direction its axes arrive
    /// with): a written command going back by less than this (µm; µrad on a rotary axis) from
    /// the furthest point its axis reached does not reverse the axis.
    #[arg(long, default_value_t = volver::core::compensate::REVERSAL_TOLERANCE_UM)]
    reversal_tolerance_um: f64,
}

/// The U gate ([`volver::compensation::vouch`]) as the command line applies it: each note
/// printed, each refusal an error unless `force` (then a warning). Returns the U after the
/// set-up's transform and raw (mm), `None` when the results carry no uncertainty.
pub fn apply(v: Vouch, force: bool) -> Result<Option<(f64, f64)>> {
    for statement in &v.statements {
        match statement {
            Statement::Note(text) => println!("  {text}"),
            Statement::Refusal {
                reason,
                override_text,
            } => {
                if !force {
                    bail!("{reason}; {override_text}");
                }
                println!("  warning: {reason} (used anyway: --force)");
            }
            _ => {}
        }
    }
    Ok(v.u.map(|u| (u.aligned_mm, u.raw_mm)))
}

fn parse_tool(a: &CompensateArgs, model: &Model) -> Result<[f64; 3]> {
    Ok(tool_point_of(
        a.tool.as_deref(),
        a.tool_reflector.as_deref(),
        model,
    )?)
}

/// Options of `volver predict`.
#[derive(clap::Args)]
pub struct PredictArgs {
    /// Results file (of `volver identify`, `report`, or a simulation's truth.json).
    #[arg(long)]
    results: PathBuf,
    /// The commands: a plan preset or a grid such as X=0:1400:200,C=0:330:30,Z=0:600:150 (mm,
    /// degrees).
    #[arg(long)]
    grid: String,
    /// The tool point, mm in the frame of the last tool-side axis; default: the reflectors'
    /// centroid.
    #[arg(
        long,
        value_name = "X,Y,Z",
        visible_alias = "tool",
        allow_hyphen_values = true
    )]
    tool_offset: Option<String>,
    /// Print one JSON object instead of a CSV table.
    #[arg(long)]
    json: bool,
}

/// Runs `volver predict`: the tool point of a results file at each command of a grid, in the
/// workpiece frame (the tracker pose and the measurement's effects left out), so that an
/// identified model and another (the truth of a simulation, a second fit) can be put side by
/// side.
pub fn predict_command(a: PredictArgs) -> Result<()> {
    let label = a.results.display().to_string();
    let file = ResultsFile::load(&a.results).context("reading the results file")?;
    let (model, params) = file.to_model(&label)?;
    let m = model.machine();
    let plan = volver::inputs::plan(m, None, Some(&a.grid))?;
    let tool = tool_point_of(a.tool_offset.as_deref(), None, &model)?;
    let rows: Vec<(Vec<f64>, [f64; 3])> = plan
        .positions
        .iter()
        .map(|c| {
            let files: Vec<f64> = m
                .axes()
                .iter()
                .enumerate()
                .map(|(k, ax)| ax.to_file_units(c.0[k]))
                .collect();
            (files, model.tool_point(&c.0, &tool, &params))
        })
        .collect();
    if a.json {
        let obj = serde_json::json!({
            "results": label,
            "model": model.spec().name,
            "tool_offset_mm": tool,
            "axes": m.axes().iter().map(|ax| ax.axis.to_string()).collect::<Vec<_>>(),
            "points": rows.iter().map(|(c, t)| serde_json::json!({
                "commands": c, "tool_point_mm": t,
            })).collect::<Vec<_>>(),
        });
        println!("{}", serde_json::to_string_pretty(&obj)?);
        return Ok(());
    }
    let names: Vec<String> = m.axes().iter().map(|ax| ax.axis.to_string()).collect();
    println!("{},tool_x_mm,tool_y_mm,tool_z_mm", names.join(","));
    for (c, t) in &rows {
        let cells: Vec<String> = c.iter().map(|v| format!("{v}")).collect();
        println!("{},{:.9},{:.9},{:.9}", cells.join(","), t[0], t[1], t[2]);
    }
    Ok(())
}

/// Runs `volver compensate`.
pub fn compensate_command(a: CompensateArgs) -> Result<()> {
    let inputs: Vec<&Path> = [
        Some(a.results.as_path()),
        a.points.as_deref(),
        a.gcode.as_deref(),
        a.offsets.as_deref(),
        a.tool_table.as_deref(),
    ]
    .into_iter()
    .flatten()
    .collect();
    volver::core::fsio::Outputs::new(inputs).claim(&a.out)?;
    let (model, params, record) = load_results(&a.results, a.accept)?;
    let m = model.machine();
    let tool = parse_tool(&a, &model)?;
    let axis = match &a.tool_axis {
        Some(t) => Some(volver::compensation::tool_axis_of(Some(t))?),
        None => None,
    };
    let comp = compensator(&model, &params, tool, a.hold.as_deref(), axis)?;
    announce(&a, &model, &comp, tool);
    check_max_u(a.max_u_um)?;
    if !(a.tolerance.is_finite() && a.tolerance > 0.0) {
        bail!(
            "--tolerance {}: the verification tolerance must be a positive length (mm)",
            a.tolerance
        );
    }
    let done = if let Some(path) = &a.points {
        apply(
            vouch(&model, &params, record.as_ref(), tool, a.max_u_um)?,
            a.force,
        )?;
        let label = path.display().to_string();
        let text = std::fs::read_to_string(path).with_context(|| format!("reading {label}"))?;
        let done = compensate_points(
            &comp,
            m,
            &text,
            &label,
            usize::from(a.decimals),
            a.reversal_tolerance_um,
        )?;
        points_summary(&done, &label);
        done
    } else {
        compensate_gcode(&a, &comp, &model, &params, record.as_ref(), tool, axis)?
    };
    println!(
        "  verified through the forward model: largest deviation {:.3e} mm as solved, {:.3e} mm as written ({} decimals)",
        done.worst_solved_mm, done.worst_written_mm, a.decimals
    );
    let (outside, worst_solved) = (done.outside, done.worst_solved_mm);
    if outside > 0 {
        println!("  warning: {outside} corrected point(s) leave an axis' travel (see the output)");
    }
    if !(a.tolerance_rad.is_finite() && a.tolerance_rad > 0.0) {
        bail!(
            "--tolerance-rad {}: the verification tolerance must be a positive angle (rad)",
            a.tolerance_rad
        );
    }
    if let Some(o) = &done.orientation {
        check_orientation(&a, o)?;
    }
    // A failed verification writes nothing: a program that misses its targets must not reach a
    // control.
    if worst_solved.is_nan() || worst_solved > a.tolerance {
        bail!(
            "a corrected command misses its target by {worst_solved:.3e} mm, above the tolerance {:.1e} mm; nothing written",
            a.tolerance
        );
    }
    write_atomic(&a.out, done.text).with_context(|| format!("writing {}", a.out.display()))?;
    println!("  written to {}", a.out.display());
    Ok(())
}

/// What the compensation of a point list did, printed.
fn points_summary(done: &Compensated, label: &str) {
    println!(
        "  {} points from {label}: uncompensated error up to {:.4} µm",
        done.points,
        done.max_error_mm * UM_PER_MM
    );
    if done.unsettled > 0 {
        println!(
            "  warning: {} point(s) an axis that overshoots (ISO 230-2 B > 0) reaches going back \
             by less than |B| from where it turned: it holds its command there, up to {:.3} µm \
             off (not in the deviations below; see the approach columns)",
            done.unsettled,
            done.worst_unsettled_mm * UM_PER_MM
        );
    }
}

/// Prints what is compensated: a warning when the tool point is off the line through the
/// reflectors, then the machine, the results, the tool and the axes solved for.
fn announce(a: &CompensateArgs, model: &Model, comp: &Compensator, tool: [f64; 3]) {
    let m = model.machine();
    if let Some(d) = distance_from_reflector_line(model, tool)
        && d > 1.0
    {
        println!(
            "  warning: the tool point is {d:.1} mm off the line through the reflectors; the tracker does not see the tool side's rotation about that line, so its compensation there rests on unmeasured errors"
        );
    }
    let free: String = comp
        .free_axes()
        .iter()
        .map(|&k| m.axes()[k].axis.letter())
        .collect();
    let steering = match comp.tool_axis() {
        Some(d) => format!(
            "tool point {} mm and tool axis ({:.4}, {:.4}, {:.4})",
            point_mm(tool),
            d[0],
            d[1],
            d[2]
        ),
        None => format!("tool point {} mm", point_mm(tool)),
    };
    println!(
        "volver compensate — {} with the errors of {} (model \"{}\"), {steering}, solving for {free}",
        m.chain(),
        a.results.display(),
        model.spec().name,
    );
    let reversal: String = volver::core::compensate::reversal_axes(model)
        .iter()
        .map(|&k| m.axes()[k].axis.letter())
        .collect();
    if !reversal.is_empty() {
        println!(
            "  reversal of {reversal}: each point compensated in the direction its axes arrive \
             with (from the written commands, in the order they run; an axis going back by less \
             than {} µm (µrad) keeps its direction)",
            a.reversal_tolerance_um
        );
    }
}

/// Prints what compensation did to the tool's direction and refuses a direction verified
/// outside `--tolerance-rad`.
fn check_orientation(
    a: &CompensateArgs,
    o: &volver::compensation::OrientationSummary,
) -> Result<()> {
    println!(
        "  tool direction: uncompensated error up to {:.4} µrad; verified through the forward \
         model away from the singularity: largest angle {:.3e} rad as solved, {:.3e} rad as \
         written",
        o.max_error_rad * URAD_PER_RAD,
        o.worst_solved_rad,
        o.worst_written_rad
    );
    if o.near_singularity > 0 {
        println!(
            "  warning: {} corrected point(s) pass within {}° of the singularity (the rotary \
             axes nearly parallel: the tilt axis near zero); there the rotary axis the \
             direction hardly depends on keeps its programmed angle (no swing of up to half a \
             turn for microradians) and up to {:.3} µrad of the direction is left (see the \
             output's sensitivity)",
            o.near_singularity,
            volver::core::compensate::SINGULAR_TILT_DEG,
            o.worst_singular_rad * URAD_PER_RAD
        );
    }
    if o.worst_solved_rad.is_nan() || o.worst_solved_rad > a.tolerance_rad {
        bail!(
            "a corrected command's tool direction misses its target by {:.3e} rad, above the \
             tolerance {:.1e} rad; nothing written",
            o.worst_solved_rad,
            a.tolerance_rad
        );
    }
    Ok(())
}

/// The G-code program of `--gcode`, read with the control's offsets and tools, linearised and
/// compensated: each tool at its own tool point, each vouched for by its U.
#[allow(clippy::too_many_arguments)]
fn compensate_gcode(
    a: &CompensateArgs,
    comp: &Compensator,
    model: &Model,
    params: &[f64],
    record: Option<&UncertaintyRecord>,
    tool: [f64; 3],
    axis: Option<[f64; 3]>,
) -> Result<Compensated> {
    let m = model.machine();
    let path = a.gcode.as_ref().expect("clap requires --points or --gcode");
    let label = path.display().to_string();
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {label}"))?;
    let (setup, points) = gcode_setup(a, model, tool)?;
    let (prog, tool_points) = machining::read_program(&text, &label, m, &setup, &points)?;
    let mut tooling = Tooling::single(comp.clone());
    if prog
        .tools()
        .iter()
        .any(|t| t.is_none_or(|t| !tool_points.contains_key(&t)))
    {
        apply(vouch(model, params, record, tool, a.max_u_um)?, a.force)?;
    }
    for (t, p) in &tool_points {
        println!("  tool T{t}: tool point {} mm", point_mm(*p));
        apply(vouch(model, params, record, *p, a.max_u_um)?, a.force)?;
        let c = compensator(model, params, *p, a.hold.as_deref(), axis)?;
        tooling.tools.insert(*t, c);
    }
    let gauge = (!tool_points.is_empty()).then_some(points.gauge);
    let header = gcode_header(a, &label, model, tool, gauge);
    let options = WriteOptions {
        decimals: usize::from(a.decimals),
        allow_outside_travel: a.allow_outside_travel,
        dialect: setup.dialect,
        reversal_tolerance_um: a.reversal_tolerance_um,
    };
    let (out, rep) = prog.compensate_with(&tooling, m, &options, &header)?;
    gcode_summary(a, &label, &rep);
    Ok(Compensated {
        text: out,
        points: rep.points,
        max_error_mm: rep.max_error_mm,
        worst_solved_mm: rep.max_deviation_mm,
        worst_written_mm: rep.max_written_deviation_mm,
        outside: rep.outside_travel.len(),
        orientation: comp
            .tool_axis()
            .map(|_| volver::compensation::OrientationSummary {
                max_error_rad: rep.max_direction_error_rad,
                worst_solved_rad: rep.max_direction_deviation_rad,
                worst_written_rad: rep.max_written_direction_deviation_rad,
                near_singularity: rep.near_singularity.len(),
                worst_singular_rad: rep.max_singular_direction_deviation_rad,
            }),
        unsettled: rep.unsettled_points,
        worst_unsettled_mm: rep.max_unsettled_deviation_mm,
    })
}

/// The reading set-up of `--gcode` (linearisation, offsets, start, tool) and where the tools'
/// points are.
fn gcode_setup(a: &CompensateArgs, model: &Model, tool: [f64; 3]) -> Result<(Setup, ToolPoints)> {
    let m = model.machine();
    let setup = Setup {
        lin: machining::linearise(a.chord_tolerance, a.max_segment),
        offsets: machining::offsets(
            a.offsets.as_deref(),
            a.tool_table.as_deref(),
            &a.offset_units,
        )?,
        start: machining::start(m, a.start.as_deref())?,
        tool: a.start_tool,
        dialect: dialect(a)?,
    };
    let points = ToolPoints {
        gauge: match &a.gauge_point {
            Some(g) => tool_point_of(Some(g), None, model).map_err(|e| {
                anyhow::anyhow!("{}", e.to_string().replace("--tool", "--gauge-point"))
            })?,
            None => tool,
        },
        axis: a
            .tool_axis
            .as_deref()
            .map(|t| volver::compensation::tool_axis_of(Some(t)))
            .transpose()?
            .unwrap_or([0.0, 0.0, -1.0]),
        same_point: a.same_tool_point,
    };
    Ok((setup, points))
}

/// The dialect of `--dialect`.
fn dialect(a: &CompensateArgs) -> Result<volver::core::dialect::Dialect> {
    a.dialect
        .parse()
        .map_err(|e| anyhow::anyhow!("--dialect {}: {e}", a.dialect))
}

/// The compensated program's header.
fn gcode_header(
    a: &CompensateArgs,
    label: &str,
    model: &Model,
    tool: [f64; 3],
    gauge: Option<[f64; 3]>,
) -> String {
    let tools = gauge.map_or(String::new(), |g| {
        format!(
            "; each tool at the gauge point {} mm plus its length",
            point_mm(g)
        )
    });
    format!(
        "compensated by volver {} from {label} with {}\nchord tolerance {} mm; tool point {} mm{tools}; errors of model {}",
        env!("CARGO_PKG_VERSION"),
        a.results.display(),
        a.chord_tolerance,
        point_mm(tool),
        model.spec().name
    )
}

/// What the G-code compensation did, printed.
fn gcode_summary(a: &CompensateArgs, label: &str, rep: &volver::core::gcode::Report) {
    println!(
        "  {} moves ({} arcs, linearised to {} mm) from {label} → {} points; uncompensated error up to {:.4} µm",
        rep.moves,
        rep.arcs,
        a.chord_tolerance,
        rep.points,
        rep.max_error_mm * UM_PER_MM
    );
    if rep.reversals > 0 || !rep.unsettled_reversals.is_empty() {
        println!(
            "  {} reversal(s) of an axis with a reversal value, each compensated from its turning \
             point on",
            rep.reversals
        );
    }
    if !rep.unsettled_reversals.is_empty() {
        println!(
            "  warning: on lines {} an axis that overshoots (lands beyond its target in the \
             direction it moves: ISO 230-2 B > 0) goes back by less than |B| from where it \
             turned: no command reaches those points in one move, so it holds its command there, \
             up to {:.3} µm off (not in the deviations below), and reverses once the program has \
             gone back more than |B|",
            lines_list(&rep.unsettled_reversals),
            rep.max_unsettled_deviation_mm * UM_PER_MM
        );
    }
    if !rep.uncompensated.is_empty() {
        println!(
            "  {} reference or machine-coordinate move(s) kept as written, not compensated (lines {})",
            rep.uncompensated.len(),
            lines_list(&rep.uncompensated)
        );
    }
    if !rep.outside_travel.is_empty() {
        println!(
            "  warning: compensated points beyond the travel written on lines {} (marked there; --allow-outside-travel)",
            lines_list(&rep.outside_travel)
        );
    }
}

/// Up to ten line numbers, then how many more.
fn lines_list(lines: &[usize]) -> String {
    let mut s: Vec<String> = lines.iter().take(10).map(usize::to_string).collect();
    if lines.len() > 10 {
        s.push(format!("and {} more", lines.len() - 10));
    }
    s.join(", ")
}
