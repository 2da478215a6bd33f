//! `volver demo`: the main job on an embedded machine (the XCFZ grinder by default, or a
//! five-axis preset with `--machine`). A synthetic verification whose data carry an effect the
//! starting model lacks; identification; the diagnosis that finds it; the model with it;
//! compensation checked on the true machine (of the tool's point, and of its direction on a
//! five-axis machine); the HTML report and the controller tables.

use anyhow::{Context, Result};
use std::path::{Path, PathBuf};
use volver::compensation::{
    TruthCheck, check_on_truth, reflector_centroid, travel_grid, write_tables,
};
use volver::core::compensate::{Compensator, cross};
use volver::core::measure::MeasurementSet;
use volver::core::model::Model;
use volver::core::plan::Plan;
use volver::core::problem::{Problem, Residuals};
use volver::core::results::ResultsFile;
use volver::core::simulate::{Effect, Magnitudes, Simulation, Synthetic, Truth};
use volver::core::tables::ErrorTables;
use volver::core::units::{UM_PER_MM, URAD_PER_RAD};
use volver::diagnosis::Standing;
use volver::inputs::{DEMO_DIR, DEMO_EFFECT, DEMO_SEED};
use volver::report::{self, Fit, ReportInput};
use volver::solvers::Options;
use volver::solvers::candidates::{Score, library, rank};
use volver::solvers::strategy::Identification;
use volver::solvers::strategy::{cross_validate, fit};
use volver::solvers::uncertainty::Covariance;

/// Options of `volver demo`.
#[derive(clap::Args)]
pub struct DemoArgs {
    /// Output folder.
    #[arg(long, default_value = DEMO_DIR)]
    out: PathBuf,
    /// The embedded machine (`volver layout --list`): xcfz, the paper's grinder, or a five-axis
    /// preset (table-table, head-head, head-table), whose demo hides a drift of its tilt axis'
    /// line and compensates the tool's point and direction.
    #[arg(long, value_name = "NAME", default_value = "xcfz")]
    machine: String,
}

/// The machine the demo runs on and what it hides in the data.
struct Setup {
    preset: &'static volver::core::presets::Preset,
    /// The folder of the simulated test under the output folder.
    data_dir: String,
}

impl Setup {
    fn xcfz(&self) -> bool {
        self.preset.name == "xcfz"
    }

    /// The hidden effect: the preset's ([`DEMO_EFFECT`] on the XCFZ grinder).
    fn effect(&self) -> &'static str {
        self.preset.demo_effect
    }
}

fn um(v: f64) -> String {
    format!("{v:.2}")
}

/// Runs the demo: seven steps, each printing its paragraph.
pub fn run(a: DemoArgs) -> Result<()> {
    let out_dir = a.out.as_path();
    let Some(preset) = volver::core::presets::named(&a.machine) else {
        anyhow::bail!(
            "--machine {}: not an embedded machine (they are {}; `volver layout --list` names them)",
            a.machine,
            volver::core::presets::names().join(", ")
        );
    };
    let setup = Setup {
        preset,
        data_dir: if preset.name == "xcfz" {
            "test4".to_string()
        } else {
            preset.name.to_string()
        },
    };
    let model = if setup.xcfz() {
        Model::default_xcfz()
    } else {
        preset.model()?
    };
    if setup.xcfz() {
        println!(
            "volver demo — the XCFZ grinder of Aguado et al. (2014), chain {}, and the paper's error model ({} parameters)\n",
            model.machine().chain(),
            model.n_params()
        );
    } else {
        println!(
            "volver demo — {}, chain {}, and its default error model ({} parameters: every ISO 230-1 error of the five axes, the rotary axes' location errors among them)\n",
            model.machine().spec().name,
            model.machine().chain(),
            model.n_params()
        );
    }
    let out = simulate(&setup, &model, out_dir)?;
    let data = &out.measurements;
    let id1 = identify_first(&setup, &model, data)?;
    let (ranked, best, model2) = diagnose(&setup, &model, data, &id1)?;
    let id2 = identify_with(&model2, data, &best.id, out.record.noise_error.emm_um)?;
    if setup.xcfz() {
        print_estimators(&model2, &out)?;
    }
    let first = (&model, &id1);
    let second = (&model2, &id2);
    let cross = cross_validation(&setup, first, second, &best.id, &out)?;
    let check = if setup.xcfz() {
        compensation(&model2, &id2, &out)?
    } else {
        compensation_five_axis(&model2, &id2, &out)?
    };
    let cov = vouch(&model2, data, &id2, &check)?;
    let noise =
        volver::solvers::uncertainty::NoiseModel::Tracker(volver::core::noise::TrackerNoise::PAPER);
    let fit_check = volver::uncertainty::check_fit(&Problem::new(&model2, data)?, &id2, noise);
    let mut table_paths = write_results(out_dir, &model2, &id2, &cov, fit_check)?;
    table_paths.extend(per_axis_files(out_dir, &model2, &id2.params, check.tool)?);
    let first_label = if setup.xcfz() {
        "paper model"
    } else {
        "default model"
    };
    let fits = vec![
        Fit {
            label: first_label.into(),
            model: &model,
            id: &id1,
        },
        Fit {
            label: format!("+ {}", best.id),
            model: &model2,
            id: &id2,
        },
    ];
    write_report(&setup, out_dir, &out, fits, ranked, cross, &check)?;
    let standing = against_noise(&Problem::new(&model2, data)?, &id2)?.0;
    where_you_are(&setup, out_dir, &table_paths, &best.id, standing);
    Ok(())
}

