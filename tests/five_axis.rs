//! Five-axis machines end to end: the embedded presets (table–table, head–head, head–table), their
//! non-redundant default models, identification to the noise, a hidden five-axis effect found,
//! compensation of the tool's position and direction, G-code with rotary words, controller
//! tables of rotary and location errors.

mod common;

use volver::core::compensate::Compensator;
use volver::core::gcode::{Linearise, Program};
use volver::core::machine::Commands;
use volver::core::model::Model;
use volver::core::noise::TrackerNoise;
use volver::core::presets::{self, Preset};
use volver::core::problem::Problem;
use volver::core::random::Rng;
use volver::core::simulate::{Effect, Magnitudes, Simulation, Truth};
use volver::solvers::Task;
use volver::solvers::observability::{hold_order, nominal_data, redundant_parameters};
use volver::solvers::strategy;

/// The five-axis presets.
fn five_axis() -> Vec<&'static Preset> {
    presets::PRESETS
        .iter()
        .filter(|p| p.name != "xcfz")
        .collect()
}

/// Random true errors in the preset's default model (default magnitudes).
fn truth(p: &Preset, seed: u64) -> Truth {
    let model = p.model().unwrap();
    Truth::random(model.machine(), model.spec(), &Magnitudes::default(), seed).unwrap()
}

/// Random commands inside the travel of `model`'s machine (`n` of them, seeded), the tilt axis
/// kept at least 5° from zero (the singularity is tested on its own).
fn random_commands(model: &Model, n: usize, seed: u64) -> Vec<Commands> {
    let mut rng = Rng::new(seed);
    let axes = model.machine().axes();
    (0..n)
        .map(|_| {
            let mut q = Commands::default();
            for (k, a) in axes.iter().enumerate() {
                let mut v = a.min + (a.max - a.min) * rng.uniform();
                let tilt = a.axis.is_rotary() && a.max - a.min < std::f64::consts::TAU - 1e-9;
                if tilt && v.abs() < 5f64.to_radians() {
                    v += 10f64.to_radians().copysign(v);
                }
                q.0[k] = v;
            }
            q
        })
        .collect()
}

#[test]
fn layout_lists_every_embedded_machine_and_prints_one() {
    let out = common::volver(&["layout", "--list"]);
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), presets::PRESETS.len(), "{text}");
    for (line, p) in lines.iter().zip(&presets::PRESETS) {
        assert!(line.starts_with(p.name), "{line}");
    }
    let out = common::volver(&["layout", "--machine", "head-table"]);
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("Chain CFXYZB"), "{text}");
    assert!(text.contains("X0B") && text.contains("Z0B"), "{text}");
    let out = common::volver(&["layout", "--machine", "five-axis"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("five-axis") && err.contains("table-table, head-head, head-table"),
        "{err}"
    );
}

/// The default models hold exactly what the identifiability analysis finds redundant: the
/// model without its `[fixed]` table has those parameters (and no other) to hold on the preset
/// plan, and the default model has none.
#[test]
fn the_default_models_hold_exactly_the_redundant_coefficients() {
    for p in five_axis() {
        let model = p.model().unwrap();
        let plan = p.plan().unwrap();
        let data = nominal_data(&model, &plan);
        let task = Task::new(Problem::new(&model, &data).unwrap());
        let held =
            redundant_parameters(&task, &model.initial_params(), &hold_order(&model)).unwrap();
        assert!(held.is_empty(), "{}: {held:?}", p.name);

        let mut spec = model.spec().clone();
        let fixed: Vec<String> = spec.fixed.keys().cloned().collect();
        assert_eq!(fixed.len(), 20, "{}", p.name);
        spec.fixed.clear();
        let full = Model::new(model.machine().clone(), spec).unwrap();
        let data = nominal_data(&full, &plan);
        let task = Task::new(Problem::new(&full, &data).unwrap());
        let held = redundant_parameters(&task, &full.initial_params(), &hold_order(&full)).unwrap();
        let mut names: Vec<String> = held
            .iter()
            .map(|r| full.params()[r.param].name.clone())
            .collect();
        names.sort();
        assert_eq!(names, fixed, "{}", p.name);
        // Every location error of both rotary axes is identified.
        for name in model.params().iter().map(|i| &i.name) {
            if name.len() == 3 && name.as_bytes()[1] == b'0' {
                assert!(!fixed.contains(name), "{}: {name}", p.name);
            }
        }
    }
}

