//! The daemon's counters and gauges for `GET /metrics`, in the Prometheus text exposition
//! format: runs by trigger and outcome (a check that found drift counts as `drifted`, not as
//! `accepted`), run durations, the last calibration's uncertainty, the
//! last drift, alarms, the connections and the queue.

use std::fmt::Write as _;

use crate::record::{Outcome, RunMode, RunRecord, Trigger};
use crate::store::RunSummary;

/// Upper bounds of the run-duration histogram, s.
const DURATION_BUCKETS: [f64; 8] = [1.0, 2.5, 5.0, 10.0, 20.0, 30.0, 60.0, 120.0];

/// The `outcome` label of a finished run in `handeye_runs_total`: `drifted` for a check that
/// measured the camera beyond `[check]`'s thresholds (so a dashboard's runs by outcome shows
/// drift apart from the checks within limits, which stay `accepted`), else the outcome.
pub(super) fn outcome_label(record: &RunRecord) -> &'static str {
    match record.drift_found() {
        Some(true) => "drifted",
        _ => record.outcome.name(),
    }
}

/// What the runs so far add up to.
#[derive(Debug, Default, Clone)]
pub(super) struct Metrics {
    /// Runs by (trigger, outcome label: [`outcome_label`]).
    runs: Vec<((Trigger, &'static str), u64)>,
    /// Durations of every finished run, s, bucketed.
    duration_buckets: [u64; DURATION_BUCKETS.len()],
    duration_sum_s: f64,
    duration_count: u64,
    last_uncertainty_mm: Option<f64>,
    last_uncertainty_deg: Option<f64>,
    last_drift_mm: Option<f64>,
    last_drift_deg: Option<f64>,
    alarms: u64,
}

/// The daemon's state as the gauges show it, at the time of the request.
#[derive(Debug, Clone, Copy)]
pub(super) struct Live {
    /// Whether the last check found drift.
    pub(super) drift_alarm: bool,
    /// Whether the robot answers, and how often its connection was re-established.
    pub(super) robot: (bool, u64),
    /// The same for the camera.
    pub(super) camera: (bool, u64),
    /// Whether a run is going.
    pub(super) busy: bool,
    /// Runs waiting behind it.
    pub(super) queued: usize,
    /// Whether the storage directory can take a run (runs are refused while not).
    pub(super) storage_usable: bool,
    /// When the last check that measured the camera ended (unix s), from the history too.
    pub(super) last_check_unix_s: Option<f64>,
    /// When the last accepted calibration ended (unix s), from the history too.
    pub(super) last_calibration_unix_s: Option<f64>,
}

impl Metrics {
    /// Counts a run that ended (asked for by `trigger`).
    pub(super) fn record(&mut self, trigger: Trigger, record: &RunRecord) {
        let outcome = outcome_label(record);
        match self
            .runs
            .iter_mut()
            .find(|((t, o), _)| *t == trigger && *o == outcome)
        {
            Some((_, n)) => *n += 1,
            None => self.runs.push(((trigger, outcome), 1)),
        }
        let secs = record.timings_ms.total / 1e3;
        if let Some(k) = DURATION_BUCKETS.iter().position(|le| secs <= *le) {
            self.duration_buckets[k] += 1;
        }
        self.duration_sum_s += secs;
        self.duration_count += 1;
        if let (RunMode::Calibrate, Outcome::Accepted, Some(r)) =
            (record.mode, record.outcome, &record.result)
        {
            self.last_uncertainty_mm = Some(r.uncertainty.translation_mm);
            self.last_uncertainty_deg = Some(r.uncertainty.rotation_deg);
        }
        if let (Some(drifted), Some(d)) = (record.drift_found(), &record.drift) {
            self.last_drift_mm = Some(d.translation_mm);
            self.last_drift_deg = Some(d.rotation_deg);
            if drifted {
                self.alarms += 1;
            }
        }
    }

    /// The gauges of a run the history holds (replayed oldest first at startup): the last
    /// calibration's uncertainty and the last drift survive a restart; the counters count
    /// since the start, as Prometheus expects of counters.
    pub(super) fn restore(&mut self, run: &RunSummary) {
        if let (RunMode::Calibrate, Some(Outcome::Accepted), Some(mm), Some(deg)) = (
            run.mode,
            run.outcome.outcome(),
            run.uncertainty_translation_mm,
            run.uncertainty_rotation_deg,
        ) {
            self.last_uncertainty_mm = Some(mm);
            self.last_uncertainty_deg = Some(deg);
        }
        if let (RunMode::Check, Some(Outcome::Accepted), Some(mm), Some(deg), Some(_)) = (
            run.mode,
            run.outcome.outcome(),
            run.drift_translation_mm,
            run.drift_rotation_deg,
            run.drifted,
        ) {
            self.last_drift_mm = Some(mm);
            self.last_drift_deg = Some(deg);
        }
    }

    /// The text `GET /metrics` serves.
    pub(super) fn exposition(&self, live: &Live) -> String {
        let m = self;
        let mut s = String::new();
        let _ = writeln!(
            s,
            "# HELP handeye_runs_total Calibration runs by trigger and outcome (accepted, drifted: a check beyond the thresholds, rejected, aborted, error)."
        );
        let _ = writeln!(s, "# TYPE handeye_runs_total counter");
        for ((trigger, outcome), n) in &m.runs {
            let _ = writeln!(
                s,
                "handeye_runs_total{{trigger=\"{}\",outcome=\"{outcome}\"}} {n}",
                trigger.name(),
            );
        }
        let _ = writeln!(
            s,
            "# HELP handeye_run_duration_seconds Duration of a run, start to end."
        );
        let _ = writeln!(s, "# TYPE handeye_run_duration_seconds histogram");
        let mut cumulative = 0;
        for (le, n) in DURATION_BUCKETS.iter().zip(m.duration_buckets) {
            cumulative += n;
            let _ = writeln!(
                s,
                "handeye_run_duration_seconds_bucket{{le=\"{le}\"}} {cumulative}"
            );
        }
        let _ = writeln!(
            s,
            "handeye_run_duration_seconds_bucket{{le=\"+Inf\"}} {}",
            m.duration_count
        );
        let _ = writeln!(s, "handeye_run_duration_seconds_sum {}", m.duration_sum_s);
        let _ = writeln!(s, "handeye_run_duration_seconds_count {}", m.duration_count);
        let gauge = |s: &mut String, name: &str, help: &str, v: Option<f64>| {
            let _ = writeln!(s, "# HELP {name} {help}");
            let _ = writeln!(s, "# TYPE {name} gauge");
            let _ = writeln!(s, "{name} {}", v.unwrap_or(f64::NAN));
        };
        gauge(
            &mut s,
            "handeye_last_calibration_uncertainty_mm",
            "Reported 1-sigma translation uncertainty of the last accepted calibration, mm.",
            m.last_uncertainty_mm,
        );
        gauge(
            &mut s,
            "handeye_last_calibration_uncertainty_degrees",
            "Reported 1-sigma rotation uncertainty of the last accepted calibration, degrees.",
            m.last_uncertainty_deg,
        );
        gauge(
            &mut s,
            "handeye_last_drift_mm",
            "Camera position drift found by the last check, mm.",
            m.last_drift_mm,
        );
        gauge(
            &mut s,
            "handeye_last_drift_degrees",
            "Camera rotation drift found by the last check, degrees.",
            m.last_drift_deg,
        );
        gauge(
            &mut s,
            "handeye_drift_alarm",
            "1 while the last check found drift beyond the thresholds.",
            Some(f64::from(u8::from(live.drift_alarm))),
        );
        gauge(
            &mut s,
            "handeye_last_check_timestamp_seconds",
            "Unix time the last check that measured the camera ended, s (NaN: none recorded).",
            live.last_check_unix_s,
        );
        gauge(
            &mut s,
            "handeye_last_calibration_timestamp_seconds",
            "Unix time the last accepted calibration ended, s (NaN: none recorded).",
            live.last_calibration_unix_s,
        );
        let _ = writeln!(s, "# HELP handeye_alarms_total Drift alarms raised.");
        let _ = writeln!(s, "# TYPE handeye_alarms_total counter");
        let _ = writeln!(s, "handeye_alarms_total {}", m.alarms);
        for (name, (up, reconnects)) in [("robot", live.robot), ("camera", live.camera)] {
            let _ = writeln!(
                s,
                "# HELP handeye_{name}_connected 1 when the {name} answers."
            );
            let _ = writeln!(s, "# TYPE handeye_{name}_connected gauge");
            let _ = writeln!(s, "handeye_{name}_connected {}", u8::from(up));
            let _ = writeln!(
                s,
                "# HELP handeye_{name}_reconnects_total Times the {name}'s connection was re-established."
            );
            let _ = writeln!(s, "# TYPE handeye_{name}_reconnects_total counter");
            let _ = writeln!(s, "handeye_{name}_reconnects_total {reconnects}");
        }
        let _ = writeln!(s, "# HELP handeye_busy 1 while a run is going.");
        let _ = writeln!(s, "# TYPE handeye_busy gauge");
        let _ = writeln!(s, "handeye_busy {}", u8::from(live.busy));
        let _ = writeln!(
            s,
            "# HELP handeye_queued Runs waiting behind the running one."
        );
        let _ = writeln!(s, "# TYPE handeye_queued gauge");
        let _ = writeln!(s, "handeye_queued {}", live.queued);
        let _ = writeln!(
            s,
            "# HELP handeye_storage_usable 1 while the storage directory can take a run; runs are refused at 0."
        );
        let _ = writeln!(s, "# TYPE handeye_storage_usable gauge");
        let _ = writeln!(
            s,
            "handeye_storage_usable {}",
            u8::from(live.storage_usable)
        );
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::record::DriftRecord;

    fn check(drifted: bool) -> RunRecord {
        let mut r = RunRecord::starting("r".into(), RunMode::Check, false, "cell.toml".into());
        r.outcome = Outcome::Accepted;
        r.drift = Some(DriftRecord {
            reference: "result of run q".into(),
            reference_pose: [[0.0; 4]; 4],
            translation_mm: if drifted { 2.0 } else { 0.1 },
            rotation_deg: 0.01,
            max_translation_mm: 1.0,
            max_rotation_deg: 0.2,
            drifted,
        });
        r
    }

    fn live() -> Live {
        Live {
            drift_alarm: true,
            robot: (true, 0),
            camera: (true, 0),
            busy: false,
            queued: 0,
            storage_usable: true,
            last_check_unix_s: None,
            last_calibration_unix_s: None,
        }
    }

    /// A check that found drift counts as `drifted`, apart from the checks within limits
    /// (`accepted`), so runs by outcome show drift; other runs keep their outcome.
    #[test]
    fn a_drifted_check_counts_as_drifted() {
        let mut m = Metrics::default();
        m.record(Trigger::Schedule, &check(true));
        m.record(Trigger::Schedule, &check(true));
        m.record(Trigger::Schedule, &check(false));
        let mut failed = RunRecord::starting("e".into(), RunMode::Calibrate, false, "c".into());
        failed.outcome = Outcome::Error;
        m.record(Trigger::Api, &failed);
        let text = m.exposition(&live());
        assert!(
            text.contains("handeye_runs_total{trigger=\"schedule\",outcome=\"drifted\"} 2\n"),
            "{text}"
        );
        assert!(
            text.contains("handeye_runs_total{trigger=\"schedule\",outcome=\"accepted\"} 1\n"),
            "{text}"
        );
        assert!(
            text.contains("handeye_runs_total{trigger=\"api\",outcome=\"error\"} 1\n"),
            "{text}"
        );
        assert!(text.contains("handeye_alarms_total 2\n"), "{text}");
    }
}
