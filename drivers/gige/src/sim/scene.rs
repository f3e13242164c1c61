//! A built-in analytic scene: a pinhole camera looking at a tilted plane with a sphere in
//! front of it. A test pattern, not a model of any real camera or robot; the binary plugs the
//! robot scan simulator in through [`FrameSource`](super::FrameSource) instead.

use handeye_hal::nalgebra::{Point3, Vector3};
use handeye_hal::PointCloud;

use super::{FrameSource, SourceError};

/// Ray-cast plane + sphere, rendered once and served for every frame (the scene is static).
#[derive(Debug, Clone)]
pub struct SceneSource {
    width: u32,
    height: u32,
    focal: f64,
    aspect: f64,
    cached: Option<PointCloud>,
}

impl SceneSource {
    /// A `width × height` sensor with a focal length of `0.9 · width` pixels.
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            focal: 0.9 * f64::from(width),
            aspect: 1.0,
            cached: None,
        }
    }

    /// The same camera with a vertical focal length `aspect` times the horizontal one (rays
    /// spread `1 / aspect` times as much vertically), as `Scan3dAspectRatio` describes it
    /// (see [`crate::decode::Scan3d`]).
    pub fn with_aspect_ratio(mut self, aspect: f64) -> Self {
        self.aspect = aspect;
        self.cached = None;
        self
    }

    /// Render the scene: sphere radius 0.15 m at (0.05, 0, 0.9) m; plane through (0, 0, 1.2) m
    /// with normal (0, −0.3, −1) (tilted towards the top); pixels outside a centred ellipse
    /// covering 95 % of the image and points farther than 2 m are invalid (NaN).
    pub fn render(&self) -> PointCloud {
        let (w, h) = (self.width as usize, self.height as usize);
        let (cu, cv) = (f64::from(self.width) / 2.0, f64::from(self.height) / 2.0);
        let centre = Vector3::new(0.05, 0.0, 0.9);
        let r = 0.15;
        let n = Vector3::new(0.0, -0.3, -1.0).normalize();
        let p0 = Vector3::new(0.0, 0.0, 1.2);
        let nan = Point3::new(f32::NAN, f32::NAN, f32::NAN);
        let mut points = Vec::with_capacity(w * h);
        let mut confidence = Vec::with_capacity(w * h);
        for v in 0..h {
            for u in 0..w {
                let du = (u as f64 + 0.5 - cu) / cu;
                let dv = (v as f64 + 0.5 - cv) / cv;
                if du * du + dv * dv > 0.95 * 0.95 * 2.0 {
                    points.push(nan);
                    confidence.push(0.0);
                    continue;
                }
                let d = Vector3::new(
                    (u as f64 + 0.5 - cu) / self.focal,
                    (v as f64 + 0.5 - cv) / (self.focal * self.aspect),
                    1.0,
                );
                // Sphere: |t d - c|² = r².
                let a = d.dot(&d);
                let b = -2.0 * d.dot(&centre);
                let c = centre.dot(&centre) - r * r;
                let disc = b * b - 4.0 * a * c;
                let t_sphere = (disc >= 0.0)
                    .then(|| (-b - disc.sqrt()) / (2.0 * a))
                    .filter(|t| *t > 0.0);
                let denom = n.dot(&d);
                let t_plane = (denom.abs() > 1e-9)
                    .then(|| n.dot(&p0) / denom)
                    .filter(|t| *t > 0.0);
                let t = match (t_sphere, t_plane) {
                    (Some(s), Some(p)) => Some(s.min(p)),
                    (s, p) => s.or(p),
                };
                match t.map(|t| d * t).filter(|p| p.z < 2.0) {
                    Some(p) => {
                        points.push(Point3::new(p.x as f32, p.y as f32, p.z as f32));
                        confidence.push(if t_sphere.is_some() { 0.8 } else { 1.0 });
                    }
                    None => {
                        points.push(nan);
                        confidence.push(0.0);
                    }
                }
            }
        }
        PointCloud {
            width: self.width,
            height: self.height,
            points,
            intensity: None,
            confidence: Some(confidence),
        }
    }
}

impl FrameSource for SceneSource {
    fn next_frame(&mut self) -> Result<PointCloud, SourceError> {
        if self.cached.is_none() {
            self.cached = Some(self.render());
        }
        Ok(self.cached.clone().unwrap_or_default())
    }

    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    fn aspect_ratio(&self) -> f64 {
        self.aspect
    }

    fn intrinsics(&self) -> (f64, f64, f64) {
        (
            self.focal,
            f64::from(self.width) / 2.0 - 0.5,
            f64::from(self.height) / 2.0 - 0.5,
        )
    }
}
