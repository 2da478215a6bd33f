//! The forward model of eq. 11 at one commanded position: the reflector's predicted point in
//! the tracker frame for the paper's XCFZ grinder with every error zero, then with one error
//! set by hand, and the exact Jacobian of the prediction with respect to every parameter.
//!
//! ```text
//! cargo run -p volver-core --example forward_model
//! ```

use volver_core::model::Model;

fn main() {
    let model = Model::default_xcfz();
    // Commands in file units: X 700 mm, C 90°, Z 300 mm.
    let commands = model
        .machine()
        .commands_from_file_units(&[700.0, 90.0, 300.0]);
    let mut params = model.initial_params();
    let nominal = model.predict(&commands, 0, &params);
    println!("nominal reflector 0: {nominal:.6?} mm");
    // EXX (positioning error of X) as a constant 10 µm: its first coefficient.
    let j = model
        .params()
        .iter()
        .position(|p| p.name.starts_with("EXX"))
        .expect("the paper's model has EXX");
    params[j] = 0.010;
    let moved = model.predict(&commands, 0, &params);
    let shift: Vec<f64> = (0..3).map(|c| (moved[c] - nominal[c]) * 1e3).collect();
    println!(
        "with {} = 10 µm: shift {shift:.3?} µm",
        model.params()[j].name
    );
    // The exact Jacobian, row-major 3 × parameters.
    let n = model.n_params();
    let mut jac = vec![0.0; 3 * n];
    let point = model.predict_with_jacobian(&commands, 0, &params, &mut jac);
    assert_eq!(point, moved);
    println!(
        "Jacobian: 3 × {n}; ∂(x, y, z)/∂{} = ({:.6}, {:.6}, {:.6})",
        model.params()[j].name,
        jac[j],
        jac[n + j],
        jac[2 * n + j]
    );
}
