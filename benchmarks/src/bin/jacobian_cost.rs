//! Cost of the exact structured Jacobian as a multiple of one f64 evaluation of the forward
//! model, for the paper's model (74 parameters) and a ~200-parameter model of the same machine.
//!
//! Run: `cargo run --release -p volver-benchmarks --bin jacobian_cost`
//!
//! Both timings cover the whole per-point work: evaluating every error function from its
//! coefficients, the chain, and (for the Jacobian) the chain's reverse pass over the error values
//! plus the chain rule through the bases into a 3 × n row block. Each figure is the best of several
//! repetitions over the same points. Two paths: the model called directly (the bases and the
//! rotary axes' sines evaluated at every call), and the path of an identification, where the
//! problem holds each point's fixed regressors (`Model::regressors`, computed once).

use std::hint::black_box;
use std::time::Instant;
use volver_core::machine::{Commands, Machine};
use volver_core::model::Model;

const LARGE_MODEL: &str = r#"
name = "XCFZ, degree-8 linear-axis errors, 7 harmonics on C"
[[error]]
name = ["EXX", "EYX", "EZX", "EAX", "EBX", "ECX", "EXZ", "EYZ", "EZZ", "EAZ", "EBZ", "ECZ"]
basis = "legendre"
degree = 8
[[error]]
name = ["EXC", "EYC", "EZC", "EAC", "EBC", "ECC"]
basis = "fourier"
order = 7
[[error]]
name = ["A0Z", "B0Z"]
"#;

fn points(machine: &Machine, n: usize) -> Vec<(Commands, usize)> {
    let mut s = 0x9E3779B97F4A7C15_u64;
    let mut next = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..n)
        .map(|i| {
            let mut c = Commands::default();
            for (k, a) in machine.axes().iter().enumerate() {
                c.0[k] = a.min + (a.max - a.min) * next();
            }
            (c, i % machine.reflectors().len())
        })
        .collect()
}

/// Best time per point (ns) over `reps` passes.
fn best_ns(reps: usize, n: usize, mut pass: impl FnMut()) -> f64 {
    (0..reps)
        .map(|_| {
            let t = Instant::now();
            pass();
            t.elapsed().as_secs_f64() * 1e9 / n as f64
        })
        .fold(f64::INFINITY, f64::min)
}

fn measure(label: &str, model: &Model) {
    let n = 20_000;
    let pts = points(model.machine(), n);
    let params: Vec<f64> = (0..model.n_params())
        .map(|j| 1e-4 * ((j as f64) * 0.37).sin())
        .collect();
    let mut jac = vec![0.0; 3 * model.n_params()];
    let reps = 7;
    let f64_ns = best_ns(reps, n, || {
        for (c, r) in &pts {
            black_box(model.predict(black_box(c), *r, black_box(&params)));
        }
    });
    let jac_ns = best_ns(reps, n, || {
        for (c, r) in &pts {
            black_box(model.predict_with_jacobian(black_box(c), *r, black_box(&params), &mut jac));
            black_box(&jac);
        }
    });
    let commands: Vec<&Commands> = pts.iter().map(|(c, _)| c).collect();
    let reg = model.regressors(commands);
    let f64_cached_ns = best_ns(reps, n, || {
        for (i, (c, r)) in pts.iter().enumerate() {
            black_box(model.predict_cached(&reg, i, black_box(c), *r, 0.0, black_box(&params)));
        }
    });
    let jac_cached_ns = best_ns(reps, n, || {
        for (i, (c, r)) in pts.iter().enumerate() {
            black_box(model.predict_with_jacobian_cached(
                &reg,
                i,
                black_box(c),
                *r,
                0.0,
                black_box(&params),
                &mut jac,
            ));
            black_box(&jac);
        }
    });
    let slots = model.terms().len() + 6;
    println!(
        "| {label:<44} | {:>6} | {:>6} | {:>11.0} | {:>12.0} | {:>8.1}× | {:>11.0} | {:>12.0} |",
        model.n_params(),
        slots,
        f64_ns,
        jac_ns,
        jac_ns / f64_ns,
        f64_cached_ns,
        jac_cached_ns,
    );
}

fn main() {
    println!("Jacobian cost: exact structured Jacobian vs one f64 evaluation, per point");
    println!("(best of 7 passes over 20 000 random points of the XCFZ machine; single thread)\n");
    println!(
        "| model                                        | params | values | f64 eval ns | Jacobian ns  | ratio     | f64, cached | Jac., cached |"
    );
    println!(
        "|----------------------------------------------|--------|--------|-------------|--------------|-----------|-------------|--------------|"
    );
    measure("paper model (cubic, 1 harmonic)", &Model::default_xcfz());
    let large = Model::from_toml_str(Machine::default_xcfz(), LARGE_MODEL, "large model")
        .expect("valid model");
    measure("degree 8 linear, 7 harmonics rotary", &large);
    println!(
        "\n\"cached\": through the fixed regressors an identification's problem holds. Targets \
         (issue 18, paper model): f64 evaluation ≤ 150 ns, Jacobian ≤ 1.5 µs per point."
    );
}
