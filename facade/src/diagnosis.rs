//! The whole of `volver diagnose` as one library call: fit the model, then say where it fails
//! (residuals by axis position, reflector, time and tracker distance; split by each axis'
//! direction of approach, where a reversal the model lacks shows ([`Direction`]); periodograms
//! over every axis in the machine frame; the largest residuals), what the data cannot separate,
//! whether the fit is at the noise, and which candidate effects most likely are missing, ranked
//! by ΔBIC.
//! [`Diagnosis`] is what `volver diagnose --json` prints; [`iterate`] runs the loop to the end.
//!
//! **The noise verdict.** With the noise specification (the machine file's `[tracker] noise`,
//! or [`diagnose_with`]'s argument; with several stations, each station's own `noise` where it
//! states one) the noise error it implies at these very points is computed, each point by its
//! station's noise (a range by the range part alone), and what a complete model's fit leaves
//! (the noise less what the fit's identified directions absorb); the fit is at the noise, above
//! it or far below it, overall and in every bin of every breakdown — without needing repeated
//! points. With several stations, the σ each station's residuals show is set beside the σ its
//! noise states ([`StationVerdict`]): a station noisier or quieter than stated stands out. When
//! the data have repeats, the noise they give is compared with the specification's at those
//! points. The candidates are then scored on residuals whitened by each point's noise.
//!
//! ```
//! let model = volver::core::model::Model::default_xcfz();
//! let data = volver::inputs::demo_test4(&model).unwrap().measurements;
//! let d = volver::diagnosis::diagnose(&model, &data).unwrap();
//! assert!(d.emm_um > 0.0);
//! assert_eq!(d.periodograms.len(), model.machine().axes().len());
//! assert!(!d.candidates.is_empty());
//! // The embedded machine states the paper's tracker; these data hide no effect: the fit is
//! // at its noise.
//! let n = d.noise.as_ref().unwrap();
//! assert!(n.at_noise && (n.ratio - 1.0).abs() < 0.05);
//! // Test 4 in its own order reaches C = 0° after turning back and C = 360° moving forward:
//! // no pose is read twice with every axis arriving from the same side, so no repeats; the
//! // turn's two ends compare C's two directions instead, and show no reversal.
//! assert!(d.noise_estimate_um.is_none() && n.repeats.is_none());
//! let c = d.directions.iter().find(|x| x.axis == "C").unwrap();
//! assert!(c.positions_both == 1 && !c.significant);
//! ```

use crate::error::{Error, Result};
pub use crate::shared::{ABOVE_NOISE_Z, CORRELATION_LISTED, Standing, standing};
use serde::Serialize;
use volver_core::diagnose;
use volver_core::measure::MeasurementSet;
use volver_core::model::Model;
use volver_core::noise::TrackerNoise;
use volver_core::problem::{Problem, Residuals};
use volver_solvers::candidates::{Score, rank, sharing, um, verdict};
use volver_solvers::identifiability::{Identifiability, analyse};

mod direction;
pub use direction::{DIRECTION_Z, Direction, Side};

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
    /// The fit against the noise specification; `None` when none is given (no `[tracker]
    /// noise` in the machine file, no `--noise`, and not every station states its own).
    pub noise: Option<NoiseVerdict>,
    /// The residuals' EMM per bin of each axis, reflector, time and tracker distance.
    pub breakdowns: Vec<Breakdown>,
    /// The residuals split by each axis' direction of approach, for every axis whose points
    /// arrived from both sides: a reversal the model lacks ([`Direction`]).
    pub directions: Vec<Direction>,
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
    /// The fit diagnosed.
    #[serde(skip)]
    pub fit: volver_solvers::strategy::Identification,
}

impl Diagnosis {
    /// The candidate the verdict recommends, when there is one: the first seen, plausible, with
    /// strong evidence, that lowers the EMM of the fit
    /// ([`volver_solvers::candidates::recommended`]).
    pub fn finding(&self) -> Option<&Candidate> {
        let floor = self.emm_um * (1.0 - volver_solvers::candidates::EMM_GAIN);
        self.candidates.iter().find(|c| {
            c.seen
                && c.flag.is_none()
                && c.failed.is_none()
                && c.delta_bic.is_some_and(|b| b < -10.0)
                && c.emm_um.is_some_and(|e| e < floor)
        })
    }

    /// `true` when the loop has nothing left to add: the fit is at the noise (when its
    /// specification is known) or no candidate is a finding.
    pub fn done(&self) -> bool {
        self.noise.as_ref().is_some_and(|n| n.at_noise) || self.finding().is_none()
    }

