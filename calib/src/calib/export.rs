//! A calibration result as files other tools read: our own JSON and TOML (the transform and its
//! inverse in every common representation), ROS `static_transform_publisher` command lines, a
//! TF YAML and a URDF fixed joint.
//!
//! The result is `parent_from_child` (maps points in `child` to `parent`): eye-in-hand
//! `flange_from_camera` with parent `tool0` (or `flange`), eye-to-hand `base_from_camera` with
//! parent `base` (the controller's base frame). Metres and radians throughout, except the fields
//! and names that say `mm` or `deg`. Quaternions are unit and have `w >= 0`.
//!
//! The files' contents only ([`Exports::files`]); the run folder writes them
//! (`crate::storage`), each atomically.

use std::borrow::Cow;

use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// `result.json`: [`ResultFile`] as JSON.
pub const RESULT_JSON: &str = "result.json";
/// `result.toml`: [`ResultFile`] as TOML.
pub const RESULT_TOML: &str = "result.toml";
/// ROS 2 and ROS 1 `static_transform_publisher` command lines.
pub const STATIC_TRANSFORM_PUBLISHER: &str = "static_transform_publisher.txt";
/// A TF YAML (geometry_msgs/TransformStamped layout).
pub const TF_YAML: &str = "tf.yaml";
/// A URDF `<joint type="fixed">` from parent to child.
pub const URDF_JOINT: &str = "urdf_joint.xml";

/// What the caller knows about the result beyond the transform.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExportMeta {
    /// Run identifier.
    pub run_id: String,
    /// Outcome of the run (e.g. `passed`).
    pub outcome: String,
    /// 1-σ position uncertainty, mm; not finite = unknown (left out of the files).
    pub uncertainty_translation_mm: f64,
    /// 1-σ rotation uncertainty, degrees; not finite = unknown (left out of the files).
    pub uncertainty_rotation_deg: f64,
    /// When the result was obtained, as the caller formats it (RFC 3339 recommended).
    pub timestamp: String,
}

/// One rigid transform `parent_from_child` in every representation the files use.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TransformRecord {
    /// Frame the transform maps into (the `frame_id` of ROS).
    pub parent: String,
    /// Frame the transform maps from (the `child_frame_id` of ROS).
    pub child: String,
    /// Homogeneous 4×4, row-major, translation in metres.
    pub matrix_row_major: [[f64; 4]; 4],
    /// Position of the child's origin in the parent frame, m.
    pub translation_m: [f64; 3],
    /// The same, mm.
    pub translation_mm: [f64; 3],
    /// Rotation vector (axis × angle, angle in [0, π]), rad.
    pub rotation_vector_rad: [f64; 3],
    /// Unit quaternion `[x, y, z, w]`, `w >= 0`.
    pub quaternion_xyzw: [f64; 4],
    /// URDF `rpy`: fixed-axis roll about x, then pitch about y, then yaw about z, rad.
    pub rpy_rad: [f64; 3],
    /// The same pose as UR's `p[x, y, z, rx, ry, rz]` (m, rotation vector rad), e.g. for
    /// `set_tcp()` (eye-in-hand) or a pendant feature (eye-to-hand).
    pub ur_pose: String,
}

/// Contents of `result.json` / `result.toml`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResultFile {
    /// How to read `transform` and `inverse`.
    pub convention: String,
    /// Run identifier.
    pub run_id: String,
    /// Outcome of the run.
    pub outcome: String,
    /// When the result was obtained.
    pub timestamp: String,
    /// 1-σ position uncertainty, mm (absent when unknown).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uncertainty_translation_mm: Option<f64>,
    /// 1-σ rotation uncertainty, degrees (absent when unknown).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uncertainty_rotation_deg: Option<f64>,
    /// The result, `parent_from_child`.
    pub transform: TransformRecord,
    /// Its inverse, `child_from_parent` (`parent` and `child` swapped).
    pub inverse: TransformRecord,
}

/// A result rendered into every export format ([`Exports::files`]); the run folder writes them.
#[derive(Debug, Clone, PartialEq)]
pub struct Exports {
    result: ResultFile,
    json: String,
    toml: String,
    static_transform_publisher: String,
    tf_yaml: String,
    urdf_joint: String,
}

