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
//! silhouette's normal for the arm's edge, only where the scan says the contour is one: at the
//! outer end of the search, nothing or background far behind (a contour against the table, the
//! second arm, a cable in front, tells nothing and is left out), and inside, scan depth near the
//! model's. Stereo depth spills past the arm's edge by its matching window, so the edge is
//! looked for inside where the depth ends (up to [`DEPTH_EDGE_PX`] beyond): of the colour steps
//! there, the strongest near the predicted outline, to a tenth of a pixel. Its offset from the
//! predicted outline is the residual (pixels along the normal), under a Cauchy kernel (cables,
//! the CAD's missing parts, background edges next to the arm).
//!
//! The outline cannot see a turn of the arm towards or away from the camera (about the base,
//! across the line of sight): its silhouette barely changes. That is the turn a stereo camera's
//! depth gradient down the image fakes. The surface the base stands on holds it: its normal,
//! fitted to the scan around the base's foot ([`support_plane`]), is the base's axis (a
//! table's flatness and the base's seat within [`SUPPORT_FLATNESS_RAD`]), and a depth error
//! growing across the image moves a surface seen edge-on along itself, not its normal.
//!
//! The depth fit enters as what it is: each frame's pose estimate with its covariance, of which
//! the part the camera's own depth errors give (scale, offset, gradient: the same in every
//! frame) is estimated once over the frames as shared parameters. The outline then holds the
//! directions in the image plane, the depth the range, the support the tilt, solved together
//! (Gauss-Newton on a left perturbation of `camera_from_model`, the contour re-extracted every
//! step). Several configurations seen by a camera fixed in the cell share the one pose
//! (eye-to-hand). The covariance is a sandwich (edges weighed by image cells of [`CELL_PX`],
//! their scores summed per model part), with what the residuals cannot show added: each
//! part's outline off the real part's by [`PART_SHIFT_PX`] (kinematic error, CAD) and the
//! colour image off the depth by [`ALIGNMENT_PX`].

use std::ops::AddAssign;

use handeye_hal::PointCloud;

use nalgebra::{
    Isometry3, Matrix6, Matrix6x4, Point3, SMatrix, SVector, Translation3, UnitQuaternion, Vector2,
    Vector3, Vector6,
};
use rayon::prelude::*;

use super::range::RangeImage;
use super::register::covariance::summary;
use super::surface::{PosedModel, PosedPart};
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
/// 1σ of a model part's outline off the real part's, pixels per axis, shared by its edges: the
/// arm's kinematic error at the measured joints and the CAD's (a few millimetres at a metre or
/// more). The residuals cannot show it where the pose absorbs it.
const PART_SHIFT_PX: f64 = 1.5;
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
    /// How the camera's own depth errors (scale, offset, gradient across and down the image,
    /// each at its 1σ) move it ([`super::Registration::camera_error_columns`]): the same errors
    /// in every frame of the camera, estimated once over the views.
    pub(crate) camera_error: Matrix6x4<f64>,
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
    /// Image cell: the edges of a stretch of contour share their error.
    cell: usize,
    /// The model part whose outline it is: the edges of a part share its error against the
    /// real arm (its kinematic error, the CAD).
    part: u32,
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
            let meshes = v.posed.parts.iter().map(PosedPart::mesh_in_model).collect();
            Some(Prepared {
                view: *v,
                intr: range.cam,
                meshes,
            })
        })
        .collect()
}

/// Parameters of the joint fit: the pose perturbation `δ` (6) and the camera's shared depth
/// errors `z` (4, prior `N(0, I)`).
const NJ: usize = 10;
type MatJ = SMatrix<f64, NJ, NJ>;
type VecJ = SVector<f64, NJ>;

