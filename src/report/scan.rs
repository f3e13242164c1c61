//! The scan as the camera saw it, each point coloured by its distance to the posed model, with
//! the model's expected outline: the picture that tells at a glance whether the scan sits on
//! the robot.

use handeye_hal::PointCloud;
use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;

use crate::calib::range::RangeImage;
use crate::calib::surface::ModelSurface;
use crate::calib::PosedModel;
use crate::geometry::raycast::{raycast, DepthImage, SceneMesh};

/// Distances beyond this are not looked up (the point is background, clutter or a misfit), m.
const SEARCH_M: f64 = 0.02;
/// Spacing of the model surface samples the distances are looked up from, m.
const SAMPLE_SPACING_M: f64 = 0.003;
/// A depth step larger than this fraction of the depth inside one link is an outline.
const CREASE_STEP: f64 = 0.04;

/// One picture pixel with a scan point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ScanPixel {
    /// Distance to the posed model surface, mm; `None` beyond [`SEARCH_M`].
    pub(crate) distance_mm: Option<f32>,
    /// Lambertian shading from the local surface normal, 0–1 (shape cue only).
    pub(crate) shade: f32,
}

/// Outline classes of the expected model outline.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Edge {
    /// No edge.
    None,
    /// An edge of a fitted link (base, shoulder, upper arm): what registration used.
    Fitted,
    /// An edge of the rest of the arm.
    Other,
}

/// The scan seen from the camera, resampled to picture size, with distances and the outline.
#[derive(Debug, Clone)]
pub struct ScanView {
    pub(crate) width: usize,
    pub(crate) height: usize,
    /// Row-major, `width × height`; `None` where the scan has no point.
    pub(crate) pixels: Vec<Option<ScanPixel>>,
    /// Row-major, `width × height`.
    pub(crate) edges: Vec<Edge>,
    /// What the picture shows (which frame of which scan).
    pub(crate) caption: String,
}