impl Exports {
    /// Renders `parent_from_child` (maps points in `child` to `parent`, metres) with the frame
    /// names and the caller's `meta`.
    pub fn new(
        parent_from_child: &Isometry3<f64>,
        parent: &str,
        child: &str,
        meta: ExportMeta,
    ) -> Self {
        let known = |v: f64| v.is_finite().then_some(v);
        let transform = TransformRecord::new(parent_from_child, parent, child);
        let inverse = TransformRecord::new(&parent_from_child.inverse(), child, parent);
        let result = ResultFile {
            convention: format!(
                "transform = {parent}_from_{child}: maps points in `{child}` to `{parent}` (the pose of `{child}` in `{parent}`); inverse = {child}_from_{parent}. Metres and radians unless a name says mm or deg; quaternions [x, y, z, w]; matrices row-major."
            ),
            run_id: meta.run_id,
            outcome: meta.outcome,
            timestamp: meta.timestamp,
            uncertainty_translation_mm: known(meta.uncertainty_translation_mm),
            uncertainty_rotation_deg: known(meta.uncertainty_rotation_deg),
            transform,
            inverse,
        };
        let json = match serde_json::to_string_pretty(&result) {
            Ok(s) => s + "\n",
            Err(e) => format!("{{\"error\": {:?}}}\n", e.to_string()),
        };
        let toml = match toml::to_string(&result) {
            Ok(s) => format!(
                "# handeye calibration result, run {}.\n# {}\n\n{s}",
                result.run_id.replace('\n', " "),
                result.convention
            ),
            Err(e) => format!("# cannot render the result as TOML: {e}\n"),
        };
        let t = &result.transform;
        let static_transform_publisher = ros_commands(t);
        let tf_yaml = tf_yaml(t);
        let urdf_joint = urdf_joint(t);
        Exports {
            result,
            json,
            toml,
            static_transform_publisher,
            tf_yaml,
            urdf_joint,
        }
    }

    /// The structured result (what `result.json` and `result.toml` hold).
    pub fn result(&self) -> &ResultFile {
        &self.result
    }

    /// `result.json`.
    pub fn json(&self) -> &str {
        &self.json
    }

    /// `result.toml`.
    pub fn toml(&self) -> &str {
        &self.toml
    }

    /// `static_transform_publisher.txt`: the ROS 2 and ROS 1 command lines.
    pub fn static_transform_publisher(&self) -> &str {
        &self.static_transform_publisher
    }

    /// `tf.yaml`.
    pub fn tf_yaml(&self) -> &str {
        &self.tf_yaml
    }

    /// `urdf_joint.xml`.
    pub fn urdf_joint(&self) -> &str {
        &self.urdf_joint
    }

    /// Every file as (name, contents).
    pub fn files(&self) -> [(&'static str, &str); 5] {
        [
            (RESULT_JSON, &self.json),
            (RESULT_TOML, &self.toml),
            (STATIC_TRANSFORM_PUBLISHER, &self.static_transform_publisher),
            (TF_YAML, &self.tf_yaml),
            (URDF_JOINT, &self.urdf_joint),
        ]
    }
}

impl TransformRecord {
    /// All representations of `parent_from_child`.
    pub fn new(parent_from_child: &Isometry3<f64>, parent: &str, child: &str) -> Self {
        let q = canonical(&parent_from_child.rotation);
        let t = parent_from_child.translation.vector;
        let rv = rotation_vector(&q);
        let (roll, pitch, yaw) = q.euler_angles();
        let m = parent_from_child.to_homogeneous();
        let mut matrix_row_major = [[0.0; 4]; 4];
        for (r, row) in matrix_row_major.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v = m[(r, c)];
            }
        }
        TransformRecord {
            parent: parent.to_string(),
            child: child.to_string(),
            matrix_row_major: matrix_row_major.map(|row| row.map(positive_zero)),
            translation_m: [t.x, t.y, t.z].map(positive_zero),
            translation_mm: [1e3 * t.x, 1e3 * t.y, 1e3 * t.z].map(positive_zero),
            rotation_vector_rad: [rv.x, rv.y, rv.z].map(positive_zero),
            quaternion_xyzw: [q.i, q.j, q.k, q.w].map(positive_zero),
            rpy_rad: [roll, pitch, yaw].map(positive_zero),
            ur_pose: format!(
                "p[{}, {}, {}, {}, {}, {}]",
                num(t.x),
                num(t.y),
                num(t.z),
                num(rv.x),
                num(rv.y),
                num(rv.z)
            ),
        }
    }

    /// The transform back from the quaternion and translation.
    pub fn isometry(&self) -> Isometry3<f64> {
        let [x, y, z, w] = self.quaternion_xyzw;
        let [tx, ty, tz] = self.translation_m;
        Isometry3::from_parts(
            nalgebra::Translation3::new(tx, ty, tz),
            UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z)),
        )
    }
}

