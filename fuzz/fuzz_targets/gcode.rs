//! G-code for the embedded XCFZ machine: see `volver_core::fuzz::gcode`.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| volver_core::fuzz::gcode(data));
