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
