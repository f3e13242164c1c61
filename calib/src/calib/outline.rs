//! The arm's outline in the colour image, fitted beside the depth.
//!
//! A camera that gives an image registered to its depth (active stereo with an RGB or infrared
//! imager) sees the arm's outline far more sharply than its depth: a stereo camera a metre or
//! more away bends its depth by smooth blobs of centimetres and by a gradient across the image,
//! which a depth-only fit takes for a turn of the arm. The outline does not bend with the depth:
//! where the model's silhouette falls in the image is set by the pose alone.
//!
//! At the current `camera_from_model` the posed model is ray-cast; its silhouette contour
//! (model pixels beside empty ones, or beside model surface far behind) is sampled, one point per
//! [`STEP_PX`]-square block. From each contour point the image is searched along the
//! silhouette's normal for the arm's edge, only where the scan says the contour is one: inside,
//! scan depth near the model's; outside, at the end of the search, nothing or background far
//! behind (a contour against the table, the second arm, a cable in front, tells nothing and is
//! left out). The edge is the strongest colour step within [`DEPTH_EDGE_PX`] of where the scan's
//! depth leaves the arm, to a tenth of a pixel; its offset from the predicted contour is the
//! residual (pixels along the normal), under a Cauchy kernel (cables, the CAD's missing parts,
//! background edges next to the arm).
//!
//! The depth fit enters as what it is: each frame's pose estimate with its covariance (the
//! smooth depth errors and the depth gradient included, so the directions the depth bends are
//! loose in it), the part every frame of the camera shares counted once over the frames. The
//! outline then holds the directions in the image plane, the depth holds the range, and the
//! two are solved together (Gauss-Newton on a left perturbation of `camera_from_model`, the
//! contour re-extracted every step). Several configurations seen by a camera fixed in the cell
//! share the one pose (eye-to-hand). The covariance is a sandwich over image cells of
//! [`CELL_PX`] (an edge's error is shared along a stretch of contour), with a colour-to-depth
//! misalignment of [`ALIGNMENT_PX`] shared by the whole image.

use handeye_hal::PointCloud;
use nalgebra::{Isometry3, Matrix6, Point3, Translation3, UnitQuaternion, Vector2, Vector3, Vector6};
use rayon::prelude::*;

use super::range::RangeImage;
use super::register::covariance::summary;
use super::surface::PosedModel;
use super::Uncertainty;
use crate::cloud::ColorImage;
use crate::geometry::raycast::{raycast, DepthImage, SceneMesh};
use crate::geometry::Intrinsics;
use crate::model::TriMesh;

/// One contour point is kept per block of this many pixels square.
const STEP_PX: usize = 3;
/// How far along the normal the image is searched for the edge, pixels each way: the pose's
/// error before the outline (a depth-only fit 3 cm off at 1.3 m) is about 20 px at 900 px focal
/// length; the search scales with the image.
const SEARCH_PX: f64 = 24.0;
/// The colour edge is looked for this close to where the scan's depth leaves the arm, pixels
/// (a stereo depth's edges are fattened by a few pixels of its matching window).
const DEPTH_EDGE_PX: i64 = 6;
/// Scan depth within this of the model's at the contour is the arm, metres (a stereo camera's
/// depth bias of 1 % at 1.5 m, its blobs, and the pose's error before the fit).
const ARM_DEPTH_M: f64 = 0.06;
/// Scan depth this far behind the contour (or none) is background, metres.
const BACKGROUND_GAP_M: f64 = 0.10;
/// Model surface this far behind a model pixel makes it a contour too (an arm link in front of
/// another), metres.
const OCCLUSION_GAP_M: f64 = 0.10;
/// Weakest colour step taken as an edge (largest of the channels' central differences, 8-bit
/// levels).
const MIN_CONTRAST: f64 = 6.0;
/// Cauchy kernel of the edge residuals, pixels (at least; wider while the fit is far off).
const KERNEL_PX: f64 = 1.5;
/// Edges whose residuals share their error: cells of this many pixels square.
const CELL_PX: usize = 40;
/// 1σ of the colour image's misalignment with the depth, pixels per axis, shared by every edge
/// of a view (the factory calibration between a stereo camera's colour imager and its depth).
const ALIGNMENT_PX: f64 = 0.5;
/// Fewest edges a fit needs over all views.
const MIN_EDGES: usize = 40;
/// Gauss-Newton steps.
const MAX_STEPS: usize = 12;

