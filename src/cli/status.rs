//! `handeye status --config FILE [--json]`: asks the running daemon (`GET /api/status` at
//! `daemon.listen`) what it is doing and prints it: state, the run in progress and its stage,
//! the last run, the last calibration and check, the drift alarm, the connections. Plain
//! HTTP/1.1 over a `std` socket with a 3 s timeout; no runtime. Exit codes for scripts
//! ([`exit_code`]): 0 all is well, 1 the daemon answered but needs attention (the drift alarm
//! is on, the last run failed — rejected, aborted or error — or the storage cannot take a
//! run), 2 no daemon answers (or it answered with an error).

use std::io::{Read, Write};
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Context};
use handeye::calendar::{unix_now, utc_text};
use handeye::config::Config;
use handeye::daemon::api::ErrorBody;
use handeye::daemon::{Finished, Status};

/// How long connecting, sending and reading may each take.
const TIMEOUT: Duration = Duration::from_secs(3);
/// Largest answer read, bytes (the status is a few kB).
const MAX_RESPONSE: u64 = 4 << 20;

/// Arguments of this subcommand.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// The cell's configuration; its `daemon.listen` says where the daemon answers.
    #[arg(long, value_name = "FILE")]
    config: PathBuf,
    /// Print the daemon's status JSON as it is.
    #[arg(long)]
    json: bool,
}

pub(crate) fn run(args: Args) -> anyhow::Result<ExitCode> {
    let cfg = Config::load(&args.config)?;
    status_at(cfg.daemon.listen, &cfg.storage.dir, &args.config, args.json)
}

/// Asks the daemon listening on `listen` (or, when its HTTP API does not answer, its control
/// socket in `storage`) and prints its status.
fn status_at(
    listen: SocketAddr,
    storage: &Path,
    config: &Path,
    json: bool,
) -> anyhow::Result<ExitCode> {
    let addr = reachable(listen);
    let (code, body) = match http_get(addr, "/api/status") {
        Ok(answer) => answer,
        // Over its connection limits, the daemon still answers on its control socket.
        Err(e) => match handeye::daemon::control::request(storage, "status") {
            Ok(text) => (200, text.into_bytes()),
            Err(_) => {
                eprintln!(
                    "no daemon answers at {addr} ({e:#}); start it with `handeye daemon --config {}` \
                     or `systemctl start handeye`",
                    config.display()
                );
                return Ok(ExitCode::from(2));
            }
        },
    };
    if code != 200 {
        let msg = serde_json::from_slice::<ErrorBody>(&body)
            .map_or_else(|_| "no reason given".to_string(), |b| b.error);
        bail!("the daemon at {addr} answered {code}: {msg}");
    }
    let status: Status = serde_json::from_slice(&body).with_context(|| {
        format!("the program at {addr} answered /api/status with something other than a handeye daemon's status")
    })?;
    if json {
        println!("{}", serde_json::to_string_pretty(&status)?);
    } else {
        print!("{}", render(addr, &status, unix_now()));
    }
    Ok(ExitCode::from(exit_code(&status)))
}

/// The exit code of an answered status: 1 when the drift alarm is on, the last run failed
/// (rejected, aborted, error) or the storage cannot take a run; else 0.
fn exit_code(status: &Status) -> u8 {
    use handeye::run::Outcome;
    let last_failed = status.last.as_ref().is_some_and(|l| {
        matches!(
            l.outcome,
            Outcome::Rejected | Outcome::Aborted | Outcome::Error
        )
    });
    u8::from(status.drift_alarm || last_failed || status.storage_problem.is_some())
}

/// Where to connect for a daemon listening on `listen`: a wildcard address is reached on
/// loopback.
pub(crate) fn reachable(listen: SocketAddr) -> SocketAddr {
    match listen.ip() {
        IpAddr::V4(ip) if ip.is_unspecified() => {
            SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), listen.port())
        }
        IpAddr::V6(ip) if ip.is_unspecified() => {
            SocketAddr::new(IpAddr::V6(Ipv6Addr::LOCALHOST), listen.port())
        }
        _ => listen,
    }
}

/// `GET path` at `addr` over HTTP/1.1: the status code and the body.
fn http_get(addr: SocketAddr, path: &str) -> anyhow::Result<(u16, Vec<u8>)> {
    http_request(addr, "GET", path, None)
}

