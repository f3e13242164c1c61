//! The history of every run, in one SQLite file (`<storage.dir>/history.sqlite`).
//!
//! A run is inserted as `running` when it starts ([`Store::begin`]) and completed when it ends
//! ([`Store::finish`]), so a crash, a power loss or a `kill -9` in between leaves a trace: the
//! next [`Store::open`] marks every run still `running` as `aborted` with
//! [`INTERRUPTED_REASON`]. Each finished run keeps its whole [`RunRecord`] as JSON, plus the
//! columns that lists and queries need (outcome, result, uncertainty, drift, what was written).
//!
//! Durability: the database runs in WAL mode (readers never block the writer, so `handeye
//! history` can read while the daemon writes) with `synchronous=FULL`: every commit is on disk
//! before `begin`/`finish` return. `NORMAL` would also never corrupt the file, but a power loss
//! could roll back the last commits — the record of a calibration that was already written to
//! the controller. Runs are seconds long and minutes apart, so the one fsync per commit costs
//! nothing that matters.
//!
//! Several processes may open the same file. Writers ([`Store::open`]) hold a shared advisory
//! lock on `history.sqlite-lock` for as long as they live; only a writer that finds no other
//! one alive (the exclusive lock is free) recovers interrupted runs, so a second process never
//! marks the daemon's run in progress as aborted. The operating system drops the lock of a
//! process that dies, however it dies.
//!
//! The schema has a version table and numbered migrations (version 1 now); a file newer than
//! this program is refused rather than misread.

use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard};
use std::time::Duration;

use rusqlite::{params, Connection, ErrorCode, OpenFlags, OptionalExtension, TransactionBehavior};
use serde::{Deserialize, Serialize};

use crate::calendar::unix_now;
use crate::record::{Outcome, RunMode, RunRecord, Stage, Trigger, WriteTarget};

#[cfg(test)]
mod tests;
mod writer_lock;

use writer_lock::{no_links, WriterLock};

/// File name of the history database in the storage directory.
pub const HISTORY_FILE: &str = "history.sqlite";
/// Why a run that was still `running` when the store was opened again is `aborted`.
pub const INTERRUPTED_REASON: &str =
    "interrupted: the program stopped during the run (crash, power loss or kill)";
/// Why a run still `running` at the next open is `aborted` when the process that ran it lived
/// on and could not record its end.
pub const UNRECORDED_REASON: &str = "its end could not be recorded: the storage was full or \
     could not be written when the run ended (the program lived on; its log has the outcome)";
/// The schema version this program writes and reads.
pub const SCHEMA_VERSION: i64 = 1;
/// How long a statement waits for another process's write lock before giving up.
const BUSY_TIMEOUT: Duration = Duration::from_secs(5);

/// Migration `n` (1-based) brings the schema from version `n - 1` to `n`; each runs in the
/// same transaction as the version row it adds.
const MIGRATIONS: &[&str] = &[
    // 1: the runs table. Times are unix seconds (UTC); `outcome` is `running` until the run
    // ends, then an `Outcome` name. The result is the unknown as UR x,y,z (m), rx,ry,rz (rad).
    "CREATE TABLE runs (
        run_id TEXT PRIMARY KEY NOT NULL,
        trigger TEXT NOT NULL,
        mode TEXT NOT NULL,
        outcome TEXT NOT NULL,
        started_unix_s REAL NOT NULL,
        finished_unix_s REAL,
        duration_ms REAL,
        failed_stage TEXT,
        reason TEXT,
        config_origin TEXT NOT NULL,
        config_digest TEXT,
        result_x_m REAL,
        result_y_m REAL,
        result_z_m REAL,
        result_rx_rad REAL,
        result_ry_rad REAL,
        result_rz_rad REAL,
        uncertainty_translation_mm REAL,
        uncertainty_rotation_deg REAL,
        drift_translation_mm REAL,
        drift_rotation_deg REAL,
        drifted INTEGER,
        written TEXT,
        capture_file TEXT,
        captures_pruned_unix_s REAL,
        record_json TEXT
    );
    CREATE INDEX runs_started ON runs (started_unix_s);
    CREATE INDEX runs_outcome ON runs (outcome, started_unix_s);",
];

