//! What a layout can and cannot measure, in words (`volver layout --plan`, the start of
//! `volver identify`): axes a floor tracker cannot see, errors that need more positions than a
//! plan has, and the combinations two reflectors and a tracker on the turntable leave open.

mod common;

use volver::core::machine::{Machine, TrackerMount};
use volver::core::model::Model;
use volver::core::plan::Plan;
use volver::solvers::observability::{Finding, Kind, nominal_data, observe};

fn mill(mount: TrackerMount) -> (Machine, Model) {
    let mut m = Machine::load(std::path::Path::new("tests/data/mill/yxfz-floor.toml")).unwrap();
    let mut spec = m.spec().clone();
    spec.tracker.mount = mount;
    m = Machine::from_spec(spec, "mill").unwrap();
    let model = Model::load(
        m.clone(),
        std::path::Path::new("tests/data/mill/cubic.toml"),
    )
    .unwrap();
    (m, model)
}

fn findings(model: &Model, grid: &str) -> Vec<Finding> {
    let plan = Plan::parse_grid(model.machine(), grid).unwrap();
    observe(model, &nominal_data(model, &plan), &model.initial_params())
}

/// A floor tracker on a table-moving mill sees neither table axis; the same tracker on the
/// table sees both.
#[test]
fn a_floor_tracker_cannot_see_the_table_axes() {
    let grid = "Y=0:500:125,X=0:800:200,Z=0:500:125";
    let (_, model) = mill(TrackerMount::Frame);
    let f = findings(&model, grid);
    let unseen: Vec<_> = f.iter().filter(|f| f.kind == Kind::Unseen).collect();
    assert_eq!(unseen.len(), 2, "{f:#?}");
    let axes: Vec<_> = unseen.iter().filter_map(|f| f.axis).collect();
    assert!(
        axes.contains(&volver::core::iso::Axis::X) && axes.contains(&volver::core::iso::Axis::Y)
    );
    for u in &unseen {
        assert!(
            u.what.contains("cannot be measured") && u.what.contains("frame"),
            "{}",
            u.what
        );
        assert!(u.fix.contains("tracker on the workpiece side"), "{}", u.fix);
    }
    let (_, model) = mill(TrackerMount::Workpiece);
    let f = findings(&model, grid);
    assert!(f.iter().all(|f| f.kind != Kind::Unseen), "{f:#?}");
}

/// Three positions of Z cannot fix a cubic; four can.
#[test]
fn a_cubic_needs_four_positions() {
    let (_, model) = mill(TrackerMount::Workpiece);
    let f = findings(&model, "Y=0:500:125,X=0:800:200,Z=0:500:250");
    let few: Vec<_> = f
        .iter()
        .filter(|f| f.kind == Kind::TooFewPositions)
        .collect();
    assert_eq!(few.len(), 1, "{f:#?}");
    assert!(
        few[0]
            .what
            .contains("need at least 4 positions of Z; the plan has 3"),
        "{}",
        few[0].what
    );
    assert!(
        few[0].fix.contains("lower their degree to 2"),
        "{}",
        few[0].fix
    );
    let f = findings(&model, "Y=0:500:125,X=0:800:200,Z=0:500:125");
    assert!(f.iter().all(|f| f.kind != Kind::TooFewPositions), "{f:#?}");
}

/// The paper's test 4: the tool's turn about the line through R1 and R2, and the tracker's pose
/// against EZC.d and the first harmonics, with the measurement that would fix each.
#[test]
fn test4_names_what_two_reflectors_and_a_turntable_tracker_leave_open() {
    let model = Model::default_xcfz();
    let plan = Plan::preset(model.machine(), "test4").unwrap();
    let f = observe(
        &model,
        &nominal_data(&model, &plan),
        &model.initial_params(),
    );
    let open: Vec<_> = f.iter().filter(|f| f.kind == Kind::Unidentified).collect();
    assert_eq!(open.len(), 2, "{f:#?}");
    assert!(open[0].what.contains("ECZ") && open[0].fix.contains("third reflector"));
    assert!(open[1].what.contains("tracker.z") && open[1].what.contains("EZC.d"));
    assert!(open[1].fix.contains("second tracker position"));
}

/// `volver layout --plan` prints the statement.
#[test]
fn layout_prints_what_the_plan_can_measure() {
    let out = common::volver(&[
        "layout",
        "--machine",
        "tests/data/mill/yxfz-floor.toml",
        "--model",
        "tests/data/mill/cubic.toml",
        "--plan",
        "Y=0:500:250,X=0:800:200,Z=0:500:250",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("moves nothing it measures"), "{text}");
    assert!(
        text.contains("need at least 4 positions of Z; the plan has 3"),
        "{text}"
    );
}

/// A line of EXX (its two coefficients tied by the reference constraint), a constant ECC and
/// B0Z on test 4: everything is identified while the tracker's angles are held; with them free,
/// the tracker standing on the C axis turns about z exactly as a constant ECC does, and that one
/// combination is named.
#[test]
fn a_tracker_on_the_c_axis_and_a_constant_ecc_are_one_motion() {
    let text = |identify: &str| {
        format!(
            "name = \"hand\"\n[[error]]\nname = \"EXX\"\nbasis = \"monomial\"\ndegree = 1\n\
             [[error]]\nname = \"ECC\"\nbasis = \"fourier\"\norder = 1\n[[error]]\nname = \"B0Z\"\n\
             [tracker]\nidentify = [{identify}]\n"
        )
    };
    let m = Machine::default_xcfz();
    let plan = Plan::preset(&m, "test4").unwrap();
    let held = Model::from_toml_str(m.clone(), &text("\"x\", \"y\", \"z\""), "h.toml").unwrap();
    let f = observe(&held, &nominal_data(&held, &plan), &held.initial_params());
    assert!(f.is_empty(), "{f:#?}");
    let free = Model::from_toml_str(
        m.clone(),
        &text("\"x\", \"y\", \"z\", \"rx\", \"ry\", \"rz\""),
        "f.toml",
    )
    .unwrap();
    let f = observe(&free, &nominal_data(&free, &plan), &free.initial_params());
    assert_eq!(f.len(), 1, "{f:#?}");
    assert!(f[0].what.contains("1 combination") && f[0].what.contains("tracker.rz"));
    assert!(f[0].what.contains("ECC.d"), "{}", f[0].what);
}
