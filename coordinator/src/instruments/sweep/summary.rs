//! A sweep's summary: per combination of coordinates (all but the seed) the runs, the success rate
//! with its Wilson 95 % interval, what the ground truth saw (contacts, runs it failed against the
//! behaviour's word, the world model's worst error, lost episodes) and, for each verdict metric,
//! mean, median and 95th percentile; failure reasons grouped by message with numbers masked. Deterministic: rows in run order, fixed
//! float formatting.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use super::store::{Outcome, RunResult};
use super::Definition;

/// The normal quantile for a two-sided 95 % interval.
const Z95: f64 = 1.959_963_984_540_054;

/// Wilson score interval at 95 % for `successes` out of `n`; (0, 1) when there are no runs.
pub fn wilson(successes: usize, n: usize) -> (f64, f64) {
    if n == 0 {
        return (0.0, 1.0);
    }
    let n = n as f64;
    let p = successes as f64 / n;
    let z2 = Z95 * Z95;
    let denom = 1.0 + z2 / n;
    let centre = (p + z2 / (2.0 * n)) / denom;
    let half = Z95 / denom * (p * (1.0 - p) / n + z2 / (4.0 * n * n)).sqrt();
    (
        (centre - half).clamp(0.0, 1.0),
        (centre + half).clamp(0.0, 1.0),
    )
}

/// The `q` quantile (0 < q ≤ 1) of sorted values by the nearest-rank method: the smallest value
/// with at least a fraction `q` of the values at or below it. `None` when empty.
pub fn percentile(sorted: &[f64], q: f64) -> Option<f64> {
    if sorted.is_empty() {
        return None;
    }
    let rank = (q * sorted.len() as f64).ceil() as usize;
    Some(sorted[rank.clamp(1, sorted.len()) - 1])
}

/// The median of sorted values (the mean of the middle two for an even count).
pub fn median(sorted: &[f64]) -> Option<f64> {
    let n = sorted.len();
    match n {
        0 => None,
        _ if n % 2 == 1 => Some(sorted[n / 2]),
        _ => Some((sorted[n / 2 - 1] + sorted[n / 2]) / 2.0),
    }
}

/// A failure message with every number masked as `#`, so "deadlock after 77 tasks" and
/// "deadlock after 110 tasks" group together.
pub fn normalise(message: &str) -> String {
    let mut out = String::with_capacity(message.len());
    let mut chars = message.chars().peekable();
    while let Some(c) = chars.next() {
        if c.is_ascii_digit() {
            while let Some(&d) = chars.peek() {
                let decimal = d == '.' && {
                    let mut ahead = chars.clone();
                    ahead.next();
                    ahead.peek().is_some_and(char::is_ascii_digit)
                };
                if d.is_ascii_digit() || decimal {
                    chars.next();
                } else {
                    break;
                }
            }
            out.push('#');
        } else {
            out.push(c);
        }
    }
    out
}

/// Statistics of one metric over a combination's runs that report it.
#[derive(Clone, Debug, PartialEq)]
pub struct MetricStats {
    /// Runs reporting it.
    pub n: usize,
    /// Mean.
    pub mean: f64,
    /// Median.
    pub median: f64,
    /// 95th percentile (nearest rank).
    pub p95: f64,
}

impl MetricStats {
    /// The statistics of some values; `None` when there are none.
    pub fn of(values: &[f64]) -> Option<Self> {
        let mut sorted: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
        sorted.sort_by(f64::total_cmp);
        Some(Self {
            n: sorted.len(),
            mean: sorted.iter().sum::<f64>() / sorted.len() as f64,
            median: median(&sorted)?,
            p95: percentile(&sorted, 0.95)?,
        })
    }
}

