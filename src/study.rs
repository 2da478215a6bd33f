//! `volver study paper`: the paper's studies (tables 5, 6, 8, 11, 12) rerun on synthetic data
//! from the generator, our figures beside the paper's.

use anyhow::Result;
use volver::core::machine::Machine;
use volver::core::measure::MeasurementSet;
use volver::core::model::{ErrorModelSpec, Model};
use volver::core::noise::TrackerNoise;
use volver::core::plan::Plan;
use volver::core::problem::Problem;
use volver::core::simulate::{Magnitudes, Simulation, Truth};
use volver::solvers::lm::LevenbergMarquardt;
use volver::solvers::strategy::{
    Errors, Identification, Phasing, Strategy, combined, cross_validate, identify_errors,
    independent,
};
use volver::solvers::{Options, Silent};

/// The study's true errors are the default magnitudes times this factor.
pub const MAGNITUDE_SCALE: f64 = 6.0;

/// One row: label, the paper's (initial EMM, final EMM, residual %) and ours.
pub struct Row {
    /// What was run.
    pub label: String,
    /// The paper's figures, when it gives them.
    pub paper: Option<(f64, f64, f64)>,
    /// Ours.
    pub ours: (f64, f64, f64),
    /// Whether our run converged.
    pub converged: bool,
}

/// One table.
pub struct Table {
    /// Title.
    pub title: String,
    /// Rows.
    pub rows: Vec<Row>,
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

fn row(label: &str, paper: Option<(f64, f64, f64)>, id: &Identification) -> Row {
    Row {
        label: label.to_string(),
        paper,
        ours: (
            id.initial.stats.emm_um,
            id.final_.stats.emm_um,
            id.residual_percent(),
        ),
        converged: id.termination.converged(),
    }
}

/// Runs the five studies with true errors drawn from `seed`.
pub fn paper(seed: u64) -> Result<Vec<Table>> {
    let m = Machine::default_xcfz();
    // The paper's uncompensated reference test is 629 µm (table 12); our default magnitudes
    // give about 100 µm, so the study scales them by MAGNITUDE_SCALE.
    let magnitudes = Magnitudes {
        tracker_mm: 0.0,
        ..Magnitudes::default().scaled(MAGNITUDE_SCALE)
    };
    let truth = Truth::random(&m, &ErrorModelSpec::complete(&m), &magnitudes, seed)?;
    let data = |plan: &str, noise: TrackerNoise| -> Result<MeasurementSet> {
        let mut sim = Simulation::new(Plan::preset(&m, plan)?, truth.clone(), seed);
        sim.noise = noise;
        Ok(sim.run()?.measurements)
    };
    // 1000 iterations: the noise-free Chebyshev-5 fit of table 8 (a quartic against cubic truths
    // plus constants the model lacks) creeps past 200 before its parameter change settles.
    let options = Options {
        max_iterations: 1000,
        ..Options::default()
    };
    let lm = LevenbergMarquardt;
    let run = |model: &Model, set: &MeasurementSet, errors, phasing| -> Result<Identification> {
        let problem = Problem::new(model, set)?;
        let strategy = Strategy {
            phasing,
            ..Strategy::default()
        };
        Ok(identify_errors(
            &lm,
            problem,
            &model.initial_params(),
            errors,
            &strategy,
            &options,
            &mut Silent,
        ))
    };
    let mut tables = Vec::new();

    // Table 5: Fourier against sine series on the table-4 mesh.
    let t4 = data("table4", TrackerNoise::NONE)?;
    let fourier = model(&m, &format!("{ROTARY}basis = \"fourier\"\norder = 1\n"))?;
    let sine = model(&m, &format!("{ROTARY}basis = \"sine\"\norder = 1\n"))?;
    let f = run(&fourier, &t4, Errors::All, Phasing::One)?;
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
        &lm,
        Problem::new(&sine, &t4)?,
        &start,
        Errors::All,
        &Strategy {
            init_tracker: false,
            ..Strategy::default()
        },
        &options,
        &mut Silent,
    );
    let mut s_row = row(
        "sine series (first harmonic)",
        Some((181.15, 16.58, 9.15)),
        &s,
    );
    s_row.ours.0 = f.initial.stats.emm_um;
    s_row.ours.2 = 100.0 * s.final_.stats.emm_um / f.initial.stats.emm_um;
    tables.push(Table {
        title: "Table 5: Fourier against sine series, rotary axis, table-4 mesh, no noise".into(),
        rows: vec![
            row(
                "Fourier series (first harmonic)",
                Some((181.15, 93.28, 51.49)),
                &f,
            ),
            s_row,
        ],
        note: "Both series of the same order span the same functions, so a converged fit reaches \
               the same Φ with either; the paper's 51 % for Fourier is an artefact (the harmonic \
               index missing from its eq. 20, see the project notes) and of an optimiser that \
               stopped early."
            .into(),
    });

