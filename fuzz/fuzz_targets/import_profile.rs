//! Import profiles and tracker-software exports: see `volver_core::fuzz::import_profile`.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| volver_core::fuzz::import_profile(data));