/// What can go wrong with the history; each message says what to do.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StoreError {
    /// There is no history database (read-only open).
    #[error("no history yet at {}: the daemon (or calibrate with history) writes it", .path.display())]
    NoHistory {
        /// The database path.
        path: PathBuf,
    },
    /// A file or folder could not be created, opened or removed.
    #[error("cannot {action} {}: {source}; check that the storage directory (`[storage] dir`) exists and is writable by this user", .path.display())]
    Io {
        /// What was attempted (`create the folder`, `remove`, …).
        action: &'static str,
        /// The file or folder.
        path: PathBuf,
        /// The operating system's error.
        #[source]
        source: std::io::Error,
    },
    /// A link stands where the history, or a file SQLite keeps beside it, belongs.
    #[error("{} is a symbolic link; the history is never opened through one (a write would land elsewhere): remove the link", .path.display())]
    Link {
        /// The link.
        path: PathBuf,
    },
    /// SQLite cannot open the file.
    #[error("cannot open the history database {}: {source}; check the permissions of the file and its folder (SQLite also needs to create {}-wal and -shm beside it)", .path.display(), .path.display())]
    Open {
        /// The database path.
        path: PathBuf,
        /// SQLite's error.
        #[source]
        source: rusqlite::Error,
    },
    /// The file is not a SQLite database, or is damaged.
    #[error("{} is corrupted or not a handeye history database ({source}); the daemon or `handeye calibrate` sets it aside when it starts and rebuilds the history from runs/<run_id>/record.json", .path.display())]
    Corrupt {
        /// The database path.
        path: PathBuf,
        /// SQLite's error.
        #[source]
        source: rusqlite::Error,
    },
    /// A SQLite database, but someone else's.
    #[error("{} is a SQLite database without handeye's history tables; point `[storage] dir` elsewhere or move the file aside", .path.display())]
    Foreign {
        /// The database path.
        path: PathBuf,
    },
    /// Written by a newer handeye.
    #[error("the history database {} is newer than this program (schema version {found}, this program knows up to {supported}); upgrade handeye, or move the file aside to start a new history", .path.display())]
    TooNew {
        /// The database path.
        path: PathBuf,
        /// The file's schema version.
        found: i64,
        /// The newest version this program knows.
        supported: i64,
    },
    /// Read-only open of a file that needs a migration first.
    #[error("the history database {} has schema version {found} and this program needs {supported}; start the daemon (or any command that writes history) once to upgrade it", .path.display())]
    NeedsUpgrade {
        /// The database path.
        path: PathBuf,
        /// The file's schema version.
        found: i64,
        /// The version this program needs.
        supported: i64,
    },
    /// Another process held the write lock for longer than the busy timeout.
    #[error("the history database {} stayed locked by another process for {} s; retry, and check no process is stuck holding it", .path.display(), BUSY_TIMEOUT.as_secs())]
    Busy {
        /// The database path.
        path: PathBuf,
        /// SQLite's error.
        #[source]
        source: rusqlite::Error,
    },
    /// A write to a store opened read-only, or to a file this user cannot write.
    #[error("cannot write the history database {}: it was opened read-only, or this user cannot write it or its folder (check the permissions of the file, its -wal and -shm files and the folder)", .path.display())]
    ReadOnly {
        /// The database path.
        path: PathBuf,
    },
    /// The disk is full.
    #[error("cannot write the history database {}: the disk is full; free some space (old raw captures under runs/ can go)", .path.display())]
    DiskFull {
        /// The database path.
        path: PathBuf,
    },
    /// `begin` with a run id that is already in the history.
    #[error("run {run_id} is already in the history; every run needs a new id (handeye::run::new_run_id)")]
    DuplicateRun {
        /// The run id.
        run_id: String,
    },
    /// A stored record is not valid JSON.
    #[error("the stored record of run {run_id} is not valid JSON ({source}); the file runs/{run_id}/record.json holds the same record")]
    BadRecord {
        /// The run id.
        run_id: String,
        /// The parser's error.
        #[source]
        source: serde_json::Error,
    },
    /// A record could not be turned into JSON (a non-finite number where JSON needs one).
    #[error("cannot store the record of run {run_id} as JSON: {source}")]
    Serialize {
        /// The run id.
        run_id: String,
        /// The serialiser's error.
        #[source]
        source: serde_json::Error,
    },
    /// Any other SQLite error.
    #[error("history database {}: cannot {action}: {source}", .path.display())]
    Sqlite {
        /// The database path.
        path: PathBuf,
        /// What was attempted.
        action: &'static str,
        /// SQLite's error.
        #[source]
        source: rusqlite::Error,
    },
}

