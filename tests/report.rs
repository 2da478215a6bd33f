//! The report's cross-validation and figures on a gantry (FYXZ, 3000 × 2000 × 800 mm, three
//! reflectors, the tracker on the table), issue 44: cross-validation refits the measurement
//! alone and starts from `identify`'s baseline; the truth is drawn in the model's squareness
//! rule and gauge; the maps cover every plane of the linear axes. Release only (`scripts/test`):
//! each test fits a 96-parameter model to 1485 points. Also the reversal panel (issue 49).

use volver::core::iso::ErrorId;
use volver::core::machine::Machine;
use volver::core::measure::MeasurementSet;
use volver::core::model::Model;
use volver::core::noise::TrackerNoise;
use volver::core::plan::Plan;
use volver::core::problem::Problem;
use volver::core::simulate::{Effect, Magnitudes, Simulation, Synthetic, Truth};
use volver::report::{Fit, ReportInput, html, truth_in_model};
use volver::solvers::lm::LevenbergMarquardt;
use volver::solvers::strategy::{Identification, cross_validate, fit};
use volver::solvers::uncertainty::{K, NoiseModel, linear};
use volver::solvers::{Options, Silent};

const GANTRY: &str = r#"
name = "FYXZ gantry mill"
chain = "FYXZ"
[axes.Y]
range = [0.0, 2000.0]
[axes.X]
range = [0.0, 3000.0]
[axes.Z]
range = [0.0, 800.0]
offset = [0.0, 0.0, 1200.0]
[[reflector]]
id = "R1"
offset = [0.0, 0.0, -150.0]
[[reflector]]
id = "R2"
offset = [80.0, 0.0, -250.0]
[[reflector]]
id = "R3"
offset = [0.0, 80.0, -200.0]
[tracker]
mount = "workpiece"
position = [1500.0, 1000.0, 0.0]
"#;

/// Cubic errors of every axis, the squareness rule from-straightness (A0Y left to EZY's slope),
/// and `extra` appended (effects).
fn model_toml(extra: &str) -> String {
    format!(
        r#"name = "cubic errors of every axis"
squareness = "from-straightness"
[[error]]
name = ["EXX", "EYX", "EZX", "EAX", "EBX", "ECX", "EXY", "EYY", "EZY", "EAY", "EBY", "ECY", "EXZ", "EYZ", "EZZ", "EAZ", "EBZ", "ECZ"]
basis = "legendre"
degree = 3
[[error]]
name = ["A0Z", "B0Z", "C0Y"]
{extra}"#
    )
}

fn gantry() -> Machine {
    Machine::from_toml_str(GANTRY, "gantry.toml").unwrap()
}

/// The grid of the issue (495 positions × 3 reflectors), a random complete truth (its
/// squareness carried separately: A0Y, C0Y, A0Z, B0Z), the tracker `noise` (`--noise`), the
/// hidden `effects`, seeded.
fn simulate(m: &Machine, noise: &str, effects: &[&str], seed: u64) -> Synthetic {
    let plan = Plan::parse_grid(m, "X=0:3000:300,Y=0:2000:250,Z=0:800:200").unwrap();
    let truth = Truth::random_complete(m, &Magnitudes::default(), 3).unwrap();
    let mut sim = Simulation::new(plan, truth, seed);
    sim.noise = TrackerNoise::from_text(noise).unwrap();
    sim.effects = effects.iter().map(|e| Effect::parse(e).unwrap()).collect();
    sim.run().unwrap()
}

fn fitted(model: &Model, data: &MeasurementSet) -> Identification {
    let id = fit(Problem::new(model, data).unwrap());
    assert!(!id.termination.failed(), "{}", id.termination);
    id
}

