//! Our driver against our simulated camera, on loopback (ephemeral ports).

use std::time::{Duration, Instant};

use handeye_gige::decode::{pfnc, Scan3d};
use handeye_gige::genicam::FeatureKind;
use handeye_gige::sim::{SceneSource, SimCamera, SimOptions, VendorHabits};
use handeye_gige::{discover, ControlConfig, GigeCamera, GigeError, GvcpClient};
use handeye_hal::{CaptureSettings, DepthCamera, PointCloud};

fn sim(opts: SimOptions) -> SimCamera {
    SimCamera::spawn(
        "127.0.0.1:0".parse().expect("addr"),
        Box::new(SceneSource::new(64, 48)),
        opts,
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

#[test]
fn discovery_info_and_features() {
    let s = sim(SimOptions {
        serial: "ABC123".into(),
        ..SimOptions::default()
    });
    let found = discover(s.addr(), Duration::from_millis(300)).expect("discover");
    assert_eq!(found.len(), 1);
    assert_eq!(found[0].info.serial, "ABC123");
    assert_eq!(found[0].info.model, "SimCam3D");
    let cam = GigeCamera::connect(s.addr(), fast()).expect("connect");
    let info = cam.info_blocking().expect("info");
    assert_eq!((info.width, info.height), (64, 48));
    assert_eq!(info.pixel_formats, vec!["Coord3D_ABC32f", "Coord3D_C16"]);
    cam.with_features(|n, p| {
        n.set_integer(p, "Width", 32)?;
        assert_eq!(n.integer(p, "Width")?, 32);
        assert_eq!(n.integer(p, "PayloadSize")?, 32 * 48 * 12);
        n.set_enum(p, "PixelFormat", "Coord3D_C16")?;
        assert_eq!(n.enum_symbol(p, "PixelFormat")?, "Coord3D_C16");
        assert_eq!(n.integer(p, "PayloadSize")?, 32 * 48 * 2);
        assert!(n.set_integer(p, "Width", 100_000).is_err());
        assert!(n.set_enum(p, "PixelFormat", "Mono8").is_err());
        assert_eq!(n.integer(p, "GevTimestampTickFrequency")?, 1_000_000_000);
        Ok(())
    })
    .expect("features");
}

fn check_scene(clouds: &[handeye_hal::PointCloud], w: u32, h: u32, tol: f32) {
    let truth = SceneSource::new(64, 48).render();
    let (ox, oy) = ((64 - w) / 2, (48 - h) / 2);
    for c in clouds {
        assert_eq!((c.width, c.height), (w, h));
        let mut compared = 0;
        for v in 0..h {
            for u in 0..w {
                let p = c.points[(v * w + u) as usize];
                let t = truth.points[((v + oy) * 64 + u + ox) as usize];
                assert_eq!(p.z.is_nan(), t.z.is_nan(), "validity at {u},{v}");
                if !t.z.is_nan() {
                    assert!((p - t).norm() < tol, "{u},{v}: {p:?} vs {t:?}");
                    compared += 1;
                }
            }
        }
        assert!(compared > (w * h / 2) as usize);
    }
}

#[test]
fn capture_abc32f_and_c16_through_the_depth_camera_trait() {
    let s = sim(SimOptions {
        frame_rate: 50.0,
        ..SimOptions::default()
    });
    let cam = GigeCamera::connect(s.addr(), fast()).expect("connect");
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("rt");
    let settings = CaptureSettings {
        frames: 2,
        frame_timeout: Duration::from_secs(2),
        exposure: None,
    };
    let clouds = rt.block_on(cam.capture(&settings)).expect("capture");
    check_scene(&clouds, 64, 48, 1e-5);
    assert!(!s.is_acquiring(), "acquisition stopped after capture");
    cam.with_features(|n, p| {
        n.set_enum(p, "PixelFormat", "Coord3D_C16")?;
        n.set_integer(p, "Width", 40)
    })
    .expect("C16");
    let clouds = rt.block_on(cam.capture(&settings)).expect("capture C16");
    // 0.1 mm depth quantization; x, y rebuilt from the published intrinsics.
    check_scene(&clouds, 40, 48, 2e-4);
}

#[test]
fn packet_loss_is_repaired_by_resend_and_confidence_arrives_multipart() {
    let s = sim(SimOptions {
        loss_ratio: 0.05,
        frame_rate: 30.0,
        seed: 3,
        ..SimOptions::default()
    });
    let mut cam = GigeCamera::connect(s.addr(), fast()).expect("connect");
    cam.options.packet_size = 600;
    cam.options.confidence = true;
    let (clouds, stats) = cam
        .capture_blocking(3, Duration::from_secs(2))
        .expect("capture");
    assert_eq!(clouds.len(), 3);
    assert!(stats.resent_packets > 0, "{stats:?}");
    assert!(s.stats().dropped_packets > 0);
    check_scene(&clouds, 64, 48, 1e-5);
    let conf = clouds[0].confidence.as_ref().expect("confidence part");
    assert_eq!(conf.len(), 64 * 48);
    assert!(
        conf.iter().any(|&c| (c - 1.0).abs() < 1e-3) && conf.iter().any(|&c| c < 0.9 && c > 0.7)
    );
}

#[test]
fn second_controller_is_refused_and_writes_need_control() {
    let s = sim(SimOptions::default());
    let a = GvcpClient::connect(s.addr(), fast()).expect("a");
    let b = GvcpClient::connect(s.addr(), fast()).expect("b");
    let guard = a.take_control().expect("control");
    let e = b.take_control().expect_err("second controller");
    assert!(matches!(e, GigeError::ControlLost { .. }), "{e}");
    let e = b.write_reg(0xA000, 32).expect_err("write without control");
    assert!(e.to_string().contains("ACCESS_DENIED"), "{e}");
    assert_eq!(b.read_reg(0xA000).expect("reads are free"), 64);
    let e = a.read_reg(0x0003).expect_err("unaligned");
    assert!(
        e.to_string().contains("BAD_ALIGNMENT") || e.to_string().contains("INVALID_ADDRESS"),
        "{e}"
    );
    let e = a.read_mem(0x0FFF_0000, 8).expect_err("out of range");
    assert!(e.to_string().contains("INVALID_ADDRESS"), "{e}");
    // Issue 23: a heartbeat timeout of days would let a dead client hold the camera that
    // long: 0.5 s to 10 min are taken.
    const HEARTBEAT_TIMEOUT: u32 = 0x0938;
    for ms in [499, 600_001, u32::MAX] {
        let e = a
            .write_reg(HEARTBEAT_TIMEOUT, ms)
            .expect_err("out of range");
        assert!(e.to_string().contains("INVALID_PARAMETER"), "{ms}: {e}");
    }
    a.write_reg(HEARTBEAT_TIMEOUT, 600_000).expect("10 min");
    a.write_reg(HEARTBEAT_TIMEOUT, 3000).expect("3 s");
    guard.check().expect("still in control");
    drop(guard);
    b.take_control().expect("released on drop");
}

#[test]
fn a_silent_camera_is_a_clear_timeout() {
    let s = sim(SimOptions {
        frame_rate: 20.0,
        ..SimOptions::default()
    });
    let addr = s.addr();
    let cam = GigeCamera::connect(addr, fast()).expect("connect");
    drop(s); // the camera goes away
    let t = Instant::now();
    let e = cam
        .capture_blocking(1, Duration::from_millis(300))
        .expect_err("no camera");
    assert!(e.to_string().contains("did not answer"), "{e}");
    assert!(t.elapsed() < Duration::from_secs(5));
}

#[test]
fn camera_that_stops_streaming_mid_capture_is_a_frame_timeout() {
    let s = sim(SimOptions {
        frame_rate: 0.2,
        ..SimOptions::default()
    });
    let cam = GigeCamera::connect(s.addr(), fast()).expect("connect");
    // One frame arrives at once, the next only after 5 s: the 300 ms frame timeout trips.
    let e = cam
        .capture_blocking(2, Duration::from_millis(300))
        .expect_err("stalls");
    assert!(matches!(e, GigeError::FrameTimeout { .. }), "{e}");
}

/// Issue 16: options the streaming thread would turn into a panic (a zero or NaN bandwidth, an
/// infinite frame rate) are refused when the camera is started.
#[test]
fn issue_16_unusable_options_are_refused_at_start() {
    for opts in [
        SimOptions {
            bandwidth_bps: Some(0.0),
            ..SimOptions::default()
        },
        SimOptions {
            bandwidth_bps: Some(f64::NAN),
            ..SimOptions::default()
        },
        SimOptions {
            frame_rate: f64::INFINITY,
            ..SimOptions::default()
        },
        SimOptions {
            loss_ratio: 1.0,
            ..SimOptions::default()
        },
    ] {
        let e = SimCamera::spawn(
            "127.0.0.175:0".parse().expect("addr"),
            Box::new(SceneSource::new(64, 48)),
            opts,
        )
        .expect_err("refused");
        assert!(matches!(e, GigeError::InvalidArgument(_)), "{e}");
    }
}

/// Issue 35: five Allied Vision cameras declare `TLParamsLocked` a Boolean. The driver wrote it
/// as an Integer, and the capture aborted before `AcquisitionStart`.
#[test]
fn capture_with_a_boolean_tl_params_locked() {
    let s = sim(SimOptions {
        frame_rate: 50.0,
        habits: VendorHabits {
            tl_params_locked_boolean: true,
            ..VendorHabits::default()
        },
        ..SimOptions::default()
    });
    let cam = GigeCamera::connect(s.addr(), fast()).expect("connect");
    cam.with_features(|n, _| {
        assert_eq!(n.kind("TLParamsLocked"), Some(FeatureKind::Boolean));
        Ok(())
    })
    .expect("features");
    let (clouds, _) = cam
        .capture_blocking(1, Duration::from_secs(2))
        .expect("capture");
    check_scene(&clouds, 64, 48, 1e-5);
    assert!(!s.is_acquiring(), "acquisition stopped after capture");
    assert!(
        cam.with_features(|n, p| n.boolean(p, "TLParamsLocked"))
            .is_ok_and(|locked| !locked),
        "unlocked after the capture"
    );
}

fn habits(h: VendorHabits) -> SimOptions {
    SimOptions {
        frame_rate: 50.0,
        habits: h,
        ..SimOptions::default()
    }
}

/// Issue 35: Photoneo-like cameras send their intensity as the first part of a multi-part
/// payload. The driver asked for multi-part only with `--confidence` and took the first part
/// (Mono16: UnsupportedFormat); now it asks whenever Range is offered and picks the range part.
#[test]
fn intensity_first_multipart_is_decoded_from_its_range_part() {
    let s = sim(habits(VendorHabits {
        intensity_first: true,
        ..VendorHabits::default()
    }));
    let cam = GigeCamera::connect(s.addr(), fast()).expect("connect");
    let (raw, _) = cam
        .capture_raw_blocking(1, Duration::from_secs(2))
        .expect("raw");
    let kinds: Vec<u32> = raw[0].parts.iter().map(|(p, _)| p.pixel_format).collect();
    assert_eq!(
        kinds,
        [pfnc::MONO16, pfnc::COORD3D_ABC32F],
        "intensity first, then range"
    );
    let (clouds, _) = cam
        .capture_blocking(2, Duration::from_secs(2))
        .expect("capture");
    check_scene(&clouds, 64, 48, 1e-5);
    let intensity = clouds[0].intensity.as_ref().expect("intensity part");
    assert_eq!(intensity.len(), 64 * 48);
}

/// Issue 35: a chunk-only payload (GVSP payload type 4, Photoneo's other mode) was counted as
/// an incomplete frame; its range chunk is now found and decoded.
#[test]
fn chunk_only_payloads_are_decoded() {
    for confidence in [false, true] {
        let s = sim(habits(VendorHabits {
            chunk_only: true,
            intensity_first: true,
            ..VendorHabits::default()
        }));
        let mut cam = GigeCamera::connect(s.addr(), fast()).expect("connect");
        cam.options.confidence = confidence;
        let (clouds, stats) = cam
            .capture_blocking(2, Duration::from_secs(2))
            .expect("capture");
        assert_eq!(stats.incomplete, 0, "{stats:?}");
        check_scene(&clouds, 64, 48, 1e-5);
        // C16 depth in a chunk, with the scale of the (only) coordinate.
        cam.with_features(|n, p| n.set_enum(p, "PixelFormat", "Coord3D_C16"))
            .expect("C16");
        let (clouds, _) = cam
            .capture_blocking(1, Duration::from_secs(2))
            .expect("capture C16");
        check_scene(&clouds, 64, 48, 2e-4);
    }
}

/// Issue 35: Nerian's description has no Scan3dCoordinateSelector and no Scan3dDistanceUnit.
/// The scale was read only through the selector (a C16 depth map came out 10 times too far);
/// the unit defaults to millimetres.
#[test]
fn scale_without_a_selector_and_no_distance_unit() {
    let s = sim(habits(VendorHabits {
        no_coordinate_selector: true,
        no_distance_unit: true,
        ..VendorHabits::default()
    }));
    let cam = GigeCamera::connect(s.addr(), fast()).expect("connect");
    cam.with_features(|n, p| {
        assert!(!n.has("Scan3dCoordinateSelector") && !n.has("Scan3dDistanceUnit"));
        n.set_enum(p, "PixelFormat", "Coord3D_C16")
    })
    .expect("C16");
    let scan3d = cam.scan3d_blocking().expect("scan3d");
    assert_eq!(scan3d.metres_per_unit, 0.001);
    assert!((scan3d.scale[2] - 0.1).abs() < 1e-12, "{scan3d:?}");
    let (clouds, _) = cam
        .capture_blocking(1, Duration::from_secs(2))
        .expect("capture");
    check_scene(&clouds, 64, 48, 2e-4);
}

/// Issue 35: `Scan3dAspectRatio` (pixels taller than wide) was ignored: a depth map's y came
/// out short by the ratio.
#[test]
fn aspect_ratio_of_depth_maps_is_honoured() {
    let source = SceneSource::new(64, 48).with_aspect_ratio(1.25);
    let truth = source.render();
    let s = SimCamera::spawn(
        "127.0.0.1:0".parse().expect("addr"),
        Box::new(source),
        habits(VendorHabits {
            aspect_ratio: true,
            ..VendorHabits::default()
        }),
    )
    .expect("sim");
    let cam = GigeCamera::connect(s.addr(), fast()).expect("connect");
    cam.with_features(|n, p| n.set_enum(p, "PixelFormat", "Coord3D_C16"))
        .expect("C16");
    assert_eq!(cam.scan3d_blocking().expect("scan3d").aspect_ratio, 1.25);
    let (clouds, _) = cam
        .capture_blocking(1, Duration::from_secs(2))
        .expect("capture");
    let mut compared = 0;
    for (p, t) in clouds[0].points.iter().zip(&truth.points) {
        if t.z.is_finite() && p.z.is_finite() {
            assert!((p - t).norm() < 2e-4, "{p:?} vs {t:?}");
            compared += 1;
        }
    }
    assert!(compared > 64 * 48 / 2, "{compared}");
}

/// Issue 35: an output mode its pixel format does not carry (ProjectedC, a depth map's mode,
/// with Coord3D_ABC32f) is a clear error naming the setting, before anything streams.
#[test]
fn projected_c_is_a_clear_error() {
    let s = sim(habits(VendorHabits {
        projected_c: true,
        ..VendorHabits::default()
    }));
    let cam = GigeCamera::connect(s.addr(), fast()).expect("connect");
    let e = cam
        .capture_blocking(1, Duration::from_secs(2))
        .expect_err("ProjectedC")
        .to_string();
    assert!(
        e.contains("Scan3dOutputMode")
            && e.contains("ProjectedC")
            && e.contains("CalibratedABC_Grid"),
        "{e}"
    );
    assert!(!s.is_acquiring());
    assert_eq!(s.stats().frames, 0);
}

/// A capture of `source`'s scene through the plain path: the simulated camera by SFNC's
/// letter, Coord3D_ABC32f in millimetres.
fn plain_capture(source: SceneSource) -> handeye_hal::PointCloud {
    let s = SimCamera::spawn(
        "127.0.0.1:0".parse().expect("addr"),
        Box::new(source),
        habits(VendorHabits::default()),
    )
    .expect("sim");
    let cam = GigeCamera::connect(s.addr(), fast()).expect("connect");
    let (mut clouds, _) = cam
        .capture_blocking(1, Duration::from_secs(2))
        .expect("plain capture");
    clouds.remove(0)
}

/// `got` holds the points of `plain` (same validity) within the quantisation of the format
/// `s` describes: half a step per coordinate for 16-bit XYZ, half a depth step carried along
/// the pixel's ray for 16-bit depth maps, f32 rounding for float formats.
fn assert_same_points(
    got: &handeye_hal::PointCloud,
    plain: &handeye_hal::PointCloud,
    s: &Scan3d,
    format: &str,
) -> usize {
    assert_eq!((got.width, got.height), (plain.width, plain.height));
    let m = s.metres_per_unit;
    let mut compared = 0;
    for v in 0..got.height as usize {
        for u in 0..got.width as usize {
            let i = v * got.width as usize + u;
            let (g, p) = (got.points[i], plain.points[i]);
            assert_eq!(g.z.is_nan(), p.z.is_nan(), "{format}: validity at {u},{v}");
            if p.z.is_nan() {
                continue;
            }
            let bound: [f64; 3] = match format {
                "Coord3D_ABC16" | "Coord3D_ABCY16" => std::array::from_fn(|k| s.scale[k] / 2.0 * m),
                "Coord3D_C16" => {
                    let dz = s.scale[2] / 2.0 * m;
                    let (cu, cv) = s.principal_point;
                    [
                        dz * (u as f64 - cu).abs() / s.focal_length,
                        dz * (v as f64 - cv).abs() / (s.focal_length * s.aspect_ratio),
                        dz,
                    ]
                }
                _ => [0.0; 3],
            };
            for k in 0..3 {
                let d = f64::from((g[k] - p[k]).abs());
                assert!(
                    d <= bound[k] + 1e-6,
                    "{format}: coordinate {k} at {u},{v} off by {d} m (bound {} m): {g:?} vs {p:?}",
                    bound[k]
                );
            }
            compared += 1;
        }
    }
    assert!(compared > got.points.len() / 2, "{format}: {compared}");
    compared
}

/// Capture one frame in `format` and compare it with the plain path.
fn capture_in(cam: &GigeCamera, format: &str, plain: &handeye_hal::PointCloud) -> PointCloud {
    cam.with_features(|n, p| n.set_enum(p, "PixelFormat", format))
        .expect(format);
    let s = cam.scan3d_blocking().expect("scan3d");
    let (mut clouds, stats) = cam
        .capture_blocking(1, Duration::from_secs(2))
        .unwrap_or_else(|e| panic!("{format}: {e}"));
    assert_eq!(stats.incomplete, 0);
    let cloud = clouds.remove(0);
    assert_same_points(&cloud, plain, &s, format);
    cloud
}

/// Issue 44: Photoneo sends n components as n + 1 parts, the last chunk data. Any chunk part
/// sent the whole frame to the chunk-only path, which looked for the range among the chunks:
/// "malformed chunk payload: no chunk holds the range image", on every frame.
#[test]
fn issue_44_multipart_with_a_chunk_part_is_decoded_from_its_image_parts() {
    let plain = plain_capture(SceneSource::new(64, 48));
    let s = sim(habits(VendorHabits {
        intensity_first: true,
        chunk_part: true,
        ..VendorHabits::default()
    }));
    let mut cam = GigeCamera::connect(s.addr(), fast()).expect("connect");
    cam.options.confidence = true;
    let (raw, _) = cam
        .capture_raw_blocking(1, Duration::from_secs(2))
        .expect("raw");
    let kinds: Vec<u16> = raw[0].parts.iter().map(|(p, _)| p.data_type).collect();
    assert_eq!(
        kinds,
        [1, 5, 9, 10],
        "intensity, range, confidence, chunk data"
    );
    let cloud = capture_in(&cam, "Coord3D_ABC32f", &plain);
    assert!(cloud.intensity.is_some() && cloud.confidence.is_some());
    capture_in(&cam, "Coord3D_C16", &plain);
}

/// Issue 44: Basler's blaze selects the invalid value per coordinate and flags only C (0);
/// the driver read it once, at C, and dropped every valid point whose X or Y is 0 (a source
/// of odd size has a column at x = 0 and a row at y = 0).
#[test]
fn issue_44_invalid_value_is_read_per_coordinate() {
    let plain = plain_capture(SceneSource::new(63, 47));
    let s = SimCamera::spawn(
        "127.0.0.1:0".parse().expect("addr"),
        Box::new(SceneSource::new(63, 47)),
        habits(VendorHabits {
            per_coordinate_invalid: true,
            ..VendorHabits::default()
        }),
    )
    .expect("sim");
    let cam = GigeCamera::connect(s.addr(), fast()).expect("connect");
    let s3 = cam.scan3d_blocking().expect("scan3d");
    assert_eq!(s3.invalid_value, [None, None, Some(0.0)]);
    let on_axis = plain
        .points
        .iter()
        .filter(|p| p.x == 0.0 || p.y == 0.0)
        .count();
    assert!(
        on_axis > 50,
        "{on_axis} points with x or y = 0 in the scene"
    );
    capture_in(&cam, "Coord3D_ABC32f", &plain);
    capture_in(&cam, "Coord3D_C16", &plain);
}

/// Issue 44: Lucid's Helios2 streams Coord3D_ABCY16 (or ABC16, C16; 0.25 mm steps, 65535
/// invalid per coordinate) and publishes its intrinsics as CalibFocalLengthX/Y and
/// CalibOpticalCenterX/Y: "not a supported 3D format".
#[test]
fn issue_44_lucid_abcy16_abc16_and_calib_intrinsics() {
    let source = || SceneSource::new(64, 48).with_aspect_ratio(1.25);
    let plain = plain_capture(source());
    let s = SimCamera::spawn(
        "127.0.0.1:0".parse().expect("addr"),
        Box::new(source()),
        habits(VendorHabits {
            lucid: true,
            ..VendorHabits::default()
        }),
    )
    .expect("sim");
    let cam = GigeCamera::connect(s.addr(), fast()).expect("connect");
    cam.with_features(|n, _| {
        assert!(!n.has("Scan3dFocalLength") && n.has("CalibFocalLengthY"));
        Ok(())
    })
    .expect("features");
    let abcy = capture_in(&cam, "Coord3D_ABCY16", &plain);
    let y = abcy.intensity.expect("Y as intensity");
    assert_eq!(y.len(), 64 * 48);
    assert!(y.iter().any(|&g| g > 0.3) && y.contains(&0.0));
    assert!(capture_in(&cam, "Coord3D_ABC16", &plain)
        .intensity
        .is_none());
    let s3 = cam.scan3d_blocking().expect("scan3d");
    assert_eq!(s3.invalid_value, [Some(65535.0); 3]);
    capture_in(&cam, "Coord3D_C16", &plain);
    let s3 = cam.scan3d_blocking().expect("scan3d");
    assert!((s3.aspect_ratio - 1.25).abs() < 1e-12, "{s3:?}");
}

/// Issue 44: SICK's Visionary sends Coord3D_C16 depth maps in ProjectedC, with
/// Scan3dFocalLength, principal point and aspect ratio, a selector that lists only
/// CoordinateC, and chunk data: refused by the output-mode check, and "has no entry
/// CoordinateA" once past it.
#[test]
fn issue_44_projected_c_depth_maps_with_only_coordinate_c() {
    let source = || SceneSource::new(64, 48).with_aspect_ratio(1.25);
    let plain = plain_capture(source());
    let s = SimCamera::spawn(
        "127.0.0.1:0".parse().expect("addr"),
        Box::new(source()),
        habits(VendorHabits {
            projected_c: true,
            only_coordinate_c: true,
            aspect_ratio: true,
            chunk_part: true,
            intensity_first: true,
            ..VendorHabits::default()
        }),
    )
    .expect("sim");
    let cam = GigeCamera::connect(s.addr(), fast()).expect("connect");
    let cloud = capture_in(&cam, "Coord3D_C16", &plain);
    assert!(cloud.intensity.is_some());
    assert_eq!(
        cam.with_features(|n, p| n.enum_symbol(p, "Scan3dOutputMode"))
            .expect("mode"),
        "ProjectedC"
    );
}

/// Issue 44: Photoneo's examples leave TriggerMode = On, TriggerSource = Software; the driver
/// never cleared it nor sent TriggerSoftware: "no complete frame within …". Free clears it;
/// software sends one TriggerSoftware per frame.
#[test]
fn issue_44_trigger_mode_left_on_is_cleared_or_used() {
    let s = sim(habits(VendorHabits {
        software_trigger: true,
        ..VendorHabits::default()
    }));
    let mut cam = GigeCamera::connect(s.addr(), fast()).expect("connect");
    assert_eq!(
        cam.with_features(|n, p| n.enum_symbol(p, "TriggerMode"))
            .expect("mode"),
        "On"
    );
    let (clouds, _) = cam
        .capture_blocking(2, Duration::from_secs(2))
        .expect("free");
    check_scene(&clouds, 64, 48, 1e-5);
    assert_eq!(
        cam.with_features(|n, p| n.enum_symbol(p, "TriggerMode"))
            .expect("mode"),
        "Off"
    );
    cam.options.trigger = handeye_hal::Trigger::Software;
    let before = s.stats().frames;
    let (clouds, _) = cam
        .capture_blocking(3, Duration::from_secs(2))
        .expect("software");
    check_scene(&clouds, 64, 48, 1e-5);
    assert_eq!(
        s.stats().frames - before,
        3,
        "one frame per TriggerSoftware"
    );
    // A camera without trigger features cannot do software triggering: said so.
    let plain = sim(habits(VendorHabits::default()));
    let mut cam = GigeCamera::connect(plain.addr(), fast()).expect("connect");
    cam.options.trigger = handeye_hal::Trigger::Software;
    let e = cam
        .capture_blocking(1, Duration::from_secs(2))
        .expect_err("no trigger")
        .to_string();
    assert!(e.contains("camera.trigger = \"free\""), "{e}");
}

/// Issue 46: a capture killed mid-stream leaves the camera streaming with `TLParamsLocked = 1`
/// after its heartbeat expires; the next capture takes it over (stops it, unlocks it), then
/// configures and captures.
#[test]
fn issue_46_a_camera_left_streaming_and_locked_is_taken_over() {
    use handeye_gige::gvcp::{ccp, reg};
    let s = sim(SimOptions {
        frame_rate: 50.0,
        ..SimOptions::default()
    });
    let killed = GigeCamera::connect(s.addr(), fast()).expect("connect");
    // Control without a heartbeat: what a killed process leaves behind.
    killed
        .client()
        .write_reg(reg::CCP, ccp::CONTROL)
        .expect("control");
    killed
        .with_features(|n, p| {
            n.set_switch(p, "TLParamsLocked", true)?;
            n.execute(p, "AcquisitionStart")
        })
        .expect("streaming");
    drop(killed);
    // The camera lets go of the dead controller when its heartbeat expires.
    let deadline = Instant::now() + Duration::from_secs(10);
    let next = loop {
        let cam = GigeCamera::connect(s.addr(), fast()).expect("connect");
        if cam.client().take_control().is_ok() {
            break cam;
        }
        assert!(
            Instant::now() < deadline,
            "the camera never released control"
        );
        std::thread::sleep(Duration::from_millis(200));
    };
    assert!(
        next.with_features(|n, p| n.integer(p, "TLParamsLocked"))
            .is_ok_and(|v| v == 1),
        "still locked after the heartbeat expired"
    );
    let (clouds, _) = next
        .capture_blocking(1, Duration::from_secs(2))
        .expect("the next capture takes the camera over");
    check_scene(&clouds, 64, 48, 1e-5);
    assert!(!s.is_acquiring(), "acquisition stopped after capture");
}
