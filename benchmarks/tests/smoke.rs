//! The bench binary's measurements run and report finite figures (no timing is judged).

use std::process::Command;

fn child(what: &str) -> serde_json::Value {
    let out = Command::new(env!("CARGO_BIN_EXE_bench"))
        .args(["child", what, "test4"])
        .output()
        .expect("bench binary");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    serde_json::from_str(text.lines().last().expect("a JSON line")).expect("JSON")
}

#[test]
fn kernels_and_the_native_lm_report_finite_figures() {
    let k = child("kernels");
    for key in [
        "f64_ns",
        "jacobian_ns",
        "normal_s",
        "jacobian_pass_s",
        "gemm_gflops",
    ] {
        let v = k[key].as_f64().unwrap_or(f64::NAN);
        assert!(v.is_finite() && v > 0.0, "{key} = {v}");
    }
    assert_eq!(k["points"], 1040);
    assert_eq!(k["params"], 74);
    let lm = child("lm");
    assert!(lm["error"].is_null(), "{lm}");
    let phi = lm["phi_mm"].as_f64().unwrap();
    // The demo's fit: Φ near the paper's noise level, converged.
    // (the paper's bounded noise gives a noise error of 35–50 µm on test 4).
    assert!((0.03..0.12).contains(&phi), "Φ {phi}");
    assert!(
        lm["termination"].as_str().unwrap().starts_with("converged"),
        "{lm}"
    );
    assert!(lm["peak_mb"].as_f64().unwrap() > 0.0);
}
