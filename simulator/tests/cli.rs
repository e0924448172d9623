//! `pocketbot-sim` refuses bad flag values with a message naming the flag, never a panic.

use std::process::Command;

#[test]
fn bad_durations_are_refused_with_a_clear_message() {
    for bad in ["NaN", "inf", "1e300", "-0.5", "0", "1e7", "soon"] {
        for args in [
            vec!["--duration".to_string(), bad.to_string()],
            vec![format!("--duration={bad}")],
        ] {
            let out = Command::new(env!("CARGO_BIN_EXE_pocketbot-sim"))
                .args(["--port-base", "0"])
                .args(&args)
                .output()
                .expect("run pocketbot-sim");
            let stderr = String::from_utf8_lossy(&out.stderr);
            assert!(!out.status.success(), "{args:?} was accepted");
            assert!(!stderr.contains("panicked"), "{args:?} panicked: {stderr}");
            assert!(
                stderr.contains("--duration") && stderr.contains(bad),
                "{args:?}: the message does not name the flag and value: {stderr}"
            );
            assert!(
                out.stdout.is_empty(),
                "{args:?}: served before refusing the value"
            );
        }
    }
}
