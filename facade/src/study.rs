//! `volver study paper`: the paper's studies (tables 5, 6, 8, 9, 10, 11, 12) rerun on synthetic
//! data from the generator, our figures beside the paper's.
//!
//! The paper's true errors are unknown. For each table, our random true errors (default
//! magnitudes, one seed) are scaled so that the table's initial EMM on its noise-free mesh
//! matches the paper's: 181.15 µm for table 5, 194.9 µm for table 6, 737.1 µm for tables 8 and 10,
//! 227.0 µm for table 9, and 628.69 µm on the reference test 4 for tables 11 and 12 (one truth for
//! all five tests, since table 12 compensates test 4 with each test's errors). The noise is the
//! paper's tracker read as bounds ([`TrackerNoise::PAPER`]).

use crate::error::Result;
use volver_core::machine::Machine;
use volver_core::measure::MeasurementSet;
use volver_core::model::{ErrorModelSpec, Model};
use volver_core::noise::TrackerNoise;
use volver_core::plan::Plan;
use volver_core::problem::{Problem, Residuals};
use volver_core::simulate::{Magnitudes, Simulation, Truth};
use volver_solvers::lm::LevenbergMarquardt;
use volver_solvers::strategy::{
    ErrorScope, Identification, Phasing, Strategy, combined, cross_validate, identify_errors,
    independent,
};
use volver_solvers::{Options, Silent, Stall, Termination};

/// A row's figures: initial and final EMM and EMax (µm) and the residual (%).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Figures {
    /// Initial EMM (errors zero, tracker fitted), µm.
    pub emm0_um: f64,
    /// Initial EMax, µm.
    pub emax0_um: f64,
    /// Final EMM, µm.
    pub emm_um: f64,
    /// Final EMax, µm.
    pub emax_um: f64,
    /// Final EMM / initial EMM, %.
    pub residual_percent: f64,
}

const fn figures(emm0_um: f64, emax0_um: f64, emm_um: f64, emax_um: f64, res: f64) -> Figures {
    Figures {
        emm0_um,
        emax0_um,
        emm_um,
        emax_um,
        residual_percent: res,
    }
}

/// One row: label, the paper's figures and ours.
pub struct Row {
    /// What was run.
    pub label: String,
    /// The paper's figures, when it gives them.
    pub paper: Option<Figures>,
    /// Ours.
    pub ours: Figures,
    /// Whether our run converged.
    pub converged: bool,
    /// What stopped our run.
    pub termination: String,
    /// When the engine claimed convergence at a point the shared check found not stationary
    /// ([`volver_solvers::stationarity`]): the fraction of Φ one more step could still remove.
    pub short_by: Option<f64>,
}

/// One table.
pub struct Table {
    /// Title.
    pub title: String,
    /// Rows.
    pub rows: Vec<Row>,
    /// The noise error of the noisy data (EMM, EMax µm): the paper's and ours (tables 9, 10).
    pub noise: Option<((f64, f64), (f64, f64))>,
    /// Why ours differ.
    pub note: String,
}

const ROTARY: &str = r#"[[error]]
name = ["EXC", "EYC", "EZC", "EAC", "EBC", "ECC"]
"#;

const LINEAR: &str = r#"squareness = "from-straightness"
[[error]]
name = ["EXX", "EYX", "EZX", "EAX", "EBX", "ECX", "EXZ", "EYZ", "EZZ", "EAZ", "EBZ", "ECZ"]
"#;

fn model(machine: &Machine, text: &str) -> Result<Model> {
    Ok(Model::from_toml_str(
        machine.clone(),
        &format!("{text}[tracker]\nidentify = [\"x\", \"y\", \"z\"]\n"),
        "study model",
    )?)
}

fn row(label: &str, paper: Option<Figures>, id: &Identification) -> Row {
    Row {
        label: label.to_string(),
        paper,
        ours: Figures {
            emm0_um: id.initial.stats.emm_um,
            emax0_um: id.initial.stats.emax_um,
            emm_um: id.reached.stats.emm_um,
            emax_um: id.reached.stats.emax_um,
            residual_percent: id.residual_percent(),
        },
        converged: id.termination.converged(),
        termination: id.termination.to_string(),
        short_by: match &id.termination {
            Termination::Stalled(Stall::NotStationary { measured, .. }) => Some(measured.gain),
            _ => None,
        },
    }
}

