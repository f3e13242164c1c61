//! The write-back as a transaction: an intent journal in the storage directory
//! (`writeback-journal.json`) says, before the first write to the controller, what the
//! controller held (the TCP read at preflight, the result registers and their sequence number
//! as read just before), what the run is about to write, and the record the run has once it
//! is all written. It is durably on disk (file and folder flushed) before the controller
//! changes, and removed once the run's end is recorded (record, `current/`, history).
//!
//! A journal found at the next start ([`reconcile`]) belongs to a run that was killed (or lost
//! power) between the two. What the controller reports then decides:
//!
//! | the controller holds | what happens | the run is recorded as |
//! |---|---|---|
//! | all of the new values | `current/` and the record completed | accepted, return interrupted |
//! | none of them (all previous) | nothing to undo | aborted, nothing written |
//! | some of them (a torn set) | the previous values written back | aborted, rolled back; check the TCP on the pendant |
//! | values that are neither | left alone | aborted; check the TCP and registers on the pendant |
//!
//! Completing needs the disk: when `current/` or the record cannot be written then, the
//! controller is rolled back instead. When the controller cannot be reached, the journal stays
//! and the next run (or start) tries again; no run starts before it is reconciled.
//!
//! The journal is evidence, not an order: before anything in it is used, its values are
//! checked as values read from the controller are ([`doubt`]): every TCP within 2 m of the
//! flange and every register set a pose within 10 m, all finite (the UR driver's bounds, one
//! check: `handeye_hal::ur_limits::within_pose_bound`), its registers the configured ones
//! (`[write_back.registers]`), its run not already complete in the history. A journal that
//! fails (or cannot be read at all) is set aside — renamed
//! `writeback-journal.json.set-aside-<UTC time>`, kept for the operator — with an `ALARM`
//! error in the log that names what to check; nothing in it is written anywhere and runs go
//! on.

use std::path::Path;

use handeye_hal::ur_limits::{within_pose_bound, MAX_POSE_DISTANCE_M, MAX_TCP_OFFSET_M};
use handeye_hal::{HalError, Robot, UrPose};
use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

use super::{error_chain, put_back, Previous};
use crate::config::RegisterMap;
use crate::record::{Outcome, RunRecord, Stage, WriteTarget};
use crate::storage::{self, JournalLock};
use crate::store::{RunStatus, Store};

/// A TCP or register value is the journal's when it is this close (m or rad): the controller
/// keeps what it was sent to within a few ulps.
const SAME: f64 = 1e-9;

/// The TCP change a run is about to make (UR poses `x,y,z,rx,ry,rz`, flange → TCP).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct TcpChange {
    /// The TCP read at preflight.
    pub previous: [f64; 6],
    /// The result.
    pub new: [f64; 6],
}

/// The register change a run is about to make.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct RegisterChange {
    /// `input_double_register_<double_start>..+5`.
    pub double_start: u32,
    /// `input_int_register_<sequence_int>`, written last.
    pub sequence_int: u32,
    /// The doubles as read just before the write.
    pub previous: [f64; 6],
    /// The sequence number as read just before the write.
    pub previous_sequence: i32,
    /// The result (x, y, z m, rx, ry, rz rad).
    pub new: [f64; 6],
    /// The sequence number written after them.
    pub sequence: i32,
}

impl RegisterChange {
    pub(crate) fn map(&self) -> RegisterMap {
        RegisterMap {
            double_start: self.double_start,
            sequence_int: self.sequence_int,
        }
    }
}

/// What a run is about to write (the journal's content).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct Intent {
    /// The run.
    pub run_id: String,
    /// Unix time the journal was written, s.
    pub written_unix_s: f64,
    /// The TCP, when the run sets it.
    pub tcp: Option<TcpChange>,
    /// The registers, when the run writes them.
    pub registers: Option<RegisterChange>,
    /// The files the run's folder gives `current/` (empty: `current/` is not replaced).
    pub current_files: Vec<String>,
    /// The run's record once everything is written (accepted, every write listed).
    pub record: RunRecord,
}

