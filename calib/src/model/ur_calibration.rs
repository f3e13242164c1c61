//! The kinematics file of UR's ROS calibration tool (`ur_calibration`'s
//! `calibration_correction`, e.g. `my_robot_calibration.yaml`): the arm's factory calibration
//! as the origins of the six URDF joints, which `ur_description` puts in its xacro as
//! `<origin xyz="${x} ${y} ${z}" rpy="${roll} ${pitch} ${yaw}"/>` of `shoulder_pan_joint`
//! (`shoulder`), `shoulder_lift_joint` (`upper_arm`), `elbow_joint` (`forearm`), and
//! `wrist_1/2/3_joint` (`wrist_1/2/3`):
//!
//! ```yaml
//! kinematics:
//!   shoulder:
//!     x: 0
//!     y: 0
//!     z: 0.1625
//!     roll: 0
//!     pitch: 0
//!     yaw: 0
//!   upper_arm: {x: 0, y: 0, z: 0, roll: 1.570796327, pitch: 0, yaw: 0}
//!   # forearm, wrist_1, wrist_2, wrist_3 alike
//!   hash: calib_209549117540498681
//! ```
//!
//! The file is a tiny fixed shape, so it is read here (block mappings, or one flow mapping per
//! joint, comments, quoted strings), not by a YAML library. Lengths m, angles rad.

use std::path::{Path, PathBuf};

use handeye_hal::limits;
use handeye_hal::ur_dh::{DhParams, Line};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

use super::{LinkNode, ModelError, Motion, QSource, RobotModel};

/// The file's entries, in joint order, with the URDF joint each one is the origin of.
pub const UR_CALIBRATION_JOINTS: [(&str, &str); 6] = [
    ("shoulder", "shoulder_pan_joint"),
    ("upper_arm", "shoulder_lift_joint"),
    ("forearm", "elbow_joint"),
    ("wrist_1", "wrist_1_joint"),
    ("wrist_2", "wrist_2_joint"),
    ("wrist_3", "wrist_3_joint"),
];

/// Keys of one joint's entry, in the order they are stored.
const FIELDS: [&str; 6] = ["x", "y", "z", "roll", "pitch", "yaw"];

/// Largest file accepted: a real one is about 1 KiB.
pub const MAX_UR_CALIBRATION_BYTES: u64 = 1 << 20;

/// Largest joint-origin offset accepted, m (the largest UR link is ~1.2 m).
const MAX_OFFSET_M: f64 = 5.0;
/// Largest roll/pitch/yaw accepted, rad (Eigen's `eulerAngles` gives up to 2π).
const MAX_ANGLE_RAD: f64 = 2.0 * std::f64::consts::TAU;

/// A `ur_calibration` kinematics file that could not be used; the message names the file, the
/// line (when there is one) and the key.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum UrCalibrationError {
    /// The file could not be read (missing, not a regular file, too large).
    #[error(
        "cannot read UR calibration {path}: {source}; give the YAML that ur_calibration wrote"
    )]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// The file is read but wrong at a line or misses a key.
    #[error("{path}:{line}: {key}: {message}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// 1-based line (the last line for a missing key).
        line: usize,
        /// The key, e.g. `kinematics.shoulder.z`.
        key: String,
        /// What is wrong.
        message: String,
    },
}

/// The calibrated kinematics of one UR arm, read from a `ur_calibration` file.
#[derive(Debug, Clone, PartialEq)]
pub struct UrCalibration {
    /// The file it was read from (recorded with the results).
    pub path: PathBuf,
    /// `[x, y, z, roll, pitch, yaw]` per joint, [`UR_CALIBRATION_JOINTS`] order: the joint's
    /// origin in its parent link (`parent_from_joint`), m and URDF rpy (rad).
    pub origins: [[f64; 6]; 6],
    /// The file's `hash` (`calib_…`), which identifies the calibration, if present.
    pub hash: Option<String>,
}

/// The file's name of entry `i` (see [`UR_CALIBRATION_JOINTS`]).
fn entry_name(i: usize) -> &'static str {
    UR_CALIBRATION_JOINTS[i].0
}

