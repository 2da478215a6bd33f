//! What several workflows share, below all of them: where a fit stands against the tracker's
//! noise ([`standing`], [`check_fit`]), the words for a combination the data cannot identify
//! ([`held_text`], [`Share`]), the default grid of commands and the tool point at the
//! reflectors' centroid, the noise named on a command line. The workflow modules re-export what
//! their users know them by (`volver::diagnosis::Standing`, `volver::uncertainty::check_fit` …);
//! this module imports none of them, so the workflows import each other one way only.

use crate::error::{Error, Result};
use serde::Serialize;
use volver_core::diagnose;
use volver_core::machine::Machine;
use volver_core::model::Model;
use volver_core::noise::TrackerNoise;
use volver_core::plan::Plan;
use volver_core::problem::{Problem, Residuals};
use volver_solvers::gauge::Gauge;
use volver_solvers::identifiability::analyse;
use volver_solvers::uncertainty::NoiseModel;

/// Parameter pairs correlated above this (absolute value) are listed by the identifiability
/// analysis of the diagnosis and of the report.
pub const CORRELATION_LISTED: f64 = 0.95;

/// How many standard deviations above what the noise leaves a fit's EMM must lie to be
/// reported as off the noise, above or below (about 1.2 % of fits at the noise by chance).
pub const ABOVE_NOISE_Z: f64 = 2.5;

/// Where a fit stands against what the tracker's noise leaves: the conclusion every output
/// states is chosen from this, never written in advance.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Standing {
    /// Within [`ABOVE_NOISE_Z`] standard deviations of what a complete model leaves.
    AtNoise,
    /// Above it: something is missing.
    Above,
    /// Far below it: the specification overstates the noise of these data.
    Below,
}

impl Standing {
    /// The standing of a fit of EMM `emm_um` against `level`.
    ///
    /// ```
    /// use volver::diagnosis::Standing;
    /// use volver::core::diagnose::NoiseLevel;
    /// let level = NoiseLevel { noise_emm_um: 50.0, fit_emm_um: 49.0, sd_um: 0.5 };
    /// assert_eq!(Standing::of(&level, 49.4), Standing::AtNoise);
    /// assert_eq!(Standing::of(&level, 67.0), Standing::Above);
    /// assert_eq!(Standing::of(&level, 30.0), Standing::Below);
    /// assert_eq!(Standing::of(&level, 67.0).conclusion(), "something is missing");
    /// ```
    pub fn of(level: &diagnose::NoiseLevel, emm_um: f64) -> Standing {
        Standing::of_z(level.z(emm_um))
    }

    /// The standing of a figure `z` standard deviations above what the noise leaves.
    ///
    /// ```
    /// use volver::diagnosis::{ABOVE_NOISE_Z, Standing};
    /// assert_eq!(Standing::of_z(ABOVE_NOISE_Z + 0.1), Standing::Above);
    /// assert_eq!(Standing::of_z(-1.0), Standing::AtNoise);
    /// ```
    pub fn of_z(z: f64) -> Standing {
        if z > ABOVE_NOISE_Z {
            Standing::Above
        } else if z < -ABOVE_NOISE_Z {
            Standing::Below
        } else {
            Standing::AtNoise
        }
    }

    /// The conclusion in words.
    pub fn conclusion(self) -> &'static str {
        match self {
            Standing::AtNoise => "the model explains everything but the noise",
            Standing::Above => "something is missing",
            Standing::Below => {
                "far below what the noise leaves: the noise specification overstates the noise \
                 of these data"
            }
        }
    }
}

/// What the noise leaves of a fit at `params` of `problem` (its identified directions absorb
/// part of it) and where the fit's EMM `emm_um` stands against it: each point by its station's
/// noise, its own `[[station]]` table's, else the tracker's `noise`
/// ([`volver_core::diagnose::noise_moments`]); `None` when the fit's identifiability cannot be
/// analysed.
pub fn standing(
    problem: &Problem,
    params: &[f64],
    emm_um: f64,
    noise: &TrackerNoise,
) -> Option<(diagnose::NoiseLevel, Standing)> {
    standing_with(problem, params, emm_um, Some(noise))
}

/// [`standing`] with the tracker's default noise `default` optional: `None` also when a station
/// that measured has no noise (neither its own nor the default).
pub fn standing_with(
    problem: &Problem,
    params: &[f64],
    emm_um: f64,
    default: Option<&TrackerNoise>,
) -> Option<(diagnose::NoiseLevel, Standing)> {
    let moments = diagnose::noise_moments(problem, default)?;
    let ident = analyse(
        &volver_solvers::Task::new(problem.clone()),
        params,
        volver_solvers::identifiability::RANK_TOLERANCE,
        CORRELATION_LISTED,
    )?;
    let coordinates = coordinates(problem);
    let all: Vec<usize> = (0..problem.n_points()).collect();
    let level = diagnose::noise_level(&moments, &all, ident.rank, coordinates);
    Some((level, Standing::of(&level, emm_um)))
}

