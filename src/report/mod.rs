//! Pictures for people: the report picture of a calibration (the scan as the camera saw it,
//! coloured by distance to the posed model, with the model's expected outline, a residual
//! histogram and the key numbers) and the drift chart of the checks over time.
//!
//! Pure functions: they take the data and return PNG bytes; no file, no driver, no font on the
//! machine (the text is drawn with a pre-rasterised Noto Sans Mono compiled into the binary).
//!
//! - [`Summary`]: the numbers and the verdict, from a run record ([`Summary::from_run`]) or a
//!   calibration report ([`Summary::from_report`]).
//! - [`ScanView`]: one scan resampled to picture size with its distances and the outline.
//! - [`render`]: the report picture; [`drift_chart`]: the drift chart.

mod canvas;
mod drift;
mod scan;

use handeye_hal::ur_dh::DhParams;
use handeye_hal::{PointCloud, UrPose};

use crate::calib::report::QualitySummary;
use crate::calib::{
    posed_model, posed_model_with_controller_kinematics, CalibError, CalibrationReport, Mount,
    Outcome, Registration, Uncertainty,
};
use crate::model::RobotModel;
use crate::record::{RunMode, RunRecord};
use canvas::{wrap, Canvas, Rgb, Size};

pub use drift::{drift_chart, DriftLimits, DriftPoint};
pub use scan::ScanView;

/// Width of the report picture, px.
pub const REPORT_WIDTH: usize = 1280;
/// Height of the report picture, px.
pub const REPORT_HEIGHT: usize = 720;
/// Largest scan picture inside the report, px.
const SCAN_W: usize = 640;
const SCAN_H: usize = 480;
/// Pixels between the panels of several views' scans.
const PANEL_GAP: usize = 4;
/// The distance colour scale ends here, mm; farther points are grey.
const SCALE_MM: f32 = 5.0;
/// The scan's colours change in steps of this, mm (bands read like contour lines).
const STEP_MM: f32 = 0.25;
/// The histogram covers distances up to this, mm.
const HIST_MM: f32 = 5.0;
/// Links up to this many joints from the root are fitted by registration (its default).
const FIT_DEPTH: usize = 2;

const WHITE: Rgb = [255, 255, 255];
const INK: Rgb = [29, 35, 42];
const MUTED: Rgb = [96, 106, 118];
const RULE: Rgb = [214, 219, 225];
const HEADER: Rgb = [31, 41, 51];
const SCAN_BG: Rgb = [21, 24, 28];
const FAR: Rgb = [128, 128, 128];
const GOOD: Rgb = [26, 127, 55];
const BAD: Rgb = [200, 30, 30];
const WARN: Rgb = [191, 102, 0];
const NEUTRAL: Rgb = [70, 90, 120];

/// Why a picture could not be made.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReportError {
    /// The scan or the model could not be used.
    #[error("cannot draw the scan: {0}")]
    Scan(#[from] CalibError),
    /// PNG encoding failed.
    #[error("cannot encode the picture: {0}")]
    Png(#[from] png::EncodingError),
}

/// The result numbers of a report.
#[derive(Debug, Clone, PartialEq)]
pub struct ResultNumbers {
    /// What the numbers are (`flange_from_camera (camera in tool0)`).
    pub unknown: String,
    /// The unknown as UR `x,y,z,rx,ry,rz` (m, rotation vector rad).
    pub ur_pose: [f64; 6],
    /// 1-σ uncertainty.
    pub uncertainty: Uncertainty,
    /// Worst-case quality over the frames.
    pub quality: QualitySummary,
}

/// A check's drift in a report.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriftNumbers {
    /// Camera position change from the current calibration, mm.
    pub translation_mm: f64,
    /// Camera rotation change, degrees.
    pub rotation_deg: f64,
    /// Thresholds, mm and degrees.
    pub limits: DriftLimits,
    /// Whether a threshold is exceeded.
    pub drifted: bool,
}

