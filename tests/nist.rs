//! The NIST StRD nonlinear-regression problems: every file reads, every model written in
//! `volver_core::nist` reproduces the certified residual sum of squares at the certified
//! parameters, its dual-number Jacobian matches finite differences, and bad files are refused
//! with the place named.

use num_dual::Dual64;
use volver::core::nist::{self, Difficulty, NAMES, lre};
use volver::core::problem::{CurveFit, Residuals};

#[test]
fn every_file_reads_and_counts_agree_with_its_header() {
    let all = nist::all().unwrap();
    assert_eq!(all.len(), 27);
    let count = |d: Difficulty| all.iter().filter(|p| p.difficulty == d).count();
    assert_eq!(
        (
            count(Difficulty::Lower),
            count(Difficulty::Average),
            count(Difficulty::Higher)
        ),
        (8, 11, 8)
    );
    for (ds, name) in all.iter().zip(NAMES) {
        assert_eq!(ds.name, name);
        let text = std::fs::read_to_string(format!("core/data/nist/{name}.dat")).unwrap();
        let obs: usize = text
            .lines()
            .find_map(|l| l.trim().strip_prefix("Number of Observations:"))
            .unwrap()
            .trim()
            .parse()
            .unwrap();
        assert_eq!(ds.n_obs(), obs, "{name}");
        assert!(
            ds.x.iter()
                .all(|r| r.len() == if name == "Nelson" { 2 } else { 1 })
        );
        assert_eq!(ds.starts[0].len(), ds.n_params());
        assert_eq!(ds.starts[1].len(), ds.n_params());
    }
}

#[test]
fn the_certified_parameters_give_the_certified_residual_sum_of_squares() {
    let mut worst = (11.0, "");
    for ds in nist::all().unwrap() {
        let rss = ds.rss(&ds.certified);
        let digits = lre(rss, ds.certified_rss);
        println!(
            "{:<9} RSS {rss:.10e} certified {:.10e}  LRE {digits:.1}",
            ds.name, ds.certified_rss
        );
        if ds.name == "Lanczos1" {
            // Generated without noise (certified RSS 1.4e-25): at the certified parameters,
            // rounded to 11 digits, the residuals are that rounding, ~1e-11 each.
            assert!(rss < 1e-19, "Lanczos1: {rss}");
        } else if digits < worst.0 {
            worst = (digits, ds.name.leak());
        }
    }
    // The certified values are given to 11 digits; the model formulas are right when the RSS
    // agrees to (nearly) as many.
    assert!(worst.0 >= 9.0, "{worst:?}");
}

#[test]
fn the_dual_number_jacobian_matches_finite_differences() {
    for ds in nist::all().unwrap() {
        let n = ds.n_params();
        for start in &ds.starts {
            for i in [0, ds.n_obs() / 2, ds.n_obs() - 1] {
                for k in 0..n {
                    let h = 1e-6 * start[k].abs().max(1e-6);
                    let (mut up, mut dn) = (start.clone(), start.clone());
                    up[k] += h;
                    dn[k] -= h;
                    let fd = (ds.residual(i, &up) - ds.residual(i, &dn)) / (2.0 * h);
                    // Forward mode, one direction at a time.
                    let b: Vec<Dual64> = (0..n)
                        .map(|j| Dual64::new(start[j], if j == k { 1.0 } else { 0.0 }))
                        .collect();
                    let ad = ds.residual(i, &b).eps;
                    assert!(
                        (fd - ad).abs() <= 1e-5 * (fd.abs() + ad.abs()) + 1e-9,
                        "{} obs {i} b{}: dual {ad} vs finite differences {fd}",
                        ds.name,
                        k + 1
                    );
                }
            }
        }
    }
}

#[test]
fn the_second_directional_derivative_matches_finite_differences() {
    for ds in nist::all().unwrap() {
        let problem = CurveFit::new(&ds);
        let n = ds.n_params();
        for start in &ds.starts {
            // A direction mixing every parameter at its own scale.
            let v: Vec<f64> = (0..n)
                .map(|k| start[k].abs().max(1e-6) * if k % 2 == 0 { 1.0 } else { -0.5 })
                .collect();
            let h = 1e-5;
            let at =
                |t: f64| -> Vec<f64> { start.iter().zip(&v).map(|(p, d)| p + t * d).collect() };
            let mut jac = vec![0.0; 3 * n];
            for i in [0, ds.n_obs() / 2, ds.n_obs() - 1] {
                let mut jv = |q: &[f64]| {
                    problem.residual_and_jacobian(i, q, &mut jac);
                    (0..n).map(|k| jac[k] * v[k]).sum::<f64>()
                };
                let fd = (jv(&at(h)) - jv(&at(-h))) / (2.0 * h);
                let exact = problem.residual_second_directional(i, start, &v)[0];
                assert!(
                    (fd - exact).abs() <= 1e-5 * (fd.abs() + exact.abs()) + 1e-9,
                    "{} obs {i}: second directional derivative {exact} vs finite differences {fd}",
                    ds.name
                );
            }
        }
    }
}

