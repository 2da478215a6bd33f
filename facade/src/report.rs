//! `volver report`: one self-contained HTML file (inline SVG, no scripts, no network) with the
//! machine, the model, the summary tables, the plots, the diagnosis and the identifiability.

mod figures;
mod findings;
mod identity;
mod iso_summary;
mod reversal;
mod truth;

use crate::error::{Error, Result};
use crate::plot::{self, escape};
use figures::{cells, function_panels, measured_planes, micro, table, tool_point_uncertainty};
use std::collections::BTreeMap;
use std::fmt::Write;
use volver_core::diagnose;
use volver_core::iso::ErrorId;
use volver_core::measure::MeasurementSet;
use volver_core::model::Model;
use volver_core::problem::{Problem, Residuals, norm};
use volver_core::units::{UM_PER_MM, URAD_PER_RAD};
use volver_solvers::Options;
use volver_solvers::candidates::Score;
use volver_solvers::identifiability::analyse;
use volver_solvers::init::init_tracker;
use volver_solvers::strategy::Identification;
use volver_solvers::uncertainty::{Covariance, K, PointUncertainty};

pub use identity::Identity;
pub use truth::{TruthInModel, truth_in_model};

/// One fitted model revision shown in the report.
pub struct Fit<'a> {
    /// What it is ("paper model", "+ raise-axis:C" …).
    pub label: String,
    /// The model.
    pub model: &'a Model,
    /// The identification.
    pub id: &'a Identification,
}

/// One cross-validation row: errors identified on one set compensate a reference test.
pub struct CrossRow {
    /// What the errors were identified on (and with which model).
    pub label: String,
    /// EMM of the reference before compensation (every error zero, the tracker's rigid fit: the
    /// initial EMM of an identification of the reference), µm.
    pub emm_before_um: f64,
    /// EMM after compensation, µm.
    pub emm_after_um: f64,
    /// U (k = 2) of that EMM as a mean over the reference's points, µm.
    pub emm_after_u95_um: f64,
    /// EMM after / EMM before, %.
    pub residual_percent: f64,
}

impl CrossRow {
    /// The row of `cv` ([`volver_solvers::strategy::cross_validate`] on `reference`).
    pub fn new(label: String, reference: &Problem, cv: &Identification) -> CrossRow {
        CrossRow {
            label,
            emm_before_um: cv.initial.stats.emm_um,
            emm_after_um: cv.reached.stats.emm_um,
            emm_after_u95_um: reference.emm_u95_um(&cv.params),
            residual_percent: cv.residual_percent(),
        }
    }
}

/// What the measurement's parameters of `model` are ([`Model::is_measurement_param`]), in
/// words, in the order of the layout: what cross-validation fits on a reference set.
pub fn measurement_parts(model: &Model) -> Vec<&'static str> {
    let mut out: Vec<&'static str> = Vec::new();
    for j in (0..model.n_params()).filter(|&j| model.is_measurement_param(j)) {
        let name = &model.params()[j].name;
        let word = match name.split('.').next().unwrap_or("") {
            "tracker" => "tracker pose",
            "station" if name.ends_with(".offset") => "range offsets",
            "station" => "station poses",
            "drift" => "tool drift",
            "reflector" => "reflector offsets",
            "range" => "range scale",
            "thermal" => "scale growth",
            "locdrift" => "location drift",
            "trackerdrift" => "tracker drift",
            "stationdrift" => "station drift",
            "field" => "fields over time",
            _ => "other terms of the test",
        };
        if !out.contains(&word) {
            out.push(word);
        }
    }
    out
}

