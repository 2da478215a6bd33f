//! The whole of `volver diagnose` as one library call: fit the model, then say where it fails
//! (residuals by axis position, reflector, time and tracker distance; periodograms over every
//! axis in the machine frame; the largest residuals), what the data cannot separate, the noise
//! from repeated points, and which candidate effects most likely are missing, ranked by ΔBIC.
//! [`Diagnosis`] is what `volver diagnose --json` prints.
//!
//! ```
//! let model = volver::core::model::Model::default_xcfz();
//! let data = volver::inputs::demo_test4(&model).unwrap().measurements;
//! let d = volver::diagnosis::diagnose(&model, &data).unwrap();
//! assert!(d.emm_um > 0.0 && d.noise_estimate_um.is_some());
//! assert_eq!(d.periodograms.len(), model.machine().axes().len());
//! assert!(!d.candidates.is_empty());
//! ```

use anyhow::{Result, bail};
use serde::Serialize;
use volver_core::diagnose;
use volver_core::measure::MeasurementSet;
use volver_core::model::Model;
use volver_core::problem::{Problem, Residuals};
use volver_solvers::candidates::{Score, rank, verdict};
use volver_solvers::identifiability::{Identifiability, analyse};

/// Parameter pairs correlated above this (absolute value) are listed by the identifiability
/// analysis of the diagnosis and of the report.
pub const CORRELATION_LISTED: f64 = 0.95;

/// How many harmonic orders each axis' periodogram shows.
pub const PERIODOGRAM_ORDERS: usize = 6;

/// How many of the largest residuals are named.
pub const OUTLIERS: usize = 5;

/// Where a fitted model fails and what it most likely misses (see the module documentation).
#[derive(Clone, Debug, Serialize)]
#[non_exhaustive]
pub struct Diagnosis {
    /// Measured points.
    #[serde(skip)]
    pub points: usize,
    /// The fitted model's name.
    #[serde(skip)]
    pub model: String,
    /// EMM of the fit (µm).
    pub emm_um: f64,
    /// EMax of the fit (µm).
    pub emax_um: f64,
    /// How the fit ended.
    pub termination: String,
    /// The noise error estimated from repeated points (µm); `None` without repeats.
    pub noise_estimate_um: Option<f64>,
    /// The repeated points behind it.
    pub repeat_pairs: Option<usize>,
    /// The residuals' EMM per bin of each axis, reflector, time and tracker distance.
    pub breakdowns: Vec<Breakdown>,
    /// Per axis, the residuals' amplitude at orders 1 … [`PERIODOGRAM_ORDERS`] over its travel.
    pub periodograms: Vec<Periodogram>,
    /// The largest residuals and where they are.
    pub outliers: Vec<Outlier>,
    /// What the data cannot separate; `None` when the analysis failed.
    pub identifiability: Option<IdentifiabilityReport>,
    /// The verdict in words.
    pub verdict: String,
    /// The candidate effects, most likely first.
    pub candidates: Vec<Candidate>,
}

/// The residuals' EMM per bin of one quantity.
#[derive(Clone, Debug, Serialize)]
pub struct Breakdown {
    /// What the bins are of (`X`, `reflector`, `time`, …).
    pub by: String,
    /// Its unit.
    pub unit: String,
    /// Largest bin EMM over the smallest.
    pub spread: f64,
    /// The bins.
    pub bins: Vec<Bin>,
}

/// One bin of a [`Breakdown`].
#[derive(Clone, Debug, Serialize)]
pub struct Bin {
    /// Its label.
    pub label: String,
    /// Points in it.
    pub count: usize,
    /// EMM of its residuals (µm).
    pub emm_um: f64,
    /// EMax of its residuals (µm).
    pub emax_um: f64,
    /// Mean residual per component (µm).
    pub mean_um: [f64; 3],
}

/// One axis' periodogram.
#[derive(Clone, Debug, Serialize)]
pub struct Periodogram {
    /// The axis.
    pub axis: String,
    /// Its lines.
    pub lines: Vec<Line>,
}

/// One order of a [`Periodogram`].
#[derive(Clone, Debug, Serialize)]
pub struct Line {
    /// The order (cycles over the travel, or per turn).
    pub order: f64,
    /// Amplitude per component (µm).
    pub amplitude_um: [f64; 3],
}

impl Line {
    /// The three components' amplitude together (µm).
    pub fn total_um(&self) -> f64 {
        diagnose::Line {
            frequency: self.order,
            amplitude_um: self.amplitude_um,
        }
        .total_um()
    }
}

/// A large residual.
#[derive(Clone, Debug, Serialize)]
pub struct Outlier {
    /// Its line in the measurement file.
    pub line: usize,
    /// Its module (µm).
    pub error_um: f64,
    /// The line, the commands (file units) and the reflector, in words.
    #[serde(rename = "where")]
    pub place: String,
}

/// What the data identify.
#[derive(Clone, Debug, Serialize)]
pub struct IdentifiabilityReport {
    /// Free directions (parameters less independent constraints).
    pub free: usize,
    /// Directions identified.
    pub rank: usize,
    /// Condition number of the identified part.
    pub condition: f64,
    /// Each combination the data cannot identify, by the parameters it moves.
    pub weak: Vec<Vec<crate::identification::Share>>,
}

