//! Results files (JSON): see `volver_core::fuzz::results_json`.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| volver_core::fuzz::results_json(data));