/// Everything the report shows.
pub struct ReportInput<'a> {
    /// Title (see [`Identity::title`]: the machine and the customer).
    pub title: String,
    /// Who the verification was for, on which machine, when, where, with what and by whom:
    /// the header block a customer signs ("—" for a field not given).
    pub identity: Identity,
    /// The measurement file's name.
    pub data_label: String,
    /// The measurements.
    pub data: &'a MeasurementSet,
    /// The fits, first to last; the last is the one plotted.
    pub fits: Vec<Fit<'a>>,
    /// The true errors, when known (synthetic data).
    pub truth: Option<(&'a Model, &'a [f64])>,
    /// The noise error of the measurements (EMM µm), when known.
    pub noise_um: Option<f64>,
    /// Candidate effects ranked for the first fit (diagnosis).
    pub candidates: Vec<Score>,
    /// Per-engine rows (engine, EMM µm, EMax µm, residual %, termination), when compared.
    pub engines: Vec<(String, f64, f64, f64, String)>,
    /// Cross-validation rows.
    pub cross: Vec<CrossRow>,
    /// Free text paragraphs (what the demo did, where the files are).
    pub notes: Vec<String>,
    /// The tool point (mm, in the frame of the last tool-side axis) whose compensated position's
    /// uncertainty the report maps.
    pub tool: [f64; 3],
    /// The U (µm, k = 2) above which `compensate` and `tables` refuse: the report says whether
    /// this tool point passes.
    pub max_u_um: f64,
}

impl<'a> ReportInput<'a> {
    /// A report of `fits` (first to last; the last is plotted) of `data`, with nothing else
    /// known: no truth, no candidates, no engines compared, no cross-validation; the tool point
    /// at the reflectors' centroid of the last fit's machine and the compensation's default
    /// limit of 25 µm. Set the other fields as needed.
    ///
    /// # Panics
    /// When `fits` is empty.
    pub fn new(
        title: impl Into<String>,
        data_label: impl Into<String>,
        data: &'a MeasurementSet,
        fits: Vec<Fit<'a>>,
    ) -> ReportInput<'a> {
        let last = fits.last().expect("a report needs at least one fit");
        let tool = crate::shared::reflector_centroid(last.model);
        ReportInput {
            title: title.into(),
            identity: Identity::default(),
            data_label: data_label.into(),
            data,
            fits,
            truth: None,
            noise_um: None,
            candidates: Vec::new(),
            engines: Vec::new(),
            cross: Vec::new(),
            notes: Vec::new(),
            tool,
            max_u_um: 25.0,
        }
    }
}

/// The HTML text.
pub fn html(input: &ReportInput) -> Result<String> {
    let last = input
        .fits
        .last()
        .ok_or_else(|| Error::Request("no fit to report".into()))?;
    let model = last.model;
    let m = model.machine();
    let problem = Problem::new(model, input.data)?;
    let params = &last.id.params;
    let before_params = init_tracker(&problem, &model.initial_params())?;
    let before = problem.residuals(&before_params);
    let after = problem.residuals(params);
    let options = Options::default();
    let task = volver_solvers::Task::new(problem.clone());
    let ident = analyse(
        &task,
        params,
        volver_solvers::identifiability::RANK_TOLERANCE,
        crate::diagnosis::CORRELATION_LISTED,
    );
    // The fit's uncertainty: the data's (the one noise rule: the machine file's `[tracker]
    // noise`, else σ from the residuals) and the gauge's held combinations' prior.
    let cov = volver_solvers::uncertainty::linear(
        &problem,
        last.id.gauge.as_ref(),
        params,
        options.objective,
        crate::inputs::noise_rule(None, m)?.0,
    );
    let truth = input
        .truth
        .map(|t| truth_in_model(model, input.data, t))
        .transpose()?;
    let mut s = String::new();
    let page = Page {
        input,
        last,
        model,
        m,
        problem,
        params,
        before,
        after,
        before_params,
        ident,
        cov,
        truth,
    };
    head(&page, &mut s)?;
    machine_and_model(&page, &mut s)?;
    stations(&page, &mut s)?;
    summary(&page, &mut s)?;
    iso_summary::section(&page, &mut s)?;
    maps(&page, &mut s)?;
    error_functions(&page, &mut s)?;
    squareness(&page, &mut s)?;
    reversal::section(&page, &mut s)?;
    findings::diagnosis(&page, &mut s)?;
    findings::candidates(&page, &mut s)?;
    findings::identifiability(&page, &mut s)?;
    findings::cross_validation(&page, &mut s)?;
    let _ = writeln!(
        s,
        "<p style=\"color:#777\">Written by volver {}. Units: mm and rad in the files, µm and µrad here.</p></body></html>",
        env!("CARGO_PKG_VERSION")
    );
    Ok(s)
}