/// A run that started ([`Store::begin`]): the row's first columns, copied from the run's
/// starting record ([`RunStart::new`]).
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
    /// When the raw scans were removed ([`Store::mark_pruned`]), unix s (replay is then
    /// impossible; the record stays).
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

/// A damaged history file that [`Store::open`] moved aside (kept, never deleted) before it
/// started a new one.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SetAside {
    /// Where the damaged file is now (its -wal and -shm files beside it, same name + suffix).
    pub path: PathBuf,
    /// What was wrong (SQLite's `quick_check`, or an empty file).
    pub why: String,
}

/// The history database. `Send + Sync`; share it with an `Arc`. Every call blocks for the
/// duration of one SQLite statement (with one fsync per write), at most 5 s (`BUSY_TIMEOUT`)
/// more while another process writes.
#[derive(Debug)]
pub struct Store {
    conn: Mutex<Connection>,
    path: PathBuf,
    read_only: bool,
    /// Writers hold a shared lock on `<path>-lock` while they live (see the module docs).
    _writer_lock: Option<File>,
    /// The damaged file this open moved aside.
    set_aside: Option<SetAside>,
    /// Whether this open created the tables (a new or empty file).
    created: bool,
    /// Whether this open found no other writer alive (and so recovered interrupted runs).
    sole_writer: bool,
}