/// With a field over X and Y (machine geometry) and a thermal drift (the test's own), the
/// cross-validation on a reference set refits the drift and the tracker only: every machine
/// parameter, the field's included, keeps the fit's value to the bit, and the baseline ("EMM
/// before") is the initial EMM an identification of the reference prints (to 1e-9 relative:
/// the same evaluation, so equal in practice). On the fit's own data it ends where the fit
/// ended (to 1e-6 relative: the refit of the drift and tracker converges to the optimum the fit
/// reached; measured 0). Before issue 44 it refitted the field too: on the closing note's CLI
/// case, baseline 60.37 µm against identify's 64.31 µm.
#[test]
#[cfg_attr(debug_assertions, ignore = "release only (scripts/test)")]
fn cross_validation_refits_only_the_measurement() {
    let m = gantry();
    let model = Model::from_toml_str(
        m.clone(),
        &model_toml("[effects]\nthermal_drift = true\nfield = [\"X*Y\"]\n"),
        "model.toml",
    )
    .unwrap();
    let kind = |prefix: &str| {
        (0..model.n_params())
            .filter(|&j| model.params()[j].name.starts_with(prefix))
            .collect::<Vec<_>>()
    };
    let (field, drift) = (kind("field."), kind("drift."));
    assert!(!field.is_empty() && !drift.is_empty());
    assert!(field.iter().all(|&j| !model.is_measurement_param(j)));
    assert!(drift.iter().all(|&j| model.is_measurement_param(j)));
    assert_eq!(
        volver::report::measurement_parts(&model),
        ["tracker pose", "tool drift"]
    );

    let effects = ["coupling=X,Z,Y,20", "thermal-drift=5,3,2"];
    let data = simulate(&m, "mpe:15,6", &effects, 3).measurements;
    let reference = simulate(&m, "mpe:15,6", &effects, 4).measurements;
    let id = fitted(&model, &data);
    for (label, set) in [("same data", &data), ("independent reference", &reference)] {
        let problem = Problem::new(&model, set).unwrap();
        let cv = cross_validate(
            &LevenbergMarquardt::default(),
            problem.clone(),
            &id.params,
            &Options::default(),
            &mut Silent,
        );
        assert!(!cv.termination.failed(), "{label}: {}", cv.termination);
        let own = fitted(&model, set);
        let (a, b) = (cv.initial.stats.emm_um, own.initial.stats.emm_um);
        eprintln!(
            "{label}: baseline {a:.6} µm, identify's initial {b:.6} µm; after {:.6} µm (fit {:.6})",
            cv.reached.stats.emm_um, own.reached.stats.emm_um
        );
        assert!(
            (a - b).abs() <= 1e-9 * b,
            "{label}: baseline {a} against {b}"
        );
        for j in (0..model.n_params()).filter(|&j| !model.is_measurement_param(j)) {
            assert_eq!(
                cv.params[j].to_bits(),
                id.params[j].to_bits(),
                "{label}: {} moved",
                model.params()[j].name
            );
        }
    }
    let same = cross_validate(
        &LevenbergMarquardt::default(),
        Problem::new(&model, &data).unwrap(),
        &id.params,
        &Options::default(),
        &mut Silent,
    );
    let (a, b) = (same.reached.stats.emm_um, id.reached.stats.emm_um);
    assert!(
        (a - b).abs() <= 1e-6 * b,
        "after {a} µm against the fit's {b} µm"
    );
}

/// The value of error `e` of the fit at `u` (mm), its U (k = 2) from the data (the held
/// combinations' prior left out: the truth is moved onto the same gauge), and the truth's value
/// there.
fn at(
    model: &Model,
    id: &Identification,
    cov: &volver::solvers::uncertainty::Covariance,
    truth: &[f64],
    e: ErrorId,
    u: f64,
) -> (f64, f64, f64) {
    let t = model.term(e).unwrap();
    let mut g = vec![0.0; model.n_params()];
    let v = model
        .error_value_gradient(e, u, &id.params, &mut g[t.params.clone()])
        .unwrap();
    let w = model.error_value(e, u, truth).unwrap();
    (v, K * cov.u_data(&g), w)
}

