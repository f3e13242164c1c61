//! The drift routes: every check's drift and the thresholds as JSON (`GET /api/drift`) and as a
//! chart (`GET /api/drift.png`).

use axum::extract::{RawQuery, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde_json::json;

use super::{png, with_store, ApiError, AppState};
use crate::report::DriftPoint;
use crate::run::{Outcome, RunMode};
use crate::store::RunStatus;

/// Most checks the drift chart and `GET /api/drift` show (the newest).
const DRIFT_RUNS: usize = 1000;
/// Largest drift chart `GET /api/drift.png` draws, px.
const MAX_CHART: usize = 2000;

/// Every check's drift (oldest first) and the accepted calibrations' times, from the history.
async fn drift_data(state: &AppState) -> Result<(Vec<(String, DriftPoint)>, Vec<f64>), ApiError> {
    let runs = with_store(state, |s| Ok(s.list(DRIFT_RUNS, None)?)).await?;
    let mut checks = Vec::new();
    let mut calibrations = Vec::new();
    for r in runs.iter().rev() {
        match (r.mode, r.outcome) {
            (RunMode::Check, _) => {
                if let (Some(t), Some(d)) = (r.drift_translation_mm, r.drift_rotation_deg) {
                    checks.push((
                        r.run_id.clone(),
                        DriftPoint {
                            unix_s: r.started_unix_s,
                            translation_mm: t,
                            rotation_deg: d,
                            drifted: r.drifted.unwrap_or(false),
                        },
                    ));
                }
            }
            (RunMode::Calibrate, RunStatus::Ended(Outcome::Accepted)) => {
                calibrations.push(r.started_unix_s)
            }
            _ => {}
        }
    }
    Ok((checks, calibrations))
}

pub(super) async fn drift(State(state): State<AppState>) -> Result<Response, ApiError> {
    let (checks, calibrations) = drift_data(&state).await?;
    let limits = state.site.drift_limits;
    let checks: Vec<_> = checks
        .iter()
        .map(|(id, p)| {
            json!({
                "run_id": id,
                "unix_s": p.unix_s,
                "translation_mm": p.translation_mm,
                "rotation_deg": p.rotation_deg,
                "drifted": p.drifted,
            })
        })
        .collect();
    Ok(Json(json!({
        "max_translation_mm": limits.translation_mm,
        "max_rotation_deg": limits.rotation_deg,
        "checks": checks,
        "calibrations_unix_s": calibrations,
    }))
    .into_response())
}

/// `width` and `height` of `GET /api/drift.png` (defaults 900×340).
pub(super) fn chart_size(query: Option<&str>) -> Result<(usize, usize), String> {
    let (mut w, mut h) = (900, 340);
    for pair in query.unwrap_or("").split('&').filter(|p| !p.is_empty()) {
        let (key, value) = pair.split_once('=').unwrap_or((pair, ""));
        let n = value
            .parse::<usize>()
            .ok()
            .filter(|n| (240..=MAX_CHART).contains(n));
        match (key, n) {
            ("width", Some(n)) => w = n.max(320),
            ("height", Some(n)) => h = n,
            ("t", _) => {} // cache buster of the page
            _ => {
                return Err(format!(
                    "{pair}: use width=N and height=N (240..{MAX_CHART} pixels)"
                ))
            }
        }
    }
    Ok((w, h))
}

pub(super) async fn drift_png(
    State(state): State<AppState>,
    RawQuery(query): RawQuery,
) -> Result<Response, ApiError> {
    let (w, h) =
        chart_size(query.as_deref()).map_err(|m| ApiError::new(StatusCode::BAD_REQUEST, m))?;
    let (checks, calibrations) = drift_data(&state).await?;
    let limits = state.site.drift_limits;
    let points: Vec<DriftPoint> = checks.into_iter().map(|(_, p)| p).collect();
    // At most CHARTS_AT_ONCE charts in memory; the others wait their turn.
    let Ok(_drawing) = state.charts.acquire().await else {
        return Err(ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            "the daemon is stopping",
        ));
    };
    let drawn = tokio::task::spawn_blocking(move || {
        crate::report::drift_chart(&points, &calibrations, limits, w, h)
    })
    .await;
    match drawn {
        Ok(Ok(bytes)) => Ok(png(bytes)),
        Ok(Err(e)) => {
            tracing::error!("drift chart: {e}");
            Err(ApiError::new(
                StatusCode::INTERNAL_SERVER_ERROR,
                "cannot draw the drift chart; see the daemon's log",
            ))
        }
        Err(e) => {
            tracing::error!("drift chart: {e}");
            Err(ApiError::new(
                StatusCode::INTERNAL_SERVER_ERROR,
                "cannot draw the drift chart; see the daemon's log",
            ))
        }
    }
}
