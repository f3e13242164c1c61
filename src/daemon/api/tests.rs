//! The API over a daemon on the hal fakes (HTTP on a free port: tokens, limits, routes), and
//! its parsers and token files.

use std::f64::consts::FRAC_PI_2;
use std::net::{IpAddr, Ipv4Addr, TcpListener};
use std::sync::OnceLock;
use std::time::Duration;

use crate::config::{self, RobotPorts, ViewTargets};
use crate::model::RobotModel;
use handeye_hal::fake::{FakeCamera, FakeRobot};
use handeye_hal::ur_dh::UrModel;
use handeye_hal::{CameraInfo, CaptureSettings, DepthCamera, HalError, PointCloud};
use serde_json::Value;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::Semaphore;

use super::access::token_matches;
use super::drift::chart_size;
use super::history::{runs_query, DEFAULT_RUNS};
use super::*;
use crate::record::Trigger;
use crate::run::RunMode;
use serde_json::json;

/// The UR home pose: upright, clear of everything; the arm starts and looks from here.
const HOME: [f64; 6] = [0.0, -FRAC_PI_2, FRAC_PI_2, -FRAC_PI_2, -FRAC_PI_2, 0.0];
const TOKEN: &str = "0123456789abcdef0123456789abcdef";

fn model() -> Option<Arc<RobotModel>> {
    static MODEL: OnceLock<Option<Arc<RobotModel>>> = OnceLock::new();
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/robots/ur/ur5e/ur5e.urdf");
    let m = MODEL
        .get_or_init(|| {
            path.exists()
                .then(|| Arc::new(RobotModel::load(&path).expect("UR5e model loads")))
        })
        .clone();
    if m.is_none() {
        assert!(
            std::env::var_os("CI").is_none(),
            "{} is missing and CI is set",
            path.display()
        );
        crate::skips::record(
            "daemon::api::tests",
            &format!("{} not found; the API tests need it", path.display()),
        );
    }
    m
}

