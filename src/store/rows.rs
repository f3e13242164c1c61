//! What the history holds of a run: its start, where it stands, its summary row (and how a
//! row is read), the partial run without a record, and the digest of its configuration.

use serde::{Deserialize, Serialize};

use crate::record::{Outcome, RunMode, RunRecord, Stage, Trigger, WriteTarget};

/// A run that started ([`Store::begin`](super::Store::begin)): the row's first columns,
/// copied from the run's starting record ([`RunStart::new`]).
#[derive(Debug, Clone, PartialEq)]
pub struct RunStart {
    /// Its id ([`crate::storage::new_run_id`]); also its folder under `runs/`.
    pub run_id: String,
    /// Who asked.
    pub trigger: Trigger,
    /// Calibrate or check.
    pub mode: RunMode,
    /// Where the configuration came from (its file path).
    pub config_origin: String,
    /// [`config_digest`] of the configuration, to tell which runs used the same settings.
    pub config_digest: String,
    /// Unix time of the start, s.
    pub started_unix_s: f64,
}

impl RunStart {
    /// The start of the run `record` (as [`RunRecord::starting`] made it), asked for by
    /// `trigger`, with the [`config_digest`] of its configuration.
    pub fn new(record: &RunRecord, trigger: Trigger, config_digest: String) -> Self {
        Self {
            run_id: record.run_id.clone(),
            trigger,
            mode: record.mode,
            config_origin: record.config.clone(),
            config_digest,
            started_unix_s: record.started_unix_s,
        }
    }
}

/// Where a run stands: still running, or ended with an outcome. Serialised as one string
/// (`running`, `accepted`, `rejected`, `aborted`, `error`, `planned`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RunStatus {
    /// Begun, not finished (yet).
    Running,
    /// Finished (or recovered as aborted).
    Ended(Outcome),
}

impl RunStatus {
    /// The stored name.
    pub fn name(self) -> &'static str {
        match self {
            RunStatus::Running => "running",
            RunStatus::Ended(o) => o.name(),
        }
    }

    /// The outcome, once ended.
    pub fn outcome(self) -> Option<Outcome> {
        match self {
            RunStatus::Running => None,
            RunStatus::Ended(o) => Some(o),
        }
    }

    /// The status of a stored name.
    pub fn parse(name: &str) -> Option<RunStatus> {
        Some(match name {
            "running" => RunStatus::Running,
            "accepted" => RunStatus::Ended(Outcome::Accepted),
            "rejected" => RunStatus::Ended(Outcome::Rejected),
            "aborted" => RunStatus::Ended(Outcome::Aborted),
            "error" => RunStatus::Ended(Outcome::Error),
            "planned" => RunStatus::Ended(Outcome::Planned),
            _ => return None,
        })
    }
}

impl std::fmt::Display for RunStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl Serialize for RunStatus {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

impl<'de> Deserialize<'de> for RunStatus {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let name = String::deserialize(d)?;
        RunStatus::parse(&name)
            .ok_or_else(|| serde::de::Error::custom(format!("unknown run status `{name}`")))
    }
}

/// One run as the history holds it (`GET /api/runs/{id}`, `handeye history show`).
/// Serialised as the record itself, or as the partial object with `"complete": false`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum StoredRun {
    /// It ended: its whole record.
    Complete(Box<RunRecord>),
    /// Still running, or interrupted before it ended: what is known of it.
    Partial(PartialRun),
}

/// What the history knows of a run that has no record (yet).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PartialRun {
    /// Its id.
    pub run_id: String,
    /// Calibrate or check.
    pub mode: RunMode,
    /// Who asked.
    pub trigger: Trigger,
    /// The configuration's origin (file path).
    pub config: String,
    /// Unix time of the start, s.
    pub started_unix_s: f64,
    /// `running`, or `aborted` when it was interrupted.
    pub outcome: RunStatus,
    /// Why (the interruption), when known.
    pub reasons: Vec<String>,
    /// Always `false`: no record.
    pub complete: bool,
}

