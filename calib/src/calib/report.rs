//! The report of one calibration: what `handeye solve --json` prints and what the daemon
//! stores. Poses are 4×4 row-major arrays in metres; angles in degrees only where the field
//! name says so.

use nalgebra::Isometry3;
use serde::Serialize;

use super::gate::{GateThresholds, Verdict};
use super::register::{Quality, Registration, StageTimings, Uncertainty, WorkspaceSigma};
use super::solve::{HandEyeSolution, Mount, Residual};
use super::Outcome;
use crate::frames::to_row_major;

/// Quality summed up over all frames (worst case of each figure).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, serde::Deserialize)]
pub struct QualitySummary {
    /// Lowest coverage of any frame, 0–1.
    pub coverage: f64,
    /// Lowest support of each fitted link (base, shoulder, upper arm) of any frame that judged
    /// it (see
    /// [`super::Quality::link_support`]).
    pub link_support: [Option<f64>; super::register::MAX_REPORTED_LINKS],
    /// Highest free-space violation fraction of any frame, 0–1.
    pub free_space_violations: f64,
    /// Highest residual RMS of any frame, mm.
    pub rmse_mm: f64,
    /// Lowest inlier fraction of any frame, 0–1.
    pub inlier_fraction: f64,
    /// Mean estimated depth scale (measured / true), when estimated.
    pub depth_scale: Option<f64>,
    /// Mean estimated range offset (measured − true distance), mm, when estimated.
    #[serde(default)]
    pub depth_offset_mm: Option<f64>,
    /// Frames used / given.
    pub frames_used: usize,
    /// Frames given.
    pub frames: usize,
    /// Views used.
    pub views_used: usize,
    /// Views given.
    pub views: usize,
}

/// One frame in the report.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct FrameReport {
    /// Where the scan came from (file name).
    pub source: String,
    /// View id (frames of one view were captured without moving).
    pub view: usize,
    /// Difference from the fused result and whether the frame was used.
    pub residual: Residual,
    /// Registration quality.
    pub quality: Quality,
    /// Registration uncertainty (1 σ).
    pub uncertainty: Uncertainty,
    /// Estimated depth scale (measured / true).
    pub depth_scale: Option<f64>,
    /// Estimated range offset (measured − true distance along each pixel's ray), mm.
    #[serde(default)]
    pub depth_offset_mm: Option<f64>,
    /// Number of degenerate directions of the registration.
    pub degenerate_directions: usize,
    /// `camera_from_model` of this frame, 4×4 row-major, metres.
    pub camera_from_model: [[f64; 4]; 4],
    /// Registration time per stage, ms.
    pub timings_ms: StageTimings,
}

/// Time per stage summed over frames, plus the solve, ms.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct ReportTimings {
    /// Sum over frames of [`StageTimings::preprocess`].
    pub preprocess: f64,
    /// Sum over frames of [`StageTimings::coarse`].
    pub coarse: f64,
    /// Sum over frames of [`StageTimings::fine`].
    pub fine: f64,
    /// Sum over frames of [`StageTimings::verify`].
    pub verify: f64,
    /// Fusion and gate.
    pub solve: f64,
    /// Everything after loading the inputs.
    pub total: f64,
}

/// The calibration report.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct CalibrationReport {
    /// Accepted or rejected by the gate.
    pub outcome: Outcome,
    /// Why it was rejected (empty when ok).
    pub reasons: Vec<String>,
    /// Eye-in-hand or eye-to-hand.
    pub mount: Mount,
    /// The frame `base_from_camera` is expressed in.
    pub base_frame: String,
    /// Camera pose in `base_frame`, 4×4 row-major, metres (eye-in-hand: at the first frame).
    pub base_from_camera: [[f64; 4]; 4],
    /// Eye-in-hand: camera pose on the flange, 4×4 row-major, metres.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub flange_from_camera: Option<[[f64; 4]; 4]>,
    /// 1-σ uncertainty of the fused result.
    pub uncertainty: Uncertainty,
    /// Worst-case quality over the frames.
    pub quality: QualitySummary,
    /// Time per stage.
    pub timings_ms: ReportTimings,
    /// Per frame.
    pub frames: Vec<FrameReport>,
    /// Per view.
    pub views: Vec<Residual>,
    /// Several configurations: how far apart two disjoint halves of them, fitted separately,
    /// put the camera (a measure of agreement that needs no reference). `None` for fewer than
    /// two used frames.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub split_half: Option<SplitHalf>,
    /// The arm's outline in the colour image, when it was fitted beside the depth.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub outline: Option<OutlineReport>,
}

