//! The daemon's web page in a real browser: headless Chromium, driven through chromedriver's
//! WebDriver HTTP protocol (a few JSON requests written by hand, see README "Dependencies and
//! why"), against `handeye daemon` on `handeye sim rig` over loopback (127.0.0.140/141, issue
//! 38's remount 127.0.0.164/165; chromedriver listens on a free port of 127.0.0.1 it picks
//! itself).
//!
//! The page loads with the right state; Check without the token (or with a wrong one) is
//! refused with the server's reason and nothing moves; Check with the token runs a check, whose
//! history row and report picture appear; the token is asked once (Calibrate then goes straight
//! through, and Cancel stops it). `handeye solve --capture … --report` draws the recorded scan.
//! Screenshots go to `target/e2e-web/` (CI keeps them).

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{json, Value};

use crate::support::{
    joints, max_change, rig_config, run, secs, shared, skip, start_rig, Daemon, TempDir,
};

const TOKEN: &str = "web-e2e-secret-token";
const ROBOT_IP: &str = "127.0.0.140";
const CAMERA_IP: &str = "127.0.0.141";
/// WebDriver's key for an element reference.
const ELEMENT: &str = "element-6066-11e4-a52e-4f735466cecf";

/// `name` on the PATH.
fn which(name: &str) -> Option<PathBuf> {
    std::env::var_os("PATH")?
        .to_str()?
        .split(':')
        .map(|d| Path::new(d).join(name))
        .find(|p| p.is_file())
}

/// Chromium and chromedriver (Debian's `chromium`, `chromium-driver`), or `None` after SKIP;
/// under CI their absence fails.
fn browser_tools(test: &str) -> Option<(PathBuf, PathBuf)> {
    let found = which("chromium")
        .or_else(|| which("chromium-browser"))
        .zip(which("chromedriver"));
    if found.is_none() {
        assert!(
            std::env::var_os("CI").is_none(),
            "{test}: chromium/chromedriver are missing (CI is set, so this is a failure; \
             .ci/install.d/chromium.sh installs them)"
        );
        skip(&format!(
            "SKIP {test}: chromium and chromedriver not found (Debian `chromium`, \
             `chromium-driver`; .ci/install.d/chromium.sh)"
        ));
    }
    found
}

/// One HTTP/1.1 request with an optional JSON body on a fresh connection; (status, body).
/// The body is read by its `Content-Length` (chromedriver keeps connections open).
fn http(
    addr: SocketAddr,
    method: &str,
    path: &str,
    body: Option<&Value>,
    auth: Option<&str>,
) -> (u16, String) {
    let mut s = TcpStream::connect_timeout(&addr, Duration::from_secs(5))
        .unwrap_or_else(|e| panic!("connect {addr}: {e}"));
    s.set_read_timeout(Some(Duration::from_secs(60)))
        .expect("timeout");
    let body = body.map(Value::to_string).unwrap_or_default();
    let auth = auth.map_or(String::new(), |t| format!("Authorization: Bearer {t}\r\n"));
    write!(
        s,
        "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n{auth}\
         Content-Type: application/json; charset=utf-8\r\nContent-Length: {}\r\n\r\n{body}",
        body.len()
    )
    .expect("send");
    let mut reader = BufReader::new(s);
    let mut head = String::new();
    loop {
        let mut line = String::new();
        let n = reader
            .read_line(&mut line)
            .unwrap_or_else(|e| panic!("{method} {path}: reading the answer: {e}"));
        if n == 0 || line == "\r\n" {
            break;
        }
        head.push_str(&line);
    }
    let code = head
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    let header = |name: &str| {
        head.lines().find_map(|l| {
            let (n, v) = l.split_once(':')?;
            n.trim()
                .eq_ignore_ascii_case(name)
                .then(|| v.trim().to_string())
        })
    };
    let mut raw = Vec::new();
    match header("content-length").and_then(|v| v.parse::<usize>().ok()) {
        Some(n) => {
            raw.resize(n, 0);
            reader.read_exact(&mut raw).expect("the body");
        }
        None => {
            reader.read_to_end(&mut raw).expect("the body");
        }
    }
    let mut body = String::from_utf8_lossy(&raw).into_owned();
    if header("transfer-encoding").is_some_and(|v| v.eq_ignore_ascii_case("chunked")) {
        body = dechunk(&body);
    }
    (code, body)
}

