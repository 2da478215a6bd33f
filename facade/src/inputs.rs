//! Reading what a fit needs: the machine, the error model and the measurements (the embedded
//! XCFZ grinder and the paper's model when no file is given), a model extended by candidates of
//! the diagnosis, and the demo's synthetic data.

use crate::error::{Context, Error, Result};
use std::path::Path;
use volver_core::machine::Machine;
use volver_core::measure::MeasurementSet;
use volver_core::model::Model;
use volver_core::plan::Plan;
use volver_core::problem::Problem;
use volver_core::simulate::{Magnitudes, Simulation, Synthetic, Truth};

/// Seed of the demo's synthetic test.
pub const DEMO_SEED: u64 = 7;

/// The effect hidden in the demo's data: a second harmonic in every error of the turntable C
/// (10 µm, 20 µrad), which the paper's model (first harmonics) cannot describe: the embedded
/// XCFZ preset's ([`volver_core::presets::Preset::demo_effect`]).
pub const DEMO_EFFECT: &str = volver_core::presets::PRESETS[0].demo_effect;

/// Where the demo writes its files.
pub const DEMO_DIR: &str = "volver-demo";

/// The machine `machine` names: a machine file (TOML), or, when no such file exists, the name
/// of an embedded machine ([`volver_core::presets`]: `xcfz`, `table-table`, `head-head`,
/// `head-table`); the embedded XCFZ grinder when absent. The preset is returned too.
///
/// ```
/// let (m, preset) = volver::inputs::machine(Some(std::path::Path::new("head-head"))).unwrap();
/// assert_eq!(m.chain().to_string(), "FXYZCA");
/// assert_eq!(preset.unwrap().name, "head-head");
/// let err = volver::inputs::machine(Some(std::path::Path::new("five-axis"))).unwrap_err();
/// assert!(format!("{err:#}").contains("table-table"));
/// ```
pub fn machine(
    machine: Option<&Path>,
) -> Result<(Machine, Option<&'static volver_core::presets::Preset>)> {
    let Some(p) = machine else {
        return Ok((Machine::default_xcfz(), volver_core::presets::named("xcfz")));
    };
    if !p.exists()
        && let Some(preset) = p.to_str().and_then(volver_core::presets::named)
    {
        return Ok((preset.machine()?, Some(preset)));
    }
    if !p.exists() && p.extension().is_none() && p.components().count() == 1 {
        return Err(Error::Request(format!(
            "--machine {}: no such file, nor an embedded machine (they are {}; `volver layout \
             --list` names them)",
            p.display(),
            volver_core::presets::names().join(", ")
        )));
    }
    Ok((Machine::load(p).context("reading the machine file")?, None))
}

/// The machine of `machine` (a TOML file or an embedded machine's name, see [`machine`]) and the
/// error model of `model` (TOML): the embedded machine's default model when absent (the
/// paper's model for the embedded XCFZ grinder). A model file needs its machine: a machine
/// file without a model file is refused.
///
/// ```
/// let (machine, model) = volver::inputs::machine_and_model(None, None).unwrap();
/// assert_eq!(machine.chain().to_string(), "XCFZ");
/// assert_eq!(model.n_params(), 74);
/// let (_, five) =
///     volver::inputs::machine_and_model(Some(std::path::Path::new("table-table")), None).unwrap();
/// assert!(five.param_index("X0C").is_some() && five.param_index("Z0A").is_some());
/// ```
pub fn machine_and_model(machine: Option<&Path>, model: Option<&Path>) -> Result<(Machine, Model)> {
    let (m, preset) = self::machine(machine)?;
    let model =
        match (model, preset) {
            (Some(p), _) => Model::load(m.clone(), p).context("reading the error model")?,
            (None, Some(preset)) => preset.model()?,
            (None, None) => return Err(Error::Request(
                "--model is needed with a machine file (the embedded models are for the embedded \
             machines)"
                    .into(),
            )),
        };
    Ok((m, model))
}

/// The plan `text` names on `machine` (an embedded machine: `preset`): a preset of
/// [`Plan::preset`] (`test4` …), an embedded machine's name (its preset plan, on this machine),
/// or grids ([`Plan::parse_grid`]); when absent, the embedded machine's preset plan, or `test4`
/// for a machine file.
///
/// ```
/// let (m, preset) = volver::inputs::machine(Some(std::path::Path::new("head-head"))).unwrap();
/// let plan = volver::inputs::plan(&m, preset, None).unwrap();
/// assert_eq!(plan.name, "head-head");
/// assert_eq!(volver::inputs::plan(&m, preset, Some("X=0,Y=0,Z=0,C=0,A=-90:90:45")).unwrap().positions.len(), 5);
/// ```
pub fn plan(
    machine: &Machine,
    preset: Option<&volver_core::presets::Preset>,
    text: Option<&str>,
) -> Result<Plan> {
    let text = text.unwrap_or(preset.map_or("test4", |p| p.name));
    if let Some(p) = volver_core::presets::named(text) {
        return p
            .plan_on(machine)
            .with_context(|| format!("the preset plan of the embedded {} machine", p.name));
    }
    Ok(if text.contains('=') {
        Plan::parse_grid(machine, text)?
    } else {
        Plan::preset(machine, text)? // an unknown name gets the list of presets
    })
}