/// What every section of [`html`] reads.
struct Page<'a> {
    input: &'a ReportInput<'a>,
    last: &'a Fit<'a>,
    model: &'a Model,
    m: &'a volver_core::machine::Machine,
    problem: Problem<'a>,
    params: &'a [f64],
    before: Vec<[f64; 3]>,
    after: Vec<[f64; 3]>,
    before_params: Vec<f64>,
    ident: Option<volver_solvers::identifiability::Identifiability>,
    cov: Option<Covariance>,
    /// The truth in the last fit's parameters, when known.
    truth: Option<TruthInModel>,
}

/// The report's style sheet: the screen layout, and for print (a browser's "print to PDF")
/// A4 pages with every chart and table kept on one page and scaled to the page's width.
const STYLE: &str = "\
body{font-family:Arial,'Liberation Sans',Helvetica,sans-serif;max-width:1100px;margin:2em auto;color:#222;line-height:1.4}\
h1{font-size:1.6em} h2{border-bottom:1px solid #ccc;margin-top:2em}\
table{border-collapse:collapse;margin:0.6em 0} td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}\
th{background:#eef2f7} td:first-child{text-align:left}\
.note{background:#f6f8fa;padding:0.6em 1em;border-left:4px solid #4a7ab5}\
.warning{background:#fdf3f2;padding:0.6em 1em;border-left:4px solid #c0392b}\
table.identity{width:100%} table.identity th{text-align:left;width:16%} table.identity td{text-align:left;width:34%}\
table.sign{width:100%;margin-top:0.8em} table.sign th{text-align:left;width:50%;background:none;font-weight:normal}\
table.sign td{height:3.2em}\
table.iso td:nth-child(2){text-align:left}\
p{orphans:3;widows:3} p:has(+table),p:has(+svg){break-after:avoid;page-break-after:avoid}\
svg{display:block;max-width:100%;height:auto;margin:0.5em 0}\
@page{size:A4;margin:14mm 12mm 16mm 12mm}\
@media print{\
body{max-width:none;margin:0;font-size:9.5pt;line-height:1.3}\
h1{font-size:15pt;margin-top:0} h2{font-size:12.5pt;margin-top:1.2em}\
h2,h3{break-after:avoid;page-break-after:avoid}\
svg,table,.note,.warning,section.identity{break-inside:avoid;page-break-inside:avoid}\
svg{max-width:100%;height:auto}\
td,th{padding:2px 5px}\
}";

/// The document head, the title, the identity block a customer signs, and the notes.
fn head(p: &Page, s: &mut String) -> Result<()> {
    let Page { input, m, .. } = p;
    let _ = write!(
        s,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{}</title>\n<style>{STYLE}</style></head><body>\n<h1>{}</h1>\n",
        escape(&input.title),
        escape(&input.title)
    );
    s.push_str(&input.identity.header_html(&m.spec().name));
    for n in &input.notes {
        let _ = writeln!(s, "<p class=\"note\">{}</p>", escape(n));
    }
    Ok(())
}

/// The machine and the model.
fn machine_and_model(p: &Page, s: &mut String) -> Result<()> {
    let Page {
        input, model, m, ..
    } = p;
    // Machine and model.
    let _ = writeln!(
        s,
        "<h2>Machine and model</h2><p>Machine <b>{}</b>, chain <b>{}</b>; measurements <b>{}</b> ({} points). Final model <b>{}</b>: {} parameters, {} constraints.</p>",
        escape(&m.spec().name),
        m.chain(),
        escape(&input.data_label),
        input.data.points.len(),
        escape(&model.spec().name),
        model.n_params(),
        model.constraints().rows.len()
    );
    let axis_rows: Vec<Vec<String>> = m
        .axes()
        .iter()
        .map(|a| {
            vec![
                a.axis.to_string(),
                format!("{:?}", a.side).to_lowercase(),
                format!(
                    "{} … {} {}",
                    a.to_file_units(a.min),
                    a.to_file_units(a.max),
                    a.file_unit()
                ),
                model
                    .terms()
                    .iter()
                    .filter(|t| m.axes()[t.axis].axis == a.axis)
                    .map(|t| format!("{} ({} {})", t.id, t.basis.kind(), t.basis.degree()))
                    .collect::<Vec<_>>()
                    .join(", "),
            ]
        })
        .collect();
    s.push_str(&table(
        &[
            "axis",
            "side",
            "travel",
            "modelled errors (basis, degree/order)",
        ],
        &axis_rows,
    ));
    Ok(())
}

