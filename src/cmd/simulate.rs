//! `volver simulate`: a synthetic test (measurements, true errors, machine file).

use anyhow::{Context, Result};
use std::path::PathBuf;
use volver::core::machine::Machine;
use volver::core::model::{ErrorModelSpec, Model};
use volver::core::noise::TrackerNoise;
use volver::core::plan::Plan;
use volver::core::results::ResultsFile;
use volver::core::simulate::{Effect, Magnitudes, Simulation, Truth, TruthSource};
use volver::core::units::S_PER_H;

/// The magnitude kinds, effects and an example, after `volver simulate --help`.
pub const SIMULATE_HELP: &str = "\
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
  thermal-scale=AXIS,PPM_PER_H        scale of a linear axis growing with time: EXX += α·x·t
  location-drift=AXIS,V1_UM_PER_H,V2_UM_PER_H
                                      line of a rotary axis drifting (X0C, Y0C += v·t for C)
  tracker-drift=RX,RY,RZ              tracker's orientation drifting with time, µrad/h
  station-drift=ID,VX,VY,VZ           a station's position drifting with time, µm/h
  coupling=AXIS,COMPONENT,BY,AMP_UM   E{COMPONENT}{AXIS} += A·sin(πξ)·η: a straightness bow
                                      growing with the position of BY (ξ, η over 0 … 1)
  reversal=AXIS,B_UM                  ISO 230-2's reversal value B of an axis (µrad for a rotary
                                      axis; negative: lost motion): the tool ±B/2 along the axis
                                      relative to the workpiece by the direction of its last
                                      move (the measuring order, --order shuffled|bidirectional)

Example:
  volver simulate --plan test4 --seed 7 --out sim --effect thermal-drift=0,0,15";

