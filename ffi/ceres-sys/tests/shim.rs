//! The shim's features on problems with known answers: subset and linear parameter spaces, the
//! module loss (a geometric median), ε changes, the iteration callback, failures that must not
//! cross the C boundary, and the Rust-side validation that keeps glog's CHECKs from aborting.

use volver_ceres_sys::{
    Control, CostFunction, Iteration, LinearSolver, Loss, Options, Problem, Space, Termination,
};

/// Residual block i: x − a_i (2-D points a_i), Jacobian I. (Ceres' LM approaches even a linear
/// problem through damped steps: its answers are checked to 1e-6.)
struct Points(Vec<[f64; 2]>);

impl CostFunction for Points {
    fn evaluate(&self, b: usize, x: &[f64], r: &mut [f64], j: Option<&mut [f64]>) -> bool {
        r[0] = x[0] - self.0[b][0];
        r[1] = x[1] - self.0[b][1];
        if let Some(j) = j {
            j.copy_from_slice(&[1.0, 0.0, 0.0, 1.0]);
        }
        true
    }
}

fn tight() -> Options {
    Options {
        max_iterations: 200,
        function_tolerance: 1e-15,
        gradient_tolerance: 1e-16,
        parameter_tolerance: 1e-14,
        ..Options::default()
    }
}

fn no_callback(_: &Iteration, _: &[f64]) -> Control {
    Control::Continue
}

#[test]
fn least_squares_gives_the_mean_and_the_module_loss_the_geometric_median() {
    // Three points at the corners and one far away: the mean is pulled, the median is not.
    let pts = Points(vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [100.0, 100.0]]);
    let mut ls = Problem::new(&[5.0, 5.0], 4, 2, &pts, Loss::None).unwrap();
    let s = ls.solve(&tight(), &mut no_callback).unwrap();
    assert_eq!(s.termination, Termination::Convergence, "{}", s.message);
    let x = ls.params();
    assert!(
        (x[0] - 25.25).abs() < 1e-6 && (x[1] - 25.25).abs() < 1e-6,
        "{x:?}"
    );

    let mut med = Problem::new(&[5.0, 5.0], 4, 2, &pts, Loss::Module { epsilon: 1.0 }).unwrap();
    for eps in [1.0, 0.1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6] {
        med.set_loss_epsilon(eps).unwrap();
        med.solve(&tight(), &mut no_callback).unwrap();
    }
    // The geometric median of these four points: the sum of distances is minimal there.
    let x = med.params();
    let sum = |p: [f64; 2]| -> f64 {
        pts.0
            .iter()
            .map(|a| ((p[0] - a[0]).powi(2) + (p[1] - a[1]).powi(2)).sqrt())
            .sum()
    };
    let at = sum([x[0], x[1]]);
    for d in [[1e-3, 0.0], [0.0, 1e-3], [-1e-3, 0.0], [0.0, -1e-3]] {
        assert!(
            at <= sum([x[0] + d[0], x[1] + d[1]]) + 1e-9,
            "{x:?} is not the median"
        );
    }
    assert!(x[0] < 1.0 && x[1] < 1.0, "{x:?}");
}

