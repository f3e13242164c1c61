//! [`MotionGuard`]: the one place every move of the arm is checked, whoever asks for it — a
//! calibration run (its views, its return), the daemon's runs (API, schedule, pendant) and
//! `handeye robot move`. It wraps any hal [`Robot`] (openrr's limiter pattern): before a
//! `move_joints` reaches the arm it checks the straight joint-space path from where the arm is
//! to the target with the planner's check (joint limits, floor clearance, self-collision, the
//! configured obstacles, the camera included) and caps speed and acceleration at the
//! configured values. A refused move never reaches the robot: nothing moves.

use std::sync::Arc;

use handeye_hal::ur_dh::UrModel;
use handeye_hal::ur_limits::UrLimits;
use handeye_hal::{HalError, MotionLimits, Robot, RobotStatus};
use nalgebra::{Isometry3, Vector3};

use crate::calib::{pipeline, Mount};
use crate::config::Config;
use crate::model::RobotModel;
pub use crate::plan::PATH_STEP_RAD;
use crate::plan::{Obstacle, ViewConstraints, ViewPlanner};
use crate::sim::Intrinsics;

/// What every move must respect: the arm's model, the camera on it, the floor, the obstacles
/// and the speed caps of one cell.
#[derive(Debug, Clone)]
pub struct Cell {
    model: Arc<RobotModel>,
    /// Where the camera sits on the flange (eye-in-hand; identity otherwise): it must clear
    /// the floor and the obstacles too.
    flange_from_camera: Isometry3<f64>,
    /// Links beyond the shoulder and the camera stay this high above the mounting plane, m.
    floor_clearance_m: f64,
    /// Boxes no link and not the camera may touch (model frame).
    obstacles: Vec<Obstacle>,
    /// Highest joint speed any move may use, rad/s.
    max_joint_speed_rad_s: f64,
    /// Highest joint acceleration any move may use, rad/s².
    max_joint_accel_rad_s2: f64,
    /// What the arm's joints can do (the hal's UR limits table): the caps never exceed it.
    arm: UrLimits,
}

/// `model_from_base`: the controller's `base` frame in the model root (URDF `base_link`).
pub fn model_from_base(model: &RobotModel) -> Isometry3<f64> {
    match pipeline::fixed_frame(model, "base") {
        Ok(p) => p,
        // Not a UR URDF with a `base` link: the controller frame is the URDF root turned by π.
        Err(_) => crate::frames::ur_base_from_base_link().inverse(),
    }
}

/// The camera's pose on the flange as the configuration gives it (the mount prior; identity
/// when unknown or eye-to-hand).
pub fn configured_flange_from_camera(cfg: &Config) -> Isometry3<f64> {
    match cfg.mount.mount {
        Mount::EyeInHand => cfg.mount.prior.unwrap_or_else(Isometry3::identity),
        Mount::EyeToHand => Isometry3::identity(),
    }
}

/// The configured obstacles (`[[views.obstacles]]`, in the controller's `base` frame) in the
/// model frame.
pub fn configured_obstacles(cfg: &Config, model_from_base: &Isometry3<f64>) -> Vec<Obstacle> {
    cfg.views
        .obstacles
        .iter()
        .map(|o| Obstacle {
            name: o.name.clone(),
            model_from_box: model_from_base
                * Isometry3::translation(o.centre_m[0], o.centre_m[1], o.centre_m[2]),
            half_extents_m: Vector3::from(o.size_m) / 2.0,
        })
        .collect()
}

impl Cell {
    /// The cell a configuration describes, for the arm `model`.
    pub fn from_config(model: Arc<RobotModel>, cfg: &Config) -> Cell {
        let obstacles = configured_obstacles(cfg, &model_from_base(&model));
        Cell {
            model,
            flange_from_camera: configured_flange_from_camera(cfg),
            floor_clearance_m: cfg.views.floor_clearance_m,
            obstacles,
            max_joint_speed_rad_s: cfg.robot.limits.max_joint_speed_rad_s,
            max_joint_accel_rad_s2: cfg.robot.limits.max_joint_accel_rad_s2,
            arm: cfg.robot.model.limits(),
        }
    }

    /// A cell known only by its arm (`model`, a UR `ur`; no configuration): no camera, no
    /// obstacles, the default floor clearance, and the given caps.
    pub fn bare(model: Arc<RobotModel>, ur: UrModel, caps: MotionLimits) -> Cell {
        Cell {
            model,
            flange_from_camera: Isometry3::identity(),
            floor_clearance_m: ViewConstraints::default().floor_clearance_m,
            obstacles: Vec::new(),
            max_joint_speed_rad_s: caps.max_joint_speed_rad_s,
            max_joint_accel_rad_s2: caps.max_joint_accel_rad_s2,
            arm: ur.limits(),
        }
    }

    /// The planner that checks motions in this cell.
    fn planner(&self) -> ViewPlanner<'_> {
        let constraints = ViewConstraints {
            floor_clearance_m: self.floor_clearance_m,
            ..ViewConstraints::default()
        };
        ViewPlanner::new(
            &self.model,
            self.flange_from_camera,
            Intrinsics::compact_1280x960(),
            constraints,
        )
        .with_obstacles(self.obstacles.clone())
    }

    /// Whether the straight joint-space path `from` → `to` is safe; why not, in a sentence
    /// that says nothing moved. Blocks for the check (milliseconds to a few hundred).
    pub fn check_path(&self, from: &[f64], to: &[f64]) -> Result<(), String> {
        if to.len() != self.model.dof() || to.iter().any(|v| !v.is_finite()) {
            return Err(format!(
                "the target must be {} finite joint angles (got {:?}); nothing moved",
                self.model.dof(),
                to
            ));
        }
        match self.planner().check_path(from, to, PATH_STEP_RAD) {
            Ok(Ok(_)) => Ok(()),
            Ok(Err(r)) => Err(format!(
                "the path to {} is not safe: {r}; nothing moved (choose another target, or \
                 move the arm on the pendant)",
                joints_text(to)
            )),
            Err(e) => Err(format!("cannot check the path: {e}; nothing moved")),
        }
    }

    /// `limits` within the cell's caps and what the arm can do.
    pub fn capped(&self, limits: MotionLimits) -> MotionLimits {
        self.arm.cap(MotionLimits {
            max_joint_speed_rad_s: limits.max_joint_speed_rad_s.min(self.max_joint_speed_rad_s),
            max_joint_accel_rad_s2: limits
                .max_joint_accel_rad_s2
                .min(self.max_joint_accel_rad_s2),
            timeout: limits.timeout,
        })
    }
}

