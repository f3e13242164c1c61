//! The GenTL backend against a producer we did not write: the EMVA reference producer
//! `viky.cti` (shipped by PyPI `genicam`, installed into `$REPO/.venv` by
//! `.ci/install.d/gentl.sh`), read point by point against harvesters, a GenTL consumer we did
//! not write either (`tests/python/gentl_harvesters.py`). Then our own producer (`sim/gentl`,
//! the simulated 3D camera as a `.cti`, built with these tests as a dev-dependency) driven by
//! harvesters and by our consumer, and a calibration through it. Without the venv the tests
//! print SKIP, and fail when env `CI` is set. Loopback address: 127.0.0.182 (the UR simulator
//! the producer's scene follows).

use std::path::{Path, PathBuf};

use crate::support::{
    iso, pose_arg, pose_error, rig_config, run, run_env, secs, shared, sim_robot, skip, true_mount,
    TempDir, BIN,
};

/// The venv's python and viky.cti, or `None` (panics under CI).
fn viky() -> Option<(PathBuf, PathBuf)> {
    let py = Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv/bin/python");
    let found = py.exists().then(|| {
        let out = std::process::Command::new(&py)
            .args([
                "-c",
                "import genicam, harvesters, os; print(os.path.join(os.path.dirname(genicam.__file__), 'viky.cti'))",
            ])
            .output()
            .expect("run python");
        let cti = PathBuf::from(String::from_utf8_lossy(&out.stdout).trim());
        (out.status.success() && cti.is_file()).then_some((py.clone(), cti))
    });
    match found.flatten() {
        Some(v) => Some(v),
        None => {
            assert!(
                std::env::var_os("CI").is_none(),
                "genicam's viky.cti or harvesters missing in {} under CI: run .ci/install.d/gentl.sh",
                py.display()
            );
            skip("SKIP gentl: $REPO/.venv with genicam (viky.cti) and harvesters not found (.ci/install.d/gentl.sh)");
            None
        }
    }
}

fn harvesters(py: &Path, args: &[&str]) -> std::process::Output {
    harvesters_env(py, args, &[])
}

