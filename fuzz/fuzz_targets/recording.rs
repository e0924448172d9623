//! Fuzz target `recording`: the checks of `fuzz_checks::recording` on every generated input.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_checks::recording::check(data));