impl Store {
    /// Opens (creating folders and file as needed) the history for writing: WAL,
    /// `synchronous=FULL`, migrations to [`SCHEMA_VERSION`]; when no other writer is alive,
    /// every run still `running` becomes `aborted` with [`INTERRUPTED_REASON`].
    pub fn open(path: &Path) -> Result<Store, StoreError> {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|source| StoreError::Io {
                action: "create the folder",
                path: dir.to_path_buf(),
                source,
            })?;
        }
        let lock = WriterLock::acquire(path)?;
        no_links(path)?;
        // Only the sole writer may move the file: another one is using it.
        let set_aside = match damage(path).filter(|_| lock.sole) {
            Some(why) => Some(set_aside(path, why)?),
            None => None,
        };
        let mut conn = Connection::open(path).map_err(|e| sql_error(path, "open", e))?;
        configure(&conn, path, false)?;
        let created = schema_version(&conn, path)?.is_none();
        migrate(&mut conn, path)?;
        let store = Store {
            conn: Mutex::new(conn),
            path: path.to_path_buf(),
            read_only: false,
            _writer_lock: None,
            set_aside,
            created,
            sole_writer: lock.sole,
        };
        let file = if lock.sole {
            let n = store.recover_interrupted()?;
            if n > 0 {
                tracing::warn!(
                    runs = n,
                    "{n} run(s) were still running when the program stopped; recorded as aborted"
                );
            }
            lock.share(path)?
        } else {
            tracing::info!(
                "another process writes {} too; leaving its runs in progress alone",
                path.display()
            );
            lock.file
        };
        Ok(Store {
            _writer_lock: Some(file),
            ..store
        })
    }

    /// Opens an existing history for reading only (the CLI): no migration, no recovery. A
    /// missing file is [`StoreError::NoHistory`].
    pub fn open_read_only(path: &Path) -> Result<Store, StoreError> {
        if !path.is_file() {
            return Err(StoreError::NoHistory {
                path: path.to_path_buf(),
            });
        }
        no_links(path)?;
        let flags = OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX;
        let conn =
            Connection::open_with_flags(path, flags).map_err(|e| sql_error(path, "open", e))?;
        configure(&conn, path, true)?;
        match schema_version(&conn, path)? {
            None => Err(StoreError::NoHistory {
                path: path.to_path_buf(),
            }),
            Some(v) if v > SCHEMA_VERSION => Err(StoreError::TooNew {
                path: path.to_path_buf(),
                found: v,
                supported: SCHEMA_VERSION,
            }),
            Some(v) if v < SCHEMA_VERSION => Err(StoreError::NeedsUpgrade {
                path: path.to_path_buf(),
                found: v,
                supported: SCHEMA_VERSION,
            }),
            Some(_) => Ok(Store {
                conn: Mutex::new(conn),
                path: path.to_path_buf(),
                read_only: true,
                _writer_lock: None,
                set_aside: None,
                created: false,
                sole_writer: false,
            }),
        }
    }

    /// The database file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The damaged file [`Store::open`] moved aside, if it did.
    pub fn set_aside(&self) -> Option<&SetAside> {
        self.set_aside.as_ref()
    }

    /// Whether [`Store::open`] found no other writer alive: no other process writes the
    /// storage folder now, so what a killed one left there may go.
    pub fn is_sole_writer(&self) -> bool {
        self.sole_writer
    }

    /// Whether [`Store::open`] started this history (no file, an empty one, or a damaged one
    /// set aside): the runs in the storage folder are not in it yet ([`Self::rebuild`]).
    pub fn is_new(&self) -> bool {
        self.created
    }

    /// Adds the runs of `records` that are not in the history yet (a new history rebuilt
    /// from the run folders' `record.json`); a record without its trigger is recorded as
    /// `cli`. Returns how many were added.
    pub fn rebuild(&self, records: &[RunRecord]) -> Result<usize, StoreError> {
        let mut added = 0;
        for record in records {
            if self.summary(&record.run_id)?.is_some() {
                continue;
            }
            self.finish(record.trigger.unwrap_or(Trigger::Cli), record)?;
            added += 1;
        }
        Ok(added)
    }

    /// Records that a run started, as `running`.
    pub fn begin(&self, run: &RunStart) -> Result<(), StoreError> {
        let conn = self.writable()?;
        let result = conn.execute(
            "INSERT INTO runs (run_id, trigger, mode, outcome, started_unix_s, config_origin,
                               config_digest)
             VALUES (?1, ?2, ?3, 'running', ?4, ?5, ?6)",
            params![
                run.run_id,
                run.trigger.name(),
                run.mode.name(),
                run.started_unix_s,
                run.config_origin,
                run.config_digest,
            ],
        );
        match result {
            Ok(_) => Ok(()),
            Err(e) if e.sqlite_error_code() == Some(ErrorCode::ConstraintViolation) => {
                Err(StoreError::DuplicateRun {
                    run_id: run.run_id.clone(),
                })
            }
            Err(e) => Err(sql_error(&self.path, "record the start of a run", e)),
        }
    }

    /// Records how a run ended: the whole record as JSON plus the indexed columns. A run
    /// that was never begun is inserted; one that was recovered as interrupted is completed
    /// (the real outcome wins). The start time and configuration given to `begin` are kept.
    pub fn finish(&self, trigger: Trigger, record: &RunRecord) -> Result<(), StoreError> {
        let json = serde_json::to_string(record).map_err(|source| StoreError::Serialize {
            run_id: record.run_id.clone(),
            source,
        })?;
        let written: Vec<&str> = record.written.iter().map(|w| w.target.name()).collect();
        let written = serde_json::to_string(&written).unwrap_or_else(|_| "[]".into());
        let pose = record.result.as_ref().map(|r| r.ur_pose);
        let pose = |i: usize| pose.map(|p| p[i]);
        let unc = record.result.as_ref().map(|r| r.uncertainty);
        let drift = record.drift.as_ref();
        let conn = self.writable()?;
        conn.execute(
            "INSERT INTO runs (run_id, trigger, mode, outcome, started_unix_s, finished_unix_s,
                duration_ms, failed_stage, reason, config_origin, result_x_m, result_y_m,
                result_z_m, result_rx_rad, result_ry_rad, result_rz_rad,
                uncertainty_translation_mm, uncertainty_rotation_deg, drift_translation_mm,
                drift_rotation_deg, drifted, written, capture_file, record_json)
             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16, ?17,
                ?18, ?19, ?20, ?21, ?22, ?23, ?24)
             ON CONFLICT (run_id) DO UPDATE SET
                trigger = excluded.trigger, mode = excluded.mode, outcome = excluded.outcome,
                finished_unix_s = excluded.finished_unix_s, duration_ms = excluded.duration_ms,
                failed_stage = excluded.failed_stage, reason = excluded.reason,
                result_x_m = excluded.result_x_m, result_y_m = excluded.result_y_m,
                result_z_m = excluded.result_z_m, result_rx_rad = excluded.result_rx_rad,
                result_ry_rad = excluded.result_ry_rad, result_rz_rad = excluded.result_rz_rad,
                uncertainty_translation_mm = excluded.uncertainty_translation_mm,
                uncertainty_rotation_deg = excluded.uncertainty_rotation_deg,
                drift_translation_mm = excluded.drift_translation_mm,
                drift_rotation_deg = excluded.drift_rotation_deg, drifted = excluded.drifted,
                written = excluded.written, capture_file = excluded.capture_file,
                record_json = excluded.record_json",
            params![
                record.run_id,
                trigger.name(),
                record.mode.name(),
                record.outcome.name(),
                record.started_unix_s,
                unix_now(),
                finite(record.timings_ms.total),
                record.failed_stage.map(|s| s.name()),
                record.reasons.first(),
                record.config,
                pose(0),
                pose(1),
                pose(2),
                pose(3),
                pose(4),
                pose(5),
                unc.map(|u| u.translation_mm).and_then(finite),
                unc.map(|u| u.rotation_deg).and_then(finite),
                drift.map(|d| d.translation_mm).and_then(finite),
                drift.map(|d| d.rotation_deg).and_then(finite),
                drift.map(|d| d.drifted),
                written,
                record.capture_file,
                json,
            ],
        )
        .map_err(|e| sql_error(&self.path, "record the end of a run", e))?;
        Ok(())
    }

    /// Up to `limit` runs, newest first; with `before_unix_s`, only runs started before it
    /// (pass the last one's `started_unix_s` to page on). Newest by the history's sequence
    /// (the rowid: rows are only ever added, in the order runs begin, and the table is never
    /// vacuumed), not by the clock, which may have been set wrong or stepped since.
    pub fn list(
        &self,
        limit: usize,
        before_unix_s: Option<f64>,
    ) -> Result<Vec<RunSummary>, StoreError> {
        let limit = i64::try_from(limit).unwrap_or(i64::MAX);
        let conn = self.lock();
        let sql = format!(
            "SELECT {SUMMARY_COLUMNS} FROM runs WHERE (?2 IS NULL OR started_unix_s < ?2)
             ORDER BY rowid DESC LIMIT ?1"
        );
        let run = || -> rusqlite::Result<Vec<RunSummary>> {
            let mut stmt = conn.prepare_cached(&sql)?;
            let rows = stmt.query_map(params![limit, before_unix_s], summary_from_row)?;
            let mut out = Vec::new();
            for row in rows {
                match row {
                    Ok(summary) => out.push(summary),
                    // SQLite itself failed (a damaged page): the list cannot go on.
                    Err(e @ rusqlite::Error::SqliteFailure(..)) => return Err(e),
                    // One row that does not read back (a value this program does not know):
                    // skipped, the others listed.
                    Err(e) => tracing::warn!(
                        "skipping a run in {} that does not read back: {e}",
                        self.path.display()
                    ),
                }
            }
            Ok(out)
        };
        run().map_err(|e| sql_error(&self.path, "list runs", e))
    }

    /// The summary of one run.
    pub fn summary(&self, run_id: &str) -> Result<Option<RunSummary>, StoreError> {
        let conn = self.lock();
        let sql = format!("SELECT {SUMMARY_COLUMNS} FROM runs WHERE run_id = ?1");
        conn.query_row(&sql, [run_id], summary_from_row)
            .optional()
            .map_err(|e| sql_error(&self.path, "read a run", e))
    }

    /// One run: its whole record once it ended; a run without a record (still running, or
    /// interrupted) gives what is known ([`PartialRun`]). Numbers are as serde_json parses
    /// them back (long decimals within 1 ulp).
    pub fn get(&self, run_id: &str) -> Result<Option<StoredRun>, StoreError> {
        let row = {
            let conn = self.lock();
            conn.query_row(
                "SELECT record_json, mode, trigger, config_origin, started_unix_s, outcome, reason
                 FROM runs WHERE run_id = ?1",
                [run_id],
                |r| {
                    Ok((
                        r.get::<_, Option<String>>(0)?,
                        r.get::<_, String>(1)?,
                        r.get::<_, String>(2)?,
                        r.get::<_, String>(3)?,
                        r.get::<_, f64>(4)?,
                        r.get::<_, String>(5)?,
                        r.get::<_, Option<String>>(6)?,
                    ))
                },
            )
            .optional()
            .map_err(|e| sql_error(&self.path, "read a run", e))?
        };
        let Some((json, mode, trigger, config, started, outcome, reason)) = row else {
            return Ok(None);
        };
        let bad = |what: String| StoreError::BadRecord {
            run_id: run_id.to_string(),
            source: serde::de::Error::custom(what),
        };
        match json {
            Some(json) => serde_json::from_str(&json)
                .map(|r| Some(StoredRun::Complete(Box::new(r))))
                .map_err(|source| StoreError::BadRecord {
                    run_id: run_id.to_string(),
                    source,
                }),
            None => Ok(Some(StoredRun::Partial(PartialRun {
                run_id: run_id.to_string(),
                mode: RunMode::parse(&mode).ok_or_else(|| bad(format!("unknown mode `{mode}`")))?,
                trigger: Trigger::parse(&trigger)
                    .ok_or_else(|| bad(format!("unknown trigger `{trigger}`")))?,
                config,
                started_unix_s: started,
                outcome: RunStatus::parse(&outcome)
                    .ok_or_else(|| bad(format!("unknown outcome `{outcome}`")))?,
                reasons: reason.into_iter().collect(),
                complete: false,
            }))),
        }
    }

    /// The newest run by the history's sequence (see [`Store::list`]), optionally of one mode
    /// and/or with one outcome. Its dates do not decide: a run made while the clock was a day
    /// or ten years wrong is the latest until a later one is begun.
    pub fn latest(
        &self,
        mode: Option<RunMode>,
        outcome: Option<Outcome>,
    ) -> Result<Option<RunSummary>, StoreError> {
        let conn = self.lock();
        let sql = format!(
            "SELECT {SUMMARY_COLUMNS} FROM runs
             WHERE (?1 IS NULL OR mode = ?1) AND (?2 IS NULL OR outcome = ?2)
             ORDER BY rowid DESC LIMIT 1"
        );
        conn.query_row(
            &sql,
            params![mode.map(RunMode::name), outcome.map(Outcome::name)],
            summary_from_row,
        )
        .optional()
        .map_err(|e| sql_error(&self.path, "find the latest run", e))
    }

    /// The runs whose raw scans may go: beyond the newest `keep_runs` and started more than
    /// `keep_days` ago, ended, not pruned yet; oldest last. The files are the run folder's
    /// ([`crate::storage::remove_raw_captures`]); [`Self::mark_pruned`] notes it.
    pub fn captures_to_prune(
        &self,
        keep_runs: usize,
        keep_days: f64,
    ) -> Result<Vec<String>, StoreError> {
        if self.read_only {
            return Err(StoreError::ReadOnly {
                path: self.path.clone(),
            });
        }
        let cutoff = unix_now() - keep_days * 86_400.0;
        let conn = self.lock();
        let run = || -> rusqlite::Result<Vec<String>> {
            let mut stmt = conn.prepare(
                "SELECT run_id, started_unix_s, outcome, captures_pruned_unix_s FROM runs
                 ORDER BY rowid DESC",
            )?;
            let rows = stmt.query_map([], |r| {
                Ok((
                    r.get::<_, String>(0)?,
                    r.get::<_, f64>(1)?,
                    r.get::<_, String>(2)?,
                    r.get::<_, Option<f64>>(3)?,
                ))
            })?;
            let mut out = Vec::new();
            for (i, row) in rows.enumerate() {
                let (id, started, outcome, pruned) = row?;
                if i >= keep_runs && started < cutoff && outcome != "running" && pruned.is_none() {
                    out.push(id);
                }
            }
            Ok(out)
        };
        run().map_err(|e| sql_error(&self.path, "find old captures", e))
    }

    /// Notes that run `run_id`'s raw scans were removed (replay is then impossible).
    pub fn mark_pruned(&self, run_id: &str) -> Result<(), StoreError> {
        self.writable()?
            .execute(
                "UPDATE runs SET captures_pruned_unix_s = ?2 WHERE run_id = ?1",
                params![run_id, unix_now()],
            )
            .map_err(|e| sql_error(&self.path, "note pruned captures", e))?;
        Ok(())
    }

    /// Marks every run still `running` as `aborted`, with [`UNRECORDED_REASON`] when its
    /// process lived on ([`crate::storage::run_unrecorded`]), else [`INTERRUPTED_REASON`];
    /// returns how many.
    fn recover_interrupted(&self) -> Result<usize, StoreError> {
        let storage = self.path.parent().unwrap_or(Path::new("."));
        let conn = self.writable()?;
        let run = || -> rusqlite::Result<usize> {
            let mut stmt = conn.prepare("SELECT run_id FROM runs WHERE outcome = 'running'")?;
            let ids = stmt.query_map([], |r| r.get::<_, String>(0))?;
            let ids = ids.collect::<rusqlite::Result<Vec<String>>>()?;
            for id in &ids {
                let why = match crate::storage::run_unrecorded(storage, id) {
                    true => UNRECORDED_REASON,
                    false => INTERRUPTED_REASON,
                };
                conn.execute(
                    "UPDATE runs SET outcome = 'aborted', reason = ?2 WHERE run_id = ?1",
                    params![id, why],
                )?;
            }
            Ok(ids.len())
        };
        run().map_err(|e| sql_error(&self.path, "recover interrupted runs", e))
    }

    fn lock(&self) -> MutexGuard<'_, Connection> {
        // A panic while holding the lock leaves the connection usable: statements are
        // atomic and an open transaction rolls back when it is dropped.
        self.conn.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn writable(&self) -> Result<MutexGuard<'_, Connection>, StoreError> {
        if self.read_only {
            return Err(StoreError::ReadOnly {
                path: self.path.clone(),
            });
        }
        Ok(self.lock())
    }
}