/// Measurements of `truth` on the preset `plan` with `noise`.
fn measure(truth: &Truth, plan: &str, noise: TrackerNoise, seed: u64) -> Result<MeasurementSet> {
    let mut sim = Simulation::new(
        Plan::preset(truth.model.machine(), plan)?,
        truth.clone(),
        seed,
    );
    sim.noise = noise;
    Ok(sim.run()?.measurements)
}

/// The noise error (EMM, EMax µm) of `truth` on `plan` with `noise`.
fn noise_error(truth: &Truth, plan: &str, noise: TrackerNoise, seed: u64) -> Result<(f64, f64)> {
    let mut sim = Simulation::new(
        Plan::preset(truth.model.machine(), plan)?,
        truth.clone(),
        seed,
    );
    sim.noise = noise;
    let e = sim.run()?.record.noise_error;
    Ok((e.emm_um, e.emax_um))
}

/// `truth` with its error functions (not the tracker pose) scaled by `k`.
fn scaled(truth: &Truth, k: f64) -> Truth {
    let mut t = truth.clone();
    let end = t.model.tracker_start();
    for v in &mut t.params[..end] {
        *v *= k;
    }
    t
}

/// `truth` scaled so that the initial EMM (errors zero, tracker fitted) of `model` on the
/// noise-free `plan` is `target_um`: the initial EMM is nearly linear in the scale, and a second
/// pass removes what is not.
fn scaled_to(truth: &Truth, model: &Model, plan: &str, target_um: f64, seed: u64) -> Result<Truth> {
    let mut t = truth.clone();
    for _ in 0..2 {
        let set = measure(&t, plan, TrackerNoise::NONE, seed)?;
        let problem = Problem::new(model, &set)?;
        let start = volver_solvers::init::init_tracker(&problem, &model.initial_params())?;
        t = scaled(&t, target_um / problem.stats(&start).emm_um);
    }
    Ok(t)
}

/// Runs the seven studies with true errors drawn from `seed` (see the module documentation).
pub fn paper(seed: u64) -> Result<Vec<Table>> {
    let st = Study::new(seed)?;
    let mut tables = Vec::new();
    table5(&st, &mut tables)?;
    table6(&st, &mut tables)?;
    let linear = table8(&st, &mut tables)?;
    table9(&st, &mut tables)?;
    table10(&st, &mut tables, &linear)?;
    tables11_12(&st, &mut tables)?;
    Ok(tables)
}

/// What every study shares: the machine, the true errors drawn from the seed, the engine and its
/// options, the paper's noise.
struct Study {
    m: Machine,
    truth: Truth,
    options: Options,
    lm: LevenbergMarquardt,
    noise: TrackerNoise,
    seed: u64,
}

impl Study {
    fn new(seed: u64) -> Result<Study> {
        let m = Machine::default_xcfz();
        let magnitudes = Magnitudes {
            tracker_mm: 0.0,
            ..Magnitudes::default()
        };
        let truth = Truth::random(&m, &ErrorModelSpec::complete(&m), &magnitudes, seed)?;
        // 5000 iterations: the noise-free fits of table 8 (cubics and a quartic against cubic
        // truths plus constants the model lacks) creep for hundreds of steps before their
        // parameter change settles.
        let options = Options {
            max_iterations: 5000,
            max_evaluations: 20_000,
            ..Options::default()
        };
        Ok(Study {
            m,
            truth,
            options,
            lm: LevenbergMarquardt::default(),
            noise: TrackerNoise::PAPER,
            seed,
        })
    }

    /// One identification as the paper makes it.
    fn run(
        &self,
        model: &Model,
        set: &MeasurementSet,
        errors: ErrorScope,
        phasing: Phasing,
    ) -> Result<Identification> {
        let problem = Problem::new(model, set)?;
        // The paper's method has no gauge: on its noise-free meshes the data determine even
        // the nearly flat combinations (curvature 1e-12 of the largest) that the gauge holds
        // for real data, and the tables compare final errors of zero.
        let strategy = Strategy {
            phasing,
            gauge: false,
            ..Strategy::default()
        };
        Ok(identify_errors(
            &self.lm,
            problem,
            &model.initial_params(),
            errors,
            &strategy,
            &self.options,
            &mut Silent,
        ))
    }
}