/// The demo's plan on its machine: test 4 on the XCFZ grinder, the preset plan on the others.
fn demo_plan(setup: &Setup, m: &volver::core::machine::Machine) -> Result<Plan> {
    Ok(if setup.xcfz() {
        Plan::preset(m, "test4")?
    } else {
        setup.preset.plan_on(m)?
    })
}

/// Step 1: A verification with something the model lacks, written under `out_dir/test4` (the
/// preset's name on a five-axis machine).
fn simulate(setup: &Setup, model: &Model, out_dir: &Path) -> Result<Synthetic> {
    let m = model.machine();
    let truth = Truth::random(m, model.spec(), &Magnitudes::default(), DEMO_SEED)?;
    let mut sim = Simulation::new(demo_plan(setup, m)?, truth, DEMO_SEED);
    let effect = setup.effect();
    sim.effects = vec![Effect::parse(effect)?];
    let out = sim.run()?;
    std::fs::create_dir_all(out_dir).with_context(|| format!("creating {}", out_dir.display()))?;
    out.write(&out_dir.join(&setup.data_dir))?;
    let r = &out.record;
    let noise = r.noise_error.emm_um;
    if setup.xcfz() {
        println!(
            "1. Simulated verification: plan test4 ({} points), seed {DEMO_SEED}, the paper's tracker noise, true errors at the default magnitudes",
            r.points
        );
        println!(
            "   hidden in the data: {DEMO_EFFECT} — a 2nd harmonic in every error of the turntable C (the model has only the 1st)"
        );
    } else {
        let tilt = m
            .axes()
            .iter()
            .find(|a| a.axis.is_rotary() && a.max - a.min < std::f64::consts::TAU - 1e-9)
            .map_or('A', |a| a.axis.letter());
        println!(
            "1. Simulated verification: the preset plan of {} ({} points: a grid of the linear axes, the rotary axes swept at the centre and at the corners), seed {DEMO_SEED}, the paper's tracker noise, true errors at the default magnitudes",
            setup.preset.name, r.points
        );
        println!(
            "   hidden in the data: {effect} — the line of the tilt axis {tilt} drifting with time as the machine warms (its location errors growing by µm/h), which the model lacks"
        );
    }
    println!(
        "   machine error EMM {} µm; noise error EMM {} µm (what a perfect model would leave)",
        um(r.machine_error.emm_um),
        um(noise)
    );
    Ok(out)
}

/// Step 2: Identification with the starting model.
fn identify_first(setup: &Setup, model: &Model, data: &MeasurementSet) -> Result<Identification> {
    let p1 = Problem::new(model, data)?;
    let id1 = fit(p1.clone());
    if id1.termination.failed() {
        anyhow::bail!("identification failed: {}", id1.termination);
    }
    let repeat = volver::core::diagnose::repeat_noise(&p1);
    println!(
        "\n2. Identification, {} model: EMM {} → {} µm in {} iterations ({:.2} s)",
        if setup.xcfz() { "paper" } else { "default" },
        um(id1.initial.stats.emm_um),
        um(id1.reached.stats.emm_um),
        id1.iterations(),
        id1.time_s
    );
    if let Some((n, pairs)) = repeat {
        println!(
            "   noise estimated from {pairs} repeated points: EMM {} µm — the fit is {:.2} × that",
            um(n.emm_um),
            id1.reached.stats.emm_um / n.emm_um
        );
    }
    println!("   {}", against_noise(&p1, &id1)?.1);
    Ok(id1)
}

