//! Fuzz target `frame`: the checks of `fuzz_checks::frame` on every generated input.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_checks::frame::check(data));
