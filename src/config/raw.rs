//! The raw TOML shape (serde, unknown keys refused). Optional keys are `Option`s: defaults are
//! applied in validation, from `defaults`, never here. Integers are read as i64 and
//! range-checked with the same messages as floats.

use serde::Deserialize;

use super::KinematicsSource;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawConfig {
    pub(super) robot: RawRobot,
    pub(super) camera: RawCamera,
    #[serde(default)]
    pub(super) mount: RawMount,
    #[serde(default)]
    pub(super) views: RawViews,
    #[serde(default)]
    pub(super) gate: RawGate,
    #[serde(default)]
    pub(super) check: RawCheck,
    #[serde(default)]
    pub(super) write_back: RawWriteBack,
    #[serde(default)]
    pub(super) storage: RawStorage,
    #[serde(default)]
    pub(super) daemon: RawDaemon,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawDaemon {
    pub(super) startup: Option<String>,
    pub(super) listen: Option<String>,
    pub(super) token_file: Option<String>,
    pub(super) check_interval_s: Option<f64>,
    pub(super) check_at: Option<Vec<String>>,
    pub(super) when_busy: Option<String>,
    pub(super) recalibrate_on_drift: Option<bool>,
    pub(super) keep_captures_runs: Option<i64>,
    pub(super) keep_captures_days: Option<f64>,
    pub(super) pendant: Option<RawPendant>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawPendant {
    pub(super) request_register: i64,
    pub(super) status_register: i64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawRobot {
    pub(super) model: String,
    pub(super) urdf: Option<String>,
    pub(super) host: String,
    #[serde(default)]
    pub(super) ports: RawPorts,
    pub(super) max_joint_speed_rad_s: Option<f64>,
    pub(super) max_joint_accel_rad_s2: Option<f64>,
    pub(super) move_timeout_s: Option<f64>,
    pub(super) allow_power_on: Option<bool>,
    pub(super) kinematics: Option<KinematicsSource>,
    pub(super) calibration: Option<String>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawPorts {
    pub(super) dashboard: Option<i64>,
    pub(super) primary: Option<i64>,
    pub(super) secondary: Option<i64>,
    pub(super) realtime: Option<i64>,
    pub(super) rtde: Option<i64>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub(super) enum RawBackend {
    Gige,
    Gentl,
    Exec,
    File,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawCamera {
    pub(super) backend: RawBackend,
    pub(super) address: Option<String>,
    pub(super) producer: Option<String>,
    pub(super) device: Option<String>,
    pub(super) call_timeout_s: Option<f64>,
    pub(super) command: Option<Vec<String>>,
    pub(super) timeout_s: Option<f64>,
    pub(super) files: Option<Vec<String>>,
    pub(super) frames: Option<i64>,
    pub(super) frame_timeout_s: Option<f64>,
    pub(super) exposure_us: Option<f64>,
    pub(super) settle_s: Option<f64>,
    pub(super) sensor: Option<crate::geometry::SensorClass>,
    pub(super) trigger: Option<handeye_hal::Trigger>,
    pub(super) user_set: Option<String>,
    pub(super) features: Option<RawFeatures>,
}

/// `[camera.features]`: name = value, in the order written (a map would sort them; the order
/// matters: a selector before the feature it selects).
#[derive(Debug, Default)]
pub(super) struct RawFeatures(pub(super) Vec<(String, handeye_hal::FeatureValue)>);

impl<'de> Deserialize<'de> for RawFeatures {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Ordered;
        impl<'de> serde::de::Visitor<'de> for Ordered {
            type Value = RawFeatures;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("a table of camera feature = value")
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut m: A,
            ) -> Result<RawFeatures, A::Error> {
                use handeye_hal::FeatureValue as V;
                let mut out = Vec::new();
                while let Some(name) = m.next_key::<String>()? {
                    let value = match m.next_value::<toml::Value>()? {
                        toml::Value::Boolean(b) => V::Bool(b),
                        toml::Value::Integer(i) => V::Int(i),
                        toml::Value::Float(x) => V::Float(x),
                        toml::Value::String(t) => V::Text(t),
                        other => {
                            return Err(serde::de::Error::custom(format!(
                                "camera.features.{name}: a {} is not a feature value; write an \
                                 entry's name or text in quotes, a number, or true/false",
                                other.type_str()
                            )))
                        }
                    };
                    out.push((name, value));
                }
                Ok(RawFeatures(out))
            }
        }
        d.deserialize_map(Ordered)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
pub(super) enum RawMountType {
    #[serde(rename = "eye-in-hand")]
    EyeInHand,
    #[serde(rename = "eye-to-hand")]
    EyeToHand,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawMount {
    #[serde(rename = "type")]
    pub(super) kind: Option<RawMountType>,
    pub(super) prior: Option<[f64; 6]>,
    pub(super) max_camera_flange_distance_m: Option<f64>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub(super) enum RawMode {
    Joints,
    Auto,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawViews {
    pub(super) mode: Option<RawMode>,
    pub(super) joints: Option<Vec<[f64; 6]>>,
    pub(super) count: Option<i64>,
    pub(super) min_distance_m: Option<f64>,
    pub(super) max_distance_m: Option<f64>,
    pub(super) seed: Option<i64>,
    #[serde(default)]
    pub(super) obstacles: Vec<RawObstacle>,
    pub(super) floor_clearance_m: Option<f64>,
    pub(super) return_to_start: Option<bool>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawObstacle {
    pub(super) name: String,
    pub(super) centre_m: [f64; 3],
    pub(super) size_m: [f64; 3],
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawGate {
    pub(super) min_coverage: Option<f64>,
    pub(super) min_link_support: Option<f64>,
    pub(super) max_free_space_violations: Option<f64>,
    pub(super) max_rmse_mm: Option<f64>,
    pub(super) min_inlier_fraction: Option<f64>,
    pub(super) max_uncertainty_translation_mm: Option<f64>,
    pub(super) max_uncertainty_rotation_deg: Option<f64>,
    pub(super) max_residual_translation_mm: Option<f64>,
    pub(super) max_residual_rotation_deg: Option<f64>,
    pub(super) max_dropped_fraction: Option<f64>,
    pub(super) max_ambiguity: Option<f64>,
    pub(super) max_depth_scale_error: Option<f64>,
    pub(super) max_depth_offset_mm: Option<f64>,
    pub(super) max_change_translation_mm: Option<f64>,
    pub(super) max_change_rotation_deg: Option<f64>,
    pub(super) max_split_half_mm: Option<f64>,
    pub(super) max_split_half_deg: Option<f64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawCheck {
    pub(super) max_drift_translation_mm: Option<f64>,
    pub(super) max_drift_rotation_deg: Option<f64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawWriteBack {
    pub(super) tcp: Option<bool>,
    pub(super) registers: Option<RawRegisters>,
    pub(super) files: Option<bool>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawRegisters {
    pub(super) double_start: i64,
    pub(super) sequence_int: i64,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawStorage {
    pub(super) dir: Option<String>,
    pub(super) keep_captures: Option<bool>,
}
