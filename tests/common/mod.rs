//! Helpers shared by the integration tests.

/// Runs the `volver` binary with `args`.
pub fn volver(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_volver"))
        .args(args)
        .output()
        .expect("volver runs")
}

/// Runs `volver simulate --out OUT ARGS…` and checks it succeeded (not every test uses it).
#[allow(dead_code)]
pub fn simulate(out: &str, args: &[&str]) {
    let mut all = vec!["simulate", "--out", out];
    all.extend_from_slice(args);
    let o = volver(&all);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// The tool at the reflectors' centroid over 8 × 12 × 5 commands of the paper's XCFZ volume
/// (X 0–1400 mm, C 0–330°, Z 0–600 mm).
#[allow(dead_code)]
pub fn tool_grid(m: &volver::core::machine::Machine) -> volver::solvers::uncertainty::ToolGrid {
    let mut commands = Vec::new();
    for x in (0..=1400).step_by(200) {
        for c in (0..=330).step_by(30) {
            for z in (0..=600).step_by(150) {
                commands.push(m.commands_from_file_units(&[x as f64, c as f64, z as f64]));
            }
        }
    }
    let r = m.reflectors();
    let tool = std::array::from_fn(|c| r.iter().map(|x| x.offset[c]).sum::<f64>() / r.len() as f64);
    volver::solvers::uncertainty::ToolGrid { commands, tool }
}
pub mod rs274;