fn scratch(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("handeye-api-{}-{tag}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("scratch dir");
    dir
}

fn free_port() -> SocketAddr {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
}

fn test_config(storage: &Path) -> Config {
    let mut cfg = config::sim_rig(
        IpAddr::V4(Ipv4Addr::LOCALHOST),
        RobotPorts::UR_STANDARD,
        "127.0.0.1".into(),
        storage.to_path_buf(),
    );
    // A view away from the start (a view at the start joints needs no move at all).
    let mut view = HOME;
    view[0] += 0.3;
    cfg.views.targets = ViewTargets::Joints(vec![view]);
    cfg.camera.settle = Duration::from_millis(10);
    cfg
}

/// A camera with nothing to replay whose captures wait for a permit, so a test decides
/// when the run in progress ends.
#[derive(Debug, Clone)]
struct GatedCamera {
    inner: FakeCamera,
    gate: Arc<Semaphore>,
}

impl DepthCamera for GatedCamera {
    async fn info(&self) -> Result<CameraInfo, HalError> {
        self.inner.info().await
    }

    async fn capture(&self, settings: &CaptureSettings) -> Result<Vec<PointCloud>, HalError> {
        let _permit = self.gate.acquire().await;
        self.inner.capture(settings).await
    }
}

/// A daemon over the fakes with the API on a free port, as a test sees it.
struct Rig {
    addr: SocketAddr,
    robot: FakeRobot,
    /// Permits for the camera's captures (none at first: a run waits at its capture).
    gate: Arc<Semaphore>,
}

/// Runs `body` against a daemon over the fakes (the API on a free port with `token`), then
/// stops the daemon and waits for it. The daemon runs on the test's task, joined with the
/// body: its future need not be `Send`.
async fn with_rig<F, Fut>(tag: &str, token: Option<&str>, body: F)
where
    F: FnOnce(Rig) -> Fut,
    Fut: std::future::Future<Output = ()>,
{
    let Some(model) = model() else {
        return;
    };
    let dir = scratch(tag);
    let cfg = test_config(&dir);
    let store = Arc::new(Store::open(&dir.join("history.sqlite")).expect("store"));
    let robot = FakeRobot::new(UrModel::Ur5e, HOME);
    let gate = Arc::new(Semaphore::new(0));
    let camera = GatedCamera {
        inner: FakeCamera::new(Vec::new()),
        gate: Arc::clone(&gate),
    };
    let addr = free_port();
    let api = Api::new(addr, token.map(String::from));
    let shutdown = CancellationToken::new();
    let daemon = crate::daemon::run(
        cfg,
        model,
        robot.clone(),
        camera,
        store,
        api,
        shutdown.clone(),
        |_| {},
    );
    let test = async {
        let mut listening = false;
        for _ in 0..200 {
            if tokio::net::TcpStream::connect(addr).await.is_ok() {
                listening = true;
                break;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        assert!(listening, "the API never listened on {addr}");
        body(Rig {
            addr,
            robot,
            gate: Arc::clone(&gate),
        })
        .await;
        gate.add_permits(100);
        shutdown.cancel();
    };
    tokio::time::timeout(Duration::from_secs(120), async {
        tokio::join!(daemon, test)
    })
    .await
    .expect("the test and the daemon's stop take less than 2 min");
}

impl Rig {
    async fn get(&self, path: &str) -> Answer {
        http(self.addr, "GET", path, &[]).await
    }

    async fn post(&self, path: &str, token: Option<&str>) -> Answer {
        match token {
            Some(t) => {
                let bearer = format!("Bearer {t}");
                http(self.addr, "POST", path, &[("Authorization", &bearer)]).await
            }
            None => http(self.addr, "POST", path, &[]).await,
        }
    }

    /// Waits for the daemon to be idle again; its status.
    async fn idle(&self) -> Value {
        for _ in 0..200 {
            let st = self.get("/api/status").await.json();
            if st["state"] == "idle" {
                return st;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        panic!("the run never ended");
    }
}

/// Issue 23: charts, pictures and exports are limited per client: a burst, then 429 with
/// `Retry-After`; the other routes and the other clients are not affected.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_23_expensive_routes_are_rate_limited_per_client() {
    with_rig("rate-limit", None, |rig| async move {
        let burst = crate::daemon::listener::RateLimit::BURST as usize;
        for k in 0..burst {
            // (JSON: this client reads answers as text.)
            let a = rig.get("/api/drift").await;
            assert_eq!(a.code, 200, "request {k}: {}", a.body);
        }
        let a = rig.get("/api/drift.png?width=2000&height=2000").await;
        assert_eq!(a.code, 429, "{}", a.body);
        assert!(a.header("retry-after").is_some(), "{}", a.head);
        assert!(a.json()["error"].as_str().unwrap_or("").contains("wait"));
        assert_eq!(rig.get("/api/drift").await.code, 429);
        assert_eq!(rig.get("/api/status").await.code, 200);
        tokio::time::sleep(Duration::from_secs_f64(
            1.1 / crate::daemon::listener::RateLimit::PER_SECOND,
        ))
        .await;
        assert_eq!(rig.get("/api/drift").await.code, 200, "refilled");
    })
    .await;
}

#[derive(Debug)]
struct Answer {
    code: u16,
    head: String,
    body: String,
}

impl Answer {
    fn json(&self) -> Value {
        serde_json::from_str(&self.body).unwrap_or_else(|e| panic!("not JSON ({e}): {}", self.body))
    }

    fn header(&self, name: &str) -> Option<&str> {
        self.head.lines().find_map(|l| {
            let (n, v) = l.split_once(':')?;
            n.eq_ignore_ascii_case(name).then(|| v.trim())
        })
    }
}

/// One HTTP/1.1 request without a body on a fresh connection (`Content-Length: 0` unless
/// `headers` say otherwise).
async fn http(addr: SocketAddr, method: &str, path: &str, headers: &[(&str, &str)]) -> Answer {
    let mut s = tokio::net::TcpStream::connect(addr).await.expect("connect");
    let mut req = format!("{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n");
    if !headers
        .iter()
        .any(|(n, _)| n.eq_ignore_ascii_case("content-length"))
    {
        req += "Content-Length: 0\r\n";
    }
    for (name, value) in headers {
        req += &format!("{name}: {value}\r\n");
    }
    req += "\r\n";
    s.write_all(req.as_bytes()).await.expect("send");
    let mut raw = String::new();
    tokio::time::timeout(Duration::from_secs(10), s.read_to_string(&mut raw))
        .await
        .expect("answer in time")
        .expect("read");
    let (head, body) = raw.split_once("\r\n\r\n").expect("HTTP answer");
    let code = head
        .split(' ')
        .nth(1)
        .and_then(|c| c.parse().ok())
        .expect("status code");
    Answer {
        code,
        head: head.to_string(),
        body: body.to_string(),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn api_moves_the_arm_only_with_the_token_one_run_at_a_time() {
    with_rig("token", Some(TOKEN), |rig| async move {
        let st = rig.get("/api/status").await;
        assert_eq!(st.code, 200, "{st:?}");
        assert_eq!(st.json()["state"], "idle");

        // No token, a wrong one, another scheme: 401 with a challenge, nothing moves.
        for token in [None, Some("wrong"), Some(&TOKEN[..TOKEN.len() - 1])] {
            let a = rig.post("/api/calibrate", token).await;
            assert_eq!(a.code, 401, "{a:?}");
            assert!(a
                .header("www-authenticate")
                .is_some_and(|v| v.starts_with("Bearer")));
            assert!(a.json()["error"]
                .as_str()
                .is_some_and(|e| e.contains("token")));
            let a = rig.post("/api/check", token).await;
            assert_eq!(a.code, 401, "{a:?}");
            let a = rig.post("/api/cancel", token).await;
            assert_eq!(a.code, 401, "{a:?}");
        }
        let basic = http(
            rig.addr,
            "POST",
            "/api/calibrate",
            &[("Authorization", "Basic dTpw")],
        )
        .await;
        assert_eq!(basic.code, 401, "{basic:?}");
        // A body larger than the limit is refused before any handler runs.
        let big = http(
            rig.addr,
            "POST",
            "/api/calibrate",
            &[("Content-Length", "100000")],
        )
        .await;
        assert_eq!(big.code, 413, "{big:?}");
        assert!(rig.robot.moves().is_empty(), "moved without a token");
        assert_eq!(rig.get("/api/status").await.json()["state"], "idle");

        // The token: accepted; a second trigger at once is refused busy.
        let a = rig.post("/api/calibrate", Some(TOKEN)).await;
        assert_eq!(a.code, 202, "{a:?}");
        let run_id = a.json()["run_id"].as_str().expect("run id").to_string();
        let busy = rig.post("/api/check", Some(TOKEN)).await;
        assert_eq!(busy.code, 409, "{busy:?}");
        let msg = busy.json()["error"].as_str().expect("error").to_string();
        assert!(msg.contains("busy") && msg.contains(&run_id), "{msg}");
        let st = rig.get("/api/status").await.json();
        assert_eq!(st["state"], "running");
        assert_eq!(st["current"]["run_id"], run_id.as_str());
        assert_eq!(st["current"]["trigger"], "api");

        // The capture fails (no clouds): the run ends in error and is in the history.
        rig.gate.add_permits(1);
        let st = rig.idle().await;
        assert_eq!(st["last"]["run_id"], run_id.as_str());
        assert_eq!(st["last"]["outcome"], "error");
        assert!(
            !rig.robot.moves().is_empty(),
            "the accepted run moved the arm"
        );

        let runs = rig.get("/api/runs").await;
        assert_eq!(runs.code, 200, "{runs:?}");
        let runs = runs.json();
        let listed = runs["runs"].as_array().expect("runs");
        assert_eq!(listed.len(), 1, "{runs}");
        assert_eq!(listed[0]["run_id"], run_id.as_str());
        assert_eq!(listed[0]["outcome"], "error");
        assert_eq!(
            listed[0]["verdict"], "error",
            "the one word every view uses"
        );
        let record = rig.get(&format!("/api/runs/{run_id}")).await;
        assert_eq!(record.code, 200, "{record:?}");
        assert_eq!(record.json()["run_id"], run_id.as_str());
        assert_eq!(rig.get("/api/runs/nope").await.code, 404);
        // No accepted calibration yet.
        let latest = rig.get("/api/latest").await;
        assert_eq!(latest.code, 404, "{latest:?}");
        assert!(latest.json()["error"].as_str().is_some());

        // Paging and bad numbers.
        let page = rig.get("/api/runs?limit=1&before=1").await.json();
        assert_eq!(page["runs"].as_array().map(Vec::len), Some(0));
        for bad in [
            "limit=0",
            "limit=1001",
            "limit=x",
            "before=-1",
            "before=nan",
            "lmit=3",
        ] {
            let a = rig.get(&format!("/api/runs?{bad}")).await;
            assert_eq!(a.code, 400, "{bad}: {a:?}");
            assert!(a.json()["error"].is_string());
        }

        // Cancel with nothing running.
        let a = rig.post("/api/cancel", Some(TOKEN)).await;
        assert_eq!(a.code, 200, "{a:?}");
        assert_eq!(a.json()["cancelled"], false);

        let m = rig.get("/metrics").await;
        assert_eq!(m.code, 200);
        assert!(m
            .header("content-type")
            .is_some_and(|c| c.starts_with("text/plain; version=0.0.4")));
        assert!(
            m.body
                .contains("handeye_runs_total{trigger=\"api\",outcome=\"error\"} 1"),
            "{}",
            m.body
        );

        let page = rig.get("/").await;
        assert_eq!(page.code, 200);
        assert!(page
            .header("content-type")
            .is_some_and(|c| c.starts_with("text/html")));
        assert!(page.header("content-security-policy").is_some());
        assert!(page.body.contains("/app.js"), "{}", page.body);
        for asset in ["/app.js", "/app.css", "/favicon.svg"] {
            assert_eq!(rig.get(asset).await.code, 200, "{asset}");
        }
        let drift = rig.get("/api/drift").await.json();
        assert_eq!(drift["checks"], json!([]), "{drift}");
        assert_eq!(drift["max_translation_mm"], 1.0);
        // No storage behind this API, and a run that ended in error has no result.
        let a = rig.get(&format!("/api/runs/{run_id}/report.png")).await;
        assert_eq!(a.code, 404, "{a:?}");
        assert_eq!(rig.get("/api/runs/..%2F..%2Fx/report.png").await.code, 404);
        let a = rig.get(&format!("/api/runs/{run_id}/exports")).await;
        assert_eq!(a.code, 404, "{a:?}");
        assert!(a.json()["error"]
            .as_str()
            .is_some_and(|e| e.contains("no result")));
        assert_eq!(rig.get("/api/drift.png?width=5").await.code, 400);
        let a = rig.get("/api/nothing").await;
        assert_eq!(a.code, 404);
        assert!(a.json()["error"].is_string());
        let a = rig.get("/api/calibrate").await;
        assert_eq!(a.code, 405);
        assert!(a.json()["error"]
            .as_str()
            .is_some_and(|e| e.contains("POST")));
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn api_cancels_the_run_in_progress() {
    with_rig("cancel", Some(TOKEN), |rig| async move {
        let a = rig.post("/api/check", Some(TOKEN)).await;
        assert_eq!(a.code, 202, "{a:?}");
        let a = rig.post("/api/cancel", Some(TOKEN)).await;
        assert_eq!(a.json()["cancelled"], true);
        let st = rig.idle().await;
        assert_eq!(st["last"]["mode"], "check");
        assert_eq!(st["last"]["outcome"], "aborted", "{st}");
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn without_a_token_nothing_moves_the_arm() {
    with_rig("no-token", None, |rig| async move {
        for path in ["/api/calibrate", "/api/check", "/api/cancel"] {
            for token in [None, Some(TOKEN)] {
                let a = rig.post(path, token).await;
                assert_eq!(a.code, 403, "{path}: {a:?}");
                assert_eq!(a.json()["error"], NO_TOKEN);
            }
        }
        assert_eq!(rig.get("/api/status").await.json()["state"], "idle");
        assert!(rig.robot.moves().is_empty());
    })
    .await;
}

/// Issue 36: wrong tokens are limited per client (14 500 tries/s were answered before);
/// past the limit even the right token waits for the next window.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn issue_36_wrong_tokens_are_rate_limited_per_client() {
    with_rig("auth-limit", Some(TOKEN), |rig| async move {
        let wrong = "not-the-token-0123456789";
        for k in 0..AuthLimit::MAX_FAILURES {
            let a = rig.post("/api/cancel", Some(wrong)).await;
            assert_eq!(a.code, 401, "try {k}: {a:?}");
        }
        for token in [wrong, TOKEN] {
            let a = rig.post("/api/cancel", Some(token)).await;
            assert_eq!(a.code, 429, "{a:?}");
            assert!(a.header("retry-after").is_some(), "{}", a.head);
        }
        assert_eq!(rig.get("/api/status").await.code, 200);
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_taken_port_is_reported_and_serve_returns() {
    let Some(model) = model() else {
        return;
    };
    let taken = TcpListener::bind("127.0.0.1:0").expect("bind");
    let addr = taken.local_addr().expect("addr");
    let dir = scratch("taken");
    let store = Arc::new(Store::open(&dir.join("history.sqlite")).expect("store"));
    let shutdown = CancellationToken::new();
    let (tx, rx) = tokio::sync::oneshot::channel();
    let daemon = crate::daemon::run(
        test_config(&dir),
        model,
        FakeRobot::new(UrModel::Ur5e, HOME),
        FakeCamera::new(Vec::new()),
        store,
        Api::new(addr, Some(TOKEN.into())),
        shutdown.clone(),
        move |h| {
            let _ = tx.send(h.clone());
        },
    );
    let test = async {
        let handle = rx.await.expect("ready");
        // The daemon runs on without its API.
        tokio::time::sleep(Duration::from_millis(300)).await;
        assert_eq!(handle.status().state, crate::daemon::DaemonState::Idle);
        assert!(handle.request(RunMode::Check, Trigger::Api).is_ok());
        shutdown.cancel();
    };
    tokio::time::timeout(Duration::from_secs(60), async {
        tokio::join!(daemon, test)
    })
    .await
    .expect("the daemon stops");
    drop(taken);
}

#[test]
fn tokens_compare_whole() {
    assert!(token_matches(b"abc", b"abc"));
    assert!(!token_matches(b"abc", b"abd"));
    assert!(!token_matches(b"abc", b"ab"));
    assert!(!token_matches(b"abc", b"abcd"));
    assert!(!token_matches(b"abc", b""));
}

#[test]
fn report_paths_and_chart_sizes_are_checked() {
    assert_eq!(chart_size(None), Ok((900, 340)));
    assert_eq!(
        chart_size(Some("width=1200&height=400&t=17")),
        Ok((1200, 400))
    );
    assert!(chart_size(Some("width=100")).is_err());
    assert!(chart_size(Some("height=99999")).is_err());
    assert!(chart_size(Some("depth=3")).is_err());
}

#[test]
fn runs_query_defaults_and_bounds() {
    assert_eq!(runs_query(None), Ok((DEFAULT_RUNS, None)));
    assert_eq!(runs_query(Some("")), Ok((DEFAULT_RUNS, None)));
    assert_eq!(
        runs_query(Some("limit=1000&before=1700000000.5")),
        Ok((1000, Some(1_700_000_000.5)))
    );
    assert!(runs_query(Some("limit=1001")).is_err_and(|e| e.contains("1 to 1000")));
    assert!(runs_query(Some("before=x")).is_err_and(|e| e.contains("unix time")));
}

#[cfg(unix)]
#[test]
fn token_files_are_checked() {
    use std::os::unix::fs::PermissionsExt;
    let dir = scratch("token-files");
    let mut cfg = test_config(&dir);
    let file = dir.join("token");
    let write = |text: &str, mode: u32| {
        std::fs::write(&file, text).expect("write");
        std::fs::set_permissions(&file, std::fs::Permissions::from_mode(mode)).expect("chmod");
    };

    // None configured: the API runs, refusing what moves the arm.
    let api = Api::from_config_with(&cfg, None).expect("no token is allowed");
    assert!(api.token.is_none());

    cfg.daemon.token_file = Some(file.clone());
    write(&format!("  {TOKEN}\n"), 0o600);
    let api = Api::from_config_with(&cfg, None).expect("a private token file");
    assert_eq!(api.token.as_deref(), Some(TOKEN));
    assert!(!format!("{api:?}").contains(TOKEN), "Debug shows the token");

    write(TOKEN, 0o644);
    let e = format!(
        "{:#}",
        Api::from_config_with(&cfg, None).expect_err("0644 is refused")
    );
    assert!(
        e.contains("chmod 600") && e.contains(&file.display().to_string()),
        "{e}"
    );
    write(TOKEN, 0o640);
    assert!(Api::from_config_with(&cfg, None).is_err());

    write(" \n", 0o600);
    let e = format!(
        "{:#}",
        Api::from_config_with(&cfg, None).expect_err("empty")
    );
    assert!(e.contains("empty"), "{e}");
    write("two words, both long enough", 0o600);
    assert!(Api::from_config_with(&cfg, None).is_err());
    // Issue 23: a 1-character token is refused, saying how long and how to make one.
    write("x", 0o600);
    let e = format!(
        "{:#}",
        Api::from_config_with(&cfg, None).expect_err("short")
    );
    assert!(
        e.contains("at least 16 random ones, e.g.") && e.contains("openssl rand"),
        "{e}"
    );
    // Issue 23: a FIFO as token file is refused at once, not waited on.
    let fifo = dir.join("token.fifo");
    let made = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .expect("mkfifo runs");
    assert!(made.success());
    std::fs::set_permissions(&fifo, std::fs::Permissions::from_mode(0o600)).expect("chmod");
    cfg.daemon.token_file = Some(fifo.clone());
    let t = std::time::Instant::now();
    let e = format!("{:#}", Api::from_config_with(&cfg, None).expect_err("FIFO"));
    assert!(e.contains("FIFO"), "{e}");
    assert!(t.elapsed() < Duration::from_secs(1), "{:?}", t.elapsed());
    cfg.daemon.token_file = Some(file.clone());

    cfg.daemon.token_file = Some(dir.join("missing"));
    assert!(Api::from_config_with(&cfg, None).is_err());

    // systemd's credential wins over the file; its mode is systemd's business (an ACL
    // shows as group bits).
    let creds = dir.join("credentials");
    std::fs::create_dir_all(&creds).expect("dir");
    let cred = creds.join("token");
    std::fs::write(&cred, "from-systemd-0123456789\n").expect("write");
    std::fs::set_permissions(&cred, std::fs::Permissions::from_mode(0o440)).expect("chmod");
    let api = Api::from_config_with(&cfg, Some(&creds)).expect("credential");
    assert_eq!(api.token.as_deref(), Some("from-systemd-0123456789"));
    // A credentials directory without `token` falls back to the file.
    cfg.daemon.token_file = Some(file.clone());
    write(TOKEN, 0o600);
    let api = Api::from_config_with(&cfg, Some(&dir.join("other"))).expect("file");
    assert_eq!(api.token.as_deref(), Some(TOKEN));
}
