//! The pinhole model of a 3D camera: the simulator renders through it, and registration uses it
//! for the range image of a scan (intrinsics estimated from an organized cloud, or a synthetic
//! grid for an unorganized one).

use nalgebra::{Point3, Vector3};

/// A camera preset: its names and its intrinsics.
type Preset = (&'static [&'static str], fn() -> Intrinsics);

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

    /// The presets: each one's names (the first is the one the command line shows) and its
    /// intrinsics.
    const PRESETS: [Preset; 3] = [
        (
            &["zivid2-m60", "zivid2plus-m60", "2448x2048"],
            Self::zivid2_plus_m60,
        ),
        (&["compact", "1280x960"], Self::compact_1280x960),
        (&["realsense-d435"], Self::realsense_d435_1280x720),
    ];

    /// Look up a preset by name: `zivid2-m60` (2448×2048), `compact` (1280×960) or
    /// `realsense-d435` (1280×720).
    pub fn preset(name: &str) -> Option<Self> {
        Self::PRESETS
            .iter()
            .find(|(names, _)| names.contains(&name))
            .map(|(_, make)| make())
    }

    /// [`Intrinsics::preset`], or an error naming the presets there are.
    pub fn preset_or_error(name: &str) -> Result<Self, String> {
        Self::preset(name).ok_or_else(|| {
            format!(
                "unknown camera preset `{name}`; use one of {}",
                Self::PRESETS
                    .iter()
                    .map(|(names, _)| names[0])
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
        for (names, make) in Intrinsics::PRESETS {
            for name in names {
                assert_eq!(Intrinsics::preset(name), Some(make()), "{name}");
            }
        }
        assert_eq!(Intrinsics::preset("2448x2048").map(|k| k.width), Some(2448));
        let err = Intrinsics::preset_or_error("kinect").expect_err("unknown");
        assert_eq!(
            err,
            "unknown camera preset `kinect`; use one of zivid2-m60, compact, realsense-d435"
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