#[test]
fn noise_free_five_axis_data_fit_to_the_file_rounding() {
    for p in five_axis() {
        let model = p.model().unwrap();
        let mut sim = Simulation::new(p.plan().unwrap(), truth(p, 11), 11);
        sim.noise = TrackerNoise::NONE;
        let data = sim.run().unwrap().measurements;
        let id = strategy::fit(Problem::new(&model, &data).unwrap());
        assert!(id.termination.converged(), "{}: {}", p.name, id.termination);
        let ratio = id.reached.stats.emm_um / id.initial.stats.emm_um;
        eprintln!(
            "{}: noise-free {:.3e} µm from {:.3} µm ({ratio:.1e})",
            p.name, id.reached.stats.emm_um, id.initial.stats.emm_um
        );
        assert!(ratio <= 1e-6, "{}: {ratio}", p.name);
    }
}

#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "release only: cargo test --release --test five_axis"
)]
fn noisy_five_axis_data_fit_to_the_noise() {
    for p in five_axis() {
        let model = p.model().unwrap();
        for seed in 1..=3 {
            let sim = Simulation::new(p.plan().unwrap(), truth(p, seed), seed);
            let out = sim.run().unwrap();
            let id = strategy::fit(Problem::new(&model, &out.measurements).unwrap());
            assert!(id.termination.converged(), "{}: {}", p.name, id.termination);
            let ratio = id.reached.stats.emm_um / out.record.noise_error.emm_um;
            eprintln!(
                "{} seed {seed}: {:.4} µm, {ratio:.4} × the noise error ({} steps)",
                p.name,
                id.reached.stats.emm_um,
                id.iterations()
            );
            assert!(
                (0.97..=1.02).contains(&ratio),
                "{} seed {seed}: {ratio}",
                p.name
            );
        }
    }
}

#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "release only: cargo test --release --test five_axis"
)]
fn a_drifting_rotary_axis_is_the_diagnosis_finding_and_brought_to_the_noise() {
    for p in five_axis() {
        common::found_on_most_seeds(&format!("{}: {}", p.name, p.demo_effect), 5, |seed| {
            drift_found(p, seed);
        });
    }
}

/// On `p`'s plan with a random truth of `seed` and `p`'s drifting tilt axis: the diagnosis'
/// first candidate is that axis' location drift, and adding it brings the fit to the noise.
fn drift_found(p: &Preset, seed: u64) {
    let model = p.model().unwrap();
    let mut sim = Simulation::new(p.plan().unwrap(), truth(p, seed), seed);
    sim.effects = vec![Effect::parse(p.demo_effect).unwrap()];
    let out = sim.run().unwrap();
    let d = volver::diagnosis::diagnose(&model, &out.measurements).unwrap();
    let tilt = &p.demo_effect["location-drift=".len().."location-drift=".len() + 1];
    let first = &d.candidates[0];
    assert_eq!(first.id, format!("location-drift:{tilt}"), "{}", p.name);
    let added = volver::inputs::with_candidates(
        model.machine(),
        model.clone(),
        std::slice::from_ref(&first.id),
    )
    .unwrap();
    let id = strategy::fit(Problem::new(&added, &out.measurements).unwrap());
    let ratio = id.reached.stats.emm_um / out.record.noise_error.emm_um;
    eprintln!(
        "{} seed {seed}: {} first (ΔBIC {:.0?}); EMM {:.3} → {:.3} µm = {ratio:.4} × the noise error",
        p.name, first.id, first.delta_bic, d.emm_um, id.reached.stats.emm_um
    );
    assert!((0.97..=1.02).contains(&ratio), "{}: {ratio}", p.name);
}

