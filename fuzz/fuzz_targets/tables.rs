//! Controller error tables in the three formats: see `volver_core::fuzz::tables`.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| volver_core::fuzz::tables(data));
