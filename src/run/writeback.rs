//! Writing an accepted result to the controller as a transaction ([`super::journal`]), and
//! putting back what it held when a write fails.

use super::*;

/// What the run's record says while the result is written to the controller: it stays so
/// when the program stops before the final record is written.
const WRITING_REASON: &str = "interrupted while writing the result above to the controller (the TCP and/or the registers, as configured); check the TCP on the pendant";

/// What the controller held before a run wrote its result: put back when the result cannot be
/// recorded (the record and `current/` must describe what the controller holds).
#[derive(Debug, Clone)]
pub(crate) struct Previous {
    /// The TCP read at preflight, when the run set the TCP.
    pub(crate) tcp: Option<Isometry3<f64>>,
    /// The result registers read just before they were written, when the run wrote them.
    pub(crate) registers: Option<(crate::config::RegisterMap, [f64; 6])>,
}

/// Writes `previous` back to the controller: the TCP, then the registers with a new sequence
/// number (so a pendant program that applied the unrecorded result applies the previous values
/// again). Returns what was done, for the run's reasons, or why it could not be done.
pub(crate) async fn put_back<R: Robot>(robot: &R, previous: &Previous) -> Result<String, String> {
    let mut done = Vec::new();
    if let Some(tcp) = &previous.tcp {
        robot
            .set_tcp(tcp)
            .await
            .map_err(|e| format!("setting the previous TCP back failed: {}", error_chain(&e)))?;
        done.push(format!(
            "the previous TCP ({}) was set back",
            UrPose::from(tcp)
        ));
    }
    if let Some((map, values)) = &previous.registers {
        let failed = |e: HalError| {
            format!(
                "writing the previous result registers back failed: {}",
                error_chain(&e)
            )
        };
        for (k, v) in values.iter().enumerate() {
            robot
                .write_double_register(map.double_start + k as u32, *v)
                .await
                .map_err(failed)?;
        }
        let seq = robot
            .read_int_register(map.sequence_int)
            .await
            .map_err(failed)?
            .wrapping_add(1)
            .max(1);
        robot
            .write_int_register(map.sequence_int, seq)
            .await
            .map_err(failed)?;
        done.push(format!(
            "the previous values of input_double_register_{}..{} were written back (input_int_register_{} = {seq})",
            map.double_start,
            map.double_start + 5,
            map.sequence_int
        ));
    }
    Ok(done.join("; "))
}

/// Puts `previous` back on the controller and says so: on success `record.written` loses its
/// TCP and register entries (the controller holds what it held before the run).
async fn restore_sentence<R: Robot>(
    robot: &R,
    previous: &Previous,
    record: &mut RunRecord,
) -> String {
    match put_back(robot, previous).await {
        Ok(done) => {
            record
                .written
                .retain(|w| !matches!(w.target, WriteTarget::Tcp | WriteTarget::Registers));
            tracing::warn!("result not recorded, controller restored: {done}");
            format!("so it was undone: {done}")
        }
        Err(why) => {
            tracing::error!("result not recorded and the controller not restored: {why}");
            format!("{why}; the controller keeps the unrecorded result: check the TCP and the registers on the pendant")
        }
    }
}

