//! Plan files (CSV): see `volver_core::fuzz::plan_file`.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| volver_core::fuzz::plan_file(data));