    /// The fit as a history record ([`crate::history`]) of the measurements `data` (as
    /// given) with the candidates `added`.
    pub fn history_record(
        &self,
        data: &str,
        added: &[String],
        parameters: usize,
    ) -> crate::history::Record {
        crate::history::Record {
            data: data.to_string(),
            model: self.model.clone(),
            added: added.to_vec(),
            parameters,
            free: self.identifiability.as_ref().map_or(0, |a| a.free),
            emm_initial_um: self.fit.initial.stats.emm_um,
            emm_final_um: self.emm_um,
            emax_final_um: self.emax_um,
            phi_mm: self.fit.reached.phi_mm,
            noise_error_um: self.noise.as_ref().map(|n| n.noise_error_um),
            termination: self.termination.clone(),
        }
    }
}

/// One round of [`iterate`]: the model's additions so far and its diagnosis.
#[derive(Clone, Debug)]
pub struct Round {
    /// Candidates added before this round's fit, in order.
    pub added: Vec<String>,
    /// The model's parameters.
    pub parameters: usize,
    /// The diagnosis of this round's fit.
    pub diagnosis: Diagnosis,
    /// The candidate the loop adds next; `None` when it stops after this round.
    pub next: Option<String>,
    /// `true` when the loop stops only because it added `max_added` candidates.
    pub limited: bool,
}

/// The diagnosis loop run to the end: diagnose `model` on `data`; while something is missing
/// ([`Diagnosis::done`] is false), add the finding, refit and diagnose again, at most
/// `max_added` times. `each` sees every round as it ends. Returns the rounds (the last is the
/// final model's) and the final model.
pub fn iterate(
    model: &Model,
    data: &MeasurementSet,
    noise: Option<&TrackerNoise>,
    max_added: usize,
    mut each: impl FnMut(&Round),
) -> Result<(Vec<Round>, Model)> {
    let mut model = model.clone();
    let mut added: Vec<String> = Vec::new();
    let mut rounds: Vec<Round> = Vec::new();
    loop {
        let diagnosis = diagnose_with(&model, data, noise)?;
        let wanted = (!diagnosis.done())
            .then(|| diagnosis.finding().map(|c| c.id.clone()))
            .flatten();
        let limited = wanted.is_some() && added.len() >= max_added;
        let next = wanted.filter(|_| !limited);
        let round = Round {
            added: added.clone(),
            parameters: model.n_params(),
            diagnosis,
            next: next.clone(),
            limited,
        };
        each(&round);
        rounds.push(round);
        match next {
            Some(id) => {
                model = crate::inputs::with_candidates(
                    model.machine(),
                    model.clone(),
                    std::slice::from_ref(&id),
                )?;
                added.push(id);
            }
            _ => return Ok((rounds, model)),
        }
    }
}

/// The fit against what the noise leaves ([`volver_core::diagnose::NoiseLevel`]).
#[derive(Clone, Debug, Serialize)]
pub struct NoiseVerdict {
    /// The tracker's noise model, as `--noise` reads it; with several stations, each station's
    /// is in [`NoiseVerdict::stations`] (`each station's own` when there is no default).
    pub model: String,
    /// The expected EMM of the noise itself at these points (µm): the noise error.
    pub noise_error_um: f64,
    /// The expected EMM of a complete model's fit (µm): the noise error less what the fit's
    /// identified directions absorb.
    pub expected_fit_um: f64,
    /// Its expanded uncertainty (k = 2) over the noise (µm).
    pub u95_um: f64,
    /// The fit's EMM over the expected one.
    pub ratio: f64,
    /// `true` when the fit is within what the noise explains (less than [`ABOVE_NOISE_Z`]
    /// standard deviations from it either way).
    pub at_noise: bool,
    /// `true` when the fit lies more than [`ABOVE_NOISE_Z`] standard deviations below what the
    /// noise leaves: the specification overstates the noise of these data.
    pub below: bool,
    /// Bins of the breakdowns where the misfit exceeds the noise, worst first.
    pub above: Vec<BinAbove>,
    /// The repeated points against the specification, when the data have repeats.
    pub repeats: Option<RepeatCheck>,
    /// With several stations, each station's stated noise beside what its residuals show, in
    /// the machine's order; empty (and absent from the JSON) with one.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub stations: Vec<StationVerdict>,
}