/// The rotary-axis model of tables 5, 6 and 9 in `basis` (first harmonics).
fn rotary_model(m: &Machine, basis: &str) -> Result<Model> {
    model(m, &format!("{ROTARY}basis = \"{basis}\"\norder = 1\n"))
}

/// Table 5: Fourier against sine series on the table-4 mesh.
fn table5(st: &Study, tables: &mut Vec<Table>) -> Result<()> {
    let Study {
        m,
        truth,
        options,
        lm,
        ..
    } = st;
    let seed = st.seed;
    // Table 5: Fourier against sine series on the table-4 mesh.
    let fourier = rotary_model(m, "fourier")?;
    let sine = rotary_model(m, "sine")?;
    let t5 = measure(
        &scaled_to(truth, &fourier, "table4", 181.15, seed)?,
        "table4",
        TrackerNoise::NONE,
        seed,
    )?;
    let f = st.run(&fourier, &t5, ErrorScope::All, Phasing::One)?;
    // The sine series starts from the Fourier solution (a zero amplitude has no phase gradient).
    let mut start = sine.initial_params();
    for (j, info) in sine.params().iter().enumerate() {
        let get = |s: String| f.params[fourier.param_index(&s).expect("same errors")];
        start[j] = if let Some((e, h)) = info.name.split_once(".a") {
            get(format!("{e}.a{h}")).hypot(get(format!("{e}.b{h}")))
        } else if let Some((e, h)) = info.name.split_once(".phi") {
            get(format!("{e}.b{h}")).atan2(get(format!("{e}.a{h}")))
        } else {
            f.params[fourier.param_index(&info.name).expect("same parameter")]
        };
    }
    let s = identify_errors(
        lm,
        Problem::new(&sine, &t5)?,
        &start,
        ErrorScope::All,
        &Strategy {
            init_tracker: false,
            gauge: false,
            ..Strategy::default()
        },
        options,
        &mut Silent,
    );
    let mut s_row = row(
        "sine series (first harmonic)",
        Some(figures(181.15, 500.25, 16.58, 60.72, 9.15)),
        &s,
    );
    s_row.ours.emm0_um = f.initial.stats.emm_um;
    s_row.ours.emax0_um = f.initial.stats.emax_um;
    s_row.ours.residual_percent = 100.0 * s.reached.stats.emm_um / f.initial.stats.emm_um;
    tables.push(Table {
        title: "Table 5: Fourier against sine series, rotary axis, table-4 mesh, no noise".into(),
        rows: vec![
            row(
                "Fourier series (first harmonic)",
                Some(figures(181.15, 500.25, 93.28, 227.78, 51.49)),
                &f,
            ),
            s_row,
        ],
        noise: None,
        note: "Both series of the same order span the same functions, so a converged fit reaches \
               the same Φ with either; the paper's 51 % for Fourier is an artefact (the harmonic \
               index missing from its eq. 20, see the project notes) and of an optimiser that \
               stopped early. Our EMax₀ differs: the paper's truth is unknown."
            .into(),
    });
    Ok(())
}

/// Table 6: one phase against TR and RT, rotary axis.
fn table6(st: &Study, tables: &mut Vec<Table>) -> Result<()> {
    let Study { m, truth, .. } = st;
    let seed = st.seed;
    let fourier = rotary_model(m, "fourier")?;
    // Table 6: one phase against TR and RT, rotary axis.
    let t6 = measure(
        &scaled_to(truth, &fourier, "table4", 194.9, seed)?,
        "table4",
        TrackerNoise::NONE,
        seed,
    )?;
    let mut rows = Vec::new();
    for (label, phasing, paper) in [
        (
            "1 phase",
            Phasing::One,
            figures(194.9, 213.5, 112.6, 186.1, 57.7),
        ),
        (
            "2 phases TR",
            Phasing::Tr,
            figures(194.9, 213.5, 15.1, 65.1, 7.8),
        ),
        (
            "2 phases RT",
            Phasing::Rt,
            figures(194.9, 213.5, 18.7, 64.8, 9.6),
        ),
    ] {
        rows.push(row(
            label,
            Some(paper),
            &st.run(&fourier, &t6, ErrorScope::All, phasing)?,
        ));
    }
    tables.push(Table {
        title: "Table 6: rotary axis by phases, table-4 mesh, no noise (paper's second test)"
            .into(),
        rows,
        noise: None,
        note: "A converged one-phase fit is the best any phasing can reach (phases only hold \
               parameters); the paper's one-phase run stopped on its criteria at 58 %. Phased \
               runs end higher because a group held at zero is absorbed by the others."
            .into(),
    });
    Ok(())
}

