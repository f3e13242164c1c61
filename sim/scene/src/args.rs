//! The options that choose the simulated camera's scene (`handeye sim camera`'s, read by the
//! GenTL producer from `HANDEYE_SIM_CAMERA_ARGS`), and the parsers of poses and robots they
//! share with the rest of the command line.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context as _;
use handeye_calib::model::RobotModel;
use handeye_calib::plan::{ViewConstraints, ViewPlanner};
use handeye_calib::sim::{Intrinsics, KinematicError, SimSettings};
use handeye_gige::sim::{FrameSource, SceneSource, SimOptions, VendorHabits, IMITATIONS};
use handeye_hal::limits;
use handeye_hal::ur_dh::PhysicalArm;

use crate::pose::{check_mount, parse_pose};
use crate::scene::{
    parse_robot_addr, LiveJoints, RobotScene, SceneJoints, SceneMount, DEFAULT_MOUNT,
};

/// What the simulated camera shows, and how fast and under which serial number.
#[derive(Debug, Clone, clap::Args)]
pub struct SceneArgs {
    /// Follow this UR controller over RTDE (`IP` or `IP:PORT`, default port 30004; e.g. a
    /// `handeye sim robot`) and render the robot at the joints it measures, seen from the
    /// camera mount. Without it the robot stands still at a generated view of its base.
    #[arg(long, value_name = "ROBOT_ADDR")]
    pub robot: Option<String>,
    /// Robot model of the rendered scene.
    #[arg(long, default_value = "ur5e")]
    pub model: String,
    /// Camera mount `flange_from_camera` as `x,y,z,rx,ry,rz` (m, rotation vector rad)
    /// [default: 0,-0.08,0.04,-0.26,0,0].
    #[arg(long, value_name = "POSE", allow_hyphen_values = true)]
    pub mount: Option<String>,
    /// Sensor width in pixels.
    #[arg(long, default_value_t = DEFAULT_WIDTH)]
    pub width: u32,
    /// Sensor height in pixels.
    #[arg(long, default_value_t = DEFAULT_HEIGHT)]
    pub height: u32,
    /// Frames per second while acquiring.
    #[arg(long, default_value_t = 10.0)]
    pub frame_rate: f64,
    /// Serve the built-in plane + sphere test pattern instead of the robot.
    #[arg(long)]
    pub test_pattern: bool,
    /// TOML file with `[noise]`, `[cell]` and `[kinematic_error]` tables (see
    /// config/simulator.example.toml). Default: realistic noise and cell; kinematic error only
    /// without `--robot` (a followed robot's measured joints are rendered on the nominal model).
    #[arg(long)]
    pub settings: Option<PathBuf>,
    /// A perfect sensor in empty space: no noise, no cell, no kinematic error.
    #[arg(long, conflicts_with = "settings")]
    pub ideal: bool,
    /// Serial number to report.
    #[arg(long, default_value = "SIM0001")]
    pub serial: String,
    /// Render the physical arm with this seed, the one `handeye sim robot
    /// --factory-calibration SEED` drives.
    #[arg(long, value_name = "SEED")]
    pub factory_calibration: Option<u64>,
    /// Describe and stream as this vendor's camera does (photoneo, lucid, sick, blaze: the
    /// habits the book's camera pages list); default: by SFNC's letter.
    #[arg(long, value_name = "VENDOR", value_parser = parse_imitation)]
    pub imitate: Option<String>,
    /// Read the mount from this file (`x,y,z,rx,ry,rz`) whenever it changes: a simulator-only
    /// way to move the camera on its bracket while running (drift tests).
    #[arg(long, value_name = "FILE")]
    pub mount_file: Option<PathBuf>,
}

/// Frame rates the simulated camera serves, frames per second.
const MIN_FRAME_RATE_HZ: f64 = 0.01;
const MAX_FRAME_RATE_HZ: f64 = 120.0;
/// Sensor sizes the simulated camera renders, pixels per side.
pub const MIN_PIXELS: u32 = 16;
/// The simulated camera's size unless `--width`/`--height` say otherwise, for `sim camera`
/// and `sim rig` alike: the `compact` preset's 1280×960, what the demo and the benchmarks use.
pub const DEFAULT_WIDTH: u32 = 1280;
/// See [`DEFAULT_WIDTH`].
pub const DEFAULT_HEIGHT: u32 = 960;
/// See [`MIN_PIXELS`].
pub const MAX_PIXELS: u32 = 8192;

impl SceneArgs {
    /// The camera options these arguments set (frame rate, serial), the rest default.
    pub fn options(&self) -> SimOptions {
        SimOptions {
            frame_rate: self.frame_rate,
            serial: self.serial.clone(),
            habits: imitation(self.imitate.as_deref()),
            ..SimOptions::default()
        }
    }