/// The fit `id` of `problem` against what the tracker's noise leaves (the machine file's noise,
/// else the paper's): its standing, and a line saying it with its figures and the conclusion
/// chosen from them.
fn against_noise(problem: &Problem, id: &Identification) -> Result<(Standing, String)> {
    let noise = problem
        .model()
        .machine()
        .tracker()
        .noise
        .unwrap_or(volver::core::noise::TrackerNoise::PAPER);
    let emm = id.reached.stats.emm_um;
    let (level, standing) = volver::diagnosis::standing(problem, &id.params, emm, &noise)
        .ok_or_else(|| anyhow::anyhow!("the fit's identifiability cannot be analysed"))?;
    let line = format!(
        "the fit is {:.2} × what the tracker's noise leaves ({} ± {} µm): {}",
        level.ratio(emm),
        um(level.fit_emm_um),
        um(2.0 * level.sd_um),
        standing.conclusion()
    );
    Ok((standing, line))
}

/// Step 3's first look at the residuals: on the XCFZ grinder their periodogram over C (where
/// the hidden harmonic shows), on a five-axis preset the EMM of each quarter of the test (where
/// a drift shows).
fn print_residual_view(setup: &Setup, p1: &Problem, id1: &Identification) -> Result<()> {
    let m = p1.model().machine();
    if setup.xcfz() {
        let rm =
            volver::core::diagnose::to_machine_frame(p1, &id1.params, &p1.residuals(&id1.params));
        let (kc, _) = m
            .axis(volver::core::iso::Axis::C)
            .ok_or_else(|| anyhow::anyhow!("the demo machine has no C axis"))?;
        let lines = volver::core::diagnose::axis_periodogram(p1, &rm, kc, 4);
        let cells: Vec<String> = lines
            .iter()
            .map(|l| format!("order {}: {:.1} µm", l.frequency, l.total_um()))
            .collect();
        println!(
            "\n3. Diagnosis: periodogram of the residuals over C — {}",
            cells.join(", ")
        );
    } else {
        // A drift shows as residuals that grow with time: the EMM of each quarter of the test.
        let norms: Vec<f64> = p1
            .residuals(&id1.params)
            .iter()
            .map(|r| volver::core::problem::norm(*r))
            .collect();
        let n = norms.len();
        let cells: Vec<String> = (0..4)
            .map(|q| {
                let part = &norms[q * n / 4..(q + 1) * n / 4];
                format!(
                    "{:.1}",
                    UM_PER_MM * part.iter().sum::<f64>() / part.len().max(1) as f64
                )
            })
            .collect();
        println!(
            "\n3. Diagnosis: EMM of the residuals in each quarter of the test (in measuring order) — {} µm",
            cells.join(", ")
        );
    }
    Ok(())
}

/// Step 3: Where it fails and what is missing: the candidates ranked, the best, and the model with
/// it.
fn diagnose(
    setup: &Setup,
    model: &Model,
    data: &MeasurementSet,
    id1: &Identification,
) -> Result<(Vec<Score>, Score, Model)> {
    let m = model.machine();
    let p1 = Problem::new(model, data)?;
    print_residual_view(setup, &p1, id1)?;
    let ranked = rank(
        &p1,
        &id1.params,
        volver::solvers::identifiability::RANK_TOLERANCE,
        p1.model().machine().tracker().noise.as_ref(),
    );
    for (i, s) in ranked.iter().take(3).enumerate() {
        println!(
            "   {}. {:<14} ΔBIC {:>8.1}  EMM {:>7} µm  {}",
            i + 1,
            s.id,
            s.delta_bic,
            um(s.emm_um),
            s.description
        );
    }
    let best = ranked
        .first()
        .filter(|s| s.failed.is_none())
        .ok_or_else(|| {
            anyhow::anyhow!(
                "{}",
                volver::solvers::candidates::verdict(&ranked, id1.reached.stats.emm_um)
            )
        })?;
    let candidate = library(model)
        .into_iter()
        .find(|c| c.id == best.id)
        .ok_or_else(|| anyhow::anyhow!("candidate {} not in the library", best.id))?;
    println!(
        "   → the missing effect: {} ({})",
        best.id, best.description
    );
    let best = best.clone();
    let model2 = Model::new(m.clone(), candidate.spec.clone())?;
    Ok((ranked, best, model2))
}