/// `METHOD path` (no body) at `addr` over HTTP/1.1, with `Authorization: Bearer TOKEN` when
/// given: the status code and the body.
pub(crate) fn http_request(
    addr: SocketAddr,
    method: &str,
    path: &str,
    token: Option<&str>,
) -> anyhow::Result<(u16, Vec<u8>)> {
    let mut stream = TcpStream::connect_timeout(&addr, TIMEOUT)?;
    stream.set_read_timeout(Some(TIMEOUT))?;
    stream.set_write_timeout(Some(TIMEOUT))?;
    let auth = token.map_or(String::new(), |t| format!("Authorization: Bearer {t}\r\n"));
    let request = format!(
        "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nAccept: application/json\r\n\
         User-Agent: handeye\r\n{auth}Content-Length: 0\r\nConnection: close\r\n\r\n"
    );
    stream.write_all(request.as_bytes())?;
    let mut raw = Vec::new();
    stream.take(MAX_RESPONSE).read_to_end(&mut raw)?;
    parse_response(&raw)
}

/// The status code and body of a raw HTTP/1.1 response (`Content-Length`, chunked, or up to
/// the end of the connection).
fn parse_response(raw: &[u8]) -> anyhow::Result<(u16, Vec<u8>)> {
    let Some(split) = raw.windows(4).position(|w| w == b"\r\n\r\n") else {
        bail!("not an HTTP response ({} bytes, no header end)", raw.len());
    };
    let head = std::str::from_utf8(&raw[..split]).context("HTTP header is not text")?;
    let body = &raw[split + 4..];
    let mut lines = head.split("\r\n");
    let status_line = lines.next().unwrap_or("");
    let code = match status_line.split(' ').collect::<Vec<_>>().as_slice() {
        [version, code, ..] if version.starts_with("HTTP/1.") => code
            .parse::<u16>()
            .with_context(|| format!("bad HTTP status line `{status_line}`"))?,
        _ => bail!("not an HTTP response: `{status_line}`"),
    };
    let mut chunked = false;
    let mut length = None;
    for line in lines {
        let Some((name, value)) = line.split_once(':') else {
            continue;
        };
        let value = value.trim();
        if name.eq_ignore_ascii_case("transfer-encoding") {
            chunked = value.to_ascii_lowercase().contains("chunked");
        } else if name.eq_ignore_ascii_case("content-length") {
            length = Some(
                value
                    .parse::<usize>()
                    .with_context(|| format!("bad Content-Length `{value}`"))?,
            );
        }
    }
    let body = if chunked {
        dechunk(body)?
    } else if let Some(n) = length {
        if body.len() < n {
            bail!("the answer ended after {} of {n} bytes", body.len());
        }
        body[..n].to_vec()
    } else {
        body.to_vec()
    };
    Ok((code, body))
}

/// The body of a chunked transfer.
fn dechunk(mut body: &[u8]) -> anyhow::Result<Vec<u8>> {
    let mut out = Vec::new();
    loop {
        let Some(eol) = body.windows(2).position(|w| w == b"\r\n") else {
            bail!("chunked answer cut short");
        };
        let size_text = std::str::from_utf8(&body[..eol]).context("bad chunk size")?;
        let size_text = size_text.split(';').next().unwrap_or("").trim();
        let size = usize::from_str_radix(size_text, 16)
            .with_context(|| format!("bad chunk size `{size_text}`"))?;
        body = &body[eol + 2..];
        if size == 0 {
            return Ok(out);
        }
        if body.len() < size + 2 {
            bail!("chunked answer cut short");
        }
        out.extend_from_slice(&body[..size]);
        body = &body[size + 2..];
    }
}

/// `3 s`, `4 min`, `2 h 5 min`, `3 d 4 h`.
fn span(seconds: f64) -> String {
    let s = seconds.max(0.0).round() as u64;
    match s {
        0..60 => format!("{s} s"),
        60..3600 => format!("{} min", s / 60),
        3600..86_400 => format!("{} h {} min", s / 3600, s % 3600 / 60),
        _ => format!("{} d {} h", s / 86_400, s % 86_400 / 3600),
    }
}

/// `2026-11-24T15:00:00Z (5 min ago)`.
fn when(unix_s: f64, now: f64) -> String {
    format!("{} ({} ago)", utc_text(unix_s), span(now - unix_s))
}

/// One finished run: `ID calibrate (asked by api): accepted in 0.9 s, ended … (… ago)`, its
/// drift (checks) and its reasons (not accepted).
fn finished(f: &Finished, now: f64) -> String {
    let mut s = format!(
        "{} {} (asked by {}): {} in {:.1} s, ended {}",
        f.run_id,
        f.mode,
        f.trigger,
        if f.verdict.is_empty() {
            f.outcome.name()
        } else {
            &f.verdict
        },
        f.duration_ms / 1e3,
        when(f.finished_unix_s, now)
    );
    if let Some(d) = f.drift {
        let (mm, deg) = (d.translation_mm, d.rotation_deg);
        let verdict = if d.exceeded {
            "beyond the thresholds"
        } else {
            "within the thresholds"
        };
        s += &format!("; drift {mm:.2} mm {deg:.3}° ({verdict})");
    }
    for r in &f.reasons {
        s += &format!("\n    {r}");
    }
    for w in &f.warnings {
        s += &format!("\n    warning: {w}");
    }
    s
}

