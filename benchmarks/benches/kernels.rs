//! Criterion benches of the native path's kernels on the paper's test 4 (1 040 points, 74
//! parameters): one f64 residual pass, one exact Jacobian pass, the normal equations (Jacobian
//! and JᵀJ in row blocks), and a whole Φ identification with the native LM.
//!
//! Run: `cargo bench -p volver-benchmarks --bench kernels`

use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;
use volver_core::model::Model;
use volver_core::plan::Plan;
use volver_core::problem::{Problem, Residuals};
use volver_core::simulate::{Magnitudes, Simulation, Truth};
use volver_solvers::kernels::normal_equations;
use volver_solvers::lm::LevenbergMarquardt;
use volver_solvers::strategy::{Strategy, identify};
use volver_solvers::{Options, Silent};

fn kernels(c: &mut Criterion) {
    let machine = volver_core::machine::Machine::default_xcfz();
    let truth = Truth::random_complete(&machine, &Magnitudes::default(), 7).expect("truth");
    let plan = Plan::preset(&machine, "test4").expect("preset");
    let data = Simulation::new(plan, truth, 7)
        .run()
        .expect("simulation")
        .measurements;
    let model = Model::default_xcfz();
    let problem = Problem::new(&model, &data).expect("problem");
    let p = model.initial_params();
    let n = problem.n_params();
    let mut row = vec![0.0; 3 * n];
    c.bench_function("test4/residual pass", |b| {
        b.iter(|| {
            for i in 0..problem.n_points() {
                black_box(problem.residual(i, black_box(&p)));
            }
        })
    });
    c.bench_function("test4/jacobian pass", |b| {
        b.iter(|| {
            for i in 0..problem.n_points() {
                black_box(problem.residual_and_jacobian(i, black_box(&p), &mut row));
            }
        })
    });
    c.bench_function("test4/normal equations", |b| {
        b.iter(|| black_box(normal_equations(&problem, black_box(&p))))
    });
    let mut group = c.benchmark_group("test4");
    group.sample_size(10);
    group.bench_function("identify phi (lm)", |b| {
        b.iter(|| {
            black_box(identify(
                &LevenbergMarquardt::default(),
                problem.clone(),
                &p,
                &Strategy::default(),
                &Options::default(),
                &mut Silent,
            ))
        })
    });
    group.finish();
}

criterion_group!(benches, kernels);
criterion_main!(benches);