/// [`machine_and_model`] and the measurements of `data` (CSV), whose scale is checked against
/// the machine (a file in metres or inches is refused with the reason).
pub fn load(
    machine: Option<&Path>,
    model: Option<&Path>,
    data: &Path,
) -> Result<(Machine, Model, MeasurementSet)> {
    load_with(machine, model, data, None)
}

/// [`load`], the measurements read through the import profile `import` when given
/// ([`volver_core::import::Profile`]: a tracker software's export as it is written).
pub fn load_with(
    machine: Option<&Path>,
    model: Option<&Path>,
    data: &Path,
    import: Option<&Path>,
) -> Result<(Machine, Model, MeasurementSet)> {
    load_taken_by(machine, model, data, import, None)
}

/// [`load_with`], each measurement's direction of approach taken from `plan`, the plan file the
/// data were taken by, when given ([`MeasurementSet::take_approach_from_plan`]: its stated
/// directions, a bidirectional plan's, else its order's; the measurement file's own
/// `approach_<AXIS>` columns win, a contradiction is refused).
pub fn load_taken_by(
    machine: Option<&Path>,
    model: Option<&Path>,
    data: &Path,
    import: Option<&Path>,
    plan: Option<&Path>,
) -> Result<(Machine, Model, MeasurementSet)> {
    let (m, model) = machine_and_model(machine, model)?;
    let mut unit: Option<(String, f64)> = None;
    let set = match import {
        Some(path) => {
            let profile =
                volver_core::import::Profile::load(path).context("reading the import profile")?;
            let (name, mm) = profile.length_unit();
            unit = Some((name.to_string(), mm));
            profile
                .load_export(&m, data)
                .context("reading the measurements through the import profile")?
        }
        None => MeasurementSet::load(&m, data).context("reading the measurements")?,
    };
    let mut set = set;
    if let Some(path) = plan {
        let p = volver_core::plan::file::load(&m, path).context("reading the plan file")?;
        set.take_approach_from_plan(
            &m,
            &p,
            &path.display().to_string(),
            &data.display().to_string(),
        )?;
    }
    if let Some(w) = set.time_unit_warning(&data.display().to_string()) {
        eprintln!("  warning: {w}");
    }
    Problem::new(&model, &set)?.check_scale_in(
        &data.display().to_string(),
        unit.as_ref().map(|(n, mm)| (&n[..], *mm)),
    )?;
    Ok((m, model, set))
}

/// `model` with the candidates `ids` (from `volver diagnose`) added in turn.
pub fn with_candidates(machine: &Machine, mut model: Model, ids: &[String]) -> Result<Model> {
    for id in ids {
        let library = volver_solvers::candidates::library(&model);
        let Some(c) = library.iter().find(|c| &c.id == id) else {
            let ids: Vec<&str> = library.iter().map(|c| c.id.as_str()).collect();
            return Err(Error::Mismatch(format!(
                "--add {id}: not a candidate for this model; candidates are {}",
                ids.join(", ")
            )));
        };
        model = Model::new(machine.clone(), c.spec.clone())?;
    }
    Ok(model)
}

/// The demo's synthetic test 4 on `model`'s machine: random true errors in the model (default
/// magnitudes), the paper's tracker noise, seed [`DEMO_SEED`], no hidden effect. `volver
/// compare` uses it.
pub fn demo_test4(model: &Model) -> Result<Synthetic> {
    let m = model.machine();
    let truth = Truth::random(m, model.spec(), &Magnitudes::default(), DEMO_SEED)?;
    Ok(Simulation::new(Plan::preset(m, "test4")?, truth, DEMO_SEED).run()?)
}

/// The noise a command uses ([`noise_rule`]), where it comes from, and how the fit stands
/// against it: stated in the text and the `--json` of `identify` and `uncertainty`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct NoiseUsed {
    /// The noise model, in words.
    pub model: String,
    /// Where it comes from: `--noise`, the machine file's `[tracker] noise`, each station's own,
    /// or the residuals; where stations state their own noise, each station's (`S2: its own
    /// normal:0,0,0.5,1; S3: the tracker's …`).
    pub source: String,
    /// When a specified noise and the data disagree (the fit's EMM clearly above or below
    /// what the noise leaves at these points), what that means; `None` when they agree or the
    /// noise is the residuals' own.
    pub disagreement: Option<String>,
}

