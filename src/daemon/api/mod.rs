//! The daemon's HTTP API (axum) and its web page: the [`Frontend`] `handeye daemon` starts
//! with its handle.
//!
//! JSON everywhere; every error is `{"error": "..."}` saying what to do. Reading is open to
//! whoever can reach `daemon.listen` (localhost by default); anything that moves the arm
//! (`/api/calibrate`, `/api/check`) or stops it (`/api/cancel`) needs
//! `Authorization: Bearer <token>` with the token from `daemon.token_file` (or the systemd
//! credential `token`). Without a configured token those requests are refused outright. A
//! client refused 20 times in 10 s (`AuthLimit`) gets 429 for them
//! until the window ends. The local CLI's cancel does not depend on this API at all
//! ([`crate::daemon::control`]).
//!
//! | route | what |
//! |---|---|
//! | `GET /api/status` | what the daemon is doing ([`crate::daemon::Status`]) |
//! | `POST /api/calibrate`, `POST /api/check` | token; 202 `{"run_id"}`, 409 when busy |
//! | `POST /api/cancel` | token; `{"cancelled": bool}` |
//! | `GET /api/runs?limit=N&before=UNIX_S` | the history, newest first |
//! | `GET /api/runs/{id}` | one run's record |
//! | `GET /api/latest` | the record of the latest accepted calibration |
//! | `GET /api/runs/{id}/report.png` | the run's report picture |
//! | `GET /api/runs/{id}/exports` | the run's result as ROS arguments, URDF joint, tf YAML |
//! | `GET /api/drift`, `GET /api/drift.png` | every check's drift and the thresholds; as a chart |
//! | `GET /metrics` | Prometheus text format |
//! | `GET /` (and `/app.js`, `/app.css`, `/favicon.svg`) | the web page, embedded in the binary |

mod access;
mod drift;
mod history;
mod page;
#[cfg(test)]
mod tests;
mod trigger;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::config::Config;
use crate::daemon::listener::{AuthLimit, RateLimit};
use crate::daemon::{DaemonHandle, Frontend};
use crate::report::DriftLimits;
use crate::store::Store;
use access::{rate_limited, read_token, refuse_large_bodies};
use axum::extract::{DefaultBodyLimit, State};
use axum::http::{header, HeaderValue, Method, StatusCode, Uri};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use drift::{drift, drift_png};
use history::{exports, latest, report_picture, run_record, runs};
use page::{app_css, app_js, favicon, index};
use tokio_util::sync::CancellationToken;
use trigger::{accept_change, calibrate, cancel, check};

/// Largest request body accepted, bytes. No route reads a body; this only stops a client from
/// making the server buffer one.
const BODY_LIMIT: usize = 4096;
/// The refusal when no token is configured.
const NO_TOKEN: &str =
    "no API token configured (daemon.token_file); nothing that moves the arm is accepted";
/// The shortest API token accepted (a short one is guessed by trying).
pub const MIN_TOKEN_CHARS: usize = 16;
/// Drift charts drawn at once (the others wait).
const CHARTS_AT_ONCE: usize = 2;

/// What the page and the pictures read besides the daemon: the run folders and the drift
/// thresholds.
#[derive(Debug, Clone)]
pub struct Site {
    /// `storage.dir`: run folders hold the report pictures (`runs/<id>/report.png`).
    storage: Option<PathBuf>,
    /// `[check]`'s thresholds, drawn in the drift chart.
    drift_limits: DriftLimits,
}

impl Default for Site {
    fn default() -> Site {
        Site {
            storage: None,
            drift_limits: DriftLimits {
                translation_mm: 1.0,
                rotation_deg: 0.2,
            },
        }
    }
}

/// The HTTP API: where it listens and the token that requests which move the arm must carry.
pub struct Api {
    listen: SocketAddr,
    token: Option<String>,
    site: Site,
}

impl std::fmt::Debug for Api {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Api")
            .field("listen", &self.listen)
            .field("token", &self.token.as_ref().map(|_| "<redacted>"))
            .field("site", &self.site)
            .finish()
    }
}

impl Api {
    /// The API on `listen`; `token: None` refuses everything that moves the arm.
    pub fn new(listen: SocketAddr, token: Option<String>) -> Api {
        Api {
            listen,
            token,
            site: Site::default(),
        }
    }

    /// The same API serving the report pictures from `storage` (the configuration's
    /// `storage.dir`) and drawing `drift_limits` in the drift chart.
    pub fn with_site(mut self, storage: PathBuf, drift_limits: DriftLimits) -> Api {
        self.site = Site {
            storage: Some(storage),
            drift_limits,
        };
        self
    }