fn strip_comment(line: &str) -> &str {
    let mut quote = None;
    for (i, c) in line.char_indices() {
        match (c, quote) {
            ('"' | '\'', None) => quote = Some(c),
            (c, Some(q)) if c == q => quote = None,
            ('#', None) if i == 0 || line[..i].ends_with([' ', '\t']) => return &line[..i],
            _ => {}
        }
    }
    line
}

fn unquote(v: &str) -> &str {
    let v = v.trim();
    for q in ['"', '\''] {
        if v.len() >= 2 && v.starts_with(q) && v.ends_with(q) {
            return &v[1..v.len() - 1];
        }
    }
    v
}

impl UrCalibration {
    /// Reads and checks the file (a regular file of at most 1 MiB).
    pub fn load(path: &Path) -> Result<Self, UrCalibrationError> {
        let read = |source| UrCalibrationError::Read {
            path: path.to_path_buf(),
            source,
        };
        let text = limits::read_text_file(path, MAX_UR_CALIBRATION_BYTES).map_err(read)?;
        Self::parse(&text, path)
    }

    /// Parses the file's text; `path` names it in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Self, UrCalibrationError> {
        let err = |line: usize, key: &str, message: String| UrCalibrationError::Invalid {
            path: path.to_path_buf(),
            line,
            key: key.to_string(),
            message,
        };
        let mut values: [[Option<f64>; 6]; 6] = [[None; 6]; 6];
        let mut hash = None;
        let mut seen_root = false;
        let mut root_indent: Option<usize> = None;
        let mut child_indent: Option<usize> = None;
        // The joint whose block mapping is open, with the indent of its keys once known.
        let mut open: Option<(usize, Option<usize>)> = None;
        let mut last_line = 0;
        let set = |values: &mut [[Option<f64>; 6]; 6],
                   j: usize,
                   key: &str,
                   value: &str,
                   line: usize|
         -> Result<(), UrCalibrationError> {
            let full = format!("kinematics.{}.{key}", entry_name(j));
            let f = FIELDS.iter().position(|&k| k == key).ok_or_else(|| {
                err(
                    line,
                    &full,
                    format!("unknown key; expected one of {}", FIELDS.join(", ")),
                )
            })?;
            if values[j][f].is_some() {
                return Err(err(line, &full, "given twice".into()));
            }
            let v: f64 = unquote(value)
                .parse()
                .map_err(|_| err(line, &full, format!("`{}` is not a number", value.trim())))?;
            let (max, unit, why) = if f < 3 {
                (MAX_OFFSET_M, "m", "a joint origin of a UR arm")
            } else {
                (MAX_ANGLE_RAD, "rad", "an rpy angle")
            };
            limits::check_range(&full, v, -max, max, unit, why).map_err(|m| err(line, &full, m))?;
            values[j][f] = Some(v);
            Ok(())
        };
        for (n, raw) in text.lines().enumerate() {
            let line = n + 1;
            last_line = line;
            let content = strip_comment(raw).trim_end();
            let trimmed = content.trim_start();
            if trimmed.is_empty() || trimmed == "---" || trimmed == "..." {
                continue;
            }
            if raw.contains('\t') && raw.trim_start().len() != raw.trim_start_matches('\t').len() {
                return Err(err(
                    line,
                    "",
                    "tab in indentation (YAML allows spaces only)".into(),
                ));
            }
            let indent = content.len() - trimmed.len();
            let Some((key, value)) = trimmed.split_once(':') else {
                return Err(err(
                    line,
                    "",
                    format!("expected `key: value`, found `{trimmed}`"),
                ));
            };
            let (key, value) = (unquote(key), value.trim());
            let root = *root_indent.get_or_insert(indent);
            if indent <= root {
                open = None;
                if key != "kinematics" {
                    return Err(err(
                        line,
                        key,
                        "unknown key; the file holds `kinematics:` only".into(),
                    ));
                }
                if seen_root {
                    return Err(err(line, key, "given twice".into()));
                }
                if !value.is_empty() {
                    return Err(err(
                        line,
                        key,
                        "expected the joints on the following lines".into(),
                    ));
                }
                seen_root = true;
                continue;
            }
            if let Some((j, ref mut ind)) = open {
                let first = *ind.get_or_insert(indent);
                if indent >= first && child_indent.is_some_and(|c| indent > c) {
                    if indent != first {
                        return Err(err(
                            line,
                            key,
                            "indentation differs from the keys above".into(),
                        ));
                    }
                    set(&mut values, j, key, value, line)?;
                    continue;
                }
                open = None;
            }
            let child = *child_indent.get_or_insert(indent);
            if indent != child {
                return Err(err(
                    line,
                    key,
                    "indentation differs from the entries above".into(),
                ));
            }
            let full = format!("kinematics.{key}");
            if key == "hash" {
                if hash.is_some() {
                    return Err(err(line, &full, "given twice".into()));
                }
                hash = Some(unquote(value).to_string());
                continue;
            }
            let j = (0..6).find(|&j| entry_name(j) == key).ok_or_else(|| {
                let names: Vec<_> = (0..6).map(entry_name).collect();
                err(
                    line,
                    &full,
                    format!("unknown key; expected hash or one of {}", names.join(", ")),
                )
            })?;
            if values[j].iter().any(Option::is_some) {
                return Err(err(line, &full, "given twice".into()));
            }
            if value.is_empty() {
                open = Some((j, None));
            } else if let Some(inner) = value.strip_prefix('{').and_then(|v| v.strip_suffix('}')) {
                for item in inner.split(',').filter(|s| !s.trim().is_empty()) {
                    let (k, v) = item.split_once(':').ok_or_else(|| {
                        err(
                            line,
                            &full,
                            format!(
                                "expected `key: value` in the braces, found `{}`",
                                item.trim()
                            ),
                        )
                    })?;
                    set(&mut values, j, unquote(k), v, line)?;
                }
            } else {
                return Err(err(
                    line,
                    &full,
                    "expected x, y, z, roll, pitch, yaw below it or in braces".into(),
                ));
            }
        }
        if !seen_root {
            return Err(err(
                last_line.max(1),
                "kinematics",
                "missing; is this a ur_calibration file?".into(),
            ));
        }
        let mut origins = [[0.0; 6]; 6];
        for j in 0..6 {
            for f in 0..6 {
                origins[j][f] = values[j][f].ok_or_else(|| {
                    err(
                        last_line.max(1),
                        &format!("kinematics.{}.{}", entry_name(j), FIELDS[f]),
                        "missing".into(),
                    )
                })?;
            }
        }
        Ok(UrCalibration {
            path: path.to_path_buf(),
            origins,
            hash,
        })
    }

    /// The exact standard DH set the file's chain describes (what the controller publishes,
    /// [`DhParams::from_axes`]): the file's six entries are joint origins, each joint turning
    /// about its frame's z, the flange at the end of wrist_3. Any such chain reads back: the
    /// raw DH steps or the chain after ur_calibration's correctChain (joints 2 and 3 moved
    /// along their axes, so no entry is hundreds of metres long). `nominal` (the arm's model)
    /// picks the sense of each DH x axis, so a nominal file gives back `nominal`.
    ///
    /// Errors when the shoulder joint does not turn about the base's z axis (the frame a UR
    /// controller reports in), naming the file.
    pub fn dh(&self, nominal: &DhParams) -> Result<DhParams, String> {
        let mut at = Isometry3::identity();
        let mut axes = [Line {
            point: Vector3::zeros(),
            direction: Vector3::z(),
        }; 6];
        for (axis, origin) in axes.iter_mut().zip(self.joint_origins()) {
            at *= origin;
            *axis = Line {
                point: at.translation.vector,
                direction: at.rotation * Vector3::z(),
            };
        }
        let first = &axes[0];
        if first.direction.cross(&Vector3::z()).norm() > 1e-9
            || first.direction.z < 0.0
            || first.point.xy().norm() > 1e-9
        {
            return Err(format!(
                "{}: kinematics.{} does not turn about the base's z axis (a UR controller's \
                 frame is the shoulder's axis); the file is not a UR calibration",
                self.path.display(),
                entry_name(0)
            ));
        }
        Ok(DhParams::from_axes(&axes, &at, nominal))
    }

    /// `parent_from_joint` of each of the six joints, [`UR_CALIBRATION_JOINTS`] order.
    pub fn joint_origins(&self) -> [Isometry3<f64>; 6] {
        self.origins.map(|[x, y, z, r, p, yaw]| {
            Isometry3::from_parts(
                Translation3::new(x, y, z),
                UnitQuaternion::from_euler_angles(r, p, yaw),
            )
        })
    }
}

