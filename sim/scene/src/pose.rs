//! Poses on the command line and in files: parsed as UR poses, and refused when farther from
//! their origin than what they name can be.

use handeye_hal::UrPose;
use nalgebra::Isometry3;

/// Clap value parser for a pose given as a [`UrPose`] (`x,y,z,rx,ry,rz` or `p[...]`: metres,
/// rotation vector in radians); which frames it relates is the option's to say. Print one with
/// `UrPose::from(&t)` (its `Display` is the same text).
pub fn parse_pose(s: &str) -> Result<Isometry3<f64>, String> {
    s.parse::<UrPose>()
        .map(Isometry3::from)
        .map_err(|e| e.to_string())
}

/// Farthest a camera mount (`flange_from_camera`) may be from the flange origin, metres: a
/// bracket or a long tool, not a camera across the cell.
pub const MAX_MOUNT_DISTANCE_M: f64 = 2.0;

/// Refuses a pose given by `flag` whose translation is farther than `max_m` metres.
pub fn check_pose_distance(
    flag: &str,
    pose: &Isometry3<f64>,
    max_m: f64,
    what: &str,
) -> Result<(), String> {
    let d = pose.translation.vector.norm();
    if d <= max_m {
        Ok(())
    } else {
        Err(format!(
            "{flag} is {d:.3} m from its origin: expected at most {max_m} m ({what}); poses are in metres"
        ))
    }
}

/// Refuses a camera mount (`flange_from_camera`, given by `flag`) beyond
/// [`MAX_MOUNT_DISTANCE_M`] of the flange.
pub fn check_mount(flag: &str, mount: &Isometry3<f64>) -> Result<(), String> {
    check_pose_distance(flag, mount, MAX_MOUNT_DISTANCE_M, "a camera on the flange")
}
