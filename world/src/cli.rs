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

/// A link profile from the command line: a profile's name, or the path of a TOML file holding a
/// `[link]` table as a world file has it (which may itself start from a `profile`).
#[derive(Clone, Debug, PartialEq)]
pub struct LinkProfileArg {
    /// What was given: the name, or the path.
    pub name: String,
    /// The model it stands for.
    pub model: crate::RadioModel,
}

/// Parses `--link-profile NAME|FILE`; for clap's `value_parser`.
pub fn parse_link_profile(text: &str) -> Result<LinkProfileArg, String> {
    let name = text.trim().to_owned();
    if let Some(model) = crate::RadioModel::profile(&name) {
        return Ok(LinkProfileArg { name, model });
    }
    let path = std::path::Path::new(&name);
    if !path.is_file() {
        return Err(format!(
            "{name:?} is neither a link profile ({}) nor a file",
            crate::RadioModel::profile_names()
        ));
    }
    let text = std::fs::read_to_string(path).map_err(|e| format!("{name}: {e}"))?;
    let model = crate::file::parse_link(&text, &name).map_err(|e| e.to_string())?;
    Ok(LinkProfileArg { name, model })
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

/// How a kick moves a robot.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KickHow {
    /// Picked up and put down: the body is moved at once and nothing on the robot feels it.
    Teleport,
    /// Shoved by a hand over this long (20–100 ms): the wheels drag, the accelerometer feels
    /// the jolt, and a body in the way stops it.
    Shove(std::time::Duration),
}

/// A shove lasts this long unless the flag says otherwise.
pub const DEFAULT_SHOVE: std::time::Duration = std::time::Duration::from_millis(50);

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
    /// Teleport or shove.
    pub how: KickHow,
}

/// A kick drawn per seed: one robot, a time in the window, a shift of up to
/// [`RANDOM_SHIFT_M`] in any direction and a turn of up to [`RANDOM_TURN_DEG`] either way,
/// uniformly, never into an overlap with another body or a wall at that instant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RandomKick {
    /// Teleport or shove.
    pub how: KickHow,
    /// The time is drawn uniformly from one second to this, after the robots are connected.
    pub within: std::time::Duration,
}

/// The largest shift and turn a random kick draws.
pub const RANDOM_SHIFT_M: f64 = 0.03;
/// See [`RANDOM_SHIFT_M`].
pub const RANDOM_TURN_DEG: f64 = 20.0;
/// The window a random kick's time is drawn from unless the flag says otherwise, seconds.
pub const RANDOM_WITHIN_S: f64 = 30.0;

/// A `--kick` flag: a given kick or one drawn per seed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum KickSpec {
    /// This kick.
    Given(KickArg),
    /// One drawn per seed.
    Random(RandomKick),
}

const KICK_USAGE: &str = "expected [teleport:|shove[/MS]:]ID:SECONDS:DX,DY[,DEG] or \
                          random[:teleport|:shove[/MS]][:WITHIN_SECONDS], e.g. 2:5:0,0.03,15, \
                          shove:2:5:0,0.015 or random:teleport";

/// Parses a `--kick` flag; for clap's `value_parser`:
/// - `ID:SECONDS:DX,DY[,DEG]` or `teleport:ID:…`: robot ID moved at once by DX, DY metres and
///   turned by DEG degrees, SECONDS after the robots are connected;
/// - `shove:ID:…` or `shove/MS:ID:…`: the same displacement given by a hand over 50 ms (or MS,
///   20 to 100);
/// - `random`, `random:shove[/MS]`, `random:teleport`, each optionally followed by
///   `:WITHIN_SECONDS`: a kick drawn per seed (a shove unless it says teleport), at a time from
///   one second to WITHIN_SECONDS (30 unless given).
pub fn parse_kick(text: &str) -> Result<KickSpec, String> {
    let usage = || format!("{text:?}: {KICK_USAGE}");
    let t = text.trim();
    if let Some(rest) = t.strip_prefix("random") {
        if !(rest.is_empty() || rest.starts_with(':')) {
            return Err(usage());
        }
        let mut parts = rest
            .strip_prefix(':')
            .into_iter()
            .flat_map(|r| r.split(':'));
        let mut how = KickHow::Shove(DEFAULT_SHOVE);
        let mut within = std::time::Duration::from_secs_f64(RANDOM_WITHIN_S);
        let mut next = parts.next();
        if let Some(h) = next.filter(|h| h.starts_with("teleport") || h.starts_with("shove")) {
            how = parse_how(h).map_err(|e| format!("{text:?}: {e}"))?;
            next = parts.next();
        }
        if let Some(w) = next {
            within = parse_duration(w).map_err(|e| format!("{text:?}: window: {e}"))?;
            if within <= std::time::Duration::from_secs(1) {
                return Err(format!("{text:?}: the window must end after one second"));
            }
        }
        if parts.next().is_some() {
            return Err(usage());
        }
        return Ok(KickSpec::Random(RandomKick { how, within }));
    }
    let (how, given) = match t.split_once(':') {
        Some((h, rest)) if h.starts_with("teleport") || h.starts_with("shove") => {
            (parse_how(h).map_err(|e| format!("{text:?}: {e}"))?, rest)
        }
        _ => (KickHow::Teleport, t),
    };
    let mut parts = given.splitn(3, ':');
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
    Ok(KickSpec::Given(KickArg {
        robot,
        at,
        dx_m: values[0],
        dy_m: values[1],
        dtheta_rad: values[2].to_radians(),
        how,
    }))
}