/// The stations of a machine with `[[station]]` tables: each one's identified position and
/// range offset with their U (k = 2), its measurements and what it leaves, and the set-up drawn
/// in the reference station's mount frame (plan and elevation). Nothing for one tracker.
fn stations(p: &Page, s: &mut String) -> Result<()> {
    if !p.m.has_stations() {
        return Ok(());
    }
    let _ = writeln!(
        s,
        "<h2>Stations</h2><p>Each station's identified position (mm, in the frame it is mounted \
         in) and range offset (µm, the dead path), with U (k = 2); its measurements and the EMM \
         they leave. With ranges alone a station's position is determined only up to the \
         combinations the gauge holds (raising every station is a constant EZC, turning them \
         about C a constant ECC: see Identifiability); distances between stations are not.</p>"
    );
    s.push_str(&table(
        &[
            "station",
            "observes",
            "mount",
            "x mm",
            "y mm",
            "z mm",
            "range offset µm",
            "measurements",
            "EMM µm",
        ],
        &station_rows(p),
    ));
    setup_views(p, s);
    Ok(())
}

/// One row per station: its identity, identified pose and range offset with U, its
/// measurements and the EMM they leave.
fn station_rows(p: &Page) -> Vec<Vec<String>> {
    let Page {
        model,
        m,
        problem,
        params,
        after,
        cov,
        ..
    } = p;
    let data = problem.data();
    let u = cov.as_ref().map(|c| c.parameters());
    let with_u = |j: usize, scale: f64, decimals: usize| match &u {
        Some(u) => format!(
            "{:.decimals$} ± {:.decimals$}",
            params[j] * scale,
            K * u[j] * scale
        ),
        None => format!("{:.decimals$}", params[j] * scale),
    };
    let mut rows = Vec::new();
    for (k, (st, b)) in m.stations().iter().zip(model.stations()).enumerate() {
        let mine: Vec<usize> = (0..data.points.len())
            .filter(|&i| data.points[i].station_index == k)
            .collect();
        let ranges = mine.iter().filter(|&&i| problem.scalar(i)).count();
        let emm = if mine.is_empty() {
            "–".to_string()
        } else {
            format!(
                "{:.3}",
                mine.iter().map(|&i| norm(after[i])).sum::<f64>() / mine.len() as f64 * UM_PER_MM
            )
        };
        rows.push(vec![
            st.id.clone(),
            format!("{:?}", st.observes).to_lowercase(),
            format!("{:?}", st.setup.mount).to_lowercase(),
            with_u(b.pose, 1.0, 4),
            with_u(b.pose + 1, 1.0, 4),
            with_u(b.pose + 2, 1.0, 4),
            b.offset
                .map_or("not modelled".to_string(), |j| with_u(j, UM_PER_MM, 2)),
            format!("{} ({ranges} ranges)", mine.len()),
            emm,
        ]);
    }
    rows
}

/// The set-up in the reference station's mount frame: each measured reflector (the identified
/// machine, the station's pose removed) and the stations mounted as it is, in plan and
/// elevation.
fn setup_views(p: &Page, s: &mut String) {
    let Page {
        model,
        m,
        problem,
        params,
        ..
    } = p;
    let data = problem.data();
    let reference = &m.stations()[0].setup;
    let r0 = reference.base_rotation;
    let step = data.points.len().div_ceil(3000).max(1);
    let points: Vec<[f64; 3]> = data
        .points
        .iter()
        .step_by(step)
        .map(|pt| {
            let mut e = model.errors_at_point(&pt.commands, pt.reflector, 0.0, params);
            e.tracker = [0.0; 6];
            let x = volver_core::kinematics::predict(
                m,
                &pt.commands,
                &m.reflectors()[pt.reflector].offset,
                &e,
            );
            std::array::from_fn(|i| (0..3).map(|j| r0[i][j] * x[j]).sum())
        })
        .collect();
    let placed: Vec<(String, [f64; 3])> = m
        .stations()
        .iter()
        .zip(model.stations())
        .filter(|(st, _)| st.setup.mount == reference.mount)
        .map(|(st, b)| {
            (
                st.id.clone(),
                [params[b.pose], params[b.pose + 1], params[b.pose + 2]],
            )
        })
        .collect();
    let view = |title: &str, a: usize, c: usize| plot::LayoutView {
        title: title.to_string(),
        xlabel: format!("{} (mm)", ["x", "y", "z"][a]),
        ylabel: format!("{} (mm)", ["x", "y", "z"][c]),
        points: points.iter().map(|p| [p[a], p[c]]).collect(),
        stations: placed
            .iter()
            .map(|(id, q)| (id.clone(), [q[a], q[c]]))
            .collect(),
    };
    s.push_str(&plot::layout_views(
        &format!(
            "The set-up, mounted on the {} (the reflectors measured, the stations)",
            format!("{:?}", reference.mount).to_lowercase()
        ),
        &[view("plan (x–y)", 0, 1), view("elevation (x–z)", 0, 2)],
    ));
}