/// One station's stated noise beside the noise its residuals show
/// ([`volver_core::diagnose::StationNoise`]).
#[derive(Clone, Debug, Serialize)]
pub struct StationVerdict {
    /// The station's id.
    pub station: String,
    /// Its stated noise, as `--noise` reads it.
    pub model: String,
    /// Whether that is its own `[[station]]` table's (else the tracker's default).
    pub own: bool,
    /// Its measurements.
    pub points: usize,
    /// The stated noise's σ per residual coordinate at its points (µm, RMS over them).
    pub stated_um: f64,
    /// The σ per coordinate its residuals show (µm): `scale × stated_um`.
    pub shown_um: f64,
    /// Shown over stated: the factor of its stated σ its whitened residuals show (1 at the
    /// noise).
    pub scale: f64,
    /// The expanded uncertainty (k = 2) of `scale` over the noise.
    pub scale_u95: f64,
    /// Where it stands: more than [`ABOVE_NOISE_Z`] standard deviations of `scale` above or
    /// below 1, or at the noise.
    pub standing: Standing,
}

impl StationVerdict {
    fn of(machine: &volver_core::machine::Machine, s: &diagnose::StationNoise) -> StationVerdict {
        StationVerdict {
            station: machine.stations()[s.station].id.clone(),
            model: s.noise.to_string(),
            own: s.own,
            points: s.points,
            stated_um: s.stated_um,
            shown_um: s.shown_um(),
            scale: s.scale,
            scale_u95: 2.0 * s.scale_sd,
            standing: Standing::of_z(s.z()),
        }
    }

    /// The station in words: `S2 (its own normal:0,0,0.5,1, 1040 points): σ 2.71 µm shown,
    /// 2.65 µm stated (1.02 ± 0.04 ×)`.
    pub fn text(&self) -> String {
        format!(
            "{} ({} {}, {} points): σ {} µm shown, {} µm stated ({:.2} ± {:.2} ×)",
            self.station,
            if self.own { "its own" } else { "the tracker's" },
            self.model,
            self.points,
            um(self.shown_um),
            um(self.stated_um),
            self.scale,
            self.scale_u95
        )
    }
}

/// A bin whose misfit exceeds the noise.
#[derive(Clone, Debug, Serialize)]
pub struct BinAbove {
    /// The breakdown (`X`, `t_s` …).
    pub by: String,
    /// The bin's label and unit.
    pub bin: String,
    /// Its EMM over what the noise leaves there.
    pub ratio: f64,
    /// Standard deviations above it.
    pub z: f64,
}

/// The noise from repeated points against the tracker's specification at those points.
#[derive(Clone, Debug, Serialize)]
pub struct RepeatCheck {
    /// Pairs of repeats.
    pub pairs: usize,
    /// The EMM of `(m₁ − m₂)/√2` (µm).
    pub estimate_um: f64,
    /// The specification's noise error at those points (µm).
    pub specified_um: f64,
    /// Its expanded uncertainty (k = 2) with this many pairs (µm).
    pub u95_um: f64,
    /// `true` when the two agree within it.
    pub agree: bool,
}

/// The same for one bin of a breakdown: with some sixty bins, each at about 2e-4 by chance.
pub const BIN_ABOVE_NOISE_Z: f64 = 3.5;

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
    /// What the noise leaves in this bin (µm; each point by its station's noise), when its
    /// specification is given.
    pub noise_um: Option<f64>,
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
    pub weak: Vec<Vec<crate::shared::Share>>,
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
    /// Why it is not a finding (a size beyond the physical bound, a nearly unidentifiable
    /// direction); such a candidate is never ranked first.
    pub flag: Option<String>,
    /// Why it could not be scored, when it could not (its figures are then absent).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub failed: Option<String>,
    /// For a field, the physical candidates over its variables, best first
    /// ([`volver_solvers::candidates::sharing`]): the physical effects it may be.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub physical: Vec<String>,
}

impl Candidate {
    fn of(s: &Score, ranked: &[Score]) -> Candidate {
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
            flag: s.flag.clone(),
            failed: s.failed.clone(),
            physical: if s.id.starts_with("field:") {
                sharing(ranked, &s.id)
                    .iter()
                    .map(|p| p.id.clone())
                    .collect()
            } else {
                Vec::new()
            },
        }
    }
}

