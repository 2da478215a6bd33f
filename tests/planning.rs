//! `volver plan`: the plan is what the machine runs (plan file → simulate, G-code → the poses it
//! moves through), the design is optimal for its criterion, and on simulated truths the planned
//! test beats test 4 with an honest U and finds a hidden drift.

mod common;

use common::volver;
use volver::core::machine::Machine;
use volver::core::model::Model;
use volver::core::noise::TrackerNoise;
use volver::core::plan::{Plan, file};
use volver::planning::{Request, candidate_grid, compare, plan};
use volver::solvers::design::{Criterion, Space};

/// A small plan: 5 candidates per axis, 240 points.
fn small(criterion: Criterion, seed: u64) -> volver::planning::Planned {
    let model = Model::default_xcfz();
    let request = Request {
        points: 240,
        criterion,
        per_axis: 5,
        repeats: 3,
        seed,
        iterations: 150,
        tool: volver::compensation::reflector_centroid(&model),
        ..Request::default()
    };
    plan(&model, &request).unwrap()
}

/// Rows of a plan file read independently of the reader: (axis values, reflector id).
fn rows(text: &str) -> Vec<(Vec<f64>, String)> {
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (
                f[1..4].iter().map(|v| v.parse().unwrap()).collect(),
                f[4].to_string(),
            )
        })
        .collect()
}

