//! `volver report`: identification, diagnosis and the HTML report.

use super::Inputs;
use anyhow::{Context, Result};
use std::path::PathBuf;
use volver::core::measure::MeasurementSet;
use volver::core::problem::Problem;
use volver::core::results::ResultsFile;
use volver::solvers::Options;

/// Options of `volver report`.
#[derive(clap::Args)]
pub struct ReportArgs {
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
    /// The report's identity fields: a TOML file with a `[report]` table (customer, machine,
    /// serial, date, place, instrument, calibration, calibration_date, operator,
    /// air_temperature_c, machine_temperature_c, remarks; every field optional); the flags
    /// below override it field by field.
    #[arg(long, value_name = "FILE")]
    report_info: Option<PathBuf>,
    #[command(flatten)]
    identity: IdentityArgs,
}

/// The identity fields as flags (over `--report-info`'s); a field given nowhere is shown as
/// "—". No date is assumed: a report reads no clock.
#[derive(clap::Args)]
struct IdentityArgs {
    /// The customer.
    #[arg(long)]
    customer: Option<String>,
    /// The machine as the customer names it (default: the machine file's name).
    #[arg(long)]
    machine_name: Option<String>,
    /// The machine's serial number.
    #[arg(long)]
    serial: Option<String>,
    /// The date of the measurement, as it is to be printed.
    #[arg(long)]
    date: Option<String>,
    /// Where the machine stands.
    #[arg(long)]
    place: Option<String>,
    /// The measuring instrument (make, model, serial).
    #[arg(long)]
    instrument: Option<String>,
    /// The instrument's calibration certificate.
    #[arg(long)]
    calibration: Option<String>,
    /// The date of that calibration.
    #[arg(long)]
    calibration_date: Option<String>,
    /// Who measured.
    #[arg(long)]
    operator: Option<String>,
    /// The air temperature during the measurement, °C.
    #[arg(long, value_name = "CELSIUS", allow_hyphen_values = true)]
    air_temperature: Option<f64>,
    /// The machine's temperature during the measurement, °C.
    #[arg(long, value_name = "CELSIUS", allow_hyphen_values = true)]
    machine_temperature: Option<f64>,
    /// Free remarks.
    #[arg(long)]
    remarks: Option<String>,
}

/// The identity: `--report-info`'s `[report]` table, each flag given over it.
fn identity(a: &ReportArgs) -> Result<volver::report::Identity> {
    let file = match &a.report_info {
        Some(p) => volver::report::Identity::load(p)
            .with_context(|| format!("reading the report's identity fields ({})", p.display()))?,
        None => volver::report::Identity::default(),
    };
    let f = &a.identity;
    let flags = volver::report::Identity {
        customer: f.customer.clone(),
        machine: f.machine_name.clone(),
        serial: f.serial.clone(),
        date: f.date.clone(),
        place: f.place.clone(),
        instrument: f.instrument.clone(),
        calibration: f.calibration.clone(),
        calibration_date: f.calibration_date.clone(),
        operator: f.operator.clone(),
        air_temperature_c: f.air_temperature,
        machine_temperature_c: f.machine_temperature,
        remarks: f.remarks.clone(),
    };
    for (flag, v) in [
        ("--air-temperature", f.air_temperature),
        ("--machine-temperature", f.machine_temperature),
    ] {
        if let Some(t) = v
            && !(-100.0..=200.0).contains(&t)
        {
            anyhow::bail!("{flag} {t}: no workshop temperature (expected −100 … 200 °C)");
        }
    }
    Ok(file.overridden_by(flags))
}