/// One configuration of the arm as the camera saw it: scan, image and the depth fit.
#[derive(Debug, Clone, Copy)]
pub(crate) struct OutlineView<'a> {
    /// The scan (camera frame), organized, pixel-aligned with `image`.
    pub(crate) cloud: &'a PointCloud,
    /// The colour image.
    pub(crate) image: &'a ColorImage,
    /// The model posed at the frame's joints (model frame).
    pub(crate) posed: &'a PosedModel,
    /// The depth fit's `camera_from_model`.
    pub(crate) depth_pose: Isometry3<f64>,
    /// Its covariance, a left perturbation in the camera frame
    /// ([`super::Registration::covariance_6x6`]).
    pub(crate) depth_covariance: Matrix6<f64>,
    /// The part of it the camera's own depth errors give, shared by every frame
    /// ([`super::Registration::camera_covariance_6x6`]).
    pub(crate) camera_covariance: Matrix6<f64>,
}

/// The result of [`fit_outline`].
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct OutlineFit {
    /// The shared `camera_from_model`.
    pub(crate) camera_from_model: Isometry3<f64>,
    /// Its covariance (left perturbation in the camera frame).
    pub(crate) covariance: Matrix6<f64>,
    /// Its 1σ summary (the robot base's position σ included).
    pub(crate) uncertainty: Uncertainty,
    /// Edges found and used at the end.
    pub(crate) edges: usize,
    /// Robust spread of the edge residuals, pixels.
    pub(crate) spread_px: f64,
    /// Share of the contour points checked (where the scan says they are a contour) whose edge
    /// is within 3 kernels of the model's outline.
    pub(crate) support: f64,
}

/// A view made ready: its intrinsics and the posed model's meshes.
struct Prepared<'a> {
    view: OutlineView<'a>,
    intr: Intrinsics,
    meshes: Vec<TriMesh>,
}

/// One edge found from a contour point.
#[derive(Debug, Clone, Copy)]
struct Edge {
    /// The contour point, camera frame at the pose it was found at.
    p: Point3<f64>,
    /// The silhouette's outward unit normal in the image.
    n: Vector2<f64>,
    /// Focal length, pixels.
    f: f64,
    /// The edge's offset from the predicted outline along `n`, pixels.
    r: f64,
    /// Image cell, for the shared errors.
    cell: usize,
}

/// The views that can be fitted: an organized scan with an image of its size.
fn prepare<'a>(views: &[OutlineView<'a>]) -> Vec<Prepared<'a>> {
    views
        .iter()
        .filter_map(|v| {
            let range = RangeImage::new(v.cloud).ok()?;
            if !range.organized
                || range.cam.width as usize != v.image.width
                || range.cam.height as usize != v.image.height
            {
                tracing::warn!(
                    "the image ({}×{}) is not the scan's pixel grid: its outline is not used",
                    v.image.width,
                    v.image.height
                );
                return None;
            }
            let meshes = v
                .posed
                .parts
                .iter()
                .map(|part| TriMesh {
                    vertices: part
                        .mesh
                        .vertices
                        .iter()
                        .map(|p| part.model_from_link * p)
                        .collect(),
                    triangles: part.mesh.triangles.clone(),
                })
                .collect();
            Some(Prepared {
                view: *v,
                intr: range.cam,
                meshes,
            })
        })
        .collect()
}