fn dechunk(mut s: &str) -> String {
    let mut out = String::new();
    while let Some((size, rest)) = s.split_once("\r\n") {
        let n = usize::from_str_radix(size.trim(), 16).unwrap_or(0);
        if n == 0 || rest.len() < n {
            break;
        }
        out.push_str(&rest[..n]);
        s = rest[n..].trim_start_matches("\r\n");
    }
    out
}

fn base64(text: &str) -> Vec<u8> {
    let val = |c: u8| -> Option<u32> {
        Some(match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' => 62,
            b'/' => 63,
            _ => return None,
        } as u32)
    };
    let mut out = Vec::new();
    let (mut acc, mut bits) = (0u32, 0);
    for v in text.bytes().filter_map(val) {
        acc = (acc << 6) | v;
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    out
}

/// Width and height of a PNG (from its IHDR).
fn png_size(bytes: &[u8]) -> (u32, u32) {
    assert!(bytes.starts_with(b"\x89PNG\r\n\x1a\n"), "not a PNG");
    let be = |i: usize| u32::from_be_bytes([bytes[i], bytes[i + 1], bytes[i + 2], bytes[i + 3]]);
    (be(16), be(20))
}

/// `bytes` (Chromium's fast RGBA PNG) as an RGB PNG with 32 levels per channel at the highest
/// compression: screenshots small enough to keep (and to put in the README), no visible
/// difference on a screen.
fn recompress(bytes: &[u8]) -> Vec<u8> {
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .expect("a PNG");
    let mut buf = vec![0; reader.output_buffer_size().expect("size")];
    let info = reader.next_frame(&mut buf).expect("a frame");
    let rgb: Vec<u8> = match info.color_type {
        png::ColorType::Rgba => buf[..info.buffer_size()]
            .chunks_exact(4)
            .flat_map(|p| [p[0], p[1], p[2]])
            .collect(),
        png::ColorType::Rgb => buf[..info.buffer_size()].to_vec(),
        _ => return bytes.to_vec(),
    };
    let rgb: Vec<u8> = rgb.iter().map(|v| (v & 0xf8) | (v >> 5)).collect();
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, info.width, info.height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::High);
    let mut w = enc.write_header().expect("header");
    w.write_image_data(&rgb).expect("pixels");
    w.finish().expect("finish");
    out
}

/// A chromedriver with one headless Chromium session; both end on drop.
struct Browser {
    driver: Child,
    addr: SocketAddr,
    session: String,
}