/// The unit quaternion of `q` with `w >= 0` (for `w == 0`, the first non-zero of x, y, z
/// positive), renormalised.
fn canonical(q: &UnitQuaternion<f64>) -> UnitQuaternion<f64> {
    let c = q.quaternion();
    let first = [c.w, c.i, c.j, c.k]
        .into_iter()
        .find(|v| *v != 0.0)
        .unwrap_or(1.0);
    let c = if first < 0.0 { -c } else { *c };
    UnitQuaternion::new_normalize(c)
}

/// Rotation vector (axis × angle, angle in [0, π]) of a quaternion with `w >= 0`; accurate for
/// tiny angles, where `2·acos(w)` is not.
fn rotation_vector(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    let v = q.imag();
    let s = v.norm();
    if s == 0.0 {
        return Vector3::zeros();
    }
    v * (2.0 * s.atan2(q.w) / s)
}

/// `-0.0` as `0.0` (files should not say `-0.0`).
fn positive_zero(v: f64) -> f64 {
    if v == 0.0 {
        0.0
    } else {
        v
    }
}

/// A number for text formats: 12 decimals (sub-nanometre, sub-nanoradian), trailing zeros and
/// negative zero dropped.
fn num(v: f64) -> String {
    if !v.is_finite() {
        return format!("{v}");
    }
    let s = format!("{v:.12}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    match s {
        "-0" | "" => "0".to_string(),
        s => s.to_string(),
    }
}

/// A frame name as one shell word.
fn shell_word(s: &str) -> Cow<'_, str> {
    shlex::try_quote(s).unwrap_or(Cow::Borrowed("INVALID_FRAME_NAME"))
}

fn ros_commands(t: &TransformRecord) -> String {
    let [x, y, z] = t.translation_m.map(num);
    let [qx, qy, qz, qw] = t.quaternion_xyzw.map(num);
    let (p, c) = (shell_word(&t.parent), shell_word(&t.child));
    format!(
        "# {c} in {p} ({p}_from_{c}), metres and unit quaternion.\n\
         # ROS 2:\n\
         ros2 run tf2_ros static_transform_publisher --x {x} --y {y} --z {z} --qx {qx} --qy {qy} --qz {qz} --qw {qw} --frame-id {p} --child-frame-id {c}\n\
         # ROS 1 (x y z qx qy qz qw frame_id child_frame_id):\n\
         rosrun tf2_ros static_transform_publisher {x} {y} {z} {qx} {qy} {qz} {qw} {p} {c}\n"
    )
}

/// A double-quoted YAML scalar.
fn yaml_str(s: &str) -> String {
    format!("\"{}\"", s.replace('\\', "\\\\").replace('"', "\\\""))
}

fn tf_yaml(t: &TransformRecord) -> String {
    let [x, y, z] = t.translation_m.map(num);
    let [qx, qy, qz, qw] = t.quaternion_xyzw.map(num);
    format!(
        "# {c} in {p} ({p}_from_{c}); geometry_msgs/TransformStamped layout, metres.\n\
         header:\n  frame_id: {py}\n\
         child_frame_id: {cy}\n\
         transform:\n  translation:\n    x: {x}\n    y: {y}\n    z: {z}\n  rotation:\n    x: {qx}\n    y: {qy}\n    z: {qz}\n    w: {qw}\n",
        p = t.parent.replace('\n', " "),
        c = t.child.replace('\n', " "),
        py = yaml_str(&t.parent),
        cy = yaml_str(&t.child),
    )
}