/// Step 4: The model with the missing effect, identified.
fn identify_with(
    model2: &Model,
    data: &MeasurementSet,
    added: &str,
    noise: f64,
) -> Result<Identification> {
    let p2 = Problem::new(model2, data)?;
    let id2 = fit(p2.clone());
    if id2.termination.failed() {
        anyhow::bail!("identification failed: {}", id2.termination);
    }
    println!(
        "\n4. Identification with {}: EMM {} µm ({} parameters) — {:.3} × the noise error; {}",
        added,
        um(id2.reached.stats.emm_um),
        model2.n_params(),
        id2.reached.stats.emm_um / noise,
        against_noise(&p2, &id2)?.1
    );
    Ok(id2)
}

/// Step 4, continued: the estimators side by side on the same data and model (Φ, ml, whitened
/// Φ), judged on the true machine, beside the Cramér–Rao limit.
fn print_estimators(model2: &Model, out: &Synthetic) -> Result<()> {
    let grid = volver::solvers::uncertainty::ToolGrid {
        commands: volver::uncertainty::grid_of(model2.machine(), None)?.positions,
        tool: reflector_centroid(model2),
    };
    let noise = out.record.noise;
    let s = volver::estimators::side_by_side(
        model2,
        &out.measurements,
        noise,
        &grid,
        Some(&out.truth),
    )?;
    println!(
        "   the estimators on these data ({noise} noise), the tool point over {} commands after the set-up's transform, on the true machine:",
        grid.commands.len()
    );
    println!(
        "     {:<8} {:>14} {:>15} {:>14} {:>9}",
        "", "error µm (RMS)", "expected µm", "U95 max µm", "EMM µm"
    );
    for r in &s.rows {
        println!(
            "     {:<8} {:>14} {:>15.2} {:>14.2} {:>9.2}",
            r.objective.to_string(),
            r.realised_um.map_or("-".into(), |v| format!("{v:.2}")),
            r.expected_um,
            r.u95_max_um,
            r.emm_um
        );
    }
    let why = if s.normal {
        "no unbiased estimator's expected error is lower"
    } else {
        "the noise is bounded: no unbiased estimator linear in the data does better"
    };
    println!(
        "     {} of this plan and noise: {:.2} µm ({why}); `--objective ml` reaches it",
        s.limit_name(),
        s.cramer_rao_um
    );
    Ok(())
}

/// Step 5: Cross-validation of both fits on an independent reference test.
fn cross_validation(
    setup: &Setup,
    (model, id1): (&Model, &Identification),
    (model2, id2): (&Model, &Identification),
    added: &str,
    out: &Synthetic,
) -> Result<Vec<report::CrossRow>> {
    let m = model.machine();
    let options = Options::default();
    let reference =
        Simulation::new(demo_plan(setup, m)?, out.truth.clone(), DEMO_SEED + 1).run()?;
    let lm = volver::solvers::lm::LevenbergMarquardt::default();
    let mut cross = Vec::new();
    let first = if setup.xcfz() {
        "paper model"
    } else {
        "default model"
    };
    for (label, mdl, params) in [(first, model, &id1.params), (added, model2, &id2.params)] {
        let problem = Problem::new(mdl, &reference.measurements)?;
        let cv = cross_validate(
            &lm,
            problem.clone(),
            params,
            &options,
            &mut volver::solvers::Silent,
        );
        cross.push(report::CrossRow::new(label.to_string(), &problem, &cv));
    }
    println!(
        "\n5. Cross-validation on an independent {} (new noise), only the measurement fitted ({}):",
        if setup.xcfz() {
            "test 4"
        } else {
            "run of the same plan"
        },
        report::measurement_parts(model2).join(", ")
    );
    for c in &cross {
        println!(
            "   errors of the {:<12} EMM {} → {} ± {} µm (k = 2), residual {:.1} %",
            c.label,
            um(c.emm_before_um),
            um(c.emm_after_um),
            um(c.emm_after_u95_um),
            c.residual_percent
        );
    }
    Ok(cross)
}

