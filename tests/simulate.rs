//! The synthetic generator: nominal points without errors and noise, reproducible files, true
//! errors of the requested size that satisfy the model's constraints, every hidden effect as its
//! formula says, and `volver simulate` files that the readers read back.

mod common;
use common::volver;

use std::f64::consts::PI;
use std::path::{Path, PathBuf};
use volver::core::basis::BasisKind;
use volver::core::iso::{Axis, ErrorId};
use volver::core::kinematics::{PointErrors, predict};
use volver::core::machine::Machine;
use volver::core::measure::MeasurementSet;
use volver::core::model::{ErrorModelSpec, Model, SquarenessRule};
use volver::core::noise::TrackerNoise;
use volver::core::plan::{PRESETS, Plan};
use volver::core::results::ResultsFile;
use volver::core::simulate::{Effect, Magnitudes, Simulation, Synthetic, Truth};

fn xcfz() -> Machine {
    Machine::default_xcfz()
}

fn random_truth(seed: u64) -> Truth {
    let m = xcfz();
    Truth::random_complete(&m, &Magnitudes::default(), seed).unwrap()
}

fn zero_truth() -> Truth {
    let m = xcfz();
    Truth::random(&m, &ErrorModelSpec::complete(&m), &Magnitudes::ZERO, 1).unwrap()
}

