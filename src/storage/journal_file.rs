//! The write-back journal's files ([`crate::run::journal`]): `<storage>/writeback-journal.json`,
//! written durably before the controller changes and removed once the run's end is recorded;
//! the lock its writer holds while it lives; and a journal that cannot be trusted set aside
//! beside it (`writeback-journal.json.set-aside-<UTC time>`), kept for the operator.

use std::path::{Path, PathBuf};

use super::{read_text_beneath, write_atomically};

/// The write-back journal ([`crate::run::journal`]): what a run is about to write to the
/// controller, kept until the run's end is recorded.
pub const JOURNAL_FILE: &str = "writeback-journal.json";
/// Held (`flock`) by the process whose write-back the journal describes, while it lives.
const JOURNAL_LOCK_FILE: &str = "writeback.lock";
/// Largest journal read back (it holds one run record: tens of kB).
const MAX_JOURNAL_BYTES: u64 = 16 << 20;

/// Writes the write-back journal durably (file and folder flushed) before the controller
/// changes. Blocking I/O.
pub(crate) fn write_journal(storage: &Path, bytes: &[u8]) -> std::io::Result<()> {
    write_atomically(&storage.join(JOURNAL_FILE), bytes)
}

/// The journal's text, when there is one (bounded, a regular file only).
pub(crate) fn read_journal(storage: &Path) -> Result<Option<String>, String> {
    let path = storage.join(JOURNAL_FILE);
    match read_text_beneath(storage, Path::new(JOURNAL_FILE), MAX_JOURNAL_BYTES) {
        Ok(text) => Ok(Some(text)),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(format!("cannot read {}: {e}", path.display())),
    }
}

/// Removes the journal durably (the folder flushed), once the run's end is recorded.
pub(crate) fn remove_journal(storage: &Path) -> std::io::Result<()> {
    remove_unrecorded_mark(storage);
    match std::fs::remove_file(storage.join(JOURNAL_FILE)) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(e),
    }
    std::fs::File::open(storage)?.sync_all()
}

/// The lock a process holds while its write-back journal describes a live run: another
/// process (`handeye calibrate` beside the daemon) never reconciles a journal whose writer
/// lives. The operating system drops it when the process dies, however it dies.
#[derive(Debug)]
pub(crate) struct JournalLock(#[allow(dead_code)] std::fs::File);

impl JournalLock {
    /// Takes the lock without waiting; `Ok(None)` when another live process holds it.
    pub(crate) fn try_acquire(storage: &Path) -> std::io::Result<Option<JournalLock>> {
        std::fs::create_dir_all(storage)?;
        let file = crate::lockfile::open_lock_file(&storage.join(JOURNAL_LOCK_FILE))?;
        Ok(
            crate::lockfile::flock(&file, crate::lockfile::FlockMode::ExclusiveNow)?
                .then_some(JournalLock(file)),
        )
    }
}

/// Beside a journal, says that the process that wrote it lived on and left it because the
/// run's end could not be recorded (a full disk), not because it was killed. Empty: it takes
/// no data block, so a full disk still takes it.
const UNRECORDED_FILE: &str = "writeback-journal.unrecorded";

/// Marks the journal as left by a live process whose run's end could not be recorded
/// ([`UNRECORDED_FILE`]). Blocking I/O.
pub(crate) fn mark_journal_unrecorded(storage: &Path) -> std::io::Result<()> {
    mark(storage, UNRECORDED_FILE)
}

/// In a run's folder, says that the process that ran it lived on and could not record the
/// run's end (a full disk), so the next start does not call it killed. Empty, as
/// [`UNRECORDED_FILE`].
const RUN_UNRECORDED_FILE: &str = "end.unrecorded";

/// Marks the run in `run_dir` as ended by a live process that could not record its end
/// ([`RUN_UNRECORDED_FILE`]). Blocking I/O.
pub(crate) fn mark_run_unrecorded(run_dir: &Path) -> std::io::Result<()> {
    mark(run_dir, RUN_UNRECORDED_FILE)
}

/// Whether run `run_id` of `storage` was marked by [`mark_run_unrecorded`].
pub fn run_unrecorded(storage: &Path, run_id: &str) -> bool {
    super::run_dir(storage, run_id).is_some_and(|d| {
        std::fs::symlink_metadata(d.join(RUN_UNRECORDED_FILE)).is_ok_and(|m| m.is_file())
    })
}

/// Creates the empty file `name` in `dir` (durably) unless it is there.
fn mark(dir: &Path, name: &str) -> std::io::Result<()> {
    let path = dir.join(name);
    if std::fs::symlink_metadata(&path).is_ok_and(|m| m.is_file()) {
        return Ok(());
    }
    super::create_fresh(&path)?;
    std::fs::File::open(dir)?.sync_all()
}

/// Whether the journal was left by a live process that could not record the run's end
/// ([`mark_journal_unrecorded`]) rather than by a kill.
pub(crate) fn journal_unrecorded(storage: &Path) -> bool {
    std::fs::symlink_metadata(storage.join(UNRECORDED_FILE)).is_ok_and(|m| m.is_file())
}

/// Removes the mark of [`mark_journal_unrecorded`] (with the journal it marks).
fn remove_unrecorded_mark(storage: &Path) {
    let _ = std::fs::remove_file(storage.join(UNRECORDED_FILE));
}

/// Moves the journal aside — `writeback-journal.json.set-aside-<UTC time>` beside it (`-2`,
/// `-3`, … when that name is taken), the folder flushed — so that no run reads it again and
/// the operator still can. Returns where it is now. Blocking I/O.
pub(crate) fn set_aside_journal(storage: &Path) -> std::io::Result<PathBuf> {
    let stamp = crate::calendar::utc_stamp(crate::calendar::unix_now().floor() as i64);
    let base = format!("{JOURNAL_FILE}.set-aside-{stamp}");
    let mut aside = storage.join(&base);
    let mut n = 1;
    while std::fs::symlink_metadata(&aside).is_ok() {
        n += 1;
        aside = storage.join(format!("{base}-{n}"));
    }
    std::fs::rename(storage.join(JOURNAL_FILE), &aside)?;
    remove_unrecorded_mark(storage);
    std::fs::File::open(storage)?.sync_all()?;
    Ok(aside)
}