impl Browser {
    fn start(chromium: &Path, chromedriver: &Path, profile: &Path) -> Browser {
        let mut driver = Command::new(chromedriver)
            .arg("--port=0")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("spawn chromedriver");
        let out = driver.stdout.take().expect("stdout");
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                if let Some(port) = line
                    .split("started successfully on port ")
                    .nth(1)
                    .and_then(|p| p.trim_end_matches('.').trim().parse::<u16>().ok())
                {
                    let _ = tx.send(port);
                }
            }
        });
        let port = rx
            .recv_timeout(Duration::from_secs(20))
            .expect("chromedriver says its port");
        let addr = SocketAddr::from(([127, 0, 0, 1], port));
        let caps = json!({"capabilities": {"alwaysMatch": {
            "browserName": "chrome",
            "goog:chromeOptions": {
                "binary": chromium,
                "args": [
                    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                    "--no-first-run", "--disable-background-networking",
                    "--disable-component-update", "--disable-sync",
                    "--disable-dev-shm-usage", "--hide-scrollbars",
                    format!("--user-data-dir={}", profile.display()),
                    "--window-size=1366,768",
                ],
            },
        }}});
        let mut browser = Browser {
            driver,
            addr,
            session: String::new(),
        };
        let v = browser.cmd("POST", "/session", Some(caps));
        browser.session = v["sessionId"]
            .as_str()
            .unwrap_or_else(|| panic!("no session: {v}"))
            .to_string();
        browser
    }

    /// A WebDriver command; its `value`.
    fn cmd(&self, method: &str, path: &str, body: Option<Value>) -> Value {
        let path = if path == "/session" {
            path.to_string()
        } else {
            format!("/session/{}{path}", self.session)
        };
        let body = body.or_else(|| (method == "POST").then(|| json!({})));
        let (code, text) = http(self.addr, method, &path, body.as_ref(), None);
        let v: Value = serde_json::from_str(&text)
            .unwrap_or_else(|e| panic!("{method} {path}: not JSON ({e}): {text}"));
        assert_eq!(code, 200, "{method} {path}: {v}");
        v["value"].clone()
    }

    fn goto(&self, url: &str) {
        self.cmd("POST", "/url", Some(json!({ "url": url })));
    }

    /// Sizes the window so that the page gets `width`×`height` CSS pixels.
    fn set_viewport(&self, width: u64, height: u64) {
        let chrome = self.js(
            "return [window.outerWidth - window.innerWidth, window.outerHeight - window.innerHeight];",
            json!([]),
        );
        let (dw, dh) = (
            chrome[0].as_u64().unwrap_or(0),
            chrome[1].as_u64().unwrap_or(0),
        );
        self.cmd(
            "POST",
            "/window/rect",
            Some(json!({"width": width + dw, "height": height + dh})),
        );
    }

    /// Runs `script` (a function body; `arguments` as given) in the page.
    fn js(&self, script: &str, args: Value) -> Value {
        self.cmd(
            "POST",
            "/execute/sync",
            Some(json!({"script": script, "args": args})),
        )
    }

    fn element(&self, css: &str) -> String {
        let v = self.cmd(
            "POST",
            "/element",
            Some(json!({"using": "css selector", "value": css})),
        );
        v[ELEMENT]
            .as_str()
            .unwrap_or_else(|| panic!("no element {css}: {v}"))
            .to_string()
    }

    fn click(&self, css: &str) {
        let el = self.element(css);
        // Centred, so the page's sticky header cannot be in the way.
        self.js(
            "document.querySelector(arguments[0]).scrollIntoView({block: 'center'});",
            json!([css]),
        );
        self.cmd("POST", &format!("/element/{el}/click"), None);
    }

    fn type_into(&self, css: &str, text: &str) {
        let el = self.element(css);
        self.cmd("POST", &format!("/element/{el}/clear"), None);
        self.cmd(
            "POST",
            &format!("/element/{el}/value"),
            Some(json!({ "text": text })),
        );
    }

    /// The text of `css` as the user sees it ("" when absent).
    fn text(&self, css: &str) -> String {
        self.js(
            "const e = document.querySelector(arguments[0]); return e ? e.textContent : '';",
            json!([css]),
        )
        .as_str()
        .unwrap_or("")
        .to_string()
    }

    fn visible(&self, css: &str) -> bool {
        self.js(
            "const e = document.querySelector(arguments[0]); \
             return !!e && !e.hidden && e.offsetParent !== null;",
            json!([css]),
        ) == json!(true)
    }

    /// Polls `probe` every 100 ms until it gives a value; panics with `what` after `limit`.
    fn wait<T>(
        &self,
        what: &str,
        limit: Duration,
        mut probe: impl FnMut(&Browser) -> Option<T>,
    ) -> T {
        let deadline = Instant::now() + limit;
        loop {
            if let Some(v) = probe(self) {
                return v;
            }
            if Instant::now() > deadline {
                let page = self.text("body");
                panic!("{what}: not within {limit:?}; the page says:\n{page}");
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// The run id and loaded width of the picture `css` (0 until it loaded).
    fn picture(&self, css: &str) -> (String, u64) {
        let v = self.js(
            "const i = document.querySelector(arguments[0]); \
             return [i.dataset.run || '', i.complete ? i.naturalWidth : 0];",
            json!([css]),
        );
        (
            v[0].as_str().unwrap_or("").to_string(),
            v[1].as_u64().unwrap_or(0),
        )
    }

    /// Saves a screenshot of the viewport (re-encoded as compact RGB); its size.
    fn screenshot(&self, path: &Path) -> (u32, u32) {
        let v = self.cmd("GET", "/screenshot", None);
        let bytes = base64(v.as_str().expect("base64 PNG"));
        let size = png_size(&bytes);
        std::fs::write(path, recompress(&bytes)).expect("write the screenshot");
        size
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        if !self.session.is_empty() {
            let path = format!("/session/{}", self.session);
            let _ = std::panic::catch_unwind(|| http(self.addr, "DELETE", &path, None, None));
        }
        let _ = self.driver.kill();
        let _ = self.driver.wait();
    }
}

/// Where the screenshots go (kept by CI with target/).
fn shots() -> PathBuf {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/e2e-web");
    std::fs::create_dir_all(&dir).expect("target/e2e-web");
    dir
}

fn api_json(api: SocketAddr, path: &str) -> Value {
    let (code, body) = http(api, "GET", path, None, None);
    assert_eq!(code, 200, "GET {path}: {body}");
    serde_json::from_str(&body).unwrap_or_else(|e| panic!("GET {path}: not JSON ({e}): {body}"))
}

fn run_count(api: SocketAddr) -> usize {
    api_json(api, "/api/runs")["runs"]
        .as_array()
        .map_or(0, Vec::len)
}

#[test]
fn the_web_page_runs_a_check_with_the_token_and_refuses_without() {
    let test = "the_web_page_runs_a_check_with_the_token_and_refuses_without";
    let Some(_) = shared(test) else { return };
    let Some((chromium, chromedriver)) = browser_tools(test) else {
        return;
    };
    let dir = TempDir::new("web");
    let rig = start_rig(&dir, ROBOT_IP, CAMERA_IP, &[]);
    let token = dir.join("token");
    std::fs::write(&token, format!("{TOKEN}\n")).expect("token");
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&token, std::fs::Permissions::from_mode(0o600)).expect("chmod");
    }
    let cfg = rig_config(
        &dir,
        ROBOT_IP,
        CAMERA_IP,
        "",
        &format!(
            "[daemon]\nlisten = \"{ROBOT_IP}:8650\"\ntoken_file = \"token\"\nstartup = \"calibrate\"\n"
        ),
    );
    let mut daemon = Daemon::start(
        &dir,
        "daemon",
        &["daemon", "--config", cfg.to_str().expect("utf-8")],
    );
    daemon.wait_for_log("handeye daemon ready", secs(60));
    let api: SocketAddr = format!("{ROBOT_IP}:8650").parse().expect("addr");
    let url = format!("http://{api}/");

    // The startup calibration first: the page then has a current calibration to show.
    let deadline = Instant::now() + secs(120);
    let startup = loop {
        let st = api_json(api, "/api/status");
        if st["last"]["outcome"].is_string() && st["state"] == "idle" {
            break st;
        }
        assert!(
            Instant::now() < deadline,
            "no startup calibration: {st}\n{}",
            daemon.log()
        );
        std::thread::sleep(Duration::from_millis(200));
    };
    assert_eq!(
        startup["last"]["outcome"],
        "accepted",
        "{startup}\n{}",
        daemon.log()
    );
    let startup_id = startup["last"]["run_id"].as_str().expect("id").to_string();

    let profile = dir.join("chromium-profile");
    let b = Browser::start(&chromium, &chromedriver, &profile);
    // The cell PC's screen.
    b.set_viewport(1366, 768);
    b.goto(&url);
    // Its first paint says nothing it will contradict: no "No run yet." while the status and
    // the picture of the startup run are on their way.
    assert!(
        !b.visible("#picture-none"),
        "first paint: {}",
        b.text("#picture-none")
    );

    // The page loads with the right state.
    b.wait("daemon idle, robot and camera connected", secs(20), |b| {
        (b.text("#chip-daemon") == "daemon: idle"
            && b.text("#chip-robot") == "robot: connected"
            && b.text("#chip-camera") == "camera: connected"
            && b.text("#chip-link").starts_with("page: live"))
        .then_some(())
    });
    assert!(!b.visible("#chip-alarm"), "no drift alarm");
    b.wait(
        "the startup calibration in the history, its picture shown",
        secs(20),
        |b| {
            let rows = b.js(
            "return [...document.querySelectorAll('#history tbody tr')].map(r => r.dataset.run);",
            json!([]),
        );
            let (run, width) = b.picture("#picture");
            (rows == json!([startup_id.clone()]) && run == startup_id && width == 1280)
                .then_some(())
        },
    );
    assert!(
        b.text("#cal-run").contains(&startup_id),
        "{}",
        b.text("#cal-run")
    );
    assert!(
        b.text("#exp-ros").contains("static_transform_publisher"),
        "{}",
        b.text("#exp-ros")
    );
    assert!(
        b.text("#exp-urdf").contains("<joint"),
        "{}",
        b.text("#exp-urdf")
    );
    assert!(b.text("#cal-x").ends_with(" mm"), "{}", b.text("#cal-x"));
    assert_eq!(
        b.text("#cal-matrix").lines().count(),
        4,
        "{}",
        b.text("#cal-matrix")
    );
    assert!(b.text("#history tbody tr td.outcome") == "accepted");

    // Without the token, and with a wrong one: refused with the server's reason, nothing moves.
    let before = joints(ROBOT_IP);
    for attempt in ["", "not-the-token"] {
        b.click("#btn-check");
        b.wait("the token is asked for", secs(5), |b| {
            b.visible("#token-box").then_some(())
        });
        b.type_into("#token", attempt);
        assert_eq!(
            b.text("#message"),
            "",
            "the last message is cleared when the token is asked"
        );
        b.click("#token-send");
        let msg = b.wait("the refusal", secs(10), |b| {
            let m = b.text("#message");
            m.starts_with("Refused").then_some(m)
        });
        assert!(
            msg.contains("401") && msg.contains("token") && msg.contains("Nothing moved"),
            "{msg}"
        );
        if attempt.is_empty() {
            assert!(msg.contains("Authorization"), "{msg}");
        } else {
            assert!(msg.contains("wrong token"), "{msg}");
        }
    }
    std::thread::sleep(Duration::from_millis(500));
    let after = joints(ROBOT_IP);
    assert!(
        max_change(&before, &after) < 1e-6,
        "moved without the token: {before:?} → {after:?}"
    );
    assert_eq!(run_count(api), 1, "a run was recorded without the token");
    assert_eq!(api_json(api, "/api/status")["state"], "idle");

    // With the token: a check runs; its row and picture appear without a reload.
    b.click("#btn-check");
    b.wait("the token is asked for", secs(5), |b| {
        b.visible("#token-box").then_some(())
    });
    b.type_into("#token", TOKEN);
    b.click("#token-send");
    let msg = b.wait("the check is accepted", secs(10), |b| {
        let m = b.text("#message");
        (!m.is_empty() && !m.starts_with("Sending")).then_some(m)
    });
    let check_id = msg
        .strip_prefix("Check accepted: run ")
        .and_then(|s| s.strip_suffix('.'))
        .unwrap_or_else(|| panic!("{msg}"))
        .to_string();
    b.wait("the stage progress while it runs", secs(20), |b| {
        (b.text("#chip-daemon") == "daemon: running" && b.text("#now").contains(&check_id))
            .then_some(())
    });
    b.wait("the check's row and picture", secs(120), |b| {
        let row = b.js(
            "const r = document.querySelector(`#history tbody tr[data-run='${arguments[0]}']`); \
             return r ? r.querySelector('td.outcome').textContent : '';",
            json!([check_id.clone()]),
        );
        let (run, width) = b.picture("#picture");
        // issue 24: one vocabulary: a check on an unchanged mount is "within limits".
        (row == json!("within limits") && run == check_id && width == 1280).then_some(())
    });
    assert_eq!(run_count(api), 2);
    let rows = b.js(
        "return document.querySelectorAll('#history tbody tr').length;",
        json!([]),
    );
    assert_eq!(rows, json!(2));
    let detail = b.text(&format!(
        "#history tbody tr[data-run='{check_id}'] td.detail"
    ));
    assert!(
        detail.starts_with("drift ") && detail.contains(" mm / "),
        "{detail}"
    );
    b.wait("the drift chart's text", secs(10), |b| {
        b.text("#drift-text")
            .starts_with("1 check(s)")
            .then_some(())
    });
    let (code, chart) = http(
        api,
        "GET",
        "/api/drift.png?width=900&height=340",
        None,
        None,
    );
    assert_eq!(code, 200, "{chart}");
    let shot = shots();
    assert_eq!(b.screenshot(&shot.join("page.png")), (1366, 768));
    // The whole page, for the README.
    b.set_viewport(1366, 1500);
    b.screenshot(&shot.join("page-full.png"));
    b.set_viewport(1366, 768);

    // A history row opens the run's record and picture.
    b.click(&format!("#history tbody tr[data-run='{check_id}']"));
    b.wait("the run dialog with its picture and record", secs(10), |b| {
        let open = b.js("return document.getElementById('run-dialog').open;", json!([]));
        let width = b.js(
            "const i = document.getElementById('run-picture'); return i.complete ? i.naturalWidth : 0;",
            json!([]),
        );
        (open == json!(true) && width == json!(1280) && b.text("#run-record").contains(&check_id))
            .then_some(())
    });
    b.screenshot(&shot.join("page-run.png"));
    b.click("#run-close");

    // The token was asked once: Calibrate goes straight through, and Cancel stops it.
    b.click("#btn-calibrate");
    let msg = b.wait("the calibration is accepted", secs(10), |b| {
        let m = b.text("#message");
        m.starts_with("Calibration accepted").then_some(m)
    });
    assert!(!b.visible("#token-box"), "asked for the token again: {msg}");
    b.wait("Cancel is enabled while it runs", secs(20), |b| {
        (b.js(
            "return document.getElementById('btn-cancel').disabled;",
            json!([]),
        ) == json!(false))
        .then_some(())
    });
    b.click("#btn-cancel");
    b.wait("the cancelled run in the history", secs(60), |b| {
        b.text("#message")
            .starts_with("Cancel sent")
            .then_some(())?;
        let first = b.text("#history tbody tr td.outcome");
        (first == "aborted").then_some(())
    });

    // A tablet sees the same page in one column.
    b.set_viewport(820, 1180);
    b.goto(&url);
    b.wait("the page on a tablet", secs(20), |b| {
        (b.text("#chip-daemon") == "daemon: idle" && b.picture("#picture").1 == 1280).then_some(())
    });
    let width = b.js("return document.documentElement.scrollWidth;", json!([]));
    assert!(
        width.as_u64().is_some_and(|w| w <= 820),
        "scrolls sideways on a tablet: {width}"
    );
    b.screenshot(&shot.join("page-tablet.png"));

    // The run kept its picture, and `solve --report` draws its recorded scan again.
    let record = api_json(api, &format!("/api/runs/{check_id}"));
    let capture = PathBuf::from(record["capture_file"].as_str().expect("capture file"));
    let run_dir = capture.parent().expect("run folder");
    let kept = std::fs::read(run_dir.join("report.png")).expect("the run's report.png");
    assert_eq!(png_size(&kept), (1280, 720));
    let out = shot.join("solve-report.png");
    let _ = std::fs::remove_file(&out);
    let solved = run(
        &[
            "solve",
            "--capture",
            capture.to_str().expect("utf-8"),
            "--report",
            out.to_str().expect("utf-8"),
        ],
        secs(120),
    )
    .success();
    eprintln!("{}", solved.stderr.trim());
    let drawn = std::fs::read(&out).expect("solve --report wrote the picture");
    assert_eq!(png_size(&drawn), (1280, 720));

    drop(b);
    drop(daemon);
    drop(rig);
}