/// Runs `volver report`.
pub fn run(a: ReportArgs) -> Result<()> {
    claim_outputs(&a)?;
    let identity = identity(&a)?;
    let (machine, model, data) = a.inputs.load()?;
    volver::compensation::check_max_u(a.max_u_um)?;
    let tool = volver::compensation::tool_point_of(a.tool_offset.as_deref(), None, &model)?;
    let problem = Problem::new(&model, &data)?;
    let id1 = fitted(&model, &data, "the fit")?;
    let candidates = volver::solvers::candidates::rank(
        &problem,
        &id1.params,
        volver::solvers::identifiability::RANK_TOLERANCE,
        machine.default_noise().as_ref(),
    );
    let extended = volver::inputs::with_candidates(&machine, model.clone(), &a.add)?;
    let id2 = if a.add.is_empty() {
        None
    } else {
        let what = format!("the fit with {}", a.add.join(", "));
        Some(fitted(&extended, &data, &what)?)
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
    let cross = cross_validation(&a, &machine, &model, last_model, last_params)?;
    let mut fits = vec![volver::report::Fit {
        label: model.spec().name.clone(),
        model: &model,
        id: &id1,
    }];
    if let Some(id) = &id2 {
        fits.push(volver::report::Fit {
            label: format!("+ {}", a.add.join(" + ")),
            model: &extended,
            id,
        });
    }
    let last_id = id2.as_ref().unwrap_or(&id1);
    let results = volver::uncertainty::results_with_uncertainty(
        last_model,
        &data,
        last_id,
        volver::inputs::noise_rule(None, last_model.machine())?.0,
    )?;
    let input = volver::report::ReportInput {
        title: identity.title(&machine.spec().name),
        identity,
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
    let html = volver::report::html(&input)?;
    write_outputs(&a, html, &results)
}

/// `model` fitted to `data` with the native engine; `Err` naming `what` when the fit fails.
fn fitted(
    model: &volver::core::model::Model,
    data: &MeasurementSet,
    what: &str,
) -> Result<volver::solvers::strategy::Identification> {
    let id = volver::solvers::strategy::fit(Problem::new(model, data)?);
    if id.termination.failed() {
        anyhow::bail!("{what} failed: {}", id.termination);
    }
    Ok(id)
}

/// The cross-validation row of `--reference`: the final fit's errors compensating it.
fn cross_validation(
    a: &ReportArgs,
    machine: &volver::core::machine::Machine,
    model: &volver::core::model::Model,
    last_model: &volver::core::model::Model,
    last_params: &[f64],
) -> Result<Vec<volver::report::CrossRow>> {
    let Some(path) = &a.reference else {
        return Ok(Vec::new());
    };
    {
        let set =
            MeasurementSet::load(machine, path).context("reading the reference measurements")?;
        Problem::new(model, &set)?.check_scale(&path.display().to_string())?;
        let lm = volver::solvers::lm::LevenbergMarquardt::default();
        let reference = Problem::new(last_model, &set)?;
        let cv = volver::solvers::strategy::cross_validate(
            &lm,
            reference.clone(),
            last_params,
            &Options::default(),
            &mut volver::solvers::Silent,
        );
        let model_label = if a.add.is_empty() {
            format!("model \"{}\"", model.spec().name)
        } else {
            format!("model \"{}\" + {}", model.spec().name, a.add.join(" + "))
        };
        Ok(vec![volver::report::CrossRow::new(
            format!("{} ({model_label})", a.inputs.data.display()),
            &reference,
            &cv,
        )])
    }
}

/// The results file `report` writes: `--results`, or the report's path with `.json`.
fn results_path(a: &ReportArgs) -> PathBuf {
    a.results
        .clone()
        .unwrap_or_else(|| a.out.with_extension("json"))
}

/// Checks the report and its results file against the inputs and each other before anything
/// runs.
fn claim_outputs(a: &ReportArgs) -> Result<()> {
    let inputs = a.inputs.paths(&[
        a.reference.as_deref(),
        a.truth.as_deref(),
        a.report_info.as_deref(),
    ]);
    let mut outputs = volver::core::fsio::Outputs::new(inputs);
    outputs.claim(&a.out)?;
    outputs
        .claim(&results_path(a))
        .context("the results file report writes (--results, default beside --out)")?;
    Ok(())
}

/// Writes the report and the final fit's results file.
fn write_outputs(a: &ReportArgs, html: String, results: &ResultsFile) -> Result<()> {
    let results_path = results_path(a);
    volver::core::fsio::write_atomic(&a.out, html)
        .with_context(|| format!("writing {}", a.out.display()))?;
    results
        .save(&results_path)
        .context("writing the results file")?;
    println!(
        "volver report — written to {}; the final fit's errors to {} (for compensate and tables)",
        a.out.display(),
        results_path.display()
    );
    Ok(())
}