/// The summary: each fit's EMM before and after, with U, the noise, the engines.
fn summary(p: &Page, s: &mut String) -> Result<()> {
    let Page { input, .. } = p;
    // Summary.
    let _ = writeln!(s, "<h2>Summary</h2>");
    let rows: Vec<Vec<String>> = input
        .fits
        .iter()
        .map(|f| {
            // U (k = 2) of each EMM as a mean over these points, from the modules' spread;
            // before: zero errors with the tracker fitted, as the identification starts.
            let problem = Problem::new(f.model, input.data)?;
            let start = f.model.initial_params();
            let tracker = volver_solvers::init::init_tracker(&problem, &start).unwrap_or(start);
            let (u0, u1) = (
                problem.emm_u95_um(&tracker),
                problem.emm_u95_um(&f.id.params),
            );
            Ok(vec![
                f.label.clone(),
                f.model.n_params().to_string(),
                format!("{:.3} ± {u0:.3}", f.id.initial.stats.emm_um),
                format!("{:.3} ± {u1:.3}", f.id.reached.stats.emm_um),
                format!("{:.3}", f.id.reached.stats.emax_um),
                format!("{:.2} %", f.id.residual_percent()),
                input.noise_um.map_or("–".into(), |n| {
                    format!("{:.3} ± {:.3}", f.id.reached.stats.emm_um / n, u1 / n)
                }),
                f.id.termination.to_string(),
            ])
        })
        .collect::<Result<_>>()?;
    s.push_str(&table(
        &[
            "model",
            "parameters",
            "EMM before µm",
            "EMM after µm",
            "EMax after µm",
            "residual",
            "EMM / noise",
            "termination",
        ],
        &rows,
    ));
    let _ = writeln!(
        s,
        "<p>Each EMM carries its U (k = 2) as a mean over these points: twice the modules' standard deviation over √N, how far it would scatter were the noise drawn again.</p>"
    );
    if let Some(n) = input.noise_um {
        let _ = writeln!(
            s,
            "<p>Noise error of the measurements (known for synthetic data): EMM {n:.3} µm. A model that explains everything but the noise ends at EMM / noise ≈ 1.</p>"
        );
    }
    if !input.engines.is_empty() {
        let rows: Vec<Vec<String>> = input
            .engines
            .iter()
            .map(|e| {
                vec![
                    e.0.clone(),
                    format!("{:.4}", e.1),
                    format!("{:.4}", e.2),
                    format!("{:.3} %", e.3),
                    e.4.clone(),
                ]
            })
            .collect();
        let _ = writeln!(s, "<h3>Per engine</h3>");
        s.push_str(&table(
            &["engine", "EMM µm", "EMax µm", "residual", "termination"],
            &rows,
        ));
    }
    Ok(())
}