/// Fits the one `camera_from_model` that the outlines of all `views` and their depth fits
/// support (see the module docs), started at `start`. `None` when no view can be used or too
/// few edges are found.
pub(crate) fn fit_outline(
    views: &[OutlineView<'_>],
    start: &Isometry3<f64>,
) -> Option<OutlineFit> {
    let prepared = prepare(views);
    if prepared.is_empty() {
        return None;
    }
    let n = prepared.len() as f64;
    // Each view's depth information, the camera's shared part counted once over the views.
    let depth: Vec<(Isometry3<f64>, Matrix6<f64>)> = prepared
        .iter()
        .map(|p| {
            let c = p.view.depth_covariance + p.view.camera_covariance * (n - 1.0);
            let c = (c + c.transpose()) / 2.0;
            c.try_inverse().map(|w| (p.view.depth_pose, w))
        })
        .collect::<Option<_>>()?;
    let w_depth: Matrix6<f64> = depth.iter().map(|(_, w)| w).sum();
    let mut t = *start;
    let mut kernel = f64::INFINITY;
    let mut last = None;
    for step in 0..=MAX_STEPS {
        let found: Vec<(Vec<Edge>, usize)> = prepared.par_iter().map(|p| edges(p, &t)).collect();
        let all: Vec<&Edge> = found.iter().flat_map(|(e, _)| e).collect();
        if all.len() < MIN_EDGES {
            return None;
        }
        let spread = robust_spread(all.iter().map(|e| e.r)).max(0.3);
        // The kernel follows the residuals down to its floor (far off, every edge is far).
        kernel = kernel.min((2.5 * spread).max(KERNEL_PX));
        let normal = normal_equations(&found, kernel, spread);
        // The depth fits' pull towards their estimates, about the current pose.
        let mut h = normal.h + w_depth;
        let mut g = normal.g;
        for (pose, w) in &depth {
            g += w * log(&(pose * t.inverse()));
        }
        for k in 0..6 {
            h[(k, k)] += 1e-12;
        }
        let h_inv = h.try_inverse()?;
        let delta = h_inv * g;
        let checked: usize = found.iter().map(|(_, c)| c).sum();
        let near = all.iter().filter(|e| e.r.abs() < 3.0 * kernel).count();
        last = Some((normal, h_inv, all.len(), spread, near as f64 / checked.max(1) as f64));
        if step == MAX_STEPS {
            break;
        }
        t = exp(&delta) * t;
        let small = delta.fixed_rows::<3>(0).norm() < 2e-5 && delta.fixed_rows::<3>(3).norm() < 2e-5;
        if small && step >= 2 && kernel <= KERNEL_PX {
            // One more pass at the converged pose for its covariance.
            let found: Vec<(Vec<Edge>, usize)> =
                prepared.par_iter().map(|p| edges(p, &t)).collect();
            let all: Vec<&Edge> = found.iter().flat_map(|(e, _)| e).collect();
            if all.len() < MIN_EDGES {
                return None;
            }
            let spread = robust_spread(all.iter().map(|e| e.r)).max(0.3);
            let normal = normal_equations(&found, kernel, spread);
            let h_inv = (normal.h + w_depth).try_inverse()?;
            let checked: usize = found.iter().map(|(_, c)| c).sum();
            let near = all.iter().filter(|e| e.r.abs() < 3.0 * kernel).count();
            last = Some((normal, h_inv, all.len(), spread, near as f64 / checked.max(1) as f64));
            break;
        }
    }
    let (normal, h_inv, edges_used, spread_px, support) = last?;
    // Sandwich: the depth fits' information as it is, the edges' by their cells' scores, and
    // the image's misalignment moving every edge of a view together.
    let meat = normal.meat + w_depth;
    let mut covariance = h_inv * meat * h_inv.transpose();
    for shift in &normal.alignment {
        let d = h_inv * shift;
        covariance += d * d.transpose() * ALIGNMENT_PX.powi(2);
    }
    let covariance = (covariance + covariance.transpose()) / 2.0;
    Some(OutlineFit {
        camera_from_model: t,
        covariance,
        uncertainty: summary(&covariance, &t.translation.vector),
        edges: edges_used,
        spread_px,
        support,
    })
}

/// The edges' normal equations about the current pose (`h δ = g` with the depth's added), the
/// scores' meat over image cells, and how the solution moves per pixel of image shift of each
/// view along x and y.
struct Normal {
    h: Matrix6<f64>,
    g: Vector6<f64>,
    meat: Matrix6<f64>,
    alignment: Vec<Vector6<f64>>,
}

fn normal_equations(found: &[(Vec<Edge>, usize)], kernel: f64, spread: f64) -> Normal {
    let mut h = Matrix6::zeros();
    let mut g = Vector6::zeros();
    let mut meat = Matrix6::zeros();
    let mut alignment = Vec::new();
    for (edges, _) in found {
        // An edge's error is shared along its stretch of contour: the cells count, not the
        // edges.
        let mut cells: std::collections::BTreeMap<usize, Vector6<f64>> = Default::default();
        for e in edges {
            cells.entry(e.cell).or_default();
        }
        let share = edges.len() as f64 / cells.len().max(1) as f64;
        let scale = 1.0 / (spread * spread * share);
        let mut shift = [Vector6::zeros(), Vector6::zeros()];
        for e in edges {
            let j = jacobian(e);
            let w = 1.0 / (1.0 + (e.r / kernel).powi(2)) * scale;
            h += j * j.transpose() * w;
            g -= j * (w * e.r);
            if let Some(score) = cells.get_mut(&e.cell) {
                *score += j * (w * e.r);
            }
            // An image shifted by one pixel along x (y) moves this edge's residual by n.x (n.y).
            shift[0] -= j * (w * e.n.x);
            shift[1] -= j * (w * e.n.y);
        }
        for s in cells.values() {
            meat += s * s.transpose();
        }
        alignment.extend(shift);
    }
    Normal {
        h,
        g,
        meat,
        alignment,
    }
}

/// How an edge's residual changes with a left perturbation `(ρ, φ)` of `camera_from_model` in
/// the camera frame: the contour point moves by `ρ + φ × p`, its projection with it, and the
/// residual (edge minus predicted outline, along `n`) by minus that along `n`.
fn jacobian(e: &Edge) -> Vector6<f64> {
    let p = e.p.coords;
    let z = p.z;
    // d(u, v)/dp for u = f x / z, v = f y / z.
    let du = Vector3::new(e.f / z, 0.0, -e.f * p.x / (z * z));
    let dv = Vector3::new(0.0, e.f / z, -e.f * p.y / (z * z));
    let a = du * e.n.x + dv * e.n.y;
    // ∂(a·(ρ + φ × p)) = (a, p × a).
    let rot = p.cross(&a);
    -Vector6::new(a.x, a.y, a.z, rot.x, rot.y, rot.z)
}

/// The contour points of the posed model at `camera_from_model` and the edges found from them
/// (see the module docs), with how many contour points the scan confirmed as a contour.
fn edges(p: &Prepared<'_>, camera_from_model: &Isometry3<f64>) -> (Vec<Edge>, usize) {
    let scenes = SceneMesh::indexed(&p.meshes);
    let render = raycast(&scenes, camera_from_model, &p.intr);
    let (w, h) = (render.width, render.height);
    // Image sizes other than the 1280 px this was tuned at scale the search.
    let scale = (w as f64 / 1280.0).max(0.25);
    let search = (SEARCH_PX * scale).round() as i64;
    let f = (p.intr.fx + p.intr.fy) / 2.0;
    let mut taken = vec![false; w.div_ceil(STEP_PX) * h.div_ceil(STEP_PX)];
    let bw = w.div_ceil(STEP_PX);
    let cells_across = w.div_ceil(CELL_PX);
    let mut out = Vec::new();
    let mut checked = 0;
    for v in 1..h.saturating_sub(1) {
        for u in 1..w.saturating_sub(1) {
            let block = (v / STEP_PX) * bw + u / STEP_PX;
            if taken[block] {
                continue;
            }
            let Some(n) = contour_normal(&render, u, v) else {
                continue;
            };
            taken[block] = true;
            let z0 = render.depth[v * w + u];
            let Some(r) = find_edge(p, (u, v), n, z0, search) else {
                continue;
            };
            checked += 1;
            let Some(r) = r else { continue };
            let Some(point) = render.point(&p.intr, u, v) else {
                continue;
            };
            out.push(Edge {
                p: point,
                n,
                f,
                r,
                cell: (v / CELL_PX) * cells_across + u / CELL_PX,
            });
        }
    }
    (out, checked)
}

/// The silhouette's outward normal at model pixel `(u, v)`: towards its neighbours without
/// model surface or with model surface far behind; `None` inside the silhouette or off it.
fn contour_normal(render: &DepthImage, u: usize, v: usize) -> Option<Vector2<f64>> {
    let w = render.width;
    let z = render.depth[v * w + u];
    if !z.is_finite() {
        return None;
    }
    let mut out = Vector2::zeros();
    for dv in -1i64..=1 {
        for du in -1i64..=1 {
            if du == 0 && dv == 0 {
                continue;
            }
            let (nu, nv) = ((u as i64 + du) as usize, (v as i64 + dv) as usize);
            let zn = render.depth[nv * w + nu];
            if !zn.is_finite() || zn > z + OCCLUSION_GAP_M {
                out += Vector2::new(du as f64, dv as f64);
            }
        }
    }
    out.try_normalize(1e-9)
}

/// From contour pixel `at` (model depth `z0`) along the outward normal `n`: `None` when the scan
/// does not show a contour there; `Some(None)` when it does but the image has no edge near it;
/// `Some(Some(r))` the edge's offset from the model's outline, pixels (the outline is half a
/// pixel outside the contour pixel's centre).
fn find_edge(
    p: &Prepared<'_>,
    at: (usize, usize),
    n: Vector2<f64>,
    z0: f64,
    search: i64,
) -> Option<Option<f64>> {
    let (w, h) = (p.intr.width as i64, p.intr.height as i64);
    let pixel = |s: f64| {
        (
            at.0 as f64 + s * n.x,
            at.1 as f64 + s * n.y,
        )
    };
    let scan_depth = |s: i64| -> Option<f64> {
        let (x, y) = pixel(s as f64);
        let (u, v) = (x.round() as i64, y.round() as i64);
        if u < 0 || v < 0 || u >= w || v >= h {
            return None;
        }
        let z = p.view.cloud.points.get((v * w + u) as usize)?.z;
        z.is_finite().then_some(f64::from(z))
    };
    // Both ends inside the image.
    let (x0, y0) = pixel(-search as f64);
    let (x1, y1) = pixel(search as f64);
    let inside = |x: f64, y: f64| x >= 1.0 && y >= 1.0 && x < (w - 2) as f64 && y < (h - 2) as f64;
    if !inside(x0, y0) || !inside(x1, y1) {
        return None;
    }
    // Outside, at the end of the search: background far behind, or nothing.
    let background = (search - 2..=search).all(|s| scan_depth(s).is_none_or(|d| d > z0 + BACKGROUND_GAP_M));
    if !background {
        return None;
    }
    // Where the scan's depth leaves the arm, going out.
    let edge = (-search..search - 2)
        .rev()
        .find(|&s| scan_depth(s).is_some_and(|d| (d - z0).abs() < ARM_DEPTH_M))?;
    // The strongest colour step near it.
    let colour = |s: f64| -> Option<[f64; 3]> {
        let (x, y) = pixel(s);
        bilinear(p.view.image, x, y)
    };
    let step = |s: i64| -> Option<f64> {
        let (a, b) = (colour(s as f64 - 1.0)?, colour(s as f64 + 1.0)?);
        Some(
            (0..3)
                .map(|c| (b[c] - a[c]).abs() / 2.0)
                .fold(0.0, f64::max),
        )
    };
    let lo = (edge - DEPTH_EDGE_PX).max(-search + 1);
    let hi = (edge + DEPTH_EDGE_PX).min(search - 1);
    let mut best: Option<(i64, f64)> = None;
    for s in lo..=hi {
        let g = step(s)?;
        if best.is_none_or(|(_, b)| g > b) {
            best = Some((s, g));
        }
    }
    let (s, g) = best?;
    if g < MIN_CONTRAST {
        return Some(None);
    }
    // A tenth of a pixel from the parabola through the step and its neighbours.
    let (gm, gp) = (step(s - 1).unwrap_or(g), step(s + 1).unwrap_or(g));
    let curvature = gm - 2.0 * g + gp;
    let sub = if curvature < -1e-9 {
        (0.5 * (gm - gp) / curvature).clamp(-0.5, 0.5)
    } else {
        0.0
    };
    Some(Some(s as f64 + sub - 0.5))
}

/// The image's colour at `(x, y)`, bilinear; `None` outside.
fn bilinear(img: &ColorImage, x: f64, y: f64) -> Option<[f64; 3]> {
    let (u, v) = (x.floor(), y.floor());
    let (a, b) = (x - u, y - v);
    let (u, v) = (u as i64, v as i64);
    let px = |du: i64, dv: i64| img.at(u + du, v + dv).map(|c| c.map(f64::from));
    let (p00, p10, p01, p11) = (px(0, 0)?, px(1, 0)?, px(0, 1)?, px(1, 1)?);
    Some(std::array::from_fn(|c| {
        (p00[c] * (1.0 - a) + p10[c] * a) * (1.0 - b) + (p01[c] * (1.0 - a) + p11[c] * a) * b
    }))
}

/// 1.4826 × the median absolute value of `r`.
fn robust_spread(r: impl Iterator<Item = f64>) -> f64 {
    let mut a: Vec<f64> = r.map(f64::abs).collect();
    if a.is_empty() {
        return 0.0;
    }
    let mid = a.len() / 2;
    1.4826 * *a.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// The left perturbation `(ρ, φ)` with `exp(δ) = x` (translation as is, rotation vector).
fn log(x: &Isometry3<f64>) -> Vector6<f64> {
    let r = x.rotation.scaled_axis();
    let t = x.translation.vector;
    Vector6::new(t.x, t.y, t.z, r.x, r.y, r.z)
}

/// The isometry of the left perturbation `δ = (ρ, φ)`.
fn exp(d: &Vector6<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(d[0], d[1], d[2]),
        UnitQuaternion::from_scaled_axis(Vector3::new(d[3], d[4], d[5])),
    )
}
