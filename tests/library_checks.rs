//! The checks the library makes before a result reaches a machine or a plan (issue 45: they
//! moved out of the CLI into `volver::compensation::{vouch, check_on_truth}` and
//! `volver::planning::Request`): what a library user gets for inputs that would give
//! meaningless numbers — a typed error of the right kind, never a panic, a NaN reported as a
//! pass, or a number that looks plausible.

use volver::Error;
use volver::compensation::{check_on_truth, reflector_centroid, travel_grid, vouch};
use volver::core::compensate::Compensator;
use volver::core::model::Model;
use volver::core::plan::Plan;
use volver::core::results::UncertaintyRecord;
use volver::core::simulate::{Magnitudes, Simulation, Truth};
use volver::identification::{Settings, identify};
use volver::planning::Request;

/// The embedded XCFZ model identified on a simulated test 3, with its uncertainty record.
fn identified() -> (Model, Vec<f64>, UncertaintyRecord) {
    let model = Model::default_xcfz();
    let m = model.machine().clone();
    let truth = Truth::random(&m, model.spec(), &Magnitudes::default(), 1).unwrap();
    let plan = Plan::preset(&m, "test3").unwrap();
    let data = Simulation::new(plan, truth, 1).run().unwrap().measurements;
    let o = identify(
        &model,
        &data,
        &Settings::default(),
        &mut volver::solvers::Silent,
    )
    .unwrap();
    let record = o
        .results
        .uncertainty
        .clone()
        .expect("a converged fit records its U");
    (model, o.id.params.clone(), record)
}

#[test]
fn the_u_gate_refuses_what_it_cannot_vouch_for_with_an_error_of_its_kind() {
    let (model, params, record) = identified();
    let tool = reflector_centroid(&model);
    // The fit itself passes a generous limit and is refused below its U.
    let ok = vouch(&model, &params, Some(&record), tool, 1e4).unwrap();
    assert!(ok.enforce().is_ok(), "{:?}", ok.statements);
    let u_um = ok.u.as_ref().unwrap().aligned_mm * 1e3;
    assert!(u_um.is_finite() && u_um > 0.0, "U {u_um} µm");
    let tight = vouch(&model, &params, Some(&record), tool, 0.5 * u_um).unwrap();
    assert!(matches!(tight.enforce(), Err(Error::Refused(_))));
    // A limit that is no length, errors that are not the model's, a tool point not finite.
    for limit in [f64::NAN, f64::INFINITY, -1.0, 0.0] {
        let e = vouch(&model, &params, Some(&record), tool, limit).unwrap_err();
        assert!(matches!(e, Error::Request(_)), "limit {limit}: {e:?}");
    }
    let e = vouch(&model, &params[..3], Some(&record), tool, 50.0).unwrap_err();
    assert!(matches!(e, Error::Mismatch(_)), "{e:?}");
    let mut nan = params.clone();
    nan[5] = f64::NAN;
    let e = vouch(&model, &nan, Some(&record), tool, 50.0).unwrap_err();
    assert!(matches!(e, Error::Request(_)), "{e:?}");
    let e = vouch(&model, &params, Some(&record), [f64::NAN, 0.0, 0.0], 50.0).unwrap_err();
    assert!(matches!(e, Error::Request(_)), "{e:?}");
    // A record of another model: its columns do not fit this model's parameters.
    let other = volver::core::presets::named("head-head")
        .unwrap()
        .model()
        .unwrap();
    let e = vouch(
        &other,
        &other.initial_params(),
        Some(&record),
        [0.0; 3],
        50.0,
    )
    .unwrap_err();
    assert!(
        matches!(&e, Error::Core(volver::core::Error::Input { .. })),
        "{e:?}"
    );
    // No record: refused (nothing vouches), overridable by the caller.
    let none = vouch(&model, &params, None, tool, 50.0).unwrap();
    assert!(matches!(none.enforce(), Err(Error::Refused(_))));
}

#[test]
fn a_compensation_is_checked_only_against_a_truth_it_can_be_compared_with() {
    let model = Model::default_xcfz();
    let params = model.initial_params();
    let tool = reflector_centroid(&model);
    let comp = Compensator::new(&model, &params, tool).unwrap();
    let grid = travel_grid(model.machine(), 3).unwrap();
    // The nominal machine compensated with its own (zero) errors: nothing to correct.
    let same = check_on_truth(&comp, &comp, &grid).unwrap();
    assert!(same.before.emm_um < 1e-6 && same.after.emm_um < 1e-6);
    assert_eq!(same.grid.len(), 27);
    // An empty grid would read as a perfect compensation.
    let e = check_on_truth(&comp, &comp, &[]).unwrap_err();
    assert!(matches!(e, Error::Request(_)), "{e:?}");
    // A truth of another machine, a truth at another tool point, a grid of another machine.
    let other = volver::core::presets::named("head-head")
        .unwrap()
        .model()
        .unwrap();
    let other_params = other.initial_params();
    let foreign = Compensator::new(&other, &other_params, tool).unwrap();
    let e = check_on_truth(&comp, &foreign, &grid).unwrap_err();
    assert!(matches!(e, Error::Mismatch(_)), "{e:?}");
    let elsewhere = Compensator::new(&model, &params, [0.0, 0.0, 100.0]).unwrap();
    let e = check_on_truth(&comp, &elsewhere, &grid).unwrap_err();
    assert!(matches!(e, Error::Mismatch(_)), "{e:?}");
    let their_grid = travel_grid(other.machine(), 2).unwrap();
    let e = check_on_truth(&comp, &comp, &their_grid).unwrap_err();
    assert!(matches!(e, Error::Mismatch(_)), "{e:?}");
}

#[test]
fn plan_requests_are_refused_as_requests_naming_what_is_wrong() {
    let refused = |r: Request, says: &str| {
        let e = r.validate().unwrap_err();
        assert!(matches!(e, Error::Request(_)), "{e:?}");
        assert!(e.to_string().contains(says), "{e}");
    };
    let base = Request::default;
    refused(
        Request {
            points: 0,
            ..base()
        },
        "0 measurements",
    );
    refused(
        Request {
            per_axis: 1,
            ..base()
        },
        "--per-axis 1",
    );
    refused(
        Request {
            repeats: 1040,
            ..base()
        },
        "--repeats 1040",
    );
    refused(
        Request {
            iterations: 0,
            ..base()
        },
        "0 iterations",
    );
    refused(
        Request {
            seconds_per_point: f64::NAN,
            ..base()
        },
        "--seconds-per-point",
    );
    refused(
        Request {
            tool: [0.0, f64::INFINITY, 0.0],
            ..base()
        },
        "tool offset",
    );
    assert_eq!(Request::points_for_hours(2.0, 6.0, 2).unwrap(), 600);
    assert!(matches!(
        Request::points_for_hours(2.0, 6.0, 0),
        Err(Error::Request(_))
    ));
    // Two candidate reflectors of one id are named as such (not as the machine's).
    let extra = |id: &str, z: f64| volver::core::machine::ReflectorSpec {
        id: id.into(),
        offset: [0.0, 0.0, z],
    };
    let r = Request {
        extra_reflectors: vec![extra("E1", 50.0), extra("E1", 80.0)],
        ..base()
    };
    let e = volver::planning::plan(&Model::default_xcfz(), &r).unwrap_err();
    assert!(e.to_string().contains("another candidate reflector"), "{e}");
}