/// What is wrong with the history file at `path`, if anything: empty (0 bytes: SQLite would
/// silently start a new history), not a database, or pages that SQLite's `quick_check` finds
/// damaged. `None` also when the file is missing or cannot be opened for another reason (the
/// open that follows says why).
fn damage(path: &Path) -> Option<String> {
    let meta = std::fs::metadata(path).ok()?;
    if meta.len() == 0 {
        return Some("the file is empty (0 bytes)".into());
    }
    let corrupt = |e: &rusqlite::Error| {
        matches!(
            e.sqlite_error_code(),
            Some(ErrorCode::DatabaseCorrupt | ErrorCode::NotADatabase)
        )
    };
    let flags = OpenFlags::SQLITE_OPEN_READ_WRITE | OpenFlags::SQLITE_OPEN_NO_MUTEX;
    let conn = match Connection::open_with_flags(path, flags) {
        Ok(c) => c,
        Err(e) if corrupt(&e) => return Some(e.to_string()),
        Err(_) => return None,
    };
    let _ = conn.busy_timeout(BUSY_TIMEOUT);
    let checked = (|| {
        let mut stmt = conn.prepare("PRAGMA quick_check")?;
        let rows = stmt.query_map([], |r| r.get::<_, String>(0))?;
        rows.take(5).collect::<rusqlite::Result<Vec<String>>>()
    })();
    match checked {
        Ok(lines) if lines.iter().all(|l| l == "ok") => None,
        Ok(lines) => Some(format!("quick_check: {}", lines.join("; "))),
        Err(e) if corrupt(&e) => Some(e.to_string()),
        Err(_) => None,
    }
}

