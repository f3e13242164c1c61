//! The pinhole model of a 3D camera: the simulator renders through it, and registration uses it
//! for the range image of a scan (intrinsics estimated from an organized cloud, or a synthetic
//! grid for an unorganized one).

use nalgebra::{Point3, Vector3};

/// A camera preset: its names, its intrinsics and its sensor class.
type Preset = (&'static [&'static str], fn() -> Intrinsics, SensorClass);

/// How a 3D camera measures depth: what its errors look like (the simulator's noise class for
/// a preset, `crate::sim::ScanNoise::of_class`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SensorClass {
    /// Projected patterns and triangulation (Zivid class): sub-millimetre noise growing with z².
    StructuredLight,
    /// Stereo matching of a projected dot pattern (RealSense D4xx class): millimetre noise
    /// growing with z², wavy surfaces, holes at depth edges.
    ActiveStereo,
    /// Phase of modulated light (Helios2, Azure Kinect class): noise growing with z,
    /// multipath at concave corners, flying pixels at depth edges.
    TimeOfFlight,
}

/// Pinhole intrinsics of a 3D camera (OpenCV convention: pixel centres at integer coordinates,
/// x right, y down, z forward; metres in camera frame).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Intrinsics {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
}

impl Intrinsics {
    /// A Zivid 2+ M60-class structured-light camera: 2448×2048 (5 MP), ~ 58°×50° field of view
    /// (optimal working distance 0.35–1.1 m).
    pub fn zivid2_plus_m60() -> Self {
        Self::from_fov(2448, 2048, 58.0_f64.to_radians())
    }

    /// A 1280×960 (1.2 MP) industrial 3D camera with a ~ 60° horizontal field of view.
    pub fn compact_1280x960() -> Self {
        Self::from_fov(1280, 960, 60.0_f64.to_radians())
    }

    /// Square pixels, centred principal point, the given horizontal field of view (radians).
    pub fn from_fov(width: u32, height: u32, horizontal_fov_rad: f64) -> Self {
        let f = 0.5 * f64::from(width) / (0.5 * horizontal_fov_rad).tan();
        Self {
            width,
            height,
            fx: f,
            fy: f,
            cx: 0.5 * f64::from(width - 1),
            cy: 0.5 * f64::from(height - 1),
        }
    }

    /// An Intel RealSense D435 at 1280×720 with depth aligned to its colour camera (~70° × 43°
    /// field of view): the intrinsics of the real frames in `../shared/realdata/xarm7_realsense`.
    pub fn realsense_d435_1280x720() -> Self {
        Self {
            width: 1280,
            height: 720,
            fx: 908.3,
            fy: 908.3,
            cx: 643.0,
            cy: 372.7,
        }
    }

    /// A LUCID Helios2 time-of-flight camera (Sony IMX556 DepthSense): 640×480 with a ~69° ×
    /// 51° field of view (square pixels, centred principal point; its lens distortion is
    /// not modelled).
    pub fn helios2_640x480() -> Self {
        Self::from_fov(640, 480, 69.0_f64.to_radians())
    }

    /// The presets: each one's names (the first is the one the command line shows), its
    /// intrinsics and its sensor class — the one place that says which class a preset is.
    const PRESETS: [Preset; 4] = [
        (
            &["zivid2-m60", "zivid2plus-m60", "2448x2048"],
            Self::zivid2_plus_m60,
            SensorClass::StructuredLight,
        ),
        (
            &["compact", "1280x960"],
            Self::compact_1280x960,
            SensorClass::StructuredLight,
        ),
        (
            &["realsense-d435"],
            Self::realsense_d435_1280x720,
            SensorClass::ActiveStereo,
        ),
        (
            &["helios2", "640x480"],
            Self::helios2_640x480,
            SensorClass::TimeOfFlight,
        ),
    ];

    /// Look up a preset by name: `zivid2-m60` (2448×2048), `compact` (1280×960),
    /// `realsense-d435` (1280×720) or `helios2` (640×480).
    pub fn preset(name: &str) -> Option<Self> {
        Self::find_preset(name).map(|(_, make, _)| make())
    }

    /// The sensor class of preset `name` (`None` for an unknown name).
    pub fn preset_class(name: &str) -> Option<SensorClass> {
        Self::find_preset(name).map(|(_, _, class)| *class)
    }

