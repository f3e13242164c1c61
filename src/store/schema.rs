//! The schema: its version, the numbered migrations that bring a file to it, and the pragmas
//! every connection opens with.

use std::path::Path;

use rusqlite::{params, Connection, TransactionBehavior};

use super::error::{sql_error, StoreError, BUSY_TIMEOUT};
use crate::calendar::unix_now;

/// The schema version this program writes and reads.
pub const SCHEMA_VERSION: i64 = 1;

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

/// Busy timeout, WAL and `synchronous=FULL` (see the module docs of [`crate::store`]). This
/// is the first statement that reads the file, so a file that is not a database fails here.
pub(super) fn configure(conn: &Connection, path: &Path, read_only: bool) -> Result<(), StoreError> {
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
pub(super) fn schema_version(conn: &Connection, path: &Path) -> Result<Option<i64>, StoreError> {
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
pub(super) fn migrate(conn: &mut Connection, path: &Path) -> Result<(), StoreError> {
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