/// The status as lines for a person.
fn render(addr: SocketAddr, st: &Status, now: f64) -> String {
    let mut out = format!(
        "handeye daemon at {addr}: {}, up {}\n",
        st.state.name(),
        span(now - st.started_unix_s)
    );
    if let Some(w) = &st.waiting {
        out += &format!("{w}\n");
    }
    let up = |connected: bool| {
        if connected {
            "connected"
        } else {
            "NOT ANSWERING"
        }
    };
    let reconnects = |n: u64| match n {
        0 => String::new(),
        n => format!(" (reconnected {n}×)"),
    };
    out += &format!(
        "robot: {}{}, camera: {}{}\n",
        up(st.robot_connected),
        reconnects(st.robot_reconnects),
        up(st.camera_connected),
        reconnects(st.camera_reconnects)
    );
    match &st.current {
        Some(c) => {
            out += &format!(
                "current run: {} {} (asked by {}) for {}",
                c.run_id,
                c.mode,
                c.trigger,
                span(now - c.since_unix_s)
            );
            match c.stage {
                Some(stage) => out += &format!(", stage {}: {}", stage.name(), c.detail),
                None => out += &format!(", {}", c.detail),
            }
            out.push('\n');
        }
        None => out += "current run: none\n",
    }
    for (i, q) in st.queued.iter().enumerate() {
        out += &format!(
            "queued {}: {} {} (asked by {})\n",
            i + 1,
            q.run_id,
            q.mode,
            q.trigger
        );
    }
    for (label, f) in [
        ("last run", &st.last),
        ("last calibration", &st.last_calibration),
        ("last check", &st.last_check),
    ] {
        match f {
            Some(f) => out += &format!("{label}: {}\n", finished(f, now)),
            None => out += &format!("{label}: none in the history\n"),
        }
    }
    if st.drift_alarm {
        out += "drift alarm: ON: the last check found the camera moved beyond the thresholds; \
                recalibrate (POST /api/calibrate, or the pendant)\n";
    } else {
        out += "drift alarm: off\n";
    }
    if let Some(aside) = &st.history_set_aside {
        out += &format!(
            "history: the damaged file was set aside as {} ({}); rebuilt from the run folders\n",
            aside.path.display(),
            aside.why
        );
    }
    if let Some(problem) = &st.storage_problem {
        out += &format!("storage: UNUSABLE, runs are refused: {problem}\n");
    }
    out
}

#[cfg(test)]
mod tests {
    use std::net::TcpListener;

    use super::*;

    fn sample() -> Status {
        serde_json::from_value(serde_json::json!({
            "state": "running",
            "current": {
                "run_id": "20261124T150000Z-00ab", "mode": "check", "trigger": "schedule",
                "since_unix_s": 1000.0, "stage": "move", "detail": "moving to view 1 of 1"
            },
            "last": {
                "run_id": "20261124T140000Z-0001", "mode": "calibrate", "trigger": "api",
                "outcome": "rejected", "reasons": ["residual 3.1 mm > 2.0 mm"],
                "finished_unix_s": 900.0, "duration_ms": 1234.0, "drift": null
            },
            "last_calibration": null,
            "last_check": {
                "run_id": "20261124T130000Z-0002", "mode": "check", "trigger": "schedule",
                "outcome": "accepted", "reasons": [], "finished_unix_s": 800.0,
                "duration_ms": 900.0, "drift": {"translation_mm": 1.5, "rotation_deg": 0.25, "exceeded": true}
            },
            "queued": [{
                "run_id": "20261124T150001Z-00ac", "mode": "calibrate", "trigger": "api",
                "since_unix_s": 1001.0, "stage": null, "detail": "queued"
            }],
            "drift_alarm": true,
            "robot_connected": true,
            "camera_connected": false,
            "robot_reconnects": 2,
            "camera_reconnects": 0,
            "started_unix_s": 0.0
        }))
        .expect("a status")
    }

    #[test]
    fn render_says_what_the_daemon_does() {
        let addr: SocketAddr = "127.0.0.1:8650".parse().expect("addr");
        let text = render(addr, &sample(), 1010.0);
        for want in [
            "handeye daemon at 127.0.0.1:8650: running, up 16 min",
            "robot: connected (reconnected 2×), camera: NOT ANSWERING\n",
            "queued 1: 20261124T150001Z-00ac calibrate (asked by api)",
            "current run: 20261124T150000Z-00ab check (asked by schedule) for 10 s, stage move: moving to view 1 of 1",
            "last run: 20261124T140000Z-0001 calibrate (asked by api): rejected in 1.2 s",
            "    residual 3.1 mm > 2.0 mm",
            "last calibration: none in the history",
            "drift 1.50 mm 0.250° (beyond the thresholds)",
            "drift alarm: ON",
        ] {
            assert!(text.contains(want), "missing `{want}` in:\n{text}");
        }
    }