/// What compensation does to the true machine over a grid of the work volume, with the tool
/// point compensated.
struct Check {
    /// The tool point (mm, frame of the last tool-side axis).
    tool: [f64; 3],
    /// The check on the true machine.
    truth: TruthCheck,
}

impl std::ops::Deref for Check {
    type Target = TruthCheck;
    fn deref(&self) -> &TruthCheck {
        &self.truth
    }
}

/// "; N leave the travel" when N > 0.
fn leaving(outside: usize) -> String {
    if outside > 0 {
        format!("; {outside} leave the travel")
    } else {
        String::new()
    }
}

/// Step 6: Compensation, checked on the true machine (known here).
fn compensation(model2: &Model, id2: &Identification, out: &Synthetic) -> Result<Check> {
    let m = model2.machine();
    let tool = reflector_centroid(model2);
    let comp = Compensator::new(model2, &id2.params, tool)?;
    let truth = Compensator::new(&out.truth.model, &out.truth.params, tool)?;
    let mut grid = Vec::new();
    for i in 0..=10 {
        for j in 0..12 {
            for k in 0..=6 {
                grid.push(m.commands_from_file_units(&[
                    140.0 * i as f64,
                    30.0 * j as f64,
                    100.0 * k as f64,
                ]));
            }
        }
    }
    let c = check_on_truth(&comp, &truth, &grid)?;
    println!(
        "\n6. Compensation over a {}-point grid of the work volume (tool point at the reflectors' centroid), checked on the true machine:",
        grid.len()
    );
    println!(
        "   true tool-point error EMM {} → {} µm, EMax {} → {} µm in the workpiece frame; every command verified through the model (largest deviation {:.1e} mm){}",
        um(c.before.emm_um),
        um(c.after.emm_um),
        um(c.before.emax_um),
        um(c.after.emax_um),
        c.worst_deviation_mm,
        leaving(c.outside_travel)
    );
    Ok(Check { tool, truth: c })
}

/// Step 6 on a five-axis machine: compensation of the tool point (the first reflector, at the
/// tool's tip) and of the tool's direction (−z of the last tool-side axis) over a grid of the
/// travel (5 positions per axis), checked on the true machine.
fn compensation_five_axis(model2: &Model, id2: &Identification, out: &Synthetic) -> Result<Check> {
    let m = model2.machine();
    let tool = m.reflectors()[0].offset;
    let axis = [0.0, 0.0, -1.0];
    let comp = Compensator::with_orientation(model2, &id2.params, tool, axis)?;
    let truth = Compensator::with_orientation(&out.truth.model, &out.truth.params, tool, axis)?;
    let grid = travel_grid(m, 5)?;
    let c = check_on_truth(&comp, &truth, &grid)?;
    let direction = c
        .direction
        .ok_or_else(|| anyhow::anyhow!("the five-axis check has no direction"))?;
    println!(
        "\n6. Compensation of the tool point ({} mm, the tool's tip) and of the tool's direction (−z) over a {}-point grid of the travel (5 positions per axis, 10 % inside its ends), every axis solved, checked on the true machine:",
        volver::compensation::point_mm(tool),
        grid.len()
    );
    println!(
        "   true tool-point error EMM {} → {} µm, EMax {} → {} µm in the workpiece frame; true direction error mean {} → {} µrad, largest {} → {} µrad",
        um(c.before.emm_um),
        um(c.after.emm_um),
        um(c.before.emax_um),
        um(c.after.emax_um),
        um(direction.before_urad.0),
        um(direction.after_urad.0),
        um(direction.before_urad.1),
        um(direction.after_urad.1)
    );
    let singular = if c.near_singularity > 0 {
        format!(
            "; {} pass within {}° of the singularity (the tilt axis at zero): there the rotary axis above it keeps its angle, the tilt axis corrects what it can of the direction (up to {:.1} µrad left)",
            c.near_singularity,
            volver::core::compensate::SINGULAR_TILT_DEG,
            c.worst_singular_rad * URAD_PER_RAD
        )
    } else {
        String::new()
    };
    println!(
        "   every command verified through the model (largest deviation {:.1e} mm; direction {:.1e} rad away from the singularity){}{singular}",
        c.worst_deviation_mm,
        c.worst_direction_rad,
        leaving(c.outside_travel)
    );
    println!(
        "   direction after the set-up's rigid transform: mean {} µrad, largest {} µrad",
        um(direction.rigid_urad.0),
        um(direction.rigid_urad.1)
    );
    Ok(Check { tool, truth: c })
}