/// Table 8: linear axes on the table-7 mesh, three bases, three phasings; also the monomial model, its scaled truth and noise-free mesh, which table 10 reuses.
fn table8(st: &Study, tables: &mut Vec<Table>) -> Result<(Model, Truth, MeasurementSet)> {
    let Study { m, truth, .. } = st;
    let seed = st.seed;
    // Table 8: linear axes on the table-7 mesh, three bases, three phasings.
    let linear = |basis: &str| {
        model(
            m,
            &format!("{LINEAR}{basis}[[error]]\nname = [\"A0Z\", \"B0Z\"]\n"),
        )
    };
    let monomial = linear("basis = \"monomial\"\ndegree = 3\n")?;
    let truth7 = scaled_to(truth, &monomial, "table7", 737.1, seed)?;
    let t7 = measure(&truth7, "table7", TrackerNoise::NONE, seed)?;
    let mut rows = Vec::new();
    let i8 = |emm, emax, res| figures(737.1, 2010.6, emm, emax, res);
    let paper8 = [
        (
            "monomial",
            "basis = \"monomial\"\ndegree = 3\n",
            [
                i8(6.6, 23.2, 0.9),
                i8(19.9, 36.6, 2.7),
                i8(39.6, 150.6, 5.4),
            ],
        ),
        (
            "Legendre",
            "basis = \"legendre\"\ndegree = 3\n",
            [
                i8(3.6, 10.46, 0.5),
                i8(75.18, 244.3, 10.2),
                i8(123.8, 374.0, 16.8),
            ],
        ),
        (
            "Chebyshev 5 nodes",
            "basis = \"chebyshev\"\nnodes = 5\n",
            [i8(4.4, 16.7, 0.1), i8(57.1, 157.8, 7.7), i8(8.4, 19.0, 1.2)],
        ),
    ];
    for (name, basis, paper) in paper8 {
        let lin = linear(basis)?;
        for ((label, phasing), p) in [
            ("1 phase", Phasing::One),
            ("TR", Phasing::Tr),
            ("RT", Phasing::Rt),
        ]
        .into_iter()
        .zip(paper)
        {
            rows.push(row(
                &format!("{name}, {label}"),
                Some(p),
                &st.run(&lin, &t7, ErrorScope::All, phasing)?,
            ));
        }
    }
    tables.push(Table {
        title: "Table 8: linear axes X, Z by basis and phases, table-7 mesh, no noise".into(),
        rows,
        noise: None,
        note: "Our true errors are cubics and the C errors at C = 0 act as constants that this \
               model lacks, so the one-phase fits end at the effect of those constants; the \
               paper's true errors are unknown. Monomial and Legendre of one degree span the same \
               functions and reach the same Φ to 0.1 % here (to 1e-13 when the model contains \
               the truth; the rest is nearly redundant directions held as unidentifiable, which \
               depend on the parametrisation), where the paper has 0.9 % against 0.5 %; \
               Chebyshev with 5 nodes is a quartic."
            .into(),
    });
    Ok((monomial, truth7, t7))
}

/// Table 9: the rotary axis with and without the paper's noise, table-4 mesh.
fn table9(st: &Study, tables: &mut Vec<Table>) -> Result<()> {
    let Study { m, truth, .. } = st;
    let noise = st.noise;
    let seed = st.seed;
    let fourier = rotary_model(m, "fourier")?;
    // Table 9: the rotary axis with and without the paper's noise, table-4 mesh.
    let truth9 = scaled_to(truth, &fourier, "table4", 227.0, seed)?;
    let with = st.run(
        &fourier,
        &measure(&truth9, "table4", noise, seed)?,
        ErrorScope::All,
        Phasing::One,
    )?;
    let without = st.run(
        &fourier,
        &measure(&truth9, "table4", TrackerNoise::NONE, seed)?,
        ErrorScope::All,
        Phasing::One,
    )?;
    tables.push(Table {
        title: "Table 9: rotary axis with and without noise, table-4 mesh, 1 phase".into(),
        rows: vec![
            row(
                "with the paper's noise",
                Some(figures(230.5, 407.2, 30.8, 65.7, 13.3)),
                &with,
            ),
            row(
                "without noise",
                Some(figures(227.0, 375.8, 16.6, 29.7, 7.36)),
                &without,
            ),
        ],
        noise: Some(((31.3, 57.8), noise_error(&truth9, "table4", noise, seed)?)),
        note: "With noise, our final EMM sits at the noise error, as the paper's (30.8 against \
               31.3 µm); without noise our first-harmonic model contains the truth and reaches \
               zero, where the paper's stopped at 7 % (its table 5's sine-series figure)."
            .into(),
    });
    Ok(())
}