    #[test]
    fn responses_parse_with_length_chunked_or_to_the_end() {
        let (code, body) =
            parse_response(b"HTTP/1.1 200 OK\r\ncontent-length: 2\r\n\r\n{}xx").expect("parse");
        assert_eq!((code, body.as_slice()), (200, b"{}".as_slice()));
        let (code, body) = parse_response(
            b"HTTP/1.1 404 Not Found\r\nTransfer-Encoding: chunked\r\n\r\n3\r\nabc\r\n2;x=y\r\nde\r\n0\r\n\r\n",
        )
        .expect("parse");
        assert_eq!((code, body.as_slice()), (404, b"abcde".as_slice()));
        let (_, body) = parse_response(b"HTTP/1.0 200 OK\r\n\r\nhello").expect("parse");
        assert_eq!(body, b"hello");
        assert!(parse_response(b"SSH-2.0-OpenSSH\r\n").is_err());
        assert!(parse_response(b"HTTP/1.1 200 OK\r\ncontent-length: 9\r\n\r\nabc").is_err());
    }

    #[test]
    fn wildcard_listen_is_reached_on_loopback() {
        let any: SocketAddr = "0.0.0.0:8650".parse().expect("addr");
        assert_eq!(reachable(any), "127.0.0.1:8650".parse().expect("addr"));
        let any6: SocketAddr = "[::]:8650".parse().expect("addr");
        assert_eq!(reachable(any6), "[::1]:8650".parse().expect("addr"));
        let lan: SocketAddr = "192.168.1.5:8650".parse().expect("addr");
        assert_eq!(reachable(lan), lan);
    }

    /// Scripts tell a cell that needs attention from one that is fine: 1 for the drift alarm,
    /// a failed last run or unusable storage.
    #[test]
    fn exit_codes_tell_fine_from_needing_attention() {
        use handeye::run::Outcome;
        let mut st = sample();
        st.drift_alarm = false;
        st.storage_problem = None;
        if let Some(last) = st.last.as_mut() {
            last.outcome = Outcome::Accepted;
        }
        assert_eq!(exit_code(&st), 0);
        let mut alarm = st.clone();
        alarm.drift_alarm = true;
        assert_eq!(exit_code(&alarm), 1);
        for failed in [Outcome::Rejected, Outcome::Aborted, Outcome::Error] {
            let mut s = st.clone();
            if let Some(last) = s.last.as_mut() {
                last.outcome = failed;
            }
            assert_eq!(exit_code(&s), 1, "{failed:?}");
        }
        let mut full = st.clone();
        full.storage_problem = Some("0 MB free".into());
        assert_eq!(exit_code(&full), 1);
        let mut none = st;
        none.last = None;
        assert_eq!(exit_code(&none), 0);
    }

    #[test]
    fn no_daemon_exits_2() {
        let port = TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .expect("free port");
        let code = status_at(
            port,
            Path::new("no-storage-here"),
            Path::new("cell.toml"),
            false,
        )
        .expect("no error");
        assert_eq!(code, ExitCode::from(2));
    }

    #[test]
    fn asks_the_daemon_over_http() {
        let listener = TcpListener::bind("127.0.0.1:0").expect("bind");
        let addr = listener.local_addr().expect("addr");
        let server = std::thread::spawn(move || {
            let (mut s, _) = listener.accept().expect("accept");
            let mut req = Vec::new();
            let mut buf = [0u8; 1024];
            while !req.windows(4).any(|w| w == b"\r\n\r\n") {
                let n = s.read(&mut buf).expect("read");
                assert!(n > 0, "request cut short");
                req.extend_from_slice(&buf[..n]);
            }
            let body = serde_json::to_string(&sample()).expect("JSON");
            let answer = format!(
                "HTTP/1.1 200 OK\r\ncontent-type: application/json\r\ncontent-length: {}\r\n\r\n{body}",
                body.len()
            );
            s.write_all(answer.as_bytes()).expect("write");
            String::from_utf8(req).expect("text")
        });
        let code = status_at(
            addr,
            Path::new("no-storage-here"),
            Path::new("cell.toml"),
            true,
        )
        .expect("answered");
        // The sample's drift alarm is on.
        assert_eq!(code, ExitCode::from(1));
        let req = server.join().expect("server");
        assert!(req.starts_with("GET /api/status HTTP/1.1\r\n"), "{req}");
    }
}
