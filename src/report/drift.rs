//! The drift chart: every check's camera position and rotation change from the calibration it
//! was compared with, over time, against the thresholds; accepted calibrations (which reset the
//! reference) as vertical lines.

use super::canvas::{Canvas, Rgb, Size};
use super::{ReportError, BAD, GOOD, INK, MUTED, RULE, WHITE};

/// One check in the chart.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriftPoint {
    /// When the check ran, unix s.
    pub unix_s: f64,
    /// Camera position change, mm.
    pub translation_mm: f64,
    /// Camera rotation change, degrees.
    pub rotation_deg: f64,
    /// Whether it exceeded a threshold.
    pub drifted: bool,
}

/// Drift thresholds (`[check]` in the configuration).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriftLimits {
    /// Position, mm.
    pub translation_mm: f64,
    /// Rotation, degrees.
    pub rotation_deg: f64,
}

const CALIBRATION: Rgb = [60, 110, 200];

/// The drift chart of `points` (any order) with `calibrations` (unix s of accepted
/// calibrations) and `limits`, `width`×`height` px (at least 320×240), as PNG.
pub fn drift_chart(
    points: &[DriftPoint],
    calibrations: &[f64],
    limits: DriftLimits,
    width: usize,
    height: usize,
) -> Result<Vec<u8>, ReportError> {
    let (width, height) = (width.max(320), height.max(240));
    let mut c = Canvas::new(width, height, WHITE);
    let mut pts: Vec<DriftPoint> = points
        .iter()
        .copied()
        .filter(|p| {
            p.unix_s.is_finite() && p.translation_mm.is_finite() && p.rotation_deg.is_finite()
        })
        .collect();
    pts.sort_by(|a, b| a.unix_s.total_cmp(&b.unix_s));
    let times = pts
        .iter()
        .map(|p| p.unix_s)
        .chain(calibrations.iter().copied().filter(|t| t.is_finite()));
    let (t0, t1) = times.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), t| {
        (a.min(t), b.max(t))
    });
    let (w, h) = (width as i64, height as i64);
    let title = format!(
        "DRIFT OF THE CHECKS  (limits {} mm / {}°)",
        limits.translation_mm, limits.rotation_deg
    );
    c.text(12, 6, &title, Size::Small, true, MUTED);
    if pts.is_empty() {
        let msg = "no checks yet: a check compares the camera with the current calibration";
        c.text(12, h / 2 - 8, msg, Size::Small, false, MUTED);
        return Ok(c.png()?);
    }
    // Pad the time range: a single check sits in the middle.
    let span = (t1 - t0).max(60.0);
    let (t0, t1) = (t0 - 0.05 * span, t1 + 0.05 * span);
    let left = 64i64;
    let right = w - 16;
    let plot_h = (h - 30 - 44) / 2 - 8;
    let panels = [
        (30i64, "position, mm", limits.translation_mm, true),
        (30 + plot_h + 16, "rotation, °", limits.rotation_deg, false),
    ];
    let x_of = |t: f64| left + ((t - t0) / (t1 - t0) * (right - left) as f64).round() as i64;
    for (top, label, limit, is_t) in panels {
        let value = |p: &DriftPoint| {
            if is_t {
                p.translation_mm
            } else {
                p.rotation_deg
            }
        };
        let vmax = pts.iter().map(value).fold(0.0, f64::max);
        let ymax = nice_ceiling((limit * 1.4).max(vmax * 1.1).max(1e-6));
        let y_of = |v: f64| top + plot_h - (v / ymax * plot_h as f64).round() as i64;
        c.stroke_rect(left, top, right - left + 1, plot_h + 1, RULE);
        for k in 0..=4 {
            let v = ymax * f64::from(k) / 4.0;
            let y = y_of(v);
            if k > 0 && k < 4 {
                c.dashed(left + 1, y, right - 1, y, [235, 238, 242], 2);
            }
            c.text_right(left - 6, y - 8, &format_value(v), Size::Small, MUTED);
        }
        c.text(left + 6, top + 2, label, Size::Small, false, MUTED);
        for t in calibrations {
            if t.is_finite() {
                let x = x_of(*t);
                c.dashed(x, top + 1, x, top + plot_h - 1, CALIBRATION, 3);
            }
        }
        let ly = y_of(limit);
        c.dashed(left + 1, ly, right - 1, ly, BAD, 6);
        c.dashed(left + 1, ly + 1, right - 1, ly + 1, BAD, 6);
        c.text_right(
            right - 4,
            ly - 17,
            &format!("limit {limit}"),
            Size::Small,
            BAD,
        );
        let mut prev: Option<(i64, i64)> = None;
        for p in &pts {
            let (x, y) = (x_of(p.unix_s), y_of(value(p).min(ymax)));
            if let Some((px, py)) = prev {
                c.line(px, py, x, y, [150, 158, 168]);
            }
            prev = Some((x, y));
        }
        for p in &pts {
            let (x, y) = (x_of(p.unix_s), y_of(value(p).min(ymax)));
            let col = if p.drifted { BAD } else { GOOD };
            dot(&mut c, x, y, col);
        }
    }
    // Time axis.
    let axis_y = 30 + 2 * plot_h + 16 + 4;
    let step = tick_step(t1 - t0);
    let mut t = (t0 / step).ceil() * step;
    let mut last_day = i64::MIN;
    while t <= t1 {
        let x = x_of(t);
        c.line(x, axis_y - 4, x, axis_y, INK);
        let text = crate::calendar::utc_text(t);
        // `YYYY-MM-DDTHH:MM:SSZ`: the date when it changes, the time always.
        let day = (t / 86_400.0).floor() as i64;
        let hhmm = if step < 60.0 {
            &text[11..19]
        } else {
            &text[11..16]
        };
        let label = if day != last_day {
            format!("{} {hhmm}", &text[5..10])
        } else {
            hhmm.to_string()
        };
        last_day = day;
        let tw = Canvas::text_width(&label, Size::Small);
        c.text(x - tw / 2, axis_y + 2, &label, Size::Small, false, MUTED);
        t += step;
    }
    let ly = h - 20;
    dot(&mut c, 16, ly + 8, GOOD);
    c.text(26, ly, "check within limits", Size::Small, false, INK);
    dot(&mut c, 220, ly + 8, BAD);
    c.text(230, ly, "drifted", Size::Small, false, INK);
    c.dashed(320, ly + 8, 344, ly + 8, CALIBRATION, 3);
    c.text(350, ly, "calibration (UTC times)", Size::Small, false, INK);
    Ok(c.png()?)
}