/// Table 10: the linear axes with and without the paper's noise, table-7 mesh.
fn table10(
    st: &Study,
    tables: &mut Vec<Table>,
    (monomial, truth7, t7): &(Model, Truth, MeasurementSet),
) -> Result<()> {
    let noise = st.noise;
    let seed = st.seed;
    // Table 10: the linear axes with and without the paper's noise, table-7 mesh.
    let with = st.run(
        monomial,
        &measure(truth7, "table7", noise, seed)?,
        ErrorScope::All,
        Phasing::One,
    )?;
    let without = st.run(monomial, t7, ErrorScope::All, Phasing::One)?;
    tables.push(Table {
        title: "Table 10: linear axes with and without noise, table-7 mesh, monomial, 1 phase"
            .into(),
        rows: vec![
            row(
                "with the paper's noise",
                Some(figures(740.0, 2092.2, 51.2, 120.2, 6.9)),
                &with,
            ),
            row(
                "without noise",
                Some(figures(737.1, 2010.6, 6.6, 23.6, 0.9)),
                &without,
            ),
        ],
        noise: Some(((46.8, 104.8), noise_error(truth7, "table7", noise, seed)?)),
        note: "With noise, both final EMMs sit at their noise errors. Without noise, ours ends \
               at the C errors that act as constants at C = 0, which this model lacks (table 8's \
               note)."
            .into(),
    });
    Ok(())
}

/// Tables 11 and 12: the five tests with the paper's noise, and compensation of test 4 by each
/// method's errors. One truth for all, scaled on the reference test 4.
fn tables11_12(st: &Study, tables: &mut Vec<Table>) -> Result<()> {
    let full = Model::default_xcfz();
    let truth4 = scaled_to(&st.truth, &full, "test4", 628.69, st.seed)?;
    let sets: Vec<MeasurementSet> = ["test1", "test2", "test3", "test4", "test5"]
        .iter()
        .map(|p| measure(&truth4, p, st.noise, st.seed))
        .collect::<Result<_>>()?;
    let pr: Vec<Problem> = sets
        .iter()
        .map(|s| Problem::new(&full, s))
        .collect::<volver_core::Result<_>>()?;
    let t = five_tests(st, &pr, &full.initial_params());
    tables.push(table11(&t));
    tables.push(table12(st, &pr, &full.initial_params(), &t));
    Ok(())
}

/// The paper's strategy for tables 11 and 12: one phase, no gauge.
fn paper_strategy() -> Strategy {
    Strategy {
        gauge: false,
        ..Strategy::default()
    }
}

/// Tests 1–5 of section 6.2, each identified on its own data (`pr`, tests 1–5) from `p0`.
fn five_tests(st: &Study, pr: &[Problem], p0: &[f64]) -> [Identification; 5] {
    let strategy = paper_strategy();
    let p0 = p0.to_vec();
    let t1 = identify_errors(
        &st.lm,
        pr[0].clone(),
        &p0,
        ErrorScope::Linear,
        &strategy,
        &st.options,
        &mut Silent,
    );
    let t2 = identify_errors(
        &st.lm,
        pr[1].clone(),
        &p0,
        ErrorScope::Rotary,
        &strategy,
        &st.options,
        &mut Silent,
    );
    let t3 = identify_errors(
        &st.lm,
        pr[2].clone(),
        &p0,
        ErrorScope::All,
        &strategy,
        &st.options,
        &mut Silent,
    );
    let t4 = identify_errors(
        &st.lm,
        pr[3].clone(),
        &p0,
        ErrorScope::All,
        &strategy,
        &st.options,
        &mut Silent,
    );
    let (_, t5) = combined(
        &st.lm,
        pr[0].clone(),
        pr[4].clone(),
        &p0,
        &strategy,
        &st.options,
        &mut Silent,
    );
    [t1, t2, t3, t4, t5]
}

