//! `volver plan`: designs a verification (poses, reflectors, order) for the tool point that
//! compensation needs, writes it as a plan file (`simulate --plan-file`) and a measuring
//! program, and with `--compare` runs plans on simulated truths side by side.

use anyhow::{Context, Result, bail};
use clap::Args;
use std::path::{Path, PathBuf};
use volver::core::dialect::Dialect;
use volver::core::fsio::write_atomic;
use volver::core::machine::Machine;
use volver::core::noise::TrackerNoise;
use volver::core::plan::file::{self, ProgramOptions, Wait};
use volver::core::plan::sides::Overrun;
use volver::core::units::S_PER_H;
use volver::planning::{Request, compare, plan};

/// Arguments of `volver plan`.
#[derive(Args)]
pub struct PlanArgs {
    /// Machine file (TOML) or an embedded machine's name (`volver layout --list`); the embedded
    /// XCFZ grinder when absent.
    #[arg(long)]
    machine: Option<PathBuf>,
    /// Error model (TOML) the plan must identify; the paper's model with the embedded machine.
    #[arg(long)]
    model: Option<PathBuf>,
    /// The tracker's noise (`paper`, `normal:…`, `uniform:…`, `mpe:A_UM,B_UM_PER_M`); default:
    /// the machine file's `[tracker] noise`, else the paper's.
    #[arg(long)]
    noise: Option<String>,
    /// Measurements in the plan (the reference pose's repeats included).
    #[arg(long, conflicts_with = "hours")]
    points: Option<usize>,
    /// The time there is (h); with --seconds-per-point it sets the number of measurements (of
    /// each station, when the machine has several: each measures the plan).
    #[arg(long)]
    hours: Option<f64>,
    /// Measuring time per point, moves and dwell included (s).
    #[arg(long, default_value_t = volver::core::simulate::DEFAULT_SECONDS_PER_POINT)]
    seconds_per_point: f64,
    /// The design criterion: i (the tool point's mean variance over the volume after the
    /// set-up's transform), v (its largest) or d (the parameters' confidence volume).
    #[arg(long, default_value = "i")]
    criterion: String,
    /// The tool point, mm in the frame of the last tool-side axis; default: the reflectors'
    /// centroid.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
    tool_offset: Option<String>,
    /// Candidate reflector positions beside the machine's (TOML: `[[reflector]]` tables with
    /// `id` and `offset` in mm on the last tool-side axis, as in a machine file); a plan that
    /// uses one is written with its machine file (PLAN.machine.toml).
    #[arg(long)]
    reflectors: Option<PathBuf>,
    /// Candidate positions per axis, about (a round step over the travel; a full turn without
    /// its end); default 13, or fewer where the grid would exceed 50 000 candidate points (6 on
    /// a five-axis machine with three reflectors).
    #[arg(long)]
    per_axis: Option<usize>,
    /// Visits of the reference pose between the first and the last measurement.
    #[arg(long, default_value_t = 8)]
    repeats: usize,
    /// Seed of the measuring order (and of the truths with --compare).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Plan file to write (CSV: order, the axes, reflector), read by `simulate --plan-file`.
    #[arg(long, required_unless_present_any = ["compare", "plan_file"])]
    out: Option<PathBuf>,
    /// Measuring program to write (G-code): between poses a rapid to the clearance position
    /// (only the clearance axes move), the other axes, then the approach; a wait per pose.
    #[arg(long)]
    gcode: Option<PathBuf>,
    /// Writes the measuring program (--gcode) of this plan file (CSV, as --out writes it)
    /// instead of designing a plan.
    #[arg(long, requires = "gcode", conflicts_with_all = ["out", "compare", "points", "hours"])]
    plan_file: Option<PathBuf>,
    /// The measuring program's clearance position, AXIS=VALUE,… in mm and degrees (e.g. Z=600);
    /// it wins over the machine file's [clearance] table.
    #[arg(long, value_name = "AXIS=VALUE,…", allow_hyphen_values = true)]
    clearance: Option<String>,
    /// How the measuring program waits at each pose: time (a dwell of --seconds-per-point per
    /// reflector measured there), m0 (a program stop: the tracker is operated by hand) or m1
    /// (an optional stop).
    #[arg(long, default_value = "time")]
    wait: String,
    /// The measuring program's G-code dialect: linuxcnc (RS274NGC: G4 P in seconds) or fanuc
    /// (G04 P in milliseconds, O number, decimal points on every axis value).
    #[arg(long, default_value = "linuxcnc")]
    dialect: String,
    /// An extra wait at each pose for the machine and the tracker to settle, before the
    /// measuring time or the stop (s, 0–3600; not part of the plan's duration).
    #[arg(long, default_value_t = 0.0)]
    dwell_s: f64,
    /// Measures each pose from both sides, as ISO 230-2 does: every designed measurement made
    /// twice, back to back, first with every moving axis arriving from below (+), then from
    /// above (−), each over the overrun (the plan file's approach_<AXIS> columns; the
    /// measuring program writes the approach moves). The measurements and the measuring time
    /// double (with --hours, the design takes half as many).
    #[arg(long, conflicts_with = "plan_file")]
    bidirectional: bool,
    /// The overrun of a linear axis (mm): how far it travels in the stated direction before a
    /// measured position (at most half its travel; a position within it of a travel end is
    /// approached from the only side the travel allows).
    #[arg(long, default_value_t = volver::core::plan::sides::DEFAULT_OVERRUN_MM)]
    overrun: f64,
    /// The overrun of a rotary axis (degrees).
    #[arg(long, default_value_t = volver::core::plan::sides::DEFAULT_OVERRUN_DEG)]
    overrun_deg: f64,
    /// The feed of the measuring program's approach moves (mm/min; degrees/min for a rotary
    /// axis moving alone), for plans that state directions of approach.
    #[arg(long, default_value_t = file::DEFAULT_APPROACH_FEED)]
    approach_feed: f64,
    /// Compares plans instead: comma-separated plan files or presets (test4 …; test4/R1+R2
    /// measures only those reflectors).
    #[arg(long, value_name = "PLAN,PLAN…")]
    compare: Option<String>,
    /// Truths per plan with --compare (seeds 1…N).
    #[arg(long, default_value_t = 20)]
    seeds: u64,
    /// The hidden effect whose detection --compare counts (`none`: skip the diagnoses).
    #[arg(long, default_value = "thermal-drift=10,-5,60")]
    drift: String,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

/// Runs `volver plan`.
pub fn run(a: PlanArgs) -> Result<()> {
    let derived_machine = claim_outputs(&a)?;
    if let Some(path) = &a.plan_file {
        return program_of_file(&a, path);
    }
    let (_, model) = volver::inputs::machine_and_model(a.machine.as_deref(), a.model.as_deref())?;
    let noise = match &a.noise {
        Some(t) => TrackerNoise::from_text(t)?,
        None => model
            .machine()
            .tracker()
            .noise
            .unwrap_or(TrackerNoise::PAPER),
    };
    let tool = volver::compensation::tool_point_of(a.tool_offset.as_deref(), None, &model)?;
    if let Some(list) = &a.compare {
        return compare_plans(&a, &model, list, &noise, tool);
    }
    // Checked before the design, which takes a while.
    let stations = model.machine().stations().len();
    let sides = if a.bidirectional { 2 } else { 1 };
    let points = match (a.points, a.hours) {
        (Some(n), _) => n,
        // Every station measures the plan; a bidirectional plan each measurement twice.
        (None, Some(h)) => Request::points_for_hours(h, a.seconds_per_point, stations)? / sides,
        (None, None) => 1040,
    };
    let program = program_options(&a, model.machine())?;
    let request = request_of(&a, &model, points, noise, tool)?;
    let planned = plan(&model, &request)?;
    let machine = planned.model.machine();
    let machine_out =
        derived_machine.filter(|_| machine.reflectors().len() > model.machine().reflectors().len());
    if let Some(path) = &machine_out {
        let text = toml::to_string(machine.spec()).context("writing the machine file")?;
        write_atomic(
            path,
            format!(
                "# The machine of a `volver plan` with the candidate reflectors it uses.\n{text}"
            ),
        )
        .with_context(|| format!("writing {}", path.display()))?;
    }
    let r = &planned.report;
    let title = format!(
        "{} ({} noise, tool at {:?} mm, seed {})",
        planned.plan.name, noise, tool, a.seed
    );
    if let Some(out) = &a.out {
        write_atomic(out, file::to_csv(&planned.plan, machine, &title))
            .with_context(|| format!("writing {}", out.display()))?;
    }
    if let (Some(path), Some(options)) = (&a.gcode, &program) {
        write_atomic(path, file::gcode(&planned.plan, machine, options, &title)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(r)?);
        return Ok(());
    }
    print_planned(&a, r, machine, &title, &machine_out);
    Ok(())
}

/// The planning request of the command line: `points` measurements, the criterion, the tool,
/// the noise, the candidate values per axis (the default for the machine with the extra
/// reflectors), the order's seed, the repeats and the extra reflectors.
fn request_of(
    a: &PlanArgs,
    model: &volver::core::model::Model,
    points: usize,
    noise: TrackerNoise,
    tool: [f64; 3],
) -> Result<Request> {
    let extra_reflectors = match &a.reflectors {
        Some(p) => extra_reflectors(p)?,
        None => Vec::new(),
    };
    Ok(Request {
        points,
        criterion: a.criterion.parse().map_err(anyhow::Error::msg)?,
        tool,
        noise,
        per_axis: match a.per_axis {
            Some(n) => n,
            // A bidirectional design weighs every candidate from both sides.
            None => volver::planning::default_per_axis(
                model.machine(),
                (model.machine().reflectors().len() + extra_reflectors.len())
                    * if a.bidirectional { 2 } else { 1 },
            )?,
        },
        seed: a.seed,
        repeats: a.repeats,
        seconds_per_point: a.seconds_per_point,
        extra_reflectors,
        bidirectional: a.bidirectional.then(|| overrun_of(a)),
        ..Request::default()
    })
}

/// The overrun of the command line (`--overrun`, `--overrun-deg`).
fn overrun_of(a: &PlanArgs) -> Overrun {
    Overrun {
        linear_mm: a.overrun,
        rotary_deg: a.overrun_deg,
    }
}

/// Prints how a bidirectional plan approaches its poses, or, for a plan measured once each of a
/// model with reversal values, what measures them.
fn print_sides(r: &volver::planning::Report, seconds_per_point: f64) {
    let Some(b) = &r.bidirectional else {
        if !r.reversal_axes.is_empty() {
            println!(
                "  the model has reversal values ({}): this plan's order decides from which side \
                 each pose is reached (the clearance axes, which the measuring program retracts \
                 between poses, arrive from the clearance's side whatever the order); \
                 --bidirectional measures every pose from both",
                r.reversal_axes.join(", ")
            );
        }
        return;
    };
    let overrun: Vec<String> = b
        .overrun
        .iter()
        .map(|(l, o, clipped)| {
            let unit = if "ABC".contains(l.as_str()) {
                "°"
            } else {
                " mm"
            };
            let half = if *clipped { " (half its travel)" } else { "" };
            format!("{l} {o}{unit}{half}")
        })
        .collect();
    println!(
        "  bidirectional (ISO 230-2): each of the {} designed measurements made twice, back to \
         back, every moving axis arriving from below (+) then from above (−) over its overrun \
         ({}): {} measurements, the measuring time doubled ({:.1} h at {} s per point)",
        b.designed,
        overrun.join(", "),
        r.points,
        r.duration_h,
        seconds_per_point
    );
    let ends: Vec<String> = b
        .one_sided_poses
        .iter()
        .filter(|(_, n)| *n > 0)
        .map(|(l, n)| format!("{l} at {n}"))
        .collect();
    if !ends.is_empty() {
        println!(
            "  poses within the overrun of a travel end, approached on that axis from the only \
             side the travel allows, both times: {}",
            ends.join(", ")
        );
    }
}

/// Prints the plan's report `r` (titled `title`) and the files written.
fn print_planned(
    a: &PlanArgs,
    r: &volver::planning::Report,
    machine: &Machine,
    title: &str,
    machine_out: &Option<PathBuf>,
) {
    println!("volver plan — {title}");
    let stations = machine.stations().len();
    let each = if stations > 1 {
        format!(" from each of {stations} stations")
    } else {
        String::new()
    };
    println!(
        "  {} measurements at {} poses{each} ({}), {:.1} h at {} s per point; chosen among {} candidate points in {:.1} s",
        r.points,
        r.poses,
        r.reflectors
            .iter()
            .map(|(id, n)| format!("{id} × {n}"))
            .collect::<Vec<_>>()
            .join(", "),
        r.duration_h,
        a.seconds_per_point,
        r.candidates,
        r.time_s
    );
    print_sides(r, a.seconds_per_point);
    println!(
        "  design: {:?}-optimal, equivalence ratio {:.3} (1 at the optimum) after {} iterations",
        r.criterion, r.equivalence, r.iterations
    );
    println!(
        "  predicted U (k = 2) of the identified tool point after the set-up's transform: mean {:.2} µm, largest {:.2} µm over the volume",
        r.u95_mean_um, r.u95_max_um
    );
    if let Some(e) = &r.efficiency {
        super::print_efficiency(e, None);
        println!(
            "  (U above is the Φ estimate's, identify's default; --objective ml reaches the limit)\n"
        );
    }
    println!(
        "  order: shuffled; time's largest correlation with an axis function {:.3} ({}); reference pose {:?} visited {} times",
        r.aliasing.0, r.aliasing.1, r.reference, r.reference_visits
    );
    if r.unidentified.is_empty() {
        println!("  every combination of the model is identified");
    } else {
        println!(
            "  {} combinations stay unidentified (held by the gauge):",
            r.unidentified.len()
        );
        for h in &r.unidentified {
            println!("    {h}");
        }
        if r.unidentifiable_by_candidates.len() == r.unidentified.len() {
            println!(
                "  no candidate pose of these reflectors identifies them: a reflector elsewhere on the tool side is needed"
            );
        }
        for adv in &r.reflector_advice {
            println!(
                "    a reflector at {:?} mm ({}) would leave {} of them",
                adv.offset_mm, adv.id, adv.unidentified
            );
        }
    }
    for (what, path) in [
        ("plan file", &a.out),
        ("measuring program", &a.gcode),
        ("machine file with the reflectors it uses", machine_out),
    ] {
        if let Some(p) = path {
            println!("  {what}: {}", p.display());
        }
    }
}

/// The measuring program's options from the command line (`None` without `--gcode`), each
/// checked with the option's name: the clearance (`--clearance`, else the machine file's),
/// the waits and the dialect.
fn program_options(a: &PlanArgs, machine: &Machine) -> Result<Option<ProgramOptions>> {
    if !(a.dwell_s.is_finite() && (0.0..=file::MAX_SETTLE_S).contains(&a.dwell_s)) {
        bail!(
            "--dwell-s {:?}: an extra settling wait of 0 to {} s per pose",
            a.dwell_s,
            file::MAX_SETTLE_S
        );
    }
    for (name, v, unit) in [
        ("--overrun", a.overrun, "mm"),
        ("--overrun-deg", a.overrun_deg, "degrees"),
    ] {
        if !(v.is_finite() && v > 0.0) {
            bail!(
                "{name} {v:?}: the distance ({unit}) an axis travels in the stated direction \
                 before a measured position is a positive number"
            );
        }
    }
    let feed = a.approach_feed;
    if !(feed.is_finite() && feed > 0.0 && feed <= file::MAX_APPROACH_FEED) {
        bail!(
            "--approach-feed {feed:?}: the approach moves' feed is more than 0 and at most {} \
             mm/min",
            file::MAX_APPROACH_FEED
        );
    }
    if a.gcode.is_none() {
        return Ok(None);
    }
    let spp = a.seconds_per_point;
    if !(spp.is_finite()
        && (file::MIN_SECONDS_PER_POINT..=file::MAX_SECONDS_PER_POINT).contains(&spp))
    {
        bail!(
            "--seconds-per-point {spp:?}: the measuring program waits this long per reflector \
             measured at a pose (to the millisecond); {} to {} s",
            file::MIN_SECONDS_PER_POINT,
            file::MAX_SECONDS_PER_POINT
        );
    }
    let clearance = match &a.clearance {
        Some(text) => machine
            .clearance_from_text(text)
            .map_err(|m| anyhow::anyhow!("--clearance {text}: {m}"))?,
        None if machine.clearance().is_empty() => bail!(
            "--gcode: the measuring program needs a clearance position, where it retracts the \
             reflectors between poses: give --clearance AXIS=VALUE (e.g. --clearance Z=600: \
             the axis and end that take the tool away from the workpiece and the tracker) or \
             a [clearance] table in the machine file (`Z = 600.0`)"
        ),
        None => machine.clearance().to_vec(),
    };
    Ok(Some(ProgramOptions {
        dialect: a
            .dialect
            .parse::<Dialect>()
            .map_err(|m| anyhow::anyhow!("--dialect: {m}"))?,
        wait: a
            .wait
            .parse::<Wait>()
            .map_err(|m| anyhow::anyhow!("--wait: {m}"))?,
        clearance,
        seconds_per_point: spp,
        settle_s: a.dwell_s,
        overrun: overrun_of(a),
        approach_feed: a.approach_feed,
    }))
}

/// `--plan-file`: the measuring program of a plan file, without a design.
fn program_of_file(a: &PlanArgs, path: &Path) -> Result<()> {
    let (machine, _) = volver::inputs::machine(a.machine.as_deref())?;
    let options = program_options(a, &machine)?.context("--plan-file needs --gcode")?;
    let plan = file::load(&machine, path)?;
    let out = a.gcode.as_deref().context("--plan-file needs --gcode")?;
    let title = format!("{} (plan file {})", plan.name, path.display());
    write_atomic(out, file::gcode(&plan, &machine, &options, &title)?)
        .with_context(|| format!("writing {}", out.display()))?;
    let stations = machine.stations().len();
    let hours = plan.n_points() as f64 * a.seconds_per_point / S_PER_H;
    println!("volver plan — the measuring program of {}", path.display());
    println!(
        "  {} measurements at {} poses, {:.2} h at {} s per point{}; {} dialect",
        plan.n_points(),
        plan.positions.len(),
        hours * stations as f64,
        a.seconds_per_point,
        if stations > 1 {
            format!(
                " ({hours:.2} h from each of {stations} stations: the program runs once from each)"
            )
        } else {
            String::new()
        },
        options.dialect
    );
    if let Some(stated) = &plan.approach {
        let (up, down) = stated.iter().fold((0, 0), |(u, d), s| {
            (
                u + usize::from(s.0.contains(&1)),
                d + usize::from(s.0.contains(&-1)),
            )
        });
        println!(
            "  the plan states directions of approach ({up} measurements with an axis arriving \
             from below, {down} from above): each such axis travels the overrun ({} mm, {}°) \
             in its direction before the position, at F{}",
            a.overrun, a.overrun_deg, a.approach_feed
        );
    }
    println!("  measuring program: {}", out.display());
    Ok(())
}

/// Checks every file `plan` may write (`--out`, `--gcode` and, with `--reflectors`, the
/// machine file derived from `--out`) against its inputs and each other before anything runs;
/// returns the derived machine file's path.
fn claim_outputs(a: &PlanArgs) -> Result<Option<PathBuf>> {
    let inputs = [
        a.machine.as_deref(),
        a.model.as_deref(),
        a.reflectors.as_deref(),
        a.plan_file.as_deref(),
    ];
    let mut outputs = volver::core::fsio::Outputs::new(inputs.into_iter().flatten());
    for out in [&a.out, &a.gcode].into_iter().flatten() {
        outputs.claim(out)?;
    }
    let derived = a
        .out
        .as_ref()
        .filter(|_| a.reflectors.is_some())
        .map(|o| o.with_extension("machine.toml"));
    if let Some(path) = &derived {
        outputs.claim(path).with_context(|| {
            format!(
                "plan writes the machine file of its candidate reflectors beside --out, as {}",
                path.display()
            )
        })?;
    }
    Ok(derived)
}

/// The candidate reflectors of a TOML file (`[[reflector]]` tables with `id` and `offset`).
fn extra_reflectors(path: &Path) -> Result<Vec<volver::core::machine::ReflectorSpec>> {
    #[derive(serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct File {
        reflector: Vec<volver::core::machine::ReflectorSpec>,
    }
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let file: File = toml::from_str(&text).map_err(|e| {
        anyhow::anyhow!(
            "{}: {}",
            path.display(),
            e.to_string().lines().collect::<Vec<_>>().join(" ")
        )
    })?;
    Ok(file.reflector)
}