/// A truth that carries its squareness separately (A0Y, C0Y, A0Z, B0Z, the rule `separate`)
/// against a fit whose rule takes it from the straightness (A0Y not even modelled), no hidden
/// effect, a low noise (1 µrad, 0.2 µm): at the far end of every axis' travel, each identified
/// component error and the truth drawn beside it (the truth in the model's parameters,
/// [`truth_in_model`]) differ by at most 1.5 U (k = 2 from the data, 3 σ; the band drawn adds
/// the held combinations' prior, on which the two agree) and at least 16 of the 18 by at most
/// U (measured: all 18, the largest 0.8 U). The truth taken by
/// name, as the report drew it before issue 44, misses EZY by more than 3 U (its slope is
/// A0Y's): the check can fail. The conversion is exact here (the truth lies in the model's span): what
/// the model cannot express of it is below 1e-3 µm.
#[test]
#[cfg_attr(debug_assertions, ignore = "release only (scripts/test)")]
fn the_truth_is_drawn_in_the_models_squareness_rule_and_gauge() {
    let m = gantry();
    let model = Model::from_toml_str(m.clone(), &model_toml(""), "model.toml").unwrap();
    let sim = simulate(&m, "1,1,0.2,0.05", &[], 5);
    let data = &sim.measurements;
    let id = fitted(&model, data);
    let problem = Problem::new(&model, data).unwrap();
    let cov = linear(
        &problem,
        id.gauge.as_ref(),
        &id.params,
        Options::default().objective,
        NoiseModel::Residual,
    )
    .unwrap();
    let conv = truth_in_model(&model, data, (&sim.truth.model, &sim.truth.params)).unwrap();
    assert!(conv.misfit_um < 1e-3, "misfit {} µm", conv.misfit_um);
    let by_name: Vec<f64> = model
        .params()
        .iter()
        .map(|p| {
            sim.truth
                .model
                .param_index(&p.name)
                .map_or(0.0, |k| sim.truth.params[k])
        })
        .collect();
    let (mut within, mut total, mut worst, mut worst_by_name) = (0, 0, 0.0_f64, 0.0_f64);
    for t in model.terms() {
        let ErrorId::Component { .. } = t.id else {
            continue;
        };
        let u = m.axes()[t.axis].max;
        let (v, big_u, w) = at(&model, &id, &cov, &conv.params, t.id, u);
        let (_, _, w0) = at(&model, &id, &cov, &by_name, t.id, u);
        let r = (v - w).abs() / big_u;
        let (scale, unit) = t.id.unit().micro();
        eprintln!(
            "{} at {u} mm: fit {:.3} ± {:.3}, truth {:.3} (by name {:.3}) {unit}: {r:.2} U",
            t.id,
            v * scale,
            big_u * scale,
            w * scale,
            w0 * scale
        );
        total += 1;
        within += usize::from(r <= 1.0);
        worst = worst.max(r);
        worst_by_name = worst_by_name.max((v - w0).abs() / big_u);
    }
    assert_eq!(total, 18);
    assert!(worst <= 1.5, "a function {worst:.2} U from its truth");
    assert!(within >= 16, "{within} of 18 within U");
    assert!(
        worst_by_name > 3.0,
        "the truth by name is within {worst_by_name:.2} U: the case carries no squareness"
    );
}

/// A gantry's report maps the error and the tool point's U in the X–Y, X–Z and Y–Z planes; the
/// XCFZ grinder's (one linear plane) in X–Z alone.
#[test]
#[cfg_attr(debug_assertions, ignore = "release only (scripts/test)")]
fn the_maps_cover_every_plane_of_the_linear_axes() {
    let m = gantry();
    let model = Model::from_toml_str(m.clone(), &model_toml(""), "model.toml").unwrap();
    let data = simulate(&m, "mpe:15,6", &[], 6).measurements;
    let id = fitted(&model, &data);
    let fits = vec![Fit {
        label: "gantry".into(),
        model: &model,
        id: &id,
    }];
    let page = html(&ReportInput::new("gantry", "gantry.csv", &data, fits)).unwrap();
    for plane in ["X–Y", "X–Z", "Y–Z"] {
        assert!(
            page.contains(&format!("Error module in the {plane} plane")),
            "{plane}"
        );
        assert!(
            page.contains(&format!("compensated tool point in the {plane} plane")),
            "{plane} U"
        );
    }
    let xcfz = Model::default_xcfz();
    let plan = Plan::preset(xcfz.machine(), "test4").unwrap();
    let truth = Truth::random(xcfz.machine(), xcfz.spec(), &Magnitudes::default(), 1).unwrap();
    let data = Simulation::new(plan, truth, 1).run().unwrap().measurements;
    let id = fitted(&xcfz, &data);
    let fits = vec![Fit {
        label: "paper".into(),
        model: &xcfz,
        id: &id,
    }];
    let page = html(&ReportInput::new("xcfz", "xcfz.csv", &data, fits)).unwrap();
    assert_eq!(page.matches("Error module in the ").count(), 1);
    assert!(page.contains("Error module in the X–Z plane"));
}

