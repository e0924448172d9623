//! Command-line values shared by the simulator's and the coordinator's binaries (durations,
//! physics rates, kicks), so a bad value is refused by clap with a message naming the flag
//! instead of panicking later, and the binaries' logging set-up (feature `cli`). Physics-free: a
//! coordinator built without the simulator parses the same flags.

/// Longest duration a flag accepts, seconds (about 11.6 days): beyond it a run is a typo, and
/// every conversion to a `Duration` or to nanoseconds of simulated time stays far from overflow.
pub const MAX_SECONDS: f64 = 1e6;

/// Parses a duration in seconds that is finite, positive and at most [`MAX_SECONDS`]; for clap's
/// `value_parser`.
pub fn parse_seconds(text: &str) -> Result<f64, String> {
    let secs: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("{text:?} is not a number of seconds"))?;
    if !secs.is_finite() {
        return Err(format!("{text:?} is not a finite number of seconds"));
    }
    if secs <= 0.0 {
        return Err(format!("{text:?} seconds: must be more than 0"));
    }
    if secs > MAX_SECONDS {
        return Err(format!(
            "{text:?} seconds: must be at most {MAX_SECONDS} (about 11.6 days)"
        ));
    }
    Ok(secs)
}

/// Physics rates a run may ask for, Hz: each divides the 1 kHz clock, and none is so coarse that
/// a robot at full speed moves more than a few millimetres per physics step.
pub const PHYSICS_HZ: [u32; 4] = [1000, 500, 250, 200];

/// Parses a physics rate in Hz (one of [`PHYSICS_HZ`]) into clock steps per physics step; for
/// clap's `value_parser`.
pub fn parse_physics_hz(text: &str) -> Result<u32, String> {
    let choices = PHYSICS_HZ.map(|hz| hz.to_string()).join(", ");
    let hz: u32 = text
        .trim()
        .parse()
        .map_err(|_| format!("{text:?} is not a rate in Hz: expected one of {choices}"))?;
    if !PHYSICS_HZ.contains(&hz) {
        return Err(format!(
            "{hz} Hz: the physics rate must be one of {choices}"
        ));
    }
    Ok(1000 / hz)
}

/// A kick from the command line: robot id, when (simulated time from the start), and the
/// displacement (metres along x and y, radians counter-clockwise).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KickArg {
    /// Robot id.
    pub robot: u16,
    /// When.
    pub at: std::time::Duration,
    /// Displacement along x, metres.
    pub dx_m: f64,
    /// Displacement along y, metres.
    pub dy_m: f64,
    /// Turn, radians counter-clockwise.
    pub dtheta_rad: f64,
}

/// Parses `ID:SECONDS:DX,DY[,DEG]` (metres and degrees), e.g. `2:5:0,0.03` or `2:5:0,0.03,15`;
/// for clap's `value_parser`.
pub fn parse_kick(text: &str) -> Result<KickArg, String> {
    let usage = || format!("{text:?}: expected ID:SECONDS:DX,DY[,DEG], e.g. 2:5:0,0.03,15");
    let mut parts = text.splitn(3, ':');
    let (Some(id), Some(at), Some(by)) = (parts.next(), parts.next(), parts.next()) else {
        return Err(usage());
    };
    let robot = id
        .trim()
        .parse()
        .map_err(|_| format!("{text:?}: robot id {id:?} is not a number from 0 to 65535"))?;
    let at = parse_duration(at).map_err(|e| format!("{text:?}: when: {e}"))?;
    let numbers: Vec<&str> = by.split(',').collect();
    if !(2..=3).contains(&numbers.len()) {
        return Err(usage());
    }
    let mut values = [0.0; 3];
    for (v, n) in values.iter_mut().zip(&numbers) {
        *v = n
            .trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| format!("{text:?}: {n:?} is not a finite number"))?;
    }
    if values[0].abs() > MAX_KICK_M || values[1].abs() > MAX_KICK_M {
        return Err(format!(
            "{text:?}: a kick moves a robot at most {MAX_KICK_M} m along each axis"
        ));
    }
    Ok(KickArg {
        robot,
        at,
        dx_m: values[0],
        dy_m: values[1],
        dtheta_rad: values[2].to_radians(),
    })
}

/// The farthest a kick moves a robot along each axis, metres: beyond it the robot leaves any
/// arena and the flag was a typo (millimetres for metres).
pub const MAX_KICK_M: f64 = 10.0;

/// Logs to stderr at `warn` unless `RUST_LOG` says otherwise, coloured only on a terminal (a log
/// file or a test's captured output gets no escape codes).
#[cfg(feature = "cli")]
pub fn init_logging() {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "warn".into()),
        )
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
}

/// As [`parse_seconds`], as a `Duration`.
pub fn parse_duration(text: &str) -> Result<std::time::Duration, String> {
    parse_seconds(text).map(std::time::Duration::from_secs_f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_physics_rate_is_a_whole_number_of_clock_steps() {
        assert_eq!(parse_physics_hz("1000"), Ok(1));
        assert_eq!(parse_physics_hz(" 500"), Ok(2));
        assert_eq!(parse_physics_hz("250"), Ok(4));
        assert_eq!(parse_physics_hz("200"), Ok(5));
        for bad in ["300", "100", "0", "-200", "2e2", "fast"] {
            let e = parse_physics_hz(bad).expect_err(bad);
            assert!(e.contains("1000, 500, 250, 200"), "{bad}: {e}");
        }
    }

    #[test]
    fn accepts_finite_positive_bounded_seconds() {
        assert_eq!(parse_seconds("60"), Ok(60.0));
        assert_eq!(parse_seconds("0.25"), Ok(0.25));
        assert_eq!(parse_seconds("1e6"), Ok(1e6));
        assert_eq!(
            parse_duration("1.5"),
            Ok(std::time::Duration::from_millis(1500))
        );
    }

    #[test]
    fn kicks_parse_with_and_without_a_turn_and_bad_ones_are_named() {
        let k = parse_kick("2:5:0,0.03").unwrap();
        assert_eq!(
            (k.robot, k.at, k.dx_m, k.dy_m, k.dtheta_rad),
            (2, std::time::Duration::from_secs(5), 0.0, 0.03, 0.0)
        );
        let k = parse_kick("7:0.5:-0.01,0.02,90").unwrap();
        assert!((k.dtheta_rad - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        for (bad, says) in [
            ("2:5", "expected ID:SECONDS"),
            ("x:5:0,0", "robot id"),
            ("2:-1:0,0", "when"),
            ("2:5:0", "expected ID:SECONDS"),
            ("2:5:0,0,1,2", "expected ID:SECONDS"),
            ("2:5:0,NaN", "not a finite number"),
            ("2:5:30,0", "at most"),
        ] {
            let e = parse_kick(bad).expect_err(bad);
            assert!(e.contains(says) && e.contains(bad), "{bad}: {e}");
        }
    }

    #[test]
    fn refuses_what_would_panic_or_run_forever() {
        for bad in [
            "NaN", "nan", "inf", "-inf", "1e300", "1e6.1", "1000001", "-0.5", "0", "-0", "", "1s",
            "ten",
        ] {
            let err = parse_seconds(bad).expect_err(bad);
            assert!(err.contains(&format!("{bad:?}")), "{bad}: {err}");
            assert!(parse_duration(bad).is_err(), "{bad}");
        }
    }
}
