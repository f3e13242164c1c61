//! Hand-eye solve: closes the kinematic chain for every registered frame and fuses frames and
//! views robustly.
//!
//! - Eye-in-hand: `flange_from_camera = model_from_flange⁻¹ · camera_from_model⁻¹` per frame
//!   (`model_from_flange` as the controller reports it at capture, converted to the model frame
//!   by the caller).
//! - Eye-to-hand: `model_from_camera = camera_from_model⁻¹` per frame.
//!
//! Fusion is two-level: the frames of one view (captured without moving), then the views.
//! Each level starts from the medoid, drops members farther than the outlier thresholds (or,
//! for a noisy camera, than [`OUTLIER_SIGMAS`] of their own σ) and
//! averages the rest (chordal L2 mean on SO(3), arithmetic mean of translations), three rounds.
//! Positions are compared where the result is used: eye-in-hand at the camera origin (the
//! camera is near the flange), eye-to-hand at the robot base (the camera is 1–2 m away, where
//! a turn of 0.02° moves its origin by 0.7 mm and the points it sees by far less), see
//! [`HandEyeSolution::workspace_point`].

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::Serialize;

use super::{CalibError, Uncertainty};

/// Where the camera is mounted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Mount {
    /// On the flange; the unknown is `flange_from_camera`.
    EyeInHand,
    /// Fixed in the cell; the unknown is `model_from_camera`.
    EyeToHand,
}

impl Mount {
    /// The unknown a run of this mount solves for: `flange_from_camera` (eye-in-hand) or
    /// `base_from_camera` (eye-to-hand).
    pub fn unknown_name(self) -> &'static str {
        match self {
            Mount::EyeInHand => "flange_from_camera",
            Mount::EyeToHand => "base_from_camera",
        }
    }

    /// The frame the unknown is expressed in, as the exports name it: `tool0` (the flange,
    /// eye-in-hand) or `base` (the controller's base, eye-to-hand).
    pub fn parent_frame(self) -> &'static str {
        match self {
            Mount::EyeInHand => "tool0",
            Mount::EyeToHand => "base",
        }
    }
}

/// One registered frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameInput {
    /// Frames with the same `view` were captured without moving the robot.
    pub view: usize,
    /// Registration result: pose of the model (URDF root) in the camera frame, metres.
    pub camera_from_model: Isometry3<f64>,
    /// Flange pose in the model frame at capture (eye-in-hand: required; eye-to-hand: ignored).
    pub model_from_flange: Option<Isometry3<f64>>,
    /// The registration's 1σ where frames are compared (position mm: eye-to-hand at the robot
    /// base, eye-in-hand at the camera origin; rotation degrees): a frame within
    /// [`OUTLIER_SIGMAS`] of it from the others is not dropped, however noisy the camera.
    /// `None`: the fixed thresholds of [`SolveOptions`] alone.
    pub sigma: Option<(f64, f64)>,
}

/// A frame or view farther from the robust mean than this many of its own σ (and farther than
/// the fixed thresholds) disagrees with the others.
pub const OUTLIER_SIGMAS: f64 = 3.0;

/// Outlier thresholds of the fusion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolveOptions {
    /// A frame/view farther than this from the robust mean is dropped, mm (eye-to-hand: at
    /// the robot base, [`HandEyeSolution::workspace_point`]).
    pub outlier_translation_mm: f64,
    /// A frame/view rotated more than this from the robust mean is dropped, degrees.
    pub outlier_rotation_deg: f64,
}

impl Default for SolveOptions {
    fn default() -> Self {
        SolveOptions {
            outlier_translation_mm: 2.0,
            outlier_rotation_deg: 0.3,
        }
    }
}

/// Difference of one frame's or view's estimate from the fused result.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, serde::Deserialize)]
pub struct Residual {
    /// Frame index (input order) or view id.
    pub index: usize,
    /// View id.
    pub view: usize,
    /// Distance of the camera origins, mm.
    pub translation_mm: f64,
    /// Eye-to-hand: distance at the robot base ([`HandEyeSolution::workspace_point`]), mm:
    /// how far apart the two estimates put the points the fixed camera sees. `None`
    /// eye-in-hand.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub workspace_mm: Option<f64>,
    /// Rotation angle between the estimates, degrees.
    pub rotation_deg: f64,
    /// Whether it contributed to the fused result.
    pub used: bool,
}