/// What the ground truth saw over one combination's runs.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TruthStats {
    /// Runs with any robot–robot or wall contact.
    pub runs_with_contacts: usize,
    /// Robot–robot contacts over all runs.
    pub robot_contacts: u64,
    /// Wall contacts over all runs.
    pub wall_contacts: u64,
    /// Runs the behaviour called a success and the ground truth failed.
    pub overruled: usize,
    /// The world model's worst position error over every run, mm (runs that measured it).
    pub worst_model_error_mm: Option<f64>,
    /// The median over runs of each run's worst model error, mm.
    pub median_model_error_mm: Option<f64>,
    /// Lost episodes over all runs.
    pub lost_episodes: u64,
    /// Time lost over all runs, seconds.
    pub lost_s: f64,
    /// Runs in which a kick landed.
    pub kicked: usize,
    /// Kicked runs with a contact that began while the kick landed.
    pub runs_with_contacts_at_kick: usize,
    /// Kicked runs with a contact at any other time: contacts the supervision let happen.
    pub runs_with_contacts_other: usize,
    /// Runs that ended with a robot lost and not found.
    pub lost_not_found: usize,
    /// Over runs, the median and the worst of each run's slowest link latency p99, ms.
    pub latency_p99_ms: Option<(f64, f64)>,
    /// Over runs, the median and the worst of each run's latest event lateness p99, ms.
    pub event_late_p99_ms: Option<(f64, f64)>,
}

impl TruthStats {
    /// The figures of some runs.
    pub fn of(runs: &[&RunResult]) -> Self {
        let mut errors: Vec<f64> = runs
            .iter()
            .filter_map(|r| r.worst_model_error_mm)
            .filter(|e| e.is_finite())
            .collect();
        errors.sort_by(f64::total_cmp);
        Self {
            runs_with_contacts: runs.iter().filter(|r| r.contacts() > 0).count(),
            robot_contacts: runs.iter().filter_map(|r| r.robot_collisions).sum(),
            wall_contacts: runs.iter().filter_map(|r| r.wall_contacts).sum(),
            overruled: runs.iter().filter(|r| r.overruled()).count(),
            worst_model_error_mm: errors.last().copied(),
            median_model_error_mm: median(&errors),
            lost_episodes: runs.iter().filter_map(|r| r.lost_episodes).sum(),
            lost_s: runs.iter().filter_map(|r| r.lost_s).sum(),
            kicked: runs.iter().filter(|r| !r.kicks_landed.is_empty()).count(),
            runs_with_contacts_at_kick: runs
                .iter()
                .filter(|r| r.contacts_at_kick.unwrap_or(0) > 0)
                .count(),
            runs_with_contacts_other: runs
                .iter()
                .filter(|r| r.contacts_other.unwrap_or(0) > 0)
                .count(),
            lost_not_found: runs.iter().filter(|r| r.lost_not_found()).count(),
            latency_p99_ms: median_and_worst(runs.iter().filter_map(|r| r.latency_p99_ms)),
            event_late_p99_ms: median_and_worst(runs.iter().filter_map(|r| r.event_late_p99_ms)),
        }
    }
}

/// The median and the largest of some figures, `None` without any.
fn median_and_worst(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let mut v: Vec<f64> = values.filter(|x| x.is_finite()).collect();
    v.sort_by(f64::total_cmp);
    Some((median(&v)?, *v.last()?))
}

/// One combination's row.
#[derive(Clone, Debug, PartialEq)]
pub struct Combination {
    /// Its key (`all` when nothing but the seed varies).
    pub key: String,
    /// Its coordinate values, one per swept coordinate.
    pub values: Vec<String>,
    /// Runs with a result.
    pub runs: usize,
    /// Successes.
    pub successes: usize,
    /// Runs that came to no verdict.
    pub errors: usize,
    /// Wilson 95 % interval of the success rate.
    pub interval: (f64, f64),
    /// Statistics of each verdict metric.
    pub metrics: BTreeMap<String, MetricStats>,
    /// What the ground truth saw.
    pub truth: TruthStats,
}

impl Combination {
    /// Success rate (0 with no runs).
    pub fn rate(&self) -> f64 {
        if self.runs == 0 {
            0.0
        } else {
            self.successes as f64 / self.runs as f64
        }
    }
}

/// Failures (and errors) sharing a message once numbers are masked.
#[derive(Clone, Debug, PartialEq)]
pub struct FailureGroup {
    /// `failure` or `error`.
    pub outcome: Outcome,
    /// The masked message.
    pub message: String,
    /// How many runs.
    pub count: usize,
    /// Ids of the first few, in run order.
    pub examples: Vec<String>,
}