/// Fits `model` to `data` with the native engine (default strategy) and diagnoses the fit
/// against the noise the machine file states (if any: its `[tracker] noise`, each station's own
/// where it states one); `Err` when the fit fails.
pub fn diagnose(model: &Model, data: &MeasurementSet) -> Result<Diagnosis> {
    diagnose_with(model, data, model.machine().default_noise().as_ref())
}

/// [`diagnose()`] against the tracker's noise `noise`, the noise of every station that states
/// none of its own (`None`, and a station without its own: no specification; the noise is then
/// judged from repeated points alone, and candidates weigh every coordinate the same).
pub fn diagnose_with(
    model: &Model,
    data: &MeasurementSet,
    noise: Option<&TrackerNoise>,
) -> Result<Diagnosis> {
    let noise = noise.filter(|n| !n.is_none());
    let problem = Problem::new(model, data)?;
    let id = volver_solvers::strategy::fit(problem.clone());
    if id.termination.failed() {
        return Err(Error::NotSolved(format!(
            "the fit failed: {}",
            id.termination
        )));
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
        noise,
    );
    let emm = id.reached.stats.emm_um;
    let breakdowns = diagnose::breakdowns(&problem, &r);
    let rank = ident.as_ref().map_or(model.n_params(), |a| a.rank);
    let levels = diagnose::noise_moments(&problem, noise);
    // Residual coordinates: three per point, one per range alone.
    let coordinates = crate::shared::coordinates(&problem);
    let level_of = |points: &[usize]| {
        levels
            .as_ref()
            .map(|mom| diagnose::noise_level(mom, points, rank, coordinates))
    };
    let verdict_noise = levels.as_ref().map(|moments| {
        let all: Vec<usize> = (0..r.len()).collect();
        let level = level_of(&all).expect("a noise model");
        let pairs = diagnose::repeat_pairs(&problem);
        let repeats = repeat.map(|(s, _)| (s.emm_um, pairs.as_slice()));
        let mut v = noise_verdict(noise, &level, emm, &breakdowns, &level_of, repeats, moments);
        if model.machine().stations().len() > 1 {
            v.stations = station_verdicts(&problem, &id.params, noise);
        }
        v
    });
    Ok(Diagnosis {
        points: data.points.len(),
        model: model.spec().name.clone(),
        emm_um: emm,
        emax_um: id.reached.stats.emax_um,
        termination: id.termination.to_string(),
        noise_estimate_um: repeat.map(|(s, _)| s.emm_um),
        repeat_pairs: repeat.map(|(_, n)| n),
        breakdowns: breakdowns.iter().map(|b| breakdown(b, &level_of)).collect(),
        directions: direction::directions(&problem, &id.params, &r),
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
        verdict: overall_verdict(&ranked, emm, verdict_noise.as_ref()),
        noise: verdict_noise,
        candidates: ranked.iter().map(|s| Candidate::of(s, &ranked)).collect(),
        fit: id,
    })
}

/// Each station's stated noise beside what its residuals show
/// ([`volver_core::diagnose::station_noises`]): the stations' variance components
/// ([`volver_solvers::identifiability::variance_components`]) on the residuals whitened by
/// their stated noise, from the fit at `params`; empty when a station has no noise or the
/// estimation fails.
fn station_verdicts(
    problem: &Problem,
    params: &[f64],
    noise: Option<&TrackerNoise>,
) -> Vec<StationVerdict> {
    let Ok(whitened) = problem.whitened(noise) else {
        return Vec::new();
    };
    let task = volver_solvers::Task::new(whitened);
    let tolerance = volver_solvers::identifiability::RANK_TOLERANCE;
    let groups: Vec<usize> = problem
        .data()
        .points
        .iter()
        .map(|p| p.station_index)
        .collect();
    volver_solvers::identifiability::variance_components(&task, params, tolerance, &groups)
        .and_then(|c| {
            let c: Vec<(f64, f64)> = c.iter().map(|c| (c.scale, c.dof)).collect();
            diagnose::station_noises(problem, noise, &c)
        })
        .iter()
        .flatten()
        .map(|s| StationVerdict::of(problem.model().machine(), s))
        .collect()
}

