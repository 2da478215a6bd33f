//! Builds volver's C++ shim over Ceres Solver and generates its bindings.
//!
//! Needs, from the system: Ceres Solver's headers and library (Debian: `libceres-dev`, which
//! brings Eigen 3, glog and gflags) and libclang for bindgen (Debian: `libclang-dev`). A missing
//! piece stops the build with a message naming the package. Override the header locations with
//! `CERES_INCLUDE_DIR` and `EIGEN_INCLUDE_DIR`, the library location with `CERES_LIB_DIR`.

use std::path::{Path, PathBuf};

const INSTALL: &str = "on Debian or Ubuntu: `apt-get install libceres-dev libclang-dev` \
                       (or run `bash scripts/test`, which installs them)";

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
    for var in ["CERES_INCLUDE_DIR", "EIGEN_INCLUDE_DIR", "CERES_LIB_DIR"] {
        println!("cargo:rerun-if-env-changed={var}");
    }
    println!("cargo:rerun-if-changed=shim/volver_ceres.h");
    println!("cargo:rerun-if-changed=shim/volver_ceres.cpp");

    let ceres = first_existing(
        "CERES_INCLUDE_DIR",
        &[
            "/usr/include",
            "/usr/local/include",
            "/opt/homebrew/include",
        ],
        "ceres/ceres.h",
    )
    .unwrap_or_else(|| {
        panic!(
            "\n\nvolver-ceres-sys: Ceres Solver's headers (ceres/ceres.h) were not found.\n\
             The `ceres` feature needs the system package libceres-dev; {INSTALL}.\n\
             Or set CERES_INCLUDE_DIR to the folder holding ceres/ceres.h.\n\n"
        )
    });
    let eigen = first_existing(
        "EIGEN_INCLUDE_DIR",
        &[
            "/usr/include/eigen3",
            "/usr/local/include/eigen3",
            "/opt/homebrew/include/eigen3",
        ],
        "Eigen/Core",
    )
    .unwrap_or_else(|| {
        panic!(
            "\n\nvolver-ceres-sys: Eigen 3's headers (eigen3/Eigen/Core) were not found; Ceres' \
             headers need them. Install libeigen3-dev (libceres-dev brings it); {INSTALL}.\n\
             Or set EIGEN_INCLUDE_DIR to the folder holding Eigen/Core.\n\n"
        )
    });

    // For crates that compile C++ of their own against Ceres (`links = "ceres"`: they read
    // DEP_CERES_INCLUDE and DEP_CERES_EIGEN).
    println!("cargo:include={}", ceres.display());
    println!("cargo:eigen={}", eigen.display());

    cc::Build::new()
        .cpp(true)
        .std("c++17")
        .file("shim/volver_ceres.cpp")
        .include("shim")
        .include(&ceres)
        .include(&eigen)
        .flag_if_supported("-Wno-unused-parameter")
        .flag_if_supported("-Wno-deprecated-declarations")
        .compile("volver_ceres_shim");

    if let Ok(dir) = std::env::var("CERES_LIB_DIR") {
        println!("cargo:rustc-link-search=native={dir}");
    }
    println!("cargo:rustc-link-lib=dylib=ceres");
    println!("cargo:rustc-link-lib=dylib=glog");

    // bindgen loads libclang at run time and panics when it is missing: say which package.
    let generated = std::panic::catch_unwind(|| {
        bindgen::Builder::default()
            .header("shim/volver_ceres.h")
            .allowlist_function("volver_ceres_.*")
            .allowlist_type("volver_ceres_.*")
            .allowlist_var("VOLVER_CERES_.*")
            .rustified_enum("volver_ceres_.*")
            .derive_default(true)
            .layout_tests(true)
            .generate()
    });
    let bindings = match generated {
        Ok(Ok(b)) => b,
        Ok(Err(e)) => panic!("volver-ceres-sys: bindgen failed on shim/volver_ceres.h: {e}"),
        Err(_) => panic!(
            "\n\nvolver-ceres-sys: bindgen could not run; it needs libclang (Debian package \
             libclang-dev); {INSTALL}.\n\n"
        ),
    };
    let out = PathBuf::from(std::env::var("OUT_DIR").expect("cargo sets OUT_DIR"));
    bindings
        .write_to_file(out.join("bindings.rs"))
        .expect("volver-ceres-sys: cannot write the generated bindings");
}