/// Text for an XML attribute value.
fn xml_attr(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

fn urdf_joint(t: &TransformRecord) -> String {
    let [x, y, z] = t.translation_m.map(num);
    let [r, p, yaw] = t.rpy_rad.map(num);
    let (parent, child) = (xml_attr(&t.parent), xml_attr(&t.child));
    format!(
        "<!-- {c} in {pa} ({pa}_from_{c}): xyz in metres, rpy = fixed-axis roll (x), pitch (y), yaw (z) in rad -->\n\
         <joint name=\"{parent}_to_{child}\" type=\"fixed\">\n  \
         <parent link=\"{parent}\"/>\n  \
         <child link=\"{child}\"/>\n  \
         <origin xyz=\"{x} {y} {z}\" rpy=\"{r} {p} {yaw}\"/>\n\
         </joint>\n",
        pa = parent.replace("--", "- -"),
        c = child.replace("--", "- -"),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::{FRAC_PI_2, PI};

    use nalgebra::Translation3;

    fn meta() -> ExportMeta {
        ExportMeta {
            run_id: "20250101T000000Z-1".to_string(),
            outcome: "passed".to_string(),
            uncertainty_translation_mm: 0.12,
            uncertainty_rotation_deg: 0.034,
            timestamp: "2025-01-01T00:00:00Z".to_string(),
        }
    }

    fn pose(t: [f64; 3], axis: [f64; 3], angle: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            UnitQuaternion::from_axis_angle(
                &nalgebra::Unit::new_normalize(Vector3::new(axis[0], axis[1], axis[2])),
                angle,
            ),
        )
    }

    fn poses() -> Vec<Isometry3<f64>> {
        vec![
            Isometry3::identity(),
            pose([0.0, -0.08, 0.04], [1.0, 0.0, 0.0], -0.26),
            pose([0.1, 0.2, 0.3], [0.3, -0.5, 0.8], 2.0),
            pose([-0.5, 0.0, 1.2], [0.0, 0.0, 1.0], PI),
            pose([0.01, 0.02, 0.03], [1.0, 1.0, 0.0], PI),
            pose([0.01, 0.02, 0.03], [0.2, -0.7, 0.1], PI - 1e-9),
            pose([0.0, 0.0, 0.0], [0.2, -0.7, 0.1], 1e-9),
            pose([1.0, 2.0, 3.0], [0.0, 1.0, 0.0], FRAC_PI_2),
            pose([1.0, 2.0, 3.0], [0.3, 1.0, 0.0], -FRAC_PI_2),
        ]
    }

    /// Rotation angle between two isometries plus translation distance.
    fn distance(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
        let d = a.inverse() * b;
        (d.translation.vector.norm(), d.rotation.angle())
    }

    fn check_record(r: &TransformRecord, expected: &Isometry3<f64>) {
        let (dt, dr) = distance(&r.isometry(), expected);
        assert!(dt < 1e-9 && dr < 1e-9, "{dt} {dr}");
        let [x, y, z, w] = r.quaternion_xyzw;
        assert!(((x * x + y * y + z * z + w * w).sqrt() - 1.0).abs() < 1e-12);
        assert!(w >= 0.0);
        // Matrix.
        let m = expected.to_homogeneous();
        for (i, row) in r.matrix_row_major.iter().enumerate() {
            for (j, v) in row.iter().enumerate() {
                assert!((v - m[(i, j)]).abs() < 1e-9);
            }
        }
        let from_matrix = crate::frames::from_row_major(&r.matrix_row_major).expect("rigid");
        let (dt, dr) = distance(&from_matrix, expected);
        assert!(dt < 1e-9 && dr < 1e-9);
        // Rotation vector.
        let rv = Vector3::from(r.rotation_vector_rad);
        assert!(rv.norm() <= PI + 1e-12);
        let (_, dr) = distance(
            &Isometry3::from_parts(expected.translation, UnitQuaternion::from_scaled_axis(rv)),
            expected,
        );
        assert!(dr < 1e-9, "rotation vector {rv:?}: {dr}");
        // URDF rpy: R = Rz(yaw) Ry(pitch) Rx(roll).
        let [roll, pitch, yaw] = r.rpy_rad;
        let rpy = UnitQuaternion::from_euler_angles(roll, pitch, yaw);
        let fixed_axes = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw)
            * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), pitch)
            * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), roll);
        assert!(rpy.angle_to(&fixed_axes) < 1e-12);
        assert!(
            rpy.angle_to(&expected.rotation) < 1e-9,
            "rpy {:?}",
            r.rpy_rad
        );
        for (mm, m) in r.translation_mm.iter().zip(r.translation_m) {
            assert!((mm - 1e3 * m).abs() < 1e-9);
        }
    }

    #[test]
    fn json_and_toml_round_trip_every_representation() {
        for p in poses() {
            let e = Exports::new(&p, "tool0", "camera", meta());
            let from_json: ResultFile = serde_json::from_str(e.json()).expect("json");
            let from_toml: ResultFile = toml::from_str(e.toml()).expect("toml");
            for r in [&from_json, &from_toml] {
                assert_eq!(r.transform.parent, "tool0");
                assert_eq!(r.transform.child, "camera");
                assert_eq!(r.inverse.parent, "camera");
                assert_eq!(r.inverse.child, "tool0");
                assert_eq!(r.outcome, "passed");
                assert_eq!(r.run_id, "20250101T000000Z-1");
                assert_eq!(r.uncertainty_translation_mm, Some(0.12));
                assert_eq!(r.uncertainty_rotation_deg, Some(0.034));
                check_record(&r.transform, &p);
                check_record(&r.inverse, &p.inverse());
                // The UR pose text is the rotation vector and translation.
                let inner = r
                    .transform
                    .ur_pose
                    .strip_prefix("p[")
                    .and_then(|s| s.strip_suffix(']'))
                    .expect("p[...]");
                let v: Vec<f64> = inner
                    .split(", ")
                    .map(|s| s.parse().expect("number"))
                    .collect();
                assert_eq!(v.len(), 6);
                let ur = Isometry3::from_parts(
                    Translation3::new(v[0], v[1], v[2]),
                    UnitQuaternion::from_scaled_axis(Vector3::new(v[3], v[4], v[5])),
                );
                let (dt, dr) = distance(&ur, &p);
                assert!(dt < 1e-9 && dr < 1e-9, "{}", r.transform.ur_pose);
            }
            // TOML parses floats exactly; serde_json to within an ulp (checked above).
            assert_eq!(&from_toml, e.result());
        }
    }

    #[test]
    fn unknown_uncertainty_is_left_out() {
        let m = ExportMeta {
            uncertainty_translation_mm: f64::NAN,
            uncertainty_rotation_deg: f64::INFINITY,
            ..meta()
        };
        let e = Exports::new(&Isometry3::identity(), "base", "camera", m);
        assert!(!e.json().contains("uncertainty"), "{}", e.json());
        let back: ResultFile = toml::from_str(e.toml()).expect("toml");
        assert_eq!(back.uncertainty_translation_mm, None);
        assert_eq!(back.uncertainty_rotation_deg, None);
    }

    #[test]
    fn rotations_of_exactly_pi_and_near_zero() {
        // π about x: the quaternion is (1, 0, 0, 0) up to sign; canonical is +x.
        let half = pose([0.0; 3], [1.0, 0.0, 0.0], PI);
        let r = TransformRecord::new(&half, "a", "b");
        assert!((r.quaternion_xyzw[0] - 1.0).abs() < 1e-12, "{r:?}");
        assert!((Vector3::from(r.rotation_vector_rad).norm() - PI).abs() < 1e-12);
        // The same rotation given with the other quaternion sign gives the same record.
        let flipped = Isometry3::from_parts(
            half.translation,
            UnitQuaternion::new_unchecked(-half.rotation.into_inner()),
        );
        assert_eq!(TransformRecord::new(&flipped, "a", "b"), r);
        // A nanoradian rotation keeps its rotation vector (2·acos(w) would round it to 0).
        let tiny = pose([0.0; 3], [0.0, 0.0, 1.0], 1e-9);
        let r = TransformRecord::new(&tiny, "a", "b");
        assert!((r.rotation_vector_rad[2] - 1e-9).abs() < 1e-15, "{r:?}");
        assert!((r.rpy_rad[2] - 1e-9).abs() < 1e-15, "{r:?}");
        let ident = TransformRecord::new(&Isometry3::identity(), "a", "b");
        assert_eq!(ident.quaternion_xyzw, [0.0, 0.0, 0.0, 1.0]);
        assert_eq!(ident.ur_pose, "p[0, 0, 0, 0, 0, 0]");
    }

    /// The numbers after `key` (up to the next `key2` or end of line), as parsed floats.
    fn numbers_after(text: &str, key: &str, count: usize) -> Vec<f64> {
        let at = text.find(key).expect(key) + key.len();
        text[at..]
            .split(|c: char| c.is_whitespace() || c == '"')
            .filter(|s| !s.is_empty())
            .take(count)
            .map(|s| s.parse().unwrap_or_else(|_| panic!("{key}: {s}")))
            .collect()
    }

    #[test]
    fn ros_yaml_and_urdf_texts_carry_the_transform() {
        for p in poses() {
            let e = Exports::new(&p, "tool0", "camera", meta());
            let ros = e.static_transform_publisher();
            let mut ros2 = Vec::new();
            for k in ["--x ", "--y ", "--z ", "--qx ", "--qy ", "--qz ", "--qw "] {
                ros2.extend(numbers_after(ros, k, 1));
            }
            assert!(
                ros.contains("--frame-id tool0 --child-frame-id camera"),
                "{ros}"
            );
            let ros1_line = ros
                .lines()
                .find(|l| l.starts_with("rosrun"))
                .expect("ROS 1 line");
            assert!(ros1_line.ends_with(" tool0 camera"), "{ros1_line}");
            let ros1 = numbers_after(ros1_line, "static_transform_publisher ", 7);
            assert_eq!(ros1, ros2);
            let q = nalgebra::Quaternion::new(ros1[6], ros1[3], ros1[4], ros1[5]);
            let got = Isometry3::from_parts(
                Translation3::new(ros1[0], ros1[1], ros1[2]),
                UnitQuaternion::from_quaternion(q),
            );
            let (dt, dr) = distance(&got, &p);
            assert!(dt < 1e-9 && dr < 1e-9, "{ros}");

            let yaml = e.tf_yaml();
            assert!(yaml.contains("frame_id: \"tool0\""), "{yaml}");
            assert!(yaml.contains("child_frame_id: \"camera\""), "{yaml}");
            let t = numbers_after(yaml, "translation:\n    x:", 1);
            assert!((t[0] - p.translation.x).abs() < 1e-9);
            let w = numbers_after(yaml, "    w:", 1);
            assert!((w[0] - e.result().transform.quaternion_xyzw[3]).abs() < 1e-9);

            let urdf = e.urdf_joint();
            let doc = roxmltree::Document::parse(urdf).expect("well-formed XML");
            let joint = doc.root_element();
            assert_eq!(joint.attribute("name"), Some("tool0_to_camera"));
            assert_eq!(joint.attribute("type"), Some("fixed"));
            let child = |tag: &str| {
                joint
                    .children()
                    .find(|n| n.has_tag_name(tag))
                    .unwrap_or_else(|| panic!("<{tag}>"))
            };
            assert_eq!(child("parent").attribute("link"), Some("tool0"));
            assert_eq!(child("child").attribute("link"), Some("camera"));
            let parse3 = |s: &str| -> Vec<f64> {
                s.split(' ').map(|v| v.parse().expect("number")).collect()
            };
            let xyz = parse3(child("origin").attribute("xyz").expect("xyz"));
            let rpy = parse3(child("origin").attribute("rpy").expect("rpy"));
            let got = Isometry3::from_parts(
                Translation3::new(xyz[0], xyz[1], xyz[2]),
                UnitQuaternion::from_euler_angles(rpy[0], rpy[1], rpy[2]),
            );
            let (dt, dr) = distance(&got, &p);
            assert!(dt < 1e-9 && dr < 1e-9, "{urdf}");
        }
    }

    #[test]
    fn odd_frame_names_are_quoted_and_escaped() {
        let e = Exports::new(&Isometry3::identity(), "my base", "cam\"<1>", meta());
        assert!(e
            .static_transform_publisher()
            .contains("--frame-id 'my base'"));
        roxmltree::Document::parse(e.urdf_joint()).expect("escaped XML");
        assert!(
            e.tf_yaml().contains(r#"child_frame_id: "cam\"<1>""#),
            "{}",
            e.tf_yaml()
        );
    }
}