impl Residual {
    /// Estimate `x`'s disagreement with `estimate`: at the camera origin, and eye-to-hand at
    /// `workspace_point` too ([`HandEyeSolution::workspace_point`]).
    fn of(
        x: &Isometry3<f64>,
        estimate: &Isometry3<f64>,
        workspace_point: Option<Point3<f64>>,
        index: usize,
        view: usize,
        used: bool,
    ) -> Self {
        let (translation_mm, rotation_deg) = distance(x, estimate);
        Residual {
            index,
            view,
            translation_mm,
            workspace_mm: workspace_point.map(|p| distance_at(x, estimate, &p).0),
            rotation_deg,
            used,
        }
    }

    /// The position disagreement the fusion drops by and the gate judges, mm: at the robot
    /// base (eye-to-hand), else at the camera origin.
    pub fn position_mm(&self) -> f64 {
        self.workspace_mm.unwrap_or(self.translation_mm)
    }
}

/// The fused hand-eye result.
#[derive(Debug, Clone, PartialEq)]
pub struct HandEyeSolution {
    /// Configuration solved for.
    pub mount: Mount,
    /// Eye-in-hand: `flange_from_camera`; eye-to-hand: `model_from_camera` (metres).
    pub estimate: Isometry3<f64>,
    /// Eye-to-hand: the robot base (the model root's origin) in the camera frame, metres (the
    /// median over the frames of where each puts it): the point where frames and views are
    /// compared with each other and with the result. `None` eye-in-hand (compared at the
    /// camera origin).
    pub workspace_point: Option<Point3<f64>>,
    /// Per-frame residuals against `estimate` (input order).
    pub frames: Vec<Residual>,
    /// Per-view residuals against `estimate` (ascending view id).
    pub views: Vec<Residual>,
    /// The estimate's 1σ when the views were fitted together (eye-in-hand, two views or more
    /// whose links were fitted; see the pipeline); `None`: the report combines the frames'.
    pub uncertainty: Option<Uncertainty>,
}

impl HandEyeSolution {
    /// Eye-in-hand result, `flange_from_camera`.
    pub fn flange_from_camera(&self) -> Option<Isometry3<f64>> {
        (self.mount == Mount::EyeInHand).then_some(self.estimate)
    }

    /// `model_from_camera`: the eye-to-hand result, or for eye-in-hand the camera pose at
    /// `model_from_flange` (e.g. at the first frame).
    pub fn model_from_camera(
        &self,
        model_from_flange: Option<&Isometry3<f64>>,
    ) -> Option<Isometry3<f64>> {
        match self.mount {
            Mount::EyeToHand => Some(self.estimate),
            Mount::EyeInHand => model_from_flange.map(|f| f * self.estimate),
        }
    }
}