/// One run in a list: the indexed columns, without the full record.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunSummary {
    /// Its id.
    pub run_id: String,
    /// Who asked.
    pub trigger: Trigger,
    /// Calibrate or check.
    pub mode: RunMode,
    /// `running`, or how it ended.
    pub outcome: RunStatus,
    /// Unix time of the start, s.
    pub started_unix_s: f64,
    /// Unix time it was recorded as ended, s (`None` while running or when interrupted).
    pub finished_unix_s: Option<f64>,
    /// The run's own total time, ms.
    pub duration_ms: Option<f64>,
    /// The stage that failed (aborted/error).
    pub failed_stage: Option<Stage>,
    /// The first reason (all of them are in the record).
    pub reason: Option<String>,
    /// The configuration's origin (file path).
    pub config_origin: String,
    /// [`config_digest`] of the configuration, when the caller gave one.
    pub config_digest: Option<String>,
    /// The result, when one was computed (also when rejected): the unknown
    /// (`flange_from_camera` or `base_from_camera`) as UR `x,y,z,rx,ry,rz` (m, rotation
    /// vector rad).
    pub ur_pose: Option<[f64; 6]>,
    /// The result's 1-σ position uncertainty, mm.
    pub uncertainty_translation_mm: Option<f64>,
    /// The result's 1-σ rotation uncertainty, degrees.
    pub uncertainty_rotation_deg: Option<f64>,
    /// Check: camera position change from the current calibration, mm.
    pub drift_translation_mm: Option<f64>,
    /// Check: camera rotation change from the current calibration, degrees.
    pub drift_rotation_deg: Option<f64>,
    /// Check: whether a drift threshold was exceeded.
    pub drifted: Option<bool>,
    /// What was written back (`tcp`, `registers`, `files`), in order.
    pub written: Vec<WriteTarget>,
    /// The run's capture file (`capture.json`, for `handeye solve --capture`).
    pub capture_file: Option<String>,
    /// When the raw scans were removed ([`Store::mark_pruned`](super::Store::mark_pruned)),
    /// unix s (replay is then impossible; the record stays).
    pub captures_pruned_unix_s: Option<f64>,
}

impl RunSummary {
    /// [`crate::record::RunRecord::drift_found`] of the run, from the columns the history
    /// keeps.
    pub fn drift_found(&self) -> Option<bool> {
        crate::record::drift_found(self.mode, self.outcome.outcome(), self.drifted)
    }

    /// [`crate::record::RunRecord::verdict`] of the run (`running` while it runs).
    pub fn verdict(&self) -> &'static str {
        match self.outcome.outcome() {
            Some(o) => crate::record::verdict(o, self.drift_found()),
            None => self.outcome.name(),
        }
    }
}

/// A stable 64-bit FNV-1a hash of a configuration's text, as 16 hex digits: it tells which
/// runs used the same configuration. It identifies; it does not secure (anyone can make
/// another text with the same digest).
pub fn config_digest(text: &str) -> String {
    let hash = text.bytes().fold(0xcbf2_9ce4_8422_2325_u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    });
    format!("{hash:016x}")
}

/// The summary columns, in the order [`summary_from_row`] reads them.
pub(super) const SUMMARY_COLUMNS: &str =
    "run_id, trigger, mode, outcome, started_unix_s, finished_unix_s,
    duration_ms, failed_stage, reason, config_origin, config_digest, result_x_m, result_y_m,
    result_z_m, result_rx_rad, result_ry_rad, result_rz_rad, uncertainty_translation_mm,
    uncertainty_rotation_deg, drift_translation_mm, drift_rotation_deg, drifted, written,
    capture_file, captures_pruned_unix_s";

pub(super) fn summary_from_row(r: &rusqlite::Row<'_>) -> rusqlite::Result<RunSummary> {
    let bad = |i: usize, what: String| {
        rusqlite::Error::FromSqlConversionFailure(i, rusqlite::types::Type::Text, what.into())
    };
    let trigger: String = r.get(1)?;
    let trigger =
        Trigger::parse(&trigger).ok_or_else(|| bad(1, format!("unknown trigger `{trigger}`")))?;
    let mode: String = r.get(2)?;
    let mode = RunMode::parse(&mode).ok_or_else(|| bad(2, format!("unknown mode `{mode}`")))?;
    let failed_stage: Option<String> = r.get(7)?;
    let failed_stage = match failed_stage {
        Some(name) => {
            Some(Stage::parse(&name).ok_or_else(|| bad(7, format!("unknown stage `{name}`")))?)
        }
        None => None,
    };
    let outcome: String = r.get(3)?;
    let outcome =
        RunStatus::parse(&outcome).ok_or_else(|| bad(3, format!("unknown outcome `{outcome}`")))?;
    let pose: [Option<f64>; 6] = [
        r.get(11)?,
        r.get(12)?,
        r.get(13)?,
        r.get(14)?,
        r.get(15)?,
        r.get(16)?,
    ];
    let ur_pose = match pose {
        [Some(x), Some(y), Some(z), Some(rx), Some(ry), Some(rz)] => Some([x, y, z, rx, ry, rz]),
        _ => None,
    };
    let written: Option<String> = r.get(22)?;
    let written = match written {
        Some(text) => serde_json::from_str(&text).map_err(|e| bad(22, e.to_string()))?,
        None => Vec::new(),
    };
    Ok(RunSummary {
        run_id: r.get(0)?,
        trigger,
        mode,
        outcome,
        started_unix_s: r.get(4)?,
        finished_unix_s: r.get(5)?,
        duration_ms: r.get(6)?,
        failed_stage,
        reason: r.get(8)?,
        config_origin: r.get(9)?,
        config_digest: r.get(10)?,
        ur_pose,
        uncertainty_translation_mm: r.get(17)?,
        uncertainty_rotation_deg: r.get(18)?,
        drift_translation_mm: r.get(19)?,
        drift_rotation_deg: r.get(20)?,
        drifted: r.get(21)?,
        written,
        capture_file: r.get(23)?,
        captures_pruned_unix_s: r.get(24)?,
    })
}