    fn find_preset(name: &str) -> Option<&'static Preset> {
        Self::PRESETS
            .iter()
            .find(|(names, _, _)| names.contains(&name))
    }

    /// [`Intrinsics::preset`], or an error naming the presets there are.
    pub fn preset_or_error(name: &str) -> Result<Self, String> {
        Self::preset(name).ok_or_else(|| {
            format!(
                "unknown camera preset `{name}`; use one of {}",
                Self::PRESETS
                    .iter()
                    .map(|(names, _, _)| names[0])
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        })
    }

    /// Same field of view at a lower resolution (used for fast visibility checks).
    pub fn scaled(&self, factor: f64) -> Self {
        let w = ((f64::from(self.width) * factor).round() as u32).max(1);
        let h = ((f64::from(self.height) * factor).round() as u32).max(1);
        let sx = f64::from(w) / f64::from(self.width);
        let sy = f64::from(h) / f64::from(self.height);
        Self {
            width: w,
            height: h,
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: (self.cx + 0.5) * sx - 0.5,
            cy: (self.cy + 0.5) * sy - 0.5,
        }
    }

    /// Pixel coordinates of a camera-frame point, or `None` when it is behind the camera.
    pub fn project(&self, p: &Point3<f64>) -> Option<(f64, f64)> {
        (p.z > 1e-9).then(|| (self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy))
    }

    /// Row-major index (`v·width + u`) of the pixel nearest to where the camera-frame point `p`
    /// (metres) projects, or `None` when it projects outside the image or lies less than 1 µm in
    /// front of the camera. The hot path of registration's range-image lookups.
    #[inline]
    pub fn pixel_index(&self, p: &Point3<f64>) -> Option<usize> {
        if p.z <= 1e-6 {
            return None;
        }
        let u = (self.fx * p.x / p.z + self.cx).round();
        let v = (self.fy * p.y / p.z + self.cy).round();
        if u < 0.0 || v < 0.0 || u >= f64::from(self.width) || v >= f64::from(self.height) {
            return None;
        }
        Some(v as usize * self.width as usize + u as usize)
    }

    /// Whether pixel coordinates fall inside the image, with a margin in pixels.
    pub fn contains(&self, u: f64, v: f64, margin: f64) -> bool {
        u >= margin
            && v >= margin
            && u <= f64::from(self.width) - 1.0 - margin
            && v <= f64::from(self.height) - 1.0 - margin
    }

    /// The viewing ray through a pixel, scaled so that its z component is 1.
    pub fn ray(&self, u: f64, v: f64) -> Vector3<f64> {
        Vector3::new((u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn projection_inverts_the_pixel_ray() {
        let k = Intrinsics::compact_1280x960();
        let p = Point3::from(k.ray(100.0, 700.0) * 0.73);
        let (u, v) = k.project(&p).expect("in front");
        assert!((u - 100.0).abs() < 1e-9 && (v - 700.0).abs() < 1e-9);
        assert!(k.project(&Point3::new(0.0, 0.0, -1.0)).is_none());
    }

    #[test]
    fn every_preset_name_resolves_and_an_unknown_one_lists_them() {
        for (names, make, class) in Intrinsics::PRESETS {
            for name in names {
                assert_eq!(Intrinsics::preset(name), Some(make()), "{name}");
                assert_eq!(Intrinsics::preset_class(name), Some(class), "{name}");
            }
        }
        assert_eq!(
            Intrinsics::preset_class("realsense-d435"),
            Some(SensorClass::ActiveStereo)
        );
        assert_eq!(
            Intrinsics::preset_class("helios2"),
            Some(SensorClass::TimeOfFlight)
        );
        assert_eq!(Intrinsics::preset_class("kinect"), None);
        let h = Intrinsics::preset("helios2").expect("helios2");
        assert_eq!((h.width, h.height), (640, 480));
        assert_eq!(Intrinsics::preset("2448x2048").map(|k| k.width), Some(2448));
        let err = Intrinsics::preset_or_error("kinect").expect_err("unknown");
        assert_eq!(
            err,
            "unknown camera preset `kinect`; use one of zivid2-m60, compact, realsense-d435, helios2"
        );
    }

    #[test]
    fn pixel_index_rounds_to_the_nearest_pixel_inside_the_image() {
        let k = Intrinsics::compact_1280x960();
        let at = |u: f64, v: f64| k.pixel_index(&Point3::from(k.ray(u, v) * 0.5));
        assert_eq!(at(0.0, 0.0), Some(0));
        assert_eq!(at(3.4, 2.6), Some(3 * 1280 + 3));
        assert_eq!(at(1279.0, 959.0), Some(1280 * 960 - 1));
        assert_eq!(at(-0.6, 10.0), None);
        assert_eq!(at(1279.6, 10.0), None);
        assert_eq!(at(10.0, 959.6), None);
        assert_eq!(k.pixel_index(&Point3::new(0.0, 0.0, 1e-7)), None);
    }

    #[test]
    fn presets_have_the_advertised_resolution_and_centred_principal_point() {
        let z = Intrinsics::zivid2_plus_m60();
        assert_eq!((z.width, z.height), (2448, 2048));
        assert!((z.cx - 1223.5).abs() < 1e-12);
        let s = z.scaled(0.25);
        assert_eq!((s.width, s.height), (612, 512));
        // the image corners keep their viewing directions
        let a = z.ray(-0.5, -0.5);
        let b = s.ray(-0.5, -0.5);
        assert!((a - b).norm() < 1e-9);
    }
}