/// Closes the chain for every frame and fuses them; see the module docs.
pub fn solve(
    mount: Mount,
    frames: &[FrameInput],
    opts: &SolveOptions,
) -> Result<HandEyeSolution, CalibError> {
    if frames.is_empty() {
        return Err(CalibError::NoFrames);
    }
    let per_frame = frame_estimates(mount, frames)?;
    let workspace_point = match mount {
        Mount::EyeInHand => None,
        Mount::EyeToHand => Some(median_point(
            frames
                .iter()
                .map(|f| f.camera_from_model.translation.vector),
        )),
    };
    let at = workspace_point.unwrap_or_else(Point3::origin);
    let view_ids = view_ids(frames);
    let mut frame_used = vec![false; frames.len()];
    let mut view_est = Vec::new();
    let mut view_tol = Vec::new();
    let tolerance = |sigma: Option<(f64, f64)>| {
        let (t, r) = sigma.unwrap_or((0.0, 0.0));
        (
            opts.outlier_translation_mm.max(OUTLIER_SIGMAS * t),
            opts.outlier_rotation_deg.max(OUTLIER_SIGMAS * r),
        )
    };
    for &v in &view_ids {
        let members: Vec<usize> = (0..frames.len()).filter(|&i| frames[i].view == v).collect();
        let items: Vec<Isometry3<f64>> = members.iter().map(|&i| per_frame[i]).collect();
        let tol: Vec<(f64, f64)> = members
            .iter()
            .map(|&i| tolerance(frames[i].sigma))
            .collect();
        let (mean, used) = robust_mean(&items, &tol, &at);
        for (k, &i) in members.iter().enumerate() {
            frame_used[i] = used[k];
        }
        view_est.push(mean);
        // The frames of one view share their error: the view is as uncertain as its members.
        let n = tol.len().max(1) as f64;
        let rms =
            |f: fn(&(f64, f64)) -> f64| (tol.iter().map(|x| f(x).powi(2)).sum::<f64>() / n).sqrt();
        view_tol.push((rms(|x| x.0), rms(|x| x.1)));
    }
    let (estimate, view_used) = robust_mean(&view_est, &view_tol, &at);
    let residual = |x: &Isometry3<f64>, index: usize, view: usize, used: bool| {
        Residual::of(x, &estimate, workspace_point, index, view, used)
    };
    let views = view_ids
        .iter()
        .enumerate()
        .map(|(k, &v)| residual(&view_est[k], v, v, view_used[k]))
        .collect::<Vec<_>>();
    let frames_out = frames
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let vk = view_ids.iter().position(|&v| v == f.view).unwrap_or(0);
            residual(&per_frame[i], i, f.view, frame_used[i] && view_used[vk])
        })
        .collect();
    Ok(HandEyeSolution {
        mount,
        estimate,
        workspace_point,
        frames: frames_out,
        views,
        uncertainty: None,
    })
}

/// [`solve`] without the frames `set_aside` marks (the views fitted together set aside a
/// frame whose quality the gate refuses): they, and views left without frames, are reported
/// unused, with their disagreement measured against the result.
pub(crate) fn solve_setting_aside(
    mount: Mount,
    frames: &[FrameInput],
    opts: &SolveOptions,
    set_aside: &[bool],
) -> Result<HandEyeSolution, CalibError> {
    let kept: Vec<usize> = (0..frames.len())
        .filter(|&i| !set_aside.get(i).copied().unwrap_or(false))
        .collect();
    if kept.len() == frames.len() {
        return solve(mount, frames, opts);
    }
    let subset: Vec<FrameInput> = kept.iter().map(|&i| frames[i].clone()).collect();
    let mut solution = solve(mount, &subset, opts)?;
    let unused = |index: usize, view: usize| Residual {
        index,
        view,
        translation_mm: 0.0,
        workspace_mm: None,
        rotation_deg: 0.0,
        used: false,
    };
    let mut by_frame: Vec<Residual> = frames
        .iter()
        .enumerate()
        .map(|(i, f)| unused(i, f.view))
        .collect();
    for (k, &i) in kept.iter().enumerate() {
        by_frame[i] = Residual {
            index: i,
            ..solution.frames[k]
        };
    }
    solution.views = view_ids(frames)
        .iter()
        .map(|&v| {
            solution
                .views
                .iter()
                .find(|r| r.view == v)
                .copied()
                .unwrap_or_else(|| unused(v, v))
        })
        .collect();
    solution.frames = by_frame;
    let estimate = solution.estimate;
    solution.re_estimate(estimate, frames)?;
    Ok(solution)
}

/// The frames' view ids, ascending, each once.
fn view_ids(frames: &[FrameInput]) -> Vec<usize> {
    let mut ids: Vec<usize> = frames.iter().map(|f| f.view).collect();
    ids.sort_unstable();
    ids.dedup();
    ids
}

