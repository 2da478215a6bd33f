//! Speed and memory of identification, the native LM against the other engines, measured in one
//! run.
//!
//! Run: `cargo run --release -p volver-benchmarks --all-features --bin bench`
//! (`-- --quick` for the two smaller sizes only, `-- --reference-only` for the comparison with the
//! expert Ceres program only, `-- --ranges-only` for ranges alone and the plan only).
//!
//! First, test 4 against Ceres at its best: the native engine and the expert Ceres program
//! (`benchmarks/ceres/expert.cpp`, feature `ceres`) on the same data, 1 and 2 threads each, best
//! of 7 runs in fresh processes: iterations, time to stop and time to reach the lowest final EMM
//! of the runs within 0.01 µm (each run's trace of accepted steps).
//!
//! Then three problems: the paper's test 4 (1 040 points, the paper's model), 10 000 points × ~200
//! parameters and 100 000 points × ~500 parameters (the XCFZ machine with Legendre and Fourier
//! bases of higher degree, random poses, the paper's noise). For each:
//!
//! * kernels (single thread, best of several passes): one f64 evaluation and one exact Jacobian
//!   row block per point, the JᵀJ formation of the native engine (`kernels::normal_equations` minus
//!   the Jacobian pass) in GF/s and as a fraction of a dense matrix multiply (faer, 1024³)
//!   measured in the same run;
//! * each engine identifying Φ from the model's start (tracker fitted rigidly first) through
//!   volver's own wrapping of it (for Ceres: our callback, not the expert program), in a child
//!   process of its own so that its peak resident memory (`VmHWM`) is its own: time, steps,
//!   time per step, ratios to the native LM, and the allocations per LM step (a counting
//!   allocator). Test 4 runs to convergence (Clarabel to 30 steps); the larger problems get a
//!   step budget per engine (their Φ creeps for hundreds of steps in every engine), so their
//!   ratios are per step;
//!
//! Then both cores: the native LM on the 10 000-point problem on one and two threads, best of 7
//! runs each, and the ratio; then the scaling of the native LM's identification time with
//! points and with parameters.
//!
//! Last, ranges alone (`-- --ranges-only` for this part only): test 4's poses measured
//! range-only from four stations (the default layout, 4 160 ranges, the paper's noise on the
//! ranges, the stations' positions and offsets identified), identified by the native LM with Φ
//! (an L1 fit) and with ve, best of 5 runs each: steps, Φ, time and Φ's time as a multiple of
//! ve's; and `volver plan`'s design (I-optimal, 1 040 points, the CLI's defaults) on that
//! four-station layout and on the one tracker, best of 3 runs each, and their ratio.
//!
//! No figure here is a test threshold.

use std::alloc::{GlobalAlloc, Layout, System};
use std::hint::black_box;
use std::process::Command;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;
use volver_core::machine::{Commands, Machine};
use volver_core::measure::MeasurementSet;
use volver_core::model::Model;
use volver_core::plan::Plan;
use volver_core::problem::{Problem, Residuals};
use volver_core::random::Rng;
use volver_core::simulate::{Magnitudes, Simulation, Truth};
use volver_solvers::strategy::{Strategy, identify};
use volver_solvers::{Iteration, Objective, Observer, Options};

/// Counts heap allocations, to check that an LM step allocates nothing in proportion to the
/// points.
struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

// SAFETY: every call is forwarded unchanged to the system allocator; the counter is atomic.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: the caller's contract is passed on.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: the caller's contract is passed on.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: the caller's contract is passed on.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// A problem size: the error model and how many random poses (× 2 reflectors).
struct Size {
    key: &'static str,
    title: &'static str,
    /// None: the paper's model on the paper's test-4 plan.
    model: Option<String>,
    poses: usize,
    /// Step limit per engine (the smaller problems run to convergence).
    max_steps: fn(&str) -> usize,
    engines: &'static [&'static str],
}

