//! `volver demo`: the main job on the embedded XCFZ grinder. A synthetic verification whose data
//! carry an effect the starting model lacks; identification; the diagnosis that finds it; the
//! model with it; compensation checked on the true machine; the HTML report and the controller
//! tables.

use anyhow::{Context, Result};
use std::path::{Path, PathBuf};
use volver::compensation::{reflector_centroid, write_tables};
use volver::core::compensate::Compensator;
use volver::core::machine::Commands;
use volver::core::measure::MeasurementSet;
use volver::core::metrics::ErrorStats;
use volver::core::model::Model;
use volver::core::plan::Plan;
use volver::core::problem::{Problem, Residuals};
use volver::core::results::ResultsFile;
use volver::core::simulate::{Effect, Magnitudes, Simulation, Synthetic, Truth};
use volver::core::tables::ErrorTables;
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
}

fn um(v: f64) -> String {
    format!("{v:.2}")
}

/// Runs the demo: seven steps, each printing its paragraph.
pub fn run(a: DemoArgs) -> Result<()> {
    let out_dir = a.out.as_path();
    let model = Model::default_xcfz();
    println!(
        "volver demo — the XCFZ grinder of Aguado et al. (2014), chain {}, and the paper's error model ({} parameters)\n",
        model.machine().chain(),
        model.n_params()
    );
    let out = simulate(&model, out_dir)?;
    let data = &out.measurements;
    let id1 = identify_first(&model, data)?;
    let (ranked, best, model2) = diagnose(&model, data, &id1)?;
    let id2 = identify_with(&model2, data, &best.id, out.record.noise_error.emm_um)?;
    let first = (&model, &id1);
    let second = (&model2, &id2);
    let cross = cross_validation(first, second, &best.id, &out)?;
    let check = compensation(&model2, &id2, &out)?;
    let cov = vouch(&model2, data, &id2, &check)?;
    let table_paths = write_results(out_dir, &model2, &id2, &cov)?;
    let fits = vec![
        Fit {
            label: "paper model".into(),
            model: &model,
            id: &id1,
        },
        Fit {
            label: format!("+ {}", best.id),
            model: &model2,
            id: &id2,
        },
    ];
    write_report(out_dir, &out, fits, ranked, cross, &check)?;
    where_you_are(out_dir, &table_paths, &best.id);
    Ok(())
}

/// Step 1: A verification with something the model lacks, written under `out_dir/test4`.
fn simulate(model: &Model, out_dir: &Path) -> Result<Synthetic> {
    let m = model.machine();
    let truth = Truth::random(m, model.spec(), &Magnitudes::default(), DEMO_SEED)?;
    let mut sim = Simulation::new(Plan::preset(m, "test4")?, truth, DEMO_SEED);
    sim.effects = vec![Effect::parse(DEMO_EFFECT)?];
    let out = sim.run()?;
    std::fs::create_dir_all(out_dir).with_context(|| format!("creating {}", out_dir.display()))?;
    out.write(&out_dir.join("test4"))?;
    let r = &out.record;
    let noise = r.noise_error.emm_um;
    println!(
        "1. Simulated verification: plan test4 ({} points), seed {DEMO_SEED}, the paper's tracker noise, true errors at the default magnitudes",
        r.points
    );
    println!(
        "   hidden in the data: {DEMO_EFFECT} — a 2nd harmonic in every error of the turntable C (the model has only the 1st)"
    );
    println!(
        "   machine error EMM {} µm; noise error EMM {} µm (what a perfect model would leave)",
        um(r.machine_error.emm_um),
        um(noise)
    );
    Ok(out)
}

/// Step 2: Identification with the starting model.
fn identify_first(model: &Model, data: &MeasurementSet) -> Result<Identification> {
    let p1 = Problem::new(model, data)?;
    let id1 = fit(p1.clone());
    if id1.termination.failed() {
        anyhow::bail!("identification failed: {}", id1.termination);
    }
    let repeat = volver::core::diagnose::repeat_noise(&p1);
    println!(
        "\n2. Identification, paper model: EMM {} → {} µm in {} iterations ({:.2} s)",
        um(id1.initial.stats.emm_um),
        um(id1.reached.stats.emm_um),
        id1.iterations(),
        id1.time_s
    );
    if let Some((n, pairs)) = repeat {
        println!(
            "   noise estimated from {pairs} repeated points: EMM {} µm — the fit is {:.2} × that: something is missing",
            um(n.emm_um),
            id1.reached.stats.emm_um / n.emm_um
        );
    }
    Ok(id1)
}