impl RobotModel {
    /// This model with the origins of the six UR joints (`shoulder_pan_joint` … `wrist_3_joint`,
    /// names may carry a prefix) replaced by `calibration`'s: every link beyond a joint is then
    /// posed by the calibrated kinematics, as in a URDF that `ur_description` generates from
    /// the file. Meshes, limits and every other joint stay.
    ///
    /// Errors: [`ModelError::NotUrArm`] unless the model's chain is those six joints in order.
    pub fn with_ur_calibration(
        &self,
        calibration: &UrCalibration,
    ) -> Result<RobotModel, ModelError> {
        let not_ur = |reason: String| ModelError::NotUrArm {
            robot: self.name.clone(),
            reason,
        };
        if self.dof() != 6 {
            return Err(not_ur(format!(
                "it has {} chain joints, not the 6 of a UR calibration file",
                self.dof()
            )));
        }
        for (i, (_, joint)) in UR_CALIBRATION_JOINTS.iter().enumerate() {
            if !self.joint_names[i].ends_with(joint) {
                return Err(not_ur(format!(
                    "chain joint {} is `{}`, not `{joint}`",
                    i + 1,
                    self.joint_names[i]
                )));
            }
        }
        let origins = calibration.joint_origins();
        let mut out = self.clone();
        for node in &mut out.links {
            let LinkNode {
                parent_from_joint,
                motion,
                ..
            } = node;
            if let Motion::Revolute {
                q: QSource::Chain(i),
                ..
            } = motion
            {
                *parent_from_joint = origins[*i];
            }
        }
        Ok(out)
    }
}