impl Intent {
    /// What to put back to undo the write.
    pub(crate) fn previous(&self) -> Previous {
        Previous {
            tcp: self
                .tcp
                .as_ref()
                .map(|t| Isometry3::from(UrPose(t.previous))),
            registers: self.registers.as_ref().map(|r| (r.map(), r.previous)),
        }
    }

    /// Writes the journal durably. Blocking I/O.
    pub(crate) fn write(&self, storage_dir: &Path) -> std::io::Result<()> {
        let bytes = serde_json::to_vec_pretty(self).map_err(std::io::Error::other)?;
        storage::write_journal(storage_dir, &bytes)
    }
}

/// What the controller holds compared with a journal.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Holds {
    /// Everything the run was about to write.
    New,
    /// Nothing of it: what it held before.
    Previous,
    /// Part of it.
    Torn,
    /// Values that are neither (changed by someone else since).
    Other,
}

fn same(a: &[f64; 6], b: &[f64; 6]) -> bool {
    a.iter().zip(b).all(|(x, y)| (x - y).abs() <= SAME)
}

/// Reads what the controller holds of the journal's targets.
async fn controller_holds<R: Robot>(robot: &R, intent: &Intent) -> Result<Holds, HalError> {
    // Per target: Some(true) new, Some(false) previous, None neither.
    let mut parts: Vec<Option<bool>> = Vec::new();
    if let Some(t) = &intent.tcp {
        let now = UrPose::from(&robot.tcp_offset().await?).values();
        // A TCP equal to the previous one and the new one counts as new.
        parts.push(if same(&now, &t.new) {
            Some(true)
        } else if same(&now, &t.previous) {
            Some(false)
        } else {
            None
        });
    }
    if let Some(r) = &intent.registers {
        let mut now = [0.0; 6];
        for (k, v) in now.iter_mut().enumerate() {
            *v = robot
                .read_double_register(r.double_start + k as u32)
                .await?;
        }
        let seq = robot.read_int_register(r.sequence_int).await?;
        // Each double on its own: a torn set has some new and some previous.
        for (k, v) in now.iter().enumerate() {
            parts.push(if (v - r.new[k]).abs() <= SAME {
                Some(true)
            } else if (v - r.previous[k]).abs() <= SAME {
                Some(false)
            } else {
                None
            });
        }
        parts.push(if seq == r.sequence {
            Some(true)
        } else if seq == r.previous_sequence {
            Some(false)
        } else {
            None
        });
    }
    Ok(if parts.iter().all(|p| *p == Some(true)) {
        Holds::New
    } else if parts.iter().all(|p| *p == Some(false)) {
        Holds::Previous
    } else if parts.iter().any(Option::is_none) {
        Holds::Other
    } else {
        Holds::Torn
    })
}

/// Why a journal could not be reconciled (it stays for the next try).
#[derive(Debug, thiserror::Error)]
#[error("the write-back of run {run_id} was interrupted and cannot be reconciled yet: {why}; no run starts until it is: {todo}")]
pub struct ReconcileError {
    /// The interrupted run.
    pub run_id: String,
    /// Why not.
    pub why: String,
    /// What to do about it.
    pub todo: &'static str,
}

/// Why a journal marked by a live process ([`storage::mark_journal_unrecorded`]) was left.
const UNRECORDED_CAUSE: &str = "the storage was full or could not be written when the run ended";

/// What to do when the controller did not answer the reconciliation.
const TODO_CONTROLLER: &str = "check that the controller answers (its network cable, RTDE on port 30004), then start a run again";
/// What to do when the storage directory did not take what the reconciliation writes.
const TODO_STORAGE: &str = "free space in the storage directory (`[storage] dir`) and check that this user can write there, then start a run again";

