//! Issue 44: camera settings from the configuration (`camera.user_set`, `[camera.features]`)
//! applied through the GenApi before every capture, against our simulated camera on loopback
//! (ephemeral ports).

use std::time::Duration;

use handeye_gige::decode::pfnc;
use handeye_gige::sim::{SceneSource, SimCamera, SimOptions, VendorHabits};
use handeye_gige::{ControlConfig, GigeCamera};
use handeye_hal::{CameraSettings, FeatureValue};

fn sim(habits: VendorHabits) -> SimCamera {
    SimCamera::spawn(
        "127.0.0.1:0".parse().expect("addr"),
        Box::new(SceneSource::new(64, 48)),
        SimOptions {
            frame_rate: 50.0,
            habits,
            ..SimOptions::default()
        },
    )
    .expect("sim")
}

fn fast() -> ControlConfig {
    ControlConfig {
        timeout: Duration::from_millis(200),
        tries: 3,
        heartbeat_timeout: Duration::from_millis(900),
        ..ControlConfig::default()
    }
}

fn text(name: &str, v: &str) -> (String, FeatureValue) {
    (name.into(), FeatureValue::Text(v.into()))
}

fn capture_format(cam: &GigeCamera) -> Result<u32, String> {
    let (raw, _) = cam
        .capture_raw_blocking(1, Duration::from_secs(2))
        .map_err(|e| e.to_string())?;
    Ok(raw[0]
        .parts
        .iter()
        .map(|(p, _)| p.pixel_format)
        .find(|f| *f != pfnc::MONO16)
        .expect("a range part"))
}

/// Issue 44: nothing of the camera could be set from handeye but the exposure (the pixel
/// format had to be chosen in the vendor's tool). `[camera.features]` now writes the pixel
/// format, in the order given, before the capture reads the Scan3d parameters: a C16 depth map
/// comes out as the same points.
#[test]
fn issue_44_features_are_written_in_order_before_the_capture() {
    let s = sim(VendorHabits::default());
    let mut cam = GigeCamera::connect(s.addr(), fast()).expect("connect");
    assert_eq!(capture_format(&cam), Ok(pfnc::COORD3D_ABC32F));
    // In order: the selector first, then the feature it selects (the last write wins).
    cam.options.settings.features = vec![
        text("PixelFormat", "Coord3D_ABC32f"),
        text("ComponentSelector", "Confidence"),
        ("ComponentEnable".into(), FeatureValue::Bool(true)),
        text("PixelFormat", "Coord3D_C16"),
    ];
    assert_eq!(capture_format(&cam), Ok(pfnc::COORD3D_C16));
    let (clouds, _) = cam
        .capture_blocking(1, Duration::from_secs(2))
        .expect("capture");
    // Not asked for by the capture: the configured ComponentEnable switched it on.
    assert!(
        clouds[0].confidence.is_some(),
        "confidence enabled by the features"
    );
    let truth = SceneSource::new(64, 48).render();
    let mut compared = 0;
    for (p, t) in clouds[0].points.iter().zip(&truth.points) {
        if t.z.is_finite() && p.z.is_finite() {
            assert!((p - t).norm() < 2e-4, "{p:?} vs {t:?}");
            compared += 1;
        }
    }
    assert!(compared > 64 * 48 / 2, "{compared}");
}

/// Issue 44: a value outside the feature's range or entries is refused before anything
/// streams, naming the setting, the camera and what the feature accepts.
#[test]
fn issue_44_a_refused_feature_names_itself_its_range_and_the_camera() {
    let s = sim(VendorHabits::default());
    let mut cam = GigeCamera::connect(s.addr(), fast()).expect("connect");
    // (the configured features, what the refusal must say)
    type Case = (Vec<(String, FeatureValue)>, &'static [&'static str]);
    let cases: [Case; 5] = [
        (
            vec![("Width".into(), FeatureValue::Int(100_000))],
            &["camera.features.Width = 100000", "SimCam3D", "16..=64"],
        ),
        (
            vec![text("PixelFormat", "Mono8")],
            &["PixelFormat", "Coord3D_ABC32f, Coord3D_C16"],
        ),
        (
            vec![("PixelFormat".into(), FeatureValue::Int(3))],
            &[
                "takes an entry's name",
                "one of Coord3D_ABC32f, Coord3D_C16",
            ],
        ),
        (
            vec![("NoSuchFeature".into(), FeatureValue::Int(3))],
            &["NoSuchFeature", "no such feature"],
        ),
        (
            vec![("PayloadSize".into(), FeatureValue::Int(3))],
            &["PayloadSize", "not writable"],
        ),
    ];
    for (features, wanted) in cases {
        cam.options.settings.features = features;
        let e = capture_format(&cam).expect_err("refused");
        for w in wanted {
            assert!(e.contains(w), "{w:?} not in: {e}");
        }
        assert_eq!(s.stats().frames, 0, "nothing streamed: {e}");
        assert!(!s.is_acquiring());
    }
}