/// Options of `volver simulate`.
#[derive(clap::Args)]
pub struct SimulateArgs {
    /// Test plan: table4, table7, test1 … test5, an embedded machine's name (its preset plan), or
    /// a grid such as X=0:1400:100,Z=0:600:50,C=0 (file units: mm, degrees; grids joined by `;`
    /// are measured in turn). Default: the embedded machine's preset plan (test4 on the XCFZ
    /// grinder and on a machine file).
    #[arg(long)]
    plan: Option<String>,
    /// A plan file instead (CSV: the axes, reflector, optionally order; as `volver plan`
    /// writes it): its rows are measured in the file's order, each axis arriving as volver's
    /// measuring program brings it (with the machine's [clearance]: the clearance axes from
    /// the clearance's side; the stated directions of approach).
    #[arg(long, conflicts_with_all = ["plan", "reflectors"])]
    plan_file: Option<PathBuf>,
    /// Seed of the true errors, the harmonics' phases and the noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Output folder (created if missing; files of the same names are replaced).
    #[arg(long)]
    out: PathBuf,
    /// Machine file (TOML) or an embedded machine's name (`volver layout --list`); the embedded
    /// XCFZ grinder when absent.
    #[arg(long)]
    machine: Option<PathBuf>,
    /// True errors from a results file (JSON) instead of random ones.
    #[arg(long, conflicts_with_all = ["truth_model", "magnitude"])]
    truth: Option<PathBuf>,
    /// Error model (TOML) giving the structure of the random true errors; when absent, an
    /// embedded five-axis machine's default model, else every error of the machine (cubic /
    /// first harmonic).
    #[arg(long)]
    truth_model: Option<PathBuf>,
    /// Size of the random true errors of one kind, e.g. straightness=20 (see below).
    #[arg(long = "magnitude", value_name = "KIND=VALUE")]
    magnitude: Vec<String>,
    /// Tracker noise: paper (uniform on ±30 µrad, ±30 µrad, ±(4 µm + 0.8 µm/m): the paper's
    /// "±" values read as bounds, which reproduces its tables 9–10), none, a distribution and
    /// four values: normal:AZ_URAD,EL_URAD,RANGE_UM,RANGE_UM_PER_M (σ) or uniform:… (bounds),
    /// or a maximum permissible error mpe:A_UM,B_UM_PER_M (±(a + b·L), k = 2). Default: the
    /// machine file's `[tracker] noise`, else the paper's; given, it wins over the file's (the
    /// output says both) and every file written states it.
    #[arg(long)]
    noise: Option<String>,
    /// An effect outside the standard model, hidden in the data (see below); repeatable.
    #[arg(long = "effect", value_name = "EFFECT=VALUES")]
    effect: Vec<String>,
    /// Test duration in hours (time stamps t_s); 10 s per point when absent.
    #[arg(long)]
    duration_h: Option<f64>,
    /// Reflectors measured at each position, ids comma-separated; all when absent.
    #[arg(long)]
    reflectors: Option<String>,
    /// Tracker stations (multilateration), the plan measured from each in turn: a number N (a
    /// default layout S1 … SN on a 500 mm circle about the tracker, mounted as it is, every
    /// other one 400 mm higher) or a layout file (TOML, `[[station]]` tables as in a machine
    /// file). The machine file written carries them.
    #[arg(long, value_name = "N|LAYOUT", conflicts_with = "truth")]
    stations: Option<String>,
    /// What is observed: point (meas_x, meas_y, meas_z), spherical (az_deg, el_deg, range_mm)
    /// or range (range_mm alone, with its station: a tracing interferometer; only the noise's
    /// range part applies, e.g. --noise normal:0,0,0.1,0.15 for U(k = 2) = 0.2 µm + 0.3 µm/m).
    #[arg(long, default_value = "point", value_parser = ["point", "spherical", "range"])]
    observe: String,
    /// Measuring order: plan (the plan's or plan file's order; a plan file's approach_<AXIS>
    /// columns give its directions), shuffled (its measurements in a random order drawn from
    /// --seed, as an optimised route takes them: each axis reaches its positions from either
    /// side, which a reversal effect makes visible) or bidirectional (each visit of a pose
    /// measured twice, every moving axis arriving from below then from above over the
    /// overrun, as ISO 230-2 measures; the directions are written in approach_<AXIS> columns).
    #[arg(long, default_value = "plan", value_parser = ["plan", "shuffled", "bidirectional"])]
    order: String,
    /// With --order bidirectional: a linear axis' overrun (mm); a position within it of a
    /// travel end is approached from the only side the travel allows.
    #[arg(long, default_value_t = volver::core::plan::sides::DEFAULT_OVERRUN_MM)]
    overrun: f64,
    /// With --order bidirectional: a rotary axis' overrun (degrees).
    #[arg(long, default_value_t = volver::core::plan::sides::DEFAULT_OVERRUN_DEG)]
    overrun_deg: f64,
}

/// Runs `volver simulate`.
pub fn run(a: SimulateArgs) -> Result<()> {
    claim_outputs(&a)?;
    let (truth, source, preset) = truth_of(&a)?;
    let machine = truth.model.machine().clone();
    let plan = plan_of(&a, &machine, preset)?;
    let mut sim = Simulation::new(plan, truth, a.seed);
    sim.truth_source = source;
    if a.observe == "range" {
        sim.observe = volver::core::measure::Observation::Range;
    }
    // With --truth and --machine (the same geometry, checked), the noise is --machine's.
    let noise_machine = match (&a.machine, &a.truth) {
        (Some(_), Some(_)) => volver::inputs::machine(a.machine.as_deref())?.0,
        _ => machine.clone(),
    };
    let (noise, noise_source) = noise_of(a.noise.as_deref(), &noise_machine)?;
    sim.noise = noise;
    sim.effects = a
        .effect
        .iter()
        .map(|t| Effect::parse(t))
        .collect::<volver::core::Result<_>>()?;
    if let Some(h) = a.duration_h {
        sim.duration_s = Some(h * S_PER_H);
    }
    let out = sim.run()?;
    let columns = if a.observe == "spherical" {
        volver::core::measure::PointColumns::Spherical
    } else {
        volver::core::measure::PointColumns::Cartesian
    };
    let files = out.write_as(&a.out, columns)?;
    print_record(&out, &machine, &files, &noise_source);
    Ok(())
}

