//! The structured dual-number Jacobian against central finite differences (relative 1e-6), for
//! every basis and every kind of error: component errors of linear and rotary axes on both sides
//! of the chain, location errors of rotary axes, squareness of linear axes, the tracker pose;
//! and the second derivative along a direction (geodesic acceleration's curvature term) against
//! central differences of the exact J·v. The cached path (a problem's fixed regressors) gives the
//! same bits as the direct one. The residuals whitened by the tracker's noise (what candidates are
//! scored on) have their own check.

use volver::core::iso::ErrorId;
use volver::core::machine::{Commands, Machine};
use volver::core::model::Model;

mod common;
use common::Rng;

/// An error model listing every component error of every axis with bases taken in turn, plus
/// every location/squareness error.
fn model_toml(machine: &Machine) -> String {
    let linear = [
        "basis = \"monomial\"\ndegree = 3",
        "basis = \"legendre\"\ndegree = 4",
        "basis = \"chebyshev\"\nnodes = 5",
    ];
    let rotary = [
        "basis = \"fourier\"\norder = 2",
        "basis = \"sine\"\norder = 2",
        "basis = \"legendre\"\ndegree = 2",
    ];
    let mut s = String::from("squareness = \"none\"\n");
    let mut i = 0;
    for ax in machine.axes() {
        for id in ErrorId::components_of(ax.axis) {
            let b = if ax.axis.is_rotary() {
                rotary[i % 3]
            } else {
                linear[i % 3]
            };
            s += &format!("[[error]]\nname = \"{id}\"\n{b}\n");
            i += 1;
        }
        for loc in ErrorId::location_names(ax.axis) {
            s += &format!("[[error]]\nname = \"{loc}\"\n");
        }
    }
    s
}

fn random_params(model: &Model, rng: &mut Rng) -> Vec<f64> {
    model
        .params()
        .iter()
        .map(|p| {
            let scale = match (p.name.contains(".phi"), p.unit) {
                (true, _) => 3.0,
                (false, volver::core::iso::Unit::Mm) => 0.05,
                (false, volver::core::iso::Unit::Rad) => 2e-4,
                (false, volver::core::iso::Unit::MmPerHour) => 0.01,
                (false, volver::core::iso::Unit::RadPerHour) => 1e-5,
                (false, volver::core::iso::Unit::Ppm | volver::core::iso::Unit::PpmPerHour) => 10.0,
                (false, other) => panic!("no test scale for unit {other:?}"),
            };
            let base = if p.name == "tracker.x" { 150.0 } else { 0.0 };
            base + scale * rng.next()
        })
        .collect()
}

/// A central-difference step that balances truncation against rounding at coordinates of
/// ~2000 mm.
fn fd_step(info: &volver::core::model::ParamInfo) -> f64 {
    if info.name.contains(".phi") {
        1e-5
    } else if info.unit == volver::core::iso::Unit::Rad {
        1e-6
    } else {
        1e-4
    }
}