impl ScanView {
    /// Resamples `cloud` (camera frame, metres; organized or not) into a picture at most
    /// `max_width × max_height`, measures each point's distance to `model` posed by
    /// `camera_from_model` (the points divided by the camera's `depth_scale` that registration
    /// estimated, measured / true, as registration measured them), and ray-casts the model's outline into the same picture. Links up
    /// to `fit_depth` movable joints from the root are drawn as the fitted ones.
    ///
    /// Errors when the cloud has too few points to be a scan.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        cloud: &PointCloud,
        model: &PosedModel,
        camera_from_model: &Isometry3<f64>,
        depth_scale: Option<f64>,
        fit_depth: usize,
        max_width: usize,
        max_height: usize,
        caption: impl Into<String>,
    ) -> Result<ScanView, crate::calib::CalibError> {
        let range = RangeImage::new(cloud)?;
        let cam = range.cam;
        let scale = (max_width as f64 / f64::from(cam.width))
            .min(max_height as f64 / f64::from(cam.height))
            .min(1.0);
        let pic = cam.scaled(scale);
        let (w, h) = (pic.width as usize, pic.height as usize);
        let (gw, gh) = (cam.width as usize, cam.height as usize);
        // Each picture pixel takes the valid scan point nearest its centre within its block.
        let block = (1.0 / scale).ceil() as i64;
        let points: Vec<Option<Point3<f64>>> = (0..w * h)
            .into_par_iter()
            .map(|i| {
                let (u, v) = ((i % w) as f64, (i / w) as f64);
                let gu = ((u + 0.5) / scale - 0.5).round() as i64;
                let gv = ((v + 0.5) / scale - 0.5).round() as i64;
                let mut best: Option<(i64, Point3<f64>)> = None;
                for dv in -(block / 2)..=(block / 2) {
                    for du in -(block / 2)..=(block / 2) {
                        let (x, y) = (gu + du, gv + dv);
                        if x < 0 || y < 0 || x as usize >= gw || y as usize >= gh {
                            continue;
                        }
                        if let Some(p) = range.point(y as usize * gw + x as usize) {
                            let d = du * du + dv * dv;
                            if best.is_none_or(|(bd, _)| d < bd) {
                                best = Some((d, p.cast::<f64>()));
                            }
                        }
                    }
                }
                best.map(|(_, p)| p)
            })
            .collect();

        let surface = ModelSurface::new(model, usize::MAX, SAMPLE_SPACING_M, 0.05);
        let model_from_camera = camera_from_model.inverse();
        let scale_error = depth_scale
            .filter(|s| s.is_finite() && *s > 0.5)
            .unwrap_or(1.0);
        let normal = |i: usize| -> Option<Vector3<f64>> {
            let (u, v) = (i % w, i / w);
            let at = |uu: usize, vv: usize| points.get(vv * w + uu).copied().flatten();
            let (l, r) = (at(u.saturating_sub(3), v)?, at((u + 3).min(w - 1), v)?);
            let (t, b) = (at(u, v.saturating_sub(3))?, at(u, (v + 3).min(h - 1))?);
            let n = (r - l).cross(&(b - t));
            let len = n.norm();
            // Neighbours on another surface (a depth edge) give no normal.
            let span = (r - l).norm().max((b - t).norm());
            (len > 0.0 && span < 0.05 * points[i]?.z).then(|| n / len)
        };
        let pixels: Vec<Option<ScanPixel>> = (0..w * h)
            .into_par_iter()
            .map(|i| {
                let p = points[i]?;
                let q = model_from_camera * Point3::from(p.coords / scale_error);
                let distance_mm = surface.nearest(&q, SEARCH_M).and_then(|s| {
                    let tri = surface.triangles.get(s.tri as usize)?;
                    let d = (tri.closest_point(&q) - q).norm();
                    (d <= SEARCH_M).then_some((d * 1e3) as f32)
                });
                // Six shading levels: enough for the shape, and the PNG stays small.
                let shade = normal(i).map_or(0.75, |n| {
                    let view = -p.coords.normalize();
                    ((n.dot(&view).abs() * 6.0).round() / 6.0) as f32
                });
                Some(ScanPixel { distance_mm, shade })
            })
            .collect();

        // The outline: the posed model ray-cast into the same picture.
        let posed: Vec<(Vec<Point3<f64>>, usize)> = model
            .parts
            .iter()
            .map(|part| (part.vertices_in_model(), part.chain_depth))
            .collect();
        let meshes: Vec<SceneMesh<'_>> = posed
            .iter()
            .zip(&model.parts)
            .enumerate()
            .map(|(k, ((vertices, _), part))| SceneMesh {
                vertices,
                triangles: &part.mesh.triangles,
                object: k as u32,
            })
            .collect();
        let depth = raycast(&meshes, camera_from_model, &pic);
        let fitted: Vec<bool> = posed.iter().map(|(_, d)| *d <= fit_depth).collect();
        let edges = outline(&depth, &fitted);
        Ok(ScanView {
            width: w,
            height: h,
            pixels,
            edges,
            caption: caption.into(),
        })
    }

    /// Distances of the scan points within `max_mm` of the model, mm (picture resolution).
    pub(crate) fn distances(&self, max_mm: f32) -> Vec<f32> {
        self.pixels
            .iter()
            .filter_map(|p| p.and_then(|p| p.distance_mm))
            .filter(|d| *d <= max_mm)
            .collect()
    }

    /// Pixels with a scan point.
    pub(crate) fn valid(&self) -> usize {
        self.pixels.iter().filter(|p| p.is_some()).count()
    }

    /// Pixels the model's outline covers.
    #[cfg(test)]
    pub(crate) fn edge_pixels(&self) -> usize {
        self.edges.iter().filter(|e| **e != Edge::None).count()
    }
}

/// Outline pixels of a ray-cast model: where the hit link changes (or the model ends), and
/// depth steps within a link; the pixel on the nearer side is marked.
fn outline(depth: &DepthImage, fitted: &[bool]) -> Vec<Edge> {
    let (w, h) = (depth.width, depth.height);
    let mut edges = vec![Edge::None; w * h];
    let class = |i: usize| -> Edge {
        match fitted.get(depth.object[i] as usize) {
            Some(true) => Edge::Fitted,
            Some(false) => Edge::Other,
            None => Edge::None,
        }
    };
    for v in 0..h {
        for u in 0..w {
            let i = v * w + u;
            for j in [(u + 1 < w).then(|| i + 1), (v + 1 < h).then(|| i + w)]
                .into_iter()
                .flatten()
            {
                let (oi, oj) = (depth.object[i], depth.object[j]);
                let (di, dj) = (depth.depth[i], depth.depth[j]);
                if oi == DepthImage::NO_HIT && oj == DepthImage::NO_HIT {
                    continue;
                }
                let step = oi != oj || (di - dj).abs() > CREASE_STEP * di.min(dj);
                if step {
                    let near = if di <= dj { i } else { j };
                    let c = class(near);
                    // A fitted link's edge wins over another link's on the same pixel.
                    if edges[near] != Edge::Fitted {
                        edges[near] = c;
                    }
                }
            }
        }
    }
    edges
}