#[test]
fn the_plan_file_and_the_program_are_what_simulate_and_the_machine_run() {
    let m = Machine::default_xcfz();
    let planned = small(Criterion::I, 3);
    let r = &planned.report;
    assert_eq!(r.points, 240);
    assert_eq!(planned.plan.n_points(), 240);
    assert_eq!(r.reference_visits, 5);
    assert!(
        r.aliasing.0 < 0.15,
        "time aliases onto {}: {}",
        r.aliasing.1,
        r.aliasing.0
    );
    let dir = std::env::temp_dir().join(format!("volver-plan-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let csv = dir.join("plan.csv");
    let text = file::to_csv(&planned.plan, &m, "test");
    std::fs::write(&csv, &text).unwrap();
    let want = rows(&text);
    assert_eq!(want.len(), 240);
    // simulate measures the rows in the file's order.
    let out = dir.join("sim");
    let o = volver(&[
        "simulate",
        "--plan-file",
        csv.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--noise",
        "none",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let measured = std::fs::read_to_string(out.join("measurements.csv")).unwrap();
    let got: Vec<(Vec<f64>, String)> = measured
        .lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (
                f[0..3].iter().map(|v| v.parse().unwrap()).collect(),
                f[3].to_string(),
            )
        })
        .collect();
    assert_eq!(got.len(), want.len());
    for (i, (g, w)) in got.iter().zip(&want).enumerate() {
        assert_eq!(g.1, w.1, "row {i}: reflector");
        for k in 0..3 {
            assert!(
                (g.0[k] - w.0[k]).abs() < 1e-6,
                "row {i}: {:?} against {:?}",
                g.0,
                w.0
            );
        }
    }
    // The measuring program names the file's rows in order, a wait per run of rows at one pose,
    // each of 1.5 s per reflector (tests/measuring_program.rs runs it through LinuxCNC's
    // interpreter: moves, clearance, dwells).
    let mut options = file::ProgramOptions::new(&m);
    options.seconds_per_point = 1.5;
    let nc = file::gcode(&planned.plan, &m, &options, "test").unwrap();
    let mut named: Vec<String> = Vec::new();
    for l in nc.lines().filter(|l| l.starts_with("G4 P")) {
        let (p, comment) = l["G4 P".len()..].split_once(' ').unwrap();
        let ids = comment
            .split("measure ")
            .nth(1)
            .unwrap()
            .split(',')
            .next()
            .unwrap();
        let ids: Vec<&str> = ids.split(' ').collect();
        assert_eq!(p.parse::<f64>().unwrap(), 1.5 * ids.len() as f64, "{l}");
        named.extend(ids.iter().map(|s| s.to_string()));
    }
    let rows: Vec<String> = want.iter().map(|w| w.1.clone()).collect();
    assert_eq!(named, rows);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_design_is_optimal_for_its_criterion() {
    let m = Machine::default_xcfz();
    let model = Model::default_xcfz();
    let candidates = candidate_grid(&m, 5).unwrap();
    let grid = volver::uncertainty::default_grid(&m, 4).unwrap();
    let tool = volver::compensation::reflector_centroid(&model);
    let space = Space::new(
        &model,
        &candidates,
        &TrackerNoise::PAPER,
        tool,
        &grid.positions,
    )
    .unwrap();
    let n = space.len();
    let points = 300;
    for criterion in [Criterion::I, Criterion::V, Criterion::D] {
        let d = space.design(points, criterion, 400).unwrap();
        assert_eq!(d.counts.iter().sum::<usize>(), points);
        assert!(
            d.equivalence < 1.05,
            "{criterion:?}: equivalence {}",
            d.equivalence
        );
        let weights: f64 = d.weights.iter().sum();
        assert!((weights - 1.0).abs() < 1e-9);
        // Better than spreading the points evenly over the candidates, and than 20 random
        // designs of the same size (any optimum must be).
        let better = |other: &[f64]| {
            let v = space.value(other, criterion).unwrap();
            match criterion {
                Criterion::I | Criterion::V => d.value <= v * 1.001,
                Criterion::D => d.value >= v - 1e-3,
                c => panic!("criterion {c:?} is not in this test"),
            }
        };
        let even = vec![points as f64 / n as f64; n];
        assert!(better(&even), "{criterion:?}: worse than even");
        let mut rng = volver::core::random::Rng::new(5);
        for _ in 0..20 {
            let mut c = vec![0.0; n];
            for _ in 0..points {
                c[((rng.uniform() * n as f64) as usize).min(n - 1)] += 1.0;
            }
            assert!(better(&c), "{criterion:?}: worse than a random design");
        }
        // The V-design's worst variance is no larger than the I-design's.
        if criterion == Criterion::V {
            let i = space.design(points, Criterion::I, 400).unwrap();
            let ci: Vec<f64> = i.counts.iter().map(|&k| k as f64).collect();
            assert!(better(&ci), "V: worse than the I-design at its worst point");
        }
    }
}

#[test]
fn what_two_reflectors_cannot_identify_is_named_and_a_third_identifies_it() {
    let two = small(Criterion::I, 1);
    // Two reflectors cannot see the tool side turn about their line: the candidates leave it,
    // and the advice names positions off the line that identify more.
    assert!(!two.report.unidentifiable_by_candidates.is_empty());
    let best = two.report.reflector_advice.first().expect("advice");
    assert!(best.unidentified < two.report.unidentifiable_by_candidates.len());
    assert_eq!(two.model.machine().reflectors().len(), 2);
    // With a candidate at the advised position the candidates leave as few as advised.
    let model = Model::default_xcfz();
    let request = Request {
        points: 240,
        per_axis: 5,
        repeats: 3,
        iterations: 150,
        tool: best.offset_mm,
        extra_reflectors: vec![volver::core::machine::ReflectorSpec {
            id: "R3".into(),
            offset: best.offset_mm,
        }],
        ..Request::default()
    };
    let three = plan(&model, &request).unwrap();
    assert_eq!(
        three.report.unidentifiable_by_candidates.len(),
        best.unidentified
    );
    // A plan that measures R3 carries a machine with it, and its steps name it there.
    let m = three.model.machine();
    let r3 = m.reflector_index("R3").expect("the plan's machine has R3");
    assert!(three.plan.steps().iter().any(|s| s.reflector == r3));
    // For a tool at that position, the plan with R3 promises a smaller U than one without.
    let without = plan(
        &model,
        &Request {
            extra_reflectors: Vec::new(),
            ..request.clone()
        },
    )
    .unwrap();
    assert!(
        three.report.u95_mean_um < without.report.u95_mean_um,
        "{} µm with R3, {} µm without",
        three.report.u95_mean_um,
        without.report.u95_mean_um
    );
    let dup = Request {
        extra_reflectors: vec![volver::core::machine::ReflectorSpec {
            id: "R1".into(),
            offset: [0.0; 3],
        }],
        ..request
    };
    let e = plan(&model, &dup).unwrap_err().to_string();
    assert!(e.contains("'R1'"), "{e}");
}

#[test]
fn a_plan_without_noise_or_points_is_refused() {
    let model = Model::default_xcfz();
    let none = Request {
        noise: TrackerNoise::NONE,
        ..Request::default()
    };
    let e = plan(&model, &none).unwrap_err().to_string();
    assert!(e.contains("noise"), "{e}");
    let few = Request {
        points: 10,
        per_axis: 4,
        ..Request::default()
    };
    let e = plan(&model, &few).unwrap_err().to_string();
    assert!(e.contains("reference pose"), "{e}");
    let many = Request {
        per_axis: 60,
        ..Request::default()
    };
    let e = plan(&model, &many).unwrap_err().to_string();
    assert!(
        e.contains("candidate points") && e.contains("--per-axis"),
        "{e}"
    );
    let o = volver(&["plan", "--dwell-s=-1", "--out", "x.csv"]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--dwell-s -1"));
    let o = volver(&["plan", "--criterion", "q", "--out", "x.csv"]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("unknown design criterion 'q'"));
}

/// A 250 mm tool below the reflectors (off the R1–R2 line, about which test 4 cannot see the
/// tool side turn) with a candidate reflector position at the tool: 20 truths each for test 4
/// (R1, R2) and the planned test of the same size (fixed seeds, the paper's noise). The planned
/// test's realised tool-point error after the set-up's transform is at most half of test 4's,
/// the predicted U covers the realised deviations in 90–99 % of the grid's coordinates for both,
/// and a drift of issue 5's size hidden in the planned sequence is the diagnosis' finding in at
/// least 18 of 20.
#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "release only: cargo test --release --test planning"
)]
fn the_planned_test_halves_test_4s_tool_point_error_with_an_honest_u_and_finds_drift() {
    let (tool, planned) = common::planned_for_a_250_mm_tool();
    assert_eq!(planned.plan.n_points(), 1040);
    let m = planned.model.machine();
    assert_eq!(
        m.reflectors().len(),
        3,
        "the plan uses the candidate reflector"
    );
    let mut test4 = Plan::preset(m, "test4").unwrap();
    test4.reflectors = vec![0, 1];
    let rows = compare(
        &planned.model,
        &[
            ("test4".to_string(), test4),
            ("planned".to_string(), planned.plan),
        ],
        20,
        &TrackerNoise::PAPER,
        tool,
        Some("thermal-drift=10,-5,60"),
    )
    .unwrap();
    for r in &rows {
        eprintln!(
            "{}: U mean {:.2} µm, realised {:.2} µm, coverage {:.3}, drift {} of {}",
            r.label, r.u95_mean_um, r.realised_emm_um, r.coverage, r.drift_found, r.drift_runs
        );
        assert!(
            (0.90..=0.99).contains(&r.coverage),
            "{}: coverage {}",
            r.label,
            r.coverage
        );
    }
    assert!(
        rows[1].realised_emm_um <= 0.5 * rows[0].realised_emm_um,
        "planned {} µm against test 4's {} µm",
        rows[1].realised_emm_um,
        rows[0].realised_emm_um
    );
    assert!(rows[1].drift_found >= 18, "{} of 20", rows[1].drift_found);
}