fn model_toml(degree: usize, order: usize) -> String {
    format!(
        r#"
name = "XCFZ, Legendre degree {degree} on X and Z, Fourier order {order} on C"
[[error]]
name = ["EXX", "EYX", "EZX", "EAX", "EBX", "ECX", "EXZ", "EYZ", "EZZ", "EAZ", "EBZ", "ECZ"]
basis = "legendre"
degree = {degree}
[[error]]
name = ["EXC", "EYC", "EZC", "EAC", "EBC", "ECC"]
basis = "fourier"
order = {order}
[[error]]
name = ["A0Z", "B0Z"]
"#
    )
}

const ALL_ENGINES: &[&str] = &["lm", "ceres", "nlopt-lbfgs", "clarabel"];
const LARGE_ENGINES: &[&str] = &["lm", "ceres"];

fn sizes() -> Vec<Size> {
    vec![
        Size {
            key: "test4",
            title: "test 4: the paper's model and plan",
            model: None,
            poses: 0,
            max_steps: |e| if e == "clarabel" { 30 } else { 200 },
            engines: ALL_ENGINES,
        },
        Size {
            key: "10k",
            title: "10 000 points, degree-8 Legendre / order-7 Fourier",
            model: Some(model_toml(8, 7)),
            poses: 5_000,
            max_steps: |e| if e == "clarabel" { 2 } else { 30 },
            engines: ALL_ENGINES,
        },
        Size {
            key: "100k",
            title: "100 000 points, degree-26 Legendre / order-15 Fourier",
            model: Some(model_toml(26, 15)),
            poses: 50_000,
            max_steps: |e| if e == "lm" { 10 } else { 3 },
            engines: LARGE_ENGINES,
        },
    ]
}

/// The model and simulated measurements of a size (deterministic).
fn build(size: &Size) -> (Model, MeasurementSet) {
    let machine = Machine::default_xcfz();
    let model = match &size.model {
        None => Model::default_xcfz(),
        Some(text) => Model::from_toml_str(machine.clone(), text, size.key).expect("valid model"),
    };
    let plan = match size.model {
        None => Plan::preset(&machine, "test4").expect("preset"),
        Some(_) => {
            let mut rng = Rng::new(17);
            let positions = (0..size.poses)
                .map(|_| {
                    let mut c = Commands::default();
                    for (k, a) in machine.axes().iter().enumerate() {
                        c.0[k] = a.min + (a.max - a.min) * rng.uniform();
                    }
                    c
                })
                .collect();
            Plan {
                name: format!("{} random poses", size.poses),
                positions,
                reflectors: (0..machine.reflectors().len()).collect(),
                sequence: None,
                approach: None,
            }
        }
    };
    let truth = Truth::random(&machine, model.spec(), &Magnitudes::default(), 7).expect("truth");
    let data = Simulation::new(plan, truth, 7)
        .run()
        .expect("simulation")
        .measurements;
    (model, data)
}