/// Why the journal `intent` is not to be used, checked as values read from the controller
/// are (see the module docs): `registers` are the configured result registers, `store` the
/// history. `None` when it can be used.
fn doubt(intent: &Intent, registers: Option<RegisterMap>, store: Option<&Store>) -> Option<String> {
    let run_id = &intent.run_id;
    if !storage::is_run_id(run_id) || intent.record.run_id != *run_id {
        return Some(format!(
            "it names no valid run (run id `{run_id}`, its record's `{}`)",
            intent.record.run_id
        ));
    }
    if let Some(t) = &intent.tcp {
        for (which, p) in [("previous", &t.previous), ("new", &t.new)] {
            if let Err(why) = within_pose_bound(p, MAX_TCP_OFFSET_M) {
                return Some(format!(
                    "its {which} TCP p{p:?} (flange → TCP) is {why}, which no controller holds"
                ));
            }
        }
    }
    if let Some(r) = &intent.registers {
        if registers != Some(r.map()) {
            let configured = match registers {
                Some(m) => format!(
                    "input_double_register_{}..{} and input_int_register_{}",
                    m.double_start,
                    m.double_start + 5,
                    m.sequence_int
                ),
                None => "none".into(),
            };
            return Some(format!(
                "it names input_double_register_{}..{} and input_int_register_{}, not the configured result registers (`[write_back.registers]`: {configured})",
                r.double_start,
                r.double_start + 5,
                r.sequence_int
            ));
        }
        for (which, p) in [("previous", &r.previous), ("new", &r.new)] {
            if let Err(why) = within_pose_bound(p, MAX_POSE_DISTANCE_M) {
                return Some(format!(
                    "its {which} result registers {p:?} (x, y, z m, rx, ry, rz rad) are {why}, which no controller holds"
                ));
            }
        }
    }
    let row = store.and_then(|s| s.summary(run_id).ok().flatten());
    if let Some(row) = row.filter(|r| r.outcome == RunStatus::Ended(Outcome::Accepted)) {
        return Some(format!(
            "its run is already complete in the history (accepted, first reason {:?})",
            row.reason.unwrap_or_default()
        ));
    }
    None
}

/// Sets the journal aside (renamed beside it, kept for the operator) and says so in the log
/// with what to check; nothing in it is used. Runs go on (`Ok(None)`) unless it cannot even
/// be moved.
fn set_aside(
    storage_dir: &Path,
    run_id: Option<&str>,
    why: &str,
) -> Result<Option<RunRecord>, ReconcileError> {
    let path = storage_dir.join(storage::JOURNAL_FILE);
    let of = run_id.map(|id| format!(" (run {id})")).unwrap_or_default();
    let aside = storage::set_aside_journal(storage_dir).map_err(|e| ReconcileError {
        run_id: run_id.unwrap_or("?").to_string(),
        why: format!("{why}, and the journal cannot be set aside: {e}"),
        todo: "move writeback-journal.json out of the storage directory by hand, then check the TCP and the result registers on the pendant",
    })?;
    let current = storage::current_run_id(storage_dir).unwrap_or_else(|| "none".into());
    tracing::error!(
        "ALARM: the write-back journal {}{of} cannot be reconciled: {why}; it was set aside as {} and nothing in it was written to the controller or the history. Check on the pendant that the TCP and the result registers hold the current calibration (`current/` holds run {current}), then remove the set-aside file",
        path.display(),
        aside.display()
    );
    clean(storage_dir, None);
    Ok(None)
}