#[test]
fn subset_and_linear_spaces_hold_what_they_should() {
    let pts = Points(vec![[3.0, 4.0]]);
    // Hold x1 at its start.
    let mut p = Problem::new(&[0.0, 7.0], 1, 2, &pts, Loss::None).unwrap();
    p.set_space(&Space::Subset(vec![1])).unwrap();
    p.solve(&tight(), &mut no_callback).unwrap();
    assert_eq!(p.params()[1], 7.0);
    assert!((p.params()[0] - 3.0).abs() < 1e-6, "{:?}", p.params());
    // Move only along (1, 1)/√2 from (0, 0): the nearest point to (3, 4) is (3.5, 3.5).
    let h = std::f64::consts::FRAC_1_SQRT_2;
    let mut q = Problem::new(&[0.0, 0.0], 1, 2, &pts, Loss::None).unwrap();
    q.set_space(&Space::Linear {
        basis: vec![h, h],
        columns: 1,
    })
    .unwrap();
    q.solve(&tight(), &mut no_callback).unwrap();
    let x = q.params();
    assert!(
        (x[0] - 3.5).abs() < 1e-6 && (x[1] - 3.5).abs() < 1e-6,
        "{x:?}"
    );
    // Every parameter held: nothing moves.
    let mut c = Problem::new(&[1.0, 2.0], 1, 2, &pts, Loss::None).unwrap();
    c.set_space(&Space::Constant).unwrap();
    c.solve(&tight(), &mut no_callback).unwrap();
    assert_eq!(c.params(), vec![1.0, 2.0]);
}

#[test]
fn bad_sizes_are_errors_not_aborts() {
    let pts = Points(vec![[3.0, 4.0]]);
    let mut p = Problem::new(&[0.0, 0.0], 1, 2, &pts, Loss::None).unwrap();
    assert!(p.set_space(&Space::Subset(vec![2])).is_err());
    assert!(p.set_space(&Space::Subset(vec![0, 0])).is_err());
    assert!(p.set_space(&Space::Subset(vec![0, 1])).is_err());
    assert!(
        p.set_space(&Space::Linear {
            basis: vec![1.0],
            columns: 1
        })
        .is_err()
    );
    assert!(p.set_params(&[1.0]).is_err());
    assert!(p.set_loss_epsilon(1.0).is_err(), "no loss to change");
    assert!(Problem::new(&[f64::NAN, 0.0], 1, 2, &pts, Loss::None).is_err());
    assert!(Problem::new(&[0.0, 0.0], 1, 2, &pts, Loss::Module { epsilon: 0.0 }).is_err());
    assert!(Problem::new(&[], 1, 2, &pts, Loss::None).is_err());
}

/// Panics on block 1 and fails (returns false) on block 2 when x0 > 10.
struct Faulty;

impl CostFunction for Faulty {
    fn evaluate(&self, b: usize, x: &[f64], r: &mut [f64], j: Option<&mut [f64]>) -> bool {
        if b == 1 && x[0] > 10.0 {
            panic!("a bug in a cost function");
        }
        r[0] = x[0] - 20.0;
        if let Some(j) = j {
            j[0] = 1.0;
        }
        true
    }
}

#[test]
fn a_panicking_cost_function_is_a_failed_evaluation_not_an_abort() {
    let mut p = Problem::new(&[0.0], 2, 1, &Faulty, Loss::None).unwrap();
    let s = p.solve(&tight(), &mut no_callback).unwrap();
    // Ceres never accepts a step past 10: every such evaluation failed.
    assert!(p.params()[0] <= 10.0, "{:?} {}", p.params(), s.message);
}

#[test]
fn the_callback_sees_every_iteration_and_can_stop_the_solve() {
    let pts = Points(vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [100.0, 100.0]]);
    let mut p = Problem::new(&[5.0, 5.0], 4, 2, &pts, Loss::Module { epsilon: 1e-3 }).unwrap();
    let mut seen = Vec::new();
    let s = p
        .solve(
            &Options {
                linear_solver: LinearSolver::DenseNormalCholesky,
                ..tight()
            },
            &mut |it, x| {
                seen.push((it.iteration, x.to_vec()));
                if it.iteration >= 2 {
                    Control::Stop
                } else {
                    Control::Continue
                }
            },
        )
        .unwrap();
    assert_eq!(s.termination, Termination::UserSuccess, "{}", s.message);
    assert_eq!(seen.iter().map(|s| s.0).collect::<Vec<_>>(), vec![0, 1, 2]);
    // The callback saw the parameter block after each iteration.
    assert_eq!(seen[2].1, p.params());
}