/// Each frame's estimate of the unknown.
fn frame_estimates(mount: Mount, frames: &[FrameInput]) -> Result<Vec<Isometry3<f64>>, CalibError> {
    frames
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let model_from_camera = f.camera_from_model.inverse();
            match mount {
                Mount::EyeToHand => Ok(model_from_camera),
                Mount::EyeInHand => f
                    .model_from_flange
                    .map(|m| m.inverse() * model_from_camera)
                    .ok_or(CalibError::BadFrame {
                        frame: i,
                        detail: "eye-in-hand needs the flange pose".into(),
                    }),
            }
        })
        .collect()
}

impl HandEyeSolution {
    /// Replaces the estimate (by the views fitted together, [`super::fuse`]) and measures each
    /// frame's and view's disagreement with it (a view's estimate: the mean of its used
    /// frames); which frames and views were used stays.
    pub(crate) fn re_estimate(
        &mut self,
        estimate: Isometry3<f64>,
        frames: &[FrameInput],
    ) -> Result<(), CalibError> {
        let per_frame = frame_estimates(self.mount, frames)?;
        let at = self.workspace_point;
        let measure = |x: &Isometry3<f64>, r: &mut Residual| {
            *r = Residual::of(x, &estimate, at, r.index, r.view, r.used);
        };
        for (r, x) in self.frames.iter_mut().zip(&per_frame) {
            measure(x, r);
        }
        for view in &mut self.views {
            let members: Vec<usize> = (0..frames.len())
                .filter(|&i| frames[i].view == view.view)
                .collect();
            let used: Vec<&Isometry3<f64>> = members
                .iter()
                .filter(|&&i| self.frames.get(i).is_some_and(|r| r.used))
                .map(|&i| &per_frame[i])
                .collect();
            let mean_of = if used.is_empty() {
                mean(members.iter().map(|&i| &per_frame[i]))
            } else {
                mean(used.into_iter())
            };
            measure(&mean_of, view);
        }
        self.estimate = estimate;
        Ok(())
    }
}

/// `(translation mm, rotation deg)` between two poses of the camera (`*_from_camera`), the
/// translation that of the camera origins.
pub(crate) fn distance(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    distance_at(a, b, &Point3::origin())
}

/// `(translation mm, rotation deg)` between two poses of the camera (`*_from_camera`), the
/// translation measured at `camera_point` (camera frame, metres): how far apart the two poses
/// put that point.
pub(crate) fn distance_at(
    a: &Isometry3<f64>,
    b: &Isometry3<f64>,
    camera_point: &Point3<f64>,
) -> (f64, f64) {
    let t = (a * camera_point - b * camera_point).norm() * 1000.0;
    let r = a.rotation.angle_to(&b.rotation).to_degrees();
    (t, r)
}

/// Component-wise median of `points` (the origin when there are none).
fn median_point(points: impl Iterator<Item = Vector3<f64>>) -> Point3<f64> {
    let points: Vec<Vector3<f64>> = points.collect();
    Point3::from(Vector3::from_fn(|k, _| {
        let mut v: Vec<f64> = points.iter().map(|p| p[k]).collect();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(0.0)
    }))
}

/// Medoid start, outlier rejection, mean of the rest, positions compared at `at` (camera
/// frame, metres); `tol[k]` is how far item `k` may be from the mean (mm, degrees). Returns
/// the mean and the inlier mask.
fn robust_mean(
    items: &[Isometry3<f64>],
    tol: &[(f64, f64)],
    at: &Point3<f64>,
) -> (Isometry3<f64>, Vec<bool>) {
    let within = |k: usize, est: &Isometry3<f64>| {
        let (t, r) = distance_at(&items[k], est, at);
        t <= tol[k].0 && r <= tol[k].1
    };
    let norm = |k: usize, b: &Isometry3<f64>| {
        let (t, r) = distance_at(&items[k], b, at);
        t / tol[k].0 + r / tol[k].1
    };
    let medoid = (0..items.len())
        .min_by(|&i, &j| {
            let si: f64 = (0..items.len()).map(|k| norm(k, &items[i])).sum();
            let sj: f64 = (0..items.len()).map(|k| norm(k, &items[j])).sum();
            si.total_cmp(&sj)
        })
        .unwrap_or(0);
    let mut est = items[medoid];
    let mut used = vec![true; items.len()];
    for _ in 0..3 {
        for (k, u) in used.iter_mut().enumerate() {
            *u = within(k, &est);
        }
        if !used.iter().any(|&u| u) {
            used[medoid] = true;
        }
        est = mean(items.iter().zip(&used).filter(|(_, &u)| u).map(|(x, _)| x));
    }
    for (k, u) in used.iter_mut().enumerate() {
        *u = *u && within(k, &est);
    }
    (est, used)
}

