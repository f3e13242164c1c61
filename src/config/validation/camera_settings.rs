//! `camera.user_set` and `[camera.features]` (issue 44).

use super::Ctx;
use crate::config::raw::RawFeatures;
use crate::config::ConfigError;

impl Ctx<'_> {
    /// `camera.user_set` and `[camera.features]`: names present, none of the features handeye
    /// sets itself (each has its own key).
    pub(super) fn camera_settings(
        &self,
        user_set: Option<String>,
        features: Option<RawFeatures>,
    ) -> Result<handeye_hal::CameraSettings, ConfigError> {
        if user_set.as_deref().is_some_and(|s| s.trim().is_empty()) {
            return Err(self.invalid(
                "camera.user_set",
                "camera.user_set is empty: give a UserSetSelector entry (\"Default\", \"UserSet1\", …; `handeye camera probe` lists them), or remove it",
            ));
        }
        let features = features.map(|f| f.0).unwrap_or_default();
        for (name, _) in &features {
            let key = format!("camera.features.{name}");
            if name.trim().is_empty() || name.chars().any(char::is_whitespace) {
                return Err(self.invalid(
                    "camera.features",
                    format!("{key}: a GenICam feature name has no spaces"),
                ));
            }
            if let Some(why) = handeye_hal::set_by_handeye(name) {
                return Err(self.invalid(
                    "camera.features",
                    format!("{key}: handeye sets {name} itself ({why}); remove it from [camera.features]"),
                ));
            }
        }
        Ok(handeye_hal::CameraSettings {
            user_set: user_set.map(|s| s.trim().to_owned()),
            features,
        })
    }
}
