//! `coordinator sweep`: a small sweep (a parameter's two values × 5 seeds of `square_walk`) runs,
//! summarises what its per-run reports say, resumes after a kill without repeating finished runs,
//! merges shards into the unsharded summary, and gives the same results every time.

use std::collections::{BTreeMap, BTreeSet};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

/// Two robots walking 0.1 m squares finish in about 5 s; 0.3 m squares bring them into each
/// other's way and they do not finish within the 8 s limit, so the sweep has both outcomes.
const SWEEP: &[&str] = &[
    "sweep",
    "--behaviour",
    "square_walk",
    "--robots",
    "2",
    "--param",
    "side=0.1,0.3",
    "--duration",
    "8",
    "--seeds",
    "1..5",
];

fn dir(name: &str) -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("sweep-{name}"));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn coordinator(args: &[&str], out: &Path, extra: &[&str]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_coordinator"));
    c.args(args).args(extra).arg("--out").arg(out);
    c
}

fn run_ok(args: &[&str], out: &Path, extra: &[&str]) -> Output {
    let o = coordinator(args, out, extra)
        .output()
        .expect("coordinator runs");
    assert!(
        o.status.success(),
        "sweep failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    o
}

fn lines(path: &Path) -> Vec<String> {
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .lines()
        .map(String::from)
        .collect()
}

fn json_lines(path: &Path) -> Vec<serde_json::Value> {
    lines(path)
        .iter()
        .map(|l| serde_json::from_str(l).expect("a JSON line"))
        .collect()
}

fn sorted(mut v: Vec<String>) -> Vec<String> {
    v.sort();
    v
}

/// summary.csv as rows of column → value, keyed by the `side` column.
fn csv(path: &Path) -> BTreeMap<String, BTreeMap<String, String>> {
    let text = std::fs::read_to_string(path).expect("summary.csv");
    let mut rows = text.lines();
    let header: Vec<&str> = rows.next().expect("a header").split(',').collect();
    rows.map(|r| {
        let row: BTreeMap<String, String> = header
            .iter()
            .zip(r.split(','))
            .map(|(h, v)| (h.to_string(), v.to_string()))
            .collect();
        (row["side"].clone(), row)
    })
    .collect()
}

#[test]
fn a_sweep_summarises_what_its_run_reports_say() {
    let out = dir("summary");
    let o = run_ok(SWEEP, &out, &["--jobs", "2"]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("# Sweep of square_walk"), "{stdout}");
    let results = json_lines(&out.join("results.jsonl"));
    assert_eq!(results.len(), 10);
    let ids: BTreeSet<&str> = results.iter().map(|r| r["id"].as_str().unwrap()).collect();
    assert!(ids.contains("robots=2,side=0.1,seed=1") && ids.contains("robots=2,side=0.3,seed=5"));

    // Recompute each combination from the per-run JSON reports alone.
    let mut reports: BTreeMap<String, Vec<serde_json::Value>> = BTreeMap::new();
    for entry in std::fs::read_dir(out.join("runs")).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_stem().unwrap().to_string_lossy().to_string();
        let side = name
            .split(',')
            .find_map(|p| p.strip_prefix("side="))
            .expect("the side in the run's name")
            .to_string();
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        reports.entry(side).or_default().push(report);
    }
    let summary = csv(&out.join("summary.csv"));
    assert_eq!(reports.len(), 2);
    let mut outcomes = BTreeSet::new();
    for (side, rs) in &reports {
        let row = &summary[side];
        let successes = rs.iter().filter(|r| r["success"] == true).count();
        outcomes.insert(successes);
        assert_eq!(row["runs"], rs.len().to_string());
        assert_eq!(row["successes"], successes.to_string());
        assert_eq!(
            row["success_rate"],
            format!("{:.6}", successes as f64 / rs.len() as f64)
        );
        let mut values: Vec<f64> = rs
            .iter()
            .filter_map(|r| r["metrics"]["worst_closure_mm"].as_f64())
            .collect();
        values.sort_by(f64::total_cmp);
        assert_eq!(row["worst_closure_mm_n"], values.len().to_string());
        if !values.is_empty() {
            let mean = values.iter().sum::<f64>() / values.len() as f64;
            let n = values.len();
            let median = if n % 2 == 1 {
                values[n / 2]
            } else {
                (values[n / 2 - 1] + values[n / 2]) / 2.0
            };
            let p95 = values[(0.95 * n as f64).ceil() as usize - 1];
            assert_eq!(row["worst_closure_mm_mean"], format!("{mean:.6}"));
            assert_eq!(row["worst_closure_mm_median"], format!("{median:.6}"));
            assert_eq!(row["worst_closure_mm_p95"], format!("{p95:.6}"));
        }
    }
    assert!(outcomes.len() > 1, "both outcomes occur: {outcomes:?}");
    // What the ground truth saw, per combination, from the same reports.
    for (side, rs) in &reports {
        let row = &summary[side];
        let count = |key: &str| rs.iter().filter_map(|r| r[key].as_u64()).sum::<u64>();
        assert_eq!(row["robot_contacts"], count("robot_collisions").to_string());
        assert_eq!(row["wall_contacts"], count("wall_contacts").to_string());
        assert_eq!(row["lost_episodes"], count("lost_episodes").to_string());
        let overruled = rs
            .iter()
            .filter(|r| r["success"] == false && r["behaviour_success"] == true)
            .count();
        assert_eq!(row["overruled"], overruled.to_string());
        let worst = rs
            .iter()
            .map(|r| {
                r["worst_model_error_mm"]
                    .as_f64()
                    .expect("sampled model error")
            })
            .reduce(f64::max)
            .unwrap();
        assert!(worst > 0.0, "{side}: the model is never exactly right");
        assert_eq!(row["worst_model_error_mm"], format!("{worst:.6}"));
    }
    for r in &results {
        assert!(r["worst_model_error_mm"].as_f64().is_some(), "{r}");
        assert!(r["behaviour_success"].as_bool().is_some(), "{r}");
        assert!(r["lost_episodes"].as_u64().is_some(), "{r}");
    }
    let md = std::fs::read_to_string(out.join("summary.md")).unwrap();
    assert!(md.contains("## Failure reasons"), "{md}");
    assert!(md.contains("## Ground truth"), "{md}");
    for svg in ["success_vs_side.svg", "metric_worst_closure_mm.svg"] {
        let text = std::fs::read_to_string(out.join(svg)).unwrap_or_default();
        assert!(text.starts_with("<svg"), "{svg} is a plot");
    }
}