/// A sweep's summary.
#[derive(Clone, Debug, PartialEq)]
pub struct Summary {
    /// The behaviour.
    pub behaviour: String,
    /// The coordinate names of `Combination::values`.
    pub keys: Vec<String>,
    /// Every metric any run reported, sorted.
    pub metrics: Vec<String>,
    /// Combinations in run order.
    pub combinations: Vec<Combination>,
    /// Failure groups, most frequent first.
    pub failures: Vec<FailureGroup>,
    /// Each kicked run that failed, in run order: its id, its kicks as they landed, and why.
    pub kicked_failures: Vec<(String, Vec<String>, String)>,
    /// Runs in the sweep definition.
    pub planned: usize,
    /// How every run was paced and loaded ([`Definition::conditions`]).
    pub conditions: String,
}

/// Summarises results (in any order, one per run id).
pub fn summarise(definition: &Definition, results: &[RunResult]) -> Summary {
    let mut results: Vec<&RunResult> = results.iter().collect();
    results.sort_by_key(|r| r.index);
    let keys = coordinate_keys(definition);
    let mut order: Vec<String> = Vec::new();
    let mut groups: BTreeMap<String, Vec<&RunResult>> = BTreeMap::new();
    for r in &results {
        if !groups.contains_key(&r.combination) {
            order.push(r.combination.clone());
        }
        groups.entry(r.combination.clone()).or_default().push(r);
    }
    let mut metrics: Vec<String> = results
        .iter()
        .flat_map(|r| r.metrics.keys().cloned())
        .collect();
    metrics.sort();
    metrics.dedup();
    let combinations = order
        .iter()
        .map(|key| {
            let rs = &groups[key];
            let successes = rs.iter().filter(|r| r.success()).count();
            let errors = rs.iter().filter(|r| r.outcome == Outcome::Error).count();
            let stats = metrics
                .iter()
                .filter_map(|m| {
                    let vs: Vec<f64> = rs
                        .iter()
                        .filter_map(|r| r.metrics.get(m).copied())
                        .collect();
                    MetricStats::of(&vs).map(|s| (m.clone(), s))
                })
                .collect();
            Combination {
                key: key.clone(),
                values: keys.iter().map(|k| coordinate(rs[0], k)).collect(),
                runs: rs.len(),
                successes,
                errors,
                interval: wilson(successes, rs.len()),
                metrics: stats,
                truth: TruthStats::of(rs),
            }
        })
        .collect();
    let mut failures: Vec<FailureGroup> = Vec::new();
    for r in results.iter().filter(|r| !r.success()) {
        let message = normalise(&r.summary);
        match failures
            .iter_mut()
            .find(|g| g.outcome == r.outcome && g.message == message)
        {
            Some(g) => {
                g.count += 1;
                if g.examples.len() < 3 {
                    g.examples.push(r.id.clone());
                }
            }
            None => failures.push(FailureGroup {
                outcome: r.outcome,
                message,
                count: 1,
                examples: vec![r.id.clone()],
            }),
        }
    }
    // Stable: ties keep the order of their first run.
    failures.sort_by_key(|g| std::cmp::Reverse(g.count));
    let kicked_failures = results
        .iter()
        .filter(|r| !r.success() && !r.kicks_landed.is_empty())
        .map(|r| (r.id.clone(), r.kicks_landed.clone(), r.summary.clone()))
        .collect();
    Summary {
        kicked_failures,
        behaviour: definition.behaviour.clone(),
        keys,
        metrics,
        combinations,
        failures,
        planned: definition.runs().len(),
        conditions: definition.conditions(),
    }
}

/// The coordinates a sweep's combinations are named by: those it lists (even with one value).
pub fn coordinate_keys(definition: &Definition) -> Vec<String> {
    let mut keys = Vec::new();
    if !definition.worlds.is_empty() {
        keys.push("world".to_string());
    }
    if !definition.robots.is_empty() {
        keys.push("robots".to_string());
    }
    if !definition.physics_hz.is_empty() {
        keys.push("physics_hz".to_string());
    }
    if !definition.kicks.is_empty() {
        keys.push("kick".to_string());
    }
    keys.extend(definition.params.iter().map(|(k, _)| k.clone()));
    keys
}

