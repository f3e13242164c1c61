//! The routes that start or stop runs (token required): calibrate, calibrate accepting a
//! change, check, cancel.

use std::net::SocketAddr;

use axum::extract::{ConnectInfo, State};
use axum::http::{HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde_json::json;

use super::access::authorize;
use super::{ApiError, AppState};
use crate::daemon::Refusal;
use crate::record::Trigger;
use crate::run::RunMode;

pub(super) async fn calibrate(
    State(state): State<AppState>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    start(&state, &headers, peer, RunMode::Calibrate, None)
}

/// `POST /api/calibrate/accept-change`: a calibration that accepts a result beyond
/// `gate.max_change_*` (the camera was remounted on purpose). The record says who: `web page
/// (ADDR)` when the page sent it (header `X-Handeye-Client: page`), else `api client ADDR`.
pub(super) async fn accept_change(
    State(state): State<AppState>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let from_page = headers
        .get("x-handeye-client")
        .is_some_and(|v| v.as_bytes() == b"page");
    let by = if from_page {
        format!("web page ({})", peer.ip())
    } else {
        format!("api client {}", peer.ip())
    };
    start(&state, &headers, peer, RunMode::Calibrate, Some(by))
}

pub(super) async fn check(
    State(state): State<AppState>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    start(&state, &headers, peer, RunMode::Check, None)
}

/// `POST /api/calibrate` and `/api/check`: 202 with the run id, 409 when a run is going.
fn start(
    state: &AppState,
    headers: &HeaderMap,
    peer: SocketAddr,
    mode: RunMode,
    accept_change: Option<String>,
) -> Result<Response, ApiError> {
    let what = match (mode, &accept_change) {
        (RunMode::Calibrate, Some(_)) => "POST /api/calibrate/accept-change",
        (RunMode::Calibrate, None) => "POST /api/calibrate",
        (RunMode::Check, _) => "POST /api/check",
    };
    authorize(state, headers, peer, what)?;
    let asked = match accept_change {
        Some(by) => state.handle.request_accepting_change(Trigger::Api, by),
        None => state.handle.request(mode, Trigger::Api),
    };
    match asked {
        Ok(run_id) => {
            tracing::info!(%peer, run_id = %run_id, "{what}: run accepted");
            Ok((StatusCode::ACCEPTED, Json(json!({ "run_id": run_id }))).into_response())
        }
        Err(e @ (Refusal::Busy { .. } | Refusal::QueueFull { .. })) => {
            Err(ApiError::new(StatusCode::CONFLICT, e.to_string()))
        }
        Err(e @ Refusal::StorageUnusable(_)) => Err(ApiError::new(
            StatusCode::INSUFFICIENT_STORAGE,
            e.to_string(),
        )),
        Err(e) => Err(ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            e.to_string(),
        )),
    }
}

pub(super) async fn cancel(
    State(state): State<AppState>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    authorize(&state, &headers, peer, "POST /api/cancel")?;
    let cancelled = state.handle.cancel();
    if cancelled {
        tracing::warn!(%peer, "run cancelled through the API");
    }
    Ok(Json(json!({ "cancelled": cancelled })).into_response())
}