/// Step 6, continued: What the data vouch for: the U of the identified tool point over the same grid
/// (the tracker's noise as simulated), after the set-up's transform and raw.
fn vouch(
    model2: &Model,
    data: &MeasurementSet,
    id2: &Identification,
    check: &Check,
) -> Result<Covariance> {
    let p2 = Problem::new(model2, data)?;
    let options = Options::default();
    let cov = volver::solvers::uncertainty::linear(
        &p2,
        id2.gauge.as_ref(),
        &id2.params,
        options.objective,
        volver::solvers::uncertainty::NoiseModel::Tracker(volver::core::noise::TrackerNoise::PAPER),
    )
    .ok_or_else(|| anyhow::anyhow!("the uncertainty of the fit could not be computed"))?;
    let grid = volver::solvers::uncertainty::ToolGrid {
        commands: check.grid.clone(),
        tool: check.tool,
    };
    let largest = |aligned: bool| {
        grid.uncertainty(model2, &id2.params, &cov, aligned)
            .iter()
            .map(|u| u.u95_max_mm())
            .fold(0.0_f64, f64::max)
            * UM_PER_MM
    };
    let (u_rigid, u_raw) = (largest(true), largest(false));
    // The held combination that dominates the raw U, by name.
    let raw_worst = grid
        .uncertainty(model2, &id2.params, &cov, false)
        .iter()
        .max_by(|a, b| a.u95_max_mm().total_cmp(&b.u95_max_mm()))
        .and_then(|u| u.worst_held)
        .zip(id2.gauge.as_ref())
        .map(|(c, g)| volver::uncertainty::combination_text(model2, g, c))
        .unwrap_or_else(|| "none".into());
    println!(
        "   after the best rigid transform (what the workpiece set-up takes up): EMM {} µm, EMax {} µm; U of the identified tool point there (k = 2) up to {} µm",
        um(check.rigid.emm_um),
        um(check.rigid.emax_um),
        um(u_rigid),
    );
    if check.direction.is_some() {
        let u = direction_u95_rad(model2, &id2.params, &cov, check);
        println!(
            "   U of the identified tool direction there (k = 2, raw in the workpiece frame) up to {} µrad",
            um(u * URAD_PER_RAD)
        );
    }
    if id2.gauge.as_ref().is_some_and(|g| !g.held.is_empty()) {
        println!(
            "   raw, U reaches {} µm, mostly from a combination the data cannot identify ({raw_worst}): a constant shift of the tool that the set-up takes up",
            um(u_raw)
        );
    } else {
        println!(
            "   raw, U reaches {} µm: the model holds no combination; what is left is mostly where the set-up put the tracker relative to the table, which the workpiece set-up takes up",
            um(u_raw)
        );
    }
    Ok(cov)
}

/// The largest expanded uncertainty (k = 2, rad) of the identified tool direction over the
/// check's grid: the direction is the difference of the tool point and a point 1 mm behind it
/// on the tool's axis, so its Jacobian is the difference of theirs, taken across the direction.
fn direction_u95_rad(model: &Model, params: &[f64], cov: &Covariance, check: &Check) -> f64 {
    let n = model.n_params();
    let back = [check.tool[0], check.tool[1], check.tool[2] + 1.0];
    let (mut jt, mut jb) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
    let mut worst = 0.0_f64;
    for q in &check.grid {
        let tip = model.tool_point_with_jacobian(q, &check.tool, params, &mut jt);
        let behind = model.tool_point_with_jacobian(q, &back, params, &mut jb);
        let d: [f64; 3] = std::array::from_fn(|c| tip[c] - behind[c]);
        // Two unit vectors across d.
        let unit = |c: [f64; 3]| c.map(|x| x / volver::core::problem::norm(c));
        let e1 = unit(cross(
            d,
            if d[0].abs() < 0.9 {
                [1.0, 0.0, 0.0]
            } else {
                [0.0, 1.0, 0.0]
            },
        ));
        let e2 = unit(cross(d, e1));
        let across = |e: [f64; 3]| -> f64 {
            let g: Vec<f64> = (0..n)
                .map(|j| (0..3).map(|c| e[c] * (jt[c * n + j] - jb[c * n + j])).sum())
                .collect();
            cov.u(&g)
        };
        worst = worst.max(across(e1).hypot(across(e2)));
    }
    volver::solvers::uncertainty::K * worst
}