/// The fewest pairs of repeated points the check of a fit against their noise takes.
pub const MIN_REPEAT_PAIRS: usize = 5;

/// How far above the noise its repeated points show a fit's EMM may lie before the model is
/// reported incomplete (× what the noise leaves a complete model): the repeats' own estimate of
/// the noise varies by some 10 % with tens of pairs.
pub const REPEAT_MARGIN: f64 = 1.2;

/// The residual coordinates of `problem`: three per point, one per range alone.
pub fn coordinates(problem: &Problem) -> usize {
    (0..problem.n_points())
        .map(|i| if problem.scalar(i) { 1 } else { 3 })
        .sum()
}

/// Each station's noise in words, where stations state their own: `S1: its own
/// normal:0,0,0.1,0.15; S2: the tracker's paper` (`default`, the tracker's: `--noise` or the
/// `[tracker]` table's; `none` for a station with neither); `None` when no station states its
/// own (every station then has `default`).
///
/// ```
/// use volver::core::machine::{Machine, Observes, StationSpec};
/// let m = Machine::default_xcfz();
/// assert_eq!(volver::shared::station_noise_words(&m, m.default_noise().as_ref()), None);
/// let mut layout = StationSpec::default_layout(&m, 2, Observes::Range);
/// layout[1].noise = Some("normal:0,0,0.5,1".into());
/// let multi = m.with_stations(layout).unwrap();
/// assert_eq!(
///     volver::shared::station_noise_words(&multi, multi.default_noise().as_ref()).unwrap(),
///     "S1: the tracker's uniform:30,30,4,0.8; S2: its own normal:0,0,0.5,1"
/// );
/// ```
pub fn station_noise_words(machine: &Machine, default: Option<&TrackerNoise>) -> Option<String> {
    let stations = machine.stations();
    if !(0..stations.len()).any(|k| machine.station_own_noise(k).is_some()) {
        return None;
    }
    let words: Vec<String> = stations
        .iter()
        .enumerate()
        .map(|(k, st)| match (machine.station_own_noise(k), default) {
            (Some(own), _) => format!("{}: its own {own}", st.id),
            (None, Some(d)) => format!("{}: the tracker's {d}", st.id),
            (None, None) => format!("{}: none stated", st.id),
        })
        .collect();
    Some(words.join("; "))
}

/// The fit `id` of `problem` against what the noise leaves a complete model ([`ModelCheck`]),
/// with the noise the rule of one noise source gives: `noise` when it is the tracker's, else the
/// machine file's `[tracker] noise`, each station by its own noise where it states one — judged
/// as the diagnosis judges it ([`standing_with`]: more than [`ABOVE_NOISE_Z`] standard
/// deviations above) — else from the repeated points ([`REPEAT_MARGIN`] above the noise they
/// show, at least [`MIN_REPEAT_PAIRS`] pairs), else unknown.
///
/// [`ModelCheck`]: volver_core::results::ModelCheck
pub fn check_fit(
    problem: &volver_core::problem::Problem,
    id: &volver_solvers::strategy::Identification,
    noise: NoiseModel,
) -> volver_core::results::ModelCheck {
    use volver_core::results::ModelCheck;
    let model = problem.model();
    let emm_um = id.reached.stats.emm_um;
    let known = matches!(noise, NoiseModel::Tracker(_) | NoiseModel::Residual);
    let spec = match noise {
        NoiseModel::Tracker(n) => Some(n),
        NoiseModel::Residual => model.machine().default_noise(),
        // A noise model this check does not know: judged by the repeated points below.
        _ => None,
    }
    .filter(|n| !n.is_none());
    if known
        && let Some((level, standing)) = standing_with(problem, &id.params, emm_um, spec.as_ref())
    {
        let basis = match station_noise_words(model.machine(), spec.as_ref()) {
            Some(words) => format!("each station's noise ({words})"),
            None => format!(
                "the tracker's specification {}",
                spec.map_or_else(String::new, |n| n.to_string())
            ),
        };
        return ModelCheck {
            emm_um,
            expected_um: Some(level.fit_emm_um),
            basis,
            above_noise: standing == Standing::Above,
        };
    }
    let held = id.gauge.as_ref().map_or(0, |g| g.held.len());
    let free = model
        .n_params()
        .saturating_sub(model.constraints().rows.len() + held);
    let keep = (1.0 - free as f64 / coordinates(problem).max(1) as f64)
        .max(0.0)
        .sqrt();
    match volver_core::diagnose::repeat_noise(problem) {
        Some((stats, pairs)) if pairs >= MIN_REPEAT_PAIRS => {
            let expected = stats.emm_um * keep;
            ModelCheck {
                emm_um,
                expected_um: Some(expected),
                basis: format!("{pairs} pairs of repeated points"),
                above_noise: emm_um > REPEAT_MARGIN * expected,
            }
        }
        _ => ModelCheck {
            emm_um,
            expected_um: None,
            basis: "no noise specification and fewer than 5 pairs of repeated points".into(),
            above_noise: false,
        },
    }
}