/// Runs `plan` on `truth` with the given noise and effects.
fn run(plan: &str, truth: Truth, noise: TrackerNoise, effects: Vec<Effect>) -> Synthetic {
    let plan = Plan::preset(truth.model.machine(), plan).unwrap();
    let mut sim = Simulation::new(plan, truth, 11);
    sim.noise = noise;
    sim.effects = effects;
    sim.run().unwrap()
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("volver-sim-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

#[test]
fn zero_errors_and_zero_noise_give_exactly_the_nominal_points() {
    let out = run("test4", zero_truth(), TrackerNoise::NONE, vec![]);
    let m = xcfz();
    let mut nominal_errors = PointErrors::<f64>::zero();
    nominal_errors.tracker[..3].copy_from_slice(&m.tracker().position);
    let model = Model::default_xcfz();
    let p0 = model.initial_params();
    for pt in &out.measurements.points {
        let want = predict(
            &m,
            &pt.commands,
            &m.reflectors()[pt.reflector].offset,
            &nominal_errors,
        );
        assert_eq!(pt.measured, want, "line {}", pt.line);
        assert_eq!(pt.measured, model.predict(&pt.commands, pt.reflector, &p0));
    }
    assert_eq!(out.record.noise_error.emm_um, 0.0);
    assert_eq!(out.record.machine_error.emax_um, 0.0);
}

#[test]
fn the_same_seed_gives_byte_identical_files_and_another_seed_does_not() {
    let write = |seed: u64, name: &str| -> (PathBuf, Vec<PathBuf>) {
        let plan = Plan::preset(&xcfz(), "test3").unwrap();
        let mut sim = Simulation::new(plan, random_truth(seed), seed);
        sim.effects = vec![
            Effect::parse("rotary-harmonics=3").unwrap(),
            Effect::parse("thermal-drift=3,-2,10").unwrap(),
        ];
        let dir = temp_dir(name);
        let files = sim.run().unwrap().write(&dir).unwrap();
        (dir, files)
    };
    let (d1, a) = write(5, "seed5a");
    let (d2, b) = write(5, "seed5b");
    let (d3, c) = write(6, "seed6");
    assert_eq!(a.len(), 4);
    for ((fa, fb), fc) in a.iter().zip(&b).zip(&c) {
        let (x, y, z) = (
            std::fs::read(fa).unwrap(),
            std::fs::read(fb).unwrap(),
            std::fs::read(fc).unwrap(),
        );
        assert_eq!(x, y, "{} differs between two runs", fa.display());
        if !fa.ends_with("machine.toml") {
            assert_ne!(x, z, "{} does not depend on the seed", fa.display());
        }
    }
    for d in [d1, d2, d3] {
        let _ = std::fs::remove_dir_all(d);
    }
}

/// Largest |error| over the travel, sampled.
fn peak(model: &Model, id: ErrorId, p: &[f64]) -> f64 {
    let t = model.term(id).unwrap();
    let ax = &model.machine().axes()[t.axis];
    (0..=400)
        .map(|i| {
            let u = ax.min + (ax.max - ax.min) * i as f64 / 400.0;
            model.error_value(id, u, p).unwrap().abs()
        })
        .fold(0.0, f64::max)
}

#[test]
fn random_true_errors_have_the_requested_size_and_satisfy_the_constraints() {
    let mags = Magnitudes::default();
    for seed in 0..5 {
        let t = random_truth(seed);
        let model = &t.model;
        assert!(model.constraints().max_violation(&t.params) < 1e-15);
        assert_eq!(model.spec().squareness, SquarenessRule::Separate);
        for term in model.terms() {
            let want = mags.for_error(term.id);
            let got = peak(model, term.id, &t.params);
            // Sampled peak: within 0.5 … 1 of the magnitude (sampling may miss the top by a hair).
            assert!(
                got <= want * (1.0 + 1e-9) && got >= 0.5 * want * 0.999,
                "seed {seed}: {} peaks at {got:e}, magnitude {want:e}",
                term.id
            );
            if !term.id.axis().is_rotary() && term.basis.kind() == BasisKind::Legendre {
                // Zero at the reference position (0 for X and Z).
                let v = model.error_value(term.id, 0.0, &t.params).unwrap();
                assert!(v.abs() < 1e-15, "{} at reference: {v}", term.id);
            }
        }
        // The squareness is held by the squareness parameters (ISO 230-1 split): the
        // straightness partners have no best-fit slope.
        for (id, v) in model.squareness(&t.params) {
            if let Some(term) = model.term(id) {
                assert!((v - t.params[term.params.start]).abs() < 1e-15, "{id}");
                assert!(v.abs() >= 0.5 * 50e-6 && v.abs() <= 50e-6, "{id} = {v}");
            }
        }
        // The tracker stays at its nominal pose unless asked otherwise.
        assert_eq!(t.tracker_pose(), [0.0; 6]);
    }
    // Seeds differ, and the tracker magnitude moves the tracker by 0.5 … 1 of it.
    assert_ne!(random_truth(1).params, random_truth(2).params);
    let m = xcfz();
    let mut mags = Magnitudes::default();
    mags.set_from_text("tracker=4").unwrap();
    let t = Truth::random(&m, &ErrorModelSpec::complete(&m), &mags, 3).unwrap();
    let d = t.tracker_pose()[..3]
        .iter()
        .map(|v| v * v)
        .sum::<f64>()
        .sqrt();
    assert!((2.0..=4.0).contains(&d), "tracker moved by {d} mm");
}

#[test]
fn random_truth_works_in_every_basis() {
    let m = xcfz();
    let toml = r#"
        squareness = "from-straightness"
        [[error]]
        name = ["EXX", "EYX"]
        basis = "monomial"
        degree = 4
        [[error]]
        name = ["EXZ", "EYZ"]
        basis = "chebyshev"
        nodes = 5
        [[error]]
        name = ["ECC", "EXC"]
        basis = "sine"
        order = 2
        [[error]]
        name = ["X0C", "A0C", "B0Z"]
        [fixed]
        "EXX.c4" = 0.0
    "#;
    let spec = ErrorModelSpec::from_toml_str(toml, "inline").unwrap();
    let t = Truth::random(&m, &spec, &Magnitudes::default(), 9).unwrap();
    assert!(t.model.constraints().max_violation(&t.params) < 1e-12);
    assert_eq!(t.params[t.model.param_index("EXX.c4").unwrap()], 0.0);
    let mags = Magnitudes::default();
    for term in t.model.terms() {
        let got = peak(&t.model, term.id, &t.params);
        let want = mags.for_error(term.id);
        assert!(
            got <= want * (1.0 + 1e-9) && got >= 0.49 * want,
            "{}: {got:e} vs {want:e}",
            term.id
        );
    }
    // A truth from a results file round-trips, and one that breaks its constraints is refused.
    let file = t.to_results().unwrap();
    let back = Truth::from_results(&file, "truth.json").unwrap();
    assert_eq!(back.params, t.params);
    let mut broken = file.clone();
    let k = t.model.param_index("EXX.c0").unwrap();
    broken.parameters[k].value += 1e-3;
    let e = Truth::from_results(&broken, "truth.json").unwrap_err();
    assert!(e.to_string().contains("truth.json") && e.to_string().contains("constraints"));
}

#[test]
fn time_stamps_cover_the_duration_in_measuring_order() {
    let plan = Plan::preset(&xcfz(), "table4").unwrap();
    let mut sim = Simulation::new(plan, zero_truth(), 1);
    sim.duration_s = Some(7200.0);
    let out = sim.run().unwrap();
    let pts = &out.measurements.points;
    let n = pts.len();
    for (i, p) in pts.iter().enumerate() {
        let want = (7200.0 * i as f64 / (n - 1) as f64 * 1e3).round() / 1e3;
        assert_eq!(p.t_s, Some(want));
    }
    assert_eq!(pts[n - 1].t_s, Some(7200.0));
    // Default: 10 s per point.
    let plan = Plan::preset(&xcfz(), "table4").unwrap();
    let out = Simulation::new(plan, zero_truth(), 1).run().unwrap();
    assert_eq!(out.record.duration_s, 10.0 * n as f64);
}

/// The angle α by which the tracker sees the table turned at a position: nominal points at C
/// are those at C = 0 turned about z by α (the tracker stands on the C axis).
fn turn(v: [f64; 3], alpha: f64) -> [f64; 3] {
    let (s, c) = alpha.sin_cos();
    [c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]]
}

#[test]
fn thermal_drift_moves_the_tool_by_rate_times_time_in_the_machine_frame() {
    let rate = [12.0, -5.0, 30.0]; // µm/h
    let base = run("test4", zero_truth(), TrackerNoise::NONE, vec![]);
    let drift = run(
        "test4",
        zero_truth(),
        TrackerNoise::NONE,
        vec![Effect::ThermalDrift {
            rate_um_per_h: rate,
        }],
    );
    let m = xcfz();
    let (ci, _) = m.axis(Axis::C).unwrap();
    let mut checked_c0 = 0;
    for (a, b) in base
        .measurements
        .points
        .iter()
        .zip(&drift.measurements.points)
    {
        let t_h = a.t_s.unwrap() / 3600.0;
        let d = rate.map(|v| v * t_h * 1e-3); // mm, machine frame
        // The tracker turns with the table: the machine-frame drift appears turned by the same
        // angle as the nominal points, read off the nominal geometry at C and at C = 0.
        let mut c0 = a.commands;
        c0.0[ci] = 0.0;
        let p0 = predict(
            &m,
            &c0,
            &m.reflectors()[a.reflector].offset,
            &PointErrors::<f64>::zero(),
        );
        let alpha = a.measured[1].atan2(a.measured[0]) - p0[1].atan2(p0[0]);
        let want = turn(d, alpha);
        let got = sub(b.measured, a.measured);
        assert!(
            dist(got, want) < 1e-9,
            "line {}: {got:?} vs {want:?}",
            a.line
        );
        if a.commands.0[ci] == 0.0 {
            assert!(dist(got, d) < 1e-12);
            checked_c0 += 1;
        }
    }
    assert!(checked_c0 > 50);
}

#[test]
fn rotary_harmonics_add_sines_of_the_stated_amplitude_to_every_rotary_error() {
    let (h_max, a_um, b_urad) = (4, 6.0, 15.0);
    let base = run("test4", random_truth(3), TrackerNoise::NONE, vec![]);
    let with = run(
        "test4",
        random_truth(3),
        TrackerNoise::NONE,
        vec![Effect::RotaryHarmonics {
            max_order: h_max,
            translation_um: a_um,
            rotation_urad: b_urad,
        }],
    );
    let (t0, t1) = (&base.truth, &with.truth);
    for term in t1.model.terms() {
        if !term.id.axis().is_rotary() {
            continue;
        }
        assert_eq!(term.basis.degree(), h_max, "{}", term.id);
        let amp = if term.id.component().is_rotary() {
            b_urad * 1e-6
        } else {
            a_um * 1e-3
        };
        let coeff =
            |s: String| t1.params[t1.model.param_index(&format!("{}.{s}", term.id)).unwrap()];
        let phases: Vec<f64> = (2..=h_max)
            .map(|h| {
                let (a, b) = (coeff(format!("a{h}")), coeff(format!("b{h}")));
                assert!(((a * a + b * b).sqrt() - amp).abs() < 1e-15 * amp.max(1.0));
                b.atan2(a)
            })
            .collect();
        for k in 0..24 {
            let theta = k as f64 * PI / 12.0 + 0.1;
            let added: f64 = (2..=h_max)
                .zip(&phases)
                .map(|(h, phi)| amp * (h as f64 * theta + phi).sin())
                .sum();
            let v1 = t1.model.error_value(term.id, theta, &t1.params).unwrap();
            let v0 = t0.model.error_value(term.id, theta, &t0.params).unwrap();
            assert!((v1 - v0 - added).abs() < 1e-15, "{} at {theta}", term.id);
        }
    }
    // The first harmonic and every linear-axis error are unchanged, and the truth file
    // reproduces the noise-free points.
    for info in t0.model.params() {
        let v0 = t0.params[t0.model.param_index(&info.name).unwrap()];
        assert_eq!(t1.params[t1.model.param_index(&info.name).unwrap()], v0);
    }
    let changed = base
        .measurements
        .points
        .iter()
        .zip(&with.measurements.points)
        .filter(|(a, b)| dist(a.measured, b.measured) > 1e-6)
        .count();
    assert!(changed > 900, "{changed} points changed");
    reproduces_from_truth(&with);
}

/// The truth file alone reproduces the noise-free points (effects it expresses included).
fn reproduces_from_truth(out: &Synthetic) {
    let file = out.truth.to_results().unwrap();
    let json = file.to_json();
    let (model, p) = ResultsFile::from_json_str(&json, "truth.json")
        .unwrap()
        .to_model("truth.json")
        .unwrap();
    for (pt, clean) in out.measurements.points.iter().zip(&out.noise_free) {
        assert_eq!(model.predict(&pt.commands, pt.reflector, &p), *clean);
    }
}

/// The exact inverse of eq. 4's small rotation, `(I + [w]× + w wᵀ)/(1 + |w|²)`, applied to v.
fn small_rotation_inverse(w: [f64; 3], v: [f64; 3]) -> [f64; 3] {
    let cross = [
        w[1] * v[2] - w[2] * v[1],
        w[2] * v[0] - w[0] * v[2],
        w[0] * v[1] - w[1] * v[0],
    ];
    let dot = w[0] * v[0] + w[1] * v[1] + w[2] * v[2];
    let n = 1.0 + w[0] * w[0] + w[1] * w[1] + w[2] * w[2];
    [0, 1, 2].map(|k| (v[k] + cross[k] + w[k] * dot) / n)
}

#[test]
fn a_tilted_tracker_rotates_every_point_by_its_small_rotation() {
    let (rx, ry) = (80.0, -45.0); // µrad
    let base = run("test4", random_truth(4), TrackerNoise::NONE, vec![]);
    let tilt = run(
        "test4",
        random_truth(4),
        TrackerNoise::NONE,
        vec![Effect::TrackerTilt {
            rx_urad: rx,
            ry_urad: ry,
        }],
    );
    let w = [rx * 1e-6, ry * 1e-6, 0.0];
    assert_eq!(tilt.truth.tracker_pose()[3..], [w[0], w[1], 0.0]);
    for (a, b) in base
        .measurements
        .points
        .iter()
        .zip(&tilt.measurements.points)
    {
        let want = small_rotation_inverse(w, a.measured);
        assert!(dist(b.measured, want) < 1e-9, "line {}", a.line);
    }
    reproduces_from_truth(&tilt);
}

#[test]
fn a_ball_screw_error_acts_as_a_commanded_position_shifted_by_it() {
    // On the nominal machine, a positioning error e of an axis on side s (−1 workpiece, +1
    // tool) moves the point as commanding u + s·e would.
    // Periods that the mesh steps (200 mm in X, 150 mm in Z) do not divide: a mesh step that
    // is a multiple of the period would see the same phase everywhere.
    for (axis, period, amp_um) in [(Axis::X, 35.0, 4.0), (Axis::Z, 40.0, 2.5)] {
        let with = run(
            "test4",
            zero_truth(),
            TrackerNoise::NONE,
            vec![Effect::BallScrew {
                axis,
                period_mm: period,
                amplitude_um: amp_um,
            }],
        );
        let m = xcfz();
        let (k, ax) = m.axis(axis).unwrap();
        let mut moved = 0;
        for pt in &with.measurements.points {
            let u = pt.commands.0[k];
            let e = amp_um * 1e-3 * (2.0 * PI * (u - ax.reference) / period).sin();
            let mut cmd = pt.commands;
            cmd.0[k] = u + ax.side.sign() * e;
            let want = predict(
                &m,
                &cmd,
                &m.reflectors()[pt.reflector].offset,
                &PointErrors::<f64>::zero(),
            );
            assert!(dist(pt.measured, want) < 1e-9, "{axis} line {}", pt.line);
            if e.abs() > 1e-4 {
                moved += 1;
            }
        }
        assert!(moved > 100, "{axis}: {moved} points moved");
    }
}

#[test]
fn a_reversal_acts_as_a_command_shifted_by_half_of_it_the_way_the_axis_came() {
    // Hand-set: X and C go out, back, out and back; each point's direction written out here
    // (the first point takes its axis' first move's, +), not derived by volver. On the nominal
    // machine ISO 230-2's reversal B (the tool's deviation relative to the workpiece along the
    // command, forward minus reverse) acts as the command shifted by ±B/2, on either side.
    let m = xcfz();
    let positions = [
        (0.0, 0.0),
        (400.0, 90.0),
        (800.0, 180.0),
        (400.0, 90.0),
        (1200.0, 270.0),
        (200.0, 0.0),
    ];
    let signs = [1.0, 1.0, 1.0, -1.0, 1.0, -1.0];
    let plan = Plan {
        name: "out and back".into(),
        positions: positions
            .iter()
            .map(|&(x, c)| m.commands_from_file_units(&[x, c, 300.0]))
            .collect(),
        reflectors: vec![0],
        sequence: None,
        approach: None,
    };
    let mut sim = Simulation::new(plan, zero_truth(), 3);
    sim.noise = TrackerNoise::NONE;
    sim.effects = vec![
        Effect::parse("reversal=X,10").unwrap(),
        Effect::parse("reversal=C,-40").unwrap(),
    ];
    let out = sim.run().unwrap();
    let (kx, _) = m.axis(Axis::X).unwrap();
    let (kc, _) = m.axis(Axis::C).unwrap();
    for (pt, s) in out.measurements.points.iter().zip(signs) {
        let mut cmd = pt.commands;
        cmd.0[kx] += s * 0.5 * 10e-3;
        cmd.0[kc] += s * 0.5 * -40e-6;
        let want = predict(
            &m,
            &cmd,
            &m.reflectors()[0].offset,
            &PointErrors::<f64>::zero(),
        );
        // The model turns C's error by a small-angle rotation, the command by an exact one:
        // they differ at second order, (20 µrad)² × 1.5 m ≈ 6e-7 mm; a wrong sign is 0.03 mm.
        assert!(
            dist(pt.measured, want) < 1e-6,
            "line {}: {:?}: {} mm",
            pt.line,
            pt.approach,
            dist(pt.measured, want)
        );
        assert_eq!(f64::from(pt.approach.0[kx]), s, "line {}", pt.line);
    }
}

#[test]
fn a_reflector_offset_error_moves_that_reflector_only() {
    let delta = [30.0, -20.0, 15.0]; // µm
    let base = run("test4", random_truth(5), TrackerNoise::NONE, vec![]);
    let with = run(
        "test4",
        random_truth(5),
        TrackerNoise::NONE,
        vec![Effect::ReflectorOffset {
            reflector: "R1".into(),
            delta_um: delta,
        }],
    );
    // The truth on a machine whose R1 sits at its nominal offset + δ.
    let mut spec = xcfz().spec().clone();
    for (o, d) in spec.reflectors[0].offset.iter_mut().zip(delta) {
        *o += d * 1e-3;
    }
    let moved = Machine::from_spec(spec, "moved R1").unwrap();
    let model = Model::new(moved, base.truth.model.spec().clone()).unwrap();
    for (a, b) in base
        .measurements
        .points
        .iter()
        .zip(&with.measurements.points)
    {
        if a.reflector == 1 {
            assert_eq!(a.measured, b.measured);
        } else {
            let want = model.predict(&b.commands, 0, &base.truth.params);
            assert!(dist(b.measured, want) < 1e-9, "line {}", b.line);
            assert!(dist(a.measured, b.measured) > 0.03);
        }
    }
}

#[test]
fn a_range_scale_error_scales_every_point_about_the_tracker() {
    let ppm = 25.0;
    let base = run("test4", random_truth(6), TrackerNoise::NONE, vec![]);
    let with = run(
        "test4",
        random_truth(6),
        TrackerNoise::NONE,
        vec![Effect::RangeScale { ppm }],
    );
    for (a, b) in base
        .measurements
        .points
        .iter()
        .zip(&with.measurements.points)
    {
        let want = a.measured.map(|v| v * (1.0 + ppm * 1e-6));
        assert!(dist(b.measured, want) < 1e-12, "line {}", a.line);
    }
}

#[test]
fn effects_do_not_change_the_noise_draws_or_the_errors() {
    // Same seed with and without a drift: the noise vectors are the same draws, so the
    // measured-minus-clean differences agree to the noise model's tiny dependence on the point.
    let noise = TrackerNoise::PAPER;
    let a = run("test3", random_truth(8), noise, vec![]);
    let b = run(
        "test3",
        random_truth(8),
        noise,
        vec![Effect::parse("thermal-drift=0,0,5").unwrap()],
    );
    for i in 0..a.noise_free.len() {
        let na = sub(a.measurements.points[i].measured, a.noise_free[i]);
        let nb = sub(b.measurements.points[i].measured, b.noise_free[i]);
        assert!(dist(na, nb) < 1e-6, "point {i}");
    }
    assert!((a.record.noise_error.emm_um - b.record.noise_error.emm_um).abs() < 1e-3);
}

#[test]
fn the_noise_error_reflects_the_tracker_noise() {
    let out = run("test4", random_truth(2), TrackerNoise::PAPER, vec![]);
    // Uniform on ±30 µrad (σ = 17.3 µrad) at 1.6 … 2.2 m on two angles (plus a few µm of
    // range): ‖noise‖ averages about 1.2 σ·r for two equal components, about 33 … 48 µm.
    let emm = out.record.noise_error.emm_um;
    assert!((30.0..55.0).contains(&emm), "noise EMM {emm} µm");
    // Per point, the noise has independent components ρ·σ_az (ρ the horizontal distance),
    // r·σ_el and σ_r: its mean square is their sum of squares.
    let noise = TrackerNoise::PAPER;
    let (mut got, mut want) = (0.0, 0.0);
    for (pt, clean) in out.measurements.points.iter().zip(&out.noise_free) {
        let rho = clean[0].hypot(clean[1]);
        let r = rho.hypot(clean[2]);
        let (s_az, s_el) = noise.angle_sigmas_rad();
        want += (rho * s_az).powi(2) + (r * s_el).powi(2) + noise.range_sigma_mm(r).powi(2);
        got += dist(pt.measured, *clean).powi(2);
    }
    let ratio = (got / want).sqrt();
    assert!((ratio - 1.0).abs() < 0.05, "RMS noise / expected = {ratio}");
}

#[test]
fn bad_effects_and_options_get_clear_errors() {
    let m = xcfz();
    let err = |text: &str| {
        match Effect::parse(text) {
            Err(e) => e,
            Ok(effect) => effect.validate(&m).unwrap_err(),
        }
        .to_string()
    };
    assert!(err("wobble=1").contains("effects are thermal-drift"));
    assert!(err("thermal-drift=1,2").contains("VX,VY,VZ"));
    assert!(err("thermal-drift=1,2,x").contains("'x' is not a finite number"));
    assert!(err("ball-screw=C,10,3").contains("C is not a linear axis of XCFZ"));
    assert!(err("ball-screw=X,0,3").contains("the period 0 mm is outside 0.1 … 1e6 mm"));
    assert!(err("rotary-harmonics=1").contains("outside 2..=15"));
    assert!(err("reflector-offset=R9,1,2,3").contains("no reflector 'R9'"));
    assert!(err("range-scale=inf").contains("not a finite number"));
    for text in [
        "thermal-drift=1,2,3",
        "rotary-harmonics=3,5,10",
        "tracker-tilt=10,-5",
        "ball-screw=Z,5,1.5",
        "reflector-offset=R2,10,0,-5",
        "range-scale=-3",
    ] {
        assert_eq!(Effect::parse(text).unwrap().to_string(), text);
    }
    let mut mags = Magnitudes::default();
    assert!(mags.set_from_text("straightness=-1").is_err());
    assert!(
        mags.set_from_text("wobble=1")
            .unwrap_err()
            .to_string()
            .contains("kinds are positioning")
    );
    assert!(TrackerNoise::from_text("30,30,4").is_err());
    // Harmonics need periodic rotary errors in the truth to extend.
    let linear_only = ErrorModelSpec::from_toml_str(
        "[[error]]\nname = \"EXX\"\nbasis = \"legendre\"\ndegree = 2\n",
        "inline",
    )
    .unwrap();
    let truth = Truth::random(&m, &linear_only, &Magnitudes::default(), 1).unwrap();
    let mut sim = Simulation::new(Plan::preset(&m, "table4").unwrap(), truth, 1);
    sim.effects = vec![Effect::parse("rotary-harmonics=3").unwrap()];
    let e = sim.run().unwrap_err().to_string();
    assert!(e.contains("no periodic"), "{e}");
    // A plan outside the travel of the truth's machine is refused, not extrapolated.
    let mut plan = Plan::preset(&m, "table4").unwrap();
    plan.positions[3].0[0] = 1500.0;
    let e = Simulation::new(plan, zero_truth(), 1).run().unwrap_err();
    assert!(e.to_string().contains("outside the travel"), "{e}");
}

#[test]
fn the_complete_model_of_the_paper_machine_is_the_paper_model() {
    let m = xcfz();
    let complete = Model::new(m.clone(), ErrorModelSpec::complete(&m)).unwrap();
    let paper = Model::default_xcfz();
    let names =
        |model: &Model| -> Vec<String> { model.params().iter().map(|p| p.name.clone()).collect() };
    assert_eq!(names(&complete), names(&paper));
    assert_eq!(
        complete.constraints().rows.len(),
        paper.constraints().rows.len()
    );
}

fn read_back(dir: &Path) -> (Machine, MeasurementSet, Model, Vec<f64>, String) {
    let machine = Machine::load(&dir.join("machine.toml")).unwrap();
    let set = MeasurementSet::load(&machine, &dir.join("measurements.csv")).unwrap();
    let (model, p) = ResultsFile::load(&dir.join("truth.json"))
        .unwrap()
        .to_model("truth.json")
        .unwrap();
    let record = std::fs::read_to_string(dir.join("simulation.json")).unwrap();
    (machine, set, model, p, record)
}

#[test]
fn volver_simulate_writes_files_the_readers_read_back_for_every_preset() {
    for preset in PRESETS {
        let dir = temp_dir(&format!("cli-{preset}"));
        let out = volver(&[
            "simulate",
            "--plan",
            preset,
            "--seed",
            "7",
            "--out",
            dir.to_str().unwrap(),
        ]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(text.contains("Noise error") && text.contains("measurements.csv"));
        let (machine, set, model, p, record) = read_back(&dir);
        assert_eq!(machine.spec(), xcfz().spec());
        let plan = Plan::preset(&machine, preset).unwrap();
        assert_eq!(set.points.len(), plan.n_points(), "{preset}");
        assert!(record.contains(&format!("\"plan\": \"{preset}\"")));
        // The CLI's numbers are the library's: the same inputs through the library.
        let truth = Truth::random(
            &machine,
            &ErrorModelSpec::complete(&machine),
            &Magnitudes::default(),
            7,
        )
        .unwrap();
        assert_eq!(p, truth.params);
        assert_eq!(model.n_params(), truth.model.n_params());
        let lib = Simulation::new(plan, truth, 7).run().unwrap();
        for (a, b) in set.points.iter().zip(&lib.measurements.points) {
            assert!(dist(a.measured, b.measured) < 1e-9 && a.commands == b.commands);
            assert_eq!(a.reflector, b.reflector);
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}

#[test]
fn volver_simulate_takes_grids_truth_files_effects_and_reports_bad_options() {
    let dir = temp_dir("cli-options");
    let d = dir.to_str().unwrap();
    let out = volver(&[
        "simulate",
        "--plan",
        "X=0:1400:350,C=0:360:90,Z=0:600:300",
        "--seed",
        "3",
        "--out",
        d,
        "--noise",
        "none",
        "--magnitude",
        "straightness=10",
        "--effect",
        "rotary-harmonics=3",
        "--effect",
        "tracker-tilt=20,0",
        "--reflectors",
        "R2",
        "--duration-h",
        "1.5",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let (_, set, model, p, record) = read_back(&dir);
    assert_eq!(set.points.len(), 5 * 5 * 3);
    assert!(set.points.iter().all(|pt| pt.reflector == 1));
    assert_eq!(set.points.last().unwrap().t_s, Some(5400.0));
    assert!(record.contains("rotary-harmonics") && record.contains("\"straightness_um\": 10.0"));
    // Noise-free and the truth expresses both effects: the truth file reproduces the points.
    for pt in &set.points {
        assert!(dist(model.predict(&pt.commands, pt.reflector, &p), pt.measured) < 1e-9);
    }
    // The truth file fed back in gives the same points.
    let dir2 = temp_dir("cli-truth");
    let truth = dir.join("truth.json");
    let out = volver(&[
        "simulate",
        "--plan",
        "X=0:1400:350,C=0:360:90,Z=0:600:300",
        "--out",
        dir2.to_str().unwrap(),
        "--noise",
        "none",
        "--truth",
        truth.to_str().unwrap(),
        "--reflectors",
        "R2",
        "--duration-h",
        "1.5",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(
        std::fs::read(dir.join("measurements.csv")).unwrap(),
        std::fs::read(dir2.join("measurements.csv")).unwrap()
    );
    for (args, needle) in [
        (vec!["--plan", "test9"], "unknown plan 'test9'"),
        (
            vec!["--effect", "ball-screw=C,1,1"],
            "C is not a linear axis",
        ),
        (vec!["--magnitude", "wobble=3"], "unknown kind 'wobble'"),
        (vec!["--noise", "loud"], "--noise"),
        (vec!["--reflectors", "R7"], "no reflector 'R7'"),
    ] {
        let mut all = vec!["simulate", "--out", d];
        all.extend(args);
        let out = volver(&all);
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(needle), "{all:?}: {err}");
    }
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&dir2);
}

/// The `paper` preset reproduces the paper's tables 9–10 noise error within 10 %, mean and
/// maximum, averaged over 20 fixed seeds on the table-4 and table-7 meshes; the literal normal
/// reading does not (its maximum is about three times the paper's on table 4). This is what
/// fixed the preset as the bounded reading (see `volver::core::noise`).
#[test]
fn the_paper_noise_preset_reproduces_tables_9_and_10() {
    use volver::core::noise::Distribution;
    let mean = |plan: &str, noise: TrackerNoise| {
        let (mut emm, mut emax) = (0.0, 0.0);
        for seed in 0..20 {
            let p = Plan::preset(&xcfz(), plan).unwrap();
            let mut sim = Simulation::new(p, zero_truth(), 100 + seed);
            sim.noise = noise;
            let e = sim.run().unwrap().record.noise_error;
            emm += e.emm_um / 20.0;
            emax += e.emax_um / 20.0;
        }
        (emm, emax)
    };
    for (plan, paper) in [("table4", (31.3, 57.8)), ("table7", (46.8, 104.8))] {
        let (emm, emax) = mean(plan, TrackerNoise::PAPER);
        assert!(
            (emm / paper.0 - 1.0).abs() < 0.1,
            "{plan}: EMM {emm} µm vs {}",
            paper.0
        );
        assert!(
            (emax / paper.1 - 1.0).abs() < 0.1,
            "{plan}: EMax {emax} µm vs {}",
            paper.1
        );
        let normal = TrackerNoise {
            distribution: Distribution::Normal,
            ..TrackerNoise::PAPER
        };
        let (emm, emax) = mean(plan, normal);
        assert!(
            emm > 1.4 * paper.0 && emax > 2.0 * paper.1,
            "{plan}: {emm} {emax}"
        );
    }
}
