//! Harnesses for fuzzing volver's readers: one function per reader, taking arbitrary bytes.
//!
//! Each either refuses its input with an error or accepts it and carries it one step further
//! (builds the model, evaluates it, writes the result back and reads it again); it panics only
//! when volver is wrong: a panic inside a reader, or volver's own output refused by its own
//! reader. The `cargo fuzz` targets in `fuzz/` call these, and `tests/fuzz_seeds.rs` runs them
//! on the committed seeds and on every input a fuzzer once found, in every test run.
//!
//! ```
//! use volver_core::fuzz;
//! fuzz::machine_toml(volver_core::machine::DEFAULT_MACHINE_TOML.as_bytes());
//! fuzz::gcode(b"G18\nG0 X100 Z50 C0\nG2 X200 Z150 I0 K100\n");
//! fuzz::measurement_csv(b"reflector,X\nR1,1e999\n"); // refused, no panic
//! ```

use crate::compensate::{Compensator, read_points};
use crate::gcode::{Linearise, Program, Setup};
use crate::machine::Machine;
use crate::measure::MeasurementSet;
use crate::model::{ErrorModelSpec, Model};
use crate::results::ResultsFile;
use crate::tables::ErrorTables;

/// A harness: arbitrary bytes in, a panic only when volver is wrong.
pub type Harness = fn(&[u8]);

/// The readers with a harness, by the name of their fuzz target.
pub const TARGETS: [(&str, Harness); 9] = [
    ("machine_toml", machine_toml),
    ("model_toml", model_toml),
    ("measurement_csv", measurement_csv),
    ("import_profile", import_profile),
    ("results_json", results_json),
    ("gcode", gcode),
    ("points_csv", points_csv),
    ("tables", tables),
    ("plan_file", plan_file),
];

/// Evaluates `model` with `params` once per reflector, every axis at zero.
fn evaluate(model: &Model, params: &[f64]) {
    let zeros = vec![0.0; model.machine().axes().len()];
    let commands = model.machine().commands_from_file_units(&zeros);
    for r in 0..model.machine().reflectors().len() {
        let _ = model.predict(&commands, r, params);
    }
}

/// Machine files (TOML): parsed, then the complete error model is built and evaluated.
pub fn machine_toml(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(machine) = Machine::from_toml_str(text, "fuzz.toml") else {
        return;
    };
    let spec = ErrorModelSpec::complete(&machine);
    if let Ok(model) = Model::new(machine, spec) {
        evaluate(&model, &model.initial_params());
    }
}

/// Error-model files (TOML) for the embedded XCFZ machine: parsed, built and evaluated.
pub fn model_toml(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(model) = Model::from_toml_str(Machine::default_xcfz(), text, "fuzz.toml") {
        evaluate(&model, &model.initial_params());
    }
}

/// The embedded XCFZ machine measured from two stations: S1 a tracker (points), S2 a tracing
/// interferometer (ranges).
fn two_stations() -> Machine {
    let m = Machine::default_xcfz();
    let mut layout =
        crate::machine::StationSpec::default_layout(&m, 2, crate::machine::Observes::Point);
    layout[1].observes = crate::machine::Observes::Range;
    m.with_stations(layout).expect("a valid layout")
}

/// Measurement files (CSV) for the embedded XCFZ machine, and for it measured from two stations
/// (a tracker and an interferometer): what the reader accepts, the writer writes (Cartesian and
/// spherical) and the reader accepts again with the same points (each observation and station
/// as read, every value within 1e-6 mm).
pub fn measurement_csv(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    for machine in [Machine::default_xcfz(), two_stations()] {
        let Ok(set) = MeasurementSet::from_csv_str(&machine, text, "fuzz.csv") else {
            continue;
        };
        rewritten(&machine, &set);
    }
}