/// The fit against the noise: overall, per bin, and the repeats (their estimate in µm and their
/// pairs) against the specification.
fn noise_verdict(
    noise: Option<&TrackerNoise>,
    level: &diagnose::NoiseLevel,
    emm: f64,
    breakdowns: &[diagnose::Breakdown],
    level_of: &dyn Fn(&[usize]) -> Option<diagnose::NoiseLevel>,
    repeats: Option<(f64, &[(usize, usize)])>,
    moments: &[(f64, f64)],
) -> NoiseVerdict {
    let mut above: Vec<BinAbove> = breakdowns
        .iter()
        .flat_map(|b| {
            b.bins.iter().filter_map(move |x| {
                let l = level_of(&x.points)?;
                let z = l.z(x.stats.emm_um);
                (z > BIN_ABOVE_NOISE_Z).then(|| BinAbove {
                    by: b.by.clone(),
                    bin: format!("{} {}", x.label, b.unit).trim().to_string(),
                    ratio: l.ratio(x.stats.emm_um),
                    z,
                })
            })
        })
        .collect();
    above.sort_by(|a, b| b.z.total_cmp(&a.z));
    // The repeats' estimate ([`diagnose::repeat_noise`]) and the pairs behind it.
    let repeats = repeats.map(|(estimate_um, pairs)| {
        let firsts: Vec<usize> = pairs.iter().map(|p| p.0).collect();
        // The noise itself (no fit absorbs any of it), at the repeated points.
        let spec = diagnose::noise_level(moments, &firsts, 0, 1);
        let u95_um = 2.0 * spec.sd_um;
        RepeatCheck {
            pairs: pairs.len(),
            estimate_um,
            specified_um: spec.noise_emm_um,
            u95_um,
            agree: (estimate_um - spec.noise_emm_um).abs() <= 1.5 * u95_um,
        }
    });
    NoiseVerdict {
        model: noise.map_or_else(|| "each station's own".to_string(), |n| n.to_string()),
        noise_error_um: level.noise_emm_um,
        expected_fit_um: level.fit_emm_um,
        u95_um: 2.0 * level.sd_um,
        ratio: level.ratio(emm),
        at_noise: Standing::of(level, emm) == Standing::AtNoise,
        below: Standing::of(level, emm) == Standing::Below,
        above,
        repeats,
        stations: Vec::new(),
    }
}

/// The verdict in words: at the noise, that nothing is missing; otherwise the candidates'
/// verdict, then where the fit stands against the noise.
fn overall_verdict(ranked: &[Score], emm: f64, noise: Option<&NoiseVerdict>) -> String {
    let candidates = verdict(ranked, emm);
    let Some(n) = noise else {
        return candidates;
    };
    let against = format!(
        "{:.2} × what the {} noise leaves ({} ± {} µm)",
        n.ratio,
        if n.stations.is_empty() {
            "tracker's"
        } else {
            "stations'"
        },
        um(n.expected_fit_um),
        um(n.u95_um)
    );
    let stations = station_words(n);
    if n.at_noise {
        let aside = match ranked.first() {
            Some(s) if s.strong() => format!(
                " that matters ({} has strong evidence but would bring the EMM only to {} µm)",
                s.id,
                um(s.emm_um)
            ),
            _ => String::new(),
        };
        format!("the fit is at the noise, {against}: nothing is missing{aside}{stations}")
    } else if n.below {
        format!(
            "{candidates}. The fit is {against}: far below it, so the specification overstates \
             the noise of these data (or they were averaged); judge by the candidates \
             alone{stations}"
        )
    } else {
        format!("{candidates}. The fit is {against}: something is missing{stations}")
    }
}

/// The stations whose residuals show a noise off their stated one, in words (empty when none):
/// `. By station, S2 shows 5.10 × its stated noise (σ 2.70 against 0.53 µm) …`.
fn station_words(n: &NoiseVerdict) -> String {
    let off: Vec<String> = n
        .stations
        .iter()
        .filter(|s| s.standing != Standing::AtNoise)
        .map(|s| {
            format!(
                "{} shows {:.2} × its stated noise (σ {} against {} µm)",
                s.station,
                s.scale,
                um(s.shown_um),
                um(s.stated_um)
            )
        })
        .collect();
    if off.is_empty() {
        String::new()
    } else {
        format!(
            ". By station, {}: its noise is not the one stated (or the model misses what it \
             alone sees)",
            off.join(", ")
        )
    }
}

fn breakdown(
    b: &diagnose::Breakdown,
    level_of: &dyn Fn(&[usize]) -> Option<diagnose::NoiseLevel>,
) -> Breakdown {
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
                noise_um: level_of(&x.points).map(|l| l.fit_emm_um),
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
                    .map(|&(j, share)| crate::shared::Share {
                        name: model.params()[j].name.clone(),
                        share,
                    })
                    .collect()
            })
            .collect(),
    }
}
