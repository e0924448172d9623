//! Faults an experiment declares (a world file's `[[faults]]`, a `--fault` flag): what goes wrong
//! with which robot's link or firmware, when, and for how long. Deterministic: every draw a fault
//! makes comes from the run's seed.

use std::time::Duration;

/// The longest latency spike a fault adds, seconds.
pub const MAX_LATENCY_S: f64 = 2.0;

/// What goes wrong.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FaultKind {
    /// The link is cut: nothing gets through either way, and what was in flight is lost.
    Cut,
    /// Each packet, either way, is lost with this probability (1: a loss burst).
    Loss(f64),
    /// Every packet, either way, arrives this many seconds later than the link would deliver it
    /// (order kept): a latency spike.
    Latency(f64),
    /// Each packet, either way, has one byte replaced by another with this probability.
    Corrupt(f64),
    /// Each packet, either way, arrives twice with this probability.
    Duplicate(f64),
    /// Each packet, either way, is overtaken by the one sent after it with this probability.
    Reorder(f64),
    /// The robot's firmware restarts: what it held in RAM (its queued moves, settings not saved)
    /// is lost, and it greets the host again.
    Reboot,
}

impl FaultKind {
    /// Every kind's name, as the flag and the world file write it.
    pub const NAMES: [&'static str; 7] = [
        "cut",
        "loss",
        "latency",
        "corrupt",
        "duplicate",
        "reorder",
        "reboot",
    ];

    /// The kind's name.
    pub fn name(&self) -> &'static str {
        match self {
            FaultKind::Cut => "cut",
            FaultKind::Loss(_) => "loss",
            FaultKind::Latency(_) => "latency",
            FaultKind::Corrupt(_) => "corrupt",
            FaultKind::Duplicate(_) => "duplicate",
            FaultKind::Reorder(_) => "reorder",
            FaultKind::Reboot => "reboot",
        }
    }

    /// The kind named `name` with its amount (a share of packets, or the latency's seconds;
    /// `None` takes the kind's default: every packet, or one second), checked.
    pub fn new(name: &str, amount: Option<f64>) -> Result<FaultKind, String> {
        let share = |a: Option<f64>| -> Result<f64, String> {
            let a = a.unwrap_or(1.0);
            if a.is_finite() && a > 0.0 && a <= 1.0 {
                Ok(a)
            } else {
                Err(format!(
                    "a {name} fault's amount is the share of packets it hits, more than 0 and at \
                     most 1, not {a}"
                ))
            }
        };
        Ok(match name {
            "cut" | "reboot" if amount.is_some() => {
                return Err(format!("a {name} fault takes no amount"));
            }
            "cut" => FaultKind::Cut,
            "reboot" => FaultKind::Reboot,
            "loss" => FaultKind::Loss(share(amount)?),
            "corrupt" => FaultKind::Corrupt(share(amount)?),
            "duplicate" => FaultKind::Duplicate(share(amount)?),
            "reorder" => FaultKind::Reorder(share(amount)?),
            "latency" => {
                let s = amount.unwrap_or(1.0);
                if !(s.is_finite() && s > 0.0 && s <= MAX_LATENCY_S) {
                    return Err(format!(
                        "a latency fault adds more than 0 and at most {MAX_LATENCY_S} s, not {s}"
                    ));
                }
                FaultKind::Latency(s)
            }
            _ => {
                return Err(format!(
                    "unknown fault {name:?}: expected one of {}",
                    Self::NAMES.join(", ")
                ))
            }
        })
    }

    /// Whether the fault lasts a while (everything but a reboot, which happens at an instant).
    pub fn lasts(&self) -> bool {
        !matches!(self, FaultKind::Reboot)
    }
}

/// One declared fault.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaultSpec {
    /// What goes wrong.
    pub kind: FaultKind,
    /// The robot's id.
    pub robot: u16,
    /// When it begins, after the robots are connected.
    pub at: Duration,
    /// How long it lasts (zero for a reboot).
    pub lasting: Duration,
}

impl FaultSpec {
    /// The fault in one line: `loss (share 0.5) of robot 2's link at 5.00 s for 2.00 s`.
    pub fn describe(&self) -> String {
        let what = match self.kind {
            FaultKind::Cut => "link cut".to_string(),
            FaultKind::Loss(s) => format!("loss of {:.0} % of packets", s * 100.0),
            FaultKind::Latency(s) => format!("latency spike of {:.0} ms", s * 1e3),
            FaultKind::Corrupt(s) => format!("corruption of {:.0} % of packets", s * 100.0),
            FaultKind::Duplicate(s) => format!("duplication of {:.0} % of packets", s * 100.0),
            FaultKind::Reorder(s) => format!("reordering of {:.0} % of packets", s * 100.0),
            FaultKind::Reboot => {
                return format!(
                    "reboot of robot {} at {:.2} s",
                    self.robot,
                    self.at.as_secs_f64()
                )
            }
        };
        format!(
            "{what} on robot {}'s link at {:.2} s for {:.2} s",
            self.robot,
            self.at.as_secs_f64(),
            self.lasting.as_secs_f64()
        )
    }
}

/// A fault drawn per seed: one robot and a time from one second to `within`, the kind and how
/// long it lasts given.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RandomFault {
    /// What goes wrong.
    pub kind: FaultKind,
    /// How long it lasts.
    pub lasting: Duration,
    /// The time is drawn from one second to this.
    pub within: Duration,
}

/// A `--fault` flag: a given fault or one drawn per seed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FaultArg {
    /// This fault.
    Given(FaultSpec),
    /// One drawn per seed.
    Random(RandomFault),
}

