//! With the `ceres` feature, builds the expert Ceres program (`ceres/expert.cpp`) that the bench
//! measures the native engine against, with the Ceres and Eigen headers `volver-ceres-sys` found
//! (it links the library too).

fn main() {
    println!("cargo:rerun-if-changed=ceres/expert.cpp");
    if std::env::var_os("CARGO_FEATURE_CERES").is_none() {
        return;
    }
    let dir = |var: &str| {
        std::env::var(var).unwrap_or_else(|_| {
            panic!("volver-benchmarks: {var} is not set; volver-ceres-sys sets it")
        })
    };
    cc::Build::new()
        .cpp(true)
        .std("c++17")
        .file("ceres/expert.cpp")
        .include(dir("DEP_CERES_INCLUDE"))
        .include(dir("DEP_CERES_EIGEN"))
        .opt_level(3)
        .define("NDEBUG", None)
        .flag_if_supported("-march=native")
        .flag_if_supported("-Wno-unused-parameter")
        .flag_if_supported("-Wno-deprecated-declarations")
        .compile("volver_expert_ceres");
}