    // Table 6: one phase against TR and RT, rotary axis.
    let mut rows = Vec::new();
    for (label, phasing, paper) in [
        ("1 phase", Phasing::One, (194.9, 112.6, 57.7)),
        ("2 phases TR", Phasing::Tr, (194.9, 15.1, 7.8)),
        ("2 phases RT", Phasing::Rt, (194.9, 18.7, 9.6)),
    ] {
        rows.push(row(
            label,
            Some(paper),
            &run(&fourier, &t4, Errors::All, phasing)?,
        ));
    }
    tables.push(Table {
        title: "Table 6: rotary axis by phases, table-4 mesh, no noise (paper's second test)"
            .into(),
        rows,
        note: "A converged one-phase fit is the best any phasing can reach (phases only hold \
               parameters); the paper's one-phase run stopped on its criteria at 58 %. Phased \
               runs end higher because a group held at zero is absorbed by the others."
            .into(),
    });

    // Table 8: linear axes on the table-7 mesh, three bases, three phasings.
    let t7 = data("table7", TrackerNoise::NONE)?;
    let mut rows = Vec::new();
    let paper8 = [
        (
            "monomial",
            "basis = \"monomial\"\ndegree = 3\n",
            [(737.1, 6.6, 0.9), (737.1, 19.9, 2.7), (737.1, 39.6, 5.4)],
        ),
        (
            "Legendre",
            "basis = \"legendre\"\ndegree = 3\n",
            [
                (737.1, 3.6, 0.5),
                (737.1, 75.18, 10.2),
                (737.1, 123.8, 16.8),
            ],
        ),
        (
            "Chebyshev 5 nodes",
            "basis = \"chebyshev\"\nnodes = 5\n",
            [(737.1, 4.4, 0.1), (737.1, 57.1, 7.7), (737.1, 8.4, 1.2)],
        ),
    ];
    for (name, basis, paper) in paper8 {
        let lin = model(
            &m,
            &format!("{LINEAR}{basis}[[error]]\nname = [\"A0Z\", \"B0Z\"]\n"),
        )?;
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
                &run(&lin, &t7, Errors::All, phasing)?,
            ));
        }
    }
    tables.push(Table {
        title: "Table 8: linear axes X, Z by basis and phases, table-7 mesh, no noise".into(),
        rows,
        note: "Our true errors are cubics and the C errors at C = 0 act as constants that this \
               model lacks, so the one-phase fits end at the effect of those constants; the \
               paper's true errors are unknown. Monomial and Legendre of one degree span the same \
               functions and reach the same Φ to 0.1 % here (to 1e-13 when the model contains \
               the truth; the rest is nearly redundant directions held as unidentifiable, which \
               depend on the parametrisation), where the paper has 0.9 % against 0.5 %; \
               Chebyshev with 5 nodes is a quartic."
            .into(),
    });

    // Tables 11 and 12: the five tests with the paper's noise, and compensation of test 4.
    let noise = TrackerNoise::PAPER;
    let sets: Vec<MeasurementSet> = ["test1", "test2", "test3", "test4", "test5"]
        .iter()
        .map(|p| data(p, noise))
        .collect::<Result<_>>()?;
    let full = Model::default_xcfz();
    let p0 = full.initial_params();
    let st = Strategy::default();
    let pr: Vec<Problem> = sets
        .iter()
        .map(|s| Problem::new(&full, s))
        .collect::<volver::core::Result<_>>()?;
    let t1 = identify_errors(&lm, pr[0], &p0, Errors::Linear, &st, &options, &mut Silent);
    let t2 = identify_errors(&lm, pr[1], &p0, Errors::Rotary, &st, &options, &mut Silent);
    let t3 = identify_errors(&lm, pr[2], &p0, Errors::All, &st, &options, &mut Silent);
    let t4 = identify_errors(&lm, pr[3], &p0, Errors::All, &st, &options, &mut Silent);
    let (_, t5) = combined(&lm, pr[0], pr[4], &p0, &st, &options, &mut Silent);
    tables.push(Table {
        title: "Table 11: the tests of section 6.2, each identified on its own data, paper's noise"
            .into(),
        rows: vec![
            row(
                "test 1 (linear axes, XZ at C = 0)",
                Some((582.48, 26.02, 4.47)),
                &t1,
            ),
            row(
                "test 2 (rotary axis, C only)",
                Some((194.91, 15.1, 7.75)),
                &t2,
            ),
            row(
                "test 3 (joint, coarse XZC mesh)",
                Some((555.84, 51.76, 9.31)),
                &t3,
            ),
            row(
                "test 4 (joint, reference mesh)",
                Some((628.69, 36.64, 5.83)),
                &t4,
            ),
            row(
                "test 5 (rotary on test 3, linear from test 1)",
                Some((555.84, 30.24, 5.44)),
                &t5,
            ),
        ],
        note:
            "Our final EMM sits at the noise error (about 80 µm with the paper's σ at 1.6–2.2 m), \
               which bounds the residual from below; the paper's noise error is 31–47 µm \
               (tables 9–10), hence its smaller percentages."
                .into(),
    });
    let (ind, _, _) = independent(&lm, pr[0], pr[1], &p0, &st, &options, &mut Silent);
    let cv = |params: &[f64]| cross_validate(&lm, pr[3], params, &options, &mut Silent);
    tables.push(Table {
        title: "Table 12: compensation of the reference test 4 by each method's errors".into(),
        rows: vec![
            row("test 1", Some((628.69, 224.54, 35.72)), &cv(&t1.params)),
            row("test 2", Some((628.69, 58000.0, 9225.53)), &cv(&t2.params)),
            row(
                "tests 1 + 2 (independent)",
                Some((628.69, 58000.0, 9225.53)),
                &cv(&ind),
            ),
            row("test 3", Some((628.69, 69.04, 10.98)), &cv(&t3.params)),
            row("test 4", Some((628.69, 36.64, 5.83)), &cv(&t4.params)),
            row(
                "test 5 (combined)",
                Some((628.69, 43.41, 6.90)),
                &cv(&t5.params),
            ),
        ],
        note: "As in the paper: the reference's own fit is best, then the combined method \
               (test 5) and the coarse joint test 3; the linear axes alone (test 1) compensate \
               little, and the rotary errors identified at X = Z = 0 alone (test 2, tests 1 + 2) \
               make the reference far worse than uncompensated: at one position their tilts \
               trade against the tracker pose and extrapolate wildly over X and Z."
            .into(),
    });
    Ok(tables)
}