/// Reconciles a write-back journal left by a process that stopped (see the module docs):
/// `current/`, the run's record and its history row (`store`) are completed, or the
/// controller rolled back; staging folders a crash left are removed. Returns the run's record
/// as now kept, `None` when there was no journal (or another live process's run owns it).
pub async fn reconcile<R: Robot>(
    robot: &R,
    storage_dir: &Path,
    registers: Option<RegisterMap>,
    store: Option<&Store>,
) -> Result<Option<RunRecord>, ReconcileError> {
    let exists = std::fs::symlink_metadata(storage_dir.join(storage::JOURNAL_FILE)).is_ok();
    let _lock = match JournalLock::try_acquire(storage_dir) {
        Ok(Some(lock)) => lock,
        // A live process writes back now: its journal and staging are not leftovers.
        Ok(None) => return Ok(None),
        // Nothing to reconcile on a storage that cannot even take the lock (read-only):
        // the run's own storage check says why.
        Err(_) if !exists => return Ok(None),
        Err(e) => {
            return Err(ReconcileError {
                run_id: "?".into(),
                why: format!("cannot lock the journal: {e}"),
                todo: TODO_STORAGE,
            })
        }
    };
    let text = match storage::read_journal(storage_dir) {
        Ok(Some(text)) => text,
        Ok(None) => {
            clean(storage_dir, None);
            return Ok(None);
        }
        // Not a regular file, too large, not readable: nothing to trust.
        Err(why) => return set_aside(storage_dir, None, &why),
    };
    let intent: Intent = match serde_json::from_str(&text) {
        Ok(i) => i,
        // Written atomically, so never torn: not ours.
        Err(e) => {
            let why = format!("it is not a write-back journal ({e})");
            return set_aside(storage_dir, None, &why);
        }
    };
    let run_id = intent.run_id.clone();
    if let Some(why) = doubt(&intent, registers, store) {
        return set_aside(storage_dir, Some(&run_id), &why);
    }
    let Some(run_dir) = storage::run_dir(storage_dir, &run_id) else {
        return set_aside(storage_dir, None, "it names no valid run");
    };
    let fail = |why: String, todo: &'static str| ReconcileError {
        run_id: run_id.clone(),
        why,
        todo,
    };
    let holds = controller_holds(robot, &intent).await.map_err(|e| {
        fail(
            format!("reading the controller: {}", error_chain(&e)),
            TODO_CONTROLLER,
        )
    })?;
    // Why the run's end was not recorded: a kill, or (a live process said so) the storage.
    let unrecorded = storage::journal_unrecorded(storage_dir);
    let cause = if unrecorded {
        UNRECORDED_CAUSE
    } else {
        "crash, power loss or kill"
    };
    let record = match holds {
        Holds::New => match complete(storage_dir, &run_dir, &intent, unrecorded) {
            Ok(record) => record,
            Err(why) => {
                let undone = put_back(robot, &intent.previous())
                    .await
                    .map_err(|e| fail(format!("{why}; and {e}"), TODO_CONTROLLER))?;
                rolled_back(
                    &intent,
                    format!(
                        "interrupted after its result was written to the controller ({cause}); at the next start it could not be completed ({why}), so it was rolled back: {undone}; check the TCP on the pendant"
                    ),
                )
            }
        },
        Holds::Previous => rolled_back(
            &intent,
            format!("interrupted before its result was written to the controller ({cause}); the controller and `current/` keep the previous calibration"),
        ),
        Holds::Torn => {
            let undone = put_back(robot, &intent.previous()).await.map_err(|e| {
                fail(
                    format!("the controller holds part of the result and {e}"),
                    TODO_CONTROLLER,
                )
            })?;
            rolled_back(
                &intent,
                format!(
                    "interrupted while writing its result to the controller ({cause}); at the next start the controller held part of it, so it was rolled back: {undone}; check the TCP on the pendant"
                ),
            )
        }
        Holds::Other => rolled_back(
            &intent,
            format!("interrupted while writing its result to the controller ({cause}); at the next start the controller held neither the previous values nor the result (changed on the pendant since?), so nothing was written; check the TCP and the registers on the pendant"),
        ),
    };
    storage::write_record(&run_dir, &record)
        .map_err(|e| fail(format!("cannot write the run record: {e}"), TODO_STORAGE))?;
    if let Some(store) = store {
        let trigger = record.trigger.unwrap_or(crate::record::Trigger::Cli);
        store.finish(trigger, &record).map_err(|e| {
            fail(
                format!("cannot record it in the history: {e}"),
                TODO_STORAGE,
            )
        })?;
    }
    storage::remove_journal(storage_dir)
        .map_err(|e| fail(format!("cannot remove the journal: {e}"), TODO_STORAGE))?;
    clean(storage_dir, None);
    match holds {
        Holds::New => tracing::warn!(run_id = %run_id, "{}", record.reasons[0]),
        _ => tracing::error!(run_id = %run_id, "{}", record.reasons[0]),
    }
    Ok(Some(record))
}