/// [`harvesters`] with more environment variables (our producer's scene).
fn harvesters_env(py: &Path, args: &[&str], env: &[(&str, &str)]) -> std::process::Output {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/gentl_harvesters.py");
    let out = std::process::Command::new(py)
        .arg(script)
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env(
            "HANDEYE_ROBOTS",
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/robots"),
        )
        .envs(env.iter().copied())
        .output()
        .expect("run harvesters");
    assert!(
        out.status.success(),
        "harvesters {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// `camera probe --gentl viky.cti` lists the devices harvesters lists, and `--device` picks
/// one by serial.
#[test]
fn probe_lists_the_reference_producers_devices() {
    let Some((py, cti)) = viky() else { return };
    let cti_s = cti.to_str().expect("utf-8 path");
    let ours = run(&["camera", "probe", "--gentl", cti_s, "--json"], secs(60)).success();
    let ours: Vec<serde_json::Value> = ours
        .json()
        .as_array()
        .expect("list")
        .iter()
        .flat_map(|i| i["devices"].as_array().expect("devices").clone())
        .collect();
    let theirs: serde_json::Value =
        serde_json::from_slice(&harvesters(&py, &["probe", cti_s]).stdout).expect("json");
    let theirs = theirs.as_array().expect("list");
    assert_eq!(ours.len(), 3, "{ours:?}");
    assert_eq!(ours.len(), theirs.len());
    for (o, t) in ours.iter().zip(theirs) {
        for (ok, tk) in [
            ("id", "id"),
            ("vendor", "vendor"),
            ("model", "model"),
            ("serial", "serial"),
        ] {
            assert_eq!(o[ok], t[tk], "{o} vs {t}");
        }
    }
    let text = run(&["camera", "probe", "--gentl", cti_s], secs(60)).success();
    assert!(
        text.stdout
            .contains("2: Machine Vision Games Ltd. Viky (serial 2"),
        "{text}"
    );
    // Issue 44: `--device` identifies one and lists the settings a user would make through
    // `[camera.features]` (before: the GenTL probe only listed devices).
    let one = run(
        &[
            "camera", "probe", "--gentl", cti_s, "--device", "2", "--json",
        ],
        secs(60),
    )
    .success();
    let doc = one.json();
    assert_eq!(doc["model"], "Viky", "{one}");
    let features = doc["features"].as_array().expect("features");
    let pixel_format = features
        .iter()
        .find(|f| f["name"] == "PixelFormat")
        .unwrap_or_else(|| panic!("PixelFormat listed: {one}"));
    assert!(pixel_format["value"].is_string(), "{pixel_format}");
    assert!(pixel_format["access"].is_string(), "{pixel_format}");
    let text = run(
        &["camera", "probe", "--gentl", cti_s, "--device", "2"],
        secs(60),
    )
    .success();
    assert!(
        text.stdout
            .contains("settings ([camera.features], camera.user_set):")
            && text.stdout.contains("  PixelFormat = "),
        "{text}"
    );
}

/// `camera capture --gentl viky.cti --out v.ply`: 400 x 400 valid points in metres, each equal
/// to the float to what harvesters reads from the same producer (mm to m as documented).
#[test]
fn capture_equals_harvesters_point_by_point() {
    let Some((py, cti)) = viky() else { return };
    let dir = TempDir::new("gentl-viky");
    let cti_s = cti.to_str().expect("utf-8 path");
    let ply = dir.join("v.ply");
    let out = run(
        &[
            "camera",
            "capture",
            "--gentl",
            cti_s,
            "--device",
            "1",
            "--json",
            "--out",
            ply.to_str().expect("utf-8 path"),
        ],
        secs(120),
    )
    .success();
    let j = out.json();
    assert_eq!(
        (j["width"].as_u64(), j["height"].as_u64()),
        (Some(400), Some(400)),
        "{out}"
    );
    assert_eq!(j["valid_points"][0].as_u64(), Some(160_000), "{out}");
    let ours = handeye::cloud::read_cloud(&ply).expect("read the PLY");
    let reference = dir.join("v.bin");
    harvesters(
        &py,
        &[
            "capture",
            cti_s,
            reference.to_str().expect("utf-8 path"),
            "1",
        ],
    );
    let ((w, h), theirs) = read_reference(&reference);
    assert_eq!((w, h), (400, 400));
    assert_same_points(&ours, &theirs);
    let mut max = [0f32; 3];
    for p in &ours.points {
        for k in 0..3 {
            max[k] = max[k].max(p[k]);
        }
    }
    // A and B span 0..399 mm, C 0..41.05 mm: metres, not millimetres.
    assert!(
        (max[0] - 0.399).abs() < 1e-6 && (max[1] - 0.399).abs() < 1e-6,
        "{max:?}"
    );
    assert!((0.04..0.042).contains(&max[2]), "{max:?}");
}

/// What `gentl_harvesters.py capture` wrote: (width, height) and x, y, z per point (m).
fn read_reference(path: &Path) -> ((u32, u32), Vec<f32>) {
    let bytes = std::fs::read(path).expect("reference");
    let word = |i: usize| [bytes[i], bytes[i + 1], bytes[i + 2], bytes[i + 3]];
    let (w, h) = (u32::from_le_bytes(word(0)), u32::from_le_bytes(word(4)));
    let points = (0..(w * h * 3) as usize)
        .map(|k| f32::from_le_bytes(word(8 + 4 * k)))
        .collect();
    ((w, h), points)
}

/// Every point of `ours` equals harvesters' to the bit (NaN where both have no measurement).
fn assert_same_points(ours: &handeye_hal::PointCloud, theirs: &[f32]) {
    assert_eq!(ours.points.len(), theirs.len() / 3);
    for (i, p) in ours.points.iter().enumerate() {
        let t = &theirs[3 * i..3 * i + 3];
        assert_eq!(
            [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()],
            [t[0].to_bits(), t[1].to_bits(), t[2].to_bits()],
            "point {i}: ours {p:?}, harvesters {t:?}"
        );
    }
}

/// Our producer, `libhandeye_gentl_sim.so` (built with these tests: a dev-dependency), linked
/// into `dir` as `handeye-sim.cti`, the name GenTL consumers look for.
fn our_producer(dir: &TempDir) -> PathBuf {
    let bin_dir = Path::new(BIN).parent().expect("the binary's directory");
    let so = [
        bin_dir.join("deps/libhandeye_gentl_sim.so"),
        bin_dir.join("libhandeye_gentl_sim.so"),
    ]
    .into_iter()
    .find(|p| p.is_file())
    .unwrap_or_else(|| {
        panic!(
            "libhandeye_gentl_sim.so is not in {}: cargo builds it with the e2e tests",
            bin_dir.display()
        )
    });
    let cti = dir.join("handeye-sim.cti");
    std::os::unix::fs::symlink(&so, &cti).expect("link the .cti");
    cti
}

/// harvesters loads our producer, lists its one device, captures a multi-part buffer (Range
/// as Coord3D_ABC32f, and Confidence16 once enabled), and its points are, to the bit, what
/// `handeye camera capture --gentl` reads through the same producer: the robot's base seen
/// from a generated view (a perfect sensor, so every frame is the same).
#[test]
fn harvesters_and_our_consumer_read_the_same_points_from_our_producer() {
    if shared("harvesters_and_our_consumer_read_the_same_points_from_our_producer").is_none() {
        return;
    }
    let Some((py, _)) = viky() else { return };
    let dir = TempDir::new("gentl-ours");
    let cti = our_producer(&dir);
    let cti_s = cti.to_str().expect("utf-8 path");
    let scene = [(
        "HANDEYE_SIM_CAMERA_ARGS",
        "--model ur5e --width 320 --height 240 --ideal --serial SIMGENTL1",
    )];

    let theirs: serde_json::Value =
        serde_json::from_slice(&harvesters_env(&py, &["probe", cti_s], &scene).stdout)
            .expect("json");
    assert_eq!(
        theirs,
        serde_json::json!([{"id": "SIMGENTL1", "vendor": "handeye", "model": "SimCam3D", "serial": "SIMGENTL1"}])
    );
    let ours = run_env(
        &["camera", "probe", "--gentl", cti_s, "--json"],
        &scene,
        secs(60),
    )
    .success()
    .json();
    assert_eq!(ours[0]["devices"][0]["serial"], "SIMGENTL1", "{ours}");
    assert_eq!(ours[0]["devices"][0]["model"], "SimCam3D", "{ours}");

    let reference = dir.join("h.bin");
    let out = harvesters_env(
        &py,
        &[
            "capture",
            cti_s,
            reference.to_str().expect("utf-8 path"),
            "0",
            "--confidence",
        ],
        &scene,
    );
    let parts: serde_json::Value = serde_json::from_slice(
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .last()
            .unwrap_or_default()
            .as_bytes(),
    )
    .expect("parts JSON");
    assert_eq!(
        parts,
        serde_json::json!([
            {"format": "Coord3D_ABC32f", "width": 320, "height": 240},
            {"format": "Confidence16", "width": 320, "height": 240},
        ])
    );
    let ((w, h), theirs) = read_reference(&reference);
    assert_eq!((w, h), (320, 240));

    let ply = dir.join("o.ply");
    let out = run_env(
        &[
            "camera",
            "capture",
            "--gentl",
            cti_s,
            "--device",
            "SIMGENTL1",
            "--json",
            "--out",
            ply.to_str().expect("utf-8 path"),
        ],
        &scene,
        secs(120),
    )
    .success();
    let j = out.json();
    assert_eq!(
        (j["width"].as_u64(), j["height"].as_u64()),
        (Some(320), Some(240)),
        "{out}"
    );
    let ours = handeye::cloud::read_cloud(&ply).expect("read the PLY");
    assert_same_points(&ours, &theirs);
    // Real 3D points of the robot, in metres, in front of the camera.
    let valid: Vec<_> = ours
        .points
        .iter()
        .filter(|p| p.coords.iter().all(|c| c.is_finite()))
        .collect();
    assert!(valid.len() > 5_000, "{} valid points", valid.len());
    assert!(
        valid.iter().all(|p| (0.05..3.0).contains(&p.z)),
        "depths outside 0.05–3 m"
    );
}

/// `handeye calibrate` with `camera.backend = "gentl"` and our producer: the scene follows a
/// `handeye sim robot` over RTDE (set through `HANDEYE_SIM_CAMERA_ARGS`) as `sim rig`'s camera
/// does, and the result is as close to the true mount as through GigE Vision.
#[test]
fn calibrates_through_our_gentl_producer_as_through_gige() {
    if shared("calibrates_through_our_gentl_producer_as_through_gige").is_none() {
        return;
    }
    let dir = TempDir::new("gentl-calibrate");
    let cti = our_producer(&dir);
    let robot_ip = "127.0.0.182";
    let _robot = sim_robot(&dir, robot_ip, &["--powered", "--factory-calibration", "1"]);
    let cfg = rig_config(&dir, robot_ip, "127.0.0.1", "frames = 3", "");
    let text = std::fs::read_to_string(&cfg).expect("config");
    let text = text.replace(
        "backend = \"gige\"\naddress = \"127.0.0.1\"",
        &format!(
            "backend = \"gentl\"\nproducer = \"{}\"\ndevice = \"SIMGENTL2\"",
            cti.display()
        ),
    );
    assert!(text.contains("gentl"), "{text}");
    std::fs::write(&cfg, text).expect("config");
    let scene = format!(
        "--robot {robot_ip} --mount {} --factory-calibration 1 --serial SIMGENTL2",
        pose_arg(&true_mount())
    );
    let out = run_env(
        &[
            "calibrate",
            "--config",
            cfg.to_str().expect("utf-8"),
            "--json",
        ],
        &[("HANDEYE_SIM_CAMERA_ARGS", &scene)],
        secs(180),
    );
    assert_eq!(out.code(), 0, "{out}");
    let record = out.json();
    assert_eq!(record["outcome"], "accepted", "{out}");
    let result = iso(&record["result"]["flange_from_camera"]);
    let (mm, deg) = pose_error(&true_mount(), &result);
    eprintln!("calibrate through GenTL: {mm:.3} mm / {deg:.4}° from the truth");
    assert!(
        mm < handeye::bench::PASS_TRANSLATION_MM && deg < handeye::bench::PASS_ROTATION_DEG,
        "{mm:.3} mm / {deg:.4}° off\n{out}"
    );
    assert_eq!(record["returned_to_start"], true, "{out}");
}

/// The scene of the hostile-producer tests: small, a perfect sensor, standing still.
const SMALL_SCENE: &str = "--model ur5e --width 64 --height 48 --ideal --serial HOSTILE1";

/// Issue 46: our producer made hostile (`HANDEYE_SIM_GENTL_FAULT`, see sim/gentl's `faults`):
/// a call that never returns, an abort, an `exit(0)` in the library's constructor, parts and
/// values that lie. Each `camera capture` ends within its deadline (the call timeout of 2 s,
/// EventGetData's frame timeout + 1 s) with exit 2 and a message naming the call or the value
/// (before: a hang past SIGTERM, a 64-fold copy, exit 0 with nothing captured or with garbage
/// points); the same capture without the fault then works.
#[test]
fn issue_46_a_hostile_producer_ends_each_capture_in_a_clear_error_within_its_deadline() {
    if shared("issue_46_a_hostile_producer_ends_each_capture_in_a_clear_error_within_its_deadline")
        .is_none()
    {
        return;
    }
    let dir = TempDir::new("gentl-hostile");
    let cti = our_producer(&dir);
    let cti_s = cti.to_str().expect("utf-8 path");
    let args = [
        "camera",
        "capture",
        "--gentl",
        cti_s,
        "--call-timeout-s",
        "2",
        "--frame-timeout-ms",
        "1000",
        "--json",
    ];
    let cases = [
        ("block:EventGetData", "did not return from EventGetData within 2s"),
        ("block:DSStartAcquisition", "did not return from DSStartAcquisition within 2s"),
        ("block:AcquisitionStart", "did not return from AcquisitionStart (GCWritePort) within 2s"),
        ("block:DSStopAcquisition", "did not return from DSStopAcquisition within 2s"),
        ("block:load", "did not return from dlopen (the producer's initialisers) within 2s"),
        ("abort:EventGetData", "ended its host process during EventGetData (it was killed by signal 6 (SIGABRT))"),
        ("exit:load", "ended its host process during dlopen (the producer's initialisers) (it exited with code 0)"),
        ("exit:DSStartAcquisition", "ended its host process during DSStartAcquisition (it exited with code 0)"),
        ("overlapping-parts", "parts that overlap: 36864 bytes at offset 0 and 36864 bytes at offset 0"),
        ("lying-format", "36864 bytes for a 64 x 48 Coord3D_C16 image (6144 expected"),
        ("short-part", "36860 bytes for a 64 x 48 Coord3D_ABC32f image (36864 expected"),
        ("zero-width", "an empty 0 x 48 image"),
        ("scale-zero", "`Scan3dCoordinateScale`: 0 for CoordinateA"),
        ("offset-1e30", "`Scan3dCoordinateOffset`: 1000000000000000000000000000000 for CoordinateA"),
    ];
    for (fault, message) in cases {
        let t = std::time::Instant::now();
        let out = run_env(
            &args,
            &[
                ("HANDEYE_SIM_CAMERA_ARGS", SMALL_SCENE),
                ("HANDEYE_SIM_GENTL_FAULT", fault),
            ],
            secs(30),
        );
        let took = t.elapsed();
        assert_eq!(out.code(), 2, "{fault}: {out}");
        assert!(out.stderr.contains(message), "{fault}: {out}");
        assert!(took < secs(6), "{fault}: {took:?}\n{out}");
        eprintln!("{fault}: exit 2 after {took:.2?}");
    }
    let out = run_env(&args, &[("HANDEYE_SIM_CAMERA_ARGS", SMALL_SCENE)], secs(30)).success();
    assert_eq!(out.json()["complete"], 1, "{out}");
    // Enumeration is bounded over all interfaces together (before: 1 024 x 1 024 devices
    // were listed, 647 MB and 25 s).
    let out = run_env(
        &["camera", "probe", "--gentl", cti_s, "--call-timeout-s", "2"],
        &[
            ("HANDEYE_SIM_CAMERA_ARGS", SMALL_SCENE),
            ("HANDEYE_SIM_GENTL_FAULT", "many-devices"),
        ],
        secs(30),
    );
    assert_eq!(out.code(), 2, "{out}");
    assert!(
        out.stderr.contains(
            "returned garbage from IFGetNumDevices: 1024 more devices, over the 1024 accepted \
             from one producer in all interfaces together"
        ),
        "{out}"
    );
}

/// Issue 46, in the daemon: a producer whose constructor calls `exit(0)` does not end the
/// daemon (it kept retrying, named the call, and became ready once the producer behaved);
/// then a run whose `EventGetData` never returns ends in an error naming the call within its
/// deadline, the status counts the camera's reconnection, and the next run is accepted
/// (before: the next run hung in preflight with no limit). Loopback: 127.0.0.60.
#[test]
fn issue_46_a_blocking_producer_fails_one_run_and_the_next_run_works() {
    if shared("issue_46_a_blocking_producer_fails_one_run_and_the_next_run_works").is_none() {
        return;
    }
    use crate::daemon::{http, wait_status, TOKEN};
    let dir = TempDir::new("gentl-daemon-hostile");
    let cti = our_producer(&dir);
    let robot_ip = "127.0.0.60";
    let _robot = sim_robot(&dir, robot_ip, &["--powered", "--factory-calibration", "1"]);
    let cfg = crate::daemon::config(&dir, robot_ip, "127.0.0.1", "");
    let text = std::fs::read_to_string(&cfg).expect("config");
    let text = text.replace(
        "backend = \"gige\"\naddress = \"127.0.0.1\"",
        &format!(
            "backend = \"gentl\"\nproducer = \"{}\"\ncall_timeout_s = 2\nframe_timeout_s = 2",
            cti.display()
        ),
    );
    assert!(text.contains("call_timeout_s"), "{text}");
    std::fs::write(&cfg, text).expect("config");
    let faults = dir.join("faults");
    std::fs::write(&faults, "exit:load").expect("faults");
    let scene = format!(
        "--robot {robot_ip} --mount {} --factory-calibration 1 --serial SIMGENTL3",
        pose_arg(&true_mount())
    );
    let faults_s = faults.to_str().expect("utf-8").to_owned();
    let mut daemon = crate::support::Daemon::start_env(
        &dir,
        "daemon",
        &["daemon", "--config", cfg.to_str().expect("utf-8")],
        &[
            ("HANDEYE_SIM_CAMERA_ARGS", &scene),
            ("HANDEYE_SIM_GENTL_FAULT", &faults_s),
        ],
    );
    daemon.wait_for_log(
        "ended its host process during dlopen (the producer's initialisers) (it exited with code 0)",
        secs(60),
    );
    std::fs::write(&faults, "block:EventGetData").expect("faults");
    daemon.wait_for_log("handeye daemon ready", secs(90));
    let api = format!("{robot_ip}:8650");

    let t = std::time::Instant::now();
    let (code, body) = http(&api, "POST", "/api/calibrate", Some(TOKEN));
    assert_eq!(code, 202, "{body}");
    let st = wait_status(
        &api,
        secs(120),
        "the run with a blocking producer ends",
        |s| s["last"]["outcome"].is_string(),
    );
    eprintln!("the blocked run ended after {:.1?}", t.elapsed());
    assert_ne!(st["last"]["outcome"], "accepted", "{st}");
    let run_id = st["last"]["run_id"].as_str().expect("run id").to_owned();
    let (_, record) = http(&api, "GET", &format!("/api/runs/{run_id}"), None);
    assert!(
        record.contains("did not return from EventGetData within 3s"),
        "{record}\n{}",
        daemon.log()
    );
    wait_status(
        &api,
        secs(60),
        "the status counts the camera's reconnection",
        |s| s["camera_reconnects"].as_u64() >= Some(1),
    );

    std::fs::write(&faults, "").expect("faults");
    let t = std::time::Instant::now();
    let (code, body) = http(&api, "POST", "/api/calibrate", Some(TOKEN));
    assert_eq!(code, 202, "{body}");
    let st = wait_status(&api, secs(240), "the next run ends", |s| {
        s["last"]["run_id"].as_str().is_some_and(|r| r != run_id)
    });
    eprintln!("the next run ended after {:.1?}", t.elapsed());
    assert_eq!(st["last"]["outcome"], "accepted", "{st}\n{}", daemon.log());
    let log = daemon.log();
    assert!(log.contains("was lost; starting a new one"), "{log}");
    assert!(log.contains("reconnecting at the next request"), "{log}");
}

/// Issue 44: our producer's system, interface, device and data stream modules had empty node
/// maps (harvesters: "Feature not present" for every SFNC GenTL feature). harvesters now reads
/// TLVendorName, DeviceAccessStatus, StreamAnnouncedBufferCount …, sets
/// StreamBufferHandlingMode (OldestFirst, the one mode the producer does; NewestOnly is not an
/// entry) and captures.
#[test]
fn issue_44_harvesters_reads_our_producers_module_node_maps_and_sets_buffer_handling() {
    if shared("issue_44_harvesters_reads_our_producers_module_node_maps").is_none() {
        return;
    }
    let Some((py, _)) = viky() else { return };
    let dir = TempDir::new("gentl-modules");
    let cti = our_producer(&dir);
    let cti_s = cti.to_str().expect("utf-8 path");
    let scene = [(
        "HANDEYE_SIM_CAMERA_ARGS",
        "--model ur5e --width 64 --height 48 --ideal --serial SIMGENTL2",
    )];
    let out = harvesters_env(&py, &["modules", cti_s], &scene);
    let got: serde_json::Value = serde_json::from_slice(
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .last()
            .unwrap_or("")
            .as_bytes(),
    )
    .expect("json");
    assert_eq!(got["system"]["TLVendorName"], "handeye", "{got}");
    assert_eq!(got["system"]["TLID"], "handeye-sim", "{got}");
    assert_eq!(got["system"]["TLType"], "Custom", "{got}");
    assert_eq!(
        got["interface"]["DeviceAccessStatus"], "OpenReadWrite",
        "{got}"
    );
    assert_eq!(got["device"]["DeviceSerialNumber"], "SIMGENTL2", "{got}");
    assert_eq!(got["device"]["DeviceModelName"], "SimCam3D", "{got}");
    assert_eq!(
        got["device"]["DeviceAccessStatus"], "OpenReadWrite",
        "{got}"
    );
    assert_eq!(got["stream"]["StreamID"], "Stream0", "{got}");
    assert_eq!(
        got["stream"]["StreamBufferHandlingMode"], "OldestFirst",
        "{got}"
    );
    assert_eq!(got["set"], "OldestFirst", "{got}");
    assert_ne!(got["newest_only"], "accepted", "{got}");
    assert!(got["announced"].as_i64().is_some_and(|n| n >= 1), "{got}");
    assert_eq!(got["parts"][0], "Coord3D_ABC32f", "{got}");
}

/// Issue 44: a producer that delivers GenDC containers (GenTL payload type 11: our producer
/// with `--imitate gendc`, its camera in GenDCStreamingMode On) is refused by name, with the
/// setting that makes it send multi-part buffers, not read as garbage.
#[test]
fn issue_44_a_gendc_payload_is_refused_by_name() {
    if shared("issue_44_a_gendc_payload_is_refused_by_name").is_none() {
        return;
    }
    let dir = TempDir::new("gentl-gendc");
    let cti = our_producer(&dir);
    let cti_s = cti.to_str().expect("utf-8 path");
    let scene = [(
        "HANDEYE_SIM_CAMERA_ARGS",
        "--test-pattern --width 32 --height 24 --imitate gendc",
    )];
    let out = run_env(&["camera", "capture", "--gentl", cti_s], &scene, secs(60));
    assert_ne!(out.code(), 0, "{out}");
    let text = out.to_string();
    assert!(
        text.contains("GenDC container (GenTL payload type 11)")
            && text.contains("set GenDCStreamingMode to Off"),
        "{text}"
    );
    // The same producer without the habit captures.
    let plain = [(
        "HANDEYE_SIM_CAMERA_ARGS",
        "--test-pattern --width 32 --height 24",
    )];
    run_env(&["camera", "capture", "--gentl", cti_s], &plain, secs(60)).success();
}
