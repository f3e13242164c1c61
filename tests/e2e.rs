//! End-to-end tests: the `handeye` binary as child processes against its simulators, over the
//! real protocols (UR dashboard/RTDE/script, GigE Vision), plus the offline commands.
//!
//! Robot models come from `../shared/robots`; without it every scenario prints SKIP (and fails
//! when env `CI` is set). Loopback addresses used here: 127.0.0.110–127.0.0.114, 127.0.0.120–127.0.0.133, 127.0.0.173–127.0.0.174 (issue 16)
//! 127.0.0.175–127.0.0.176 (issue 24, nothing listens), 127.0.0.201–127.0.0.208 (issue 23) with
//! 127.0.1.1–127.0.1.125 as client addresses, 127.0.0.140–127.0.0.141 (the web page), 127.0.0.160–127.0.0.161 (issue 38, a remount), 127.0.0.162–127.0.0.163 (issue 38, the command line's remount), 127.0.0.164–127.0.0.165 (issue 38, the page's Accept remount), 127.0.0.166–127.0.0.171 (issue 38 robot --config, issue 36 corrupt controller values), 127.0.0.230–127.0.0.232 (issue 36: primary and stream faults), 127.0.0.236–127.0.0.245 (issue 36: kills, cancel, storage), 127.0.0.144–127.0.0.145 (issue 46: write-back journals), 127.0.0.147–127.0.0.149 (issue 46: controller state mid-move), 127.0.0.70–127.0.0.79 (issue 46: one arm, one master; the clock; the control socket), 127.0.0.184–127.0.0.187 (issue 42, the pendant), 127.0.0.193 (issue 42, the storage's owner; nothing listens), 127.0.0.190–127.0.0.192 (packaging/deb/check.sh's rig and daemon), 127.0.0.80–127.0.0.89 (issue 44, a rig per vendor imitation), 127.0.0.60 (issue 46, a hostile GenTL producer under the daemon) and 127.0.0.182 (issue 35, the robot
//! our GenTL producer's scene follows).

#[path = "e2e/arm.rs"]
mod arm;
#[path = "e2e/book.rs"]
mod book;
#[path = "e2e/calibrate.rs"]
mod calibrate;
#[path = "e2e/daemon.rs"]
mod daemon;
#[path = "e2e/gentl.rs"]
mod gentl;
#[path = "e2e/hostile.rs"]
mod hostile;
#[path = "e2e/imitations.rs"]
mod imitations;
#[path = "e2e/monitoring.rs"]
mod monitoring;
#[path = "e2e/owner.rs"]
mod owner;
#[path = "e2e/pendant.rs"]
mod pendant;
#[path = "e2e/readme.rs"]
mod readme;
#[path = "e2e/rig.rs"]
mod rig;
#[path = "e2e/scan.rs"]
mod scan;
#[path = "e2e/small_fs.rs"]
mod small_fs;
#[path = "e2e/storage.rs"]
mod storage;
#[path = "e2e/support.rs"]
mod support;
#[path = "e2e/systemd.rs"]
mod systemd;
#[path = "e2e/ur_clients.rs"]
mod ur_clients;
#[path = "e2e/web.rs"]
mod web;
#[path = "e2e/writeback.rs"]
mod writeback;