fn clean(storage_dir: &Path, keep: Option<&str>) {
    for p in storage::clean_staging(storage_dir, keep) {
        tracing::info!("removed {} (left by a crash)", p.display());
    }
}

/// Completes an interrupted run whose result the controller holds: `current/` (from the
/// run's folder, unless it already names the run) and its record. Returns the record.
fn complete(
    storage_dir: &Path,
    run_dir: &Path,
    intent: &Intent,
    unrecorded: bool,
) -> Result<RunRecord, String> {
    if !intent.current_files.is_empty()
        && storage::current_run_id(storage_dir).as_deref() != Some(&intent.run_id)
    {
        storage::make_current_from_run(storage_dir, run_dir, &intent.run_id, &intent.current_files)
            .map_err(|e| format!("`current/` could not be replaced: {e}"))?;
    }
    // The record written after the return move (or after the write-back) knows more than
    // the journal's (timings, the return); it is used when it lists every write.
    let on_disk = storage::read_run_record(storage_dir, &intent.run_id).filter(|r| {
        r.outcome == Outcome::Accepted
            && intent
                .record
                .written
                .iter()
                .all(|w| r.written.iter().any(|x| x.target == w.target))
    });
    let mut record = on_disk.unwrap_or_else(|| intent.record.clone());
    record.outcome = Outcome::Accepted;
    record.failed_stage = None;
    let arm = if record.returned_to_start {
        "the arm had moved back to the start"
    } else {
        "the arm was not moved back to the start: it stands where it stopped"
    };
    let stopped = if unrecorded {
        format!("the run's end could not be recorded after the result was written to the controller ({UNRECORDED_CAUSE})")
    } else {
        "the program stopped after the result was written to the controller (crash, power loss or kill)".into()
    };
    record.reasons.insert(
        0,
        format!(
            "{stopped}; completed at the next start: the controller, `current/` and the history hold this result; {arm}"
        ),
    );
    Ok(record)
}

/// The run's record after a roll-back (or when nothing was written): aborted in the
/// write-back, nothing listed as written to the controller or `current/`.
fn rolled_back(intent: &Intent, reason: String) -> RunRecord {
    let mut record = intent.record.clone();
    record.outcome = Outcome::Aborted;
    record.failed_stage = Some(Stage::WriteBack);
    record.written.retain(|w| {
        !matches!(
            w.target,
            WriteTarget::Tcp | WriteTarget::Registers | WriteTarget::Files
        )
    });
    record.reasons.insert(0, reason);
    record
}

/// Test hook: with env `HANDEYE_TEST_PAUSE_AT` naming `step`, the process says so on stderr
/// (`handeye: paused at <step>`) and waits there forever, to be killed at exactly that step
/// by the tests (`kill -9`). Unset (always, outside the tests), nothing.
pub(crate) async fn pause_point(step: &str) {
    let Some(at) = std::env::var_os(PAUSE_ENV) else {
        return;
    };
    if at == step {
        eprintln!("handeye: paused at {step} ({PAUSE_ENV})");
        std::future::pending::<()>().await;
    }
}

/// The env variable of the tests' pause points (`pause_point`): `HANDEYE_TEST_PAUSE_AT=<step>`.
pub const PAUSE_ENV: &str = "HANDEYE_TEST_PAUSE_AT";

#[cfg(test)]
mod tests {
    use super::*;
    use crate::record::{RunMode, Written};
    use handeye_hal::fake::FakeRobot;
    use handeye_hal::ur_dh::UrModel;

    const HOME: [f64; 6] = [0.0, -1.57, 1.57, -1.57, -1.57, 0.0];
    /// The configured result registers: doubles 24..29, sequence 24.
    const MAP: Option<RegisterMap> = Some(RegisterMap {
        double_start: 24,
        sequence_int: 24,
    });
    const OLD: [f64; 6] = [0.0, -0.08, 0.04, -0.26, 0.0, 0.0];
    const NEW: [f64; 6] = [0.008, -0.074, 0.047, -0.22, 0.03, 0.02];