/// A run's value of a coordinate.
pub fn coordinate(r: &RunResult, key: &str) -> String {
    match key {
        "world" => r.world.clone().unwrap_or_default(),
        "robots" => r.robots.map(|n| n.to_string()).unwrap_or_default(),
        "physics_hz" => r.physics_hz.map(|n| n.to_string()).unwrap_or_default(),
        "kick" => r.kick.clone().unwrap_or_default(),
        k => r.params.get(k).cloned().unwrap_or_default(),
    }
}

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

fn f6(v: f64) -> String {
    format!("{v:.6}")
}

impl Summary {
    /// The summary as CSV: one row per combination.
    pub fn to_csv(&self) -> String {
        let mut header: Vec<String> = self.keys.clone();
        header.extend(
            [
                "runs",
                "successes",
                "errors",
                "success_rate",
                "wilson_low",
                "wilson_high",
                "runs_with_contacts",
                "robot_contacts",
                "wall_contacts",
                "overruled",
                "worst_model_error_mm",
                "median_model_error_mm",
                "lost_episodes",
                "lost_s",
                "kicked",
                "runs_with_contacts_at_kick",
                "runs_with_contacts_other",
                "lost_not_found",
            ]
            .map(String::from),
        );
        for m in &self.metrics {
            for s in ["n", "mean", "median", "p95"] {
                header.push(format!("{m}_{s}"));
            }
        }
        let mut out = header
            .iter()
            .map(|h| csv_field(h))
            .collect::<Vec<_>>()
            .join(",");
        out.push('\n');
        for c in &self.combinations {
            let mut row: Vec<String> = c.values.iter().map(|v| csv_field(v)).collect();
            row.push(c.runs.to_string());
            row.push(c.successes.to_string());
            row.push(c.errors.to_string());
            row.push(f6(c.rate()));
            row.push(f6(c.interval.0));
            row.push(f6(c.interval.1));
            let t = &c.truth;
            row.push(t.runs_with_contacts.to_string());
            row.push(t.robot_contacts.to_string());
            row.push(t.wall_contacts.to_string());
            row.push(t.overruled.to_string());
            row.push(t.worst_model_error_mm.map(f6).unwrap_or_default());
            row.push(t.median_model_error_mm.map(f6).unwrap_or_default());
            row.push(t.lost_episodes.to_string());
            row.push(f6(t.lost_s));
            row.push(t.kicked.to_string());
            row.push(t.runs_with_contacts_at_kick.to_string());
            row.push(t.runs_with_contacts_other.to_string());
            row.push(t.lost_not_found.to_string());
            for m in &self.metrics {
                match c.metrics.get(m) {
                    Some(s) => {
                        row.extend([s.n.to_string(), f6(s.mean), f6(s.median), f6(s.p95)]);
                    }
                    None => row.extend(["0", "", "", ""].map(String::from)),
                }
            }
            out.push_str(&row.join(","));
            out.push('\n');
        }
        out
    }