/// Colour maps and vector diagrams of the error over the measured volume, before and after, and the tool point's U.
fn maps(p: &Page, s: &mut String) -> Result<()> {
    let Page {
        input,
        last,
        model,
        m,
        problem,
        params,
        before,
        after,
        before_params,
        cov,
        ..
    } = p;
    // Maps and vectors, in each plane of the linear axes the data move.
    let planes = measured_planes(problem);
    if !planes.is_empty() {
        let names: Vec<String> = planes
            .iter()
            .map(|&(a, b)| format!("{}–{}", m.axes()[a].axis, m.axes()[b].axis))
            .collect();
        let _ = writeln!(
            s,
            "<h2>Error over the measured volume</h2><p>Mean error module per position in each plane of the linear axes ({}; over the other axes and the reflectors): before, the measured points against the nominal machine (tracker pose fitted); after, against the identified model — the error left after compensation.{}</p>",
            names.join(", "),
            escape(&unmapped(m, &planes))
        );
    }
    let mb = diagnose::to_machine_frame(problem, before_params, before);
    let ma = diagnose::to_machine_frame(problem, params, after);
    for (ka, kb) in planes {
        let (la, lb) = (m.axes()[ka].axis, m.axes()[kb].axis);
        let dirs = (la.direction(), lb.direction());
        let (map_b, vec_b) = cells(problem, (ka, kb), &mb, dirs);
        let (map_a, vec_a) = cells(problem, (ka, kb), &ma, dirs);
        s.push_str(&plot::colour_maps(
            &format!("Error module in the {la}–{lb} plane (µm)"),
            &format!("{la} (mm)"),
            &format!("{lb} (mm)"),
            &[
                ("before compensation", map_b),
                ("after compensation", map_a),
            ],
        ));
        let peak = vec_b
            .iter()
            .map(|c| c.a.hypot(c.b))
            .fold(0.0_f64, f64::max)
            .max(1e-9);
        let span = (m.axes()[ka].max - m.axes()[ka].min).max(m.axes()[kb].max - m.axes()[kb].min);
        let magnification = (0.08 * span / (peak * 1e-3)).max(1.0).round();
        s.push_str(&plot::vector_diagrams(
            &format!("Error vectors in the {la}{lb} plane (machine frame)"),
            &format!("{la} (mm)"),
            &format!("{lb} (mm)"),
            magnification,
            &[
                ("before compensation", vec_b),
                ("after compensation", vec_a),
            ],
        ));
    }
    if let Some(cov) = &cov {
        tool_point_uncertainty(s, input, model, params, last.id.gauge.as_ref(), cov)?;
    }
    Ok(())
}

/// What the maps leave out, in words: each rotary axis (its positions are averaged over in
/// every map; its errors are drawn as functions of its angle) and each linear axis the data do
/// not move (no plane with it).
fn unmapped(m: &volver_core::machine::Machine, planes: &[(usize, usize)]) -> String {
    let mut out = String::new();
    for a in m.axes() {
        if a.axis.is_rotary() {
            let _ = write!(
                out,
                " {} is rotary: every map averages over its positions; its errors are drawn \
                 against its angle under Identified error functions.",
                a.axis
            );
        }
    }
    for (k, a) in m.axes().iter().enumerate() {
        if !a.axis.is_rotary() && !planes.iter().any(|&(p, q)| p == k || q == k) {
            let _ = write!(
                out,
                " {} is not mapped: the data do not move it with another linear axis.",
                a.axis
            );
        }
    }
    out
}

/// The identified error functions with their U bands, the constants and the implied squareness.
fn error_functions(p: &Page, s: &mut String) -> Result<()> {
    let Page {
        last,
        model,
        params,
        cov,
        truth,
        problem,
        ..
    } = p;
    // Whether the bands mean anything: the fit against the noise.
    let check = crate::shared::check_fit(
        problem,
        last.id,
        volver_solvers::uncertainty::NoiseModel::Residual,
    );
    let noise = cov
        .as_ref()
        .map_or_else(String::new, |c| c.noise.to_string());
    let _ = writeln!(
        s,
        "<h2>Identified error functions</h2><p>Each component error against its axis position; the band is its expanded uncertainty U (k = 2): the data's (linearised, noise: {noise}) and a prior of 100 µm or 100 µrad RMS on each combination the data cannot identify (held by the gauge at the reference){}. A panel titled \"not determined\" shows a function the data do not fix: its value is the gauge's choice, not a measurement.</p>",
        match truth {
            Some(t) => format!(
                "; the dashed line is the truth in this model's parameters (its squareness rule \
                 \"{}\", reference and gauge: the model fitted to the truth's noise-free points at \
                 these commands; what the model cannot express of the truth: EMM {:.3} µm)",
                model.spec().squareness,
                t.misfit_um
            ),
            None => String::new(),
        }
    );
    let _ = writeln!(
        s,
        "<p{}>{}{}</p>",
        if check.above_noise {
            " class=\"warning\""
        } else {
            ""
        },
        if check.above_noise {
            "<strong>These bands do not hold:</strong> "
        } else {
            ""
        },
        plot::escape(&check.statement())
    );
    // Nine panels (three rows) per chart, so that a chart fits a printed page.
    let panels = function_panels(
        model,
        params,
        cov.as_ref(),
        last.id.gauge.as_ref(),
        truth.as_ref().map(|t| (*model, t.params.as_slice())),
    );
    let parts = panels.len().div_ceil(9);
    for (i, chunk) in panels.chunks(9).enumerate() {
        let title = if parts > 1 {
            format!("Component errors ({} of {parts})", i + 1)
        } else {
            "Component errors".to_string()
        };
        s.push_str(&plot::error_functions(&title, chunk));
    }
    let consts = location_rows(model, params, cov.as_ref());
    if !consts.is_empty() {
        s.push_str(&table(
            &[
                "location / squareness error (ISO 230-1 sign)",
                "value ± U (k = 2)",
            ],
            &consts,
        ));
    }
    Ok(())
}