fn check(machine: Machine, seed: u64) -> usize {
    let text = model_toml(&machine);
    let model = Model::from_toml_str(machine, &text, "generated model").unwrap();
    let mut rng = Rng(seed);
    let n = model.n_params();
    let mut jac = vec![0.0; 3 * n];
    let mut checked = 0;
    for _ in 0..6 {
        let p = random_params(&model, &mut rng);
        let mut c = Commands::default();
        for (k, ax) in model.machine().axes().iter().enumerate() {
            c.0[k] = ax.min + (ax.max - ax.min) * 0.5 * (1.0 + rng.next());
        }
        // The fixed regressors a problem computes once (basis values, the rotary axes'
        // sines) give the same bits as evaluating them at every call.
        let reg = model.regressors([&c]);
        let mut jac_cached = vec![0.0; 3 * n];
        for r in 0..model.machine().reflectors().len() {
            let x = model.predict_with_jacobian(&c, r, &p, &mut jac);
            assert_eq!(
                x,
                model.predict(&c, r, &p),
                "value of the dual pass equals the f64 model"
            );
            assert_eq!(model.predict_cached(&reg, 0, &c, r, 0.0, &p), x);
            let xc = model.predict_with_jacobian_cached(&reg, 0, &c, r, 0.0, &p, &mut jac_cached);
            assert_eq!(xc, x);
            assert_eq!(jac_cached, jac, "cached regressors: the same Jacobian bits");
            for j in 0..n {
                let h = fd_step(&model.params()[j]);
                let mut pp = p.clone();
                let mut pm = p.clone();
                pp[j] += h;
                pm[j] -= h;
                let (a, b) = (model.predict(&c, r, &pp), model.predict(&c, r, &pm));
                for i in 0..3 {
                    let fd = (a[i] - b[i]) / (2.0 * h);
                    let ad = jac[i * n + j];
                    assert!(
                        (fd - ad).abs() <= 1e-6 * fd.abs().max(ad.abs()).max(1.0),
                        "{} coordinate {i}: dual {ad} vs finite difference {fd}",
                        model.params()[j].name
                    );
                    checked += 1;
                }
            }
            // The tool point's exact Jacobian, at a tool offset off the reflectors, against
            // central differences of the f64 tool point.
            let tool = [12.0, -30.0, -87.0];
            let t = model.tool_point_with_jacobian(&c, &tool, &p, &mut jac);
            assert_eq!(
                t,
                model.tool_point(&c.0, &tool, &p),
                "value of the dual pass"
            );
            for j in 0..n {
                let info = &model.params()[j];
                let h = fd_step(info);
                let (mut pp, mut pm) = (p.clone(), p.clone());
                pp[j] += h;
                pm[j] -= h;
                let a: [f64; 3] = model.tool_point(&c.0, &tool, &pp);
                let b: [f64; 3] = model.tool_point(&c.0, &tool, &pm);
                for i in 0..3 {
                    let fd = (a[i] - b[i]) / (2.0 * h);
                    let ad = jac[i * n + j];
                    assert!(
                        (fd - ad).abs() <= 1e-6 * fd.abs().max(ad.abs()).max(1.0),
                        "tool point: {} coordinate {i}: dual {ad} vs finite difference {fd}",
                        info.name
                    );
                    checked += 1;
                }
            }
            // The second derivative along a random direction against central differences of
            // the exact first derivative J·v.
            let v = random_params(&model, &mut rng);
            let jv = |q: &[f64], jac: &mut [f64]| {
                model.predict_with_jacobian(&c, r, q, jac);
                (0..3)
                    .map(|i| (0..n).map(|j| jac[i * n + j] * v[j]).sum::<f64>())
                    .collect::<Vec<f64>>()
            };
            let h = 1e-4;
            let pp: Vec<f64> = p.iter().zip(&v).map(|(a, b)| a + h * b).collect();
            let pm: Vec<f64> = p.iter().zip(&v).map(|(a, b)| a - h * b).collect();
            let (a, b) = (jv(&pp, &mut jac), jv(&pm, &mut jac));
            let exact = model.predict_second_directional_at(&c, r, 0.0, &p, &v);
            for i in 0..3 {
                let fd = (a[i] - b[i]) / (2.0 * h);
                assert!(
                    (fd - exact[i]).abs() <= 1e-6 * fd.abs().max(exact[i].abs()) + 1e-9,
                    "coordinate {i}: second directional derivative {} vs finite difference {fd}",
                    exact[i]
                );
                checked += 1;
            }
        }
    }
    checked
}

#[test]
fn paper_machine_every_basis_and_error() {
    let n = check(Machine::default_xcfz(), 7);
    assert!(n > 3000);
}

