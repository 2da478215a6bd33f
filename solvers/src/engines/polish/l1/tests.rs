//! The L1 finish on problems whose optima are known: small linear L1 regressions against the
//! enumeration of every vertex, degenerate ones (rows repeated, an exact fit), the median of a
//! location problem, and a nonlinear curve whose optimum is checked by its first-order
//! conditions.

use super::*;
use crate::Task;
use crate::engines::test_problems::Location;
use crate::options::Objective;
use std::borrow::Cow;
use volver_core::model::Constraints;
use volver_core::random::Rng;

/// Σ |r_i + a_i·δ|.
fn l1_at(a: &[f64], r: &[f64], delta: &[f64]) -> f64 {
    let m = delta.len();
    (0..r.len())
        .map(|i| (r[i] + dot(&a[i * m..(i + 1) * m], delta)).abs())
        .sum()
}

/// `A_B δ = −r_B` by Gaussian elimination with partial pivoting; `None` when singular.
fn basic_step(a: &[f64], r: &[f64], rows: &[usize]) -> Option<Vec<f64>> {
    let m = rows.len();
    let mut e: Vec<Vec<f64>> = rows
        .iter()
        .map(|&i| {
            let mut row = a[i * m..(i + 1) * m].to_vec();
            row.push(-r[i]);
            row
        })
        .collect();
    for c in 0..m {
        let pivot = (c..m).max_by(|&x, &y| e[x][c].abs().total_cmp(&e[y][c].abs()))?;
        if e[pivot][c].abs() < 1e-12 {
            return None;
        }
        e.swap(c, pivot);
        let top = e[c].clone();
        for row in e.iter_mut().skip(c + 1) {
            let f = row[c] / top[c];
            for (x, y) in row[c..].iter_mut().zip(&top[c..]) {
                *x -= f * y;
            }
        }
    }
    let mut delta = vec![0.0; m];
    for c in (0..m).rev() {
        let known: f64 = (c + 1..m).map(|j| e[c][j] * delta[j]).sum();
        delta[c] = (e[c][m] - known) / e[c][c];
    }
    Some(delta)
}

/// The best vertex by enumeration of every basis of m rows.
fn enumerated(a: &[f64], r: &[f64], m: usize) -> f64 {
    fn bases(n: usize, rows: &mut Vec<usize>, m: usize, visit: &mut dyn FnMut(&[usize])) {
        if rows.len() == m {
            visit(rows);
            return;
        }
        for i in rows.last().map_or(0, |l| l + 1)..n {
            rows.push(i);
            bases(n, rows, m, visit);
            rows.pop();
        }
    }
    let mut best = f64::INFINITY;
    bases(r.len(), &mut Vec::new(), m, &mut |rows| {
        if let Some(delta) = basic_step(a, r, rows) {
            best = best.min(l1_at(a, r, &delta));
        }
    });
    best
}

#[test]
fn small_regressions_reach_the_best_vertex() {
    for seed in 0..40 {
        let mut rng = Rng::new(seed);
        let m = 1 + (seed as usize % 3);
        let n = 5 + (seed as usize % 7);
        let a: Vec<f64> = (0..n * m).map(|_| rng.normal()).collect();
        let r: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
        let mut basis = first_basis(&a, &r, m).expect("random rows span");
        let lp = vertex(&a, &r, &mut basis).expect("a bounded programme");
        let reached = l1_at(&a, &r, &lp.delta);
        let best = enumerated(&a, &r, m);
        assert!(
            (reached - best).abs() <= 1e-12 * best.max(1.0),
            "seed {seed}: {reached} against the best vertex's {best}"
        );
        // Its basic rows are interpolated, and ρ is the linearised residual there.
        for &i in basis.iter() {
            assert!((r[i] + dot(&a[i * m..(i + 1) * m], &lp.delta)).abs() < 1e-12);
        }
    }
}

