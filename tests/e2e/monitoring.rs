//! The fleet view (`monitoring/`): the Prometheus alerting rules pass `promtool check rules` and
//! their unit tests (`promtool test rules`), every query of the Grafana dashboard parses as
//! PromQL, and every `handeye_*` metric the rules and the dashboard use is one the daemon
//! serves ([`check_live_metrics`], called with a live `/metrics` by the daemon's e2e test).
//! promtool comes from Debian's `prometheus` package (`.ci/install.d/prometheus.sh`).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use crate::support::{skip, TempDir};

fn monitoring() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("monitoring")
}

/// `promtool`, or `None` (after printing SKIP) off CI; panics under CI.
pub(crate) fn promtool(test: &str) -> Option<&'static str> {
    let found = Command::new("promtool")
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if found {
        return Some("promtool");
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "{test}: promtool is missing in CI: run .ci/install.d/prometheus.sh"
    );
    skip(&format!("SKIP {test}: promtool not found"));
    None
}

fn promtool_ok(args: &[&str], dir: &Path) -> String {
    let out = Command::new("promtool")
        .args(args)
        .current_dir(dir)
        .output()
        .expect("promtool runs");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "promtool {args:?}:\n{text}");
    text
}

/// Every PromQL expression of the dashboard (template variables filled in).
fn dashboard_queries() -> Vec<String> {
    let text = std::fs::read_to_string(monitoring().join("grafana-dashboard.json"))
        .expect("grafana-dashboard.json");
    let doc: serde_json::Value = serde_json::from_str(&text).expect("the dashboard is JSON");
    assert_eq!(doc["uid"], "handeye-cells");
    let panels = doc["panels"].as_array().expect("panels");
    assert!(!panels.is_empty());
    let mut queries = Vec::new();
    for p in panels {
        assert_eq!(p["datasource"]["uid"], "${datasource}", "{p}");
        let targets = p["targets"].as_array().expect("targets");
        assert!(!targets.is_empty(), "a panel without a query: {p}");
        for t in targets {
            let expr = t["expr"].as_str().expect("expr");
            queries.push(expr.replace("$instance", ".*"));
        }
    }
    queries
}

/// The `handeye_*` metric names in `text`.
fn metric_names(text: &str) -> BTreeSet<String> {
    let mut names = BTreeSet::new();
    let mut rest = text;
    while let Some(i) = rest.find("handeye_") {
        let tail = &rest[i..];
        let end = tail
            .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
            .unwrap_or(tail.len());
        names.insert(tail[..end].to_string());
        rest = &tail[end..];
    }
    names
}

/// What the rules and the dashboard ask for.
fn used_metrics() -> BTreeSet<String> {
    let rules = std::fs::read_to_string(monitoring().join("handeye.rules.yml")).expect("rules");
    let mut used = BTreeSet::new();
    for line in rules
        .lines()
        .filter(|l| l.trim_start().starts_with("expr:"))
    {
        used.extend(metric_names(line));
    }
    for q in dashboard_queries() {
        used.extend(metric_names(&q));
    }
    used
}

/// A live `/metrics` passes `promtool check metrics` and serves every metric the rules and the
/// dashboard use.
pub(crate) fn check_live_metrics(test: &str, metrics: &str) {
    let Some(promtool) = promtool(test) else {
        return;
    };
    let mut child = Command::new(promtool)
        .args(["check", "metrics"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("promtool runs");
    {
        use std::io::Write as _;
        let mut stdin = child.stdin.take().expect("stdin");
        stdin
            .write_all(metrics.as_bytes())
            .expect("metrics to promtool");
    }
    let out = child.wait_with_output().expect("promtool ends");
    assert!(
        out.status.success(),
        "promtool check metrics:\n{}{}\n{metrics}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let served = metric_names(metrics);
    let missing: Vec<String> = used_metrics().difference(&served).cloned().collect();
    assert!(
        missing.is_empty(),
        "the rules or the dashboard use metrics the daemon does not serve: {missing:?}"
    );
}

#[test]
fn the_alerting_rules_and_the_dashboard_pass_promtool() {
    let test = "the_alerting_rules_and_the_dashboard_pass_promtool";
    if promtool(test).is_none() {
        return;
    }
    let dir = monitoring();
    let text = promtool_ok(&["check", "rules", "handeye.rules.yml"], &dir);
    assert!(text.contains("SUCCESS: 8 rules found"), "{text}");
    let text = promtool_ok(&["test", "rules", "handeye.rules.test.yml"], &dir);
    assert!(text.contains("SUCCESS"), "{text}");

    // Each dashboard query parses: promtool checks it as a recording rule.
    let queries = dashboard_queries();
    let tmp = TempDir::new("dashboard-queries");
    let mut rules = String::from("groups:\n  - name: dashboard\n    rules:\n");
    for (i, q) in queries.iter().enumerate() {
        rules += &format!(
            "      - record: handeye_dashboard:panel_{i}\n        expr: {}\n",
            serde_json::to_string(q).expect("quoted")
        );
    }
    std::fs::write(tmp.join("dashboard.rules.yml"), rules).expect("write");
    let text = promtool_ok(&["check", "rules", "dashboard.rules.yml"], &tmp.join(""));
    assert!(
        text.contains(&format!("SUCCESS: {} rules found", queries.len())),
        "{text}"
    );
    // And a broken query would not: the check can fail.
    std::fs::write(
        tmp.join("broken.rules.yml"),
        "groups:\n  - name: b\n    rules:\n      - record: b\n        expr: \"sum(handeye_busy\"\n",
    )
    .expect("write");
    let out = Command::new("promtool")
        .args(["check", "rules", "broken.rules.yml"])
        .current_dir(tmp.join(""))
        .output()
        .expect("promtool runs");
    assert!(!out.status.success(), "a broken query passed");
}