/// The one rule of what belongs to the measurement ([`Model::is_measurement_param`]) is what
/// the tool point leaves out: over a grid of each machine's volume, a step of any measurement
/// parameter leaves [`Model::tool_point`] unchanged to the bit, and a step of any other moves
/// it somewhere, with every kind of effect the model files offer (on the gantry: drift,
/// reflector offset, range scale, scale growth, the tracker's drift, ball screw, fields over
/// axes and over time; on the XCFZ grinder: the location drift of C, a field over C and t, and
/// the reversal of X and C, the tool point taken with every axis arriving moving forward).
#[test]
fn the_measurement_is_what_the_tool_point_leaves_out() {
    let gantry = Model::from_toml_str(
        gantry(),
        &model_toml(
            "[effects]\nthermal_drift = true\nreflector_offset = [\"R1\"]\nrange_scale = true\n\
             thermal_scale = [\"X\"]\ntracker_drift = true\nfield = [\"X*Y\", \"Y*t\", \"Z\"]\n\
             [[effects.ball_screw]]\naxis = \"X\"\nperiod_mm = 700.0\n",
        ),
        "gantry-model.toml",
    )
    .unwrap();
    let xcfz = Model::from_toml_str(
        Machine::default_xcfz(),
        &format!(
            "{}\n[effects]\nlocation_drift = [\"C\"]\nfield = [\"C*t\"]\nreversal = [\"X\", \"C\"]\n",
            volver::core::model::DEFAULT_MODEL_TOML
        ),
        "xcfz-model.toml",
    )
    .unwrap();
    for model in [&gantry, &xcfz] {
        let n = model.n_params();
        // Every parameter away from zero, so that no step meets a zero factor.
        let params: Vec<f64> = (0..n)
            .map(|j| model.initial_params()[j] + 1e-5 * (1.0 + (j % 7) as f64))
            .collect();
        let grid = volver::uncertainty::default_grid(model.machine(), 3).unwrap();
        let tool = volver::compensation::reflector_centroid(model);
        // Every axis arriving moving forward: a reversal moves the tool point then.
        let state = volver::core::model::PointState {
            t_s: 0.0,
            approach: volver::core::approach::Approach::all(model.machine().axes().len(), 1),
        };
        for (j, info) in model.params().iter().enumerate() {
            let mut q = params.clone();
            q[j] += 1e-3;
            let moves = grid.positions.iter().any(|c| {
                model.tool_point_in(&c.0, &tool, state, &q)
                    != model.tool_point_in(&c.0, &tool, state, &params)
            });
            assert_eq!(
                moves,
                !model.is_measurement_param(j),
                "{}: moves the tool point {moves}, measurement {}",
                info.name,
                model.is_measurement_param(j)
            );
        }
    }
}

/// The reversal panel: XCFZ test 4 in a shuffled order with a hidden reversal of X (30 µm) and
/// C (−60 µrad), the paper's noise (the embedded machine's, which the report's U uses); the
/// paper's model with `reversal = ["X", "C"]` fitted; the
/// report's panel gives each B with its U (k = 2), and the truth lies within it (coverage at
/// k = 2; fixed seed), with the counts of points approached forward and in reverse.
#[test]
#[cfg_attr(debug_assertions, ignore = "release only (scripts/test)")]
fn the_reversal_panel_gives_each_b_with_its_u() {
    let m = Machine::default_xcfz();
    let truth = Truth::random(&m, Model::default_xcfz().spec(), &Magnitudes::default(), 5).unwrap();
    let plan = Plan::preset(&m, "test4").unwrap().shuffled(5);
    let mut sim = Simulation::new(plan, truth, 5);
    sim.noise = TrackerNoise::PAPER;
    sim.effects = ["reversal=X,30", "reversal=C,-60"]
        .iter()
        .map(|e| Effect::parse(e).unwrap())
        .collect();
    let data = sim.run().unwrap().measurements;
    let text = format!(
        "{}\n[effects]\nreversal = [\"X\", \"C\"]\n",
        volver::core::model::DEFAULT_MODEL_TOML
    );
    let model = Model::from_toml_str(m, &text, "model.toml").unwrap();
    let id = fitted(&model, &data);
    let fit = Fit {
        label: "with reversal".into(),
        model: &model,
        id: &id,
    };
    let page = html(&ReportInput::new("reversal", "data.csv", &data, vec![fit])).unwrap();
    let at = page
        .find("Reversal (direction of approach)")
        .expect("the panel");
    let panel = &page[at..at + page[at..].find("</table>").unwrap()];
    for (axis, unit, truth) in [("X", "µm", 30.0), ("C", "µrad", -60.0)] {
        let row = panel
            .split("<tr>")
            .find(|r| r.contains(&format!("<td>{axis}</td>")))
            .unwrap_or_else(|| panic!("no row for {axis}: {panel}"));
        let cell = row.split("<td>").nth(2).unwrap();
        let (b, rest) = cell.split_once(" ± ").unwrap();
        let u = rest.split_once(&format!(" {unit}")).unwrap().0;
        let (b, u): (f64, f64) = (b.parse().unwrap(), u.parse().unwrap());
        println!("{axis}: B {b} ± {u} {unit} (truth {truth})");
        assert!((b - truth).abs() <= u, "{axis}: {b} ± {u} against {truth}");
        assert!(
            u < 0.2 * truth.abs(),
            "{axis}: U {u} is no measurement of {truth}"
        );
        assert!(row.contains(" / "), "{row}");
    }
}