/// Compensation of the tool point and direction over random commands: the forward model at
/// the compensated command puts the tool where, and turns it the way, the nominal machine does
/// at the programmed one.
#[test]
fn compensation_round_trips_position_and_direction_over_random_commands() {
    for p in five_axis() {
        let t = truth(p, 3);
        let (model, params) = (&t.model, &t.params);
        let tool = [0.0, 0.0, -150.0];
        let comp = Compensator::with_orientation(model, params, tool, [0.0, 0.0, -1.0]).unwrap();
        let (mut worst_mm, mut worst_rad, mut before_mm, mut before_rad) =
            (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for q in random_commands(model, 200, 17) {
            let c = comp.compensate(&q).unwrap();
            let o = c.orientation.as_ref().unwrap();
            // Independent f64 evaluations of the nominal and the real machine.
            let nominal = comp.nominal_point(&q);
            let reached = model.tool_point(&c.commands.0, &tool, params);
            let dev = volver::core::problem::norm([
                reached[0] - nominal[0],
                reached[1] - nominal[1],
                reached[2] - nominal[2],
            ]);
            let dir = comp.actual_direction(&c.commands).unwrap();
            let target = comp.nominal_direction(&q).unwrap();
            // |d × t| = sin of the angle between the unit vectors.
            let angle =
                volver::core::problem::norm(volver::core::compensate::cross(dir, target)).asin();
            worst_mm = worst_mm.max(dev);
            worst_rad = worst_rad.max(angle.max(o.deviation_rad));
            before_mm = before_mm.max(c.error_mm);
            before_rad = before_rad.max(o.error_rad);
            assert!(c.steps <= 6, "{}: {} steps", p.name, c.steps);
            assert!(!o.near_singularity, "{}", p.name);
        }
        eprintln!(
            "{}: 200 commands, error up to {:.2} µm and {:.2} µrad, compensated {worst_mm:.1e} mm \
             and {worst_rad:.1e} rad",
            p.name,
            before_mm * 1e3,
            before_rad * 1e6
        );
        assert!(worst_mm <= 1e-9 && worst_rad <= 1e-9, "{}", p.name);
        assert!(before_mm > 1e-3 && before_rad > 1e-6, "{}", p.name);
    }
}

#[test]
fn the_tilt_axis_at_zero_is_reported_as_the_singularity() {
    let p = presets::named("table-table").unwrap();
    let t = truth(p, 4);
    let comp =
        Compensator::with_orientation(&t.model, &t.params, [0.0, 0.0, -150.0], [0.0, 0.0, -1.0])
            .unwrap();
    let m = t.model.machine();
    // Chain order A, C, X, Y, Z.
    let at = |a: f64| m.commands_from_file_units(&[a, 40.0, 50.0, 20.0, 100.0]);
    let tilted = comp.compensate(&at(30.0)).unwrap();
    let o = tilted.orientation.unwrap();
    assert!(!o.near_singularity && (o.sensitivity - 0.5).abs() < 1e-3);
    for a in [0.0, 0.2] {
        let c = comp.compensate(&at(a)).unwrap();
        let o = c.orientation.clone().unwrap();
        assert!(o.near_singularity, "A = {a}: sensitivity {}", o.sensitivity);
        assert!(c.deviation_mm < 1e-9, "A = {a}: the point is still met");
        // C keeps its programmed angle (no half turn of the table for microradians); A does
        // what it can: part of the direction's error is left, and said.
        assert_eq!(c.commands.0[1], at(a).0[1], "A = {a}");
        assert!(
            o.deviation_rad > 1e-6 && o.deviation_rad < o.error_rad,
            "A = {a}: {o:?}"
        );
    }
    // Orientation needs five axes.
    let xcfz = Model::default_xcfz();
    let p0 = xcfz.initial_params();
    let err = Compensator::with_orientation(&xcfz, &p0, [0.0; 3], [0.0, 0.0, -1.0]).unwrap_err();
    assert!(err.to_string().contains("five-axis"), "{err}");
}

/// A five-axis program with A and C words: compensated, written in machine-axis coordinates,
/// re-read by the G-code reader for the positions it moves through, each of which puts the
/// tool (point and direction) where the nominal machine puts it for the programmed line.
#[test]
fn a_five_axis_program_is_written_in_machine_axes_and_re_read() {
    let p = presets::named("table-table").unwrap();
    let t = truth(p, 6);
    let m = t.model.machine();
    let tool = [0.0, 0.0, -150.0];
    let comp = Compensator::with_orientation(&t.model, &t.params, tool, [0.0, 0.0, -1.0]).unwrap();
    let text = "%\nO0005\nG21 G90\nG0 X0 Y0 Z300 A20 C0\nG1 X100 Y50 Z150 A-30 C45 F800\n\
                G1 X-120 Y80 Z100 A45 C200\nG91 G1 X10 A5 C-20\nM30\n%\n";
    let prog = Program::parse(text, "five.nc", m, &Linearise::default()).unwrap();
    let (out, rep) = prog.compensate(&comp, m, 6, "test").unwrap();
    assert_eq!(rep.points, 4);
    assert!(rep.max_direction_error_rad > 1e-6, "{rep:?}");
    assert!(rep.max_written_direction_deviation_rad < 1e-7, "{rep:?}");
    assert!(!out.contains("G91"), "{out}");
    // Programmed positions, chain order A, C, X, Y, Z, as the program states them (the last
    // line incremental from the one before).
    let programmed = [
        [20.0, 0.0, 0.0, 0.0, 300.0],
        [-30.0, 45.0, 100.0, 50.0, 150.0],
        [45.0, 200.0, -120.0, 80.0, 100.0],
        [50.0, 180.0, -110.0, 80.0, 100.0],
    ];
    let again = Program::parse(&out, "out.nc", m, &Linearise::default()).unwrap();
    let moved: Vec<_> = again.points().into_iter().map(|(q, _, _)| q).collect();
    assert_eq!(moved.len(), programmed.len(), "{out}");
    for (q, prog_q) in moved.iter().zip(&programmed) {
        let written = m.commands_from_file_units(&q[..5]);
        let wanted = m.commands_from_file_units(prog_q);
        // The written command moved off the programmed one (it compensates) …
        assert!((0..5).any(|k| (q[k] - prog_q[k]).abs() > 1e-4), "{q:?}");
        // … and the real machine there puts the tool where the nominal one puts it.
        let dev = comp.deviation_mm(&written, comp.nominal_point(&wanted));
        let ang = comp.direction_deviation_rad(&written, comp.nominal_direction(&wanted).unwrap());
        assert!(dev < 1e-5 && ang < 1e-7, "{q:?}: {dev} mm, {ang} rad");
    }
    // Every line's words in machine-axis order X Y Z A C.
    for line in out
        .lines()
        .filter(|l| l.starts_with("G1") || l.starts_with("G0"))
    {
        let letters: String = line
            .split_whitespace()
            .filter_map(|w| w.chars().next())
            .filter(|c| "XYZABC".contains(*c))
            .collect();
        assert_eq!(letters, "XYZAC", "{line}");
    }
}

#[test]
fn tool_centre_point_programs_are_refused_naming_the_word() {
    let m = presets::named("head-head").unwrap().machine().unwrap();
    for (line, word) in [
        ("G43.4 H1", "G43.4"),
        ("G43.5 H2", "G43.5"),
        ("G234 H1", "G234"),
        ("G1 X10 M128", "M128"),
        ("TRAORI", "TRAORI"),
        ("TRAORI(1)", "TRAORI"),
        ("N20 RTCP", "RTCP"),
        ("G68.2 X0 Y0 Z0 I0 J45 K0", "G68.2"),
    ] {
        let text = format!("G21 G90\nG0 X0 Y0 Z100 A0 C0\n{line}\nG1 X10 A20\n");
        let err = Program::parse(&text, "tcp.nc", &m, &Linearise::default())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("tcp.nc:3") && err.contains(word),
            "{line}: {err}"
        );
    }
    // Not those words: a comment, another M code; a longer number is another code, which volver
    // does not know (refused as unknown, not as tool-centre-point mode).
    for line in [
        "(M128 would switch TCPM on)",
        "G1 X10 M8",
        "G1 X12.5 ; TRAORI later",
    ] {
        let text = format!("G21 G90\nG0 X0 Y0 Z100 A0 C0\n{line}\n");
        let r = Program::parse(&text, "ok.nc", &m, &Linearise::default());
        assert!(r.is_ok(), "{line}: {:?}", r.err());
    }
    let text = "G21 G90\nG0 X0 Y0 Z100 A0 C0\nG1 X10 M1280\n";
    let e = Program::parse(text, "ok.nc", &m, &Linearise::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("not a code volver reads") && !e.contains("tool-centre"),
        "{e}"
    );
}