#[test]
fn repeated_rows_and_exact_fits_do_not_cycle() {
    // A line through every point, each point twice, and a third copy of one row moved off it:
    // the optimum interpolates the line (an exact fit but for that copy).
    let xs = [0.0, 1.0, 2.0, 3.0, 4.0];
    let mut a = Vec::new();
    let mut r = Vec::new();
    for &x in &xs {
        for _ in 0..2 {
            a.extend([1.0, x]);
            // Residual at δ = 0 of the line 1 + 2x against a start at zero.
            r.push(-(1.0 + 2.0 * x));
        }
    }
    a.extend([1.0, 2.0]);
    r.push(-4.0);
    let mut basis = first_basis(&a, &r, 2).unwrap();
    let lp = vertex(&a, &r, &mut basis).expect("no cycle");
    assert!(
        (lp.delta[0] - 1.0).abs() < 1e-12 && (lp.delta[1] - 2.0).abs() < 1e-12,
        "{lp:?}"
    );
    assert!((l1_at(&a, &r, &lp.delta) - 1.0).abs() < 1e-12);
    // The median of values each repeated, from a basis at one copy of the wrong one.
    let y = [3.0, 3.0, 0.0, 10.0, 11.0, 0.0, 3.0];
    let r: Vec<f64> = y.iter().map(|v| -v).collect();
    let a = vec![1.0; y.len()];
    let mut basis = vec![2];
    let lp = vertex(&a, &r, &mut basis).expect("no cycle");
    assert_eq!(lp.delta, vec![3.0]);
}

#[test]
fn the_median_exactly_from_afar() {
    let y = [1.0, 2.0, 4.0, 5.0, 100.0];
    let task = Task::new(Location {
        y: y.to_vec(),
        scalar: true,
    });
    // Smoothed Newton steps cannot leave 4.3 (the points' test of the Newton polish); the
    // linear programme goes to the median at once.
    let (p, report) = crate::engines::polish::settle(&task, &[4.3], Objective::Phi, 1e-9)
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(p, vec![4.0], "{report:?}");
    assert_eq!(report.stop, SettleStop::Vertex, "{report:?}");
    assert_eq!(report.steps, 1, "{report:?}");
}

/// `r_i = b₁ exp(b₂ x_i) − y_i`, one scalar per point.
#[derive(Debug)]
struct Exponential {
    x: Vec<f64>,
    y: Vec<f64>,
}

impl Residuals for Exponential {
    fn n_params(&self) -> usize {
        2
    }
    fn n_points(&self) -> usize {
        self.x.len()
    }
    fn param_names(&self) -> Vec<String> {
        vec!["b1".into(), "b2".into()]
    }
    fn constraints(&self) -> Cow<'_, Constraints> {
        Cow::Owned(Constraints::default())
    }
    fn residual(&self, i: usize, p: &[f64]) -> [f64; 3] {
        [p[0] * (p[1] * self.x[i]).exp() - self.y[i], 0.0, 0.0]
    }
    fn residual_and_jacobian(&self, i: usize, p: &[f64], jac: &mut [f64]) -> [f64; 3] {
        let e = (p[1] * self.x[i]).exp();
        jac.fill(0.0);
        jac[0] = e;
        jac[1] = p[0] * self.x[i] * e;
        self.residual(i, p)
    }
    fn residual_second_directional(&self, i: usize, p: &[f64], d: &[f64]) -> [f64; 3] {
        let (x, e) = (self.x[i], (p[1] * self.x[i]).exp());
        [
            2.0 * d[0] * d[1] * x * e + p[0] * x * x * e * d[1] * d[1],
            0.0,
            0.0,
        ]
    }
    fn observation_scale(&self, i: usize) -> f64 {
        self.y[i].abs()
    }
    fn scalar(&self, _: usize) -> bool {
        true
    }
}

#[test]
fn a_nonlinear_curve_ends_at_a_vertex() {
    let mut rng = Rng::new(5);
    let x: Vec<f64> = (0..30).map(|k| k as f64 / 10.0).collect();
    let mut y: Vec<f64> = x
        .iter()
        .map(|&x| 2.0 * (0.7 * x).exp() + 0.05 * rng.normal())
        .collect();
    y[7] += 3.0; // an outlier the L1 fit ignores
    let problem = Exponential { x, y };
    let task = Task::new(problem);
    let (p, report) = crate::engines::polish::settle(&task, &[1.5, 0.9], Objective::Phi, 1e-9)
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(report.stop, SettleStop::Vertex, "{report:?}");
    let phi = task.problem.phi(&p);
    // Two residuals interpolated (to rounding), and no small move lowers Φ.
    let zeros = (0..30)
        .filter(|&i| task.problem.residual(i, &p)[0].abs() < 1e-12)
        .count();
    assert_eq!(zeros, 2, "{report:?}");
    for k in 0..16 {
        let t = std::f64::consts::TAU * k as f64 / 16.0;
        for h in [1e-3, 1e-6] {
            let q = [p[0] + h * t.cos(), p[1] + h * t.sin()];
            assert!(task.problem.phi(&q) > phi, "{k} {h}");
        }
    }
    assert!(
        (p[0] - 2.0).abs() < 0.1 && (p[1] - 0.7).abs() < 0.05,
        "{p:?}"
    );
}