/// Best wall time (s) of `reps` runs.
fn best(reps: usize, mut f: impl FnMut()) -> f64 {
    (0..reps)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

/// Peak resident memory of this process (MB), from /proc.
fn peak_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

/// Kernel timings of a size, as JSON.
fn kernels(size: &Size) -> serde_json::Value {
    let (model, data) = build(size);
    let problem = Problem::new(&model, &data).expect("problem");
    let p = model.initial_params();
    let (np, n) = (problem.n_points(), problem.n_params());
    // Enough passes for the best to be a quiet one (a test-4 pass takes about a millisecond).
    let reps = if np > 50_000 {
        2
    } else if np > 5_000 {
        5
    } else {
        50
    };
    let mut row = vec![0.0; 3 * n];
    let f64_s = best(reps, || {
        for i in 0..np {
            black_box(problem.residual(i, black_box(&p)));
        }
    });
    let jac_s = best(reps, || {
        for i in 0..np {
            black_box(problem.residual_and_jacobian(i, black_box(&p), &mut row));
        }
    });
    let normal_s = best(reps, || {
        black_box(volver_solvers::kernels::normal_equations(&problem, &p));
    });
    let a0 = ALLOCATIONS.load(Ordering::Relaxed);
    black_box(volver_solvers::kernels::normal_equations(&problem, &p));
    let normal_allocations = ALLOCATIONS.load(Ordering::Relaxed) - a0;
    // A dense matrix multiply, single thread, in the same run.
    let k = 1024;
    let a = faer::Mat::<f64>::from_fn(k, k, |i, j| ((i * 7 + j * 3) % 11) as f64 - 5.0);
    let b = faer::Mat::<f64>::from_fn(k, k, |i, j| ((i * 5 + j * 2) % 13) as f64 - 6.0);
    let mut c = faer::Mat::<f64>::zeros(k, k);
    let gemm_s = best(3, || {
        faer::linalg::matmul::matmul(
            c.as_mut(),
            faer::Accum::Replace,
            a.as_ref(),
            b.as_ref(),
            1.0,
            faer::Par::Seq,
        );
        black_box(&c);
    });
    let rows = 3 * np;
    serde_json::json!({
        "points": np,
        "params": n,
        "f64_ns": f64_s * 1e9 / np as f64,
        "jacobian_ns": jac_s * 1e9 / np as f64,
        "normal_s": normal_s,
        "normal_allocations": normal_allocations,
        "jacobian_pass_s": jac_s,
        // Lower triangle of JᵀJ: n(n+1)/2 dot products of length 3·points.
        "jtj_gflop": rows as f64 * n as f64 * (n + 1) as f64 / 1e9,
        "gemm_gflops": 2.0 * (k as f64).powi(3) / gemm_s / 1e9,
    })
}

/// Counts steps and allocations between the first and the last step.
#[derive(Default)]
struct Steps {
    start: Option<Instant>,
    /// Accepted steps: time since the start (s) and EMM (µm).
    trace: Vec<(f64, f64)>,
    steps: usize,
    first: Option<(usize, usize)>,
    last: Option<(usize, usize)>,
}

impl Observer for Steps {
    fn iteration(&mut self, it: &Iteration) {
        self.steps += 1;
        let now = (self.steps, ALLOCATIONS.load(Ordering::Relaxed));
        self.first.get_or_insert(now);
        self.last = Some(now);
        let t = self.start.map_or(f64::NAN, |t| t.elapsed().as_secs_f64());
        if it.accepted {
            self.trace.push((t, it.emm_um));
        }
        if std::env::var_os("VOLVER_BENCH_TRACE").is_some() {
            eprintln!(
                "{t:9.6} s step {:4} evals {:5} cost {:.9e} EMM {:.6} µm λ {:.1e} {} allocations {}",
                it.iteration, it.evaluations, it.cost, it.emm_um, it.damping, it.accepted, now.1
            );
        }
    }
}

/// One engine identifying Φ on a size, as JSON.
fn run_engine(size: &Size, name: &str) -> serde_json::Value {
    let (model, data) = build(size);
    // The clock includes the problem's set-up (its fixed regressors), as the expert program's
    // includes its own.
    let t = Instant::now();
    let problem = Problem::new(&model, &data).expect("problem");
    let engine = match volver_solvers::engine(name) {
        Ok(e) => e,
        Err(e) => return serde_json::json!({ "engine": name, "error": e.to_string() }),
    };
    let options = Options {
        objective: Objective::Phi,
        max_iterations: (size.max_steps)(name),
        max_evaluations: 10 * (size.max_steps)(name) + 20,
        ..Options::default()
    };
    let mut steps = Steps {
        start: Some(t),
        ..Steps::default()
    };
    let id = identify(
        engine.as_ref(),
        problem.clone(),
        &model.initial_params(),
        &Strategy::default(),
        &options,
        &mut steps,
    );
    let time_s = t.elapsed().as_secs_f64();
    let allocs_per_step = match (steps.first, steps.last) {
        (Some((s0, a0)), Some((s1, a1))) if s1 > s0 => (a1 - a0) as f64 / (s1 - s0) as f64,
        _ => f64::NAN,
    };
    let mut trace = steps.trace;
    trace.push((time_s, id.reached.stats.emm_um));
    serde_json::json!({
        "engine": name,
        "trace": trace,
        "threads": rayon_threads(),
        "phi_mm": problem.phi(&id.params),
        "steps": id.iterations(),
        "evaluations": id.evaluations(),
        "time_s": time_s,
        "termination": id.termination.to_string(),
        "allocations_per_step": allocs_per_step,
        "peak_mb": peak_mb(),
        "params": problem.n_params(),
        "points": problem.n_points(),
    })
}

/// The threads of rayon's pool (the native engine's passes).
fn rayon_threads() -> usize {
    rayon::current_num_threads()
}

/// The expert Ceres program fitting Φ on a size with `threads` threads, as JSON.
#[cfg(feature = "ceres")]
fn run_expert(size: &Size, threads: usize) -> serde_json::Value {
    use volver_benchmarks::expert::Expert;
    let (model, data) = build(size);
    let problem = Problem::new(&model, &data).expect("problem");
    let name = format!(
        "expert Ceres, {threads} thread{}",
        if threads > 1 { "s" } else { "" }
    );
    let t0 = Instant::now();
    // The same start as volver's identification: the tracker fitted rigidly first.
    let prepared = volver_solvers::init::init_tracker(&problem, &model.initial_params())
        .map_err(|e| e.to_string())
        .and_then(|start| Expert::new(&problem, &start).map(|e| (start, e)));
    let (start, expert) = match prepared {
        Ok(x) => x,
        Err(e) => return serde_json::json!({ "engine": name, "error": e }),
    };
    let before = t0.elapsed().as_secs_f64();
    // ε = 1 nm: the smoothed EMM is within 0.001 µm of the EMM.
    let fit = match expert.fit(&start, threads, 1e-6) {
        Ok(f) => f,
        Err(e) => return serde_json::json!({ "engine": name, "error": e }),
    };
    let time_s = t0.elapsed().as_secs_f64();
    let mut trace: Vec<(f64, f64)> = fit
        .trace
        .iter()
        .map(|&(t, emm)| (before + t, emm * 1e3))
        .collect();
    trace.push((time_s, fit.final_emm_mm * 1e3));
    serde_json::json!({
        "engine": name,
        "trace": trace,
        "threads": threads,
        "phi_mm": problem.phi(&fit.params),
        "steps": fit.iterations,
        "time_s": time_s,
        "termination": fit.message,
        "peak_mb": peak_mb(),
        "params": problem.n_params(),
        "points": problem.n_points(),
    })
}

#[cfg(not(feature = "ceres"))]
fn run_expert(_: &Size, threads: usize) -> serde_json::Value {
    serde_json::json!({
        "engine": format!("expert Ceres, {threads} threads"),
        "error": "built without the `ceres` feature",
    })
}

/// Runs `child <what> <size>` in a fresh process and parses its JSON line.
fn child(what: &str, size: &str) -> serde_json::Value {
    child_with_threads(what, size, None)
}

/// [`child`] with rayon's pool at `threads` threads (the native engine's passes).
fn child_with_threads(what: &str, size: &str, threads: Option<usize>) -> serde_json::Value {
    let exe = std::env::current_exe().expect("own path");
    let mut command = Command::new(exe);
    command.args(["child", what, size]);
    if let Some(t) = threads {
        command.env("RAYON_NUM_THREADS", t.to_string());
    }
    let out = command.output().expect("child process");
    let text = String::from_utf8_lossy(&out.stdout);
    match text
        .lines()
        .last()
        .map(serde_json::from_str::<serde_json::Value>)
    {
        Some(Ok(v)) if out.status.success() => v,
        _ => serde_json::json!({
            "engine": what,
            "error": format!(
                "child failed ({}): {}",
                out.status,
                String::from_utf8_lossy(&out.stderr).lines().last().unwrap_or("")
            ),
        }),
    }
}

fn f(v: &serde_json::Value, key: &str) -> f64 {
    v[key].as_f64().unwrap_or(f64::NAN)
}

fn report(size: &Size) {
    // Kernels on one thread (the passes run on rayon's pool).
    let k = child_with_threads("kernels", size.key, Some(1));
    let (np, n) = (f(&k, "points"), f(&k, "params"));
    let jtj_s = f(&k, "normal_s") - f(&k, "jacobian_pass_s");
    let jtj_rate = f(&k, "jtj_gflop") / jtj_s;
    println!("\n## {} ({np} points, {n} parameters)\n", size.title);
    println!(
        "Kernels, single thread: f64 evaluation {:.0} ns/point; Jacobian {:.0} ns/point ({:.1}× an evaluation); \
         JᵀJ formation {:.3} s = {:.2} GF/s, {:.0} % of a dense matrix multiply ({:.2} GF/s); \
         one pass of the normal equations allocates {} times.\n",
        f(&k, "f64_ns"),
        f(&k, "jacobian_ns"),
        f(&k, "jacobian_ns") / f(&k, "f64_ns"),
        jtj_s,
        jtj_rate,
        100.0 * jtj_rate / f(&k, "gemm_gflops"),
        f(&k, "gemm_gflops"),
        k["normal_allocations"],
    );
    println!(
        "| engine | Φ mm | steps | evals | time s | s/step | time × LM | s/step × LM | peak MB | allocs/step | termination |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    let runs: Vec<serde_json::Value> = size.engines.iter().map(|e| child(e, size.key)).collect();
    let lm = runs.iter().find(|r| r["engine"] == "lm").cloned();
    for r in &runs {
        if let Some(e) = r["error"].as_str() {
            println!(
                "| {} | — | | | | | | | | | {e} |",
                r["engine"].as_str().unwrap_or("?")
            );
            continue;
        }
        let per = f(r, "time_s") / f(r, "steps");
        let (ratio, ratio_step) = match &lm {
            Some(l) => (
                f(r, "time_s") / f(l, "time_s"),
                per / (f(l, "time_s") / f(l, "steps")),
            ),
            None => (f64::NAN, f64::NAN),
        };
        println!(
            "| {} | {:.9} | {} | {} | {:.3} | {:.4} | {:.2} | {:.2} | {:.0} | {:.1} | {} |",
            r["engine"].as_str().unwrap_or("?"),
            f(r, "phi_mm"),
            r["steps"],
            r["evaluations"],
            f(r, "time_s"),
            per,
            ratio,
            ratio_step,
            f(r, "peak_mb"),
            f(r, "allocations_per_step"),
            r["termination"].as_str().unwrap_or("?"),
        );
    }
    if let Some(l) = &lm {
        let per = f(l, "time_s") / f(l, "steps");
        println!(
            "\nNative LM: {:.4} s per step = {:.2} × the JᵀJ formation time.",
            per,
            per / jtj_s
        );
    }
}

/// Time (s) at which a trace first comes within `within` µm of `target` µm.
fn time_to(trace: &serde_json::Value, target: f64, within: f64) -> f64 {
    trace
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|p| Some((p[0].as_f64()?, p[1].as_f64()?)))
        .find(|&(_, emm)| emm <= target + within)
        .map_or(f64::NAN, |(t, _)| t)
}

/// The native engine against the expert Ceres program on test 4, 1 and 2 threads each, best
/// of `reps` runs (each in its own process).
fn reference(reps: usize) {
    println!(
        "\n## Test 4 against Ceres at its best (the expert program, `benchmarks/ceres/expert.cpp`)\n"
    );
    let best_of = |what: &str, threads: usize| -> serde_json::Value {
        (0..reps)
            .map(|_| child_with_threads(what, "test4", Some(threads)))
            .min_by(|a, b| f(a, "time_s").total_cmp(&f(b, "time_s")))
            .unwrap_or_default()
    };
    let runs: Vec<serde_json::Value> = [1, 2]
        .into_iter()
        .flat_map(|t| [best_of("lm", t), best_of(&format!("expert:{t}"), t)])
        .collect();
    if let Some(e) = runs.iter().find_map(|r| r["error"].as_str()) {
        println!("Not measured: {e}.");
        return;
    }
    // The target: the lower final EMM of the four runs, within 0.01 µm.
    let best = runs
        .iter()
        .filter_map(|r| r["trace"].as_array()?.last()?[1].as_f64())
        .fold(f64::INFINITY, f64::min);
    println!(
        "Φ from the model's start (tracker fitted rigidly first, included in the times); best of \
         {reps} runs by time to stop; target: the lowest final EMM, {best:.4} µm, within 0.01 µm.\n"
    );
    println!(
        "| engine | threads | iterations | final EMM µm | time to stop ms | time to target ms | × volver, stop | × volver, target | termination |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for pair in runs.chunks(2) {
        let ours = &pair[0];
        let ours_target = time_to(&ours["trace"], best, 0.01);
        for r in pair {
            let target = time_to(&r["trace"], best, 0.01);
            let final_emm = r["trace"]
                .as_array()
                .and_then(|t| t.last())
                .and_then(|p| p[1].as_f64())
                .unwrap_or(f64::NAN);
            println!(
                "| {} | {} | {} | {:.4} | {:.1} | {:.1} | {:.2} | {:.2} | {} |",
                r["engine"].as_str().unwrap_or("?"),
                r["threads"],
                r["steps"],
                final_emm,
                1e3 * f(r, "time_s"),
                1e3 * target,
                f(r, "time_s") / f(ours, "time_s"),
                target / ours_target,
                r["termination"].as_str().unwrap_or("?"),
            );
        }
    }
}

/// The native LM's identification of the 10 000-point size on one and two threads, best of
/// `reps` runs each (each in its own process): how much of the second core it uses.
fn threads(reps: usize) {
    println!("\n## Both cores: the native LM on 10 000 points, one and two threads\n");
    let best_of = |threads: usize| -> serde_json::Value {
        (0..reps)
            .map(|_| child_with_threads("lm", "10k", Some(threads)))
            .min_by(|a, b| f(a, "time_s").total_cmp(&f(b, "time_s")))
            .unwrap_or_default()
    };
    let (one, two) = (best_of(1), best_of(2));
    if let Some(e) = [&one, &two].iter().find_map(|r| r["error"].as_str()) {
        println!("Not measured: {e}.");
        return;
    }
    println!(
        "Best of {reps} runs each (Φ, to convergence, the problem's set-up included): {:.3} s on \
         one thread, {:.3} s on two, {:.2}×; the same Φ on both ({:.12e} and {:.12e} mm).",
        f(&one, "time_s"),
        f(&two, "time_s"),
        f(&one, "time_s") / f(&two, "time_s"),
        f(&one, "phi_mm"),
        f(&two, "phi_mm"),
    );
}

fn scaling() {
    println!("\n## Scaling of the native LM (Φ, to convergence or 30 steps)\n");
    println!("| model | params | points | steps | time s | s/step |");
    println!("|---|---|---|---|---|---|");
    for (label, degree, order, poses) in [
        ("degree 3 / order 1", 3, 1, 500),
        ("degree 3 / order 1", 3, 1, 2_000),
        ("degree 3 / order 1", 3, 1, 8_000),
        ("degree 3 / order 1", 3, 1, 32_000),
        ("degree 8 / order 7", 8, 7, 5_000),
        ("degree 16 / order 11", 16, 11, 5_000),
        ("degree 26 / order 15", 26, 15, 5_000),
    ] {
        let key = format!("scale:{degree}:{order}:{poses}");
        let r = child("lm", &key);
        println!(
            "| {label} | {} | {} | {} | {:.3} | {:.4} |",
            r["params"],
            r["points"],
            r["steps"],
            f(&r, "time_s"),
            f(&r, "time_s") / f(&r, "steps"),
        );
    }
}

/// The XCFZ machine measured range-only from the default layout of four stations, and the
/// paper's model with each station's range offset.
fn ranges_model() -> Model {
    use volver_core::machine::{Observes, StationSpec};
    let xcfz = Machine::default_xcfz();
    let multi = xcfz
        .with_stations(StationSpec::default_layout(&xcfz, 4, Observes::Range))
        .expect("the default layout");
    let text = volver_core::model::DEFAULT_MODEL_TOML.replace(
        "identify = [\"x\", \"y\", \"z\"]",
        "identify = [\"x\", \"y\", \"z\"]\nrange_offset = true",
    );
    Model::from_toml_str(multi, &text, "paper model with range offsets").expect("valid model")
}

/// Test 4's ranges from four stations (seed 7, the paper's noise on the ranges) identified by
/// the native LM with `objective` (`phi` or `ve`), as JSON.
fn run_ranges(objective: &str) -> serde_json::Value {
    use volver_core::measure::Observation;
    let model = ranges_model();
    let machine = model.machine();
    let truth = Truth::random(
        machine,
        Model::default_xcfz().spec(),
        &Magnitudes::default(),
        7,
    )
    .expect("truth");
    let mut sim = Simulation::new(Plan::preset(machine, "test4").expect("preset"), truth, 7);
    sim.observe = Observation::Range;
    let data = sim.run().expect("simulation").measurements;
    let t = Instant::now();
    let problem = Problem::new(&model, &data).expect("problem");
    let options = Options {
        objective: if objective == "ve" {
            Objective::Ve
        } else {
            Objective::Phi
        },
        ..Options::default()
    };
    let id = identify(
        &volver_solvers::lm::LevenbergMarquardt::default(),
        problem.clone(),
        &model.initial_params(),
        &Strategy::default(),
        &options,
        &mut volver_solvers::Silent,
    );
    serde_json::json!({
        "objective": objective,
        "time_s": t.elapsed().as_secs_f64(),
        "steps": id.iterations(),
        "evaluations": id.evaluations(),
        "phi_mm": problem.phi(&id.params),
        "points": problem.n_points(),
        "termination": id.termination.to_string(),
    })
}

/// `volver plan`'s design with the CLI's defaults (I-optimal, 1 040 points, the paper's noise,
/// the tool at the reflectors' centroid) on the four-station layout of ranges (`ranges4`) or
/// the one tracker, as JSON.
fn run_plan(layout: &str) -> serde_json::Value {
    let model = if layout == "ranges4" {
        ranges_model()
    } else {
        Model::default_xcfz()
    };
    let machine = model.machine();
    let request = volver::planning::Request {
        tool: volver::compensation::reflector_centroid(&model),
        per_axis: volver::planning::default_per_axis(machine, machine.reflectors().len())
            .expect("a candidate grid"),
        ..volver::planning::Request::default()
    };
    let t = Instant::now();
    match volver::planning::plan(&model, &request) {
        Ok(planned) => serde_json::json!({
            "layout": layout,
            "time_s": t.elapsed().as_secs_f64(),
            "candidates": planned.report.candidates,
            "equivalence": planned.report.equivalence,
            "u95_mean_um": planned.report.u95_mean_um,
        }),
        Err(e) => serde_json::json!({ "layout": layout, "error": e.to_string() }),
    }
}

/// Φ against ve on the four stations' ranges, and the plan's time on that layout against one
/// tracker's: best of `reps` runs each, each in its own process.
fn ranges(reps: usize) {
    println!(
        "\n## Ranges alone: test 4 from four stations (4 160 ranges, paper noise), and its plan\n"
    );
    let best_of = |what: &str, arg: &str, n: usize| -> serde_json::Value {
        (0..n)
            .map(|_| child(what, arg))
            .min_by(|a, b| f(a, "time_s").total_cmp(&f(b, "time_s")))
            .unwrap_or_default()
    };
    let (phi, ve) = (
        best_of("ranges", "phi", reps),
        best_of("ranges", "ve", reps),
    );
    println!("| objective | steps | evals | Φ mm | time s | × ve | termination |");
    println!("|---|---|---|---|---|---|---|");
    for r in [&phi, &ve] {
        println!(
            "| {} | {} | {} | {:.12e} | {:.3} | {:.2} | {} |",
            r["objective"].as_str().unwrap_or("?"),
            r["steps"],
            r["evaluations"],
            f(r, "phi_mm"),
            f(r, "time_s"),
            f(r, "time_s") / f(&ve, "time_s"),
            r["termination"].as_str().unwrap_or("?"),
        );
    }
    let reps_plan = reps.div_ceil(2);
    let (four, one) = (
        best_of("plan", "ranges4", reps_plan),
        best_of("plan", "tracker", reps_plan),
    );
    if let Some(e) = [&four, &one].iter().find_map(|r| r["error"].as_str()) {
        println!("\n`volver plan` not measured: {e}.");
        return;
    }
    println!(
        "\n`volver plan` (I-optimal, 1 040 points, CLI defaults), best of {reps_plan}: {:.2} s on \
         the four stations' ranges ({} candidates, equivalence {:.4}, U mean {:.3} µm), {:.2} s \
         with one tracker ({} candidates, U mean {:.3} µm): {:.2}×.",
        f(&four, "time_s"),
        four["candidates"],
        f(&four, "equivalence"),
        f(&four, "u95_mean_um"),
        f(&one, "time_s"),
        one["candidates"],
        f(&one, "u95_mean_um"),
        f(&four, "time_s") / f(&one, "time_s"),
    );
}

/// The size a child is asked for: a named one or `scale:degree:order:poses`.
fn size_of(key: &str) -> Size {
    if let Some(rest) = key.strip_prefix("scale:") {
        let v: Vec<usize> = rest.split(':').filter_map(|x| x.parse().ok()).collect();
        return Size {
            key: "scale",
            title: "scaling",
            model: Some(model_toml(v[0], v[1])),
            poses: v[2],
            max_steps: |_| 30,
            engines: &["lm"],
        };
    }
    sizes()
        .into_iter()
        .find(|s| s.key == key)
        .unwrap_or_else(|| panic!("unknown size {key}"))
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() == 4 && args[1] == "child" {
        // As the CLI does: the passes start on this thread.
        volver_solvers::share_calling_thread();
        if args[2] == "ranges" {
            println!("{}", run_ranges(&args[3]));
            return;
        }
        if args[2] == "plan" {
            println!("{}", run_plan(&args[3]));
            return;
        }
        let size = size_of(&args[3]);
        let v = if args[2] == "kernels" {
            kernels(&size)
        } else if let Some(t) = args[2].strip_prefix("expert:") {
            run_expert(&size, t.parse().expect("expert:<threads>"))
        } else {
            run_engine(&size, &args[2])
        };
        println!("{v}");
        return;
    }
    let quick = args.iter().any(|a| a == "--quick");
    let t = Instant::now();
    println!(
        "volver bench — engines: {}; one process per measurement; Φ from the model's start",
        volver_solvers::engine_names().join(", ")
    );
    if args.iter().any(|a| a == "--ranges-only") {
        ranges(if quick { 3 } else { 5 });
        println!("\nTotal {:.0} s.", t.elapsed().as_secs_f64());
        return;
    }
    reference(if quick { 3 } else { 7 });
    if args.iter().any(|a| a == "--reference-only") {
        return;
    }
    for size in sizes() {
        if quick && size.key == "100k" {
            continue;
        }
        report(&size);
    }
    threads(if quick { 3 } else { 7 });
    scaling();
    ranges(if quick { 3 } else { 5 });
    println!("\nTotal {:.0} s.", t.elapsed().as_secs_f64());
}