/// Step 3: Where it fails and what is missing: the candidates ranked, the best, and the model with
/// it.
fn diagnose(
    model: &Model,
    data: &MeasurementSet,
    id1: &Identification,
) -> Result<(Vec<Score>, Score, Model)> {
    let m = model.machine();
    let p1 = Problem::new(model, data)?;
    let rm = volver::core::diagnose::to_machine_frame(&p1, &id1.params, &p1.residuals(&id1.params));
    let (kc, _) = m
        .axis(volver::core::iso::Axis::C)
        .ok_or_else(|| anyhow::anyhow!("the demo machine has no C axis"))?;
    let lines = volver::core::diagnose::axis_periodogram(&p1, &rm, kc, 4);
    let cells: Vec<String> = lines
        .iter()
        .map(|l| format!("order {}: {:.1} µm", l.frequency, l.total_um()))
        .collect();
    println!(
        "\n3. Diagnosis: periodogram of the residuals over C — {}",
        cells.join(", ")
    );
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
        .ok_or_else(|| anyhow::anyhow!("no candidate to rank"))?;
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
        "\n4. Identification with {}: EMM {} µm ({} parameters) — {:.3} × the noise error: the model explains everything but the noise",
        added,
        um(id2.reached.stats.emm_um),
        model2.n_params(),
        id2.reached.stats.emm_um / noise
    );
    Ok(id2)
}

