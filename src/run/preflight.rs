//! Preflight: the robot powered, brakes released, safety normal, remote control, no program
//! running; the speed slider, TCP and the controller's kinematics recorded; the camera
//! reachable, and the calibration a check compares with. Any failure ends the run before
//! anything moves.

use super::*;

impl<R: Robot, C: DepthCamera> Context<'_, R, C> {
    /// Checks that the robot may move and the camera answers; records the start state.
    /// Returns the controller's kinematics (when used) and the current calibration.
    pub(super) async fn preflight(
        &mut self,
    ) -> Result<
        (
            Option<handeye_hal::ur_dh::DhParams>,
            Option<(Isometry3<f64>, String)>,
        ),
        Failure,
    > {
        let stage = Stage::Preflight;
        let robot = self.robot;
        let camera = self.camera;
        let allow_power_on = self.cfg.robot.allow_power_on;
        let (status, start, tcp, flange, powered_on) = cancellable(self.cancel, stage, async {
            let mut status = robot
                .status()
                .await
                .map_err(|e| Failure::robot(stage, "reading the robot's state", e))?;
            // Only when the configuration says so explicitly; never past a stop of any kind.
            let powerable =
                matches!(
                    status.robot_mode,
                    RobotMode::PowerOff | RobotMode::PowerOn | RobotMode::Idle
                ) && matches!(status.safety_mode, SafetyMode::Normal | SafetyMode::Reduced)
                    && status.remote_control;
            let powered_on = powerable && allow_power_on;
            if powered_on {
                tracing::warn!(
                    "the robot is {:?}: powering it on and releasing the brakes \
                     (robot.allow_power_on = true)",
                    status.robot_mode
                );
                robot.power_on().await.map_err(|e| {
                    Failure::robot(stage, "powering the robot on (robot.allow_power_on)", e)
                })?;
                status = robot
                    .status()
                    .await
                    .map_err(|e| Failure::robot(stage, "reading the robot's state", e))?;
            }
            let start = robot
                .joint_positions()
                .await
                .map_err(|e| Failure::robot(stage, "reading the joints", e))?;
            let tcp = robot
                .tcp_offset()
                .await
                .map_err(|e| Failure::robot(stage, "reading the TCP", e))?;
            let flange = robot
                .flange_pose()
                .await
                .map_err(|e| Failure::robot(stage, "reading the flange pose", e))?;
            Ok((status, start, tcp, flange, powered_on))
        })
        .await?;
        let identity =
            match cancellable(self.cancel, stage, async { Ok(robot.identity().await) }).await? {
                Ok(id) => Some(id),
                Err(e) => {
                    let w = format!(
                        "cannot ask the controller who it is ({}): the arm is not compared with \
                     the one the current calibration was made on; check the dashboard \
                     connection (port 29999)",
                        error_chain(&e)
                    );
                    tracing::warn!("{w}");
                    self.record.warnings.push(w);
                    None
                }
            };
        if start.len() != self.model.dof() {
            return Err(Failure::error(
                stage,
                format!(
                    "the robot reports {} joints but the model {} has {}; configure the right robot model",
                    start.len(),
                    self.model.name(),
                    self.model.dof()
                ),
            ));
        }
        // Without the controller's kinematics: posed by `robot.calibration` when given, else
        // the nominal URDF.
        let fallback = |why: Option<String>| match &self.cfg.robot.calibration {
            Some(file) => KinematicsUsed {
                source: KinematicsOrigin::File,
                note: Some(format!(
                    "{}posed by the calibration file {}",
                    why.map_or_else(String::new, |w| format!("{w}; ")),
                    file.display()
                )),
                dh: None,
            },
            None => KinematicsUsed {
                source: KinematicsOrigin::Nominal,
                note: why.map(|w| format!("{w}; posed by the nominal URDF")),
                dh: None,
            },
        };
        let mut kinematics = match self.cfg.robot.kinematics {
            KinematicsSource::Nominal => fallback(None),
            KinematicsSource::Controller => {
                match cancellable(self.cancel, stage, async { Ok(robot.kinematics().await) })
                    .await?
                {
                    Ok(Some(k)) => KinematicsUsed {
                        source: KinematicsOrigin::Controller,
                        note: (!k.calibrated).then(|| {
                            "the controller says its arm is not factory calibrated".to_string()
                        }),
                        dh: Some(k.dh),
                    },
                    Ok(None) => fallback(Some("the controller publishes no kinematics".into())),
                    // Values no arm has: no pose this controller reports is trusted.
                    Err(e @ HalError::Protocol { .. }) => {
                        return Err(Failure::error(
                            stage,
                            format!(
                                "the controller's kinematics: {}; nothing moved and nothing was \
                                 written",
                                error_chain(&e)
                            ),
                        ))
                    }
                    Err(e) => fallback(Some(format!(
                        "cannot read the controller's kinematics ({})",
                        error_chain(&e)
                    ))),
                }
            }
        };
        if let Some(note) = &kinematics.note {
            tracing::warn!("{note}");
        }
        if let (Some(file), KinematicsOrigin::File) =
            (&self.cfg.robot.calibration, kinematics.source)
        {
            // The file's DH set poses the model as the controller's would.
            let dh = crate::model::UrCalibration::load(file)
                .map_err(|e| e.to_string())
                .and_then(|c| c.dh(&self.cfg.robot.model.dh()))
                .map_err(|e| {
                    Failure::error(
                        stage,
                        format!("robot.calibration: {e}; fix the file or remove the key"),
                    )
                })?;
            kinematics.dh = Some(dh);
        }
        let reported_model = identity.as_ref().and_then(|i| i.model.as_deref());
        let model_check = check_model_matches(
            self.cfg.robot.model,
            reported_model,
            kinematics.dh.as_ref().map(|dh| (dh, kinematics.source)),
        );
        let camera_info = cancellable(self.cancel, stage, async {
            camera.info().await.map_err(|e| {
                let what = match e {
                    // It answered, and refuses what was asked (a configured setting its
                    // description cannot take, issue 44): the message says what to change.
                    handeye_hal::HalError::Refused { .. } => {
                        format!("the camera refuses: {}", error_chain(&e))
                    }
                    _ => format!(
                        "the camera does not answer: {}; check its power, cable and address",
                        error_chain(&e)
                    ),
                };
                Failure::error(stage, what)
            })
        })
        .await;
        let controller_dh = kinematics.dh;
        // Before anything moves: the controller's joints and flange must belong together.
        let flange_check = self.check_flange(
            stage,
            &start,
            &flange,
            reference_dh(&kinematics).as_ref(),
            "at the start",
        );
        let reference = self.reference(&tcp, identity.as_ref());
        self.record.preflight = Some(PreflightRecord {
            status: status.clone(),
            camera: camera_info.as_ref().cloned().unwrap_or_default(),
            start_joints: start,
            tcp_offset: to_row_major(&tcp),
            kinematics,
            powered_on,
            controller: identity,
        });
        model_check.map_err(|m| Failure::error(stage, m))?;
        flange_check?;
        preflight_status(&status, self.req.program_handover, allow_power_on)?;
        camera_info?;
        Ok((controller_dh, reference))
    }

    /// The calibration a check compares with, and a calibrate's previous result: the last
    /// accepted result in storage, else (check, eye-in-hand with TCP write-back) the
    /// controller's TCP. When the stored result was made on another arm, or on other
    /// kinematics of this one (`identity` against the one it was made with), the record
    /// warns: a check still compares, a calibrate's gate does not.
    pub(super) fn reference(
        &mut self,
        tcp: &Isometry3<f64>,
        identity: Option<&ControllerIdentity>,
    ) -> Option<(Isometry3<f64>, String)> {
        if let Some(current) = load_current(&self.cfg.storage.dir, self.cfg.mount.mount) {
            let mismatch = identity
                .zip(current.controller.as_ref())
                .and_then(|(now, then)| now.calibration_mismatch(then));
            if let Some(m) = mismatch {
                let w = match self.req.mode {
                    RunMode::Check => {
                        format!("{m}; the drift is measured from that arm's calibration")
                    }
                    RunMode::Calibrate => format!(
                        "{m}; this run does, and its gate does not compare with that arm's \
                         result"
                    ),
                };
                tracing::warn!("{w}");
                self.record.warnings.push(w);
                self.other_arm = true;
            }
            return Some((current.pose, current.source));
        }
        let tcp_is_camera = self.cfg.mount.mount == Mount::EyeInHand
            && self.cfg.write_back.tcp
            && (tcp.translation.vector.norm() > 1e-9 || tcp.rotation.angle() > 1e-9);
        (self.req.mode == RunMode::Check && tcp_is_camera)
            .then(|| (*tcp, "the controller's active TCP".to_string()))
    }
}