#[test]
fn a_killed_sweep_resumes_without_repeating_finished_runs() {
    let out = dir("resume");
    let mut child = coordinator(SWEEP, &out, &["--jobs", "1"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("coordinator starts");
    let stderr = BufReader::new(child.stderr.take().unwrap());
    let mut finished = 0;
    for line in stderr.lines() {
        if line.unwrap().starts_with('[') {
            finished += 1;
            if finished == 3 {
                break;
            }
        }
    }
    assert_eq!(finished, 3, "the sweep reported three finished runs");
    child.kill().unwrap();
    child.wait().unwrap();
    let before = lines(&out.join("results.jsonl"));
    assert!((3..10).contains(&before.len()), "{} results", before.len());

    let o = run_ok(SWEEP, &out, &["--jobs", "2"]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        stderr.contains(&format!("{} already done, skipped", before.len())),
        "{stderr}"
    );
    assert_eq!(
        stderr.lines().filter(|l| l.starts_with('[')).count(),
        10 - before.len(),
        "{stderr}"
    );
    let after = lines(&out.join("results.jsonl"));
    assert_eq!(
        after[..before.len()],
        before[..],
        "finished runs are kept as they were"
    );
    for file in ["results.jsonl", "timing.jsonl"] {
        let ids: Vec<String> = json_lines(&out.join(file))
            .iter()
            .map(|r| r["id"].as_str().unwrap().to_string())
            .collect();
        let unique: BTreeSet<&String> = ids.iter().collect();
        assert_eq!(
            (ids.len(), unique.len()),
            (10, 10),
            "{file}: every run once"
        );
    }
}

#[test]
fn shards_merge_into_the_unsharded_summary_and_runs_repeat_exactly() {
    let whole = dir("whole");
    let again = dir("again");
    let (a, b, merged) = (dir("shard1"), dir("shard2"), dir("merged"));
    run_ok(SWEEP, &whole, &["--jobs", "2"]);
    run_ok(SWEEP, &again, &["--jobs", "2", "--record-failures"]);
    run_ok(SWEEP, &a, &["--jobs", "2", "--shard", "1/2"]);
    run_ok(SWEEP, &b, &["--jobs", "2", "--shard", "2/2"]);
    assert_eq!(lines(&a.join("results.jsonl")).len(), 5);
    assert_eq!(lines(&b.join("results.jsonl")).len(), 5);

    // The same sweep twice: the same results, line for line (wall times are kept elsewhere).
    assert_eq!(
        sorted(lines(&whole.join("results.jsonl"))),
        sorted(lines(&again.join("results.jsonl")))
    );
    // Recording changes no result, and only the failed runs keep theirs.
    let kept: BTreeSet<String> = std::fs::read_dir(again.join("failures"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .collect();
    let failed: BTreeSet<String> = json_lines(&again.join("results.jsonl"))
        .iter()
        .filter(|r| r["outcome"] != "success")
        .map(|r| format!("{}.mcap", r["id"].as_str().unwrap()))
        .collect();
    assert_eq!(kept, failed);
    assert_eq!(kept.len(), 5);
    let wall = json_lines(&whole.join("timing.jsonl"));
    assert!(wall.iter().all(|t| t["wall_s"].as_f64().unwrap() > 0.0));

    let a_dir = a.to_string_lossy().to_string();
    let b_dir = b.to_string_lossy().to_string();
    run_ok(&["sweep", "merge", &a_dir, &b_dir], &merged, &[]);
    for file in ["summary.csv", "summary.md"] {
        assert_eq!(
            std::fs::read_to_string(merged.join(file)).unwrap(),
            std::fs::read_to_string(whole.join(file)).unwrap(),
            "{file}"
        );
    }
    assert_eq!(
        sorted(lines(&merged.join("results.jsonl"))),
        sorted(lines(&whole.join("results.jsonl")))
    );

    // Results written before the ground-truth fields existed still merge, with them empty.
    let old = dir("old-shard");
    std::fs::create_dir_all(&old).unwrap();
    for entry in std::fs::read_dir(&a).unwrap() {
        let path = entry.unwrap().path();
        if path.is_file() {
            std::fs::copy(&path, old.join(path.file_name().unwrap())).unwrap();
        }
    }
    let mut old_lines = String::new();
    for mut r in json_lines(&a.join("results.jsonl")) {
        let o = r.as_object_mut().unwrap();
        for key in [
            "behaviour_success",
            "worst_model_error_mm",
            "lost_episodes",
            "lost_s",
        ] {
            assert!(o.remove(key).is_some(), "{key}");
        }
        o.insert("worst_estimate_error_mm".into(), serde_json::json!(1.5));
        old_lines.push_str(&serde_json::to_string(&r).unwrap());
        old_lines.push('\n');
    }
    std::fs::write(old.join("results.jsonl"), old_lines).unwrap();
    let remerged = dir("remerged");
    let old_dir = old.to_string_lossy().to_string();
    run_ok(&["sweep", "merge", &old_dir, &b_dir], &remerged, &[]);
    let rs = json_lines(&remerged.join("results.jsonl"));
    assert_eq!(rs.len(), 10);
    assert_eq!(
        rs.iter()
            .filter(|r| r["worst_model_error_mm"].is_null() && r["lost_episodes"].is_null())
            .count(),
        5
    );
}

#[test]
fn bad_input_is_refused_with_the_reason() {
    let out = dir("bad");
    let refused = |args: &[&str], extra: &[&str], expect: &[&str]| {
        let o = coordinator(args, &out, extra).output().unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{stderr}");
        for e in expect {
            assert!(stderr.contains(e), "{e:?} in {stderr}");
        }
    };
    let mut reversed: Vec<&str> = SWEEP.to_vec();
    *reversed.last_mut().unwrap() = "5..1";
    refused(&reversed, &[], &["5..1", "empty"]);
    refused(SWEEP, &["--shard", "3/2"], &["3/2", "between 1 and N"]);
    refused(
        SWEEP,
        &["--physics-hz", "1000,300"],
        &["--physics-hz \"300\"", "1000, 500, 250, 200"],
    );
    let mut unknown: Vec<&str> = SWEEP.to_vec();
    unknown[2] = "square_dance";
    refused(
        &unknown,
        &[],
        &["unknown behaviour \"square_dance\"", "square_walk"],
    );
    assert!(!out.exists(), "nothing is written for a refused sweep");

    let one = [
        "sweep",
        "--behaviour",
        "square_walk",
        "--robots",
        "2",
        "--physics-hz",
        "500",
        "--seeds",
        "1",
    ];
    run_ok(&one, &out, &[]);
    // The rate reaches the run: its report says what physics it ran on.
    let result = &json_lines(&out.join("results.jsonl"))[0];
    assert_eq!(result["physics_hz"], 500, "{result}");
    let report = out.join("runs/robots=2,physics_hz=500,seed=1.json");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    assert_eq!(report["physics_hz"], 500);
    let other = [
        "sweep",
        "--behaviour",
        "square_walk",
        "--robots",
        "2",
        "--physics-hz",
        "500",
        "--seeds",
        "1..2",
    ];
    refused(&other, &[], &["holds a different sweep", "seeds"]);
    assert_eq!(lines(&out.join("results.jsonl")).len(), 1);
}

/// A sweep counts only its own runs, once each, and refuses a folder it cannot prove is its own:
/// a line copied in twice and a line of a run it does not have once made "7 of 6 runs", and with
/// `sweep.json` deleted another behaviour's results were mixed into its rates.
#[test]
fn a_sweep_counts_only_its_own_runs_and_refuses_a_folder_without_its_definition() {
    let out = dir("own-runs");
    run_ok(SWEEP, &out, &[]);
    let results = out.join("results.jsonl");
    let mut text = std::fs::read_to_string(&results).unwrap();
    let first = text.lines().next().unwrap().to_string();
    // Another seed's run: `seed=2` becomes `seed=92`, a run this sweep does not have.
    let foreign = first.replacen(",seed=", ",seed=9", 1);
    assert_ne!(foreign, first);
    text += &format!("{first}\n{foreign}\n");
    std::fs::write(&results, text).unwrap();
    let o = run_ok(SWEEP, &out, &[]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        stderr.contains("1 line(s) of runs this sweep does not have and 1 repeated"),
        "{stderr}"
    );
    let md = std::fs::read_to_string(out.join("summary.md")).unwrap();
    assert!(md.contains("10 of 10 runs have results"), "{md}");

    std::fs::remove_file(out.join("sweep.json")).unwrap();
    let other = &["sweep", "--behaviour", "line_follow", "--seeds", "1..2"];
    let o = coordinator(other, &out, &[])
        .output()
        .expect("coordinator runs");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("holds results but no sweep.json"),
        "{stderr}"
    );
}