/// The noise to simulate with and where it comes from: `--noise` when given (naming the machine
/// file's when it differs), else the machine file's `[tracker] noise`, else the paper's; a
/// station whose `[[station]]` table states its own noise is simulated with its own (named per
/// station).
fn noise_of(given: Option<&str>, machine: &Machine) -> Result<(TrackerNoise, String)> {
    let (noise, source) = default_noise_of(given, machine)?;
    Ok(
        match volver::shared::station_noise_words(machine, Some(&noise)) {
            Some(words) => (noise, format!("{source}; by station, {words}")),
            None => (noise, source),
        },
    )
}

/// [`noise_of`]'s default, the tracker's, before the stations' own.
fn default_noise_of(given: Option<&str>, machine: &Machine) -> Result<(TrackerNoise, String)> {
    let file = machine.default_noise();
    Ok(match (given, file) {
        (Some(text), Some(f)) => {
            let n = TrackerNoise::from_text(text)?;
            if n == f {
                (n, "--noise, as the machine file's [tracker] noise".into())
            } else {
                (
                    n,
                    format!("--noise, over the machine file's [tracker] noise {f}"),
                )
            }
        }
        (Some(text), None) => (TrackerNoise::from_text(text)?, "--noise".into()),
        (None, Some(f)) => (f, "the machine file's [tracker] noise".into()),
        (None, None) => (
            TrackerNoise::PAPER,
            "the paper's (no --noise, no [tracker] noise in the machine file)".into(),
        ),
    })
}

/// Checks the four files `simulate` writes into `--out` against its input files (and each
/// other) before anything runs.
fn claim_outputs(a: &SimulateArgs) -> Result<()> {
    let stations = a.stations.as_deref().map(std::path::Path::new);
    let inputs = [
        a.machine.as_deref(),
        a.truth.as_deref(),
        a.truth_model.as_deref(),
        a.plan_file.as_deref(),
        stations,
    ];
    let mut outputs = volver::core::fsio::Outputs::new(inputs.into_iter().flatten());
    let f = volver::core::simulate::SimulationFiles::default();
    outputs.claim_in(
        &a.out,
        &[&f.measurements, &f.truth, &f.machine, "simulation.json"],
    )?;
    Ok(())
}