/// Controller tables of a five-axis machine: a hand-set location error of each rotary axis and
/// a hand-set harmonic of the tilt axis read in every format at their known values.
#[test]
fn controller_tables_carry_rotary_and_location_errors() {
    use volver::core::tables::ErrorTables;
    let p = presets::named("table-table").unwrap();
    let model = p.model().unwrap();
    let mut params = model.initial_params();
    let set = |params: &mut Vec<f64>, name: &str, v: f64| {
        params[model.param_index(name).unwrap()] = v;
    };
    set(&mut params, "X0C", 0.012); // mm
    set(&mut params, "B0A", 25e-6); // rad
    set(&mut params, "EAA.a1", 40e-6); // rad: EAA(a) = 40 µrad · sin a
    let t = ErrorTables::from_model(&model, &params, 50.0, 10.0).unwrap();
    let constant = |name: &str| t.constants.iter().find(|c| c.0 == name).unwrap().1;
    assert!((constant("X0C") - 0.012).abs() < 1e-15);
    assert!((constant("B0A") - 25e-6).abs() < 1e-18);
    let a = t.axes.iter().find(|a| a.axis.letter() == 'A').unwrap();
    let eaa = &a.errors.iter().find(|e| e.0 == "EAA").unwrap().1;
    let i = a
        .positions
        .iter()
        .position(|&x| (x - 30.0).abs() < 1e-9)
        .unwrap();
    assert!((eaa[i] - 40e-6 * 0.5).abs() < 1e-15, "{}", eaa[i]);
    // Each format, read as text for the values a controller would take.
    let isg = t.to_isg_csv();
    assert!(isg.contains("X0C Y0C A0C B0C Y0A Z0A B0A C0A"), "{isg}");
    let constants: Vec<&str> = isg
        .lines()
        .skip_while(|l| !l.starts_with("X0C "))
        .nth(1)
        .unwrap()
        .split_whitespace()
        .collect();
    assert_eq!(
        (constants[0], constants[6]),
        ("0.012000000000", "0.000025000000")
    );
    let block = isg.split('#').find(|b| b.contains("\nA EXA ")).unwrap();
    let row: Vec<&str> = block
        .lines()
        .find(|l| l.starts_with("30.000000 "))
        .unwrap()
        .split_whitespace()
        .collect();
    assert_eq!(row[4], "0.000020000000", "EAA at A = 30°: {row:?}");
    let etalon = t.to_etalon();
    assert!(
        etalon.contains("[X0C]\nVALUE = 0.012000000000\n"),
        "{etalon}"
    );
    assert!(
        etalon.contains("[B0A]\nVALUE = 0.000025000000\n"),
        "{etalon}"
    );
    let eaa = etalon.split("[EAA]").nth(1).unwrap();
    assert!(eaa.contains("\n  30.000000 0.000020000000\n"), "{eaa}");
    let plain = t.to_plain_csv();
    assert!(plain.contains("\nX0C,C,,,12.000000000,um\n"), "{plain}");
    assert!(plain.contains("\nB0A,A,,,25.000000,urad\n"), "{plain}");
    assert!(
        plain.contains("\nEAA,A,30.000000,deg,20.000000,urad\n"),
        "{plain}"
    );
}