#[test]
fn six_axis_chain_with_rotary_axes_on_both_sides() {
    // Workpiece: Y on the frame, trunnion B on Y; tool: X on the frame, Z on X, head C on Z.
    let text = r#"
        name = "test 6-axis"
        chain = "YBFXZC"
        [axes.Y]
        range = [-400.0, 400.0]
        offset = [0.0, 0.0, -50.0]
        reference = 100.0
        [axes.B]
        range = [-110.0, 110.0]
        offset = [0.0, 20.0, 200.0]
        [axes.X]
        range = [0.0, 1200.0]
        offset = [-600.0, 0.0, 0.0]
        [axes.Z]
        range = [0.0, 700.0]
        offset = [0.0, 0.0, 900.0]
        [axes.C]
        range = [-360.0, 360.0]
        offset = [0.0, 0.0, -150.0]
        [[reflector]]
        id = "short"
        offset = [0.0, 0.0, -80.0]
        [[reflector]]
        id = "long"
        offset = [40.0, -30.0, -220.0]
        [tracker]
        mount = "workpiece"
        position = [150.0, -30.0, 20.0]
        orientation_deg = [1.5, -2.0, 30.0]
    "#;
    let m = Machine::from_toml_str(text, "6-axis").unwrap();
    let n = check(m, 11);
    assert!(n > 5000, "{n} derivatives checked");
}

#[test]
fn tracker_on_the_frame() {
    let text = Machine::default_xcfz().spec().clone();
    let mut spec = text;
    spec.tracker.mount = volver::core::machine::TrackerMount::Frame;
    spec.chain = "FXZC".into();
    let m = Machine::from_spec(spec, "frame-mounted").unwrap();
    check(m, 5);
}

/// The residuals whitened by the tracker's noise (what candidates are scored on): their
/// Jacobian against central differences of their own residuals, at random parameters of the
/// paper's model on a simulated test 4.
#[test]
fn whitened_residuals() {
    use volver::core::noise::TrackerNoise;
    use volver::core::problem::{Problem, Residuals};
    let m = Machine::default_xcfz();
    let model = Model::default_xcfz();
    let truth = volver::core::simulate::Truth::random_complete(
        &m,
        &volver::core::simulate::Magnitudes::default(),
        3,
    )
    .unwrap();
    let plan = volver::core::plan::Plan::preset(&m, "test4").unwrap();
    let data = volver::core::simulate::Simulation::new(plan, truth, 3)
        .run()
        .unwrap()
        .measurements;
    let problem = Problem::new(&model, &data).unwrap();
    let noise = TrackerNoise::from_text("normal:10,20,2,0.5").unwrap();
    let w = problem.whitened(Some(&noise)).unwrap();
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let p = random_params(&model, &mut rng);
    let n = model.n_params();
    let mut jac = vec![0.0; 3 * n];
    let mut checked = 0;
    let mut raw = vec![0.0; 3 * n];
    for i in (0..w.n_points()).step_by(97) {
        w.residual_and_jacobian(i, &p, &mut jac);
        w.plain().residual_and_jacobian(i, &p, &mut raw);
        // The whitening mixes the three rows: differences are judged against the column's
        // size times the whitening's gain (1e-6 relative, as the raw Jacobian's test).
        let rows = noise.whitening(data.points[i].measured).unwrap();
        let gain = rows
            .iter()
            .map(|r| (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt())
            .fold(0.0, f64::max);
        for (j, info) in model.params().iter().enumerate() {
            let h = fd_step(info);
            let (mut a, mut b) = (p.clone(), p.clone());
            a[j] += h;
            b[j] -= h;
            let (ra, rb) = (w.residual(i, &a), w.residual(i, &b));
            for c in 0..3 {
                let fd = (ra[c] - rb[c]) / (2.0 * h);
                let an = jac[c * n + j];
                let column = (0..3).map(|k| raw[k * n + j].powi(2)).sum::<f64>().sqrt();
                assert!(
                    (fd - an).abs() <= 1e-6 * (gain * column).max(1.0),
                    "point {i}, {} row {c}: {an} vs {fd}",
                    info.name
                );
                checked += 1;
            }
        }
    }
    assert!(checked > 1000);
}