/// What a report picture says besides the scan.
#[derive(Debug, Clone, PartialEq)]
pub struct Summary {
    /// First line (`check 20261124T143314Z-4e4f`).
    pub title: String,
    /// Second line (when, from what).
    pub subtitle: String,
    /// How it ended.
    pub outcome: Outcome,
    /// The verdict in one or two words (`ACCEPTED`, `REJECTED`, `DRIFTED`, …).
    pub headline: String,
    /// The gate's (or the failure's) reasons.
    pub reasons: Vec<String>,
    /// The measured result, when one was computed (also when rejected).
    pub result: Option<ResultNumbers>,
    /// Check: the comparison with the current calibration.
    pub drift: Option<DriftNumbers>,
    /// Further facts, one line each (timings, what was written).
    pub notes: Vec<String>,
}

fn unknown_name(mount: Mount) -> String {
    format!(
        "{} (camera in {})",
        mount.unknown_name(),
        mount.parent_frame()
    )
}

impl Summary {
    /// The summary of a run.
    pub fn from_run(record: &RunRecord) -> Summary {
        let mode = match record.mode {
            RunMode::Calibrate => "calibration",
            RunMode::Check => "check",
        };
        let drift = record.drift.as_ref().map(|d| DriftNumbers {
            translation_mm: d.translation_mm,
            rotation_deg: d.rotation_deg,
            limits: DriftLimits {
                translation_mm: d.max_translation_mm,
                rotation_deg: d.max_rotation_deg,
            },
            drifted: d.drifted,
        });
        let headline = record.verdict().to_uppercase();
        let mut notes = Vec::new();
        if let Some(stage) = record.failed_stage {
            notes.push(format!("failed at stage: {}", stage.name()));
        }
        let t = &record.timings_ms;
        if t.total > 0.0 {
            notes.push(format!(
                "time {:.1} s (register {:.0} ms, moves {:.1} s)",
                t.total / 1e3,
                t.register,
                (t.moves + t.return_move) / 1e3
            ));
        }
        if !record.written.is_empty() {
            let targets: Vec<&str> = record.written.iter().map(|w| w.target.name()).collect();
            notes.push(format!("written back: {}", targets.join(", ")));
        } else if record.mode == RunMode::Calibrate {
            notes.push("nothing written back".into());
        }
        Summary {
            title: format!("{mode} {}", record.run_id),
            subtitle: format!(
                "{}  |  {}",
                crate::calendar::utc_text(record.started_unix_s),
                record.config
            ),
            outcome: record.outcome,
            headline,
            reasons: record.reasons.clone(),
            result: record.result.as_ref().map(|r| ResultNumbers {
                unknown: unknown_name(r.mount),
                ur_pose: r.ur_pose,
                uncertainty: r.uncertainty,
                quality: r.report.quality,
            }),
            drift,
            notes,
        }
    }

    /// The summary of a calibration report (`handeye solve`); `title` names the input.
    pub fn from_report(report: &CalibrationReport, title: &str) -> Summary {
        let matrix = report
            .flange_from_camera
            .as_ref()
            .unwrap_or(&report.base_from_camera);
        let ur_pose = crate::frames::from_row_major(matrix)
            .map(|p| UrPose::from(&p).values())
            .unwrap_or([f64::NAN; 6]);
        let unknown = match report.mount {
            Mount::EyeInHand => unknown_name(Mount::EyeInHand),
            Mount::EyeToHand => format!(
                "{}_from_camera (camera in {})",
                report.base_frame, report.base_frame
            ),
        };
        let t = &report.timings_ms;
        Summary {
            title: format!("solve {title}"),
            subtitle: format!(
                "{} frame(s), {} view(s), poses in `{}`",
                report.quality.frames, report.quality.views, report.base_frame
            ),
            outcome: report.outcome,
            headline: report.outcome.name().to_uppercase(),
            reasons: report.reasons.clone(),
            result: Some(ResultNumbers {
                unknown,
                ur_pose,
                uncertainty: report.uncertainty,
                quality: report.quality,
            }),
            drift: None,
            notes: vec![format!(
                "compute {:.0} ms (coarse {:.0}, fine {:.0}, verify {:.0})",
                t.total, t.coarse, t.fine, t.verify
            )],
        }
    }

