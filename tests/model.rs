//! Error models: parameter layout, constraints (reference position, squareness from
//! straightness, fixed parameters), bad input, results files.

use volver::core::iso::{ErrorId, Group, Unit};
use volver::core::machine::Machine;
use volver::core::model::{ConstraintKind, Model};
use volver::core::results::ResultsFile;
use volver::solvers::nullspace::NullSpace;

fn id(s: &str) -> ErrorId {
    s.parse().unwrap()
}

/// The paper machine with Z's reference moved inside the range, to test a reference that is not
/// the range's lower end.
fn machine_with_reference(z_ref: f64) -> Machine {
    let mut spec = Machine::default_xcfz().spec().clone();
    spec.axes.get_mut("Z").unwrap().reference = z_ref;
    Machine::from_spec(spec, "test").unwrap()
}

#[test]
fn paper_layout_names_units_groups() {
    let m = Model::default_xcfz();
    assert_eq!(m.n_params(), 74);
    let p = |n: &str| &m.params()[m.param_index(n).unwrap_or_else(|| panic!("{n}"))];
    assert_eq!(
        (p("EYX.c2").unit, p("EYX.c2").group),
        (Unit::Mm, Group::Translation)
    );
    assert_eq!(
        (p("EBZ.c3").unit, p("EBZ.c3").group),
        (Unit::Rad, Group::Rotation)
    );
    assert_eq!(
        (p("ECC.a1").unit, p("ECC.b1").group),
        (Unit::Rad, Group::Rotation)
    );
    assert_eq!(
        (p("B0Z").unit, p("B0Z").group),
        (Unit::Rad, Group::Squareness)
    );
    assert_eq!(
        (p("tracker.rx").unit, p("tracker.z").group),
        (Unit::Rad, Group::Tracker)
    );
    let kinds = |k| m.constraints().rows.iter().filter(|r| r.kind == k).count();
    assert_eq!(kinds(ConstraintKind::Reference), 12);
    assert_eq!(kinds(ConstraintKind::Squareness), 2);
    assert_eq!(kinds(ConstraintKind::Fixed), 3);
    assert_eq!(m.constraints().max_violation(&m.initial_params()), 0.0);
}

#[test]
fn linear_axis_errors_vanish_at_the_reference_in_every_basis() {
    for (basis, deg) in [
        ("monomial", "degree = 3"),
        ("legendre", "degree = 5"),
        ("chebyshev", "nodes = 4"),
    ] {
        let text = format!(
            "squareness = \"none\"\n[[error]]\nname = [\"EXZ\", \"EAZ\", \"EYX\"]\nbasis = \"{basis}\"\n{deg}\n\
             [[error]]\nname = \"EXC\"\nbasis = \"fourier\"\norder = 2\n"
        );
        let model = Model::from_toml_str(machine_with_reference(350.0), &text, "m.toml").unwrap();
        let ns = NullSpace::for_model(&model).unwrap();
        // Reference rows for 3 linear-axis errors + 6 fixed tracker values? No: all six tracker
        // values are identified by default, so only the 3 reference rows.
        assert_eq!(ns.rank(), 3, "{basis}");
        let z: Vec<f64> = (0..ns.n_free())
            .map(|i| 0.01 * ((i * 7 % 5) as f64 - 2.0))
            .collect();
        let p = ns.expand(&z);
        for (e, pos) in [("EXZ", 350.0), ("EAZ", 350.0), ("EYX", 0.0)] {
            let v = model.error_value(id(e), pos, &p).unwrap();
            assert!(v.abs() < 1e-15, "{basis} {e}({pos}) = {v}");
            let elsewhere = model.error_value(id(e), 600.0, &p).unwrap();
            assert!(
                elsewhere.abs() > 1e-6,
                "{basis} {e} is not identically zero"
            );
        }
        // Rotary-axis errors keep their constant D.
        let t = model.term(id("EXC")).unwrap();
        assert!(
            !model
                .constraints()
                .rows
                .iter()
                .any(|r| r.coeffs.iter().any(|(j, _)| t.params.contains(j)))
        );
    }
}

