use nalgebra::{Point3, Vector3};

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

    /// Look up a preset by name: `zivid2-m60` (2448×2048) or `compact` (1280×960).
    pub fn preset(name: &str) -> Option<Self> {
        match name {
            "zivid2-m60" | "zivid2plus-m60" | "2448x2048" => Some(Self::zivid2_plus_m60()),
            "compact" | "1280x960" => Some(Self::compact_1280x960()),
            _ => None,
        }
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

/// `world_from_camera` for a camera at `eye` looking at `target` (OpenCV axes: z along the view
/// direction, y as close to `down` as the view direction allows).
pub fn look_at(
    eye: &Point3<f64>,
    target: &Point3<f64>,
    down: &Vector3<f64>,
) -> nalgebra::Isometry3<f64> {
    let z = (target - eye).normalize();
    let x = down.cross(&z);
    let x = if x.norm() < 1e-9 {
        z.cross(&Vector3::x()).normalize()
    } else {
        x.normalize()
    };
    let y = z.cross(&x);
    let r = nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_columns(&[x, y, z]));
    nalgebra::Isometry3::from_parts(nalgebra::Translation3::from(eye.coords), r.into())
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
    fn look_at_puts_the_target_on_the_optical_axis_with_y_down() {
        let t = look_at(
            &Point3::new(0.6, 0.2, 0.5),
            &Point3::new(0.0, 0.0, 0.1),
            &-Vector3::z(),
        );
        let p = t.inverse() * Point3::new(0.0, 0.0, 0.1);
        assert!(p.x.abs() < 1e-12 && p.y.abs() < 1e-12 && p.z > 0.0);
        // a point above the target appears above the image centre (negative y)
        assert!((t.inverse() * Point3::new(0.0, 0.0, 0.3)).y < 0.0);
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