/// How far apart two disjoint halves of the configurations put the camera, each half fitted
/// on its own as the whole was (alternate frames in input order).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, serde::Deserialize)]
pub struct SplitHalf {
    /// Frames in each half.
    pub frames: [usize; 2],
    /// Distance of the two camera origins, mm.
    pub translation_mm: f64,
    /// Eye-to-hand: distance at the robot base, mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub workspace_mm: Option<f64>,
    /// Rotation between the two, degrees.
    pub rotation_deg: f64,
}

impl SplitHalf {
    /// Why this agreement fails `th`'s split-half limit, if it does.
    pub fn reason(&self, th: &GateThresholds) -> Option<String> {
        let (max_mm, max_deg) = th.max_split_half?;
        let position_mm = self.workspace_mm.unwrap_or(self.translation_mm);
        let at = if self.workspace_mm.is_some() {
            " at the robot base"
        } else {
            ""
        };
        (position_mm > max_mm || self.rotation_deg > max_deg).then(|| {
            format!(
                "two halves of the configurations ({} and {} frames), fitted apart, disagree by {position_mm:.1} mm{at} / {:.2}° (max {max_mm:.1} mm / {max_deg:.2}°): the result is not as accurate as its σ says; add configurations that show the arm elsewhere in the image, or raise max_split_half_mm / max_split_half_deg in the cell config's [gate] if that is accurate enough for the cell",
                self.frames[0], self.frames[1], self.rotation_deg
            )
        })
    }
}

/// The outline's part in a result ([`crate::calib::outline`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, serde::Deserialize)]
pub struct OutlineReport {
    /// Image edges fitted.
    pub edges: usize,
    /// Robust spread of their distances from the model's outline, pixels.
    pub spread_px: f64,
    /// Share of the contour points the scan shows as a contour whose image edge lies on the
    /// model's outline.
    pub support: f64,
}

