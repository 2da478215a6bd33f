//! Machine files (TOML): see `volver_core::fuzz::machine_toml`.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| volver_core::fuzz::machine_toml(data));
