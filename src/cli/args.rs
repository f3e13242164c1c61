//! Parsers for values given on the command line.

use handeye::model::{KinematicError, MAX_KINEMATIC_SIGMA};
pub(crate) use handeye_sim_scene::{
    check_mount, check_pose_distance, parse_pose, resolve_robot, robots_dir, MAX_MOUNT_DISTANCE_M,
};

/// Joint angles in radians from one command-line value (`q1,q2,...`).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct JointList(pub(crate) Vec<f64>);

/// Parses comma-separated joint angles in radians.
pub(crate) fn parse_joints(s: &str) -> Result<JointList, String> {
    let v = parse_numbers(s)?;
    if v.is_empty() {
        return Err("expected comma-separated joint angles in radians".into());
    }
    Ok(JointList(v))
}

/// Parses `offset,length,misalignment[,housing_shift,housing_turn]` — the 1σ of each joint's
/// zero offset (mrad), link length (mm) and axis misalignment (mrad) of the real arm against
/// its URDF, and of each link housing's shift (mm) and turn (mrad) off its link's frame
/// (default: a manufactured arm's 0.3 mm / 0.3 mrad).
pub(crate) fn parse_kinematic_error(s: &str) -> Result<KinematicError, String> {
    let v = parse_numbers(s)?;
    // 1σ in mrad / mm: a real arm is within tenths of its model, and beyond this limit the
    // propagated uncertainty is meaningless (1e160 made it 0 and the result accepted).
    let max = MAX_KINEMATIC_SIGMA * 1e3;
    let joints = |offset: f64, length: f64, misalignment: f64| KinematicError {
        joint_offset_sigma_rad: offset * 1e-3,
        link_length_sigma_m: length * 1e-3,
        axis_misalignment_sigma_rad: misalignment * 1e-3,
        ..KinematicError::default()
    };
    match v[..] {
        _ if !v.iter().all(|x| (0.0..=max).contains(x)) => Err(()),
        [offset, length, misalignment] => Ok(joints(offset, length, misalignment)),
        [offset, length, misalignment, shift, turn] => Ok(KinematicError {
            housing_translation_sigma_m: shift * 1e-3,
            housing_rotation_sigma_rad: turn * 1e-3,
            ..joints(offset, length, misalignment)
        }),
        _ => Err(()),
    }
    .map_err(|()| {
        format!(
            "expected 3 or 5 numbers from 0 to {max}: offset_mrad,length_mm,misalignment_mrad[,housing_shift_mm,housing_turn_mrad] (e.g. 0.3,0.3,0.3; 0,0,0 when the URDF is the controller's calibrated kinematics; 0,0,0,0,0 for an arm exactly its model), got `{}`",
            handeye_hal::limits::Quoted(s)
        )
    })
}

/// Farthest a camera fixed in the cell may be from the robot's root frame, metres.
pub(crate) const MAX_CELL_CAMERA_DISTANCE_M: f64 = 20.0;

/// Refuses joint values (given by `flag`) outside the model's joint limits (with 1 mrad of
/// slack for rounding; continuous joints take any finite angle); the message names the joint
/// and its limits.
pub(crate) fn check_joint_limits(
    flag: &str,
    model: &handeye::model::RobotModel,
    q: &[f64],
) -> Result<(), String> {
    for (i, (v, lim)) in q.iter().zip(model.joint_limits()).enumerate() {
        // A continuous joint takes any angle.
        if model.joint_is_continuous(i) && v.is_finite() {
            continue;
        }
        if !(*v >= lim.lower - 1e-3 && *v <= lim.upper + 1e-3) {
            return Err(format!(
                "{flag} value {} (joint `{}`) = {v}: outside its limits [{}, {}] (radians, metres for prismatic joints)",
                i + 1,
                model.joint_names()[i],
                lim.lower,
                lim.upper
            ));
        }
    }
    Ok(())
}

/// Parses a positive finite distance in metres.
pub(crate) fn parse_distance(s: &str) -> Result<f64, String> {
    match parse_numbers(s)?[..] {
        [d] if d > 0.0 && d <= 10.0 => Ok(d),
        _ => Err(format!(
            "expected one distance above 0 and at most 10 metres (e.g. 0.3), got `{}`",
            handeye_hal::limits::Quoted(s)
        )),
    }
}

/// `--max-uncertainty`: the gate's largest 1σ per frame, `mm,degrees`, in the cell config's
/// ranges for the same `[gate]` keys.
pub(crate) fn parse_max_uncertainty(s: &str) -> Result<(f64, f64), String> {
    let expected = |why: &str| {
        format!(
            "expected the largest position σ in mm and rotation σ in degrees ({why}), e.g. `5,0.5`; got `{}`",
            handeye_hal::limits::Quoted(s)
        )
    };
    match parse_numbers(s)?[..] {
        [mm, deg] => handeye::config::check_gate_uncertainty(mm, deg).map_err(|e| expected(&e)),
        _ => Err(expected("two numbers")),
    }
}

pub(crate) fn parse_numbers(s: &str) -> Result<Vec<f64>, String> {
    s.split(',')
        .map(|t| {
            let t = t.trim();
            t.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    format!(
                        "`{}` is not a finite number",
                        handeye_hal::limits::Quoted(t)
                    )
                })
        })
        .collect()
}