    fn colour(&self) -> Rgb {
        match (self.outcome, &self.drift) {
            (Outcome::Accepted, Some(d)) if d.drifted => BAD,
            (Outcome::Accepted, _) => GOOD,
            (Outcome::Rejected | Outcome::Error, _) => BAD,
            (Outcome::Aborted, _) => WARN,
            (Outcome::Planned, _) => NEUTRAL,
        }
    }
}

/// The scan of one frame as the report shows it: the model posed at `joints` (radians, URDF
/// order; by the controller's calibrated kinematics when given) and placed by the frame's
/// registration (its `camera_from_model` and estimated depth scale).
pub fn scan_view(
    model: &RobotModel,
    joints: &[f64],
    controller_dh: Option<&DhParams>,
    cloud: &PointCloud,
    registration: &Registration,
    caption: &str,
    panels: usize,
) -> Result<ScanView, ReportError> {
    let posed = match controller_dh {
        Some(dh) => posed_model_with_controller_kinematics(model, joints, dh)?,
        None => posed_model(model, joints)?,
    };
    let (w, h) = panel_size(panels);
    Ok(ScanView::new(
        cloud,
        &posed,
        &registration.camera_from_model,
        registration.depth_scale,
        FIT_DEPTH,
        w,
        h,
        caption,
    )?)
}

/// Columns and rows of the scan area's grid for `panels` scans: one fills it, two to four
/// share it two by two, more three by three (at most nine are drawn).
fn grid(panels: usize) -> (usize, usize) {
    match panels {
        0 | 1 => (1, 1),
        2 => (2, 1),
        3 | 4 => (2, 2),
        _ => (3, 3),
    }
}

/// The size of one panel of the scan area for `panels` scans ([`grid`]), pixels.
fn panel_size(panels: usize) -> (usize, usize) {
    let (cols, rows) = grid(panels);
    (
        (SCAN_W - (cols - 1) * PANEL_GAP) / cols,
        (SCAN_H - (rows - 1) * PANEL_GAP) / rows,
    )
}

/// The distance colour: blue (on the surface) through cyan, green, yellow to red at
/// [`SCALE_MM`] (CloudCompare's familiar scale).
pub(crate) fn distance_colour(mm: f32) -> Rgb {
    const STOPS: [(f32, Rgb); 5] = [
        (0.0, [40, 70, 230]),
        (0.25, [0, 180, 230]),
        (0.5, [40, 190, 80]),
        (0.75, [245, 215, 30]),
        (1.0, [225, 40, 30]),
    ];
    let t = (mm / SCALE_MM).clamp(0.0, 1.0);
    for k in 1..STOPS.len() {
        let (t1, c1) = STOPS[k];
        if t <= t1 {
            let (t0, c0) = STOPS[k - 1];
            let f = (t - t0) / (t1 - t0);
            let mut c = [0u8; 3];
            for i in 0..3 {
                c[i] = (f32::from(c0[i]) + f * (f32::from(c1[i]) - f32::from(c0[i]))).round() as u8;
            }
            return c;
        }
    }
    STOPS[STOPS.len() - 1].1
}

fn shaded(c: Rgb, shade: f32) -> Rgb {
    let k = 0.45 + 0.55 * shade.clamp(0.0, 1.0);
    [
        (f32::from(c[0]) * k) as u8,
        (f32::from(c[1]) * k) as u8,
        (f32::from(c[2]) * k) as u8,
    ]
}