/// One row per location (constant) error: its value with U (k = 2), in µm or µrad.
fn location_rows(model: &Model, params: &[f64], cov: Option<&Covariance>) -> Vec<Vec<String>> {
    model
        .terms()
        .iter()
        .filter(|t| matches!(t.id, ErrorId::Location { .. }))
        .map(|t| {
            // ISO 230-1's sign (a squareness C0X, A0Y, B0Z is the parameter's negative).
            let v = params[t.params.start] * t.id.iso_sign() + 0.0;
            let mut g = vec![0.0; params.len()];
            g[t.params.start] = 1.0;
            let u = cov.map_or(0.0, |c| K * c.u(&g));
            let (scale, unit) = micro(t.id);
            vec![
                t.id.to_string(),
                format!("{:.3} ± {:.3} {unit}", v * scale, u * scale),
            ]
        })
        .collect()
}

/// The squareness the model implies, with U (k = 2).
fn squareness(p: &Page, s: &mut String) -> Result<()> {
    let Page {
        model,
        params,
        cov,
        truth,
        ..
    } = p;
    let true_sq = truth.as_ref().map(|t| model.squareness(&t.params));
    // Each implied squareness is linear in the parameters: its standard uncertainty from the
    // gradient (one unit step per parameter) and the covariance.
    let implied = model.squareness(params);
    let sq: Vec<Vec<String>> = implied
        .iter()
        .map(|(id, v)| {
            let u = cov.as_ref().map_or(0.0, |c| {
                let mut q = params.to_vec();
                let g: Vec<f64> = (0..q.len())
                    .map(|j| {
                        q[j] += 1.0;
                        let w = model
                            .squareness(&q)
                            .iter()
                            .find(|(i, _)| i == id)
                            .map_or(*v, |(_, w)| *w);
                        q[j] -= 1.0;
                        w - v
                    })
                    .collect();
                K * c.u(&g)
            });
            // ISO 230-1's sign: C0X, A0Y and B0Z are the negatives of the model's reading.
            let iso = id.iso_sign() * URAD_PER_RAD;
            let mut row = vec![
                id.to_string(),
                format!("{:.3} ± {:.3} µrad", v * iso + 0.0, u * URAD_PER_RAD),
            ];
            if let Some(t) = &true_sq {
                row.push(
                    t.iter()
                        .find(|(i, _)| i == id)
                        .map_or("–".into(), |(_, w)| format!("{:.3} µrad", w * iso)),
                );
            }
            row
        })
        .collect();
    if !sq.is_empty() {
        let _ = writeln!(
            s,
            "<p>Squareness implied by the model (its parameter plus its straightness partner's slope, rule: {}), in ISO 230-1's sign: the angle by which the axis' line of motion is turned right-handed about the named axis (C0X, A0Y and B0Z are the negatives of volver's parameters of those names):</p>",
            model.spec().squareness
        );
        let head: &[&str] = if true_sq.is_some() {
            &["squareness", "value ± U (k = 2)", "truth (in this model)"]
        } else {
            &["squareness", "value ± U (k = 2)"]
        };
        s.push_str(&table(head, &sq));
    }
    Ok(())
}