/// Issue 44: `camera.user_set` loads the user set (UserSetSelector, UserSetLoad) before the
/// features are written; a set the camera lacks is refused with its entries.
#[test]
fn issue_44_user_set_is_loaded_before_the_features() {
    let s = sim(VendorHabits::default());
    let mut cam = GigeCamera::connect(s.addr(), fast()).expect("connect");
    // The simulated camera's UserSet1 holds Coord3D_C16.
    cam.options.settings = CameraSettings {
        user_set: Some("UserSet1".into()),
        features: Vec::new(),
    };
    assert_eq!(capture_format(&cam), Ok(pfnc::COORD3D_C16));
    cam.options.settings.user_set = Some("Default".into());
    assert_eq!(capture_format(&cam), Ok(pfnc::COORD3D_ABC32F));
    // Loaded first: a feature after it wins.
    cam.options.settings = CameraSettings {
        user_set: Some("UserSet1".into()),
        features: vec![text("PixelFormat", "Coord3D_ABC32f")],
    };
    assert_eq!(capture_format(&cam), Ok(pfnc::COORD3D_ABC32F));
    cam.options.settings.user_set = Some("UserSet7".into());
    let e = capture_format(&cam).expect_err("no such set");
    assert!(
        e.contains("camera.user_set = \"UserSet7\"") && e.contains("Default, UserSet1"),
        "{e}"
    );
}

/// Issue 44: `handeye camera probe` lists the features a user would set, with their value,
/// range or entries and access.
#[test]
fn issue_44_probe_lists_the_settable_features() {
    let s = sim(VendorHabits {
        software_trigger: true,
        ..VendorHabits::default()
    });
    let cam = GigeCamera::connect(s.addr(), fast()).expect("connect");
    let list = cam.user_features_blocking().expect("probe");
    let get = |n: &str| {
        list.iter()
            .find(|f| f.name == n)
            .unwrap_or_else(|| panic!("{n} not in {list:?}"))
    };
    let pf = get("PixelFormat");
    assert_eq!(pf.value.as_deref(), Some("Coord3D_ABC32f"));
    assert_eq!(
        pf.allowed.as_deref(),
        Some("one of Coord3D_ABC32f, Coord3D_C16")
    );
    assert_eq!(pf.access, "read/write");
    assert_eq!(get("TriggerMode").value.as_deref(), Some("On"));
    assert_eq!(get("Scan3dOutputMode").kind, "Enumeration");
    assert_eq!(get("UserSetSelector").value.as_deref(), Some("Default"));
    assert!(list.iter().all(|f| f.name != "Width"), "not a 3D setting");
}

/// Issue 44: what the description alone refuses (an entry the enumeration lacks, a feature the
/// camera lacks or handeye sets itself, a value of the wrong kind, a user set that is no
/// entry) is found by `info`, which the run's preflight calls before the arm moves.
#[test]
fn issue_44_settings_the_description_refuses_fail_in_info_before_a_capture() {
    let s = sim(VendorHabits::default());
    let mut cam = GigeCamera::connect(s.addr(), fast()).expect("connect");
    cam.info_blocking().expect("no settings: info");
    let cases: [(CameraSettings, &str); 5] = [
        (
            CameraSettings {
                user_set: None,
                features: vec![text("PixelFormat", "Mono8")],
            },
            "PixelFormat has no entry `Mono8`; entries: Coord3D_ABC32f, Coord3D_C16",
        ),
        (
            CameraSettings {
                user_set: None,
                features: vec![("Gain".into(), FeatureValue::Float(2.0))],
            },
            "camera.features.Gain = 2: the camera handeye SimCam3D refuses it: the camera has no such feature",
        ),
        (
            CameraSettings {
                user_set: None,
                features: vec![("TriggerMode".into(), FeatureValue::Text("On".into()))],
            },
            "handeye sets TriggerMode itself (camera.trigger)",
        ),
        (
            CameraSettings {
                user_set: None,
                features: vec![("Width".into(), FeatureValue::Text("wide".into()))],
            },
            "Width is Integer and takes a whole number",
        ),
        (
            CameraSettings {
                user_set: Some("UserSet7".into()),
                features: Vec::new(),
            },
            "UserSetSelector has no entry `UserSet7`; entries: Default, UserSet1",
        ),
    ];
    for (settings, wanted) in cases {
        cam.options.settings = settings;
        let e = cam.info_blocking().expect_err("refused").to_string();
        assert!(e.contains(wanted), "{wanted:?} not in: {e}");
    }
}