    /// Checks the numbers, loads the robot, plans the view or starts following the robot
    /// (blocking: meshes load, a thread connects over RTDE), and returns the frame source
    /// with a sentence saying what it shows.
    pub fn frame_source(&self) -> anyhow::Result<(Box<dyn FrameSource>, String)> {
        limits::check_range(
            "--frame-rate",
            self.frame_rate,
            MIN_FRAME_RATE_HZ,
            MAX_FRAME_RATE_HZ,
            "frames/s",
            "",
        )
        .map_err(anyhow::Error::msg)?;
        anyhow::ensure!(
            (MIN_PIXELS..=MAX_PIXELS).contains(&self.width)
                && (MIN_PIXELS..=MAX_PIXELS).contains(&self.height),
            "--width {} --height {}: each must be {MIN_PIXELS}–{MAX_PIXELS} pixels",
            self.width,
            self.height
        );
        let robot = self.robot.as_deref().map(parse_robot_addr).transpose()?;
        if robot.is_some() && self.test_pattern {
            anyhow::bail!("--robot and --test-pattern exclude each other");
        }
        if self.test_pattern {
            return Ok((
                Box::new(SceneSource::new(self.width, self.height)),
                "built-in plane + sphere test scene".into(),
            ));
        }
        let mount = parse_pose(self.mount.as_deref().unwrap_or(DEFAULT_MOUNT))
            .map_err(|e| anyhow::anyhow!("--mount: {e}"))?;
        check_mount("--mount", &mount).map_err(anyhow::Error::msg)?;
        let model = Arc::new(RobotModel::load(
            &resolve_robot(&self.model).map_err(anyhow::Error::msg)?,
        )?);
        let settings = match (&self.settings, self.ideal) {
            (_, true) => SimSettings::ideal(),
            (Some(path), false) => SimSettings::load(path)?,
            (None, false) if robot.is_some() => SimSettings {
                // The controller's calibration is the arm's; its readings are off.
                kinematic_error: KinematicError::default().readings_only(),
                ..SimSettings::default()
            },
            (None, false) => SimSettings::default(),
        };
        let intrinsics = Intrinsics::from_fov(self.width, self.height, 60f64.to_radians());
        let (joints, scene) = match robot {
            Some(addr) => {
                anyhow::ensure!(
                    model.dof() == 6,
                    "--model {} has {} joints; a UR controller reports 6",
                    self.model,
                    model.dof()
                );
                let live = LiveJoints::follow(addr).context("starting the RTDE follower")?;
                (
                    SceneJoints::Live(live),
                    format!("{} following the robot at {addr} over RTDE", model.name()),
                )
            }
            None => {
                let planner =
                    ViewPlanner::new(&model, mount, intrinsics, ViewConstraints::default());
                let joints = planner.generate(1, 1)?.remove(0);
                let scene = format!("{} at joints {:?} rad", model.name(), joints);
                (SceneJoints::Fixed(joints), scene)
            }
        };
        let arm = match self.factory_calibration {
            Some(seed) => Some(factory_arm(&model, seed)?),
            None => None,
        };
        let source = RobotScene {
            model,
            joints,
            mount: match &self.mount_file {
                Some(path) => SceneMount::watched(mount, path.clone()),
                None => SceneMount::fixed(mount),
            },
            intrinsics,
            settings,
            arm,
            frame: 0,
        };
        Ok((Box::new(source), scene))
    }
}

/// The physical arm of a factory-calibrated `model` as the UR simulator started with
/// `--factory-calibration seed` drives it.
pub fn factory_arm(model: &RobotModel, seed: u64) -> anyhow::Result<PhysicalArm> {
    let ur = model.ur_model().ok_or_else(|| {
        anyhow::anyhow!(
            "--factory-calibration needs a UR model; {} is not one",
            model.name()
        )
    })?;
    Ok(PhysicalArm::factory(ur, seed))
}

/// Where the Debian package installs the robot models (`ur/<model>/<model>.urdf`).
pub const PACKAGED_ROBOTS: &str = "/usr/share/handeye/robots";

/// Where the robot models are: `$HANDEYE_ROBOTS`, else `../shared/robots` from the current
/// directory, else the package's [`PACKAGED_ROBOTS`], else `../shared/robots` beside the
/// source tree this was built from.
pub fn robots_dir() -> Option<std::path::PathBuf> {
    robots_dir_candidates()
        .into_iter()
        .map(|(p, _)| p)
        .find(|p| p.is_dir())
}

