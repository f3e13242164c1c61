//! The README's examples as one sequence: every fenced block whose info string is
//! `sh readme-test` is extracted in order and each command runs (`sh -c`, `handeye` on the
//! PATH, in one scratch directory), so the README and this test cannot drift apart. Every
//! command must succeed; `simulate-scan` must not warn; a `solve --json` result must match
//! the simulator's ground truth of the scan it solved.

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
    let readme = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("README.md"))
        .expect("README.md");
    let commands = readme_commands(&readme);
    assert!(
        commands
            .iter()
            .any(|c| c.starts_with("handeye simulate-scan"))
            && commands.iter().any(|c| c.starts_with("handeye solve")),
        "the README must keep a simulate-scan → solve sequence marked readme-test: {commands:?}"
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
