//! `handeye history`: the runs recorded in `<storage.dir>/history.sqlite` (see
//! `handeye::store`), read-only, so it works while the daemon writes.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use handeye::calendar::utc_text;
use handeye::config::Config;
use handeye::record::Stage;
use handeye::store::{RunSummary, Store, StoredRun, HISTORY_FILE};

/// Arguments of `history`.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// The cell's configuration; the history is `<storage.dir>/history.sqlite`. Before or
    /// after the subcommand (`history --config F list` or `history list --config F`).
    #[arg(long, value_name = "FILE", global = true)]
    config: Option<PathBuf>,
    #[command(subcommand)]
    command: HistoryCommand,
}

#[derive(Debug, clap::Subcommand)]
enum HistoryCommand {
    /// The newest runs, newest first.
    List {
        /// How many.
        #[arg(long, default_value_t = 20)]
        limit: usize,
        /// One JSON array of run summaries instead of a table.
        #[arg(long)]
        json: bool,
    },
    /// One run's record: outcome, reasons, result, drift, what was written, timings.
    Show {
        /// The run's id (from `history list`).
        run_id: String,
        /// The whole record as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Every run's summary, oldest first, for a spreadsheet or a script.
    Export {
        /// Write here instead of to standard output.
        #[arg(long, value_name = "FILE")]
        out: Option<PathBuf>,
        /// `json` (an array), `jsonl` (one object per line, with `verdict` and `started_utc`
        /// in ISO 8601, for log shippers) or `csv` (with a header line).
        #[arg(long, value_enum, default_value_t = Format::Json)]
        format: Format,
    },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Format {
    Json,
    Jsonl,
    Csv,
}

pub(crate) fn run(args: Args) -> anyhow::Result<ExitCode> {
    let Some(config) = &args.config else {
        anyhow::bail!("--config FILE is required: the cell's configuration, whose storage.dir holds the history");
    };
    let cfg = Config::load(config)?;
    let path = cfg.storage.dir.join(HISTORY_FILE);
    let store = Store::open_read_only(&path)?;
    let stdout = std::io::stdout();
    execute(&store, &args.command, &mut stdout.lock())?;
    Ok(ExitCode::SUCCESS)
}

fn execute(store: &Store, command: &HistoryCommand, out: &mut dyn Write) -> anyhow::Result<()> {
    match command {
        HistoryCommand::List { limit, json } => {
            let runs = store.list(*limit, None)?;
            if *json {
                writeln!(out, "{}", serde_json::to_string_pretty(&runs)?)?;
            } else {
                write_table(out, &runs)?;
            }
        }
        HistoryCommand::Show { run_id, json } => {
            let Some(record) = store.get(run_id)? else {
                anyhow::bail!(
                    "no run `{run_id}` in {}; `handeye history list` shows the ids",
                    store.path().display()
                );
            };
            if *json {
                writeln!(out, "{}", serde_json::to_string_pretty(&record)?)?;
            } else {
                let summary = store.summary(run_id)?;
                write_record(out, &record, summary.as_ref())?;
            }
        }
        HistoryCommand::Export { out: file, format } => {
            let mut runs = store.list(usize::MAX, None)?;
            runs.reverse();
            let text = match format {
                Format::Json => format!("{}\n", serde_json::to_string_pretty(&runs)?),
                Format::Jsonl => jsonl(&runs)?,
                Format::Csv => csv(&runs),
            };
            match file {
                Some(path) => write_file(path, &text)?,
                None => out.write_all(text.as_bytes())?,
            }
        }
    }
    Ok(())
}

fn write_file(path: &Path, text: &str) -> anyhow::Result<()> {
    std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
}

/// One line per run.
fn write_table(out: &mut dyn Write, runs: &[RunSummary]) -> std::io::Result<()> {
    if runs.is_empty() {
        return writeln!(out, "no runs recorded yet");
    }
    writeln!(
        out,
        "{:<20}  {:<21}  {:<8}  {:<9}  {:<13}  {:>7}  {:<26}  REASON",
        "STARTED (UTC)", "RUN ID", "TRIGGER", "MODE", "VERDICT", "TIME", "RESULT"
    )?;
    for r in runs {
        let time = r
            .duration_ms
            .map_or_else(|| "-".into(), |ms| format!("{:.1} s", ms / 1e3));
        let line = format!(
            "{:<20}  {:<21}  {:<8}  {:<9}  {:<13}  {:>7}  {:<26}  {}",
            utc_text(r.started_unix_s),
            r.run_id,
            r.trigger,
            r.mode.name(),
            r.verdict(),
            time,
            result_cell(r),
            r.reason
                .as_deref()
                .map_or(String::new(), |s| shorten(s, 72)),
        );
        writeln!(out, "{}", line.trim_end())?;
    }
    Ok(())
}

/// The drift of a check, else the uncertainty of a result.
fn result_cell(r: &RunSummary) -> String {
    match (r.drift_translation_mm, r.drift_rotation_deg) {
        (Some(mm), Some(deg)) => {
            let verdict = if r.drifted == Some(true) {
                " DRIFTED"
            } else {
                ""
            };
            format!("drift {mm:.2} mm {deg:.3}°{verdict}")
        }
        _ => match (r.uncertainty_translation_mm, r.uncertainty_rotation_deg) {
            (Some(mm), Some(deg)) => format!("±{mm:.2} mm ±{deg:.3}°"),
            _ => "-".into(),
        },
    }
}

fn shorten(s: &str, max: usize) -> String {
    if s.chars().count() <= max {
        s.to_string()
    } else {
        let mut t: String = s.chars().take(max - 1).collect();
        t.push('…');
        t
    }
}

/// The main lines of a run: its record, or what is known of a run that never finished.
fn write_record(
    out: &mut dyn Write,
    run: &StoredRun,
    summary: Option<&RunSummary>,
) -> std::io::Result<()> {
    let (run_id, mode, outcome, started, config) = match run {
        StoredRun::Complete(r) => (
            &r.run_id,
            r.mode,
            r.outcome.name(),
            r.started_unix_s,
            &r.config,
        ),
        StoredRun::Partial(p) => (
            &p.run_id,
            p.mode,
            p.outcome.name(),
            p.started_unix_s,
            &p.config,
        ),
    };
    write!(out, "run {run_id}: {mode}, {outcome}")?;
    if let Some(sm) = summary {
        write!(out, " (trigger {})", sm.trigger)?;
    }
    writeln!(out)?;
    let mut started = utc_text(started);
    if let StoredRun::Complete(r) = run {
        started += &format!(", took {:.2} s", r.timings_ms.total / 1e3);
    }
    writeln!(out, "started   {started}")?;
    let mut config = config.clone();
    if let Some(digest) = summary.and_then(|sm| sm.config_digest.as_deref()) {
        config += &format!(" (digest {digest})");
    }
    writeln!(out, "config    {config}")?;
    let rec = match run {
        StoredRun::Complete(r) => r,
        StoredRun::Partial(p) => {
            writeln!(
                out,
                "record    none: the run is still running, or was interrupted before it ended"
            )?;
            return write_reasons(out, &p.reasons);
        }
    };
    if let Some(stage) = rec.failed_stage {
        writeln!(out, "failed    at {}", stage.name())?;
    }
    write_reasons(out, &rec.reasons)?;
    if let Some(result) = &rec.result {
        let p = result.ur_pose;
        let angle = (p[3] * p[3] + p[4] * p[4] + p[5] * p[5])
            .sqrt()
            .to_degrees();
        writeln!(
            out,
            "result    {}: translation ({:.3}, {:.3}, {:.3}) mm, rotation vector ({:.6}, {:.6}, {:.6}) rad ({angle:.3}°)",
            result.mount.unknown_name(),
            p[0] * 1e3,
            p[1] * 1e3,
            p[2] * 1e3,
            p[3],
            p[4],
            p[5]
        )?;
        let u = result.uncertainty;
        writeln!(
            out,
            "          1σ uncertainty ±{:.3} mm, ±{:.4}°{}",
            u.translation_mm,
            u.rotation_deg,
            u.workspace_note()
        )?;
    }
    if let Some(c) = &rec.change_accepted {
        let moved = match (c.translation_mm, c.rotation_deg) {
            (Some(mm), Some(deg)) => {
                format!("moved {mm:.2} mm, {deg:.3}° from the previous calibration")
            }
            _ => "no previous calibration to compare with".into(),
        };
        let beyond = if c.beyond_limits {
            "beyond gate.max_change_*"
        } else {
            "within gate.max_change_*"
        };
        writeln!(out, "remount   accepted by {}: {moved} ({beyond})", c.by)?;
    }
    if let Some(d) = &rec.drift {
        let verdict = if d.drifted {
            "DRIFTED"
        } else {
            "within thresholds"
        };
        writeln!(
            out,
            "drift     {:.3} mm, {:.4}° from {} (thresholds {} mm, {}°): {verdict}",
            d.translation_mm, d.rotation_deg, d.reference, d.max_translation_mm, d.max_rotation_deg,
        )?;
    }
    if rec.written.is_empty() {
        writeln!(out, "written   nothing")?;
    }
    for (i, w) in rec.written.iter().enumerate() {
        let label = if i == 0 { "written" } else { "" };
        writeln!(out, "{label:<9} {}: {}", w.target, w.detail)?;
    }
    let parts: Vec<String> = rec
        .timings_ms
        .stages()
        .iter()
        .map(|(k, ms)| format!("{k} {ms:.0}"))
        .collect();
    writeln!(out, "timings   ms: {}", parts.join(", "))?;
    if let Some(path) = &rec.capture_file {
        let pruned = summary.is_some_and(|sm| sm.captures_pruned_unix_s.is_some());
        let note = if pruned {
            " (raw scans pruned; replay is no longer possible)"
        } else {
            ""
        };
        writeln!(out, "capture   {path}{note}")?;
    }
    Ok(())
}

/// `reasons   - …`, one line each.
fn write_reasons(out: &mut dyn Write, reasons: &[String]) -> std::io::Result<()> {
    for (i, reason) in reasons.iter().enumerate() {
        let label = if i == 0 { "reasons" } else { "" };
        writeln!(out, "{label:<9} - {reason}")?;
    }
    Ok(())
}

/// The summaries as CSV (RFC 4180: a header line, fields quoted when needed).
/// One JSON object per run and line: the summary, its `verdict` and `started_utc` (ISO 8601).
fn jsonl(runs: &[RunSummary]) -> anyhow::Result<String> {
    let mut out = String::new();
    for r in runs {
        let mut v = serde_json::to_value(r)?;
        v["verdict"] = r.verdict().into();
        v["started_utc"] = utc_text(r.started_unix_s).into();
        out += &serde_json::to_string(&v)?;
        out.push('\n');
    }
    Ok(out)
}

fn csv(runs: &[RunSummary]) -> String {
    const HEADER: &str = "run_id,trigger,mode,outcome,started_utc,started_unix_s,finished_unix_s,duration_ms,failed_stage,reason,x_m,y_m,z_m,rx_rad,ry_rad,rz_rad,uncertainty_translation_mm,uncertainty_rotation_deg,drift_translation_mm,drift_rotation_deg,drifted,written,capture_file,captures_pruned_unix_s,config_origin,config_digest";
    let num = |v: Option<f64>| v.map_or(String::new(), |x| x.to_string());
    let text = |v: Option<&str>| v.map_or(String::new(), quote);
    let mut out = format!("{HEADER}\n");
    for r in runs {
        let pose = |i: usize| num(r.ur_pose.map(|p| p[i]));
        let fields = [
            quote(&r.run_id),
            quote(r.trigger.name()),
            r.mode.name().to_string(),
            r.outcome.name().to_string(),
            utc_text(r.started_unix_s),
            r.started_unix_s.to_string(),
            num(r.finished_unix_s),
            num(r.duration_ms),
            text(r.failed_stage.map(Stage::name)),
            text(r.reason.as_deref()),
            pose(0),
            pose(1),
            pose(2),
            pose(3),
            pose(4),
            pose(5),
            num(r.uncertainty_translation_mm),
            num(r.uncertainty_rotation_deg),
            num(r.drift_translation_mm),
            num(r.drift_rotation_deg),
            r.drifted.map_or(String::new(), |d| d.to_string()),
            quote(
                &r.written
                    .iter()
                    .map(|w| w.name())
                    .collect::<Vec<_>>()
                    .join("+"),
            ),
            text(r.capture_file.as_deref()),
            num(r.captures_pruned_unix_s),
            quote(&r.config_origin),
            text(r.config_digest.as_deref()),
        ];
        out += &fields.join(",");
        out.push('\n');
    }
    out
}

fn quote(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;
    use handeye::calib::report::{QualitySummary, ReportTimings};
    use handeye::calib::{CalibrationReport, Mount, Uncertainty};
    use handeye::run::{
        DriftRecord, Outcome, ResultRecord, RunMode, RunRecord, RunTimings, Stage, Written,
    };
    use handeye::store::RunStart;

    #[derive(Debug, Parser)]
    struct Cli {
        #[command(flatten)]
        args: Args,
    }

    fn pose(x: f64, y: f64, z: f64) -> [[f64; 4]; 4] {
        [
            [1.0, 0.0, 0.0, x],
            [0.0, 1.0, 0.0, y],
            [0.0, 0.0, 1.0, z],
            [0.0, 0.0, 0.0, 1.0],
        ]
    }

    fn record(run_id: &str, mode: RunMode, outcome: Outcome, started: f64) -> RunRecord {
        let uncertainty = Uncertainty {
            translation_mm: 0.21,
            rotation_deg: 0.03,
            workspace: None,
        };
        let accepted = outcome == Outcome::Accepted;
        RunRecord {
            run_id: run_id.into(),
            mode,
            dry_run: false,
            config: "/etc/handeye/cell.toml".into(),
            trigger: None,
            started_unix_s: started,
            outcome,
            reasons: if accepted {
                vec![]
            } else {
                vec!["coverage 0.31 < 0.6, \"too little\": aim the camera at the base".into()]
            },
            warnings: vec![],
            failed_stage: (!accepted).then_some(Stage::Solve),
            preflight: None,
            views: vec![],
            forecast: None,
            captures: vec![],
            capture_file: Some(format!("/var/lib/handeye/runs/{run_id}/capture.json")),
            result: Some(ResultRecord {
                mount: Mount::EyeInHand,
                flange_from_camera: Some(pose(0.0, -0.08, 0.04)),
                base_from_camera: pose(0.4, -0.1, 0.5),
                ur_pose: [0.0, -0.08, 0.04, -0.26, 0.0, 0.0],
                uncertainty,
                report: CalibrationReport {
                    outcome,
                    reasons: vec![],
                    mount: Mount::EyeInHand,
                    base_frame: "base".into(),
                    base_from_camera: pose(0.4, -0.1, 0.5),
                    flange_from_camera: Some(pose(0.0, -0.08, 0.04)),
                    uncertainty,
                    quality: QualitySummary {
                        coverage: 0.8,
                        link_support: [None; 3],
                        free_space_violations: 0.01,
                        rmse_mm: 0.4,
                        inlier_fraction: 0.9,
                        depth_scale: None,
                        depth_offset_mm: None,
                        frames_used: 1,
                        frames: 1,
                        views_used: 1,
                        views: 1,
                    },
                    timings_ms: ReportTimings::default(),
                    frames: vec![],
                    views: vec![],
                    split_half: None,
                    outline: None,
                },
            }),
            drift: (mode == RunMode::Check).then(|| DriftRecord {
                reference: "result of run A".into(),
                reference_pose: pose(0.0, -0.08, 0.04),
                translation_mm: 0.42,
                rotation_deg: 0.05,
                max_translation_mm: 2.0,
                max_rotation_deg: 0.5,
                drifted: false,
            }),
            change_accepted: None,
            written: if accepted && mode == RunMode::Calibrate {
                vec![Written {
                    target: handeye::record::WriteTarget::Tcp,
                    detail: "set_tcp, read back".into(),
                }]
            } else {
                vec![]
            },
            returned_to_start: true,
            timings_ms: RunTimings {
                total: 4200.0,
                register: 310.0,
                ..RunTimings::default()
            },
        }
    }

    /// Runs `handeye history --config <cfg> <words>` against `store`; returns stdout.
    fn history(store: &Store, cfg: &Path, words: &[&str]) -> anyhow::Result<String> {
        let mut argv = vec!["history", "--config", cfg.to_str().expect("utf-8")];
        argv.extend_from_slice(words);
        let cli = Cli::try_parse_from(argv)?;
        let mut out = Vec::new();
        execute(store, &cli.args.command, &mut out)?;
        Ok(String::from_utf8(out)?)
    }

    /// `--config` goes before or after the subcommand, as with every other command (issue
    /// 38); without it the message says what to give.
    #[test]
    fn config_is_accepted_before_or_after_the_subcommand() {
        for argv in [
            &["history", "--config", "cell.toml", "list"][..],
            &["history", "list", "--config", "cell.toml"][..],
            &["history", "show", "r1", "--config", "cell.toml", "--json"][..],
        ] {
            let cli = Cli::try_parse_from(argv).expect("parses");
            assert_eq!(
                cli.args.config.as_deref(),
                Some(Path::new("cell.toml")),
                "{argv:?}"
            );
        }
        let err = run(Cli::parse_from(["history", "list"]).args).expect_err("no config");
        assert!(
            err.to_string().contains("--config FILE is required"),
            "{err}"
        );
    }

    #[test]
    fn history_lists_shows_and_exports_the_runs() {
        let dir = std::env::temp_dir().join(format!("handeye-history-cli-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("dir");
        let cfg_path = dir.join("cell.toml");
        std::fs::write(
            &cfg_path,
            "[robot]\nmodel = \"ur5e\"\nhost = \"192.168.56.101\"\n\n[camera]\nbackend = \"gige\"\naddress = \"192.168.1.50\"\n\n[mount]\nprior = [0.0, -0.08, 0.04, -0.26, 0.0, 0.0]\n\n[storage]\ndir = \"data\"\n",
        )
        .expect("config");

        // Before anything is written: the message says who writes the history (exit 2).
        let err = run(Cli::parse_from([
            "history",
            "--config",
            cfg_path.to_str().expect("utf-8"),
            "list",
        ])
        .args)
        .expect_err("no history yet");
        let db = dir.join("data").join(HISTORY_FILE);
        assert!(err.to_string().starts_with("no history yet at "), "{err}");
        assert!(err.to_string().contains("history.sqlite"), "{err}");

        let writer = Store::open(&db).expect("writer");
        let t = 1_764_000_000.0; // 2025-11-24T16:00:00Z
        writer
            .begin(&RunStart {
                run_id: "run-a".into(),
                trigger: handeye::record::Trigger::Startup,
                mode: RunMode::Calibrate,
                config_origin: cfg_path.display().to_string(),
                config_digest: handeye::store::config_digest("cell"),
                started_unix_s: t,
            })
            .expect("begin");
        writer
            .finish(
                handeye::record::Trigger::Startup,
                &record("run-a", RunMode::Calibrate, Outcome::Accepted, t),
            )
            .expect("finish");
        writer
            .finish(
                handeye::record::Trigger::Schedule,
                &record("run-b", RunMode::Check, Outcome::Accepted, t + 3600.0),
            )
            .expect("finish");
        writer
            .finish(
                handeye::record::Trigger::Api,
                &record("run-c", RunMode::Calibrate, Outcome::Rejected, t + 7200.0),
            )
            .expect("finish");
        // The CLI opens read-only, while the writer is still open.
        let store = Store::open_read_only(&db).expect("reader");

        let list = history(&store, &cfg_path, &["list"]).expect("list");
        let lines: Vec<&str> = list.lines().collect();
        assert_eq!(lines.len(), 4, "{list}");
        assert!(
            lines.iter().all(|l| l.trim_end() == *l),
            "no trailing blanks: {list}"
        );
        assert!(lines[0].starts_with("STARTED (UTC)"), "{list}");
        assert!(
            lines[1].contains("run-c")
                && lines[1].contains("rejected")
                && lines[1].contains("coverage 0.31"),
            "{list}"
        );
        assert!(
            lines[2].contains("run-b") && lines[2].contains("drift 0.42 mm"),
            "{list}"
        );
        assert!(
            lines[3].starts_with("2025-11-24T16:00:00Z ")
                && lines[3].contains("startup")
                && lines[3].contains("±0.21 mm"),
            "{list}"
        );
        let limited =
            history(&store, &cfg_path, &["list", "--limit", "1", "--json"]).expect("list");
        let json: serde_json::Value = serde_json::from_str(&limited).expect("json");
        assert_eq!(json.as_array().map(Vec::len), Some(1));
        assert_eq!(json[0]["run_id"], "run-c");
        assert_eq!(json[0]["outcome"], "rejected");

        let show = history(&store, &cfg_path, &["show", "run-a"]).expect("show");
        for expected in [
            "run run-a: calibrate, accepted (trigger startup)",
            "started   2025-11-24T16:00:00Z, took 4.20 s",
            "(digest ",
            "result    flange_from_camera: translation (0.000, -80.000, 40.000) mm, rotation vector (-0.260000, 0.000000, 0.000000) rad (14.897°)",
            "±0.210 mm",
            "written   tcp: set_tcp, read back",
            "register 310",
            "capture   /var/lib/handeye/runs/run-a/capture.json",
        ] {
            assert!(show.contains(expected), "`{expected}` in:\n{show}");
        }
        let show = history(&store, &cfg_path, &["show", "run-b"]).expect("show");
        assert!(show.contains("drift     0.420 mm, 0.0500° from result of run A (thresholds 2 mm, 0.5°): within thresholds"), "{show}");
        let show = history(&store, &cfg_path, &["show", "run-c"]).expect("show");
        assert!(
            show.contains("failed    at solve") && show.contains("reasons   - coverage 0.31"),
            "{show}"
        );
        assert!(show.contains("written   nothing"), "{show}");
        let json = history(&store, &cfg_path, &["show", "run-c", "--json"]).expect("show");
        let json: serde_json::Value = serde_json::from_str(&json).expect("json");
        assert_eq!(
            json,
            serde_json::to_value(record(
                "run-c",
                RunMode::Calibrate,
                Outcome::Rejected,
                t + 7200.0
            ))
            .expect("json")
        );
        let err = history(&store, &cfg_path, &["show", "nope"]).expect_err("unknown id");
        assert!(err.to_string().contains("no run `nope`"), "{err}");

        let jsonl = history(&store, &cfg_path, &["export", "--format", "jsonl"]).expect("jsonl");
        let lines: Vec<serde_json::Value> = jsonl
            .lines()
            .map(|l| serde_json::from_str(l).expect("one object per line"))
            .collect();
        assert_eq!(lines.len(), 3, "{jsonl}");
        assert_eq!(lines[0]["run_id"], "run-a", "oldest first: {jsonl}");
        assert_eq!(lines[0]["started_utc"], "2025-11-24T16:00:00Z", "{jsonl}");
        assert_eq!(lines[0]["verdict"], "accepted", "{jsonl}");
        assert_eq!(lines[1]["verdict"], "within limits", "{jsonl}");
        assert_eq!(lines[2]["verdict"], "rejected", "{jsonl}");

        let csv = history(&store, &cfg_path, &["export", "--format", "csv"]).expect("csv");
        let rows: Vec<&str> = csv.lines().collect();
        assert_eq!(rows.len(), 4, "{csv}");
        assert!(
            rows[0].starts_with("run_id,trigger,mode,outcome,started_utc,"),
            "{csv}"
        );
        let columns = rows[0].split(',').count();
        assert!(
            rows[1].starts_with("run-a,startup,calibrate,accepted,2025-11-24T16:00:00Z,"),
            "oldest first: {csv}"
        );
        assert!(
            rows[1].contains(",0,-0.08,0.04,-0.26,0,0,0.21,0.03,"),
            "{csv}"
        );
        assert!(rows[1].contains(",tcp,"), "{csv}");
        // The quoted reason keeps its comma and quotes.
        assert!(
            rows[3]
                .contains(r#","coverage 0.31 < 0.6, ""too little"": aim the camera at the base","#),
            "{csv}"
        );
        for row in &rows[1..3] {
            assert_eq!(row.split(',').count(), columns, "{row}");
        }
        let out = dir.join("export.json");
        let printed = history(
            &store,
            &cfg_path,
            &["export", "--out", out.to_str().expect("utf-8")],
        )
        .expect("export");
        assert!(printed.is_empty());
        let all: Vec<RunSummary> =
            serde_json::from_str(&std::fs::read_to_string(&out).expect("exported")).expect("json");
        let ids: Vec<&str> = all.iter().map(|r| r.run_id.as_str()).collect();
        assert_eq!(ids, ["run-a", "run-b", "run-c"]);

        // The whole command, through the configuration.
        let code = run(Cli::parse_from([
            "history",
            "--config",
            cfg_path.to_str().expect("utf-8"),
            "list",
        ])
        .args)
        .expect("runs");
        assert_eq!(code, ExitCode::SUCCESS);
        drop((store, writer));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
