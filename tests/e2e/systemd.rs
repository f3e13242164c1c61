//! `systemd/handeye.service`: systemd accepts it, and nobody drops its readiness protocol,
//! watchdog or hardening by accident.

use std::path::Path;
use std::process::Command;

use crate::support::{TempDir, BIN};

/// The unit as shipped.
fn unit_text() -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("systemd/handeye.service");
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The `Key=value` lines of the unit (comments and section headers dropped), trimmed.
fn settings(text: &str) -> Vec<&str> {
    text.lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#') && !l.starts_with('['))
        .collect()
}

/// `systemd-analyze verify` on a copy of the unit whose `ExecStart=` runs the binary under test
/// (verify checks that the executable exists). Exit 0 and nothing on stderr about the unit:
/// systemd only warns, exit 0, about unknown keys and bad values.
#[test]
fn unit_passes_systemd_analyze_verify() {
    let test = "unit_passes_systemd_analyze_verify";
    let available = Command::new("systemd-analyze")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !available {
        assert!(
            std::env::var_os("CI").is_none(),
            "{test}: systemd-analyze is missing (CI is set, so this is a failure; .ci/install.d/systemd.sh installs it)"
        );
        crate::support::skip(&format!(
            "SKIP {test}: systemd-analyze not found (Debian package `systemd`)"
        ));
        return;
    }

    let text = unit_text();
    const SHIPPED: &str = "ExecStart=/usr/local/bin/handeye ";
    assert_eq!(
        text.lines().filter(|l| l.starts_with(SHIPPED)).count(),
        1,
        "expected exactly one line starting with {SHIPPED:?}"
    );
    assert!(
        !BIN.contains(char::is_whitespace),
        "binary path {BIN:?} has whitespace"
    );
    let copy_text = text.replace(SHIPPED, &format!("ExecStart={BIN} "));

    let dir = TempDir::new("systemd-verify");
    // The file name is the unit name: verify needs the `.service` suffix.
    let copy = dir.join("handeye.service");
    std::fs::write(&copy, copy_text).expect("write the unit copy");
    let out = Command::new("systemd-analyze")
        .args(["verify", "--man=no"])
        .arg(&copy)
        .env("SYSTEMD_LOG_COLOR", "0")
        .output()
        .expect("run systemd-analyze verify");
    let stderr = String::from_utf8_lossy(&out.stderr);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let about_unit: Vec<&str> = stderr.lines().filter(|l| l.contains("handeye")).collect();
    assert!(
        out.status.success() && about_unit.is_empty(),
        "systemd-analyze verify {}: {}\n--- stdout\n{stdout}\n--- stderr\n{stderr}",
        copy.display(),
        out.status
    );
    // Anything else on stderr is about the host's own units: show it, do not fail on it.
    if !stderr.trim().is_empty() {
        eprintln!("systemd-analyze verify (not about handeye.service):\n{stderr}");
    }
}

/// The settings the daemon's behaviour and the README rely on are present, whatever systemd
/// is installed.
#[test]
fn unit_keeps_notify_watchdog_and_hardening() {
    let text = unit_text();
    let lines = settings(&text);
    for want in [
        "Type=notify",
        "NotifyAccess=main",
        "ExecStart=/usr/local/bin/handeye daemon --config /etc/handeye/handeye.toml",
        "WatchdogSec=30",
        "Restart=on-failure",
        "RestartSec=5",
        "TimeoutStopSec=15",
        "DynamicUser=yes",
        "LoadCredential=token:/etc/handeye/token",
        "StateDirectory=handeye",
        "ConfigurationDirectory=handeye",
        "UMask=0077",
        "NoNewPrivileges=yes",
        "ProtectSystem=strict",
        "ProtectHome=yes",
        "PrivateTmp=yes",
        "PrivateDevices=yes",
        "ProtectKernelTunables=yes",
        "ProtectKernelModules=yes",
        "ProtectKernelLogs=yes",
        "ProtectControlGroups=yes",
        "RestrictAddressFamilies=AF_INET AF_INET6 AF_UNIX",
        "RestrictNamespaces=yes",
        "LockPersonality=yes",
        "MemoryDenyWriteExecute=yes",
        "RestrictRealtime=yes",
        "SystemCallArchitectures=native",
        "SystemCallFilter=@system-service",
        "CapabilityBoundingSet=",
        "LimitNOFILE=4096",
        "MemoryMax=2G",
        "TasksMax=512",
        "WantedBy=multi-user.target",
    ] {
        assert!(
            lines.contains(&want),
            "systemd/handeye.service lost `{want}`"
        );
    }
    // Each setting is explained by the comment line just above it.
    let all: Vec<&str> = text.lines().map(str::trim).collect();
    for (i, l) in all.iter().enumerate() {
        let is_setting = !l.is_empty() && !l.starts_with('#') && !l.starts_with('[');
        if is_setting {
            assert!(
                i > 0 && all[i - 1].starts_with('#'),
                "systemd/handeye.service line {}: `{l}` has no comment above it",
                i + 1
            );
        }
    }
}
