//! The recorder: a run as the service keeps it. Around the run's steps it begins the history
//! row, writes the record and the report picture into the run's folder, finishes the row and
//! prunes old raw scans. The daemon (every trigger) and `handeye calibrate`/`check` (trigger
//! `cli`) run through it, so every run that can change `current/` or the controller's TCP is
//! in `handeye history` and on the page.

use std::path::PathBuf;
use std::sync::Arc;

use handeye_hal::{DepthCamera, Robot};
use tokio_util::sync::CancellationToken;

use super::{execute, new_run_id, PictureScan, Progress, RunRequest};
use crate::config::Config;
use crate::model::RobotModel;
use crate::record::{Outcome, RunRecord, Stage, Trigger};
use crate::storage;
use crate::store::{config_digest, RunStart, Store, StoreError, INTERRUPTED_REASON};

/// Who keeps the runs: the history (when there is one) and the run folders.
#[derive(Debug, Clone)]
pub struct Recorder {
    /// The history and who asks for the runs recorded in it; `None`: the run's files only.
    history: Option<(Arc<Store>, Trigger)>,
}

impl Recorder {
    /// Records runs asked for by `trigger` in `store` and the run folders.
    pub fn new(store: Arc<Store>, trigger: Trigger) -> Self {
        Self {
            history: Some((store, trigger)),
        }
    }

    /// Keeps only the runs' files (record, picture, results), no history row.
    pub fn files_only() -> Self {
        Self { history: None }
    }

    /// Runs once and keeps it: room checked, the history row begun and a first record written
    /// (a crash leaves them to be recovered as interrupted) — when any of these fails the run
    /// does not start and its record says why —, the run, its record and report picture
    /// written, the row finished, the raw scans beyond `daemon.keep_captures_*` pruned.
    /// Returns the complete record whatever happens; history errors at the end are logged.
    #[allow(clippy::too_many_arguments)]
    pub async fn run<R: Robot, C: DepthCamera>(
        &self,
        robot: &R,
        camera: &C,
        model: &Arc<RobotModel>,
        cfg: &Config,
        req: RunRequest,
        cancel: &CancellationToken,
        progress: &dyn Progress,
    ) -> RunRecord {
        let run_id = match req.run_id.clone() {
            Some(id) if storage::is_run_id(&id) => id,
            Some(id) => {
                tracing::warn!("`{id}` cannot name a run's folder; the run gets a new id");
                new_run_id()
            }
            None => new_run_id(),
        };
        // Start time, mode and configuration are decided here, once; the row copies them.
        let mut record = RunRecord::starting(run_id, req.mode, req.dry_run, cfg.origin.clone());
        record.trigger = self.history.as_ref().map(|(_, trigger)| *trigger);
        let run_dir = storage::run_folder(&cfg.storage.dir, &record.run_id);
        // A write-back interrupted by a crash is reconciled with the controller first; a dry
        // run writes nothing to the controller and leaves that to the next run that writes.
        let reconciled = if req.dry_run {
            Ok(None)
        } else {
            super::journal::reconcile(
                robot,
                &cfg.storage.dir,
                cfg.write_back.registers,
                self.history.as_ref().map(|(s, _)| s.as_ref()),
            )
            .await
        };
        let ahead = match reconciled {
            Ok(_) => self.write_ahead(&record, &run_dir, cfg),
            Err(e) => Err(e.to_string()),
        };
        if let Err(why) = ahead {
            tracing::error!(run_id = %record.run_id, "run not started: {why}");
            record.failed_stage = Some(Stage::Preflight);
            record.reasons.push(format!(
                "{why}; nothing moved and nothing was written to the controller"
            ));
            if let Some((store, trigger)) = &self.history {
                if let Err(e) = store.finish(*trigger, &record) {
                    tracing::error!("cannot record the end of run {}: {e}", record.run_id);
                }
            }
            // The folder goes when it holds nothing (its first record could not be written).
            let _ = std::fs::remove_dir(&run_dir);
            return record;
        }
        let (mut record, pictures, journal) = execute(
            robot,
            camera,
            model,
            cfg,
            req,
            record,
            run_dir.clone(),
            cancel,
            progress,
        )
        .await;
        let mut kept = storage::write_record(&run_dir, &record);
        if kept.is_err() && storage::release_reserve(&cfg.storage.dir) {
            kept = storage::write_record(&run_dir, &record);
        }
        let record_kept = kept.is_ok();
        if let Err(e) = kept {
            tracing::error!(
                "cannot write the run record into {}: {e}",
                run_dir.display()
            );
            record
                .reasons
                .push(format!("the run record could not be written: {e}"));
        }
        // The picture comes after the record: whatever happens to it, the run is kept.
        write_picture(run_dir.clone(), &record, model, pictures).await;
        let mut recorded = true;
        if let Some((store, trigger)) = &self.history {
            let mut finished = store.finish(*trigger, &record);
            if finished.is_err() && storage::release_reserve(&cfg.storage.dir) {
                finished = store.finish(*trigger, &record);
            }
            if let Err(e) = finished {
                recorded = false;
                tracing::error!("cannot record the end of run {}: {e}", record.run_id);
            }
        }
        if !recorded || !record_kept {
            // This process lives on: the next start must not call the run killed.
            if let Err(e) = storage::mark_run_unrecorded(&run_dir) {
                tracing::warn!("cannot mark run {} as ended unrecorded: {e}", record.run_id);
            }
        }
        if journal.is_some() {
            end_journal(&cfg.storage.dir, &record, recorded);
        }
        drop(journal);
        if let Some((store, _)) = &self.history {
            let d = &cfg.daemon;
            match prune_captures(
                store,
                &cfg.storage.dir,
                d.keep_captures_runs,
                d.keep_captures_days,
            ) {
                Ok(removed) if !removed.is_empty() => {
                    tracing::info!("removed {} old raw capture file(s)", removed.len());
                }
                Ok(_) => {}
                Err(e) => tracing::warn!("cannot prune old captures: {e}"),
            }
        }
        record
    }