/// Fits the one `camera_from_model` that the outlines of all `views` and their depth fits
/// support (see the module docs), started at `start`. `None` when no view can be used or too
/// few edges are found.
///
/// Each view's depth estimate `δᵢ` (about the current pose) is `δ + Mᵢ z + εᵢ`: the shared pose,
/// the camera's depth errors `z` carried by that view's `Mᵢ`, and its own error `εᵢ` of
/// covariance `Cᵢ − Mᵢ Mᵢᵀ`. The camera's errors are thus counted once, whatever the number of
/// views, and where the views' `Mᵢ` differ (the arm elsewhere in the image) the views estimate
/// them.
pub(crate) fn fit_outline(views: &[OutlineView<'_>], start: &Isometry3<f64>) -> Option<OutlineFit> {
    let prepared = prepare(views);
    if prepared.is_empty() {
        return None;
    }
    // The surface the base stands on, the same in every view: its normal, averaged over the
    // views that show it, with one view's σ.
    let planes: Vec<(Vector3<f64>, f64)> = prepared
        .iter()
        .filter_map(|p| support_plane(p.view.cloud, p.view.posed, start))
        .collect();
    let support = (!planes.is_empty()).then(|| {
        let n = planes
            .iter()
            .map(|(n, _)| n)
            .sum::<Vector3<f64>>()
            .normalize();
        let sigma = planes.iter().map(|(_, s)| s).sum::<f64>() / planes.len() as f64;
        (n, sigma)
    });
    // Each view's own depth information (without the camera's shared errors).
    let depth: Vec<(Isometry3<f64>, Matrix6<f64>, Matrix6x4<f64>)> = prepared
        .iter()
        .map(|p| {
            let m = p.view.camera_error;
            let own = p.view.depth_covariance - m * m.transpose();
            let own = (own + own.transpose()) / 2.0;
            // What the subtraction leaves below a micrometre / microradian is held there.
            let eig = own.symmetric_eigen();
            let floor = eig.eigenvalues.map(|e| e.max(1e-12));
            let w = eig.eigenvectors
                * Matrix6::from_diagonal(&floor.map(|e| 1.0 / e))
                * eig.eigenvectors.transpose();
            (p.view.depth_pose, w, m)
        })
        .collect();
    // The depth's part of the normal equations about pose `t` and shared errors `z`: its
    // information (also the sandwich's meat) and gradient.
    let depth_terms = |t: &Isometry3<f64>, z: &SVector<f64, 4>| {
        let mut h = MatJ::zeros();
        let mut g = VecJ::zeros();
        for (pose, w, m) in &depth {
            // e = δᵢ − δ − M z, ∂e/∂(δ, z) = −[I, M].
            let mut j = SMatrix::<f64, 6, NJ>::zeros();
            j.fixed_view_mut::<6, 6>(0, 0)
                .copy_from(&Matrix6::identity());
            j.fixed_view_mut::<6, 4>(0, 6).copy_from(m);
            let e = log(&(pose * t.inverse())) - m * z;
            h += j.transpose() * w * j;
            g += j.transpose() * w * e;
        }
        for k in 6..NJ {
            h[(k, k)] += 1.0;
            g[k] -= z[k - 6];
        }
        // The base's axis along the support's normal: r = n × a, a = R e_z, which a turn φ
        // moves by n × (φ × a) = −[n]×[a]× φ.
        if let Some((n, sigma)) = support {
            let a = t.rotation * Vector3::z();
            let r = n.cross(&a);
            let j = -(n.cross_matrix() * a.cross_matrix());
            let w = 1.0 / (sigma * sigma);
            let mut hv = h.fixed_view_mut::<3, 3>(3, 3);
            hv += j.transpose() * j * w;
            let mut gv = g.fixed_rows_mut::<3>(3);
            gv -= j.transpose() * r * w;
        }
        (h, g)
    };
    let mut t = *start;
    let mut z = SVector::<f64, 4>::zeros();
    let mut kernel = SEARCH_PX / 2.0;
    let mut last = None;
    for step in 0..=MAX_STEPS {
        let found: Vec<(Vec<Edge>, usize)> =
            prepared.par_iter().map(|p| edges(p, &t, kernel)).collect();
        let all: Vec<&Edge> = found.iter().flat_map(|(e, _)| e).collect();
        if all.len() < MIN_EDGES {
            return None;
        }
        let spread = robust_spread(all.iter().map(|e| e.r)).max(0.3);
        let normal = normal_equations(&found, kernel, spread);
        let (hd, gd) = depth_terms(&t, &z);
        let mut h = hd;
        let mut g = gd;
        h.fixed_view_mut::<6, 6>(0, 0).add_assign(&normal.h);
        g.fixed_rows_mut::<6>(0).add_assign(&normal.g);
        let h_inv = h.try_inverse()?;
        let checked: usize = found.iter().map(|(_, c)| c).sum();
        let near = all.iter().filter(|e| e.r.abs() < 3.0 * kernel).count();
        let converged_kernel = kernel;
        // The kernel follows the residuals down to its floor (far off, every edge is far).
        kernel = kernel.min((2.5 * spread).max(KERNEL_PX));
        let delta = h_inv * g;
        tracing::debug!(
            step,
            edges = all.len(),
            spread_px = spread,
            kernel_px = converged_kernel,
            step_mm = delta.fixed_rows::<3>(0).norm() * 1e3,
            "outline fit"
        );
        let small = delta.fixed_rows::<3>(0).norm() < 2e-5
            && delta.fixed_rows::<3>(3).norm() < 2e-5
            && delta.fixed_rows::<4>(6).amax() < 1e-3;
        last = Some((
            normal,
            hd,
            h_inv,
            all.len(),
            spread,
            near as f64 / checked.max(1) as f64,
        ));
        if step == MAX_STEPS || (small && step >= 2 && converged_kernel <= kernel) {
            break;
        }
        t = exp(&delta.fixed_rows::<6>(0).into_owned()) * t;
        z += delta.fixed_rows::<4>(6);
    }
    let (normal, hd, h_inv, edges_used, spread_px, support) = last?;
    // Sandwich: the depth's information as it is, the edges' by their cells' scores, and the
    // image's misalignment moving every edge of a view together.
    let mut meat = hd;
    meat.fixed_view_mut::<6, 6>(0, 0).add_assign(&normal.meat);
    let mut full = h_inv * meat * h_inv.transpose();
    for shift in &normal.alignment {
        let mut s = VecJ::zeros();
        s.fixed_rows_mut::<6>(0).copy_from(shift);
        let d = h_inv * s;
        full += d * d.transpose() * ALIGNMENT_PX.powi(2);
    }
    for shift in &normal.parts_moved {
        let mut s = VecJ::zeros();
        s.fixed_rows_mut::<6>(0).copy_from(shift);
        let d = h_inv * s;
        full += d * d.transpose() * PART_SHIFT_PX.powi(2);
    }
    let covariance: Matrix6<f64> = full.fixed_view::<6, 6>(0, 0).into_owned();
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
    /// How the solution moves per pixel of image shift of each part's outline, along x and y.
    parts_moved: Vec<Vector6<f64>>,
}

fn normal_equations(found: &[(Vec<Edge>, usize)], kernel: f64, spread: f64) -> Normal {
    let mut h = Matrix6::zeros();
    let mut g = Vector6::zeros();
    let mut meat = Matrix6::zeros();
    let mut alignment = Vec::new();
    let mut parts_moved = Vec::new();
    for (edges, _) in found {
        // An edge's error is shared along its stretch of contour: the cells weigh, not the
        // edges. The parts' outlines share theirs (kinematic error, CAD): the meat sums them.
        let mut cells = std::collections::BTreeSet::new();
        let mut parts: std::collections::BTreeMap<u32, Vector6<f64>> = Default::default();
        let mut part_shift: std::collections::BTreeMap<u32, [Vector6<f64>; 2]> = Default::default();
        for e in edges {
            cells.insert(e.cell);
        }
        let share = edges.len() as f64 / cells.len().max(1) as f64;
        let scale = 1.0 / (spread * spread * share);
        let mut shift = [Vector6::zeros(), Vector6::zeros()];
        for e in edges {
            let j = jacobian(e);
            let w = 1.0 / (1.0 + (e.r / kernel).powi(2)) * scale;
            h += j * j.transpose() * w;
            g -= j * (w * e.r);
            *parts.entry(e.part).or_default() += j * (w * e.r);
            // An image shifted by one pixel along x (y) moves this edge's residual by n.x (n.y).
            shift[0] -= j * (w * e.n.x);
            shift[1] -= j * (w * e.n.y);
            let ps = part_shift.entry(e.part).or_default();
            ps[0] -= j * (w * e.n.x);
            ps[1] -= j * (w * e.n.y);
        }
        parts_moved.extend(part_shift.into_values().flatten());
        for s in parts.values() {
            meat += s * s.transpose();
        }
        alignment.extend(shift);
    }
    Normal {
        h,
        g,
        meat,
        alignment,
        parts_moved,
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
fn edges(p: &Prepared<'_>, camera_from_model: &Isometry3<f64>, kernel: f64) -> (Vec<Edge>, usize) {
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
            let Some(r) = find_edge(p, (u, v), n, z0, search, kernel) else {
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
                part: render.object[v * w + u],
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
    kernel: f64,
) -> Option<Option<f64>> {
    let (w, h) = (p.intr.width as i64, p.intr.height as i64);
    let pixel = |s: f64| (at.0 as f64 + s * n.x, at.1 as f64 + s * n.y);
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
    let background =
        (search - 2..=search).all(|s| scan_depth(s).is_none_or(|d| d > z0 + BACKGROUND_GAP_M));
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
    // Stereo depth spills past the arm's edge onto the background (its matching window), never
    // short of it by more than a pixel or two: the edge is inside where the depth ends. Of the
    // colour steps there (local maxima), the strongest near the predicted outline.
    let hi = (edge + DEPTH_EDGE_PX).min(search - 1);
    let mut best: Option<(i64, f64)> = None;
    let mut best_score = 0.0;
    let steps: Vec<Option<f64>> = (-search..=search).map(step).collect();
    let g_at = |s: i64| steps.get((s + search) as usize).copied().flatten();
    for s in (-search + 1)..=hi {
        let Some(g) = g_at(s) else { continue };
        let peak = g >= g_at(s - 1).unwrap_or(0.0) && g >= g_at(s + 1).unwrap_or(0.0);
        if !peak || g < MIN_CONTRAST {
            continue;
        }
        let score = g / (1.0 + (s as f64 / kernel.max(2.0)).powi(2));
        if score > best_score {
            best_score = score;
            best = Some((s, g));
        }
    }
    let Some((s, g)) = best else {
        return Some(None);
    };
    // A tenth of a pixel from the parabola through the step and its neighbours.
    let (gm, gp) = (g_at(s - 1).unwrap_or(g), g_at(s + 1).unwrap_or(g));
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

/// The surface the robot base stands on, as the scan sees it: a plane fitted (robustly) to the
/// scan points around the base, near its foot, at `camera_from_model`. Its normal (camera
/// frame, towards the robot) with its 1σ, radians; `None` where too little of it is in view.
pub(crate) fn support_plane(
    cloud: &PointCloud,
    posed: &PosedModel,
    camera_from_model: &Isometry3<f64>,
) -> Option<(Vector3<f64>, f64)> {
    // The base's footprint: its widest point near the foot.
    let foot = posed
        .parts
        .iter()
        .filter(|p| p.chain_depth == 0)
        .flat_map(|p| p.mesh.vertices.iter().map(|v| p.model_from_link * v))
        .filter(|v| v.z < FOOT_HEIGHT_M)
        .map(|v| v.coords.xy().norm())
        .fold(0.0, f64::max);
    let (r_min, r_max) = (
        foot + SUPPORT_MARGIN_M,
        foot + SUPPORT_MARGIN_M + SUPPORT_WIDTH_M,
    );
    let model_from_camera = camera_from_model.inverse();
    let pts: Vec<Vector3<f64>> = cloud
        .points
        .iter()
        .step_by(2)
        .filter(|p| p.z.is_finite())
        .map(|p| Vector3::new(f64::from(p.x), f64::from(p.y), f64::from(p.z)))
        .filter(|p| {
            let q = model_from_camera * Point3::from(*p);
            let r = q.coords.xy().norm();
            q.z.abs() < SUPPORT_BAND_M && (r_min..r_max).contains(&r)
        })
        .collect();
    if pts.len() < MIN_SUPPORT_POINTS {
        return None;
    }
    // Start from the model's own z axis through the base; reweight by distance (Cauchy).
    let mut n = camera_from_model.rotation * Vector3::z();
    let mut c = camera_from_model.translation.vector;
    let mut spread = SUPPORT_KERNEL_M;
    let mut extent = 0.0;
    for _ in 0..6 {
        let w: Vec<f64> = pts
            .iter()
            .map(|p| 1.0 / (1.0 + ((p - c).dot(&n) / SUPPORT_KERNEL_M).powi(2)))
            .collect();
        let ws: f64 = w.iter().sum();
        let mean = pts
            .iter()
            .zip(&w)
            .map(|(p, w)| p * *w)
            .sum::<Vector3<f64>>()
            / ws;
        let cov = pts
            .iter()
            .zip(&w)
            .map(|(p, w)| (p - mean) * (p - mean).transpose() * *w)
            .sum::<nalgebra::Matrix3<f64>>()
            / ws;
        let eig = cov.symmetric_eigen();
        let k = eig.eigenvalues.imin();
        let mut normal = eig.eigenvectors.column(k).into_owned();
        if normal.dot(&n) < 0.0 {
            normal = -normal;
        }
        n = normal;
        c = mean;
        spread = eig.eigenvalues[k].max(0.0).sqrt();
        let mut others: Vec<f64> = (0..3)
            .filter(|&j| j != k)
            .map(|j| eig.eigenvalues[j])
            .collect();
        others.sort_by(f64::total_cmp);
        extent = others[0].max(0.0).sqrt();
    }
    if extent < MIN_SUPPORT_EXTENT_M {
        return None;
    }
    // The normal's statistical σ over independent patches, and the flatness of a table and
    // the base's seat on it.
    let patches = (pts.len() as f64 / SUPPORT_POINTS_PER_PATCH).max(1.0);
    let sigma = (spread / (extent * patches.sqrt())).hypot(SUPPORT_FLATNESS_RAD);
    Some((n, sigma))
}

/// The base's foot: its vertices this close to the model's z = 0, metres.
const FOOT_HEIGHT_M: f64 = 0.03;
/// Scan points this far beyond the foot (clear of the base and its cable), metres…
const SUPPORT_MARGIN_M: f64 = 0.03;
/// …out to this much farther, metres.
const SUPPORT_WIDTH_M: f64 = 0.30;
/// …and within this of the model's z = 0 (a mounting plate under the base), metres.
const SUPPORT_BAND_M: f64 = 0.04;
/// Cauchy kernel of the plane fit, metres.
const SUPPORT_KERNEL_M: f64 = 0.004;
/// Fewest scan points for a plane.
const MIN_SUPPORT_POINTS: usize = 400;
/// Smallest in-plane spread (1σ of the points across their narrower direction), metres.
const MIN_SUPPORT_EXTENT_M: f64 = 0.04;
/// Scan points taken as one independent patch of the plane's error.
const SUPPORT_POINTS_PER_PATCH: f64 = 200.0;
/// 1σ of the angle between the base's axis and the surface around it: a table's flatness and
/// the base's seat on it, radians.
const SUPPORT_FLATNESS_RAD: f64 = 0.005;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::testutil::toy_robot;

    /// A camera 1.3 m from the toy arm, 0.35 m above its floor, looking at it from the side
    /// (OpenCV axes): `camera_from_model`.
    fn side_camera() -> Isometry3<f64> {
        let eye = Vector3::new(1.3, 0.1, 0.35);
        let z = (Vector3::new(0.0, 0.0, 0.3) - eye).normalize();
        let x = Vector3::new(0.0, 0.0, -1.0).cross(&z).normalize();
        let y = z.cross(&x);
        let rotation =
            nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_columns(&[x, y, z]));
        Isometry3::from_parts(
            Translation3::from(eye),
            UnitQuaternion::from_rotation_matrix(&rotation),
        )
        .inverse()
    }

    /// The toy arm on a 1.2 m floor seen by `camera_from_model` with `intr`: the exact scan
    /// (NaN where nothing is hit) and an image of it (arm white, floor grey, nothing dark).
    fn scan_and_image(
        posed: &PosedModel,
        camera_from_model: &Isometry3<f64>,
        intr: &Intrinsics,
    ) -> (PointCloud, ColorImage) {
        let mut meshes: Vec<TriMesh> = posed.parts.iter().map(PosedPart::mesh_in_model).collect();
        let floor = 0.6;
        meshes.push(TriMesh {
            vertices: [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
                .iter()
                .map(|(x, y)| Point3::new(x * floor, y * floor, 0.0))
                .collect(),
            triangles: vec![[0, 1, 2], [0, 2, 3]],
        });
        let floor_id = (meshes.len() - 1) as u32;
        let render = raycast(&SceneMesh::indexed(&meshes), camera_from_model, intr);
        let (w, h) = (render.width, render.height);
        let mut points = Vec::with_capacity(w * h);
        let mut rgb = Vec::with_capacity(w * h);
        for v in 0..h {
            for u in 0..w {
                let p = render.point(intr, u, v);
                points.push(p.map_or(Point3::new(f32::NAN, f32::NAN, f32::NAN), |p| p.cast()));
                rgb.push(match render.object[v * w + u] {
                    DepthImage::NO_HIT => [20, 20, 20],
                    o if o == floor_id => [90, 90, 90],
                    _ => [220, 220, 220],
                });
            }
        }
        let cloud = PointCloud {
            width: w as u32,
            height: h as u32,
            points,
            intensity: None,
            confidence: None,
        };
        (
            cloud,
            ColorImage {
                width: w,
                height: h,
                rgb,
            },
        )
    }

    /// Issue 45: a depth fit 8 mm and 0.4° off in the image plane, with a σ that allows it,
    /// is brought onto the arm by its outline in the image; the surface the base stands on is
    /// found with the base's axis as its normal.
    #[test]
    fn issue_45_the_outline_brings_a_depth_fit_onto_the_arm() {
        let posed = toy_robot(&[0.3, -0.8, 0.6]);
        let truth = side_camera();
        let intr = Intrinsics::realsense_d435_1280x720().scaled(0.5);
        let (cloud, image) = scan_and_image(&posed, &truth, &intr);
        let (normal, sigma) = support_plane(&cloud, &posed, &truth).expect("the floor");
        let axis = truth.rotation * Vector3::z();
        assert!(normal.angle(&axis) < 1e-4, "{normal} vs {axis}");
        assert!(sigma < 0.01, "{sigma}");
        let off = Isometry3::new(
            Vector3::new(0.008, -0.004, 0.0),
            Vector3::new(0.0, 0.0, 0.4f64.to_radians()),
        ) * truth;
        let mut depth_covariance = Matrix6::zeros();
        for k in 0..3 {
            depth_covariance[(k, k)] = 0.01f64.powi(2);
            depth_covariance[(k + 3, k + 3)] = 0.5f64.to_radians().powi(2);
        }
        let view = OutlineView {
            cloud: &cloud,
            image: &image,
            posed: &posed,
            depth_pose: off,
            depth_covariance,
            camera_error: Matrix6x4::zeros(),
        };
        let fit = fit_outline(&[view], &off).expect("fitted");
        // Where each puts the robot base, in the image plane (camera x, y) and along the line
        // of sight; and the turn about the line of sight.
        let base = |a: &Isometry3<f64>| (a.translation.vector - truth.translation.vector) * 1e3;
        let roll = |a: &Isometry3<f64>| {
            (a.rotation * truth.rotation.inverse())
                .scaled_axis()
                .z
                .to_degrees()
        };
        let (before, after) = (base(&off), base(&fit.camera_from_model));
        assert!(before.xy().norm() > 7.0, "{before}");
        assert!(after.xy().norm() < 1.5, "in the image plane: {after} mm");
        // The outline barely sees the range; the depth fit holds it, to the outline's
        // sub-pixel bias (a few millimetres at 1.3 m and half the resolution).
        assert!(after.z.abs() < 6.0, "along the line of sight: {after} mm");
        assert!(
            roll(&fit.camera_from_model).abs() < 0.1,
            "{}°",
            roll(&fit.camera_from_model)
        );
        assert!(fit.support > 0.9, "{}", fit.support);
        assert!(fit.spread_px < 0.5, "{}", fit.spread_px);
        // The σ at the base is the parts' outlines' (1.5 px each, half resolution), below the
        // depth fit's 17 mm.
        let sigma = fit
            .uncertainty
            .workspace
            .expect("at the base")
            .translation_mm;
        assert!(sigma < 10.0, "{:?}", fit.uncertainty);
    }
}