/// Draws the scan picture (distance colours, shading, outline).
fn scan_canvas(view: &ScanView) -> Canvas {
    let mut c = Canvas::new(view.width, view.height, SCAN_BG);
    for (i, p) in view.pixels.iter().enumerate() {
        let Some(p) = p else { continue };
        let base = match p.distance_mm {
            // In steps of STEP_MM, as the colour bar shows them.
            Some(d) if d <= SCALE_MM => distance_colour(((d / STEP_MM).floor() + 0.5) * STEP_MM),
            _ => FAR,
        };
        c.set(
            (i % view.width) as i64,
            (i / view.width) as i64,
            shaded(base, p.shade),
        );
    }
    for (i, e) in view.edges.iter().enumerate() {
        let (x, y) = ((i % view.width) as i64, (i / view.width) as i64);
        match e {
            scan::Edge::Fitted => c.set(x, y, WHITE),
            scan::Edge::Other => c.blend(x, y, [255, 120, 255], 200),
            scan::Edge::None => {}
        }
    }
    c
}

/// A section heading with a rule; returns the y below it.
fn heading(c: &mut Canvas, x: i64, y: i64, w: i64, text: &str) -> i64 {
    c.text(x, y, text, Size::Small, true, MUTED);
    c.line(x, y + 18, x + w, y + 18, RULE);
    y + 24
}

