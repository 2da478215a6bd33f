//! With the `ceres` feature, builds the expert Ceres program (`ceres/expert.cpp`) that the bench
//! measures the native engine against. Needs Ceres Solver's and Eigen 3's headers (Debian:
//! `libceres-dev`); override their locations with `CERES_INCLUDE_DIR` and `EIGEN_INCLUDE_DIR`, the
//! library's with `CERES_LIB_DIR` (as for `volver-ceres-sys`).

use std::path::{Path, PathBuf};

fn first_existing(env: &str, candidates: &[&str], probe: &str) -> Option<PathBuf> {
    if let Ok(dir) = std::env::var(env) {
        return Path::new(&dir)
            .join(probe)
            .exists()
            .then(|| PathBuf::from(dir));
    }
    candidates
        .iter()
        .map(PathBuf::from)
        .find(|d| d.join(probe).exists())
}

fn main() {
    println!("cargo:rerun-if-changed=ceres/expert.cpp");
    for var in ["CERES_INCLUDE_DIR", "EIGEN_INCLUDE_DIR", "CERES_LIB_DIR"] {
        println!("cargo:rerun-if-env-changed={var}");
    }
    if std::env::var_os("CARGO_FEATURE_CERES").is_none() {
        return;
    }
    let install =
        "on Debian or Ubuntu: `apt-get install libceres-dev` (or run `bash scripts/test`)";
    let ceres = first_existing(
        "CERES_INCLUDE_DIR",
        &[
            "/usr/include",
            "/usr/local/include",
            "/opt/homebrew/include",
        ],
        "ceres/ceres.h",
    )
    .unwrap_or_else(|| panic!("volver-benchmarks: Ceres' headers were not found; {install}"));
    let eigen = first_existing(
        "EIGEN_INCLUDE_DIR",
        &[
            "/usr/include/eigen3",
            "/usr/local/include/eigen3",
            "/opt/homebrew/include/eigen3",
        ],
        "Eigen/Core",
    )
    .unwrap_or_else(|| panic!("volver-benchmarks: Eigen 3's headers were not found; {install}"));
    cc::Build::new()
        .cpp(true)
        .std("c++17")
        .file("ceres/expert.cpp")
        .include(&ceres)
        .include(&eigen)
        .opt_level(3)
        .define("NDEBUG", None)
        .flag_if_supported("-march=native")
        .flag_if_supported("-Wno-unused-parameter")
        .flag_if_supported("-Wno-deprecated-declarations")
        .compile("volver_expert_ceres");
    if let Ok(dir) = std::env::var("CERES_LIB_DIR") {
        println!("cargo:rustc-link-search=native={dir}");
    }
    println!("cargo:rustc-link-lib=dylib=ceres");
    println!("cargo:rustc-link-lib=dylib=glog");
}