    /// Write-ahead, before anything moves: the storage has room for a run
    /// ([`storage::RUN_BASE_BYTES`]; the run checks again for its scans once it knows their
    /// number and size), the history row is begun, and the run's folder holds a first record
    /// saying the run has not ended — each durably written. Returns why not.
    fn write_ahead(
        &self,
        record: &RunRecord,
        run_dir: &std::path::Path,
        cfg: &Config,
    ) -> Result<(), String> {
        storage::check_room(&cfg.storage.dir, storage::RUN_BASE_BYTES)
            .map_err(|e| e.to_string())?;
        if let Err(e) = storage::keep_reserve(&cfg.storage.dir) {
            tracing::warn!(
                "cannot keep {} MB in reserve in {}: {e}",
                storage::RESERVE_BYTES >> 20,
                cfg.storage.dir.display()
            );
        }
        super::clock::watch(
            self.history.as_ref().map(|(s, _)| s.as_ref()),
            record.started_unix_s,
        );
        if let Some((store, trigger)) = &self.history {
            let start = RunStart::new(record, *trigger, config_digest(&format!("{cfg:?}")));
            store
                .begin(&start)
                .map_err(|e| format!("cannot record the start of the run in the history: {e}"))?;
        }
        let mut first = record.clone();
        first.outcome = Outcome::Aborted;
        first.reasons.push(INTERRUPTED_REASON.to_string());
        storage::write_record(run_dir, &first).map_err(|e| {
            format!(
                "cannot write the run record into {}: {e}; free space there or set `[storage] dir` to a writable disk",
                run_dir.display()
            )
        })
    }
}

/// Removes the run's write-back journal once its end is kept and agrees with the controller:
/// the history row is written (`recorded`) and the record is accepted or lists nothing
/// written to the controller (rolled back). Otherwise it stays, for the next start to
/// reconcile ([`super::journal::reconcile`]).
fn end_journal(storage_dir: &std::path::Path, record: &RunRecord, recorded: bool) {
    use crate::record::WriteTarget;
    let controller_unrecorded = record.outcome != Outcome::Accepted
        && record
            .written
            .iter()
            .any(|w| matches!(w.target, WriteTarget::Tcp | WriteTarget::Registers));
    if !recorded || controller_unrecorded {
        // This process lives on: the next start must not take the journal for a kill's.
        if let Err(e) = storage::mark_journal_unrecorded(storage_dir) {
            tracing::warn!("cannot mark the write-back journal as left by a live run: {e}");
        }
        tracing::error!(
            run_id = %record.run_id,
            "the write-back journal stays in {}: the next start reconciles the controller with this run's record",
            storage_dir.display()
        );
        return;
    }
    if let Err(e) = storage::remove_journal(storage_dir) {
        tracing::error!("cannot remove the write-back journal: {e}; the next start reconciles it");
    }
}