#[test]
fn squareness_and_straightness_slope_are_the_same_motion() {
    // Z with only A0Z, versus Z with only a linear EYZ: equal predictions when A0Z = −slope,
    // and Model::squareness reports the same value for both.
    let only_sq = Model::from_toml_str(
        Machine::default_xcfz(),
        "[[error]]\nname = \"A0Z\"\n",
        "a.toml",
    )
    .unwrap();
    let only_st = Model::from_toml_str(
        Machine::default_xcfz(),
        "[[error]]\nname = \"EYZ\"\nbasis = \"legendre\"\ndegree = 1\n",
        "b.toml",
    )
    .unwrap();
    let slope_per_mm = 2e-5;
    let mut p_st = only_st.initial_params();
    // EYZ(ξ) = c0 + c1 ξ, ξ = z/300 − 1; vanishing at z = 0: c0 = c1; slope c1/300 per mm.
    let c1 = slope_per_mm * 300.0;
    p_st[only_st.param_index("EYZ.c0").unwrap()] = c1;
    p_st[only_st.param_index("EYZ.c1").unwrap()] = c1;
    assert!(only_st.constraints().max_violation(&p_st) < 1e-18);
    let mut p_sq = only_sq.initial_params();
    p_sq[only_sq.param_index("A0Z").unwrap()] = -slope_per_mm;
    for pos in [
        [0.0, 0.0, 0.0],
        [700.0, 45.0, 300.0],
        [1400.0, 300.0, 600.0],
    ] {
        let cmd = only_st.machine().commands_from_file_units(&pos);
        let (a, b) = (
            only_st.predict(&cmd, 1, &p_st),
            only_sq.predict(&cmd, 1, &p_sq),
        );
        for i in 0..3 {
            assert!((a[i] - b[i]).abs() < 1e-12, "{pos:?}");
        }
    }
    let sq_st = only_st.squareness(&p_st);
    let sq_sq = only_sq.squareness(&p_sq);
    assert_eq!(sq_st.len(), 1);
    assert_eq!(sq_st[0].0, id("A0Z"));
    assert!((sq_st[0].1 - sq_sq[0].1).abs() < 1e-18 && (sq_st[0].1 + slope_per_mm).abs() < 1e-18);
}

#[test]
fn squareness_rules() {
    let body = "[[error]]\nname = [\"EXZ\", \"EYZ\"]\nbasis = \"legendre\"\ndegree = 3\n[[error]]\nname = [\"A0Z\", \"B0Z\"]\n";
    let build = |rule: &str| {
        Model::from_toml_str(
            Machine::default_xcfz(),
            &format!("squareness = \"{rule}\"\n{body}"),
            "m.toml",
        )
        .unwrap()
    };
    // The paper's rule holds the squareness parameters at zero.
    let paper = build("from-straightness");
    let ns = NullSpace::for_model(&paper).unwrap();
    let p = ns.expand(
        &(0..ns.n_free())
            .map(|i| 0.003 * (1.0 + i as f64).sin())
            .collect::<Vec<_>>(),
    );
    assert!(p[paper.param_index("A0Z").unwrap()].abs() < 1e-15);
    // …and the squareness is read from the slope.
    let sq = paper.squareness(&p);
    assert!(sq.iter().all(|(_, v)| v.abs() > 1e-9), "{sq:?}");
    // The ISO split holds the straightness slope at zero: the squareness equals its parameter.
    let iso = build("separate");
    let ns = NullSpace::for_model(&iso).unwrap();
    let p = ns.expand(
        &(0..ns.n_free())
            .map(|i| 0.002 * (i as f64 - 3.0))
            .collect::<Vec<_>>(),
    );
    for (e, v) in iso.squareness(&p) {
        assert!(
            (v - p[iso.param_index(&e.to_string()).unwrap()]).abs() < 1e-15,
            "{e}"
        );
    }
    // No rule: two more free directions than either rule.
    let free = |m: &Model| NullSpace::for_model(m).unwrap().n_free();
    assert_eq!(free(&build("none")), free(&paper) + 2);
    assert_eq!(free(&paper), free(&iso));
}

#[test]
fn fixed_parameters_and_tracker_identification() {
    let text = "[[error]]\nname = \"EXX\"\nbasis = \"monomial\"\ndegree = 2\n[tracker]\nidentify = [\"x\", \"rz\"]\n[fixed]\n\"EXX.c2\" = 0.004\n";
    let m = Model::from_toml_str(Machine::default_xcfz(), text, "m.toml").unwrap();
    let p = m.initial_params();
    assert_eq!(p[m.param_index("EXX.c2").unwrap()], 0.004);
    let ns = NullSpace::for_model(&m).unwrap();
    // 3 + 6 parameters; reference row, EXX.c2, and 4 tracker values held.
    assert_eq!((m.n_params(), ns.rank(), ns.n_free()), (9, 6, 3));
    let q = ns.expand(&[0.1, 0.2, 0.3]);
    assert!((q[m.param_index("EXX.c2").unwrap()] - 0.004).abs() < 1e-15);
    assert!(q[m.param_index("tracker.ry").unwrap()].abs() < 1e-15);
}

fn model_err(text: &str) -> String {
    Model::from_toml_str(Machine::default_xcfz(), text, "m.toml")
        .unwrap_err()
        .to_string()
}