    /// The API as configured: `daemon.listen`, and the token from `$CREDENTIALS_DIRECTORY/token`
    /// when systemd passes one (`LoadCredential=token:/etc/handeye/token`), else from
    /// `daemon.token_file`. Refuses an empty token, or (Unix) a token file that group or others
    /// can access.
    pub fn from_config(cfg: &Config) -> anyhow::Result<Api> {
        let credentials = std::env::var_os("CREDENTIALS_DIRECTORY").map(PathBuf::from);
        Api::from_config_with(cfg, credentials.as_deref())
    }

    /// The token that authorises requests that move or stop the arm (`handeye cancel` sends
    /// it); `None` when none is configured.
    pub fn token(&self) -> Option<&str> {
        self.token.as_deref()
    }

    /// [`Api::from_config`] with the credentials directory given (tests).
    fn from_config_with(cfg: &Config, credentials: Option<&Path>) -> anyhow::Result<Api> {
        let listen = cfg.daemon.listen;
        // systemd makes its credentials readable by the service alone (mode 0400, or an ACL
        // that shows as group bits), so only the configured file's mode is checked.
        let credential = credentials
            .map(|dir| dir.join("token"))
            .filter(|p| p.exists());
        let (path, check_mode) = match (credential, &cfg.daemon.token_file) {
            (Some(p), _) => (Some(p), false),
            (None, file) => (file.clone(), true),
        };
        let token = match &path {
            Some(p) => Some(read_token(p, check_mode)?),
            None => None,
        };
        match &path {
            Some(p) => tracing::info!("API token from {}", p.display()),
            None => tracing::warn!(
                "{NO_TOKEN}: POST /api/calibrate, /api/check and /api/cancel are refused"
            ),
        }
        if !listen.ip().is_loopback() {
            tracing::warn!(
                "the HTTP API listens on {listen}, reachable from the network (daemon.listen)"
            );
        }
        Ok(Api::new(listen, token).with_site(
            cfg.storage.dir.clone(),
            DriftLimits {
                translation_mm: cfg.check.max_drift_translation_mm,
                rotation_deg: cfg.check.max_drift_rotation_deg,
            },
        ))
    }
}

impl Frontend for Api {
    async fn serve(self, handle: DaemonHandle, shutdown: CancellationToken) {
        let listener = match tokio::net::TcpListener::bind(self.listen).await {
            Ok(l) => l,
            Err(e) => {
                let hint = if e.kind() == std::io::ErrorKind::AddrInUse {
                    "another program (another handeye daemon?) uses that port; stop it or set \
                     another daemon.listen"
                } else {
                    "check daemon.listen"
                };
                tracing::error!(
                    "cannot serve the HTTP API on {}: {e}; {hint}. The daemon runs on without \
                     its API and web page",
                    self.listen
                );
                return;
            }
        };
        match listener.local_addr() {
            Ok(addr) => tracing::info!("HTTP API on http://{addr}/"),
            Err(e) => tracing::warn!("HTTP API listening, address unknown: {e}"),
        }
        let app = router(handle, self.token, self.site);
        super::listener::serve(listener, app, shutdown).await;
    }
}
/// What every handler shares.
#[derive(Clone)]
struct AppState {
    handle: DaemonHandle,
    token: Option<Arc<str>>,
    site: Arc<Site>,
    /// Each client's allowance on the routes that read files or draw ([`rate_limited`]).
    rate: Arc<RateLimit>,
    /// Each client's refused tokens ([`authorize`](access::authorize)).
    auth: Arc<AuthLimit>,
    /// Charts drawn at once (each holds its pixels: up to 16 MB at the largest size).
    charts: Arc<tokio::sync::Semaphore>,
}

