//! What the daemon shows of itself: the run in progress, how runs ended, the drift a check
//! measured, and the whole status (`GET /api/status`, `handeye status`).

use serde::{Deserialize, Serialize};

use crate::calendar::unix_now;
use crate::record::{Outcome, RunMode, RunRecord, Stage, Trigger};

/// The run in progress.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Current {
    /// Its id (also in the history).
    pub run_id: String,
    /// Calibrate or check.
    pub mode: RunMode,
    /// Who asked.
    pub trigger: Trigger,
    /// Unix time it was accepted, s.
    pub since_unix_s: f64,
    /// The stage it is in.
    pub stage: Option<Stage>,
    /// The stage's last progress line.
    pub detail: String,
}

/// A run's end, as the status shows it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Finished {
    /// Its id.
    pub run_id: String,
    /// Calibrate or check.
    pub mode: RunMode,
    /// Who asked.
    pub trigger: Trigger,
    /// How it ended.
    pub outcome: Outcome,
    /// The word every view uses for it ([`RunRecord::verdict`]): a check that measured the
    /// camera is `drifted` or `within limits`, any other run its outcome.
    #[serde(default)]
    pub verdict: String,
    /// Why (empty when accepted).
    pub reasons: Vec<String>,
    /// What the operator should know whatever the outcome ([`RunRecord::warnings`]): e.g. the
    /// current calibration was made on another arm.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
    /// Unix time it ended, s.
    pub finished_unix_s: f64,
    /// The whole run, ms.
    pub duration_ms: f64,
    /// Check: the camera's change from the current calibration.
    pub drift: Option<Drift>,
}

impl Finished {
    /// How `record` (a `mode` run asked for by `trigger`) ended, as the status shows it.
    pub(super) fn of(mode: RunMode, trigger: Trigger, record: &RunRecord) -> Finished {
        Finished {
            run_id: record.run_id.clone(),
            mode,
            trigger,
            outcome: record.outcome,
            verdict: record.verdict().to_string(),
            reasons: record.reasons.clone(),
            warnings: record.warnings.clone(),
            finished_unix_s: unix_now(),
            duration_ms: record.timings_ms.total,
            drift: record.drift.as_ref().map(|d| Drift {
                translation_mm: d.translation_mm,
                rotation_deg: d.rotation_deg,
                exceeded: d.drifted,
            }),
        }
    }
}

/// A check's measured change of the camera pose from the current calibration.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Drift {
    /// Camera position change, mm.
    pub translation_mm: f64,
    /// Camera rotation change, degrees.
    pub rotation_deg: f64,
    /// Whether either of `[check]`'s thresholds is exceeded.
    pub exceeded: bool,
}

/// Whether the daemon runs something.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DaemonState {
    /// Waiting for a trigger.
    Idle,
    /// A run is going.
    Running,
    /// Shutting down.
    Stopping,
}

impl DaemonState {
    /// Lower-case name as in JSON.
    pub fn name(self) -> &'static str {
        match self {
            DaemonState::Idle => "idle",
            DaemonState::Running => "running",
            DaemonState::Stopping => "stopping",
        }
    }
}

/// What the daemon is doing: the API's `GET /api/status`, read back by `handeye status`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Status {
    /// `idle`, `running` or `stopping`.
    pub state: DaemonState,
    /// The run in progress.
    pub current: Option<Current>,
    /// Runs accepted behind it (`daemon.when_busy = "queue"`), next first.
    pub queued: Vec<Current>,
    /// The last run that ended.
    pub last: Option<Finished>,
    /// The last calibrate run that was accepted.
    pub last_calibration: Option<Finished>,
    /// The last check run that measured a drift.
    pub last_check: Option<Finished>,
    /// Whether the last check found drift (an alarm until a run clears it).
    pub drift_alarm: bool,
    /// Whether the robot answered its last status request.
    pub robot_connected: bool,
    /// Whether the camera answered its last request.
    pub camera_connected: bool,
    /// How often the robot's connection was re-established since the daemon started.
    pub robot_reconnects: u64,
    /// How often the camera's connection was re-established since the daemon started.
    pub camera_reconnects: u64,
    /// Unix time the daemon started, s.
    pub started_unix_s: f64,
    /// Why the storage directory cannot take a run (full, read-only); runs are refused
    /// until it can. `None`: it can.
    #[serde(default)]
    pub storage_problem: Option<String>,
    /// The damaged history file set aside when the daemon started (a new history was
    /// rebuilt from the run folders).
    #[serde(default)]
    pub history_set_aside: Option<crate::store::SetAside>,
    /// While the daemon has not reached the robot or the camera yet: what it waits for
    /// (`waiting for robot at 192.168.0.10 (attempt 4, next in 8 s): …`); runs are refused.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub waiting: Option<String>,
}