impl<R: Robot, C: DepthCamera> Context<'_, R, C> {
    /// Writes the accepted result as a transaction ([`journal`]). Write-ahead first: the
    /// result files (staged for `current/`), a record saying the result is being written to
    /// the controller, and the intent journal (what the controller holds now, what is about
    /// to be written, the record once it is) are durably on disk before the controller
    /// changes, so a full disk stops the run with nothing written and a kill at any later
    /// instant is reconciled at the next start. Then the TCP, then the registers (the
    /// sequence number last, so a pendant program applies nothing half-written, and the set
    /// read back), then the record saying they were written, then `current/` is replaced, so
    /// it only ever holds a calibration the controller has confirmed. From the journal on,
    /// a cancel or a shutdown waits for these few requests: they never stop half-way. When a
    /// write, the record or `current/` fails, the controller gets back the TCP read at
    /// preflight and the registers read before writing them ([`put_back`]), and the error
    /// says so. The journal goes once the recorder has kept the run's end.
    pub(super) async fn write_back(&mut self, unknown: &Isometry3<f64>) -> Result<(), Failure> {
        let stage = Stage::WriteBack;
        let wb = self.cfg.write_back;
        let mount = self.cfg.mount.mount;
        let robot = self.robot;
        let storage_dir = self.cfg.storage.dir.clone();
        let kept = |what: &str, e: std::io::Error| {
            Failure::error(
                stage,
                format!("cannot keep {what} before writing it to the controller: {e}; nothing was written to the controller; free space in the storage directory (`[storage] dir`) and run again"),
            )
        };
        // The journal's lock first: no other process takes this run's staging or journal
        // for a crash's leftovers.
        let lock = match storage::JournalLock::try_acquire(&storage_dir) {
            Ok(Some(lock)) => lock,
            Ok(None) => {
                return Err(Failure::error(
                    stage,
                    "another handeye process is writing a result to the controller from the same storage directory; nothing was written; run again once it has ended",
                ))
            }
            Err(e) => return Err(kept("the write-back journal's lock", e)),
        };
        let staged = if wb.files {
            let result = self.record.result.clone();
            let staged = storage::stage_result(
                &storage_dir,
                &self.run_dir,
                unknown,
                mount,
                &self.record,
                result.as_ref(),
            )
            .map_err(|e| kept("the result files", e))?;
            Some(staged)
        } else {
            None
        };
        let mut pending = self.record.clone();
        pending.outcome = Outcome::Aborted;
        pending.failed_stage = Some(stage);
        pending.reasons.push(WRITING_REASON.to_string());
        storage::write_record(&self.run_dir, &pending).map_err(|e| kept("the run record", e))?;
        // What to put back if the result cannot be recorded: the TCP read at preflight and
        // the registers as they are now.
        let set_tcp = wb.tcp && mount == Mount::EyeInHand;
        let previous_tcp = set_tcp
            .then(|| {
                self.record
                    .preflight
                    .as_ref()
                    .and_then(|p| crate::frames::from_row_major(&p.tcp_offset))
            })
            .flatten();
        let p = UrPose::from(unknown).values();
        let registers = match wb.registers {
            Some(map) => {
                let (previous, previous_sequence) = cancellable(self.cancel, stage, async {
                    let failed = |e| Failure::robot(stage, "reading the result registers", e);
                    let mut values = [0.0; 6];
                    for (k, v) in values.iter_mut().enumerate() {
                        *v = robot
                            .read_double_register(map.double_start + k as u32)
                            .await
                            .map_err(failed)?;
                    }
                    let seq = robot
                        .read_int_register(map.sequence_int)
                        .await
                        .map_err(failed)?;
                    Ok((values, seq))
                })
                .await?;
                Some(journal::RegisterChange {
                    double_start: map.double_start,
                    sequence_int: map.sequence_int,
                    previous,
                    previous_sequence,
                    new: p,
                    sequence: previous_sequence.wrapping_add(1).max(1),
                })
            }
            None => None,
        };
        let tcp_written = Written {
            target: WriteTarget::Tcp,
            detail: format!(
                "set_tcp(p[{:.6}, {:.6}, {:.6}, {:.6}, {:.6}, {:.6}]), read back over RTDE",
                p[0], p[1], p[2], p[3], p[4], p[5]
            ),
        };
        let registers_written = registers.as_ref().map(|r| Written {
            target: WriteTarget::Registers,
            detail: format!(
                "input_double_register_{}..{} = x,y,z,rx,ry,rz (m, rad); input_int_register_{} = {}; read back",
                r.double_start,
                r.double_start + 5,
                r.sequence_int,
                r.sequence
            ),
        });
        let current_files = staged.as_ref().map(|s| s.file_names()).unwrap_or_default();
        let files_written = staged.as_ref().map(|_| Written {
            target: WriteTarget::Files,
            detail: current_files
                .iter()
                .map(|n| {
                    storage_dir
                        .join(storage::CURRENT_DIR)
                        .join(n)
                        .display()
                        .to_string()
                })
                .collect::<Vec<_>>()
                .join(", "),
        });
        // The record as it reads once everything is written: what the next start completes
        // when the program stops after the controller took the result.
        let mut done = self.record.clone();
        done.written.extend(
            set_tcp
                .then(|| tcp_written.clone())
                .into_iter()
                .chain(registers_written.clone())
                .chain(files_written.clone()),
        );
        let intent = journal::Intent {
            run_id: self.record.run_id.clone(),
            written_unix_s: unix_now(),
            tcp: previous_tcp.as_ref().map(|prev| journal::TcpChange {
                previous: UrPose::from(prev).values(),
                new: p,
            }),
            registers: registers.clone(),
            current_files,
            record: done,
        };
        intent
            .write(&storage_dir)
            .map_err(|e| kept("the write-back journal", e))?;
        self.journal = Some(lock);
        self.previous = Some(intent.previous());
        journal::pause_point("journal").await;
        if set_tcp {
            if let Err(e) = robot.set_tcp(unknown).await {
                return Err(self.undo(Failure::robot(stage, "setting the TCP", e)).await);
            }
            self.record.written.push(tcp_written);
            journal::pause_point("tcp").await;
        }
        if let (Some(r), Some(w)) = (&registers, registers_written) {
            if let Err(f) = self.write_registers(r).await {
                return Err(self.undo(f).await);
            }
            self.record.written.push(w);
        }
        // The record that describes what the controller now holds, before `current/` says so;
        // when it cannot be kept, the controller gets back what it held.
        if let Err(e) = storage::write_record(&self.run_dir, &self.record) {
            let undone = self.put_back().await;
            return Err(Failure::error(
                stage,
                format!("the result was written to the controller but the run record could not be written: {e}; {undone}; free space in the storage directory (`[storage] dir`) and run again"),
            ));
        }
        journal::pause_point("record").await;
        if let (Some(staged), Some(w)) = (staged, files_written) {
            match staged.commit() {
                Ok(_) => self.record.written.push(w),
                Err(e) => {
                    let what = format!("`current/` could not be replaced after the result was written to the controller: {e}");
                    let put_back = self.put_back().await;
                    return Err(Failure::error(stage, format!("{what}; {put_back}")));
                }
            }
            journal::pause_point("current").await;
        }
        Ok(())
    }

    /// Writes the result registers of `r`: the six doubles, then the sequence number (a
    /// pendant program waits for it, so it never applies a half-written set), then reads the
    /// set back. Not cancellable: it is a few requests and never stops half-way.
    pub(super) async fn write_registers(&self, r: &journal::RegisterChange) -> Result<(), Failure> {
        let stage = Stage::WriteBack;
        let robot = self.robot;
        let failed = |what: &'static str| move |e: HalError| Failure::robot(stage, what, e);
        for (k, v) in r.new.iter().enumerate() {
            robot
                .write_double_register(r.double_start + k as u32, *v)
                .await
                .map_err(failed("writing the result registers"))?;
            journal::pause_point(&format!("register-{k}")).await;
        }
        robot
            .write_int_register(r.sequence_int, r.sequence)
            .await
            .map_err(failed("writing the sequence register"))?;
        journal::pause_point("sequence").await;
        let mut back = [0.0; 6];
        for (k, v) in back.iter_mut().enumerate() {
            *v = robot
                .read_double_register(r.double_start + k as u32)
                .await
                .map_err(failed("reading the result registers back"))?;
        }
        let seq = robot
            .read_int_register(r.sequence_int)
            .await
            .map_err(failed("reading the sequence register back"))?;
        if back != r.new || seq != r.sequence {
            return Err(Failure::error(
                stage,
                format!(
                    "the result registers read back {back:?} (sequence {seq}) instead of {:?} (sequence {}): another RTDE client writes them?",
                    r.new, r.sequence
                ),
            ));
        }
        Ok(())
    }

    /// `f` with what [`Self::put_back`] did about the partly written result.
    pub(super) async fn undo(&mut self, mut f: Failure) -> Failure {
        let undone = self.put_back().await;
        f.message = format!("{}; {undone}", f.message);
        f
    }

    /// Puts back what the controller held before the write-back (see [`put_back`]); on
    /// success the record no longer lists the TCP and registers as written. Returns the
    /// sentence for the run's reasons.
    pub(super) async fn put_back(&mut self) -> String {
        let Some(previous) = self.previous.take() else {
            return "nothing had been written to the controller".into();
        };
        restore_sentence(self.robot, &previous, &mut self.record).await
    }
}