/// An error and its causes as one line for the operator (`a: b: c`, as `{:#}` prints it),
/// with every cause whose text the message before it already contains left out (an error
/// that quotes its OS error and also chains it would say it twice), bad input echoed bounded
/// and escaped ([`handeye_hal::limits::sanitize_message`]).
pub(crate) fn error_text(e: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in e.chain() {
        let part = cause.to_string();
        if text.contains(&part) {
            continue;
        }
        if !text.is_empty() {
            text.push_str(": ");
        }
        text.push_str(&part);
    }
    handeye_hal::limits::sanitize_message(&text)
}

/// [`robots_dir`] for a test: `None` after a SKIP line (written past the test harness's
/// capture, so it shows when the test passes); a failure when env `CI` is set.
#[cfg(test)]
pub(crate) fn robots_dir_or_skip(test: &str) -> Option<std::path::PathBuf> {
    let dir = robots_dir();
    if dir.is_none() {
        assert!(
            std::env::var_os("CI").is_none(),
            "{test}: no robot models (../shared/robots or HANDEYE_ROBOTS) and CI is set"
        );
        handeye::skips::record(test, "no robot models (../shared/robots or HANDEYE_ROBOTS)");
    }
    dir
}

#[cfg(test)]
mod tests {
    use super::*;
    use handeye_hal::UrPose;

    #[test]
    fn the_gate_limits_are_two_positive_numbers_in_range() {
        assert_eq!(parse_max_uncertainty("5, 0.5"), Ok((5.0, 0.5)));
        for bad in ["5", "5,0.5,1", "0,0.5", "5,-1", "2000,1", "5,200"] {
            let e = parse_max_uncertainty(bad).expect_err(bad);
            assert!(e.contains("e.g. `5,0.5`"), "{bad}: {e}");
        }
        for bad in ["x,1", "nan,1"] {
            let e = parse_max_uncertainty(bad).expect_err(bad);
            assert!(e.contains("is not a finite number"), "{bad}: {e}");
        }
    }

    #[test]
    fn poses_round_trip_and_errors_name_the_problem() {
        let t = parse_pose("0.1, -0.2,0.3,0,0,1.5").expect("valid");
        assert!((t.rotation.angle() - 1.5).abs() < 1e-12);
        let back = parse_pose(&UrPose::from(&t).to_string()).expect("valid");
        assert!((back.to_homogeneous() - t.to_homogeneous()).norm() < 1e-6);
        assert!(parse_pose("1,2,3")
            .expect_err("invalid")
            .contains("expected 6"));
        assert!(parse_pose("1,2,3,4,5,x")
            .expect_err("invalid")
            .contains("`x`"));
        assert!(parse_joints("0,nan").is_err());
        assert_eq!(parse_joints("0,1.5").expect("valid").0, vec![0.0, 1.5]);
    }

    #[test]
    fn issue_16_error_text_says_the_os_error_once_and_bounds_tokens() {
        let os = std::io::Error::from_raw_os_error(2);
        let e = anyhow::Error::new(std::io::Error::new(os.kind(), os.to_string()))
            .context(format!("cannot open x.ply: {os}; check the path"))
            .context("reading scan x.ply");
        let text = error_text(&e);
        assert_eq!(text.matches("os error 2").count(), 1, "{text}");
        assert!(
            text.starts_with("reading scan x.ply: cannot open x.ply"),
            "{text}"
        );
        let long = format!("bad `{}\u{1b}[2J`", "x".repeat(10 << 20));
        let text = error_text(&anyhow::anyhow!(long));
        assert!(
            text.len() < 1200 && !text.contains('\u{1b}'),
            "{}",
            text.len()
        );
    }

    #[test]
    fn distances_are_positive_metres() {
        assert_eq!(parse_distance("0.45"), Ok(0.45));
        for bad in ["0", "-0.3", "0.3,0.4", "inf", "far"] {
            let e = parse_distance(bad).expect_err(bad);
            assert!(e.contains("metres") || e.contains("finite"), "{bad}: {e}");
        }
    }

    #[test]
    fn kinematic_error_is_read_in_mrad_and_mm() {
        assert_eq!(
            parse_kinematic_error("0.3,0.3,0.3").expect("valid"),
            KinematicError::default()
        );
        assert_eq!(
            parse_kinematic_error("0,0,0").expect("valid"),
            KinematicError {
                housing_translation_sigma_m: 3e-4,
                housing_rotation_sigma_rad: 3e-4,
                ..KinematicError::default().readings_only()
            }
        );
        // The joints' and housings' errors; the readings' errors are the arm's class.
        assert_eq!(
            parse_kinematic_error("0,0,0,0,0").expect("valid"),
            KinematicError::default().readings_only()
        );
        let housed = parse_kinematic_error("0,0,0,0.5,0.2").expect("valid");
        assert_eq!(housed.housing_translation_sigma_m, 0.5e-3);
        assert_eq!(housed.housing_rotation_sigma_rad, 0.2e-3);
        for bad in [
            "0.3,0.3",
            "0.3,-0.3,0.1",
            "0.3,0.3,0.1,0",
            "0.3,0.3,0.1,0,0,0",
            "a,b,c",
            "1e160,0.3,0.1",
            "0.3,51,0.1",
        ] {
            let e = parse_kinematic_error(bad).expect_err(bad);
            assert!(
                e.contains("offset_mrad,length_mm,misalignment_mrad") || e.contains("finite"),
                "{e}"
            );
        }
    }
}