/// A candidate effect.
#[derive(Clone, Debug, Serialize)]
pub struct Candidate {
    /// Its id (for `identify --add`).
    pub id: String,
    /// What it adds, in words.
    pub description: String,
    /// Whether these data see it at all.
    pub seen: bool,
    /// ΔBIC of the model with it (below −10: strong evidence); `None` when not seen.
    pub delta_bic: Option<f64>,
    /// The EMM with it (µm).
    pub emm_um: Option<f64>,
    /// Its identified size.
    pub size: Option<f64>,
    /// The size's unit.
    pub size_unit: &'static str,
    /// Parameters it adds.
    pub added: usize,
    /// Candidates these data cannot tell from it.
    pub equivalent: Vec<String>,
}

impl Candidate {
    fn of(s: &Score) -> Candidate {
        Candidate {
            id: s.id.clone(),
            description: s.description.clone(),
            seen: s.seen(),
            delta_bic: s.seen().then_some(s.delta_bic),
            emm_um: s.seen().then_some(s.emm_um),
            size: s.seen().then_some(s.size),
            size_unit: s.size_unit,
            added: s.added,
            equivalent: s.equivalent.clone(),
        }
    }
}

/// Fits `model` to `data` with the native engine (default strategy) and diagnoses the fit;
/// `Err` when the fit fails.
pub fn diagnose(model: &Model, data: &MeasurementSet) -> Result<Diagnosis> {
    let problem = Problem::new(model, data)?;
    let id = volver_solvers::strategy::fit(problem.clone());
    if id.termination.failed() {
        bail!("the fit failed: {}", id.termination);
    }
    let r = problem.residuals(&id.params);
    let repeat = diagnose::repeat_noise(&problem);
    let ident = analyse(
        &volver_solvers::Task::new(problem.clone()),
        &id.params,
        volver_solvers::identifiability::RANK_TOLERANCE,
        CORRELATION_LISTED,
    );
    let ranked = rank(
        &problem,
        &id.params,
        volver_solvers::identifiability::RANK_TOLERANCE,
    );
    Ok(Diagnosis {
        points: data.points.len(),
        model: model.spec().name.clone(),
        emm_um: id.reached.stats.emm_um,
        emax_um: id.reached.stats.emax_um,
        termination: id.termination.to_string(),
        noise_estimate_um: repeat.map(|(s, _)| s.emm_um),
        repeat_pairs: repeat.map(|(_, n)| n),
        breakdowns: diagnose::breakdowns(&problem, &r)
            .iter()
            .map(breakdown)
            .collect(),
        periodograms: periodograms(&problem, &id.params, &r),
        outliers: diagnose::largest(&r, OUTLIERS)
            .into_iter()
            .map(|(i, e)| Outlier {
                line: data.points[i].line,
                error_um: e,
                place: describe(model, data, i),
            })
            .collect(),
        identifiability: ident.as_ref().map(|a| identifiability(model, a)),
        verdict: verdict(&ranked, id.reached.stats.emm_um),
        candidates: ranked.iter().map(Candidate::of).collect(),
    })
}

fn breakdown(b: &diagnose::Breakdown) -> Breakdown {
    Breakdown {
        by: b.by.clone(),
        unit: b.unit.clone(),
        spread: b.spread(),
        bins: b
            .bins
            .iter()
            .map(|x| Bin {
                label: x.label.clone(),
                count: x.count,
                emm_um: x.stats.emm_um,
                emax_um: x.stats.emax_um,
                mean_um: x.mean_um,
            })
            .collect(),
    }
}

/// Every axis' periodogram of the residuals in the machine frame.
fn periodograms(problem: &Problem, params: &[f64], r: &[[f64; 3]]) -> Vec<Periodogram> {
    let rm = diagnose::to_machine_frame(problem, params, r);
    let m = problem.model().machine();
    m.axes()
        .iter()
        .enumerate()
        .map(|(k, ax)| Periodogram {
            axis: ax.axis.to_string(),
            lines: diagnose::axis_periodogram(problem, &rm, k, PERIODOGRAM_ORDERS)
                .iter()
                .map(|l| Line {
                    order: l.frequency,
                    amplitude_um: l.amplitude_um,
                })
                .collect(),
        })
        .collect()
}

/// Point `i` in words: its line, commands (file units, to 1e-6) and reflector.
fn describe(model: &Model, data: &MeasurementSet, i: usize) -> String {
    let m = model.machine();
    let p = &data.points[i];
    let pos: Vec<String> = m
        .axes()
        .iter()
        .enumerate()
        .map(|(k, ax)| {
            let v = (ax.to_file_units(p.commands.0[k]) * 1e6).round() / 1e6;
            format!("{}={v}", ax.axis)
        })
        .collect();
    format!(
        "line {} ({} {})",
        p.line,
        pos.join(" "),
        m.reflectors()[p.reflector].id
    )
}

fn identifiability(model: &Model, a: &Identifiability) -> IdentifiabilityReport {
    IdentifiabilityReport {
        free: a.free,
        rank: a.rank,
        condition: a.condition,
        weak: a
            .weak
            .iter()
            .map(|w| {
                w.parameters
                    .iter()
                    .map(|&(j, share)| crate::identification::Share {
                        name: model.params()[j].name.clone(),
                        share,
                    })
                    .collect()
            })
            .collect(),
    }
}