/// The report picture of one calibration: `scans` (one per view that was registered, in view
/// order, each made by [`scan_view`] for `scans.len()` panels; up to nine drawn, in a grid)
/// and `summary`. [`REPORT_WIDTH`]×[`REPORT_HEIGHT`] RGB PNG.
pub fn render(summary: &Summary, scans: &[ScanView]) -> Result<Vec<u8>, ReportError> {
    let (w, h) = (REPORT_WIDTH as i64, REPORT_HEIGHT as i64);
    let mut c = Canvas::new(REPORT_WIDTH, REPORT_HEIGHT, WHITE);
    let verdict = summary.colour();

    // Header: what, when, and the verdict as a badge.
    c.fill_rect(0, 0, w, 60, HEADER);
    c.fill_rect(0, 60, w, 4, verdict);
    c.text(16, 8, &summary.title, Size::Title, true, WHITE);
    let sub: String = canvas::printable(&summary.subtitle)
        .chars()
        .take(110)
        .collect();
    c.text(16, 36, &sub, Size::Small, false, [190, 198, 208]);
    let badge = &summary.headline;
    let bw = Canvas::text_width(badge, Size::Title) + 32;
    c.fill_rect(w - bw - 16, 12, bw, 36, verdict);
    c.text(w - bw, 18, badge, Size::Title, true, WHITE);

    // Left: the scan.
    let (sx, sy) = (16i64, 80i64);
    c.fill_rect(sx, sy, SCAN_W as i64, SCAN_H as i64, SCAN_BG);
    let (cols, rows) = grid(scans.len());
    let (pw, ph) = panel_size(scans.len());
    match scans.first() {
        Some(_) => {
            for (k, view) in scans.iter().take(cols * rows).enumerate() {
                let (px, py) = (
                    sx + ((k % cols) * (pw + PANEL_GAP)) as i64,
                    sy + ((k / cols) * (ph + PANEL_GAP)) as i64,
                );
                let pic = scan_canvas(view);
                let ox = px + (pw as i64 - view.width as i64) / 2;
                let oy = py + (ph as i64 - view.height as i64) / 2;
                c.blit(ox, oy, &pic);
                if scans.len() > 1 {
                    // Each panel says which view it is, as the run's lines number them.
                    let label = truncate(&view.caption, pw / 9);
                    c.fill_rect(
                        px,
                        py,
                        Canvas::text_width(&label, Size::Small) + 8,
                        20,
                        SCAN_BG,
                    );
                    c.text(px + 4, py + 2, &label, Size::Small, true, WHITE);
                }
            }
            for k in 1..cols {
                let x = sx + (k * (pw + PANEL_GAP)) as i64 - PANEL_GAP as i64 / 2 - 1;
                c.fill_rect(x, sy, 2, SCAN_H as i64, WHITE);
            }
            for k in 1..rows {
                let y = sy + (k * (ph + PANEL_GAP)) as i64 - PANEL_GAP as i64 / 2 - 1;
                c.fill_rect(sx, y, SCAN_W as i64, 2, WHITE);
            }
        }
        None => {
            let msg = "no scan registered in this run";
            let tw = Canvas::text_width(msg, Size::Body);
            c.text(
                sx + (SCAN_W as i64 - tw) / 2,
                sy + 220,
                msg,
                Size::Body,
                false,
                [200, 205, 210],
            );
        }
    }
    c.stroke_rect(sx - 1, sy - 1, SCAN_W as i64 + 2, SCAN_H as i64 + 2, RULE);
    if let Some(view) = scans.first() {
        let y = sy + SCAN_H as i64 + 8;
        let caption = match scans.len() {
            1 => view.caption.clone(),
            n => format!("views 1 to {n}: one frame of each, registered"),
        };
        c.text(sx, y, &truncate(&caption, 80), Size::Small, false, MUTED);
        legend(&mut c, sx, y + 24);
    }

    // Right: the numbers.
    let (rx, rw) = (sx + SCAN_W as i64 + 32, w - (sx + SCAN_W as i64 + 32) - 16);
    let mut y = 80;
    if let Some(r) = &summary.result {
        y = heading(&mut c, rx, y, rw, &format!("RESULT  {}", r.unknown));
        let [x, yy, z, ax, ay, az] = r.ur_pose;
        let rows = [
            (
                format!("x {:>10.3} mm", x * 1e3),
                format!("rx {:>10.6} rad", ax),
            ),
            (
                format!("y {:>10.3} mm", yy * 1e3),
                format!("ry {:>10.6} rad", ay),
            ),
            (
                format!("z {:>10.3} mm", z * 1e3),
                format!("rz {:>10.6} rad", az),
            ),
        ];
        for (a, b) in rows {
            c.text(rx, y, &a, Size::Body, false, INK);
            c.text(rx + 250, y, &b, Size::Body, false, INK);
            y += 22;
        }
        let rotation =
            nalgebra::UnitQuaternion::from_scaled_axis(nalgebra::Vector3::new(ax, ay, az));
        let (roll, pitch, yaw) = rotation.euler_angles();
        c.text(
            rx,
            y,
            &format!(
                "rotation {:.3}°  (roll {:.3}°, pitch {:.3}°, yaw {:.3}°)",
                rotation.angle().to_degrees(),
                roll.to_degrees(),
                pitch.to_degrees(),
                yaw.to_degrees()
            ),
            Size::Small,
            false,
            MUTED,
        );
        y += 18;
        c.text(
            rx,
            y,
            &format!(
                "uncertainty (1 sigma)  {:.3} mm / {:.4}°",
                r.uncertainty.translation_mm, r.uncertainty.rotation_deg
            ),
            Size::Small,
            true,
            INK,
        );
        if let Some(w) = r.uncertainty.workspace {
            y += 18;
            c.text(
                rx,
                y,
                &format!(
                    "at the robot base ({:.2} m away)  {:.3} mm",
                    w.distance_m, w.translation_mm
                ),
                Size::Small,
                true,
                INK,
            );
        }
        y += 26;
        y = heading(&mut c, rx, y, rw, "QUALITY");
        let q = &r.quality;
        let lines = [
            format!(
                "coverage {:5.1} %    free-space violations {:5.2} %",
                100.0 * q.coverage,
                100.0 * q.free_space_violations
            ),
            format!(
                "support: base {}  shoulder {}  upper arm {}",
                percent(q.link_support[0]),
                percent(q.link_support[1]),
                percent(q.link_support[2])
            ),
            format!(
                "rms residual {:.3} mm    inliers {:5.1} %",
                q.rmse_mm,
                100.0 * q.inlier_fraction
            ),
            format!(
                "frames {}/{}    views {}/{}    depth scale {}    range offset {}",
                q.frames_used,
                q.frames,
                q.views_used,
                q.views,
                q.depth_scale.map_or("-".to_string(), |s| format!("{s:.4}")),
                q.depth_offset_mm
                    .map_or("-".to_string(), |m| format!("{m:+.2} mm"))
            ),
        ];
        for l in lines {
            c.text(rx, y, &l, Size::Small, false, INK);
            y += 20;
        }
        y += 8;
    }
    if let Some(d) = &summary.drift {
        y = heading(&mut c, rx, y, rw, "DRIFT FROM THE CURRENT CALIBRATION");
        let col = if d.drifted { BAD } else { GOOD };
        c.text(
            rx,
            y,
            &format!(
                "{:.3} mm / {:.4}°   (limits {} mm / {}°)  {}",
                d.translation_mm,
                d.rotation_deg,
                d.limits.translation_mm,
                d.limits.rotation_deg,
                if d.drifted { "EXCEEDED" } else { "within" }
            ),
            Size::Body,
            d.drifted,
            col,
        );
        y += 30;
    }
    let why = if summary.result.is_some() {
        "GATE"
    } else {
        "WHY IT ENDED"
    };
    y = heading(&mut c, rx, y, rw, why);
    let max_chars = (rw / Size::Small.advance() as i64) as usize;
    if summary.reasons.is_empty() {
        let drifted = summary.drift.as_ref().map(|d| d.drifted);
        let ok = match summary.outcome {
            Outcome::Accepted if drifted == Some(true) => {
                "the camera moved beyond the thresholds: recalibrate"
            }
            Outcome::Accepted => "every check passed",
            Outcome::Planned => "dry run: planned, nothing moved",
            _ => "no reason recorded",
        };
        c.text(rx, y, ok, Size::Small, false, verdict);
        y += 20;
    } else {
        let mut lines = Vec::new();
        for r in &summary.reasons {
            for (k, l) in wrap(r, max_chars - 2).into_iter().enumerate() {
                lines.push(if k == 0 {
                    format!("- {l}")
                } else {
                    format!("  {l}")
                });
            }
        }
        let room = 6usize;
        let more = lines.len().saturating_sub(room);
        for l in lines.iter().take(room) {
            c.text(rx, y, l, Size::Small, false, verdict);
            y += 18;
        }
        if more > 0 {
            c.text(
                rx,
                y,
                &format!("  ({more} more lines in the record)"),
                Size::Small,
                false,
                MUTED,
            );
            y += 18;
        }
    }
    for n in &summary.notes {
        c.text(rx, y, &truncate(n, max_chars), Size::Small, false, MUTED);
        y += 18;
    }

    // Bottom right: the histogram.
    let hy = (y + 16).max(h - 300).min(h - 140);
    if !scans.is_empty() {
        histogram(&mut c, rx, hy, rw, h - hy - 16, scans, summary);
    }
    Ok(c.png()?)
}

