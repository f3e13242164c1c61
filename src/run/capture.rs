//! Moving to each view, settling, and capturing: the joints and the controller's flange pose
//! at that instant, the frames, and the checks that the arm stood still while the camera
//! captured.

use super::*;

/// The arm must not move more than this while the camera exposes, rad.
const MAX_JOINT_CHANGE_DURING_CAPTURE_RAD: f64 = 1e-3;

impl<R: Robot, C: DepthCamera> Context<'_, R, C> {
    /// Moves to every view, settles, records joints and flange pose and captures frames.
    pub(super) async fn move_and_capture(&mut self) -> Result<Vec<Frame>, Failure> {
        let mut frames = Vec::new();
        let views = self.planned_joints();
        let keep = self.cfg.storage.keep_captures;
        let start = self.start_joints();
        let mut capture_file = CaptureFile {
            model: self.model.name().to_string(),
            mount: self.cfg.mount.mount,
            base_frame: "base".into(),
            prior: self.cfg.mount.prior.as_ref().map(to_row_major),
            controller_dh: self.record.preflight.as_ref().and_then(|p| p.kinematics.dh),
            dh_from_controller: self
                .record
                .preflight
                .as_ref()
                .is_some_and(|p| reference_dh(&p.kinematics).is_some()),
            views: Vec::new(),
        };
        for (v, q) in views.iter().enumerate() {
            let t = Instant::now();
            self.progress.stage(
                Stage::Move,
                &format!("moving to view {} of {}", v + 1, views.len()),
            );
            // A view at the start joints (eye-to-hand without targets: measure where the arm
            // stands) needs no motion at all.
            if !(v == 0 && start.as_deref() == Some(q.as_slice())) {
                self.moved = true;
                let moved = self
                    .move_to(q, Stage::Move, &format!("move to view {}", v + 1))
                    .await;
                // Also an aborted move took its time.
                self.record.timings_ms.moves += elapsed_ms(t);
                moved?;
                self.links_intact(Stage::Move)?;
            }

            let t = Instant::now();
            self.progress.stage(Stage::Settle, "letting the arm settle");
            let settle = self.cfg.camera.settle;
            cancellable(self.cancel, Stage::Settle, async {
                tokio::time::sleep(settle).await;
                Ok(())
            })
            .await?;
            self.record.timings_ms.settle += elapsed_ms(t);

            let t = Instant::now();
            let n = self.cfg.camera.capture.frames;
            self.progress.stage(
                Stage::Capture,
                &format!("capturing {n} frame(s) at view {}", v + 1),
            );
            let (capture, clouds) = self.capture(v).await?;
            self.links_intact(Stage::Capture)?;
            self.record.timings_ms.capture += elapsed_ms(t);
            let base_from_flange = crate::frames::from_row_major(&capture.base_from_flange)
                .ok_or_else(|| {
                    Failure::error(
                        Stage::Capture,
                        format!(
                            "the controller's flange pose at view {} is not a rigid transform; \
                             check the controller (nothing was written)",
                            v + 1
                        ),
                    )
                })?;
            let dh = self
                .record
                .preflight
                .as_ref()
                .and_then(|p| reference_dh(&p.kinematics));
            self.check_flange(
                Stage::Capture,
                &capture.joints,
                &base_from_flange,
                dh.as_ref(),
                &format!("at view {}", v + 1),
            )?;
            let mut record = capture;
            for (k, cloud) in clouds.into_iter().enumerate() {
                let path = if keep {
                    match storage::save_frame(&self.run_dir, v, k, &cloud) {
                        Ok(p) => Some(p),
                        Err(e) => {
                            tracing::warn!("cannot keep the raw capture: {e}");
                            None
                        }
                    }
                } else {
                    None
                };
                record.frames.push(FrameRecord {
                    path: path.as_ref().map(|p| p.display().to_string()),
                    width: cloud.width,
                    height: cloud.height,
                    valid_points: cloud.valid_count(),
                });
                frames.push(Frame {
                    view: v,
                    source: path.as_ref().map_or_else(
                        || format!("view {v} frame {k}"),
                        |p| p.display().to_string(),
                    ),
                    cloud,
                    joints: record.joints.clone(),
                    model_from_flange: Some(self.model_from_base * base_from_flange),
                    image: None,
                });
            }
            // The capture file names its scans relative to itself: a run folder can move.
            let mut portable = record.clone();
            for f in &mut portable.frames {
                f.path = f.path.as_deref().map(|p| {
                    std::path::Path::new(p)
                        .file_name()
                        .map_or_else(|| p.to_string(), |n| n.to_string_lossy().into_owned())
                });
            }
            capture_file.views.push(portable);
            self.record.captures.push(record);
        }
        if keep {
            match storage::write_capture_file(&self.run_dir, &capture_file) {
                Ok(p) => self.record.capture_file = Some(p.display().to_string()),
                Err(e) => tracing::warn!("cannot keep the capture description: {e}"),
            }
        }
        Ok(frames)
    }

    pub(super) async fn move_to(&self, q: &[f64], stage: Stage, what: &str) -> Result<(), Failure> {
        let robot = self.robot;
        let limits = self.cfg.robot.limits;
        let r = cancellable(self.cancel, stage, async {
            robot
                .move_joints(q, limits)
                .await
                .map_err(|e| Failure::robot(stage, what, e))
        })
        .await;
        if r.is_err() && self.cancel.is_cancelled() {
            // The dropped move future stops the arm; say so to the controller as well.
            if let Err(e) = robot.stop().await {
                tracing::error!("could not stop the arm after a cancel: {e}");
            }
        }
        r
    }

    /// Refuses a flange pose (`base_from_flange`, as the controller reported it with `joints`)
    /// that is not the forward kinematics of those joints: by the controller's own DH
    /// (`controller_dh`, tight) or else the nominal URDF. A corrupt or inconsistent controller
    /// value would become a wrong TCP: nothing moves or is written after this fails.
    pub(super) fn check_flange(
        &self,
        stage: Stage,
        joints: &[f64],
        base_from_flange: &Isometry3<f64>,
        controller_dh: Option<&handeye_hal::ur_dh::DhParams>,
        when: &str,
    ) -> Result<(), Failure> {
        use crate::model::reported::{check_reported_flange, FlangeReference};
        let reference = match controller_dh {
            Some(dh) => FlangeReference::ControllerDh {
                dh,
                model_from_base: &self.model_from_base,
            },
            None => FlangeReference::Nominal,
        };
        let model_from_flange = self.model_from_base * base_from_flange;
        match check_reported_flange(self.model, joints, &model_from_flange, reference) {
            Ok(Ok(())) => Ok(()),
            Ok(Err(m)) => Err(Failure::error(
                stage,
                format!(
                    "the controller's flange pose {when} {m}: the controller reports joints and \
                     a flange that do not belong together (corrupt data, or another robot \
                     model than robot.model); check the controller and the network — nothing \
                     was written"
                ),
            )),
            Err(e) => Err(Failure::error(
                stage,
                format!("the controller's joints {when}: {e}"),
            )),
        }
    }

    /// Records joints and flange pose, captures the frames, checks the arm stood still.
    pub(super) async fn capture(
        &self,
        view: usize,
    ) -> Result<(CaptureRecord, Vec<handeye_hal::PointCloud>), Failure> {
        let stage = Stage::Capture;
        let robot = self.robot;
        let camera = self.camera;
        let settings = self.cfg.camera.capture.clone();
        // A hard ceiling on the whole capture, whatever the camera does.
        let ceiling = settings.frame_timeout * settings.frames.max(1) + Duration::from_secs(5);
        cancellable(self.cancel, stage, async {
            let joints = robot
                .joint_positions()
                .await
                .map_err(|e| Failure::robot(stage, "reading the joints", e))?;
            let base_from_flange = robot
                .flange_pose()
                .await
                .map_err(|e| Failure::robot(stage, "reading the flange pose", e))?;
            let at = unix_now();
            let clouds = match tokio::time::timeout(ceiling, camera.capture(&settings)).await {
                Ok(Ok(c)) => c,
                Ok(Err(e)) => {
                    return Err(Failure::error(
                        stage,
                        format!(
                            "the camera failed to capture at view {}: {}; check the camera",
                            view + 1,
                            error_chain(&e)
                        ),
                    ))
                }
                Err(_) => {
                    return Err(Failure::error(
                        stage,
                        format!(
                            "the camera delivered no frames within {ceiling:?} at view {}; check the camera",
                            view + 1
                        ),
                    ))
                }
            };
            if clouds.len() != settings.frames as usize {
                return Err(Failure::error(
                    stage,
                    format!(
                        "the camera delivered {} frames instead of {}",
                        clouds.len(),
                        settings.frames
                    ),
                ));
            }
            let after = robot
                .joint_positions()
                .await
                .map_err(|e| Failure::robot(stage, "reading the joints", e))?;
            let change = joints
                .iter()
                .zip(&after)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            if change > MAX_JOINT_CHANGE_DURING_CAPTURE_RAD {
                return Err(Failure {
                    outcome: Outcome::Aborted,
                    stage,
                    message: format!(
                        "the arm moved by {change:.4} rad while the camera captured view {}; something else is moving the arm",
                        view + 1
                    ),
                });
            }
            Ok((
                CaptureRecord {
                    view,
                    joints,
                    base_from_flange: to_row_major(&base_from_flange),
                    unix_time_s: at,
                    joint_change_during_capture_rad: change,
                    frames: Vec::new(),
                },
                clouds,
            ))
        })
        .await
    }
}
