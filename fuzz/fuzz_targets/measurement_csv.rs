//! Measurement files (CSV) for the embedded XCFZ machine: see `volver_core::fuzz::measurement_csv`.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| volver_core::fuzz::measurement_csv(data));