/// The API's routes over `handle`; `token: None` refuses everything that moves the arm.
pub fn router(handle: DaemonHandle, token: Option<String>, site: Site) -> Router {
    let state = AppState {
        handle,
        token: token.map(Arc::from),
        site: Arc::new(site),
        rate: Arc::new(RateLimit::default()),
        auth: Arc::new(AuthLimit::default()),
        charts: Arc::new(tokio::sync::Semaphore::new(CHARTS_AT_ONCE)),
    };
    // The routes that read a run's files, the history or draw: limited per client.
    let expensive = Router::new()
        .route("/api/runs/{id}/report.png", get(report_picture))
        .route("/api/runs/{id}/exports", get(exports))
        .route("/api/drift", get(drift))
        .route("/api/drift.png", get(drift_png))
        .route_layer(axum::middleware::from_fn_with_state(
            state.clone(),
            rate_limited,
        ));
    Router::new()
        .route("/", get(index))
        .route("/app.js", get(app_js))
        .route("/app.css", get(app_css))
        .route("/favicon.svg", get(favicon))
        .merge(expensive)
        .route("/api/status", get(status))
        .route("/api/calibrate", post(calibrate))
        .route("/api/calibrate/accept-change", post(accept_change))
        .route("/api/check", post(check))
        .route("/api/cancel", post(cancel))
        .route("/api/runs", get(runs))
        .route("/api/runs/{id}", get(run_record))
        .route("/api/latest", get(latest))
        .route("/metrics", get(metrics))
        .fallback(not_found)
        .method_not_allowed_fallback(method_not_allowed)
        .layer(DefaultBodyLimit::max(BODY_LIMIT))
        .layer(axum::middleware::from_fn(refuse_large_bodies))
        .with_state(state)
}

/// The body of every error answer: what went wrong and what to do.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct ErrorBody {
    /// One sentence for the operator.
    pub error: String,
}

/// An error answer: `{"error": message}` with a status.
#[derive(Debug)]
struct ApiError {
    status: StatusCode,
    message: String,
    /// `WWW-Authenticate` value for 401s.
    challenge: Option<&'static str>,
    /// `Retry-After`, s.
    retry_after_s: Option<u64>,
}

impl ApiError {
    fn new(status: StatusCode, message: impl Into<String>) -> ApiError {
        ApiError {
            status,
            message: message.into(),
            challenge: None,
            retry_after_s: None,
        }
    }

    fn unauthorized(message: &str, challenge: &'static str) -> ApiError {
        ApiError {
            challenge: Some(challenge),
            ..ApiError::new(StatusCode::UNAUTHORIZED, message)
        }
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let body = ErrorBody {
            error: self.message,
        };
        let mut resp = (self.status, Json(body)).into_response();
        if let Some(c) = self.challenge {
            resp.headers_mut()
                .insert(header::WWW_AUTHENTICATE, HeaderValue::from_static(c));
        }
        if let Some(s) = self.retry_after_s {
            if let Ok(v) = HeaderValue::from_str(&s.to_string()) {
                resp.headers_mut().insert(header::RETRY_AFTER, v);
            }
        }
        resp
    }
}

/// A PNG answer; pictures of finished runs never change, charts do (`no-cache`).
fn png(bytes: Vec<u8>) -> Response {
    (
        [
            (header::CONTENT_TYPE, HeaderValue::from_static("image/png")),
            (header::CACHE_CONTROL, HeaderValue::from_static("no-cache")),
        ],
        bytes,
    )
        .into_response()
}

async fn status(State(state): State<AppState>) -> Response {
    Json(state.handle.status()).into_response()
}

/// Runs a (blocking, SQLite) store call off the runtime's workers.
async fn with_store<T: Send + 'static>(
    state: &AppState,
    call: impl FnOnce(&Store) -> anyhow::Result<T> + Send + 'static,
) -> Result<T, ApiError> {
    let store = Arc::clone(state.handle.store());
    match tokio::task::spawn_blocking(move || call(&store)).await {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => {
            tracing::error!("history: {e:#}");
            Err(ApiError::new(
                StatusCode::INTERNAL_SERVER_ERROR,
                format!("cannot read the history: {e:#}; see the daemon's log"),
            ))
        }
        Err(e) => {
            tracing::error!("history query failed: {e}");
            Err(ApiError::new(
                StatusCode::INTERNAL_SERVER_ERROR,
                "the history query failed; see the daemon's log",
            ))
        }
    }
}

async fn metrics(State(state): State<AppState>) -> Response {
    (
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("text/plain; version=0.0.4; charset=utf-8"),
        )],
        state.handle.metrics(),
    )
        .into_response()
}

async fn not_found(method: Method, uri: Uri) -> ApiError {
    ApiError::new(
        StatusCode::NOT_FOUND,
        format!("no route {method} {}; GET / lists the API", uri.path()),
    )
}

async fn method_not_allowed(method: Method, uri: Uri) -> ApiError {
    let hint = match uri.path() {
        "/api/calibrate" | "/api/check" | "/api/cancel" => "use POST",
        _ => "use GET",
    };
    ApiError::new(
        StatusCode::METHOD_NOT_ALLOWED,
        format!("{method} is not allowed on {}; {hint}", uri.path()),
    )
}