fn truncate(s: &str, n: usize) -> String {
    let p = canvas::printable(s);
    if p.chars().count() <= n {
        p
    } else {
        let mut t: String = p.chars().take(n.saturating_sub(3)).collect();
        t.push_str("...");
        t
    }
}

/// The colour bar and the outline legend under the scan.
fn legend(c: &mut Canvas, x: i64, y: i64) {
    c.text(x, y, "distance to the posed model", Size::Small, false, INK);
    let (bx, by, bw, bh) = (x + 240, y + 2, 300i64, 14i64);
    for k in 0..bw {
        let d = SCALE_MM * k as f32 / bw as f32;
        let col = distance_colour(((d / STEP_MM).floor() + 0.5) * STEP_MM);
        c.line(bx + k, by, bx + k, by + bh - 1, col);
    }
    c.stroke_rect(bx - 1, by - 1, bw + 2, bh + 2, RULE);
    for mm in 0..=SCALE_MM as i64 {
        let tx = bx + mm * (bw - 1) / SCALE_MM as i64;
        c.line(tx, by + bh, tx, by + bh + 3, MUTED);
        let label = if mm == SCALE_MM as i64 {
            format!("{mm} mm")
        } else {
            format!("{mm}")
        };
        c.text(tx - 4, by + bh + 4, &label, Size::Small, false, MUTED);
    }
    c.fill_rect(bx + bw + 36, by, 14, bh, FAR);
    c.text(bx + bw + 54, y, "> 5 mm", Size::Small, false, MUTED);
    let y2 = y + 40;
    c.fill_rect(x, y2 + 7, 18, 2, WHITE);
    c.stroke_rect(x - 1, y2 + 5, 20, 6, [120, 120, 120]);
    c.text(
        x + 26,
        y2,
        "model outline: base, shoulder, upper arm (fitted)",
        Size::Small,
        false,
        INK,
    );
    c.fill_rect(x + 440, y2 + 7, 18, 2, [255, 120, 255]);
    c.text(x + 466, y2, "other links", Size::Small, false, INK);
    c.fill_rect(x + 580, y2 + 3, 14, 12, SCAN_BG);
    c.text(x + 600, y2, "no data", Size::Small, false, MUTED);
}

