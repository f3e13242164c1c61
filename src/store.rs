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

use rusqlite::{params, Connection, ErrorCode, OpenFlags, OptionalExtension};

use crate::calendar::unix_now;
use crate::record::{Outcome, RunMode, RunRecord, Trigger};

mod damaged;
mod error;
mod rows;
mod schema;
#[cfg(test)]
mod tests;
mod writer_lock;

use damaged::{damage, set_aside};
use rows::{summary_from_row, SUMMARY_COLUMNS};
use schema::{configure, migrate, schema_version};
use writer_lock::{no_links, WriterLock};

pub use damaged::SetAside;
use error::sql_error;
pub use error::StoreError;
pub use rows::{config_digest, PartialRun, RunStart, RunStatus, RunSummary, StoredRun};
pub use schema::SCHEMA_VERSION;

/// File name of the history database in the storage directory.
pub const HISTORY_FILE: &str = "history.sqlite";
/// Why a run that was still `running` when the store was opened again is `aborted`.
pub const INTERRUPTED_REASON: &str =
    "interrupted: the program stopped during the run (crash, power loss or kill)";
/// Why a run still `running` at the next open is `aborted` when the process that ran it lived
/// on and could not record its end.
pub const UNRECORDED_REASON: &str = "its end could not be recorded: the storage was full or \
     could not be written when the run ended (the program lived on; its log has the outcome)";

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

/// SQLite stores NaN as NULL anyway; say so explicitly.
fn finite(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}
