//! Examples of the PocketFleet public APIs; run them with `cargo run --example NAME`.
//!
//! - `hello_robot`: the thesis's Appendix A.1 program against a simulated robot.