/// Step 5: Cross-validation of both fits on an independent reference test.
fn cross_validation(
    (model, id1): (&Model, &Identification),
    (model2, id2): (&Model, &Identification),
    added: &str,
    out: &Synthetic,
) -> Result<Vec<report::CrossRow>> {
    let m = model.machine();
    let options = Options::default();
    let reference =
        Simulation::new(Plan::preset(m, "test4")?, out.truth.clone(), DEMO_SEED + 1).run()?;
    let lm = volver::solvers::lm::LevenbergMarquardt::default();
    let mut cross = Vec::new();
    for (label, mdl, params) in [
        ("paper model", model, &id1.params),
        (added, model2, &id2.params),
    ] {
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
        "\n5. Cross-validation on an independent test 4 (new noise), tracker pose fitted only:"
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

/// What compensation does to the true machine over a grid of the work volume.
struct Check {
    /// The programmed commands.
    grid: Vec<Commands>,
    /// The tool point.
    tool: [f64; 3],
    /// True tool-point error before and after compensation, and after the best rigid transform.
    before: ErrorStats,
    after: ErrorStats,
    rigid: ErrorStats,
}

/// Step 6: Compensation, checked on the true machine (known here).
fn compensation(model2: &Model, id2: &Identification, out: &Synthetic) -> Result<Check> {
    let m = model2.machine();
    let tool = reflector_centroid(model2);
    let comp = Compensator::new(model2, &id2.params, tool)?;
    let (mut before, mut after) = (Vec::new(), Vec::new());
    let mut programmed_grid = Vec::new();
    let (mut worst, mut outside) = (0.0_f64, 0usize);
    for i in 0..=10 {
        for j in 0..12 {
            for k in 0..=6 {
                let programmed = m.commands_from_file_units(&[
                    140.0 * i as f64,
                    30.0 * j as f64,
                    100.0 * k as f64,
                ]);
                programmed_grid.push(programmed);
                let c = comp.compensate(&programmed)?;
                worst = worst.max(c.deviation_mm);
                outside += usize::from(!c.outside_travel.is_empty());
                let t = |q: &Commands| out.truth.model.tool_point(&q.0, &tool, &out.truth.params);
                before.push((t(&programmed), c.target));
                after.push((t(&c.commands), c.target));
            }
        }
    }
    let stats = |v: &[([f64; 3], [f64; 3])]| {
        let (a, b): (Vec<_>, Vec<_>) = v.iter().copied().unzip();
        ErrorStats::between(&a, &b)
    };
    let (sb, sa) = (stats(&before), stats(&after));
    // What a workpiece set-up leaves: the compensated tool points after the best rigid transform
    // onto their targets (a constant shift and turn of the tool relative to the table is taken
    // up when the workpiece is set up and probed).
    let rigid = {
        let (a, b): (Vec<_>, Vec<_>) = after.iter().copied().unzip();
        volver::core::metrics::ErrorStats::after_rigid(&a, &b)
    };
    println!(
        "\n6. Compensation over a {}-point grid of the work volume (tool point at the reflectors' centroid), checked on the true machine:",
        before.len()
    );
    println!(
        "   true tool-point error EMM {} → {} µm, EMax {} → {} µm in the workpiece frame; every command verified through the model (largest deviation {:.1e} mm){}",
        um(sb.emm_um),
        um(sa.emm_um),
        um(sb.emax_um),
        um(sa.emax_um),
        worst,
        if outside > 0 {
            format!("; {outside} leave the travel")
        } else {
            String::new()
        }
    );
    Ok(Check {
        grid: programmed_grid,
        tool,
        before: sb,
        after: sa,
        rigid,
    })
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
            * 1e3
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
    println!(
        "   raw, U reaches {} µm, mostly from a combination the data cannot identify ({raw_worst}): a constant shift of the tool that the set-up takes up",
        um(u_raw)
    );
    Ok(cov)
}

/// Step 7: The results file and the controller tables (with their U); returns the tables' paths.
fn write_results(
    out_dir: &Path,
    model2: &Model,
    id2: &Identification,
    cov: &Covariance,
) -> Result<Vec<PathBuf>> {
    let mut results = ResultsFile::from_model(model2, &id2.params)?;
    let held = id2
        .gauge
        .as_ref()
        .map(|g| {
            (0..g.held.len())
                .map(|c| volver::uncertainty::combination_text(model2, g, c))
                .collect()
        })
        .unwrap_or_default();
    results.uncertainty = Some(cov.to_record(volver::solvers::gauge::RULE, held));
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

/// Step 7, continued: The HTML report of both fits.
fn write_report(
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
    let tool = reflector_centroid(fits[1].model);
    let input = ReportInput {
        title: "volver demo — XCFZ grinder, synthetic test 4".into(),
        data_label: out_dir.join("test4/measurements.csv").display().to_string(),
        data: &out.measurements,
        fits,
        truth: Some((&out.truth.model, &out.truth.params)),
        noise_um: Some(noise),
        candidates: ranked,
        engines: Vec::new(),
        cross,
        notes: vec![format!(
            "Synthetic verification of the XCFZ grinder (plan test4, seed {DEMO_SEED}) with an effect the paper's model lacks ({DEMO_EFFECT}). The paper's model left EMM {} µm; the diagnosis named {}; with it the fit ends at {} µm against a noise error of {} µm. Compensation with the final errors takes the true tool-point error from EMM {} to {} µm in the workpiece frame, and to {} µm after the best rigid transform (which a workpiece set-up takes up).",
            um(id1.reached.stats.emm_um),
            added,
            um(id2.reached.stats.emm_um),
            um(noise),
            um(check.before.emm_um),
            um(check.after.emm_um),
            um(check.rigid.emm_um)
        )],
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
fn where_you_are(out_dir: &Path, table_paths: &[PathBuf], added: &str) {
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
    println!("   test4/                   the measurements, the truth and the simulation record");
    println!(
        "\nWhere you are: the errors are identified and the model explains the data to the noise. Next:"
    );
    println!(
        "   volver diagnose --data {0}/test4/measurements.csv            (the diagnosis in full)",
        out_dir.display()
    );
    println!(
        "   volver compensate --results {0}/fit.json --gcode PART.nc --out PART-comp.nc",
        out_dir.display()
    );
    println!(
        "   volver report --data {0}/test4/measurements.csv --add {1} --truth {0}/test4/truth.json --out report.html",
        out_dir.display(),
        added
    );
}
