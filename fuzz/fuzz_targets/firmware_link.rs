//! Fuzz target `firmware_link`: the checks of `fuzz_checks::firmware_link` on every generated input.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_checks::firmware_link::check(data));
