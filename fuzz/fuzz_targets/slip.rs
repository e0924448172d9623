//! Fuzz target `slip`: the checks of `fuzz_checks::slip` on every generated input.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_checks::slip::check(data));
