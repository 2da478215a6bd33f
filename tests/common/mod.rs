//! Helpers shared by the integration tests.

/// Runs the `volver` binary with `args`.
pub fn volver(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_volver"))
        .args(args)
        .output()
        .expect("volver runs")
}