/// One text per held combination of `gauge` ([`combination_text`]), in its order; none without
/// a gauge: the names a results file records for the columns of its held factor.
pub fn held_text(model: &Model, gauge: Option<&Gauge>) -> Vec<String> {
    gauge
        .map(|g| {
            (0..g.held.len())
                .map(|c| combination_text(model, g, c))
                .collect()
        })
        .unwrap_or_default()
}

/// The names of the parameters a held combination moves, with their shares.
pub fn combination_text(model: &Model, gauge: &Gauge, c: usize) -> String {
    let parts: Vec<String> = gauge.held[c]
        .parameters
        .iter()
        .take(4)
        .map(|&(j, s)| format!("{} {s:+.2}", model.params()[j].name))
        .collect();
    parts.join(", ")
}

/// A grid of `per_axis` evenly spaced positions over every axis' travel (a full-turn rotary
/// axis stops one step short of its end, which is its start).
pub fn default_grid(m: &Machine, per_axis: usize) -> Result<Plan> {
    let parts: Vec<String> = m
        .axes()
        .iter()
        .map(|ax| {
            let (a, b) = (ax.to_file_units(ax.min), ax.to_file_units(ax.max));
            let full_turn = ax.axis.is_rotary() && (b - a) >= 360.0 - 1e-9;
            let steps = if full_turn { per_axis } else { per_axis - 1 };
            let step = (b - a) / steps.max(1) as f64;
            let end = if full_turn { b - step } else { b };
            if step > 0.0 {
                format!("{}={a}:{end}:{step}", ax.axis)
            } else {
                format!("{}={a}", ax.axis)
            }
        })
        .collect();
    Ok(Plan::parse_grid(m, &parts.join(","))?)
}

/// The noise model of `--noise`.
pub fn noise_of(text: Option<&str>) -> Result<NoiseModel> {
    Ok(match text {
        Some(t) => {
            let n = TrackerNoise::from_text(t)?;
            if n.is_none() {
                return Err(Error::Request(format!(
                    "--noise {t}: a noise-free tracker gives no uncertainty; give its noise"
                )));
            }
            NoiseModel::Tracker(n)
        }
        None => NoiseModel::Residual,
    })
}

/// Refuses a station whose noise (its own, else `default`) has σ = 0 for what it observes — its
/// angles or range for a tracker, its range for an interferometer — naming it: an uncertainty or
/// a design from it would give that station's measurements infinite weight (a NaN, or a
/// decomposition that fails, without this check).
///
/// ```
/// use volver::core::{machine::Machine, noise::TrackerNoise};
/// let m = Machine::default_xcfz();
/// assert!(volver::shared::check_station_noises(&m, &TrackerNoise::PAPER).is_ok());
/// let none = TrackerNoise::from_text("none").unwrap();
/// let err = volver::shared::check_station_noises(&m, &none).unwrap_err().to_string();
/// assert!(err.contains("the tracker") && err.contains("σ = 0"), "{err}");
/// ```
pub fn check_station_noises(machine: &Machine, default: &TrackerNoise) -> Result<()> {
    use volver_core::machine::Observes;
    for (k, st) in machine.stations().iter().enumerate() {
        let n = machine.station_noise_or(k, *default);
        // At a metre: the range's σ is a + b·L, zero only when both are.
        if !n.measures(st.observes == Observes::Range, 1000.0) {
            let who = match st.id.as_str() {
                "" => "the tracker".to_string(),
                id => format!("station '{id}'"),
            };
            return Err(Error::Request(format!(
                "{who}'s noise {n} has σ = 0 for what it measures: its measurements would weigh \
                 infinitely; state its noise (--noise, the machine file's [tracker] noise or \
                 the station's own noise)"
            )));
        }
    }
    Ok(())
}

/// A parameter's share of a combination.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Share {
    /// The parameter's name (ISO 230-1, e.g. `EXC.b1`).
    pub name: String,
    /// Its share (a component of the unit combination).
    pub share: f64,
}

/// The centroid of the reflector offsets (mm).
pub fn reflector_centroid(model: &Model) -> [f64; 3] {
    let r = model.machine().reflectors();
    let mut c = [0.0; 3];
    for x in r {
        for (ci, oi) in c.iter_mut().zip(x.offset) {
            *ci += oi / r.len() as f64;
        }
    }
    c
}
