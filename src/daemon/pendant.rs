//! The pendant trigger: a program on the teach pendant asks for a run through RTDE registers
//! (`daemon.pendant`): 1 calibrate, 2 check in its request register (`output_int_register_N`),
//! answered in its status register (`input_int_register_N`): 0 idle, 1 busy, 2 done, 3 failed,
//! 4 refused.
//!
//! The handshake is a protocol, not a level: a request counts only on an edge this daemon saw,
//! the request register going from 0 to 1 or 2 on one link. A value found when the daemon
//! starts or after the link came back (a program aborted before it wrote 0, a reboot, a
//! restarted service) never starts a run: it is answered 4 so that a program waiting on it
//! ends, and the program must write 0 (answered 0) before it asks again. A value left after a
//! run was answered (a program that never resets) asks for nothing either. The pendant is read
//! while a run goes, so a request then is answered at once: 4 (refused) or, with
//! `daemon.when_busy = "queue"`, 1 (queued, answered 2 or 3 when it ends). An answer the
//! controller did not take is written again at the next read.

use std::time::Duration;

use handeye_hal::Robot;

use super::DaemonHandle;
use crate::config::PendantConfig;
use crate::record::{Outcome, RunMode, Trigger};

/// How often the pendant's request register is read (also while a run goes).
pub(super) const POLL: Duration = Duration::from_millis(200);
/// Answers in the pendant's status register.
const IDLE: i32 = 0;
const BUSY: i32 = 1;
const DONE: i32 = 2;
const FAILED: i32 = 3;
const REFUSED: i32 = 4;

/// The daemon's side of the handshake with one pendant program.
#[derive(Debug)]
pub(super) struct Pendant {
    cfg: PendantConfig,
    /// The request register as last read on the current link; `None` before the first read
    /// (start), after the link came back or after a read failed: the next value read is
    /// where things stand, never a request.
    seen: Option<i32>,
    /// The robot's link generation `seen` was read on.
    link: u64,
    /// The run the pendant asked for and waits on, answered when it ends.
    waits_on: Option<String>,
    /// An answer not yet taken by the controller, written again at the next read.
    owed: Option<i32>,
}

impl Pendant {
    pub(super) fn new(cfg: PendantConfig) -> Self {
        Self {
            cfg,
            seen: None,
            link: 0,
            waits_on: None,
            owed: None,
        }
    }

    /// Reads the request register once and answers what changed (see the module's doc).
    pub(super) async fn poll<R: Robot>(&mut self, robot: &R, handle: &DaemonHandle) {
        let link = robot.link_generation();
        let read = robot
            .read_output_int_register(self.cfg.request_register)
            .await;
        let v = match read {
            Ok(v) => v,
            Err(e) => {
                tracing::debug!("cannot read the pendant's request register: {e}");
                self.seen = None;
                return;
            }
        };
        if link != self.link || robot.link_generation() != link {
            // Read on a new link: where things stand now, not a request.
            self.link = robot.link_generation();
            self.seen = None;
        }
        self.take(v, handle);
        self.flush(robot).await;
    }

    /// What the value `v` of the request register means, given the last one seen: updates
    /// the state and the answer owed, synchronously (a poll dropped while it writes loses
    /// nothing: the answer is written at the next one).
    fn take(&mut self, v: i32, handle: &DaemonHandle) {
        let previous = self.seen.replace(v);
        if previous == Some(v) {
            return;
        }
        let register = self.cfg.request_register;
        let answer = match (previous, v) {
            (_, 0) => {
                if let Some(run) = self.waits_on.take() {
                    tracing::info!(
                        "the pendant program withdrew its request (output_int_register_{register} = 0) \
                         while run {run} goes; its outcome is in the history, not in the status register"
                    );
                }
                IDLE
            }
            (None, v) => {
                if self.waits_on.is_some() {
                    // The link came back during the run this program asked for: it still waits
                    // for that run's answer.
                    return;
                }
                tracing::warn!(
                    "output_int_register_{register} = {v} when the daemon started or its link to \
                     the controller came back: not taken as a request (a program stopped before it \
                     wrote 0?); answered 4. To ask, the program writes 0, waits for 0 in \
                     input_int_register_{}, then writes 1 or 2",
                    self.cfg.status_register
                );
                REFUSED
            }
            (Some(0), 1 | 2) => {
                let mode = if v == 1 {
                    RunMode::Calibrate
                } else {
                    RunMode::Check
                };
                match handle.request_with_handover(mode, Trigger::Pendant) {
                    Ok(run_id) => {
                        self.waits_on = Some(run_id);
                        BUSY
                    }
                    Err(e) => {
                        tracing::warn!("pendant request refused: {e}");
                        REFUSED
                    }
                }
            }
            (Some(p), 1 | 2) => {
                tracing::warn!(
                    "output_int_register_{register} went from {p} to {v} without 0 between: not \
                     taken as a request; answered 4 (the program writes 0 before each request)"
                );
                REFUSED
            }
            (_, v) => {
                tracing::warn!(
                    "pendant request register output_int_register_{register} = {v}: expected 1 \
                     (calibrate), 2 (check) or 0; answered 4"
                );
                REFUSED
            }
        };
        self.owed = Some(answer);
    }