    /// The summary as Markdown (also what the sweep prints).
    pub fn to_markdown(&self) -> String {
        let mut s = String::new();
        let runs: usize = self.combinations.iter().map(|c| c.runs).sum();
        let successes: usize = self.combinations.iter().map(|c| c.successes).sum();
        let errors: usize = self.combinations.iter().map(|c| c.errors).sum();
        let _ = writeln!(s, "# Sweep of {}\n", self.behaviour);
        let _ = writeln!(s, "Every run: {}.\n", self.conditions);
        let _ = writeln!(
            s,
            "{runs} of {} runs have results: {successes} succeeded, {} failed, {errors} came to no verdict.\n",
            self.planned,
            runs - successes - errors
        );
        let _ = writeln!(s, "| combination | runs | success | 95 % interval |");
        let _ = writeln!(s, "|---|---:|---:|---|");
        for c in &self.combinations {
            let _ = writeln!(
                s,
                "| {} | {} | {}/{} = {:.1} % | {:.1}–{:.1} % |",
                c.key,
                c.runs,
                c.successes,
                c.runs,
                100.0 * c.rate(),
                100.0 * c.interval.0,
                100.0 * c.interval.1
            );
        }
        let _ = writeln!(s, "\n## Ground truth\n");
        let _ = writeln!(
            s,
            "| combination | runs with contacts | robot contacts | wall contacts | overruled | worst model error [mm] | median [mm] | lost episodes | lost [s] |"
        );
        let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|---:|---:|---:|");
        for c in &self.combinations {
            let t = &c.truth;
            let mm = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.1}"));
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {} | {} | {} | {:.2} |",
                c.key,
                t.runs_with_contacts,
                t.robot_contacts,
                t.wall_contacts,
                t.overruled,
                mm(t.worst_model_error_mm),
                mm(t.median_model_error_mm),
                t.lost_episodes,
                t.lost_s
            );
        }
        if self.combinations.iter().any(|c| c.truth.kicked > 0) {
            self.disturbances_markdown(&mut s);
        }
        if self
            .combinations
            .iter()
            .any(|c| c.truth.latency_p99_ms.is_some())
        {
            let _ = writeln!(s, "\n## Links\n");
            let _ = writeln!(
                s,
                "Per run, the slowest link's one-way latency p99 and the latest link's event lateness p99: their median over runs and the worst run.\n"
            );
            let _ = writeln!(
                s,
                "| combination | latency p99, median [ms] | worst [ms] | events late p99, median [ms] | worst [ms] |"
            );
            let _ = writeln!(s, "|---|---:|---:|---:|---:|");
            for c in &self.combinations {
                let pair = |v: Option<(f64, f64)>| {
                    v.map_or("- | -".to_string(), |(m, w)| format!("{m:.1} | {w:.1}"))
                };
                let _ = writeln!(
                    s,
                    "| {} | {} | {} |",
                    c.key,
                    pair(c.truth.latency_p99_ms),
                    pair(c.truth.event_late_p99_ms)
                );
            }
        }
        for m in &self.metrics {
            let _ = writeln!(s, "\n## {m}\n");
            let _ = writeln!(s, "| combination | n | mean | median | p95 |");
            let _ = writeln!(s, "|---|---:|---:|---:|---:|");
            for c in &self.combinations {
                if let Some(st) = c.metrics.get(m) {
                    let _ = writeln!(
                        s,
                        "| {} | {} | {:.4} | {:.4} | {:.4} |",
                        c.key, st.n, st.mean, st.median, st.p95
                    );
                }
            }
        }
        let _ = writeln!(s, "\n## Failure reasons\n");
        if self.failures.is_empty() {
            let _ = writeln!(s, "None.");
        } else {
            let _ = writeln!(s, "| runs | kind | message | e.g. |");
            let _ = writeln!(s, "|---:|---|---|---|");
            for g in &self.failures {
                let kind = match g.outcome {
                    Outcome::Error => "error",
                    _ => "failure",
                };
                let _ = writeln!(
                    s,
                    "| {} | {kind} | {} | {} |",
                    g.count,
                    g.message.replace('|', "\\|"),
                    g.examples.join("; ")
                );
            }
        }
        s
    }
}

