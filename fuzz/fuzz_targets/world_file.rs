//! Fuzz target `world_file`: the checks of `fuzz_checks::world_file` on every generated input.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_checks::world_file::check(data));