/// Step 7: The results file and the controller tables (with their U); returns the tables' paths.
fn write_results(
    out_dir: &Path,
    model2: &Model,
    id2: &Identification,
    cov: &Covariance,
    fit_check: volver::core::results::ModelCheck,
) -> Result<Vec<PathBuf>> {
    let mut results = ResultsFile::from_model(model2, &id2.params)?;
    let held = volver::uncertainty::held_text(model2, id2.gauge.as_ref());
    let mut record = cov.to_record(volver::solvers::gauge::RULE, held);
    record.model_check = Some(fit_check);
    results.uncertainty = Some(record);
    let fit_path = out_dir.join("fit.json");
    results.save(&fit_path)?;
    let tables = ErrorTables::from_model(model2, &id2.params, 10.0, 5.0)?;
    let mut table_paths = write_tables(&tables, &out_dir.join("tables"))?;
    if let Some(r) = &results.uncertainty {
        let u =
            volver::compensation::table_uncertainty(model2, &id2.params, r, &tables, 10.0, 5.0)?;
        let p = out_dir.join("tables").join("errors-u95.csv");
        volver::core::fsio::write_atomic(&p, u.to_plain_csv())
            .with_context(|| format!("writing {}", p.display()))?;
        table_paths.push(p);
    }
    Ok(table_paths)
}

/// The demo report's identity block: nothing but what the demo is (a field not given prints
/// as "—").
fn demo_identity() -> report::Identity {
    report::Identity {
        remarks: Some(
            "Synthetic data written by volver demo: no customer, instrument or operator.".into(),
        ),
        ..report::Identity::default()
    }
}

/// Step 7, continued: the per-axis tables of LinuxCNC and Siemens controls (the projections
/// of the identified error, `volver tables`) and what they leave beside volumetric
/// compensation, at the tool point; returns the files' paths.
fn per_axis_files(
    out_dir: &Path,
    model: &Model,
    params: &[f64],
    tool: [f64; 3],
) -> Result<Vec<PathBuf>> {
    use volver::compensation::{Format, compare_per_axis, controller_files};
    let tables = ErrorTables::from_model(model, params, 10.0, 5.0)?;
    // As `volver tables` without --force: no controller file for a model with parts that
    // per-axis tables cannot carry (a drift over time, a field over the axes).
    let uncarried = volver::compensation::carry(model, params, &tables, tool)?.lines();
    if !uncarried.is_empty() {
        println!(
            "\n   LinuxCNC and Siemens tables not written: per-axis tables cannot carry {}",
            uncarried.join("; ")
        );
        return Ok(Vec::new());
    }
    let c = compare_per_axis(model, params, &tables, &[tool], 10.0, 5.0)?;
    println!(
        "\n   What each way of compensating leaves of the tool point's error over {} commands of \
         the travel (tool point {} mm):",
        c.leadscrew.1.grid.len(),
        volver::compensation::point_mm(tool)
    );
    for line in c.lines(model.machine()) {
        println!("     {line}");
    }
    let options = volver::core::tables::siemens::SiemensOptions::default();
    let mut paths = Vec::new();
    for (f, files) in controller_files(&c, model.machine(), &Format::ALL, &options) {
        match files {
            Ok(files) => {
                for (name, text) in files {
                    let p = out_dir.join("tables").join(name);
                    volver::core::fsio::write_atomic(&p, text)
                        .with_context(|| format!("writing {}", p.display()))?;
                    paths.push(p);
                }
            }
            Err(why) => println!("   {f} tables not written: {why}"),
        }
    }
    Ok(paths)
}