/// `--compare`: the plans side by side on simulated truths.
fn compare_plans(
    a: &PlanArgs,
    model: &volver::core::model::Model,
    list: &str,
    noise: &TrackerNoise,
    tool: [f64; 3],
) -> Result<()> {
    let machine = model.machine();
    let mut plans = Vec::new();
    for item in list.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let plan = if Path::new(item).exists() {
            file::load(machine, Path::new(item))?
        } else {
            // PRESET or PRESET/ID+ID…: the preset measuring those reflectors only.
            let (name, ids) = item.split_once('/').unwrap_or((item, ""));
            let mut plan = volver::inputs::plan(machine, None, Some(name))
                .with_context(|| format!("--compare {item}: neither a plan file nor a preset"))?;
            if !ids.is_empty() {
                plan.reflectors = ids
                    .split('+')
                    .map(|id| {
                        machine.reflector_index(id).ok_or_else(|| {
                            anyhow::anyhow!("--compare {item}: no reflector '{id}' in the machine")
                        })
                    })
                    .collect::<Result<_>>()?;
                volver::planning::check_distinct_reflectors(machine, &plan.reflectors)
                    .with_context(|| format!("--compare {item}"))?;
            }
            plan
        };
        plans.push((item.to_string(), plan));
    }
    if plans.is_empty() {
        bail!("--compare {list:?}: no plan named (comma-separated plan files or presets)");
    }
    let drift = (a.drift != "none").then_some(a.drift.as_str());
    let rows = compare(model, &plans, a.seeds, noise, tool, drift)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
        return Ok(());
    }
    println!(
        "volver plan --compare — {} truths per plan ({} noise, tool at {:?} mm); tool point after the set-up's transform",
        a.seeds, noise, tool
    );
    println!(
        "| plan | points | predicted U mean µm | realised EMM µm (mean of seeds) | coverage of U | {} found |",
        drift.unwrap_or("drift")
    );
    println!("|---|---|---|---|---|---|");
    for r in &rows {
        println!(
            "| {} | {} | {:.2} | {:.2} | {:.1} % | {} |",
            r.label,
            r.points,
            r.u95_mean_um,
            r.realised_emm_um,
            100.0 * r.coverage,
            if r.drift_runs > 0 {
                format!("{} of {}", r.drift_found, r.drift_runs)
            } else {
                "–".to_string()
            }
        );
    }
    Ok(())
}
