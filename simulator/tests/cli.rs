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

/// A world the simulator cannot hold is a usage error like a bad flag: exit 2, the file and line
/// named, no backtrace (it once exited 1 with anyhow's "Error:" and a stack trace).
#[test]
fn a_world_it_cannot_hold_exits_2_naming_the_line() {
    let path = std::env::temp_dir().join(format!("pocketbot-sim-big-{}.toml", std::process::id()));
    std::fs::write(
        &path,
        "name = \"big\"\n[arena]\nwidth_m = 1e30\nheight_m = 1.0\n",
    )
    .expect("write world");
    let out = Command::new(env!("CARGO_BIN_EXE_pocketbot-sim"))
        .args(["--port-base", "0", "--world"])
        .arg(&path)
        .output()
        .expect("run pocketbot-sim");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains(".toml:3: arena.width_m"), "{stderr}");
    assert!(
        !stderr.contains("backtrace") && !stderr.contains("panicked"),
        "{stderr}"
    );
    assert!(out.stdout.is_empty());
    let _ = std::fs::remove_file(&path);
}