#[test]
fn bad_error_models_name_file_line_and_field() {
    let e =
        model_err("name = \"x\"\n\n[[error]]\nname = \"EQX\"\nbasis = \"legendre\"\ndegree = 3\n");
    assert!(
        e.starts_with("m.toml:4: field 'error.name'") && e.contains("not an ISO 230 error name"),
        "{e}"
    );
    let e = model_err("[[error]]\nname = \"EXY\"\nbasis = \"legendre\"\ndegree = 3\n");
    assert!(
        e.contains("axis Y, which the machine's chain XCFZ does not have"),
        "{e}"
    );
    let e = model_err("[[error]]\nname = [\"EXX\", \"EYX\"]\nbasis = \"fourier\"\norder = 1\n");
    assert!(
        e.starts_with("m.toml:2") && e.contains("X is a linear axis"),
        "{e}"
    );
    let e = model_err("[[error]]\nname = \"EXX\"\nbasis = \"legendre\"\n");
    assert!(e.contains("needs `degree`"), "{e}");
    let e = model_err("[[error]]\nname = \"EXX\"\nbasis = \"spline\"\ndegree = 3\n");
    assert!(e.starts_with("m.toml:3") && e.contains("spline"), "{e}");
    let e = model_err(
        "[[error]]\nname = \"EXX\"\nbasis = \"legendre\"\ndegree = 3\n[[error]]\nname = \"EXX\"\nbasis = \"monomial\"\ndegree = 2\n",
    );
    assert!(e.contains("listed twice"), "{e}");
    let e = model_err("[[error]]\nname = \"X0C\"\nbasis = \"legendre\"\ndegree = 2\n");
    assert!(e.contains("a constant: give it no basis"), "{e}");
    let e = model_err("[fixed]\n\"EXX.c9\" = 1.0\n");
    assert!(
        e.starts_with("m.toml:2: field 'fixed.EXX.c9'") && e.contains("no parameter"),
        "{e}"
    );
    let e = model_err("[tracker]\nidentify = [\"x\", \"yaw\"]\n");
    assert!(
        e.starts_with("m.toml:2") && e.contains("x, y, z, rx, ry, rz"),
        "{e}"
    );
    let e = model_err("squareness = \"sometimes\"\n");
    assert!(e.starts_with("m.toml:1") && e.contains("sometimes"), "{e}");
}

#[test]
fn results_file_round_trip_and_errors_evaluate_later() {
    let model = Model::default_xcfz();
    let ns = NullSpace::for_model(&model).unwrap();
    let p = ns.expand(
        &(0..ns.n_free())
            .map(|i| 1e-3 * (i as f64).sin())
            .collect::<Vec<_>>(),
    );
    let json = ResultsFile::from_model(&model, &p).unwrap().to_json();
    let (back, q) = ResultsFile::from_json_str(&json, "r.json")
        .unwrap()
        .to_model("r.json")
        .unwrap();
    assert_eq!(p, q);
    for e in ["EXX", "EBZ", "ECC"] {
        for pos in [0.0, 0.4, 1.3] {
            assert_eq!(
                model.error_value(id(e), pos, &p),
                back.error_value(id(e), pos, &q)
            );
        }
    }
    // A tampered file is refused with the place named.
    let bad = json.replacen("\"EXX.c0\"", "\"EXX.c7\"", 1);
    let e = ResultsFile::from_json_str(&bad, "r.json")
        .unwrap()
        .to_model("r.json")
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("r.json: field 'parameters[0]'") && e.contains("EXX.c7"),
        "{e}"
    );
    let e = ResultsFile::from_json_str("{\"format\": 3}", "r.json")
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("r.json:1") && e.contains("not a volver results file"),
        "{e}"
    );
    let mut nan = p.clone();
    nan[0] = f64::NAN;
    assert!(ResultsFile::from_model(&model, &nan).is_err());
}

