//! Command-line value parsers shared by the simulator's and the coordinator's binaries, so a bad
//! value is refused by clap with a message naming the flag instead of panicking later.

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

/// Logs to stderr at `warn` unless `RUST_LOG` says otherwise, coloured only on a terminal (a log
/// file or a test's captured output gets no escape codes).
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