/// Issue 38: the page's Accept remount asks in the page first (a dialog, screenshot
/// `page-remount-confirm.png`); "Do not accept" sends nothing; accepting asks for the token,
/// calibrates accepting the new mount, clears the drift alarm, and the record says the page
/// accepted it. The daemon on 127.0.0.164/165.
#[test]
fn issue_38_the_page_accepts_a_remount_after_confirming() {
    let test = "issue_38_the_page_accepts_a_remount_after_confirming";
    let Some(_) = shared(test) else { return };
    let Some((chromium, chromedriver)) = browser_tools(test) else {
        return;
    };
    let dir = TempDir::new("web-remount");
    let (robot_ip, camera_ip) = ("127.0.0.164", "127.0.0.165");
    let _rig = start_rig(&dir, robot_ip, camera_ip, &[]);
    let cfg = crate::daemon::config(&dir, robot_ip, camera_ip, "startup = \"calibrate\"");
    let daemon = crate::daemon::start_daemon(&dir, "daemon", &cfg);
    let api_text = format!("{robot_ip}:8650");
    let api: SocketAddr = api_text.parse().expect("addr");
    let st = crate::daemon::wait_status(&api_text, secs(120), "the startup calibration", |s| {
        s["last_calibration"]["trigger"] == "startup" && s["state"] == "idle"
    });
    assert_eq!(
        st["last_calibration"]["outcome"],
        "accepted",
        "{st}\n{}",
        daemon.log()
    );
    // Remounted beyond gate.max_change_*: a check raises the alarm.
    crate::daemon::remount(&dir);
    let (code, body) =
        crate::daemon::http(&api_text, "POST", "/api/check", Some(crate::daemon::TOKEN));
    assert_eq!(code, 202, "{body}");
    let check: Value = serde_json::from_str(&body).expect("JSON");
    let st = crate::daemon::wait_status(&api_text, secs(120), "the check", |s| {
        s["last"]["run_id"] == check["run_id"] && s["state"] == "idle"
    });
    assert_eq!(st["drift_alarm"], true, "{st}");
    let runs = run_count(api);

    let profile = dir.join("chromium-profile");
    let b = Browser::start(&chromium, &chromedriver, &profile);
    b.set_viewport(1366, 768);
    b.goto(&format!("http://{api}/"));
    b.wait("the drift alarm on the page", secs(20), |b| {
        (b.visible("#chip-alarm") && b.text("#chip-daemon") == "daemon: idle").then_some(())
    });
    let dialog_open = |b: &Browser| {
        b.js(
            "return document.getElementById('remount-dialog').open;",
            json!([]),
        )
    };

    // The button asks in the page; "Do not accept" sends nothing.
    b.click("#btn-remount");
    b.wait("the confirmation", secs(5), |b| {
        (dialog_open(b) == json!(true)).then_some(())
    });
    let asked = b.text("#remount-dialog");
    assert!(
        asked.contains("Accept a new camera mount?")
            && asked.contains("remounted on purpose")
            && asked.contains("gate.max_change_translation_mm"),
        "{asked}"
    );
    assert_eq!(
        b.screenshot(&shots().join("page-remount-confirm.png")),
        (1366, 768)
    );
    b.click("#remount-no");
    b.wait("the refusal to send", secs(5), |b| {
        (dialog_open(b) == json!(false) && b.text("#message") == "Not sent. Nothing moved.")
            .then_some(())
    });
    assert!(!b.visible("#token-box"), "the token was asked for");
    std::thread::sleep(Duration::from_millis(500));
    assert_eq!(
        run_count(api),
        runs,
        "a run was recorded without the confirmation"
    );

    // Confirmed: the token is asked for, then the calibration accepting the mount runs.
    b.click("#btn-remount");
    b.wait("the confirmation", secs(5), |b| {
        (dialog_open(b) == json!(true)).then_some(())
    });
    b.click("#remount-yes");
    b.wait("the token is asked for", secs(5), |b| {
        b.visible("#token-box").then_some(())
    });
    b.type_into("#token", crate::daemon::TOKEN);
    b.click("#token-send");
    let msg = b.wait("the calibration is accepted", secs(10), |b| {
        let m = b.text("#message");
        (!m.is_empty() && !m.starts_with("Sending")).then_some(m)
    });
    let run_id = msg
        .strip_prefix("Calibration accepting the new mount accepted: run ")
        .and_then(|s| s.strip_suffix('.'))
        .unwrap_or_else(|| panic!("{msg}"))
        .to_string();
    b.wait(
        "the accepted run in the history, the alarm off",
        secs(120),
        |b| {
            let first = b.js(
                "const r = document.querySelector('#history tbody tr'); \
             return r ? [r.dataset.run, r.querySelector('td.outcome').textContent] : [];",
                json!([]),
            );
            (first == json!([run_id.clone(), "accepted"]) && !b.visible("#chip-alarm"))
                .then_some(())
        },
    );
    b.screenshot(&shots().join("page-remount-accepted.png"));
    let record = api_json(api, &format!("/api/runs/{run_id}"));
    let accepted = &record["change_accepted"];
    assert!(
        accepted["by"]
            .as_str()
            .is_some_and(|by| by.starts_with("web page (127.")),
        "{record}"
    );
    assert_eq!(accepted["beyond_limits"], true, "{record}");
    assert_eq!(api_json(api, "/api/status")["drift_alarm"], false);
}