/// The file `ur_calibration` writes for `dh` (a controller's DH set of a `nominal` arm), with
/// `hash` as its calibration's name: the chain after correctChain, each joint's frame on its
/// axis near the nominal place ([`DhParams::near_chain`]), as xyz + URDF rpy. Like the tool's,
/// it has no entry beyond wrist_3. [`UrCalibration::dh`] reads it back to `dh`.
pub fn ur_calibration_yaml(dh: &DhParams, nominal: &DhParams, hash: &str) -> String {
    let mut s = String::from("kinematics:\n");
    for (i, t) in dh.near_chain(nominal).iter().enumerate() {
        let (r, p, y) = t.rotation.euler_angles();
        let v = t.translation.vector;
        s += &format!(
            "  {}:\n    x: {:e}\n    y: {:e}\n    z: {:e}\n    roll: {:e}\n    pitch: {:e}\n    yaw: {:e}\n",
            entry_name(i),
            v.x,
            v.y,
            v.z,
            r,
            p,
            y
        );
    }
    s + &format!("  hash: \"{hash}\"\n")
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    fn parse(text: &str) -> Result<UrCalibration, UrCalibrationError> {
        UrCalibration::parse(text, Path::new("cal.yaml"))
    }

    const UR5E: &str = "kinematics:\n  shoulder:\n    x: 0\n    y: 0\n    z: 0.1625\n    roll: 0\n    pitch: 0\n    yaw: 0\n  upper_arm: {x: 0, y: 0, z: 0, roll: 1.570796327, pitch: 0, yaw: 0}\n  forearm: {x: -0.425, y: 0, z: 0, roll: 0, pitch: 0, yaw: 0}  # comment\n  wrist_1: {x: -0.3922, y: 0, z: 0.1333, roll: 0, pitch: 0, yaw: 0}\n  wrist_2: {x: 0, y: -0.0997, z: -2.044881182297852e-11, roll: 1.570796327, pitch: 0, yaw: 0}\n  wrist_3: {x: 0, y: 0.0996, z: -2.042830148012698e-11, roll: 1.570796326589793, pitch: 3.141592653589793, yaw: 3.141592653589793}\n  hash: calib_209549117540498681\n";

    #[test]
    fn parses_block_and_flow_entries() {
        let c = parse(UR5E).expect("parses");
        assert_eq!(c.origins[0][2], 0.1625);
        assert_eq!(c.origins[2][0], -0.425);
        assert_eq!(c.origins[5][4], std::f64::consts::PI);
        assert_eq!(c.hash.as_deref(), Some("calib_209549117540498681"));
    }

    #[test]
    fn errors_name_file_line_and_key() {
        let msg = |t: &str| parse(t).expect_err("refused").to_string();
        let m = msg(&UR5E.replace("    z: 0.1625\n", ""));
        assert!(
            m.starts_with("cal.yaml:") && m.contains("kinematics.shoulder.z: missing"),
            "{m}"
        );
        let m = msg(&UR5E.replace("z: 0.1625", "z: .nan"));
        assert!(m.starts_with("cal.yaml:5: kinematics.shoulder.z:"), "{m}");
        let m = msg(&UR5E.replace("z: 0.1625", "z: 1e9"));
        assert!(m.starts_with("cal.yaml:5: kinematics.shoulder.z:"), "{m}");
        let m = msg(&UR5E.replace("z: 0.1625", "z: abc"));
        assert!(m.contains("not a number"), "{m}");
        let m = msg(&UR5E.replace("x: -0.425", "q: -0.425"));
        assert!(
            m.starts_with("cal.yaml:10: kinematics.forearm.q: unknown key"),
            "{m}"
        );
        let m = msg(&UR5E.replace("wrist_1:", "wrist_9:"));
        assert!(m.contains(":11: kinematics.wrist_9: unknown key"), "{m}");
        let m = msg("robot: {}\n");
        assert!(m.contains(":1: robot: unknown key"), "{m}");
        let m = msg("");
        assert!(m.contains("kinematics: missing"), "{m}");
        let m = msg(&format!("{UR5E}  shoulder: {{x: 0}}\n"));
        assert!(m.contains("kinematics.shoulder: given twice"), "{m}");
    }

    #[test]
    fn load_refuses_directories_and_missing_files() {
        let dir = std::env::temp_dir();
        assert!(matches!(
            UrCalibration::load(&dir),
            Err(UrCalibrationError::Read { .. })
        ));
        let missing = dir.join("handeye-no-such-calibration.yaml");
        let e = UrCalibration::load(&missing).expect_err("missing");
        assert!(
            e.to_string().contains("handeye-no-such-calibration.yaml"),
            "{e}"
        );
    }

    /// The model posed with a file written from calibrated DH puts the flange where the DH
    /// forward kinematics does (the controller's `actual_TCP_pose` with a zero TCP).
    #[test]
    fn the_file_gives_back_the_dh_it_was_written_from() {
        for seed in [1, 5, 9] {
            // A real controller's DH: joints 2 and 3 hundreds of metres along their axes.
            let dh =
                handeye_hal::ur_dh::PhysicalArm::factory(handeye_hal::ur_dh::UrModel::Ur10e, seed)
                    .controller_dh();
            let mut want = dh;
            (want.a[5], want.alpha[5]) = (0.0, 0.0);
            let nominal = handeye_hal::ur_dh::UrModel::Ur10e.dh();
            let text = ur_calibration_yaml(&dh, &nominal, "calib_12345");
            // After correctChain: no entry is far from the arm.
            let file = parse(&text).expect("parses");
            for o in file.joint_origins() {
                assert!(o.translation.vector.norm() < 1.0, "{text}");
            }
            let got = file.dh(&nominal).expect("a UR chain");
            // The same arm: the forward kinematics agree (the huge d of nearly parallel axes
            // come back to a few µm of their hundreds of metres, which the kinematics do not
            // feel), the other parameters to rounding.
            for q in [
                [0.0; 6],
                [0.4, -1.2, 1.1, -1.3, -1.5, 0.2],
                [2.0, -2.5, -1.0, 2.2, 0.3, -3.0],
            ] {
                let (g, w) = (got.forward(&q), want.forward(&q));
                assert!((g.translation.vector - w.translation.vector).norm() < 1e-9);
                assert!(g.rotation.angle_to(&w.rotation) < 1e-9);
            }
            for (g, w) in [
                (got.a, want.a),
                (got.alpha, want.alpha),
                (got.theta, want.theta),
            ] {
                for k in 0..6 {
                    assert!(
                        (g[k] - w[k]).abs() < 1e-6,
                        "seed {seed}: {got:?} vs {want:?}"
                    );
                }
            }
        }
        // Any chain of joints turning about their z reads back, a shoulder off the base's z
        // axis is named.
        let nominal = handeye_hal::ur_dh::UrModel::Ur5e.dh();
        let file = parse(UR5E).expect("parses");
        let got = file.dh(&nominal).expect("the nominal file");
        assert!(
            (got.forward(&[0.3; 6]).translation.vector
                - nominal.forward(&[0.3; 6]).translation.vector)
                .norm()
                < 1e-9
        );
        let text = UR5E.replace(
            "x: 0\n    y: 0\n    z: 0.1625",
            "x: 0.01\n    y: 0\n    z: 0.1625",
        );
        assert_ne!(text, UR5E);
        let e = parse(&text)
            .expect("parses")
            .dh(&nominal)
            .expect_err("off the axis");
        assert!(e.contains("kinematics.shoulder"), "{e}");
    }

    #[test]
    fn file_posed_model_matches_calibrated_dh() {
        let Some(dir) = crate::testutil::shared_robots() else {
            return;
        };
        let mut rng = StdRng::seed_from_u64(17);
        for name in ["ur5e", "ur10e", "ur3", "ur20"] {
            let m = RobotModel::load(&dir.join("ur").join(name).join(format!("{name}.urdf")))
                .expect("loads");
            let nominal = m.ur_model().expect("a UR arm").dh();
            // The nominal file is the URDF itself.
            let same = m
                .with_ur_calibration(
                    &parse(&ur_calibration_yaml(&nominal, &nominal, "calib_12345"))
                        .expect("parses"),
                )
                .expect("posed");
            let q: [f64; 6] = std::array::from_fn(|_| rng.random_range(-3.0..3.0));
            let (a, b) = (
                same.link_poses(&q).expect("fk"),
                m.link_poses(&q).expect("fk"),
            );
            for (x, y) in a.iter().zip(&b) {
                assert!(
                    (x.translation.vector - y.translation.vector).norm() < 1e-9,
                    "{name}"
                );
                assert!(x.rotation.angle_to(&y.rotation) < 1e-9, "{name}");
            }
            // The file has no entry beyond wrist_3 (a controller's DH has a_6 = α_6 = 0).
            let mut calibrated =
                handeye_hal::ur_dh::PhysicalArm::factory(m.ur_model().expect("a UR arm"), 5)
                    .controller_dh();
            (calibrated.a[5], calibrated.alpha[5]) = (0.0, 0.0);
            let posed = m
                .with_ur_calibration(
                    &parse(&ur_calibration_yaml(&calibrated, &nominal, "calib_12345"))
                        .expect("parses"),
                )
                .expect("posed");
            let (mut worst_t, mut worst_r) = (0.0f64, 0.0f64);
            for _ in 0..50 {
                let q: [f64; 6] = std::array::from_fn(|_| rng.random_range(-3.0..3.0));
                let flange = posed.frame_pose("tool0", &q).expect("tool0");
                let want = posed.frame_pose("base", &q).expect("base") * calibrated.forward(&q);
                let d = flange.inverse() * want;
                worst_t = worst_t.max(d.translation.vector.norm());
                worst_r = worst_r.max(d.rotation.angle());
                let nominal_flange = m.frame_pose("tool0", &q).expect("tool0");
                assert!(
                    (nominal_flange.translation.vector - flange.translation.vector).norm() > 1e-5,
                    "{name}: the calibration moved the flange"
                );
            }
            eprintln!("{name}: flange vs calibrated DH: {worst_t:.2e} m, {worst_r:.2e} rad");
            assert!(
                worst_t < 1e-6 && worst_r < 1e-6,
                "{name}: {worst_t:e} m {worst_r:e} rad"
            );
        }
    }
}