/// Histogram of the scan points' distances to the model (those within [`HIST_MM`]).
/// The residuals' histogram of every view's scan shown.
fn histogram(
    c: &mut Canvas,
    x: i64,
    y: i64,
    w: i64,
    h: i64,
    scans: &[ScanView],
    summary: &Summary,
) {
    let d: Vec<f32> = scans.iter().flat_map(|v| v.distances(HIST_MM)).collect();
    let valid = scans.iter().map(ScanView::valid).sum::<usize>().max(1);
    let within1 = d.iter().filter(|v| **v <= 1.0).count();
    let title =
        format!(
        "RESIDUALS (mm)  {} of {} scan points within {HIST_MM:.0} mm, {:.0} % of those within 1",
        d.len(),
        valid,
        if d.is_empty() { 0.0 } else { 100.0 * within1 as f64 / d.len() as f64 }
    );
    let y = heading(
        c,
        x,
        y,
        w,
        &truncate(&title, (w / Size::Small.advance() as i64) as usize),
    );
    let bins = 40usize;
    let mut counts = vec![0usize; bins];
    for v in &d {
        let k = ((v / HIST_MM) * bins as f32) as usize;
        counts[k.min(bins - 1)] += 1;
    }
    let peak = counts.iter().copied().max().unwrap_or(0).max(1);
    let (px, py, pw, ph) = (x + 8, y + 4, w - 16, h - 50);
    let bar = pw / bins as i64;
    for (k, n) in counts.iter().enumerate() {
        let bh = (*n as f64 / peak as f64 * ph as f64).round() as i64;
        let mid = (k as f32 + 0.5) * HIST_MM / bins as f32;
        let col = if mid <= SCALE_MM {
            distance_colour(mid)
        } else {
            FAR
        };
        c.fill_rect(px + k as i64 * bar, py + ph - bh, bar - 1, bh, col);
    }
    c.line(px, py + ph, px + bar * bins as i64, py + ph, INK);
    for mm in 0..=HIST_MM as i64 {
        let tx = px + (mm as f32 / HIST_MM * (bar * bins as i64) as f32) as i64;
        c.line(tx, py + ph, tx, py + ph + 3, INK);
        c.text(
            tx - 4,
            py + ph + 4,
            &format!("{mm}"),
            Size::Small,
            false,
            MUTED,
        );
    }
    if let Some(r) = &summary.result {
        let rms = r.quality.rmse_mm as f32;
        if rms.is_finite() && rms < HIST_MM {
            let tx = px + (rms / HIST_MM * (bar * bins as i64) as f32) as i64;
            c.dashed(tx, py, tx, py + ph, INK, 3);
            let label = format!("- - registration rms {rms:.2} mm");
            c.text_right(px + pw, py, &label, Size::Small, INK);
        }
    }
}

#[cfg(test)]
mod tests;

/// A coverage as `95.1 %`, or `-` when it was not judged.
fn percent(fraction: Option<f64>) -> String {
    fraction.map_or("-".into(), |f| format!("{:.1} %", 100.0 * f))
}