impl Summary {
    /// The kicked runs' table, and each failed kicked run with the kick it got.
    fn disturbances_markdown(&self, s: &mut String) {
        let _ = writeln!(s, "\n## Disturbances\n");
        let _ = writeln!(
            s,
            "| combination | kicked runs | runs with a contact at the kick | runs with a contact after it | lost and not found | lost [s] |"
        );
        let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|");
        for c in &self.combinations {
            let t = &c.truth;
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {:.2} |",
                c.key,
                t.kicked,
                t.runs_with_contacts_at_kick,
                t.runs_with_contacts_other,
                t.lost_not_found,
                t.lost_s
            );
        }
        if !self.kicked_failures.is_empty() {
            let _ = writeln!(s, "\nKicked runs that failed:\n");
            for (id, kicks, why) in &self.kicked_failures {
                let _ = writeln!(
                    s,
                    "- {id}: {}: {}",
                    kicks.join("; "),
                    why.replace('|', "\\|")
                );
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wilson_matches_known_intervals() {
        let close =
            |a: (f64, f64), b: (f64, f64)| (a.0 - b.0).abs() < 5e-5 && (a.1 - b.1).abs() < 5e-5;
        // Reference values from the closed form as tabulated by Newcombe (1998).
        assert!(
            close(wilson(5, 10), (0.2366, 0.7634)),
            "{:?}",
            wilson(5, 10)
        );
        assert!(close(wilson(0, 10), (0.0, 0.2775)), "{:?}", wilson(0, 10));
        assert!(close(wilson(10, 10), (0.7225, 1.0)), "{:?}", wilson(10, 10));
        assert!(
            close(wilson(81, 263), (0.2553, 0.3662)),
            "{:?}",
            wilson(81, 263)
        );
        assert_eq!(wilson(0, 0), (0.0, 1.0));
    }

    #[test]
    fn percentile_and_median_by_nearest_rank() {
        let v: Vec<f64> = (1..=20).map(f64::from).collect();
        assert_eq!(percentile(&v, 0.95), Some(19.0));
        assert_eq!(percentile(&v[..10], 0.95), Some(10.0));
        assert_eq!(percentile(&[4.0], 0.95), Some(4.0));
        assert_eq!(percentile(&[], 0.95), None);
        assert_eq!(median(&[1.0, 2.0, 3.0, 4.0]), Some(2.5));
        assert_eq!(median(&[1.0, 2.0, 7.0]), Some(2.0));
        let s = MetricStats::of(&[3.0, 1.0, 2.0]).unwrap();
        assert_eq!((s.n, s.mean, s.median, s.p95), (3, 2.0, 2.0, 3.0));
        assert_eq!(MetricStats::of(&[]), None);
    }

    #[test]
    fn ground_truth_figures_add_up_and_old_results_count_as_unmeasured() {
        // A line written before the ground-truth fields existed.
        let old: RunResult = serde_json::from_str(
            r#"{"id":"seed=1","index":0,"combination":"all","world":null,"robots":null,
            "params":{},"seed":1,"outcome":"success","exit_code":0,"summary":"ok","metrics":{},
            "robot_collisions":0,"wall_contacts":0,"experiment_time_s":5.0,
            "worst_estimate_error_mm":2.5}"#,
        )
        .unwrap();
        assert_eq!(old.behaviour_success, None);
        assert_eq!(old.worst_model_error_mm, None);
        let run = |seed: u64, outcome, behaviour, contacts: (u64, u64), error, lost| RunResult {
            id: format!("seed={seed}"),
            index: seed as usize - 1,
            seed,
            outcome,
            behaviour_success: Some(behaviour),
            robot_collisions: Some(contacts.0),
            wall_contacts: Some(contacts.1),
            worst_model_error_mm: Some(error),
            lost_episodes: Some(lost),
            lost_s: Some(lost as f64 * 1.5),
            latency_p99_ms: Some(20.0 + 10.0 * lost as f64),
            event_late_p99_ms: Some(error),
            ..old.clone()
        };
        let runs = [
            old.clone(),
            run(2, Outcome::Failure, true, (3, 0), 12.0, 1),
            run(3, Outcome::Failure, false, (0, 2), 40.0, 0),
            run(4, Outcome::Success, true, (0, 0), 8.0, 2),
        ];
        assert!(!runs[0].overruled() && runs[1].overruled() && !runs[2].overruled());
        let t = TruthStats::of(&runs.iter().collect::<Vec<_>>());
        assert_eq!(
            t,
            TruthStats {
                runs_with_contacts: 2,
                robot_contacts: 3,
                wall_contacts: 2,
                overruled: 1,
                worst_model_error_mm: Some(40.0),
                median_model_error_mm: Some(12.0),
                lost_episodes: 3,
                lost_s: 4.5,
                latency_p99_ms: Some((30.0, 40.0)),
                event_late_p99_ms: Some((12.0, 40.0)),
                ..TruthStats::default()
            }
        );
    }

    #[test]
    fn numbers_are_masked_in_failure_messages() {
        assert_eq!(
            normalise("deadlock after 77 tasks"),
            "deadlock after # tasks"
        );
        assert_eq!(
            normalise("deadlock after 110 tasks"),
            "deadlock after # tasks"
        );
        assert_eq!(
            normalise("did not finish within 8s; closure 3.25 mm."),
            "did not finish within #s; closure # mm."
        );
        assert_eq!(normalise("robots 1 and 2"), "robots # and #");
        assert_eq!(normalise("no numbers"), "no numbers");
    }
}