const FAULT_USAGE: &str = "expected KIND:ID:SECONDS[:FOR_SECONDS[:AMOUNT]] or \
                           random:KIND[:FOR_SECONDS[:AMOUNT]], KIND one of cut, loss, latency, \
                           corrupt, duplicate, reorder, reboot; e.g. loss:2:5:3:0.5, \
                           latency:1:4:5:1.5, reboot:2:8 or random:cut:3";

/// How long a fault drawn at random lasts unless the flag says otherwise, seconds.
pub const RANDOM_LASTING_S: f64 = 3.0;
/// The window a random fault's time is drawn from, seconds.
pub const RANDOM_WITHIN_S: f64 = 30.0;

/// Parses a `--fault` flag; for clap's `value_parser`:
/// - `KIND:ID:SECONDS[:FOR_SECONDS[:AMOUNT]]`: robot ID's link (or firmware, for `reboot`)
///   fails SECONDS after the robots are connected, for FOR_SECONDS (a reboot takes none);
///   AMOUNT is the share of packets hit (default 1) or a latency spike's seconds (default 1,
///   at most 2);
/// - `random:KIND[:FOR_SECONDS[:AMOUNT]]`: the robot and a time from 1 to 30 s drawn per seed,
///   lasting 3 s unless FOR_SECONDS says otherwise.
pub fn parse_fault(text: &str) -> Result<FaultArg, String> {
    let usage = || format!("{text:?}: {FAULT_USAGE}");
    let parts: Vec<&str> = text.trim().split(':').map(str::trim).collect();
    let number = |s: &str, what: &str| -> Result<f64, String> {
        s.parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| format!("{text:?}: {what} {s:?} is not a finite number"))
    };
    let lasting = |s: &str| -> Result<Duration, String> {
        crate::cli::parse_duration(s).map_err(|e| format!("{text:?}: how long: {e}"))
    };
    if parts.first() == Some(&"random") {
        let (Some(kind), rest) = (parts.get(1), parts.get(2..).unwrap_or(&[])) else {
            return Err(usage());
        };
        if rest.len() > 2 || (*kind == "reboot" && !rest.is_empty()) {
            return Err(usage());
        }
        let amount = rest.get(1).map(|a| number(a, "amount")).transpose()?;
        let kind = FaultKind::new(kind, amount).map_err(|e| format!("{text:?}: {e}"))?;
        let lasting = match (kind.lasts(), rest.first()) {
            (false, _) => Duration::ZERO,
            (true, Some(s)) => lasting(s)?,
            (true, None) => Duration::from_secs_f64(RANDOM_LASTING_S),
        };
        return Ok(FaultArg::Random(RandomFault {
            kind,
            lasting,
            within: Duration::from_secs_f64(RANDOM_WITHIN_S),
        }));
    }
    let (Some(kind), Some(id), Some(at)) = (parts.first(), parts.get(1), parts.get(2)) else {
        return Err(usage());
    };
    let rest = parts.get(3..).unwrap_or(&[]);
    if rest.len() > 2 {
        return Err(usage());
    }
    let robot = id
        .parse()
        .map_err(|_| format!("{text:?}: robot id {id:?} is not a number from 0 to 65535"))?;
    let at = crate::cli::parse_duration(at).map_err(|e| format!("{text:?}: when: {e}"))?;
    let amount = rest.get(1).map(|a| number(a, "amount")).transpose()?;
    let kind = FaultKind::new(kind, amount).map_err(|e| format!("{text:?}: {e}"))?;
    let lasting = match (kind.lasts(), rest.first()) {
        (false, None) => Duration::ZERO,
        (false, Some(_)) => return Err(format!("{text:?}: a reboot happens at an instant")),
        (true, Some(s)) => lasting(s)?,
        (true, None) => {
            return Err(format!(
                "{text:?}: a {} fault needs how long it lasts (KIND:ID:SECONDS:FOR_SECONDS)",
                kind.name()
            ))
        }
    };
    Ok(FaultArg::Given(FaultSpec {
        kind,
        robot,
        at,
        lasting,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_fault_kind_parses_with_its_amount_and_bad_ones_say_why() {
        let given = |t: &str| match parse_fault(t) {
            Ok(FaultArg::Given(f)) => f,
            other => panic!("{t}: {other:?}"),
        };
        let f = given("loss:2:5:3:0.5");
        assert_eq!(f.kind, FaultKind::Loss(0.5));
        assert_eq!(
            (f.robot, f.at, f.lasting),
            (2, Duration::from_secs(5), Duration::from_secs(3))
        );
        assert_eq!(given("cut:1:2:4").kind, FaultKind::Cut);
        assert_eq!(given("latency:1:2:4").kind, FaultKind::Latency(1.0));
        assert_eq!(given("reboot:3:7").lasting, Duration::ZERO);
        assert!(matches!(
            parse_fault("random:corrupt:2:0.1"),
            Ok(FaultArg::Random(RandomFault { kind: FaultKind::Corrupt(s), .. })) if s == 0.1
        ));
        for (bad, says) in [
            ("latency:1:2:4:3", "at most 2"),
            ("loss:1:2:4:1.5", "at most 1"),
            ("cut:1:2", "how long"),
            ("cut:1:2:3:0.5", "takes no amount"),
            ("reboot:1:2:3", "instant"),
            ("jam:1:2:3", "unknown fault"),
            ("loss:x:2:3", "robot id"),
            ("loss:1:2:nan", "how long"),
            ("random", "expected"),
        ] {
            let e = parse_fault(bad).unwrap_err();
            assert!(e.contains(says), "{bad}: {e}");
        }
    }
}
