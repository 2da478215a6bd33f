//! Every engine's "converged" can be trusted (issue 48): started far from the optimum of an L1
//! fit with outliers (Φ of a sphere fit to tracker points), each engine of the build either
//! reaches the optimum the exact engines agree on or reports that it stopped short; none says
//! converged at a point that is not stationary. The shared check ([`stationarity`]) runs after
//! every engine; ill-posed inputs come back as typed errors or flagged summaries.
//!
//! The sphere's residuals are written by hand here (exact Jacobian and second derivative, checked
//! against central differences below), so that the test depends on nothing of the model.
//!
//! [`stationarity`]: volver::solvers::stationarity

use std::borrow::Cow;
use volver::core::model::{Constraint, ConstraintKind, Constraints};
use volver::core::problem::Residuals;
use volver::solvers::{Invalid, Objective, Options, Silent, Stall, Task, Termination, engine};

/// A sphere `‖p − c‖ = R` fitted to points (mm): parameters `[cx, cy, cz, R]`, one scalar
/// residual per point, `‖p_i − c‖ − R`.
#[derive(Debug, Clone)]
struct Sphere {
    points: Vec<[f64; 3]>,
    constraints: Constraints,
}

impl Sphere {
    fn new(points: Vec<[f64; 3]>) -> Sphere {
        Sphere {
            points,
            constraints: Constraints::default(),
        }
    }

    fn offset(&self, i: usize, p: &[f64]) -> ([f64; 3], f64) {
        let d = [
            self.points[i][0] - p[0],
            self.points[i][1] - p[1],
            self.points[i][2] - p[2],
        ];
        (d, (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt())
    }
}

impl Residuals for Sphere {
    fn n_params(&self) -> usize {
        4
    }
    fn n_points(&self) -> usize {
        self.points.len()
    }
    fn param_names(&self) -> Vec<String> {
        ["cx", "cy", "cz", "R"].map(String::from).to_vec()
    }
    fn constraints(&self) -> Cow<'_, Constraints> {
        Cow::Borrowed(&self.constraints)
    }
    fn residual(&self, i: usize, p: &[f64]) -> [f64; 3] {
        [self.offset(i, p).1 - p[3], 0.0, 0.0]
    }
    fn residual_and_jacobian(&self, i: usize, p: &[f64], jac: &mut [f64]) -> [f64; 3] {
        let (d, l) = self.offset(i, p);
        jac.fill(0.0);
        for k in 0..3 {
            jac[k] = -d[k] / l;
        }
        jac[3] = -1.0;
        [l - p[3], 0.0, 0.0]
    }
    fn residual_second_directional(&self, i: usize, p: &[f64], dir: &[f64]) -> [f64; 3] {
        // d²/dt² ‖d − t·v‖ = (‖v‖² − (d̂·v)²) / ‖d‖ (R enters linearly).
        let (d, l) = self.offset(i, p);
        let v2 = dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2];
        let along = (d[0] * dir[0] + d[1] * dir[1] + d[2] * dir[2]) / l;
        [(v2 - along * along) / l, 0.0, 0.0]
    }
    fn observation_scale(&self, i: usize) -> f64 {
        self.points[i].iter().map(|v| v.abs()).fold(0.0, f64::max)
    }
    fn scalar(&self, _i: usize) -> bool {
        true
    }
}