fn dot(c: &mut Canvas, x: i64, y: i64, col: Rgb) {
    for dy in -3i64..=3 {
        for dx in -3i64..=3 {
            let r2 = dx * dx + dy * dy;
            if r2 <= 9 {
                c.set(x + dx, y + dy, if r2 >= 7 { WHITE } else { col });
            }
        }
    }
}

/// The smallest 1, 2 or 4 × 10^k at or above `v` (its quarters are round numbers).
fn nice_ceiling(v: f64) -> f64 {
    let e = 10f64.powf(v.log10().floor());
    for m in [1.0, 2.0, 4.0, 10.0] {
        if m * e >= v * (1.0 - 1e-9) {
            return m * e;
        }
    }
    10.0 * e
}

fn format_value(v: f64) -> String {
    if v == 0.0 {
        "0".into()
    } else if v >= 10.0 {
        format!("{v:.0}")
    } else if v >= 1.0 {
        format!("{v:.1}")
    } else if v >= 0.1 {
        format!("{v:.2}")
    } else {
        format!("{v:.3}")
    }
}

/// A tick spacing (s) that puts at most six ticks on `span` seconds.
fn tick_step(span: f64) -> f64 {
    const STEPS: [f64; 15] = [
        10.0, 30.0, 60.0, 300.0, 600.0, 900.0, 1800.0, 3600.0, 7200.0, 10_800.0, 21_600.0,
        43_200.0, 86_400.0, 172_800.0, 604_800.0,
    ];
    STEPS
        .iter()
        .copied()
        .find(|s| span / s <= 6.0)
        .unwrap_or_else(|| (span / 6.0 / 86_400.0).ceil() * 86_400.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axis_helpers() {
        assert_eq!(nice_ceiling(0.7), 1.0);
        assert_eq!(nice_ceiling(1.4), 2.0);
        assert_eq!(nice_ceiling(2.1), 4.0);
        assert!((nice_ceiling(0.28) - 0.4).abs() < 1e-12);
        assert_eq!(tick_step(3000.0), 600.0);
        assert_eq!(tick_step(86_400.0 * 3.0), 43_200.0);
    }
}