#[test]
fn bad_files_are_refused_with_the_place_named() {
    let good = std::fs::read_to_string("core/data/nist/Misra1a.dat").unwrap();
    let lines: Vec<&str> = good.lines().collect();
    // A start that is not a number (line 41, b1).
    let mut bad = lines.clone();
    let b1 = bad[40].replace("500", "5x0");
    bad[40] = &b1;
    let err = nist::Dataset::parse("Misra1a", &bad.join("\n"), "bad.dat")
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("bad.dat") && err.contains("41") && err.contains("b1"),
        "{err}"
    );
    // A data line with a missing column (line 61).
    let mut bad = lines.clone();
    bad[60] = "      10.07E0";
    let err = nist::Dataset::parse("Misra1a", &bad.join("\n"), "bad.dat")
        .unwrap_err()
        .to_string();
    assert!(err.contains("bad.dat") && err.contains("61"), "{err}");
    // A truncated file.
    let err = nist::Dataset::parse("Misra1a", &lines[..50].join("\n"), "cut.dat")
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("cut.dat") && err.contains("past the end"),
        "{err}"
    );
    // An unknown problem.
    assert!(
        nist::dataset("Rosenbrock")
            .unwrap_err()
            .to_string()
            .contains("Misra1a")
    );
}

#[test]
fn the_native_lm_reaches_four_digits_of_the_certified_rss_and_parameters() {
    use volver::solvers::nist_suite;
    let mut short = Vec::new();
    for ds in nist::all().unwrap() {
        for start in 0..2 {
            let r = nist_suite::run(&ds, start, &nist_suite::lm(), &nist_suite::options());
            println!(
                "{:<9} start {}  LRE params {:>4.1}  RSS {:>4.1}  {} it  {}",
                r.problem, r.start, r.lre_params, r.lre_rss, r.iterations, r.termination
            );
            assert!(!r.termination.failed(), "{}: {}", r.problem, r.termination);
            // Lanczos1's certified RSS (1.4e-25) lies below what a double-precision evaluation
            // of its model resolves: residuals of ~8e-14 carry rounding of ~1e-16, so every
            // engine gets ~3 digits of the RSS; its parameters are judged instead.
            let digits = if r.problem == "Lanczos1" {
                r.lre_params
            } else {
                r.lre_rss
            };
            if digits < 4.0 {
                short.push(format!("{} start {}: {digits:.1}", r.problem, r.start));
            }
            // Where the RSS is reached, the certified parameters are too: a fit that matches the
            // RSS with other parameters has stopped in a flat valley, not at the certified
            // optimum (the criterion of McCullough's StRD assessments: 4 digits of each).
            if r.lre_rss >= 4.0 && r.lre_params < 4.0 {
                short.push(format!(
                    "{} start {}: parameters {:.1} at RSS {:.1}",
                    r.problem, r.start, r.lre_params, r.lre_rss
                ));
            }
        }
    }
    assert!(short.is_empty(), "fewer than 4 digits: {short:?}");
}

/// The goal: a native LM at least as accurate as Ceres (dense QR, the same options) on
/// every problem, measured in the same run. Digits beyond 9 are at the rounding of the problems'
/// own condition, where which engine stops nearer is chance; below that the LM must not trail.
#[cfg(feature = "ceres")]
#[test]
fn the_native_lm_is_at_least_as_accurate_as_ceres() {
    use volver::solvers::{ceres::Ceres, nist_suite};
    let (mut sum_lm, mut sum_ceres) = (0.0, 0.0);
    let mut behind = Vec::new();
    for ds in nist::all().unwrap() {
        for start in 0..2 {
            let lm = nist_suite::run(&ds, start, &nist_suite::lm(), &nist_suite::options());
            let ceres = nist_suite::run(&ds, start, &Ceres::default(), &nist_suite::options());
            sum_lm += lm.lre_params + lm.lre_rss;
            sum_ceres += ceres.lre_params + ceres.lre_rss;
            for (what, a, b) in [
                ("parameters", lm.lre_params, ceres.lre_params),
                ("RSS", lm.lre_rss, ceres.lre_rss),
            ] {
                if a < b.min(9.0) - 0.5 {
                    behind.push(format!(
                        "{} start {}: {what} LM {a:.1} vs Ceres {b:.1}",
                        ds.name,
                        start + 1
                    ));
                }
            }
        }
    }
    assert!(behind.is_empty(), "{behind:?}");
    assert!(
        sum_lm >= sum_ceres,
        "mean LRE: LM {sum_lm} vs Ceres {sum_ceres}"
    );
}

mod common;

#[test]
fn volver_compare_runs_the_nist_suite() {
    let out = common::volver(&["compare", "--suite", "nist", "--engines", "lm", "--json"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["runs"].as_array().unwrap().len(), 54);
    let mean = v["means"][0]["mean_lre_rss"].as_f64().unwrap();
    assert!(mean > 9.0, "mean LRE of the RSS {mean}");
    let out = common::volver(&["compare", "--suite", "nist", "--engines", "lm"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("Bennett5") && text.contains("mean"), "{text}");
    let out = common::volver(&["compare", "--suite", "strd2"]);
    assert!(!out.status.success());
}