/// The command line on a preset: simulate, identify with the default model, compensate a point
/// list and a program in position and direction, write the tables, and plan a test.
#[test]
fn the_command_line_runs_a_five_axis_preset_end_to_end() {
    let dir = std::env::temp_dir().join(format!("volver-five-{}", std::process::id()));
    let d = |f: &str| dir.join(f).display().to_string();
    common::simulate(&d("sim"), &["--machine", "head-table", "--seed", "2"]);
    let text = std::fs::read_to_string(dir.join("sim/measurements.csv")).unwrap();
    assert_eq!(
        text.lines().count() - 1,
        1179,
        "the preset plan, 3 reflectors"
    );
    let out = common::volver(&[
        "identify",
        "--machine",
        "head-table",
        "--data",
        &d("sim/measurements.csv"),
        "--out",
        &d("fit.json"),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    std::fs::write(
        dir.join("points.csv"),
        "id,X,Y,Z,C,B\np1,100,-50,200,30,-45\np2,-200,120,50,300,-90\np3,0,0,100,0,0.1\n",
    )
    .unwrap();
    let out = common::volver(&[
        "compensate",
        "--results",
        &d("fit.json"),
        "--points",
        &d("points.csv"),
        "--out",
        &d("comp.csv"),
        "--tool-offset",
        "0,0,-220",
        "--force",
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("tool axis") && stdout.contains("solving for CXYZB"),
        "{stdout}"
    );
    assert!(
        stdout.contains("tool direction: uncompensated error up to"),
        "{stdout}"
    );
    assert!(
        stdout.contains("1 corrected point(s) pass within 1°"),
        "{stdout}"
    );
    let comp = std::fs::read_to_string(dir.join("comp.csv")).unwrap();
    assert!(
        comp.lines()
            .next()
            .unwrap()
            .ends_with("direction_error_urad,direction_deviation_urad,sensitivity"),
        "{comp}"
    );
    std::fs::write(
        dir.join("prog.nc"),
        "G21 G90\nG1 X10 Y20 Z100 C45 B-30 F500\nG43.4 H1\n",
    )
    .unwrap();
    let out = common::volver(&[
        "compensate",
        "--results",
        &d("fit.json"),
        "--gcode",
        &d("prog.nc"),
        "--out",
        &d("prog-comp.nc"),
        "--force",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("prog.nc:3") && err.contains("G43.4"),
        "{err}"
    );
    let out = common::volver(&[
        "tables",
        "--results",
        &d("fit.json"),
        "--out",
        &d("tables"),
        "--force",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let plain = std::fs::read_to_string(dir.join("tables/errors.csv")).unwrap();
    for name in [
        "X0C,C,",
        "Y0C,C,",
        "X0B,B,",
        "Z0B,B,",
        "EBB,B,-120.000000,deg,",
    ] {
        assert!(plain.contains(name), "{name}");
    }
    std::fs::remove_dir_all(&dir).ok();
}
