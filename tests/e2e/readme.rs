//! The manual's examples as one sequence: every fenced block whose info string is
//! `sh readme-test`, in README.md and then in the book's pages in the order of
//! `docs/src/SUMMARY.md`, is extracted in order and each command runs (`sh -c`, `handeye` on
//! the PATH, in one scratch directory), so the manual and this test cannot drift apart. Every
//! command must succeed; `simulate-scan` must not warn; a `solve --json` result must match
//! the simulator's ground truth of the scan it solved. The README's sample of
//! `handeye demo --seed 3` is compared with a real run of it.

use std::io::Read as _;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::support::{iso, pose_error, shared, TempDir, BIN};

/// The commands of the README's `readme-test` blocks, continuation lines joined, comments and
/// blank lines left out.
fn readme_commands(readme: &str) -> Vec<String> {
    let mut commands = Vec::new();
    let mut in_block = false;
    let mut pending = String::new();
    for line in readme.lines() {
        let trimmed = line.trim_start();
        if let Some(info) = trimmed.strip_prefix("```") {
            in_block = !in_block && info.split_whitespace().any(|w| w == "readme-test");
            continue;
        }
        if !in_block || (pending.is_empty() && (trimmed.is_empty() || trimmed.starts_with('#'))) {
            continue;
        }
        match line.strip_suffix('\\') {
            Some(head) => pending.push_str(head),
            None => {
                pending.push_str(line);
                commands.push(std::mem::take(&mut pending).trim().to_string());
            }
        }
    }
    commands
}

