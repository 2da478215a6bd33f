//! Error-model files (TOML) for the embedded XCFZ machine: see `volver_core::fuzz::model_toml`.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| volver_core::fuzz::model_toml(data));