/// `set` written by volver in both layouts of points and read back: the same observations.
fn rewritten(machine: &Machine, set: &MeasurementSet) {
    use crate::measure::PointColumns;
    for columns in [PointColumns::Cartesian, PointColumns::Spherical] {
        let written = set.to_csv_with(machine, columns);
        let again = match MeasurementSet::from_csv_str(machine, &written, "rewritten.csv") {
            Ok(again) => again,
            Err(e) => panic!("volver's own measurement file is refused: {e}\n{written}"),
        };
        assert_eq!(again.points.len(), set.points.len(), "{written}");
        for (a, b) in set.points.iter().zip(&again.points) {
            assert_eq!(a.observation, b.observation, "{written}");
            assert_eq!(a.station_index, b.station_index, "{written}");
            let scale = a.measured.iter().fold(1.0_f64, |m, v| m.max(v.abs()));
            for k in 0..3 {
                assert!(
                    (a.measured[k] - b.measured[k]).abs() <= 1e-6 * scale,
                    "{:?} written as {:?}\n{written}",
                    a.measured,
                    b.measured
                );
            }
        }
    }
}

/// An import profile (TOML) and a tracker software's export, separated by a line `---`: the
/// profile read, the export read through it for the XCFZ machine measured from two stations;
/// what it accepts volver writes as a measurement file and reads again with the same points.
pub fn import_profile(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Some((profile, export)) = text.split_once("\n---\n") else {
        return;
    };
    let Ok(profile) = crate::import::Profile::from_toml_str(profile, "fuzz.toml") else {
        return;
    };
    let machine = two_stations();
    if let Ok(set) = profile.read(&machine, export, "export.txt") {
        rewritten(&machine, &set);
        // The scale check in the profile's unit refuses or accepts, without a panic.
        let model = Model::new(machine.clone(), ErrorModelSpec::complete(&machine))
            .expect("the complete model builds");
        if let Ok(problem) = crate::problem::Problem::new(&model, &set) {
            let _ = problem.check_scale_in("export.txt", Some(profile.length_unit()));
        }
    }
}

/// Results files (JSON) with or without their covariance record: parsed, then the machine, the
/// model and the parameters are rebuilt and evaluated; an accepted covariance record gives every
/// parameter a finite standard uncertainty, and not all of them zero; what is accepted volver
/// writes and reads again to the same parameters.
pub fn results_json(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(results) = ResultsFile::from_json_str(text, "fuzz.json") else {
        return;
    };
    let Ok((model, params)) = results.to_model("fuzz.json") else {
        return;
    };
    evaluate(&model, &params);
    if let Some(u) = &results.uncertainty {
        let variance: Vec<f64> = (0..params.len())
            .map(|j| {
                let data: f64 = u.data_factor.iter().map(|c| c[j] * c[j]).sum();
                let held: f64 = u.held_factor.iter().map(|c| c[j] * c[j]).sum();
                data + held * u.held_prior_mm * u.held_prior_mm
            })
            .collect();
        assert!(
            variance.iter().all(|v| !v.is_nan()),
            "a NaN variance from an accepted covariance record"
        );
        assert!(
            u.data_factor.iter().flatten().any(|v| *v != 0.0),
            "an accepted covariance record claims U = 0 for every parameter"
        );
    }
    let written = results.to_json();
    match ResultsFile::from_json_str(&written, "rewritten.json").map(|r| r.to_model("rewritten")) {
        Ok(Ok((_, again))) => assert_eq!(again, params, "{written}"),
        Ok(Err(e)) | Err(e) => panic!("volver's own results file is refused: {e}\n{written}"),
    }
}

/// Plan files (CSV) for the embedded XCFZ machine: what the reader accepts volver writes as a
/// plan file (positions rounded to 1e-9 mm or degree) and reads again with the same
/// measurements in the same order, every position within 1e-6 of its unit.
pub fn plan_file(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let machine = Machine::default_xcfz();
    let Ok(plan) = crate::plan::file::from_csv_str(&machine, text, "fuzz.csv") else {
        return;
    };
    let poses = |p: &crate::plan::Plan| -> Vec<(Vec<f64>, usize)> {
        p.steps()
            .iter()
            .map(|s| {
                let c = &p.positions[s.position];
                let v = (machine.axes().iter().enumerate())
                    .map(|(k, ax)| ax.to_file_units(c.0[k]))
                    .collect();
                (v, s.reflector)
            })
            .collect()
    };
    let written = crate::plan::file::to_csv(&plan, &machine, "fuzz");
    let again = match crate::plan::file::from_csv_str(&machine, &written, "rewritten.csv") {
        Ok(again) => again,
        Err(e) => panic!("volver's own plan file is refused: {e}\n{written}"),
    };
    let (a, b) = (poses(&plan), poses(&again));
    assert_eq!(a.len(), b.len(), "{written}");
    for ((p, r), (q, s)) in a.iter().zip(&b) {
        assert_eq!(r, s, "{written}");
        for (x, y) in p.iter().zip(q) {
            assert!((x - y).abs() <= 1e-6, "{x} written as {y}\n{written}");
        }
    }
}