/// Table 11: the five tests' own fits.
fn table11(t: &[Identification; 5]) -> Table {
    Table {
        title: "Table 11: the tests of section 6.2, each identified on its own data, paper's noise"
            .into(),
        rows: vec![
            row(
                "test 1 (linear axes, XZ at C = 0)",
                Some(figures(582.48, 1654.03, 26.02, 87.59, 4.47)),
                &t[0],
            ),
            row(
                "test 2 (rotary axis, C only)",
                Some(figures(194.91, 213.46, 15.1, 65.06, 7.75)),
                &t[1],
            ),
            row(
                "test 3 (joint, coarse XZC mesh)",
                Some(figures(555.84, 1523.42, 51.76, 191.13, 9.31)),
                &t[2],
            ),
            row(
                "test 4 (joint, reference mesh)",
                Some(figures(628.69, 1893.27, 36.64, 104.81, 5.83)),
                &t[3],
            ),
            row(
                "test 5 (rotary on test 3, linear from test 1)",
                Some(figures(555.84, 1523.42, 30.24, 75.06, 5.44)),
                &t[4],
            ),
        ],
        noise: None,
        note: "Our final EMMs sit at each test's noise error (the bounded noise of tables 9–10), \
               as the paper's do. Tests 1–3 and 5 start from the one truth scaled on test 4: \
               their EMM₀ differ from the paper's as our random truth differs from its unknown \
               one; test 2's final EMM is the noise of a single position seen from 1.2 m."
            .into(),
    }
}

/// Table 12: the reference test 4 compensated by each method's errors.
fn table12(st: &Study, pr: &[Problem], p0: &[f64], t: &[Identification; 5]) -> Table {
    let p0 = p0.to_vec();
    let (ind, _, _) = independent(
        &st.lm,
        pr[0].clone(),
        pr[1].clone(),
        &p0,
        &paper_strategy(),
        &st.options,
        &mut Silent,
    );
    let cv =
        |params: &[f64]| cross_validate(&st.lm, pr[3].clone(), params, &st.options, &mut Silent);
    let i12 = |emm, emax, res| figures(628.69, 1893.27, emm, emax, res);
    Table {
        title: "Table 12: compensation of the reference test 4 by each method's errors".into(),
        rows: vec![
            row(
                "test 1",
                Some(i12(224.54, 662.32, 35.72)),
                &cv(&t[0].params),
            ),
            row(
                "test 2",
                Some(i12(58000.0, 141000.0, 9225.53)),
                &cv(&t[1].params),
            ),
            row(
                "tests 1 + 2 (independent)",
                Some(i12(58000.0, 141000.0, 9225.53)),
                &cv(&ind),
            ),
            row("test 3", Some(i12(69.04, 278.31, 10.98)), &cv(&t[2].params)),
            row("test 4", Some(i12(36.64, 104.81, 5.83)), &cv(&t[3].params)),
            row(
                "test 5 (combined)",
                Some(i12(43.41, 149.84, 6.90)),
                &cv(&t[4].params),
            ),
        ],
        noise: None,
        note: "As in the paper: the reference's own fit is best, then the combined method \
               (test 5) and the coarse joint test 3; the linear axes alone (test 1) compensate \
               little, and the rotary errors identified at X = Z = 0 alone (test 2, tests 1 + 2) \
               make the reference far worse than uncompensated: at one position their tilts \
               trade against the tracker pose and extrapolate wildly over X and Z."
            .into(),
    }
}