/// The folders [`robots_dir`] looks in, in its order, each with where it comes from
/// (`$HANDEYE_ROBOTS`, `the package`, …); the first that is a folder holds the models.
pub fn robots_dir_candidates() -> Vec<(std::path::PathBuf, &'static str)> {
    let mut out = Vec::new();
    if let Some(p) = std::env::var_os("HANDEYE_ROBOTS") {
        out.push((std::path::PathBuf::from(p), "$HANDEYE_ROBOTS"));
    }
    out.push((
        std::path::PathBuf::from("../shared/robots"),
        "beside the current directory",
    ));
    // Where the Debian package installs the UR models (packaging/deb/build.sh).
    out.push((std::path::PathBuf::from(PACKAGED_ROBOTS), "the package"));
    // This crate is `sim/scene` in the source tree.
    out.push((
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/robots"),
        "beside the source tree this was built from",
    ));
    out
}

/// A robot given as a URDF path, or as a name (`ur5e`, `kuka_iiwa7`) looked up as
/// `<name>.urdf` under [`robots_dir`].
pub fn resolve_robot(name_or_path: &str) -> Result<std::path::PathBuf, String> {
    let p = std::path::Path::new(name_or_path);
    if p.extension().is_some_and(|e| e == "urdf") || p.is_file() {
        return Ok(p.to_path_buf());
    }
    let dir = robots_dir().ok_or_else(|| {
        format!("robot `{name_or_path}`: no robot models found (looked in $HANDEYE_ROBOTS, ../shared/robots and {PACKAGED_ROBOTS}); install the package (it carries the UR models), set HANDEYE_ROBOTS to the folder of the models, or give a URDF path (robot.urdf)")
    })?;
    let urdfs = handeye_calib::model::find_urdfs(&dir);
    if let Some(u) = urdfs
        .iter()
        .find(|u| u.file_stem().is_some_and(|s| s == name_or_path))
    {
        return Ok(u.clone());
    }
    Err(not_found(name_or_path, &dir, &urdfs))
}

/// The refusal of a robot name without a model: the names there are, and the way to give a
/// URDF of one's own.
fn not_found(name: &str, dir: &std::path::Path, urdfs: &[std::path::PathBuf]) -> String {
    let mut names: Vec<String> = urdfs
        .iter()
        .filter_map(|u| u.file_stem().map(|s| s.to_string_lossy().into_owned()))
        .collect();
    names.sort();
    names.dedup();
    let available = if names.is_empty() {
        "none".to_string()
    } else {
        names.join(", ")
    };
    format!(
        "robot `{name}`: no model files (`{name}.urdf`) under {}; the models there: \
         {available}. Pick one of these, or give the arm's URDF (with its meshes) as robot.urdf",
        dir.display()
    )
}

/// `--imitate`: one of the simulated camera's imitations.
pub fn parse_imitation(s: &str) -> Result<String, String> {
    match VendorHabits::imitating(s) {
        Some(_) => Ok(s.to_owned()),
        None => Err(format!(
            "no imitation `{s}`; the simulated camera imitates {}",
            IMITATIONS
                .iter()
                .map(|(n, what)| format!("{n} ({what})"))
                .collect::<Vec<_>>()
                .join("; ")
        )),
    }
}

/// The habits of `--imitate` (checked by [`parse_imitation`]); SFNC's letter without it.
pub fn imitation(vendor: Option<&str>) -> VendorHabits {
    vendor.and_then(VendorHabits::imitating).unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_model_without_files_is_refused_naming_the_models_there() {
        let urdfs = [
            "ur/ur5e/ur5e.urdf",
            "ur/ur10e/ur10e.urdf",
            "kuka_iiwa7/kuka_iiwa7.urdf",
        ]
        .map(std::path::PathBuf::from);
        let e = not_found(
            "ur7e",
            std::path::Path::new("/usr/share/handeye/robots"),
            &urdfs,
        );
        assert!(
            e.starts_with(
                "robot `ur7e`: no model files (`ur7e.urdf`) under /usr/share/handeye/robots"
            ),
            "{e}"
        );
        assert!(
            e.contains("the models there: kuka_iiwa7, ur10e, ur5e."),
            "{e}"
        );
        assert!(e.contains("robot.urdf"), "{e}");
    }

    #[test]
    fn ur7e_ur12e_and_ur15_have_no_models_in_the_reference_set() {
        let Some(_) = robots_dir() else {
            assert!(
                std::env::var_os("CI").is_none(),
                "no robot models and CI is set"
            );
            // Counted by .ci/run's skip summary.
            handeye_hal::skips::record(
                "ur7e_ur12e_and_ur15_have_no_models_in_the_reference_set",
                "no robot models",
            );
            return;
        };
        for name in ["ur7e", "ur12e", "ur15"] {
            let e = resolve_robot(name).expect_err(name);
            assert!(e.contains("ur5e") && e.contains("ur10e"), "{e}");
        }
        resolve_robot("ur5e").expect("ur5e has its model");
    }
}