/// The true errors: from `--truth`, or drawn at random in `--truth-model`'s structure (every
/// error of the machine by default) at the `--magnitude`s; where they come from; and the
/// embedded machine `--machine` names (the XCFZ grinder when absent).
fn truth_of(
    a: &SimulateArgs,
) -> Result<(
    Truth,
    TruthSource,
    Option<&'static volver::core::presets::Preset>,
)> {
    let (given_machine, preset) = match &a.machine {
        Some(_) => {
            let (m, preset) = volver::inputs::machine(a.machine.as_deref())?;
            (Some(m), preset)
        }
        None => (None, volver::core::presets::named("xcfz")),
    };
    let (truth, source) = match &a.truth {
        Some(path) => {
            let label = path.display().to_string();
            let results = ResultsFile::load(path).context("reading the truth file")?;
            let truth = Truth::from_results(&results, &label).context("reading the truth file")?;
            // The geometry must agree (the noise is not geometry: the given machine's, or
            // --noise, is simulated); what differs is named.
            let differences = given_machine.as_ref().map_or_else(Vec::new, |m| {
                volver::identification::machine_differences(truth.model.machine().spec(), m.spec())
            });
            if !differences.is_empty() {
                anyhow::bail!(
                    "the machine of {label} differs from --machine {}: {}; leave --machine out \
                     to use the truth's machine",
                    a.machine
                        .as_ref()
                        .map(|p| p.display().to_string())
                        .unwrap_or_default(),
                    differences.join("; ")
                );
            }
            (truth, TruthSource::File { path: label })
        }
        None => {
            let m = with_stations(a, given_machine.unwrap_or_else(Machine::default_xcfz))?;
            let structure = match &a.truth_model {
                Some(p) => Model::load(m.clone(), p)
                    .context("reading the truth model")?
                    .spec()
                    .clone(),
                None => match preset {
                    Some(p) if p.name != "xcfz" => p.model()?.spec().clone(),
                    _ => ErrorModelSpec::complete(&m),
                },
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
    Ok((truth, source, preset))
}

/// `m` with the stations of `--stations` (a count laid out by default, or a layout file)
/// observing as `--observe` says; `m` as it is without `--stations`.
fn with_stations(a: &SimulateArgs, m: Machine) -> Result<Machine> {
    let Some(text) = &a.stations else {
        return Ok(m);
    };
    let observes = if a.observe == "range" {
        volver::core::machine::Observes::Range
    } else {
        volver::core::machine::Observes::Point
    };
    let layout = match text.parse::<usize>() {
        Ok(0) => anyhow::bail!("--stations 0: at least one station"),
        Ok(n) if n > volver::core::machine::MAX_STATIONS => anyhow::bail!(
            "--stations {n}: at most {} stations (every station measures the whole \
                 plan)",
            volver::core::machine::MAX_STATIONS
        ),
        Ok(n) => volver::core::machine::StationSpec::default_layout(&m, n, observes),
        Err(_) => {
            let path = std::path::Path::new(text);
            let body = std::fs::read_to_string(path)
                .with_context(|| format!("reading the station layout {text}"))?;
            volver::core::machine::StationSpec::layout_from_toml_str(&body, text)?
        }
    };
    Ok(m.with_stations(layout)?)
}

/// The plan of `--plan` on `machine` (an embedded machine: `preset`), measuring the reflectors
/// of `--reflectors`.
fn plan_of(
    a: &SimulateArgs,
    machine: &Machine,
    preset: Option<&volver::core::presets::Preset>,
) -> Result<Plan> {
    let plan = plan_in_order(a, machine, preset)?;
    let mut plan = match a.order.as_str() {
        "shuffled" => plan.shuffled(a.seed),
        "bidirectional" => {
            let overrun = volver::core::plan::sides::Overrun {
                linear_mm: a.overrun,
                rotary_deg: a.overrun_deg,
            };
            plan.bidirectional(machine, &overrun).with_context(|| {
                format!(
                    "--order bidirectional --overrun {} --overrun-deg {}",
                    a.overrun, a.overrun_deg
                )
            })?
        }
        _ => plan,
    };
    // A plan file is measured as volver's measuring program runs it: its clearance axes,
    // retracted between poses, arrive from the clearance's side.
    if a.plan_file.is_some() {
        plan.approach = Some(plan.program_or_order_approaches(machine, 1));
    }
    Ok(plan)
}

/// The plan of `--plan`, `--plan-file` or the preset, in its own order.
fn plan_in_order(
    a: &SimulateArgs,
    machine: &Machine,
    preset: Option<&volver::core::presets::Preset>,
) -> Result<Plan> {
    if let Some(path) = &a.plan_file {
        return Ok(volver::core::plan::file::load(machine, path)?);
    }
    let mut plan = volver::inputs::plan(machine, preset, a.plan.as_deref())?;
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
    Ok(plan)
}

/// What was simulated and written.
fn print_record(
    out: &volver::core::simulate::Synthetic,
    machine: &Machine,
    files: &[PathBuf],
    noise_source: &str,
) {
    let r = &out.record;
    if r.positions * r.reflectors.len() == r.points {
        println!(
            "volver simulate — plan {} ({} positions × {} reflectors = {} points), seed {}",
            r.plan,
            r.positions,
            r.reflectors.len(),
            r.points,
            r.seed
        );
    } else {
        println!(
            "volver simulate — plan {} ({} points at {} positions, reflectors {}, in the plan's order), seed {}",
            r.plan,
            r.points,
            r.positions,
            r.reflectors.join(", "),
            r.seed
        );
    }
    println!("  machine: {} ({})", machine.spec().name, machine.chain());
    match &r.truth {
        TruthSource::Random { structure, .. } => {
            println!("  true errors: random, structure \"{structure}\"")
        }
        TruthSource::File { path } => println!("  true errors: from {path}"),
        TruthSource::Given => println!("  true errors: given"),
        _ => println!("  true errors: another source"),
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
    println!("    from {noise_source}");
    if r.effects.is_empty() {
        println!("  hidden effects: none");
    } else {
        let list: Vec<String> = r.effects.iter().map(ToString::to_string).collect();
        println!("  hidden effects: {}", list.join("  "));
    }
    println!(
        "  duration: {:.2} h (t_s from 0 to {:.0} s)",
        r.duration_s / S_PER_H,
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