/// Step 7, continued: The HTML report of both fits.
fn write_report(
    setup: &Setup,
    out_dir: &Path,
    out: &Synthetic,
    fits: Vec<Fit>,
    ranked: Vec<Score>,
    cross: Vec<report::CrossRow>,
    check: &Check,
) -> Result<()> {
    let noise = out.record.noise_error.emm_um;
    let (id1, id2) = (fits[0].id, fits[1].id);
    let added = fits[1].label.trim_start_matches("+ ").to_string();
    let tool = if setup.xcfz() {
        reflector_centroid(fits[1].model)
    } else {
        check.tool
    };
    let identity = demo_identity();
    let title = format!(
        "{} — volver demo, synthetic data",
        identity.title(&fits[0].model.machine().spec().name)
    );
    let note = if setup.xcfz() {
        format!(
            "Synthetic verification of the XCFZ grinder (plan test4, seed {DEMO_SEED}) with an effect the paper's model lacks ({DEMO_EFFECT}). The paper's model left EMM {} µm; the diagnosis named {}; with it the fit ends at {} µm against a noise error of {} µm. Compensation with the final errors takes the true tool-point error from EMM {} to {} µm in the workpiece frame, and to {} µm after the best rigid transform (which a workpiece set-up takes up).",
            um(id1.reached.stats.emm_um),
            added,
            um(id2.reached.stats.emm_um),
            um(noise),
            um(check.before.emm_um),
            um(check.after.emm_um),
            um(check.rigid.emm_um)
        )
    } else {
        let d = check.direction.as_ref();
        format!(
            "Synthetic verification of the {} preset (its preset plan, seed {DEMO_SEED}) with an effect its default model lacks ({}). The default model left EMM {} µm; the diagnosis named {}; with it the fit ends at {} µm against a noise error of {} µm. Compensation of the tool point and direction with every axis takes the true tool-point error from EMM {} to {} µm in the workpiece frame ({} µm after the best rigid transform), and the tool direction's error from {} to {} µrad on average.",
            setup.preset.name,
            setup.effect(),
            um(id1.reached.stats.emm_um),
            added,
            um(id2.reached.stats.emm_um),
            um(noise),
            um(check.before.emm_um),
            um(check.after.emm_um),
            um(check.rigid.emm_um),
            um(d.map_or(f64::NAN, |d| d.before_urad.0)),
            um(d.map_or(f64::NAN, |d| d.after_urad.0))
        )
    };
    let input = ReportInput {
        title,
        identity,
        data_label: out_dir
            .join(&setup.data_dir)
            .join("measurements.csv")
            .display()
            .to_string(),
        data: &out.measurements,
        fits,
        truth: Some((&out.truth.model, &out.truth.params)),
        noise_um: Some(noise),
        candidates: ranked,
        engines: Vec::new(),
        cross,
        notes: vec![note],
        tool,
        max_u_um: 25.0,
    };
    let html = report::html(&input)?;
    let report_path = out_dir.join("report.html");
    volver::core::fsio::write_atomic(&report_path, html)
        .with_context(|| format!("writing {}", report_path.display()))?;
    Ok(())
}

/// Step 7, continued: What was written and what to do next.
fn where_you_are(
    setup: &Setup,
    out_dir: &Path,
    table_paths: &[PathBuf],
    added: &str,
    standing: Standing,
) {
    println!("\n7. Written in {}/:", out_dir.display());
    println!(
        "   report.html              the HTML report (maps, vectors, error functions, diagnosis, identifiability)"
    );
    println!("   fit.json                 the identified errors (results file)");
    for p in table_paths {
        println!(
            "   {:<24} controller table",
            p.strip_prefix(out_dir).unwrap_or(p).display()
        );
    }
    let dir = &setup.data_dir;
    println!(
        "   {:<24} the measurements, the truth and the simulation record",
        format!("{dir}/")
    );
    let state = match standing {
        Standing::AtNoise => {
            "the errors are identified and the model explains the data to the noise"
        }
        Standing::Above => {
            "the errors are identified, but the model does not yet explain the data (the fit is \
             above the noise): diagnose again before you compensate"
        }
        Standing::Below => {
            "the errors are identified; the fit is far below the noise the specification states, \
             so judge the model by the candidates"
        }
    };
    println!("\nWhere you are: {state}. Next:");
    // The machine is named on the command line unless it is the default.
    let machine = if setup.xcfz() {
        String::new()
    } else {
        format!(" --machine {}", setup.preset.name)
    };
    println!(
        "   volver diagnose{machine} --data {0}/{dir}/measurements.csv            (the diagnosis in full)",
        out_dir.display()
    );
    println!(
        "   volver compensate --results {0}/fit.json --gcode PART.nc --out PART-comp.nc",
        out_dir.display()
    );
    println!(
        "   volver report{machine} --data {0}/{dir}/measurements.csv --add {1} --truth {0}/{dir}/truth.json --out report.html",
        out_dir.display(),
        added
    );
}