/// Runs one shell command line in `dir` with `handeye` on the PATH; kills it after `limit`.
fn sh(dir: &Path, cmd: &str, limit: Duration) -> (i32, String, String) {
    let bin_dir = Path::new(BIN).parent().expect("binary directory");
    let path = format!(
        "{}:{}",
        bin_dir.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let mut child = Command::new("sh")
        .arg("-c")
        .arg(cmd)
        .current_dir(dir)
        .env("PATH", path)
        .env(
            "HANDEYE_ROBOTS",
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/robots"),
        )
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn sh");
    let drain = |r: Option<Box<dyn std::io::Read + Send>>| {
        std::thread::spawn(move || {
            let mut s = String::new();
            if let Some(mut r) = r {
                let _ = r.read_to_string(&mut s);
            }
            s
        })
    };
    let out = drain(child.stdout.take().map(|s| Box::new(s) as _));
    let err = drain(child.stderr.take().map(|s| Box::new(s) as _));
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().expect("wait") {
            break s;
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            panic!("`{cmd}` took longer than {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    (
        status.code().unwrap_or(-1),
        out.join().expect("stdout"),
        err.join().expect("stderr"),
    )
}

/// README.md, then the book's pages in the order of docs/src/SUMMARY.md, as one text.
fn manual() -> String {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut text = std::fs::read_to_string(root.join("README.md")).expect("README.md");
    let summary = std::fs::read_to_string(root.join("docs/src/SUMMARY.md")).expect("SUMMARY.md");
    for page in crate::book::links(&summary) {
        text.push('\n');
        text.push_str(
            &std::fs::read_to_string(root.join("docs/src").join(&page)).expect("book page"),
        );
    }
    text
}

#[test]
fn readme_blocks_are_extracted_in_order() {
    let text = "a\n```sh readme-test\n# c\nhandeye x \\\n  --y 1\n\nhandeye z\n```\n```sh\nhandeye not\n```\n";
    assert_eq!(readme_commands(text), ["handeye x   --y 1", "handeye z"]);
}

#[test]
fn readme_examples_run_as_a_sequence() {
    let Some(_shared) = shared("readme_examples_run_as_a_sequence") else {
        return;
    };
    let commands = readme_commands(&manual());
    assert!(
        commands
            .iter()
            .any(|c| c.starts_with("handeye simulate-scan"))
            && commands.iter().any(|c| c.starts_with("handeye solve")),
        "the manual must keep a simulate-scan → solve sequence marked readme-test: {commands:?}"
    );
    let dir = TempDir::new("readme");
    let work = dir.join("");
    for cmd in &commands {
        let (code, stdout, stderr) = sh(&work, cmd, Duration::from_secs(120));
        let shown = format!("`{cmd}` exited {code}\n--- stdout\n{stdout}\n--- stderr\n{stderr}");
        assert_eq!(code, 0, "{shown}");
        if cmd.starts_with("handeye simulate-scan") {
            assert!(!stderr.contains("warning"), "{shown}");
        }
        if cmd.starts_with("handeye solve") && cmd.contains("--json") {
            let result: serde_json::Value = serde_json::from_str(&stdout).expect("one JSON object");
            assert_eq!(result["outcome"], "accepted", "{shown}");
            // The scan it solved: the `--scan` argument, its truth beside it.
            let scan = cmd
                .split_whitespace()
                .skip_while(|w| *w != "--scan")
                .nth(1)
                .expect("--scan");
            let gt_file = work.join(scan.replace(".ply", ".gt.json"));
            let gt: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(&gt_file).expect("ground truth"))
                    .expect("JSON");
            let (mm, deg) = pose_error(
                &iso(&result["flange_from_camera"]),
                &iso(&gt["flange_from_camera"]),
            );
            assert!(
                mm < 2.0 && deg < 0.5,
                "{mm} mm, {deg}° off the truth\n{shown}"
            );
        }
    }
}

/// The README's sample of `handeye demo --seed 3`: the block whose info string is
/// `text demo-seed-3`.
fn demo_sample(readme: &str) -> Vec<String> {
    let mut lines = Vec::new();
    let mut inside = false;
    for line in readme.lines() {
        if let Some(info) = line.trim_start().strip_prefix("```") {
            if inside {
                break;
            }
            inside = info.split_whitespace().any(|w| w == "demo-seed-3");
            continue;
        }
        if inside {
            lines.push(line.to_string());
        }
    }
    lines
}

/// A demo line with what changes from run to run masked: the rig's ports and the timings
/// (`rig:` and `time:` lines: every number), the run folder's paths and the run id.
fn mask(line: &str) -> String {
    let is_run_id = |t: &str| {
        let b = t.as_bytes();
        b.len() == 21 && b[8] == b'T' && b[15] == b'Z' && b[16] == b'-'
    };
    let words: Vec<String> = line
        .split(' ')
        .map(|w| {
            if w.contains("handeye-demo-") {
                "<path>".to_string()
            } else if is_run_id(w.trim_end_matches([':', ','])) {
                "<run>".to_string()
            } else {
                w.to_string()
            }
        })
        .collect();
    let masked = words.join(" ");
    let head = masked.trim_start();
    if head.starts_with("rig:") || head.starts_with("time:") {
        let mut out = String::new();
        let mut in_number = false;
        for c in masked.chars() {
            if c.is_ascii_digit() || (in_number && c == '.') {
                if !in_number {
                    out.push('#');
                }
                in_number = true;
            } else {
                in_number = false;
                out.push(c);
            }
        }
        out
    } else {
        masked
    }
}

#[test]
fn demo_lines_are_masked_where_runs_differ() {
    assert_eq!(
        mask("  rig: UR controller on 127.0.0.1 (RTDE port 36945, dashboard 42415)"),
        mask("  rig: UR controller on 127.0.0.1 (RTDE port 1, dashboard 2)")
    );
    assert_eq!(
        mask("  raw capture: /tmp/handeye-demo-1-3/runs/20261124T143314Z-4e4f/capture.json (x)"),
        "  raw capture: <path> (x)"
    );
    assert_eq!(
        mask("handeye calibrate — run 20261124T143314Z-4e4f: accepted"),
        "handeye calibrate — run <run> accepted"
    );
    assert_ne!(
        mask("  error vs ground truth: 0.012 mm"),
        mask("  error vs ground truth: 0.088 mm")
    );
}

/// Every line of the README's demo sample is what `handeye demo --seed 3` prints now, in
/// order, but for the ports, paths, run id and timings; a line that ends in `…` is abridged
/// and matches the beginning of its line.
#[test]
fn readme_demo_sample_is_what_the_demo_prints() {
    let Some(_shared) = shared("readme_demo_sample_is_what_the_demo_prints") else {
        return;
    };
    let readme = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("README.md"))
        .expect("README.md");
    let sample = demo_sample(&readme);
    assert!(
        sample.len() >= 10 && sample[0].starts_with("handeye demo"),
        "the README must show a `text demo-seed-3` block: {sample:?}"
    );
    let dir = TempDir::new("readme-demo");
    let (code, stdout, stderr) = sh(
        &dir.join(""),
        "handeye demo --seed 3",
        Duration::from_secs(300),
    );
    assert_eq!(
        code, 0,
        "handeye demo --seed 3 exited {code}\n{stdout}\n{stderr}"
    );
    let printed: Vec<String> = stdout.lines().map(mask).collect();
    let mut at = 0;
    for line in &sample {
        if line.trim() == "…" {
            continue;
        }
        let want = mask(line);
        let found = match want.strip_suffix('…') {
            Some(prefix) => printed[at..].iter().position(|p| p.starts_with(prefix)),
            None => printed[at..].iter().position(|p| *p == want),
        };
        match found {
            Some(i) => at += i + 1,
            None => panic!(
                "the README's demo sample line\n  {line}\nis not (in order) what \
                 `handeye demo --seed 3` prints now; replace the sample with this run:\n{stdout}"
            ),
        }
    }
}