/// Table 12 as a bar chart: residual % on the reference per method, ours and the paper's side by
/// side. Bars are capped at 200 % (the rotary-only methods make the reference far worse); the
/// label then carries the true figure.
pub fn table12_svg(t: &Table) -> String {
    const CAP: f64 = 200.0;
    let mut data = Vec::new();
    for r in &t.rows {
        let label = r.label.split(" (").next().unwrap_or(&r.label).to_string();
        for (who, v) in [
            ("ours", Some(r.ours.residual_percent)),
            ("paper", r.paper.map(|p| p.residual_percent)),
        ] {
            if let Some(v) = v {
                let text = if v > CAP {
                    format!("{label} · {who} ({v:.0} %)")
                } else {
                    format!("{label} · {who}")
                };
                data.push((text, v.min(CAP)));
            }
        }
    }
    crate::plot::bars(
        "Table 12: residual on the reference test 4 after compensation (%, capped at 200)",
        "residual (%)",
        &data,
        None,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every run converges or stops within 1e-4 of Φ of a stationary point, and the claims of
    /// the notes hold on the figures. Three of the native LM's phased fits (Chebyshev 5 nodes
    /// with 1 phase, tests 3 and 4 joint) claimed convergence where the shared check measures a
    /// gain of 4.9e-6, 1.8e-5 and 1.1e-5: restarted with every tolerance at 0 the LM lowers Φ by
    /// 2.3e-5, 1.0e-5 and 4.2e-6 relative (and still does not reach a stationary point in 2000
    /// iterations): the check is right, the LM's Φ stage crawls there. The bound 1e-4 is five
    /// times the largest of these.
    #[test]
    fn the_papers_studies_converge_and_support_their_notes() {
        let tables = paper(1).unwrap();
        assert_eq!(tables.len(), 7);
        for t in &tables {
            for r in &t.rows {
                assert!(
                    r.converged || r.short_by.is_some_and(|g| g <= 1e-4),
                    "{}: {} did not converge: {}",
                    t.title,
                    r.label,
                    r.termination
                );
                assert!(r.ours.emm_um.is_finite() && r.ours.emm0_um > 0.0);
            }
        }
        // Each table's truth is scaled to the paper's initial EMM on its noise-free mesh, so
        // those rows start there by construction (`scaled_to`); what is checked is its second
        // pass, which takes out the initial EMM's nonlinearity in the scale (measured: within
        // 3e-8). Table 11's tests start from test 4's truth on their own meshes, and table 12
        // starts from the noisy reference: neither is scaled, so neither is compared.
        for t in &tables[..5] {
            for r in t
                .rows
                .iter()
                .filter(|r| !r.label.contains("with the paper's noise"))
            {
                let p = r.paper.expect("every row has the paper's figures");
                assert!(
                    (r.ours.emm0_um / p.emm0_um - 1.0).abs() < 1e-6,
                    "{}: {} starts at {} µm, scaled to the paper's {}",
                    t.title,
                    r.label,
                    r.ours.emm0_um,
                    p.emm0_um
                );
            }
        }
        // Table 12 compensates one reference with each method's errors: every row starts from
        // it (its tracker refitted from the same start), to the rounding.
        let start = tables[6].rows[0].ours.emm0_um;
        for r in &tables[6].rows {
            assert!((r.ours.emm0_um / start - 1.0).abs() < 1e-12, "{}", r.label);
        }
        // Tables 9–10: with noise the final EMM sits at the noise error (within 10 %), which is
        // the paper's within 15 %.
        for t in &tables[3..5] {
            let ((pe, _), (oe, _)) = t.noise.unwrap();
            assert!(
                (t.rows[0].ours.emm_um / oe - 1.0).abs() < 0.1,
                "{}",
                t.title
            );
            assert!((oe / pe - 1.0).abs() < 0.15, "{}: {oe} vs {pe}", t.title);
        }
        let fin = |t: usize, r: usize| tables[t].rows[r].ours.emm_um;
        // Table 5: Fourier and sine of one order reach the same (zero) error.
        assert!(fin(0, 0) < 1e-3 && fin(0, 1) < 1e-3);
        // Table 6: one phase is the best any phasing reaches.
        assert!(fin(1, 0) <= fin(1, 1) && fin(1, 0) <= fin(1, 2));
        // Table 8: monomial and Legendre of one degree reach the same Φ (the mean error module:
        // EMM / 1000) to 0.1 %, as its note says (measured 5e-14 on seed 1).
        assert!((fin(2, 0) / fin(2, 3) - 1.0).abs() < 1e-3);
        // Table 12: the reference's own fit is best, combined and test 3 next, test 2 diverges.
        let uncompensated = tables[6].rows[0].ours.emm0_um;
        assert!(fin(6, 4) <= fin(6, 5) && fin(6, 4) <= fin(6, 3));
        assert!(fin(6, 1) > uncompensated && fin(6, 0) < uncompensated);
    }
}