/// G-code for the embedded XCFZ machine starting at its reference position: parsed (arcs
/// linearised to 0.01 mm, moves split at 50 mm), compensated with the paper model carrying a known positioning error of X (50 µm at
/// the end of its travel), and the compensated program must parse again and mean what volver
/// meant: re-read by the same reader, it moves through one point per programmed point, each
/// rapid or optional as its source, and each putting the tool (through the forward model with
/// those errors) within 1e-4 mm of the programmed point's nominal tool point.
pub fn gcode(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let machine = Machine::default_xcfz();
    let lin = Linearise {
        chord_tolerance_mm: 0.01,
        max_segment_mm: Some(50.0),
    };
    // The machine starts at its reference position (every axis known), as `--start` gives it.
    let setup = Setup {
        lin,
        start: std::array::from_fn(|k| machine.axes().get(k).map(|a| a.to_file_units(a.reference))),
        ..Setup::default()
    };
    let Ok(program) = Program::read(text, "fuzz.nc", &machine, &setup) else {
        return;
    };
    let model = Model::default_xcfz();
    let mut params = model.initial_params();
    params[model
        .param_index("EXX.c1")
        .expect("the paper model has EXX")] = 0.05;
    let comp = Compensator::new(&model, &params, [0.0; 3]).expect("the paper model compensates");
    let Ok((out, _)) = program.compensate(&comp, &machine, 6, "fuzz") else {
        return;
    };
    let whole = Linearise {
        max_segment_mm: None,
        ..lin
    };
    let again = Setup {
        lin: whole,
        ..setup.clone()
    };
    let back = match Program::read(&out, "compensated.nc", &machine, &again) {
        Ok(back) => back,
        Err(e) => panic!("volver's own G-code is refused: {e}\n{out}"),
    };
    let (wanted, got) = (program.points(), back.points());
    assert_eq!(wanted.len(), got.len(), "points moved through\n{out}");
    for (i, ((p, rapid, optional), (q, rapid_back, optional_back))) in
        wanted.iter().zip(&got).enumerate()
    {
        assert_eq!(
            (rapid, optional),
            (rapid_back, optional_back),
            "point {i}\n{out}"
        );
        let programmed = machine.commands_from_file_units(&p[..machine.axes().len()]);
        let written = machine.commands_from_file_units(&q[..machine.axes().len()]);
        let d = comp.deviation_mm(&written, comp.nominal_point(&programmed));
        assert!(
            d < 1e-4,
            "point {i}: the compensated program misses its target by {d} mm\n{out}"
        );
    }
}

/// Point lists (CSV) for the embedded XCFZ machine.
pub fn points_csv(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = read_points(text, "fuzz.csv", &Machine::default_xcfz());
    }
}

/// Controller tables; the first byte picks the format (ISG CSV, Etalon style, plain CSV). What a
/// reader accepts, its writer writes and the reader accepts again.
pub fn tables(data: &[u8]) {
    type Reader = fn(&str, &str) -> crate::error::Result<ErrorTables>;
    let Some((&which, rest)) = data.split_first() else {
        return;
    };
    let Ok(text) = std::str::from_utf8(rest) else {
        return;
    };
    let (read, write): (Reader, fn(&ErrorTables) -> String) = match which % 3 {
        0 => (ErrorTables::from_isg_csv, ErrorTables::to_isg_csv),
        1 => (ErrorTables::from_etalon, ErrorTables::to_etalon),
        _ => (ErrorTables::from_plain_csv, ErrorTables::to_plain_csv),
    };
    let Ok(t) = read(text, "fuzz.txt") else {
        return;
    };
    let written = write(&t);
    if let Err(e) = read(&written, "rewritten.txt") {
        panic!("volver's own table is refused: {e}\n{written}");
    }
}