/// A small deterministic generator (splitmix64), uniform in [0, 1).
struct Rng(u64);
impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f64 {
        let (u, v) = (self.uniform().max(1e-300), self.uniform());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// `n` points on a cap of a sphere (centre `c`, radius `r`, polar angle up to `cap` rad) with
/// 2 µm of noise along the normal and `outliers` of them pushed out by 0.5 … 3 mm.
fn sphere_points(seed: u64, c: [f64; 3], r: f64, cap: f64, n: usize, outliers: usize) -> Sphere {
    let mut rng = Rng(seed);
    let points = (0..n)
        .map(|i| {
            let theta = (1.0 - rng.uniform() * (1.0 - cap.cos())).acos();
            let phi = std::f64::consts::TAU * rng.uniform();
            let u = [
                theta.sin() * phi.cos(),
                theta.sin() * phi.sin(),
                theta.cos(),
            ];
            let out = if i < outliers {
                0.5 + 2.5 * rng.uniform()
            } else {
                0.0
            };
            let rr = r + 0.002 * rng.normal() + out;
            [c[0] + rr * u[0], c[1] + rr * u[1], c[2] + rr * u[2]]
        })
        .collect();
    Sphere::new(points)
}

/// The engines whose optimum is the reference: exact on Φ.
const EXACT: [&str; 3] = ["lm", "lm+clarabel", "clarabel"];

/// The agreement suite's tolerance of the exact engines on Φ (relative; tests/agreement.rs).
const AGREEMENT: f64 = 1e-6;

/// One engine's run: its name, the parameters and objective reached, its termination.
struct Run {
    name: String,
    params: Vec<f64>,
    cost: f64,
    termination: Termination,
}

/// Every engine of the build from `start`.
fn run_all(task: &Task, start: &[f64], options: &Options) -> Vec<Run> {
    volver::solvers::engine_names()
        .into_iter()
        .map(|name| {
            let s = engine(name).expect("an engine of the build").solve(
                task,
                start,
                options,
                &mut Silent,
            );
            Run {
                name: name.to_string(),
                cost: s.summary.final_cost(),
                params: s.params,
                termination: s.summary.termination,
            }
        })
        .collect()
}

/// How much lower the native LM gets when restarted from `params` (relative): a check of a
/// claimed minimum that holds for any truth, local minima included, and uses nothing of the
/// shared check.
fn restart_gain(task: &Task, params: &[f64], cost: f64, options: &Options) -> f64 {
    let again = engine("lm")
        .unwrap()
        .solve(task, params, options, &mut Silent)
        .summary
        .final_cost();
    (cost - again) / cost
}

/// No engine says converged where a restart of the native LM still gains more than the
/// agreement tolerance; the exact engines converge to one optimum (the cases have one basin
/// from their starts).
fn judge(case: &str, task: &Task, options: &Options, runs: &[Run]) {
    let best = runs
        .iter()
        .filter(|r| EXACT.contains(&r.name.as_str()))
        .map(|r| r.cost)
        .fold(f64::INFINITY, f64::min);
    for r in runs {
        let t = &r.termination;
        assert!(!t.failed(), "{case}: {} failed: {t}", r.name);
        let excess = (r.cost - best) / best;
        if t.converged() {
            let gain = restart_gain(task, &r.params, r.cost, options);
            assert!(
                gain <= AGREEMENT,
                "{case}: {} says \"{t}\" at {:.9e}, where the LM restarted gains {gain:.2e}",
                r.name,
                r.cost
            );
        }
        if EXACT.contains(&r.name.as_str()) {
            assert!(
                t.converged() && excess <= AGREEMENT,
                "{case}: the exact engine {} ended at {:.9e} ({excess:.2e} above the \
                 optimum): {t}",
                r.name,
                r.cost
            );
        }
        eprintln!("{case}: {:<14} {:.12e} ({excess:+.1e}) {t}", r.name, r.cost);
    }
}

#[test]
fn no_engine_says_converged_away_from_the_optimum_of_an_l1_sphere_fit() {
    // Shapes: a full sphere, a 60° and an 80° cap (a tracker sees one side); magnitudes: 50,
    // 400 and 25 mm radii, far from the origin; starts: 200 mm off with a 1 mm radius, and the
    // centroid with a radius 10 times too large. The exact engines agree on each (one basin);
    // from the first start of the third case they do not (two local minima 3e-3 apart): there
    // only the restart check applies.
    let cases = [
        (
            11,
            [100.0, -20.0, 300.0],
            50.0,
            std::f64::consts::PI,
            200,
            10,
        ),
        (
            12,
            [-800.0, 1500.0, 200.0],
            400.0,
            60f64.to_radians(),
            200,
            10,
        ),
        (13, [0.0, 0.0, 2000.0], 25.0, 80f64.to_radians(), 120, 6),
    ];
    for (seed, c, r, cap, n, out) in cases {
        let sphere = sphere_points(seed, c, r, cap, n, out);
        let task = Task::new(sphere.clone());
        let mean = (0..3)
            .map(|k| sphere.points.iter().map(|p| p[k]).sum::<f64>() / n as f64)
            .collect::<Vec<_>>();
        let starts = [
            vec![c[0] + 200.0, c[1] - 150.0, c[2] + 100.0, 1.0],
            vec![mean[0], mean[1], mean[2], 10.0 * r],
        ];
        for (k, start) in starts.iter().enumerate() {
            for objective in [Objective::Phi, Objective::Ve] {
                let options = Options {
                    objective,
                    ..Options::default()
                };
                let case = format!("seed {seed}, start {k}, {objective}");
                let runs = run_all(&task, start, &options);
                if seed == 13 && k == 0 {
                    judge_claims_only(&case, &task, &options, &runs);
                } else {
                    judge(&case, &task, &options, &runs);
                }
            }
        }
    }
}

/// [`judge`] without the agreement of the exact engines (a start between two minima).
fn judge_claims_only(case: &str, task: &Task, options: &Options, runs: &[Run]) {
    for r in runs.iter().filter(|r| r.termination.converged()) {
        let gain = restart_gain(task, &r.params, r.cost, options);
        assert!(
            gain <= AGREEMENT,
            "{case}: {} restarted gains {gain:.2e}",
            r.name
        );
    }
}

#[test]
fn a_claim_with_loose_tolerances_far_from_the_optimum_is_reported_as_stopped() {
    // A parameter tolerance of 0.5 lets every engine stop after its first steps: where the
    // point is not stationary the shared check must say so, whatever the engine.
    let sphere = sphere_points(21, [10.0, 20.0, 30.0], 40.0, 1.2, 150, 5);
    let task = Task::new(sphere);
    let options = Options {
        parameter_tolerance: 0.5,
        objective_tolerance: 0.5,
        ..Options::default()
    };
    let start = [150.0, -60.0, 90.0, 5.0];
    let reference = engine("lm")
        .unwrap()
        .solve(&task, &start, &Options::default(), &mut Silent)
        .summary
        .final_cost();
    let mut stopped = 0;
    for Run {
        name,
        cost,
        termination: t,
        ..
    } in run_all(&task, &start, &options)
    {
        let excess = (cost - reference) / reference;
        if t.converged() {
            assert!(excess <= AGREEMENT, "{name}: \"{t}\" at {excess:.2e} above");
        } else if let Termination::Stalled(Stall::NotStationary { measured, .. }) = &t {
            assert!(measured.gain > measured.tolerance || measured.above_start);
            let text = t.to_string();
            assert!(
                text.contains("not stationary") || text.contains("above its start"),
                "{t}"
            );
            stopped += 1;
        }
        eprintln!("{name:<14} {cost:.9e} ({excess:+.1e}) {t}");
    }
    assert!(
        stopped > 0,
        "no engine stopped early: the check was not exercised"
    );
}

#[test]
fn a_constraint_naming_a_missing_parameter_is_a_typed_error_for_every_engine() {
    let mut sphere = sphere_points(31, [0.0, 0.0, 0.0], 30.0, 2.0, 50, 0);
    sphere.constraints.rows.push(Constraint {
        kind: ConstraintKind::Fixed,
        label: "held by the user".into(),
        coeffs: vec![(7, 1.0)],
        rhs: 0.0,
    });
    let task = Task::new(sphere);
    for name in volver::solvers::engine_names() {
        let s = engine(name).unwrap().solve(
            &task,
            &[1.0, 1.0, 1.0, 20.0],
            &Options::default(),
            &mut Silent,
        );
        match &s.summary.termination {
            Termination::InvalidInput(Invalid::Constraints(e)) => {
                let text = e.to_string();
                assert!(
                    text.contains("parameter 7") && text.contains("4 parameters"),
                    "{name}: {text}"
                );
            }
            t => panic!("{name}: {t}"),
        }
    }
}

#[test]
fn fewer_observations_than_free_parameters_are_flagged_alike_by_every_engine() {
    // Two points, four parameters: a one-parameter family of spheres at least fits them exactly.
    let sphere = Sphere::new(vec![[10.0, 0.0, 0.0], [0.0, 10.0, 0.0]]);
    let task = Task::new(sphere);
    let mut seen = Vec::new();
    for name in volver::solvers::engine_names() {
        let s = engine(name).unwrap().solve(
            &task,
            &[1.0, 2.0, 3.0, 5.0],
            &Options::default(),
            &mut Silent,
        );
        let summary = &s.summary;
        assert_eq!(summary.observations, 2, "{name}");
        assert_eq!(summary.free_parameters, 4, "{name}");
        assert!(summary.underdetermined(), "{name}");
        assert!(
            summary.full_report().contains("fewer observations"),
            "{name}: {}",
            summary.full_report()
        );
        if summary.stationarity.is_some() {
            seen.push((name, summary.unidentifiable));
        }
    }
    // Rank 2 at most: the design of two scalar residuals leaves at least two directions.
    for (name, u) in &seen {
        assert!(*u >= 2, "{name}: {u} unidentifiable directions");
    }
    let first = seen.first().map(|s| s.1);
    assert!(seen.iter().all(|s| Some(s.1) == first), "{seen:?}");
}

#[test]
fn the_sphere_jacobian_and_curvature_match_central_differences() {
    let sphere = sphere_points(41, [5.0, -3.0, 12.0], 20.0, 1.0, 8, 1);
    let p = [4.0, -2.5, 11.0, 19.0];
    let dir = [0.3, -0.2, 0.5, 0.1];
    for i in 0..8 {
        let mut jac = [0.0; 12];
        sphere.residual_and_jacobian(i, &p, &mut jac);
        let h = 1e-6;
        for j in 0..4 {
            let (mut a, mut b) = (p, p);
            a[j] += h;
            b[j] -= h;
            let fd = (sphere.residual(i, &a)[0] - sphere.residual(i, &b)[0]) / (2.0 * h);
            assert!((fd - jac[j]).abs() < 1e-8, "point {i}, column {j}");
        }
        let at = |t: f64| {
            let q: Vec<f64> = p.iter().zip(&dir).map(|(x, d)| x + t * d).collect();
            sphere.residual(i, &q)[0]
        };
        let h = 1e-4;
        let fd2 = (at(h) - 2.0 * at(0.0) + at(-h)) / (h * h);
        let exact = sphere.residual_second_directional(i, &p, &dir)[0];
        assert!((fd2 - exact).abs() < 1e-5, "point {i}: {fd2} vs {exact}");
    }
}