#[test]
fn squareness_from_slope_on_a_workpiece_side_axis() {
    // YFXZ: Y moves the workpiece, so its errors enter with the opposite sign (s = −1). C0Y and
    // the slope of EXY must still describe the same motion, and Model::squareness must agree.
    let machine = || {
        Machine::from_toml_str(
            "name = \"t\"\nchain = \"YFXZ\"\n[axes.Y]\nrange = [-200.0, 600.0]\nreference = 100.0\n\
             [axes.X]\nrange = [0.0, 1000.0]\n[axes.Z]\nrange = [0.0, 500.0]\n\
             [[reflector]]\nid = \"R\"\noffset = [5.0, 5.0, -60.0]\n",
            "yfxz.toml",
        )
        .unwrap()
    };
    let only_sq = Model::from_toml_str(machine(), "[[error]]\nname = \"C0Y\"\n", "a.toml").unwrap();
    let only_st = Model::from_toml_str(
        machine(),
        "[[error]]\nname = \"EXY\"\nbasis = \"monomial\"\ndegree = 1\n",
        "b.toml",
    )
    .unwrap();
    // EXY(ξ) = c0 + c1 ξ with ξ = (y + 200)/400 − 1; zero at y = 100 (ξ = −0.25): c0 = 0.25 c1.
    let slope_per_mm = 3e-5;
    let c1 = slope_per_mm * 400.0;
    let mut p_st = only_st.initial_params();
    p_st[only_st.param_index("EXY.c0").unwrap()] = 0.25 * c1;
    p_st[only_st.param_index("EXY.c1").unwrap()] = c1;
    assert!(only_st.constraints().max_violation(&p_st) < 1e-18);
    let implied = only_st.squareness(&p_st);
    assert_eq!(implied.len(), 1);
    assert_eq!(implied[0].0, id("C0Y"));
    // Workpiece side: the slope enters with s = −1, so C0Y = +slope.
    assert!((implied[0].1 - slope_per_mm).abs() < 1e-18, "{implied:?}");
    let mut p_sq = only_sq.initial_params();
    p_sq[only_sq.param_index("C0Y").unwrap()] = implied[0].1;
    for pos in [
        [100.0, 0.0, 0.0],
        [-200.0, 500.0, 100.0],
        [600.0, 1000.0, 500.0],
    ] {
        let cmd = only_st.machine().commands_from_file_units(&pos);
        let (a, b) = (
            only_st.predict(&cmd, 0, &p_st),
            only_sq.predict(&cmd, 0, &p_sq),
        );
        for i in 0..3 {
            assert!((a[i] - b[i]).abs() < 1e-12, "{pos:?}: {a:?} vs {b:?}");
        }
    }
}

/// Terms of one axis in one basis share the basis' values at a point (evaluated once): every
/// error value at a point, and every column of the Jacobian, is the same as evaluated term by
/// term, whatever the order of the terms (grouped, interleaved with another basis, or a sine
/// series between them), at the last bit of a dot product.
#[test]
fn shared_basis_values_give_each_term_its_own_value() {
    let m = volver::core::machine::Machine::default_xcfz();
    let text = "[[error]]\nname = [\"EXX\", \"EYX\"]\nbasis = \"legendre\"\ndegree = 3\n\
                [[error]]\nname = [\"EZX\"]\nbasis = \"monomial\"\ndegree = 3\n\
                [[error]]\nname = [\"EAX\", \"EBX\"]\nbasis = \"legendre\"\ndegree = 3\n\
                [[error]]\nname = [\"EXC\", \"EYC\"]\nbasis = \"sine\"\norder = 2\n\
                [[error]]\nname = [\"EZC\", \"ECC\"]\nbasis = \"fourier\"\norder = 2\n";
    let model = Model::from_toml_str(m.clone(), text, "inline").unwrap();
    let n = model.n_params();
    let params: Vec<f64> = (0..n)
        .map(|j| 1e-3 * ((j as f64) * 0.71 + 0.3).sin())
        .collect();
    let cmd = m.commands_from_file_units(&[612.5, 37.0, 250.0]);
    let e = model.errors_at(&cmd, &params);
    let mut jac = vec![0.0; 3 * n];
    let p = model.predict_with_jacobian(&cmd, 1, &params, &mut jac);
    let q = model.predict(&cmd, 1, &params);
    for c in 0..3 {
        assert!((p[c] - q[c]).abs() < 1e-12, "{p:?} {q:?}");
    }
    let mut grad = vec![0.0; 16];
    for t in model.terms() {
        let k = t.params.len();
        let v = model
            .error_value_gradient(t.id, cmd.0[t.axis], &params, &mut grad)
            .unwrap();
        let slot = match t.id {
            volver::core::iso::ErrorId::Component { component, .. } => {
                e.component[t.axis][component.index()]
            }
            _ => unreachable!(),
        };
        assert!((v - slot).abs() <= 1e-15, "{}: {v} against {slot}", t.id);
        // Each column of the Jacobian is the chain's sensitivity to this value times the
        // basis value: the ratio of two columns of one term is the ratio of their basis values.
        for a in 1..k {
            let (ja, j0) = (t.params.start + a, t.params.start);
            for r in 0..3 {
                let (x, y) = (jac[r * n + ja] * grad[0], jac[r * n + j0] * grad[a]);
                assert!(
                    (x - y).abs() <= 1e-12 * (x.abs() + y.abs()) + 1e-300,
                    "{}",
                    t.id
                );
            }
        }
    }
}