fn joints_text(q: &[f64]) -> String {
    let deg: Vec<String> = q.iter().map(|v| format!("{:.1}", v.to_degrees())).collect();
    format!("[{}]°", deg.join(", "))
}

/// A [`Robot`] whose every move is checked against its [`Cell`] and capped in speed first.
/// Everything else passes through unchanged.
#[derive(Debug, Clone)]
pub struct MotionGuard<R> {
    inner: R,
    cell: Arc<Cell>,
}

impl<R: Robot> MotionGuard<R> {
    /// Guards `robot` in `cell`.
    pub fn new(robot: R, cell: Cell) -> Self {
        Self {
            inner: robot,
            cell: Arc::new(cell),
        }
    }

    /// The guarded robot (for what the hal trait does not cover).
    pub fn inner(&self) -> &R {
        &self.inner
    }
}

impl<R: Robot> Robot for MotionGuard<R> {
    async fn status(&self) -> Result<RobotStatus, HalError> {
        self.inner.status().await
    }

    async fn joint_positions(&self) -> Result<Vec<f64>, HalError> {
        self.inner.joint_positions().await
    }

    async fn flange_pose(&self) -> Result<Isometry3<f64>, HalError> {
        self.inner.flange_pose().await
    }

    async fn move_joints(&self, q: &[f64], limits: MotionLimits) -> Result<(), HalError> {
        let from = self
            .inner
            .joint_positions()
            .await
            .map_err(HalError::before_move)?;
        let cell = Arc::clone(&self.cell);
        let to = q.to_vec();
        let checked = tokio::task::spawn_blocking(move || cell.check_path(&from, &to))
            .await
            .map_err(|e| HalError::InvalidArgument(format!("the path check failed: {e}")))?;
        if let Err(reason) = checked {
            tracing::info!("move refused: {reason}");
            return Err(HalError::Refused {
                device: "the motion guard".into(),
                request: "the move".into(),
                reason,
            });
        }
        self.inner.move_joints(q, self.cell.capped(limits)).await
    }

    async fn stop(&self) -> Result<(), HalError> {
        self.inner.stop().await
    }

    async fn power_on(&self) -> Result<(), HalError> {
        self.inner.power_on().await
    }

    async fn set_tcp(&self, flange_from_tcp: &Isometry3<f64>) -> Result<(), HalError> {
        self.inner.set_tcp(flange_from_tcp).await
    }

    async fn write_double_register(&self, index: u32, value: f64) -> Result<(), HalError> {
        self.inner.write_double_register(index, value).await
    }

    async fn read_double_register(&self, index: u32) -> Result<f64, HalError> {
        self.inner.read_double_register(index).await
    }

    async fn write_int_register(&self, index: u32, value: i32) -> Result<(), HalError> {
        self.inner.write_int_register(index, value).await
    }

    async fn read_int_register(&self, index: u32) -> Result<i32, HalError> {
        self.inner.read_int_register(index).await
    }

    async fn read_output_int_register(&self, index: u32) -> Result<i32, HalError> {
        self.inner.read_output_int_register(index).await
    }

    async fn tcp_offset(&self) -> Result<Isometry3<f64>, HalError> {
        self.inner.tcp_offset().await
    }

    async fn kinematics(&self) -> Result<Option<handeye_hal::ControllerKinematics>, HalError> {
        self.inner.kinematics().await
    }

    async fn identity(&self) -> Result<handeye_hal::ControllerIdentity, HalError> {
        self.inner.identity().await
    }

    fn link_generation(&self) -> u64 {
        self.inner.link_generation()
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;
    use crate::testutil::shared_robot;

    /// The guard caps every move at the configured caps and at what the arm can do (the
    /// hal's UR limits table): a UR10e's base turns at 2π/3 rad/s whatever is asked.
    #[test]
    fn moves_are_capped_at_the_caps_and_the_arm_s_limits() {
        let Some(model) = shared_robot("ur/ur10e/ur10e.urdf") else {
            return;
        };
        let generous = MotionLimits {
            max_joint_speed_rad_s: 3.1,
            max_joint_accel_rad_s2: 60.0,
            timeout: Duration::from_secs(9),
        };
        let cell = Cell::bare(Arc::clone(&model), UrModel::Ur10e, generous);
        let capped = cell.capped(generous);
        assert_eq!(
            capped.max_joint_speed_rad_s,
            UrModel::Ur10e.limits().move_speed_rad_s()
        );
        assert_eq!(capped.max_joint_accel_rad_s2, 40.0);
        assert_eq!(capped.timeout, Duration::from_secs(9));
        // The configured caps, when lower, win.
        let careful = MotionLimits {
            max_joint_speed_rad_s: 0.25,
            max_joint_accel_rad_s2: 0.5,
            timeout: Duration::from_secs(9),
        };
        let cell = Cell::bare(model, UrModel::Ur10e, careful);
        assert_eq!(cell.capped(generous), careful);
    }
}