/// Moves the damaged history at `path` (and its -wal and -shm files) to
/// `<path>.damaged-<UTC time>`, logged, so a new one can start; nothing is deleted.
fn set_aside(path: &Path, why: String) -> Result<SetAside, StoreError> {
    let mut aside = path.as_os_str().to_owned();
    aside.push(format!(
        ".damaged-{}",
        crate::calendar::utc_stamp(unix_now().floor() as i64)
    ));
    let aside = PathBuf::from(aside);
    let io = |source| StoreError::Io {
        action: "move aside the damaged",
        path: path.to_path_buf(),
        source,
    };
    std::fs::rename(path, &aside).map_err(io)?;
    for suffix in ["-wal", "-shm"] {
        let (mut from, mut to) = (path.as_os_str().to_owned(), aside.as_os_str().to_owned());
        from.push(suffix);
        to.push(suffix);
        if Path::new(&from).exists() {
            std::fs::rename(&from, &to).map_err(io)?;
        }
    }
    tracing::error!(
        "the history {} is damaged ({why}); kept as {} and a new history started",
        path.display(),
        aside.display()
    );
    Ok(SetAside { path: aside, why })
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
const SUMMARY_COLUMNS: &str = "run_id, trigger, mode, outcome, started_unix_s, finished_unix_s,
    duration_ms, failed_stage, reason, config_origin, config_digest, result_x_m, result_y_m,
    result_z_m, result_rx_rad, result_ry_rad, result_rz_rad, uncertainty_translation_mm,
    uncertainty_rotation_deg, drift_translation_mm, drift_rotation_deg, drifted, written,
    capture_file, captures_pruned_unix_s";

fn summary_from_row(r: &rusqlite::Row<'_>) -> rusqlite::Result<RunSummary> {
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

/// Busy timeout, WAL and `synchronous=FULL` (see the module docs). This is the first
/// statement that reads the file, so a file that is not a database fails here.
fn configure(conn: &Connection, path: &Path, read_only: bool) -> Result<(), StoreError> {
    conn.busy_timeout(BUSY_TIMEOUT)
        .map_err(|e| sql_error(path, "set the busy timeout", e))?;
    if read_only {
        conn.pragma_update(None, "query_only", true)
            .map_err(|e| sql_error(path, "open read-only", e))?;
        // Reads the header: garbage is refused here.
        conn.query_row("SELECT count(*) FROM sqlite_master", [], |r| {
            r.get::<_, i64>(0)
        })
        .map_err(|e| sql_error(path, "read the schema", e))?;
        return Ok(());
    }
    let mode: String = conn
        .query_row("PRAGMA journal_mode = WAL", [], |r| r.get(0))
        .map_err(|e| sql_error(path, "switch to WAL", e))?;
    if !mode.eq_ignore_ascii_case("wal") {
        tracing::warn!(
            "{}: SQLite kept journal mode `{mode}` instead of WAL (a file system without shared memory?); readers may wait for writers",
            path.display()
        );
    }
    conn.pragma_update(None, "synchronous", "FULL")
        .map_err(|e| sql_error(path, "set synchronous=FULL", e))?;
    Ok(())
}

/// The schema version, `None` for an empty database; a database with other tables and no
/// version table is someone else's.
fn schema_version(conn: &Connection, path: &Path) -> Result<Option<i64>, StoreError> {
    let tables: Vec<String> = (|| {
        let mut stmt = conn.prepare("SELECT name FROM sqlite_master WHERE type = 'table'")?;
        let rows = stmt.query_map([], |r| r.get(0))?;
        rows.collect::<rusqlite::Result<Vec<String>>>()
    })()
    .map_err(|e| sql_error(path, "read the schema", e))?;
    if !tables.iter().any(|t| t == "schema_version") {
        return if tables.is_empty() {
            Ok(None)
        } else {
            Err(StoreError::Foreign {
                path: path.to_path_buf(),
            })
        };
    }
    conn.query_row("SELECT max(version) FROM schema_version", [], |r| {
        r.get::<_, Option<i64>>(0)
    })
    .map(|v| Some(v.unwrap_or(0)))
    .map_err(|e| sql_error(path, "read the schema version", e))
}

/// Brings the schema to [`SCHEMA_VERSION`] in one immediate transaction (two processes
/// opening a new file at once migrate it once).
fn migrate(conn: &mut Connection, path: &Path) -> Result<(), StoreError> {
    let tx = conn
        .transaction_with_behavior(TransactionBehavior::Immediate)
        .map_err(|e| sql_error(path, "start the migration", e))?;
    let found = match schema_version(&tx, path)? {
        Some(v) => v,
        None => {
            tx.execute_batch(
                "CREATE TABLE schema_version (
                    version INTEGER PRIMARY KEY NOT NULL,
                    applied_unix_s REAL NOT NULL
                 );",
            )
            .map_err(|e| sql_error(path, "create the version table", e))?;
            0
        }
    };
    if found > SCHEMA_VERSION {
        return Err(StoreError::TooNew {
            path: path.to_path_buf(),
            found,
            supported: SCHEMA_VERSION,
        });
    }
    for (i, sql) in MIGRATIONS.iter().enumerate() {
        let version = i as i64 + 1;
        if version <= found {
            continue;
        }
        tx.execute_batch(sql)
            .map_err(|e| sql_error(path, "migrate the schema", e))?;
        tx.execute(
            "INSERT INTO schema_version (version, applied_unix_s) VALUES (?1, ?2)",
            params![version, unix_now()],
        )
        .map_err(|e| sql_error(path, "migrate the schema", e))?;
        tracing::info!(
            "{}: history schema migrated to version {version}",
            path.display()
        );
    }
    tx.commit()
        .map_err(|e| sql_error(path, "commit the migration", e))
}

/// Maps SQLite's errors to the ones an operator can act on.
fn sql_error(path: &Path, action: &'static str, e: rusqlite::Error) -> StoreError {
    let path = path.to_path_buf();
    match e.sqlite_error_code() {
        Some(ErrorCode::NotADatabase | ErrorCode::DatabaseCorrupt) => {
            StoreError::Corrupt { path, source: e }
        }
        Some(ErrorCode::DatabaseBusy | ErrorCode::DatabaseLocked) => {
            StoreError::Busy { path, source: e }
        }
        Some(ErrorCode::ReadOnly) => StoreError::ReadOnly { path },
        Some(ErrorCode::DiskFull) => StoreError::DiskFull { path },
        Some(ErrorCode::CannotOpen | ErrorCode::PermissionDenied) => {
            StoreError::Open { path, source: e }
        }
        _ => StoreError::Sqlite {
            path,
            action,
            source: e,
        },
    }
}

/// SQLite stores NaN as NULL anyway; say so explicitly.
fn finite(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}