    /// Answers the pendant that asked for run `run_id` with how it ended: done when accepted,
    /// failed otherwise. Nothing when the pendant did not ask for it or withdrew its request.
    pub(super) async fn finished<R: Robot>(&mut self, robot: &R, run_id: &str, outcome: Outcome) {
        if self.waits_on.as_deref() != Some(run_id) {
            return;
        }
        self.waits_on = None;
        self.owed = Some(if outcome == Outcome::Accepted {
            DONE
        } else {
            FAILED
        });
        self.flush(robot).await;
    }

    /// Writes the answer owed to the status register (`input_int_register_N`); kept for the
    /// next read when the controller does not take it.
    async fn flush<R: Robot>(&mut self, robot: &R) {
        let Some(value) = self.owed else { return };
        let register = self.cfg.status_register;
        match robot.write_int_register(register, value).await {
            Ok(()) => {
                if self.owed == Some(value) {
                    self.owed = None;
                }
            }
            Err(e) => tracing::warn!(
                "cannot answer the pendant in input_int_register_{register} ({value}), \
                 written again at the next read: {e}"
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use handeye_hal::fake::FakeRobot;
    use handeye_hal::ur_dh::UrModel;
    use tokio_util::sync::CancellationToken;

    use super::*;
    use crate::config::WhenBusy;
    use crate::store::Store;

    const REQUEST: u32 = 25;
    const STATUS: u32 = 26;

    struct Cell {
        robot: FakeRobot,
        handle: DaemonHandle,
        pendant: Pendant,
        dir: std::path::PathBuf,
    }

    impl Cell {
        fn new(tag: &str, when_busy: WhenBusy) -> Self {
            let dir =
                std::env::temp_dir().join(format!("handeye-pendant-{}-{tag}", std::process::id()));
            let _ = std::fs::remove_dir_all(&dir);
            std::fs::create_dir_all(&dir).expect("dir");
            let store = Arc::new(Store::open(&dir.join("history.sqlite")).expect("store"));
            Self {
                robot: FakeRobot::new(UrModel::Ur5e, [0.0; 6]),
                handle: super::super::handle(store, when_busy, CancellationToken::new()),
                pendant: Pendant::new(PendantConfig {
                    request_register: REQUEST,
                    status_register: STATUS,
                }),
                dir,
            }
        }

        /// The program writes `v`; the daemon reads it once; what the status register holds.
        async fn program_writes(&mut self, v: i32) -> i32 {
            self.robot.set_output_int_register(REQUEST, v);
            self.poll().await
        }

        async fn poll(&mut self) -> i32 {
            self.pendant.poll(&self.robot, &self.handle).await;
            self.robot.read_int_register(STATUS).await.expect("status")
        }

        fn runs(&self) -> Vec<(RunMode, Trigger)> {
            let st = self.handle.status();
            st.current
                .iter()
                .chain(&st.queued)
                .map(|c| (c.mode, c.trigger))
                .collect()
        }

        /// The daemon's worker ends the current run with `outcome` and answers the pendant.
        async fn end_current(&mut self, outcome: Outcome) {
            let job = self.handle.next_job().expect("a run");
            let mut record = crate::record::RunRecord::starting(
                job.entry.run_id.clone(),
                job.entry.mode,
                false,
                "test".into(),
            );
            record.outcome = outcome;
            self.handle.finished(&job, &record);
            self.pendant
                .finished(&self.robot, &job.entry.run_id, outcome)
                .await;
        }
    }

    impl Drop for Cell {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }

    /// Issue 42: a value left in the request register when the daemon starts (a program
    /// aborted before it wrote 0, a reboot) never moves the arm, whatever it is; it is
    /// answered 4, and a request after the program wrote 0 runs.
    #[tokio::test]
    async fn issue_42_a_stale_request_at_start_never_starts_a_run() {
        for stale in [1, 2, 3, 4, -1, 99] {
            let mut cell = Cell::new(&format!("stale{stale}"), WhenBusy::Refuse);
            cell.robot.set_output_int_register(REQUEST, stale);
            for _ in 0..5 {
                assert_eq!(cell.poll().await, REFUSED, "stale {stale}");
            }
            assert!(
                cell.runs().is_empty(),
                "stale {stale} started {:?}",
                cell.runs()
            );
            assert_eq!(cell.program_writes(0).await, IDLE);
            assert_eq!(cell.program_writes(1).await, BUSY);
            assert_eq!(cell.runs(), [(RunMode::Calibrate, Trigger::Pendant)]);
        }
    }

    /// Issue 42: the same after the link to the controller came back (a restarted
    /// controller, a new RTDE session): the value then is not an edge.
    #[tokio::test]
    async fn issue_42_a_value_read_after_a_reconnect_is_not_a_request() {
        let mut cell = Cell::new("reconnect", WhenBusy::Refuse);
        assert_eq!(cell.program_writes(0).await, IDLE);
        // The controller restarts; its program wrote 2 while the daemon was not connected.
        cell.robot.set_output_int_register(REQUEST, 2);
        cell.robot.reconnect();
        assert_eq!(cell.poll().await, REFUSED);
        assert!(cell.runs().is_empty());
        // A read that fails (the link is down) also forgets the last value.
        assert_eq!(cell.program_writes(0).await, IDLE);
        cell.robot.fail_register_reads(true);
        cell.robot.set_output_int_register(REQUEST, 1);
        cell.pendant.poll(&cell.robot, &cell.handle).await;
        cell.robot.fail_register_reads(false);
        assert_eq!(cell.poll().await, REFUSED);
        assert!(cell.runs().is_empty());
        assert_eq!(cell.program_writes(0).await, IDLE);
        assert_eq!(cell.program_writes(2).await, BUSY);
        assert_eq!(cell.runs(), [(RunMode::Check, Trigger::Pendant)]);
    }

    /// Issue 42: a request while another run goes is answered at once: 4 with
    /// `when_busy = "refuse"`, and it never runs afterwards.
    #[tokio::test]
    async fn issue_42_a_request_during_a_run_is_refused_and_never_runs() {
        let mut cell = Cell::new("busy", WhenBusy::Refuse);
        assert_eq!(cell.program_writes(0).await, IDLE);
        cell.handle
            .request(RunMode::Check, Trigger::Api)
            .expect("the API's run");
        assert_eq!(cell.program_writes(1).await, REFUSED);
        assert_eq!(cell.poll().await, REFUSED);
        cell.end_current(Outcome::Accepted).await;
        for _ in 0..3 {
            assert_eq!(cell.poll().await, REFUSED);
        }
        assert!(cell.runs().is_empty(), "{:?}", cell.runs());
        // The program resets and asks again: now it runs.
        assert_eq!(cell.program_writes(0).await, IDLE);
        assert_eq!(cell.program_writes(1).await, BUSY);
        cell.end_current(Outcome::Rejected).await;
        assert_eq!(cell.poll().await, FAILED);
    }

    /// Issue 42: with `when_busy = "queue"` the request waits behind the running one,
    /// answered 1 at once and 2 when its own run ends (not when the first one does).
    #[tokio::test]
    async fn issue_42_a_request_during_a_run_is_queued_when_configured() {
        let mut cell = Cell::new("queue", WhenBusy::Queue);
        assert_eq!(cell.program_writes(0).await, IDLE);
        cell.handle
            .request(RunMode::Check, Trigger::Schedule)
            .expect("the schedule's run");
        assert_eq!(cell.program_writes(1).await, BUSY);
        assert_eq!(
            cell.runs(),
            [
                (RunMode::Check, Trigger::Schedule),
                (RunMode::Calibrate, Trigger::Pendant)
            ]
        );
        cell.end_current(Outcome::Rejected).await;
        assert_eq!(cell.poll().await, BUSY);
        cell.end_current(Outcome::Accepted).await;
        assert_eq!(cell.poll().await, DONE);
    }

    /// Issue 42: a program that never writes 0 after its answer asks for nothing more; the
    /// answer stays, and other triggers still run.
    #[tokio::test]
    async fn issue_42_a_program_that_never_resets_asks_once() {
        let mut cell = Cell::new("noreset", WhenBusy::Refuse);
        assert_eq!(cell.program_writes(0).await, IDLE);
        assert_eq!(cell.program_writes(2).await, BUSY);
        cell.end_current(Outcome::Accepted).await;
        for _ in 0..10 {
            assert_eq!(cell.poll().await, DONE);
        }
        assert!(cell.runs().is_empty());
        cell.handle
            .request(RunMode::Check, Trigger::Api)
            .expect("the API still runs");
        cell.end_current(Outcome::Accepted).await;
        // A change straight to another request, without 0: refused, not run.
        assert_eq!(cell.program_writes(1).await, REFUSED);
        assert!(cell.runs().is_empty());
    }

    /// An answer the controller did not take is written at the next read; a program that
    /// withdrew its request (0 during its run) is not answered when the run ends.
    #[tokio::test]
    async fn an_answer_not_taken_is_written_again_and_a_withdrawn_request_is_not_answered() {
        let mut cell = Cell::new("owed", WhenBusy::Refuse);
        assert_eq!(cell.program_writes(0).await, IDLE);
        cell.robot.fail_register_writes(true);
        assert_eq!(cell.program_writes(1).await, IDLE, "not taken");
        cell.robot.fail_register_writes(false);
        assert_eq!(cell.poll().await, BUSY, "written at the next read");
        assert_eq!(cell.program_writes(0).await, IDLE);
        cell.end_current(Outcome::Accepted).await;
        assert_eq!(cell.poll().await, IDLE);
    }
}