impl CalibrationReport {
    /// Builds the report. `base_from_model` maps the model (URDF root) into `base_frame`;
    /// `base_from_camera` is the camera in that frame (eye-in-hand: at the first frame).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        solution: &HandEyeSolution,
        registrations: &[Registration],
        sources: &[String],
        verdict: &Verdict,
        base_frame: &str,
        base_from_camera: &Isometry3<f64>,
        solve_ms: f64,
        total_ms: f64,
    ) -> Self {
        let frames: Vec<FrameReport> = registrations
            .iter()
            .zip(&solution.frames)
            .enumerate()
            .map(|(i, (r, res))| FrameReport {
                source: sources.get(i).cloned().unwrap_or_default(),
                view: res.view,
                residual: *res,
                quality: r.quality,
                uncertainty: r.uncertainty,
                depth_scale: r.depth_scale,
                depth_offset_mm: r.depth_offset_m.map(|m| m * 1e3),
                degenerate_directions: r.degenerate_directions.len(),
                camera_from_model: to_row_major(&r.camera_from_model),
                timings_ms: r.timings_ms,
            })
            .collect();
        let fold = |f: &dyn Fn(&Registration) -> f64, worst: fn(f64, f64) -> f64, init: f64| {
            registrations.iter().map(f).fold(init, worst)
        };
        let mean = |v: Vec<f64>| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
        let scales: Vec<f64> = registrations.iter().filter_map(|r| r.depth_scale).collect();
        let offsets_mm: Vec<f64> = registrations
            .iter()
            .filter_map(|r| r.depth_offset_m.map(|m| m * 1e3))
            .collect();
        let views_used: Vec<&Residual> = solution.views.iter().filter(|v| v.used).collect();
        let quality = QualitySummary {
            coverage: fold(&|r| r.quality.coverage, f64::min, 1.0),
            link_support: std::array::from_fn(|k| {
                registrations
                    .iter()
                    .filter_map(|r| r.quality.link_support[k])
                    .reduce(f64::min)
            }),
            free_space_violations: fold(&|r| r.quality.free_space_violations, f64::max, 0.0),
            rmse_mm: fold(&|r| r.quality.rmse_mm, f64::max, 0.0),
            inlier_fraction: fold(&|r| r.quality.inlier_fraction, f64::min, 1.0),
            depth_scale: mean(scales),
            depth_offset_mm: mean(offsets_mm),
            frames_used: solution.frames.iter().filter(|f| f.used).count(),
            frames: solution.frames.len(),
            views_used: views_used.len(),
            views: solution.views.len(),
        };
        // Fused uncertainty: the views' joint fit's when they were fitted together; else the
        // mean registration variance over the used views (views are independent, frames of
        // one view are not), plus the spread of the views; the part the camera's own depth
        // errors give (`Registration::camera_error`) is shared by every view and is not
        // divided.
        let n = views_used.len().max(1) as f64;
        let used_regs: Vec<&Registration> = registrations
            .iter()
            .zip(&solution.frames)
            .filter(|(_, f)| f.used)
            .map(|(r, _)| r)
            .collect();
        let m = used_regs.len().max(1) as f64;
        // Mean over the used frames of the squared σ `sigma` picks, total and the camera's.
        let mean_var = |sigma: &dyn Fn(&Uncertainty) -> Option<f64>| {
            let total = used_regs
                .iter()
                .map(|r| sigma(&r.uncertainty).map(|s| s * s))
                .sum::<Option<f64>>()?;
            let camera: f64 = used_regs
                .iter()
                .filter_map(|r| sigma(&r.camera_error).map(|s| s * s))
                .sum();
            Some((total / m, (camera / m).min(total / m)))
        };
        let fused =
            |(var, shared): (f64, f64), spread: f64| (shared + (var - shared + spread) / n).sqrt();
        let spread = |pick: &dyn Fn(&Residual) -> f64| {
            views_used.iter().map(|v| pick(v).powi(2)).sum::<f64>() / n
        };
        // Eye-to-hand, the same at the robot base (where the views are compared): every used
        // frame's σ there, and the views' spread there.
        let workspace = solution.workspace_point.and_then(|p| {
            let var = mean_var(&|u| u.workspace.map(|w| w.translation_mm))?;
            Some(WorkspaceSigma {
                translation_mm: fused(var, spread(&|v| v.position_mm())),
                distance_m: p.coords.norm(),
            })
        });
        let uncertainty = solution.uncertainty.unwrap_or(Uncertainty {
            translation_mm: mean_var(&|u| Some(u.translation_mm))
                .map_or(0.0, |var| fused(var, spread(&|v| v.translation_mm))),
            rotation_deg: mean_var(&|u| Some(u.rotation_deg))
                .map_or(0.0, |var| fused(var, spread(&|v| v.rotation_deg))),
            workspace,
        });
        let mut timings = ReportTimings {
            solve: solve_ms,
            total: total_ms,
            ..Default::default()
        };
        for r in registrations {
            timings.preprocess += r.timings_ms.preprocess;
            timings.coarse += r.timings_ms.coarse;
            timings.fine += r.timings_ms.fine;
            timings.verify += r.timings_ms.verify;
        }
        CalibrationReport {
            outcome: verdict.outcome,
            reasons: verdict.reasons.clone(),
            mount: solution.mount,
            base_frame: base_frame.to_string(),
            base_from_camera: to_row_major(base_from_camera),
            flange_from_camera: solution.flange_from_camera().map(|x| to_row_major(&x)),
            uncertainty,
            quality,
            timings_ms: timings,
            split_half: None,
            outline: None,
            frames,
            views: solution.views.clone(),
        }
    }

    /// A short human-readable summary (several lines).
    pub fn summary(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let _ = writeln!(s, "outcome: {}", self.outcome);
        for r in &self.reasons {
            let _ = writeln!(s, "  reason: {r}");
        }
        let pose = |m: &[[f64; 4]; 4]| {
            crate::frames::from_row_major(m)
                .map(|p| {
                    let [x, y, z, rx, ry, rz] = handeye_hal::UrPose::from(p).values();
                    format!(
                        "xyz [{x:.5}, {y:.5}, {z:.5}] m, rotvec [{rx:.5}, {ry:.5}, {rz:.5}] rad"
                    )
                })
                .unwrap_or_default()
        };
        if let Some(f) = &self.flange_from_camera {
            let _ = writeln!(s, "flange_from_camera: {}", pose(f));
        }
        let _ = writeln!(
            s,
            "{}_from_camera: {}",
            self.base_frame,
            pose(&self.base_from_camera)
        );
        let _ = writeln!(
            s,
            "uncertainty (1σ): {:.3} mm, {:.4}°{}",
            self.uncertainty.translation_mm,
            self.uncertainty.rotation_deg,
            self.uncertainty.workspace_note()
        );
        let q = &self.quality;
        let _ = writeln!(
            s,
            "quality: coverage {:.1}%, free-space violations {:.2}%, rmse {:.3} mm, inliers {:.1}%, frames {}/{}, views {}/{}",
            100.0 * q.coverage,
            100.0 * q.free_space_violations,
            q.rmse_mm,
            100.0 * q.inlier_fraction,
            q.frames_used,
            q.frames,
            q.views_used,
            q.views
        );
        for f in &self.frames {
            let _ = writeln!(
                s,
                "  frame {} (view {}, {}): residual {:.3} mm{} / {:.4}°{}, coverage {:.1}%, {:.0} ms",
                f.residual.index,
                f.view,
                f.source,
                f.residual.position_mm(),
                if f.residual.workspace_mm.is_some() {
                    " at the robot base"
                } else {
                    ""
                },
                f.residual.rotation_deg,
                if f.residual.used { "" } else { " (dropped)" },
                100.0 * f.quality.coverage,
                f.timings_ms.total
            );
        }
        let t = &self.timings_ms;
        let _ = writeln!(
            s,
            "time: preprocess {:.0} ms, coarse {:.0} ms, fine {:.0} ms, verify {:.0} ms, total {:.0} ms",
            t.preprocess, t.coarse, t.fine, t.verify, t.total
        );
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::solve::{solve, FrameInput, SolveOptions};
    use crate::calib::testutil::good_registration;
    use nalgebra::Vector3;

    /// Two views of a fixed camera: the fused σ at the robot base is the frames' σ there and
    /// the views' spread there, over the views; the summary names the point. A wrist camera's
    /// report has no such σ.
    #[test]
    fn an_eye_to_hand_report_fuses_the_sigma_at_the_robot_base() {
        let mut reg = good_registration();
        reg.camera_from_model =
            Isometry3::new(Vector3::new(0.2, -0.1, 1.5), Vector3::new(2.4, 0.0, 0.0));
        reg.uncertainty.translation_mm = 1.4;
        reg.uncertainty.workspace = Some(WorkspaceSigma {
            translation_mm: 0.3,
            distance_m: reg.camera_from_model.translation.vector.norm(),
        });
        let mut other = reg.clone();
        other.camera_from_model = Isometry3::translation(0.0004, 0.0, 0.0) * reg.camera_from_model;
        let regs = [reg, other];
        let frames: Vec<FrameInput> = regs
            .iter()
            .enumerate()
            .map(|(view, r)| FrameInput {
                sigma: None,
                view,
                camera_from_model: r.camera_from_model,
                model_from_flange: Some(Isometry3::translation(0.4, 0.0, 0.6)),
            })
            .collect();
        let verdict = Verdict {
            outcome: Outcome::Accepted,
            reasons: vec![],
        };
        let report = |mount| {
            let s = solve(mount, &frames, &SolveOptions::default()).expect("solved");
            let names = ["a".to_string(), "b".to_string()];
            CalibrationReport::new(&s, &regs, &names, &verdict, "base", &s.estimate, 0.0, 0.0)
        };
        let fixed = report(Mount::EyeToHand);
        let w = fixed.uncertainty.workspace.expect("eye-to-hand");
        // Each view 0.2 mm from the mean: ((0.3² + 0.2²) / 2)^½.
        let expected = ((0.3f64.powi(2) + 0.2f64.powi(2)) / 2.0).sqrt();
        assert!((w.translation_mm - expected).abs() < 1e-9, "{w:?}");
        assert!((w.distance_m - 1.5166).abs() < 1e-3, "{w:?}");
        assert!(
            fixed
                .summary()
                .contains("; at the robot base, 1.52 m from the camera: 0.255 mm"),
            "{}",
            fixed.summary()
        );
        let wrist = report(Mount::EyeInHand);
        assert_eq!(wrist.uncertainty.workspace, None);
        assert!((wrist.uncertainty.translation_mm - fixed.uncertainty.translation_mm).abs() < 1e-9);
        assert!(
            !wrist.summary().contains("robot base"),
            "{}",
            wrist.summary()
        );
    }

    /// Two views of one camera whose depth errors give 0.8 of each frame's 1 mm / 0.1°: the
    /// fused σ keeps that shared part whole and divides only the rest, (0.8² + (1 − 0.8²) /
    /// 2)^½ = 0.906 mm, not the 0.707 mm of independent views.
    #[test]
    fn the_cameras_own_error_is_not_divided_by_the_views() {
        let mut reg = good_registration();
        reg.uncertainty = Uncertainty {
            translation_mm: 1.0,
            rotation_deg: 0.1,
            workspace: None,
        };
        let regs = [reg.clone(), reg.clone()];
        let frames: Vec<FrameInput> = (0..2)
            .map(|view| FrameInput {
                sigma: None,
                view,
                camera_from_model: reg.camera_from_model,
                model_from_flange: None,
            })
            .collect();
        let s = solve(Mount::EyeToHand, &frames, &SolveOptions::default()).expect("solved");
        let verdict = Verdict {
            outcome: Outcome::Accepted,
            reasons: vec![],
        };
        let names = ["a".to_string(), "b".to_string()];
        let fused = |regs: &[Registration]| {
            CalibrationReport::new(&s, regs, &names, &verdict, "base", &s.estimate, 0.0, 0.0)
                .uncertainty
        };
        let independent = fused(&regs);
        assert!((independent.translation_mm - 0.5f64.sqrt()).abs() < 1e-9);
        let shared = regs.map(|mut r| {
            r.camera_error = Uncertainty {
                translation_mm: 0.8,
                rotation_deg: 0.08,
                workspace: None,
            };
            r
        });
        let u = fused(&shared);
        let expected = (0.64f64 + 0.36 / 2.0).sqrt();
        assert!((u.translation_mm - expected).abs() < 1e-9, "{u:?}");
        assert!((u.rotation_deg - 0.1 * expected).abs() < 1e-9, "{u:?}");
    }
}