/// Opens the history at `path` for writing ([`Store::open`]: a damaged file is set aside)
/// and, when the history is new — no file, an empty one, or a damaged one set aside — adds
/// the runs whose records are in the run folders beside it, so no run is lost from the list.
/// When no other writer is alive, the temporary files (`*.tmp`) a kill left in the storage
/// folder and the run folders are removed ([`storage::remove_temporary_files`]). Blocking I/O.
pub fn open_history(path: &std::path::Path) -> Result<Store, StoreError> {
    let store = Store::open(path)?;
    let storage_dir = path.parent().unwrap_or(std::path::Path::new("."));
    // No other process writes there now: the temporary files a kill left go.
    if store.is_sole_writer() {
        for p in storage::remove_temporary_files(storage_dir) {
            tracing::info!("removed {} (a temporary file left by a kill)", p.display());
        }
    }
    if store.is_new() {
        let records = storage::run_records(storage_dir);
        if !records.is_empty() {
            let added = store.rebuild(&records)?;
            tracing::warn!(
                "the history {} was rebuilt from {added} run record(s) in {}",
                path.display(),
                storage_dir.join(storage::RUNS_DIR).display()
            );
        }
    }
    Ok(store)
}

/// Why old raw scans could not be pruned.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PruneError {
    /// The history could not say which, or not note it.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// A run folder could not be read or a file removed.
    #[error(transparent)]
    Storage(#[from] storage::StorageError),
}

/// Deletes the raw scans (`runs/<id>/view*_frame*.ply`, and temporary files a kill left there)
/// of the runs that are both beyond the newest `keep_runs` and started more than `keep_days`
/// ago, and notes it in their rows;
/// records, `capture.json` and results stay. Runs still running are never touched; run
/// folders that are not in the history are left alone. Returns the files removed.
pub fn prune_captures(
    store: &Store,
    storage_dir: &std::path::Path,
    keep_runs: usize,
    keep_days: f64,
) -> Result<Vec<PathBuf>, PruneError> {
    let mut removed = Vec::new();
    for run_id in store.captures_to_prune(keep_runs, keep_days)? {
        removed.extend(storage::remove_raw_captures(storage_dir, &run_id)?);
        store.mark_pruned(&run_id)?;
    }
    Ok(removed)
}

/// Renders the run's report picture (a few hundred ms a scan, on a blocking thread) and
/// writes it into `run_dir`. Never fails the run: what goes wrong is logged.
async fn write_picture(
    run_dir: PathBuf,
    record: &RunRecord,
    model: &Arc<RobotModel>,
    scans: Vec<PictureScan>,
) {
    let (record, model) = (record.clone(), Arc::clone(model));
    let written = tokio::task::spawn_blocking(move || {
        let t = std::time::Instant::now();
        let png = render_picture(&record, &model, &scans)?;
        storage::write_report_picture(&run_dir, &png).map_err(|e| {
            format!(
                "cannot write the report picture into {}: {e}",
                run_dir.display()
            )
        })?;
        tracing::debug!(
            ms = t.elapsed().as_secs_f64() * 1e3,
            "report picture written"
        );
        Ok::<_, String>(())
    })
    .await;
    match written {
        Ok(Ok(())) => {}
        Ok(Err(e)) => tracing::error!("{e}"),
        Err(e) => tracing::error!("the report picture failed: {e}"),
    }
}

/// The report picture of `record`, with a panel for each view's scan (numbered from 1, as the
/// run's lines number the views).
fn render_picture(
    record: &RunRecord,
    model: &RobotModel,
    scans: &[PictureScan],
) -> Result<Vec<u8>, String> {
    let frames = record
        .captures
        .iter()
        .map(|c| c.frames.len())
        .sum::<usize>();
    let views = record.views.len().max(scans.len());
    let shown: Vec<crate::report::ScanView> = scans
        .iter()
        .filter_map(|s| {
            let caption = if scans.len() == 1 {
                format!(
                    "view {} of {views}, frame 1 of {frames}: {}",
                    s.frame.view + 1,
                    s.frame.source
                )
            } else {
                format!("view {} of {views}", s.frame.view + 1)
            };
            match crate::report::scan_view(
                model,
                &s.frame.joints,
                s.controller_dh.as_ref(),
                &s.frame.cloud,
                &s.registration,
                &caption,
                scans.len(),
            ) {
                Ok(v) => Some(v),
                Err(e) => {
                    tracing::warn!(
                        "report picture without the scan of view {}: {e}",
                        s.frame.view + 1
                    );
                    None
                }
            }
        })
        .collect();
    let summary = crate::report::Summary::from_run(record);
    crate::report::render(&summary, &shown)
        .map_err(|e| format!("cannot render the report picture: {e}"))
}