/// Table 12 as a bar chart: residual % on the reference per method, ours and the paper's side by
/// side. Bars are capped at 200 % (the rotary-only methods make the reference far worse); the
/// label then carries the true figure.
pub fn table12_svg(t: &Table) -> String {
    const CAP: f64 = 200.0;
    let mut data = Vec::new();
    for r in &t.rows {
        let label = r.label.split(" (").next().unwrap_or(&r.label).to_string();
        for (who, v) in [("ours", Some(r.ours.2)), ("paper", r.paper.map(|p| p.2))] {
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

/// Prints the tables.
pub fn print(tables: &[Table]) {
    for t in tables {
        println!("\n{}", t.title);
        println!(
            "  {:<46} {:>28}   {:>30}",
            "", "paper: EMM₀ → EMM µm (res.)", "volver: EMM₀ → EMM µm (res.)"
        );
        for r in &t.rows {
            let paper = r.paper.map_or("—".to_string(), |(a, b, c)| {
                format!("{a:>8.2} → {b:>8.2} ({c:>6.2} %)")
            });
            let (a, b, c) = r.ours;
            println!(
                "  {:<46} {:>28}   {:>8.2} → {:>9.4} ({:>7.3} %){}",
                r.label,
                paper,
                a,
                b,
                c,
                if r.converged { "" } else { " *" }
            );
        }
        println!("  note: {}", t.note);
    }
    println!("\n  * stopped by a limit, not converged");
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every run converges, and the claims of the notes hold on the figures.
    #[test]
    fn the_papers_studies_converge_and_support_their_notes() {
        let tables = paper(1).unwrap();
        assert_eq!(tables.len(), 5);
        for t in &tables {
            for r in &t.rows {
                assert!(r.converged, "{}: {} did not converge", t.title, r.label);
                assert!(r.ours.1.is_finite() && r.ours.0 > 0.0);
            }
        }
        let fin = |t: usize, r: usize| tables[t].rows[r].ours.1;
        // Table 5: Fourier and sine of one order reach the same (zero) error.
        assert!(fin(0, 0) < 1e-3 && fin(0, 1) < 1e-3);
        // Table 6: one phase is the best any phasing reaches.
        assert!(fin(1, 0) <= fin(1, 1) && fin(1, 0) <= fin(1, 2));
        // Table 8: monomial and Legendre of one degree reach the same Φ.
        assert!((fin(2, 0) / fin(2, 3) - 1.0).abs() < 1e-2);
        // Table 12: the reference's own fit is best, combined and test 3 next, test 2 diverges.
        let uncompensated = tables[4].rows[0].ours.0;
        assert!(fin(4, 4) <= fin(4, 5) && fin(4, 4) <= fin(4, 3));
        assert!(fin(4, 1) > uncompensated && fin(4, 0) < uncompensated);
    }
}