/// Chordal L2 mean of the rotations (projection of the summed matrices onto SO(3)) and the
/// arithmetic mean of the translations.
fn mean<'a>(items: impl Iterator<Item = &'a Isometry3<f64>>) -> Isometry3<f64> {
    let mut m = Matrix3::zeros();
    let mut t = Vector3::zeros();
    let mut n = 0.0f64;
    for x in items {
        m += x.rotation.to_rotation_matrix().into_inner();
        t += x.translation.vector;
        n += 1.0;
    }
    let svd = m.svd(true, true);
    let rot = match (svd.u, svd.v_t) {
        (Some(u), Some(v_t)) => {
            let mut d = Matrix3::identity();
            if (u * v_t).determinant() < 0.0 {
                d[(2, 2)] = -1.0;
            }
            Rotation3::from_matrix_unchecked(u * d * v_t)
        }
        _ => Rotation3::identity(),
    };
    Isometry3::from_parts(
        Translation3::from(t / n.max(1.0)),
        UnitQuaternion::from_rotation_matrix(&rot),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(t: [f64; 3], r: [f64; 3]) -> Isometry3<f64> {
        Isometry3::new(Vector3::from(t), Vector3::from(r))
    }

    #[test]
    fn eye_in_hand_closure_is_exact() {
        let flange_from_camera = pose([0.03, -0.08, 0.05], [0.1, -0.2, 1.4]);
        let frames: Vec<FrameInput> = (0..4)
            .map(|k| {
                let model_from_flange = pose(
                    [0.3 + 0.05 * k as f64, -0.2, 0.5],
                    [2.5, 0.3 * k as f64, 0.2],
                );
                let camera_from_model = (model_from_flange * flange_from_camera).inverse();
                FrameInput {
                    sigma: None,
                    view: k,
                    camera_from_model,
                    model_from_flange: Some(model_from_flange),
                }
            })
            .collect();
        let s = solve(Mount::EyeInHand, &frames, &SolveOptions::default()).expect("solved");
        let (t, r) = distance(&s.estimate, &flange_from_camera);
        assert!(t < 1e-9 && r < 1e-9, "{t} {r}");
        assert!(s.frames.iter().all(|f| f.used && f.translation_mm < 1e-9));
        assert_eq!(s.flange_from_camera(), Some(s.estimate));
        // Missing flange pose is an input error.
        let mut bad = frames.clone();
        bad[1].model_from_flange = None;
        assert!(matches!(
            solve(Mount::EyeInHand, &bad, &SolveOptions::default()),
            Err(CalibError::BadFrame { frame: 1, .. })
        ));
        assert!(matches!(
            solve(Mount::EyeInHand, &[], &SolveOptions::default()),
            Err(CalibError::NoFrames)
        ));
    }

    #[test]
    fn eye_to_hand_closure_is_exact() {
        let model_from_camera = pose([1.2, 0.4, 0.9], [0.5, 2.0, -0.3]);
        let frames = vec![
            FrameInput {
                sigma: None,
                view: 0,
                camera_from_model: model_from_camera.inverse(),
                model_from_flange: None
            };
            3
        ];
        let s = solve(Mount::EyeToHand, &frames, &SolveOptions::default()).expect("solved");
        let (t, r) = distance(&s.estimate, &model_from_camera);
        assert!(t < 1e-9 && r < 1e-9);
        let (t, r) = distance(
            &s.model_from_camera(None).expect("eye-to-hand"),
            &model_from_camera,
        );
        assert!(t < 1e-9 && r < 1e-9);
        assert_eq!(s.flange_from_camera(), None);
    }

    #[test]
    fn outlier_view_is_rejected() {
        let truth = pose([0.03, -0.08, 0.05], [0.1, -0.2, 1.4]);
        let mut frames = Vec::new();
        for v in 0..5 {
            for f in 0..2 {
                // Small noise per frame; view 3 is off by 1.5° (a wrong registration).
                let noise = pose(
                    [1e-4 * (v as f64 - 2.0), 5e-5 * f as f64, 0.0],
                    [0.0, 2e-4 * f as f64, 1e-4 * v as f64],
                );
                let bad = if v == 3 {
                    pose([0.004, 0.0, 0.0], [0.026, 0.0, 0.0])
                } else {
                    Isometry3::identity()
                };
                let model_from_flange =
                    pose([0.4, 0.1 * v as f64, 0.5], [2.8, 0.2, 0.1 * v as f64]);
                let x = truth * noise * bad;
                let camera_from_model = (model_from_flange * x).inverse();
                frames.push(FrameInput {
                    sigma: None,
                    view: v,
                    camera_from_model,
                    model_from_flange: Some(model_from_flange),
                });
            }
        }
        let s = solve(Mount::EyeInHand, &frames, &SolveOptions::default()).expect("solved");
        let (t, r) = distance(&s.estimate, &truth);
        assert!(t < 0.3 && r < 0.03, "{t} mm {r} deg");
        assert!(!s.views[3].used);
        assert!(s.views.iter().filter(|v| v.used).count() == 4);
        assert!(s.views[3].rotation_deg > 1.0);
        assert!(s.frames.iter().filter(|f| f.view == 3).all(|f| !f.used));
    }

    /// A fixed camera whose every frame is uncertain by 10 mm / 1° (a consumer stereo camera
    /// 1.3 m away): frames that scatter within that are all fused, not dropped for missing the
    /// fixed 2 mm / 0.3°; one 6σ off is still dropped and named.
    #[test]
    fn a_noisy_cameras_frames_are_judged_by_their_own_sigma() {
        let truth = pose([1.2, 0.4, 0.9], [0.5, 2.0, -0.3]);
        let base = Point3::from(truth.inverse().translation.vector);
        let mut frames: Vec<FrameInput> = (0..5)
            .map(|v| {
                let s = v as f64 - 2.0;
                // Off by up to 8 mm at the robot base and 1.2°: within 3σ.
                let off = pose([0.004 * s, -0.002 * s, 0.0], [0.01 * s, 0.0, 0.0]);
                FrameInput {
                    sigma: Some((10.0, 1.0)),
                    view: v,
                    camera_from_model: (truth * off).inverse(),
                    model_from_flange: None,
                }
            })
            .collect();
        let s = solve(Mount::EyeToHand, &frames, &SolveOptions::default()).expect("solved");
        assert!(s.frames.iter().all(|f| f.used), "{:?}", s.frames);
        let (t, r) = distance_at(&s.estimate, &truth, &base);
        assert!(t < 1.0 && r < 0.1, "{t} mm {r}°");
        // Without their σ only the fixed thresholds count: most are dropped.
        let blind: Vec<FrameInput> = frames
            .iter()
            .map(|f| FrameInput {
                sigma: None,
                ..f.clone()
            })
            .collect();
        let s = solve(Mount::EyeToHand, &blind, &SolveOptions::default()).expect("solved");
        assert!(s.frames.iter().filter(|f| !f.used).count() >= 2);
        // A frame 6σ off is dropped.
        frames[4].camera_from_model = (truth * pose([0.0, 0.0, 0.0], [0.1, 0.0, 0.0])).inverse();
        let s = solve(Mount::EyeToHand, &frames, &SolveOptions::default()).expect("solved");
        assert!(!s.frames[4].used && s.frames[..4].iter().all(|f| f.used));
    }
}