/// `teleport`, `shove` or `shove/MS`.
fn parse_how(text: &str) -> Result<KickHow, String> {
    match text {
        "teleport" => Ok(KickHow::Teleport),
        "shove" => Ok(KickHow::Shove(DEFAULT_SHOVE)),
        _ => {
            let ms = text
                .strip_prefix("shove/")
                .and_then(|ms| ms.trim().parse::<u64>().ok())
                .ok_or_else(|| format!("{text:?} is not teleport, shove or shove/MS"))?;
            if !(20..=100).contains(&ms) {
                return Err(format!("a shove lasts 20 to 100 ms, not {ms}"));
            }
            Ok(KickHow::Shove(std::time::Duration::from_millis(ms)))
        }
    }
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
    #[test]
    fn a_link_profile_is_a_name_or_a_file_and_a_bad_one_is_named() {
        let b = super::parse_link_profile("bluetooth").unwrap();
        assert_eq!(b.model.loss, 0.01);
        assert_eq!(b.model.loss_burst_ms, 20.0);
        let e = super::parse_link_profile("bluetoth").unwrap_err();
        assert!(e.contains("ideal, l2cap, bluetooth, poor"), "{e}");
        let dir = std::env::temp_dir().join(format!("link-profile-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let good = dir.join("good.toml");
        std::fs::write(&good, "[link]\nprofile = \"poor\"\nloss = 0.02\n").unwrap();
        let m = super::parse_link_profile(good.to_str().unwrap())
            .unwrap()
            .model;
        assert_eq!((m.latency_ms, m.loss, m.loss_burst_ms), (40.0, 0.02, 50.0));
        let bad = dir.join("bad.toml");
        std::fs::write(&bad, "[link]\nlatency_ms = 5\nloss_burst_ms = -1\n").unwrap();
        let e = super::parse_link_profile(bad.to_str().unwrap()).unwrap_err();
        assert!(
            e.contains("bad.toml:3:") && e.contains("loss_burst_ms"),
            "{e}"
        );
        let unknown = dir.join("unknown.toml");
        std::fs::write(&unknown, "[link]\nprofile = \"wifi\"\n").unwrap();
        let e = super::parse_link_profile(unknown.to_str().unwrap()).unwrap_err();
        assert!(e.contains("unknown.toml:2:") && e.contains("wifi"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

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

    fn given(spec: &str) -> KickArg {
        match parse_kick(spec) {
            Ok(KickSpec::Given(k)) => k,
            other => panic!("{spec}: {other:?}"),
        }
    }

    #[test]
    fn kicks_parse_with_and_without_a_turn_and_bad_ones_are_named() {
        let k = given("2:5:0,0.03");
        assert_eq!(
            (k.robot, k.at, k.dx_m, k.dy_m, k.dtheta_rad, k.how),
            (
                2,
                std::time::Duration::from_secs(5),
                0.0,
                0.03,
                0.0,
                KickHow::Teleport
            )
        );
        let k = given("7:0.5:-0.01,0.02,90");
        assert!((k.dtheta_rad - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert_eq!(given("shove:1:2:0,0.01").how, KickHow::Shove(DEFAULT_SHOVE));
        assert_eq!(
            given("shove/80:1:2:0,0.01").how,
            KickHow::Shove(std::time::Duration::from_millis(80))
        );
        assert_eq!(given("teleport:1:2:0,0.01").how, KickHow::Teleport);
        for (bad, says) in [
            ("2:5", "expected [teleport"),
            ("x:5:0,0", "robot id"),
            ("2:-1:0,0", "when"),
            ("2:5:0", "expected [teleport"),
            ("2:5:0,0,1,2", "expected [teleport"),
            ("2:5:0,NaN", "not a finite number"),
            ("2:5:30,0", "at most"),
            ("shove/5:2:5:0,0", "20 to 100"),
            ("shove/x:2:5:0,0", "not teleport, shove"),
            ("randomly", "expected [teleport"),
            ("random:shove:0.5", "after one second"),
            ("random:teleport:30:4", "expected [teleport"),
        ] {
            let e = parse_kick(bad).expect_err(bad);
            assert!(e.contains(says) && e.contains(bad), "{bad}: {e}");
        }
    }

    #[test]
    fn random_kicks_are_shoves_unless_they_say_teleport() {
        let r = |s| match parse_kick(s) {
            Ok(KickSpec::Random(r)) => (r.how, r.within.as_secs_f64()),
            other => panic!("{s}: {other:?}"),
        };
        assert_eq!(
            r("random"),
            (KickHow::Shove(DEFAULT_SHOVE), RANDOM_WITHIN_S)
        );
        assert_eq!(r("random:teleport"), (KickHow::Teleport, RANDOM_WITHIN_S));
        assert_eq!(r("random:4"), (KickHow::Shove(DEFAULT_SHOVE), 4.0));
        assert_eq!(
            r("random:shove/20:12"),
            (KickHow::Shove(std::time::Duration::from_millis(20)), 12.0)
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