/// The one noise rule: `--noise` when given (it wins over the machine file's, and the source
/// says both when they differ), else the machine file's `[tracker] noise`, else each station's
/// own when every `[[station]]` table states one, else an isotropic normal with the residuals'
/// variance. A station that states its own noise is weighed by it whatever the default (the
/// source then says so per station: `S2: its own normal:0,0,0.5,1`), except by the residuals'
/// isotropic noise.
///
/// ```
/// use volver::core::machine::{Machine, Observes, StationSpec};
/// let m = Machine::default_xcfz();
/// let mut layout = StationSpec::default_layout(&m, 2, Observes::Range);
/// layout[1].noise = Some("normal:0,0,0.5,1".into());
/// let multi = m.with_stations(layout).unwrap();
/// let (_, used) = volver::inputs::noise_rule(None, &multi).unwrap();
/// assert!(used.source.contains("S1: the tracker's uniform:30,30,4,0.8; S2: its own normal:0,0,0.5,1"));
/// ```
pub fn noise_rule(
    given: Option<&str>,
    machine: &Machine,
) -> Result<(volver_solvers::uncertainty::NoiseModel, NoiseUsed)> {
    use volver_solvers::uncertainty::NoiseModel;
    let file = machine.default_noise().filter(|n| !n.is_none());
    let own = |k| machine.station_own_noise(k).filter(|n| !n.is_none());
    // Every station states its own: the default is never used (any stands for it).
    let every_own =
        machine.has_stations() && (0..machine.stations().len()).all(|k| own(k).is_some());
    let (model, source) = match (given, file) {
        (Some(text), file) => {
            let model = crate::shared::noise_of(Some(text))?;
            let source = match file {
                Some(f) if NoiseModel::Tracker(f) != model => {
                    format!("--noise, over the machine file's [tracker] noise {f}")
                }
                Some(_) => "--noise, as the machine file's [tracker] noise".to_string(),
                None => "--noise".to_string(),
            };
            (model, source)
        }
        (None, Some(f)) => (
            NoiseModel::Tracker(f),
            "the machine file's [tracker] noise".to_string(),
        ),
        (None, None) => match own(0).filter(|_| every_own) {
            Some(first) => (
                NoiseModel::Tracker(first),
                "each station's own noise (no --noise, no [tracker] noise in the machine file)"
                    .to_string(),
            ),
            None => (
                NoiseModel::Residual,
                "the residuals (no --noise, no [tracker] noise in the machine file)".to_string(),
            ),
        },
    };
    let default = match model {
        NoiseModel::Tracker(n) => Some(n),
        _ => None,
    };
    let words = crate::shared::station_noise_words(machine, default.as_ref());
    let source = match (words, default) {
        (Some(w), Some(_)) if every_own && given.is_some() => {
            format!("{source}, which no station takes (each states its own): {w}")
        }
        (Some(w), Some(_)) => format!("{source}; by station, {w}"),
        (Some(w), None) => format!(
            "{source}; the stations' own noise ({w}) is not used: not every station states one"
        ),
        (None, _) => source,
    };
    let used = NoiseUsed {
        model: if every_own {
            "each station's own".to_string()
        } else {
            model.to_string()
        },
        source,
        disagreement: None,
    };
    Ok((model, used))
}

impl NoiseUsed {
    /// `self` with the fit at `params` (EMM `emm_um`) of `model` on `data` judged against a
    /// specified noise ([`crate::shared::standing`]): a disagreement when the fit is clearly
    /// above what the noise leaves at these points (the model misses something, or the noise is
    /// understated: the intervals then assume a model the data do not support) or far below it.
    pub fn judged(
        mut self,
        noise: volver_solvers::uncertainty::NoiseModel,
        model: &Model,
        data: &MeasurementSet,
        params: &[f64],
        emm_um: f64,
    ) -> NoiseUsed {
        use crate::shared::Standing;
        let volver_solvers::uncertainty::NoiseModel::Tracker(n) = noise else {
            return self;
        };
        let Ok(problem) = Problem::new(model, data) else {
            return self;
        };
        if let Some((level, standing)) = crate::shared::standing(&problem, params, emm_um, &n)
            && standing != Standing::AtNoise
        {
            self.disagreement = Some(format!(
                "the fit's EMM {emm_um:.2} µm is {:.2} × what this noise leaves at these points \
                 ({:.2} µm): {}{}",
                level.ratio(emm_um),
                level.fit_emm_um,
                standing.conclusion(),
                if standing == Standing::Above {
                    " (`volver diagnose`), or the noise is understated; intervals from it \
                     assume a complete model"
                } else {
                    ""
                }
            ));
        }
        self
    }

    /// The statement as printed under a command's summary (two lines with a disagreement).
    pub fn text(&self) -> String {
        let mut out = format!("  noise: {}, from {}", self.model, self.source);
        if let Some(d) = &self.disagreement {
            out.push_str(&format!("\n  noise against the data: {d}"));
        }
        out
    }
}