    struct Dir(std::path::PathBuf);
    impl Drop for Dir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
    fn dir(tag: &str) -> Dir {
        let d = std::env::temp_dir().join(format!("handeye-journal-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).expect("dir");
        Dir(d)
    }

    /// A journal of run `id` setting the TCP and registers 24..29/24 from OLD to NEW, and a
    /// robot holding OLD (sequence 3).
    async fn prepared(storage: &Path, id: &str) -> (FakeRobot, Intent) {
        let robot = FakeRobot::new(UrModel::Ur5e, HOME);
        robot
            .set_tcp(&Isometry3::from(UrPose(OLD)))
            .await
            .expect("tcp");
        for (k, v) in OLD.iter().enumerate() {
            robot
                .write_double_register(24 + k as u32, *v)
                .await
                .expect("reg");
        }
        robot.write_int_register(24, 3).await.expect("seq");
        let mut record = RunRecord::starting(id.into(), RunMode::Calibrate, false, "t".into());
        record.outcome = Outcome::Accepted;
        for target in [WriteTarget::Tcp, WriteTarget::Registers] {
            record.written.push(Written {
                target,
                detail: String::new(),
            });
        }
        let intent = Intent {
            run_id: id.into(),
            written_unix_s: 0.0,
            tcp: Some(TcpChange {
                previous: OLD,
                new: NEW,
            }),
            registers: Some(RegisterChange {
                double_start: 24,
                sequence_int: 24,
                previous: OLD,
                previous_sequence: 3,
                new: NEW,
                sequence: 4,
            }),
            current_files: Vec::new(),
            record,
        };
        intent.write(storage).expect("journal");
        std::fs::create_dir_all(storage.join("runs").join(id)).expect("run folder");
        (robot, intent)
    }

    async fn registers(robot: &FakeRobot) -> ([f64; 6], i32) {
        let mut v = [0.0; 6];
        for (k, x) in v.iter_mut().enumerate() {
            *x = robot
                .read_double_register(24 + k as u32)
                .await
                .expect("reg");
        }
        (v, robot.read_int_register(24).await.expect("seq"))
    }

    #[tokio::test]
    async fn a_torn_register_set_is_rolled_back_and_the_run_says_so() {
        let d = dir("torn");
        let id = "20261128T000000Z-0001";
        let (robot, _) = prepared(&d.0, id).await;
        // Killed after the TCP and three of the six doubles.
        robot
            .set_tcp(&Isometry3::from(UrPose(NEW)))
            .await
            .expect("tcp");
        for (k, v) in NEW.iter().enumerate().take(3) {
            robot
                .write_double_register(24 + k as u32, *v)
                .await
                .expect("reg");
        }
        let record = reconcile(&robot, &d.0, MAP, None)
            .await
            .expect("reconciled")
            .expect("a run");
        assert_eq!(record.outcome, Outcome::Aborted);
        assert!(
            record.reasons[0].contains("rolled back"),
            "{:?}",
            record.reasons
        );
        assert!(record.reasons[0].contains("check the TCP on the pendant"));
        assert!(record.written.is_empty(), "{:?}", record.written);
        let (regs, seq) = registers(&robot).await;
        assert_eq!(regs, OLD, "one whole set: the previous one");
        assert!(
            seq > 3,
            "a new sequence number (a pendant program applies the previous set): {seq}"
        );
        assert!(same(&UrPose::from(&robot.tcp()).values(), &OLD));
        assert!(!d.0.join(storage::JOURNAL_FILE).exists());
        let kept = storage::read_run_record(&d.0, id).expect("record written");
        assert_eq!(kept.outcome, Outcome::Aborted);
    }

    #[tokio::test]
    async fn a_complete_write_is_completed_as_accepted_with_the_return_interrupted() {
        let d = dir("complete");
        let id = "20261128T000000Z-0002";
        let (robot, _) = prepared(&d.0, id).await;
        robot
            .set_tcp(&Isometry3::from(UrPose(NEW)))
            .await
            .expect("tcp");
        for (k, v) in NEW.iter().enumerate() {
            robot
                .write_double_register(24 + k as u32, *v)
                .await
                .expect("reg");
        }
        robot.write_int_register(24, 4).await.expect("seq");
        let record = reconcile(&robot, &d.0, MAP, None)
            .await
            .expect("reconciled")
            .expect("a run");
        assert_eq!(record.outcome, Outcome::Accepted);
        assert!(
            record.reasons[0].contains("not moved back"),
            "{:?}",
            record.reasons
        );
        assert_eq!(registers(&robot).await, (NEW, 4), "left as written");
        assert!(!d.0.join(storage::JOURNAL_FILE).exists());
    }

    #[tokio::test]
    async fn nothing_written_is_recorded_as_such_and_a_live_writer_is_left_alone() {
        let d = dir("nothing");
        let id = "20261128T000000Z-0003";
        let (robot, _) = prepared(&d.0, id).await;
        // Another live process holds the journal's lock: its journal is not touched.
        let held = storage::JournalLock::try_acquire(&d.0)
            .expect("lock")
            .expect("free");
        assert!(reconcile(&robot, &d.0, MAP, None)
            .await
            .expect("ok")
            .is_none());
        assert!(d.0.join(storage::JOURNAL_FILE).exists());
        drop(held);
        let record = reconcile(&robot, &d.0, MAP, None)
            .await
            .expect("reconciled")
            .expect("a run");
        assert_eq!(record.outcome, Outcome::Aborted);
        assert!(record.reasons[0].contains("before its result was written"));
        assert_eq!(registers(&robot).await, (OLD, 3), "untouched");
    }

    /// The journals set aside beside the journal (`writeback-journal.json.set-aside-*`).
    fn set_aside_files(storage: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(storage)
            .expect("storage")
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.starts_with("writeback-journal.json.set-aside-"))
            .collect();
        v.sort();
        v
    }

    /// Issue 46: a journal is evidence, not an order. After a torn kill (the TCP new, the
    /// registers previous), journals whose values no controller holds — a previous TCP 5 m or
    /// 1e300 m from the flange, NaN result registers — or that name registers other than the
    /// configured ones are set aside (kept, renamed): nothing is written to the controller,
    /// no record is made up, and the next reconciliation finds nothing to block on.
    #[tokio::test]
    async fn issue_46_a_journal_with_values_no_controller_holds_is_set_aside() {
        type Spoil = fn(&mut Intent);
        let cases: [(&str, Spoil); 5] = [
            ("previous TCP 5 m away", |i| {
                i.tcp.as_mut().expect("tcp").previous[0] = 5.0
            }),
            ("previous TCP 1e300 m away", |i| {
                i.tcp.as_mut().expect("tcp").previous[2] = 1e300
            }),
            ("NaN previous registers", |i| {
                i.registers.as_mut().expect("registers").previous[3] = f64::NAN
            }),
            ("registers outside the configured range", |i| {
                i.registers.as_mut().expect("registers").double_start = 40
            }),
            ("sequence register not the configured one", |i| {
                i.registers.as_mut().expect("registers").sequence_int = 99
            }),
        ];
        for (k, (what, spoil)) in cases.into_iter().enumerate() {
            let d = dir(&format!("doubt{k}"));
            let id = format!("20261128T000000Z-01{k:02}");
            let (robot, mut intent) = prepared(&d.0, &id).await;
            spoil(&mut intent);
            intent.write(&d.0).expect("journal");
            // Killed after the TCP: a torn write, which would be rolled back.
            robot
                .set_tcp(&Isometry3::from(UrPose(NEW)))
                .await
                .expect("tcp");
            let tcp_writes = robot.tcp_history().len();
            let reconciled = reconcile(&robot, &d.0, MAP, None).await;
            assert!(matches!(reconciled, Ok(None)), "{what}: {reconciled:?}");
            assert_eq!(
                robot.tcp_history().len(),
                tcp_writes,
                "{what}: a TCP was set"
            );
            assert!(same(&UrPose::from(&robot.tcp()).values(), &NEW), "{what}");
            assert_eq!(
                registers(&robot).await,
                (OLD, 3),
                "{what}: registers written"
            );
            assert!(!d.0.join(storage::JOURNAL_FILE).exists(), "{what}");
            assert_eq!(
                set_aside_files(&d.0).len(),
                1,
                "{what}: kept for the operator"
            );
            assert!(
                storage::read_run_record(&d.0, &id).is_none(),
                "{what}: a record was made from it"
            );
            // Nothing is left to block the next run.
            assert!(matches!(reconcile(&robot, &d.0, MAP, None).await, Ok(None)));
        }
    }

    /// Issue 46: a journal naming a run the history holds as accepted (the current
    /// calibration) is not applied: its history row stays `accepted` (before, a controller
    /// holding the journal's "previous" values turned it `aborted`); the journal is set aside.
    #[tokio::test]
    async fn issue_46_a_journal_naming_a_completed_run_leaves_its_history_alone() {
        use crate::record::Trigger;
        let d = dir("completed");
        let id = "20261128T000000Z-0200";
        let (robot, intent) = prepared(&d.0, id).await;
        let store = Store::open(&d.0.join(crate::store::HISTORY_FILE)).expect("history");
        store.finish(Trigger::Api, &intent.record).expect("row");
        let reconciled = reconcile(&robot, &d.0, MAP, Some(&store)).await;
        assert!(matches!(reconciled, Ok(None)), "{reconciled:?}");
        let row = store.summary(id).expect("read").expect("row");
        assert_eq!(row.outcome, RunStatus::Ended(Outcome::Accepted), "{row:?}");
        assert_eq!(registers(&robot).await, (OLD, 3));
        assert!(!d.0.join(storage::JOURNAL_FILE).exists());
        assert_eq!(set_aside_files(&d.0).len(), 1);
    }

    /// Issue 46: a journal that is no journal is set aside too (not read again, kept), and a
    /// second one set aside in the same second gets its own name.
    #[tokio::test]
    async fn issue_46_unreadable_journals_are_each_kept_aside() {
        let d = dir("unreadable");
        let robot = FakeRobot::new(UrModel::Ur5e, HOME);
        for text in ["{ not json", "[]"] {
            storage::write_journal(&d.0, text.as_bytes()).expect("journal");
            assert!(matches!(reconcile(&robot, &d.0, MAP, None).await, Ok(None)));
        }
        assert_eq!(set_aside_files(&d.0).len(), 2);
        assert!(!d.0.join(storage::JOURNAL_FILE).exists());
    }

    /// Issue 46: a journal a live run left because its end could not be recorded (the disk
    /// full: the recorder marks it) is completed saying so, not as "crash, power loss or
    /// kill"; the mark goes with the journal.
    #[tokio::test]
    async fn issue_46_a_run_whose_end_the_full_disk_kept_from_the_history_is_not_called_a_kill() {
        let d = dir("unrecorded");
        let id = "20261128T000000Z-0300";
        let (robot, _) = prepared(&d.0, id).await;
        robot
            .set_tcp(&Isometry3::from(UrPose(NEW)))
            .await
            .expect("tcp");
        for (k, v) in NEW.iter().enumerate() {
            robot
                .write_double_register(24 + k as u32, *v)
                .await
                .expect("reg");
        }
        robot.write_int_register(24, 4).await.expect("seq");
        storage::mark_journal_unrecorded(&d.0).expect("mark");
        assert!(storage::journal_unrecorded(&d.0));
        let record = reconcile(&robot, &d.0, MAP, None)
            .await
            .expect("reconciled")
            .expect("a run");
        assert_eq!(record.outcome, Outcome::Accepted);
        let why = &record.reasons[0];
        assert!(
            why.contains("the storage was full") && !why.contains("crash, power loss or kill"),
            "{why}"
        );
        assert!(!storage::journal_unrecorded(&d.0), "the mark stays");
        assert!(!d.0.join(storage::JOURNAL_FILE).exists());
    }
}
