//! Real scans (`../shared/realdata/xarm7_realsense`, see its README): registration on data no
//! simulator here made. An Intel RealSense D4xx fixed ~1.3 m from a UFACTORY xArm7 (the whole
//! arm, a second arm and clutter in view), five arm configurations, and the data authors' own
//! estimate of `base_from_camera` (a reference good to a few millimetres, not ground truth).
//!
//! What these tests hold the core to (see the README's real-scan section for the numbers):
//! - the scan's own noise is measured, and a real sensor's is told from the simulator's;
//! - with the reference as the guess, the arm is found in every frame where the guess puts it
//!   (the guess is honoured, not lost to the global search);
//! - with or without a guess, no result far from the reference is accepted, per frame or
//!   fused.

use handeye_calib::calib::pipeline::{calibrate_frames, Calibration, Frame};
use handeye_calib::calib::range::RangeImage;
use handeye_calib::testutil::RealSet;
use nalgebra::Isometry3;

/// A result this close to the reference agrees with it (the issue's bar for an accepted
/// frame); farther and accepted is a wrong result.
const AGREE_MM: f64 = 5.0;
const AGREE_DEG: f64 = 0.5;

/// Camera-origin distance (mm) and rotation (degrees) between two `base_from_camera`.
fn apart(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    (
        (a.translation.vector - b.translation.vector).norm() * 1e3,
        (a.inverse() * b).rotation.angle().to_degrees(),
    )
}

/// Calibrates `frames` and checks the one rule no configuration may break: an accepted result
/// agrees with the reference. Returns the calibration, `None` when it fails.
fn calibrate_and_check(set: &RealSet, frames: &[Frame], guess: bool) -> Option<Calibration> {
    let names: Vec<&str> = frames.iter().map(|f| f.source.as_str()).collect();
    match calibrate_frames(&set.model, frames, &set.options(guess)) {
        Err(e) => {
            eprintln!("{names:?} (guess {guess}): {e}");
            None
        }
        Ok(c) => {
            let (mm, deg) = apart(&c.base_from_camera, &set.reference);
            let accepted = c.verdict.passed();
            eprintln!(
                "{names:?} (guess {guess}): {mm:.1} mm, {deg:.2}° from the reference, accepted {accepted}; {:?}",
                c.verdict.reasons
            );
            assert!(
                !accepted || (mm <= AGREE_MM && deg <= AGREE_DEG),
                "{names:?}: accepted {mm:.1} mm / {deg:.2}° from the reference"
            );
            Some(c)
        }
    }
}

/// The simulated active-stereo scan request of frame `f`, seen from the reference camera pose
/// with the real intrinsics.
fn reference_request<'a>(
    set: &'a RealSet,
    f: &Frame,
    settings: &handeye_calib::sim::SimSettings,
    seed: u64,
) -> handeye_calib::sim::ScanRequest<'a> {
    use handeye_calib::geometry::Intrinsics;
    use handeye_calib::sim::{Placement, ScanRequest};
    ScanRequest::new(
        &set.model,
        f.joints.clone(),
        Placement::EyeToHand {
            model_from_camera: set.model_from_camera(),
        },
        Intrinsics::preset("realsense-d435").expect("preset"),
        settings,
        seed,
    )
}

#[test]
fn a_real_sensor_measures_noisier_than_the_simulated_one() {
    let Some(set) = handeye_calib::testutil::real_set() else {
        return;
    };
    for f in &set.frames {
        let noise = RangeImage::new(&f.cloud)
            .expect("a scan")
            .noise_m()
            .expect("enough flat patches");
        // A RealSense at 0.8–1.8 m: about 0.7 mm (1 mm depth steps, stereo noise).
        assert!(
            (0.4e-3..1.5e-3).contains(&noise),
            "{}: {:.3} mm",
            f.source,
            noise * 1e3
        );
    }
    // The simulator's structured-light camera, where the registration's distances were chosen.
    let Some(ur5e) = handeye_calib::testutil::shared_robot("ur/ur5e/ur5e.urdf") else {
        return;
    };
    let cfg = handeye_calib::bench::BenchConfig {
        views: 2,
        scans_per_view: 1,
        ..Default::default()
    };
    let plan = handeye_calib::bench::plan_trials(&ur5e, &cfg).expect("views");
    for (q, seeds) in plan.views.iter().zip(&plan.scan_seeds) {
        let sim =
            handeye_calib::sim::simulate_scan(&cfg.scan_request(&ur5e, q, plan.mount, seeds[0]))
                .expect("simulated");
        let noise = RangeImage::new(&sim.cloud)
            .expect("a scan")
            .noise_m()
            .expect("patches");
        assert!(noise < 0.25e-3, "simulated: {:.3} mm", noise * 1e3);
    }
}

/// The simulator's active-stereo class, fitted to these frames: a simulated scan of the xArm7
/// at each frame's joints, seen from the reference camera pose with the real intrinsics, has
/// the noise the registration measures on the real frame (within 25 %).
#[test]
fn the_simulated_active_stereo_camera_is_as_noisy_as_the_real_one() {
    use handeye_calib::sim::{simulate_scan, SimSettings};
    let Some(set) = handeye_calib::testutil::real_set() else {
        return;
    };
    let settings = SimSettings::for_camera("realsense-d435");
    for (k, f) in set.frames.iter().enumerate() {
        let real = RangeImage::new(&f.cloud)
            .expect("scan")
            .noise_m()
            .expect("patches");
        let req = reference_request(&set, f, &settings, k as u64);
        let sim = simulate_scan(&req).expect("simulated");
        let simulated = RangeImage::new(&sim.cloud)
            .expect("scan")
            .noise_m()
            .expect("patches");
        eprintln!(
            "{}: noise real {:.3} mm, simulated {:.3} mm",
            f.source,
            real * 1e3,
            simulated * 1e3
        );
        assert!(
            (0.75..1.25).contains(&(simulated / real)),
            "{}: real {:.3} mm, simulated {:.3} mm",
            f.source,
            real * 1e3,
            simulated * 1e3
        );
    }
}

/// Depth errors (metres, measured − true) of `cloud` on the robot: at every pixel whose ray
/// hits a link of `exact` (the arm rendered without noise from the same pose) at least
/// [`CORE_PX`] pixels inside the arm's outline, so that edges, flying pixels and the 1-pixel
/// uncertainty of the outline stay out of it.
fn depth_errors_on_the_arm(
    cloud: &handeye_hal::PointCloud,
    exact: &handeye_calib::sim::SimulatedScan,
) -> Vec<f64> {
    const CORE_PX: i64 = 6;
    let (w, h) = (exact.cloud.width as i64, exact.cloud.height as i64);
    let on_arm = |u: i64, v: i64| {
        (0..w).contains(&u)
            && (0..h).contains(&v)
            && exact
                .objects
                .get(exact.labels[(v * w + u) as usize] as usize)
                .is_some_and(|o| o.starts_with("link:"))
    };
    let mut errors = Vec::new();
    for v in 0..h {
        for u in 0..w {
            let i = (v * w + u) as usize;
            let (measured, truth) = (cloud.points[i].z, exact.cloud.points[i].z);
            let core = (-CORE_PX..=CORE_PX)
                .all(|dv| (-CORE_PX..=CORE_PX).all(|du| on_arm(u + du, v + dv)));
            if core && measured.is_finite() && truth.is_finite() {
                errors.push(f64::from(measured - truth));
            }
        }
    }
    errors
}

/// (median, interquartile range) of `x`, sorted in place.
fn median_iqr(x: &mut [f64]) -> (f64, f64) {
    x.sort_by(f64::total_cmp);
    let q = |p: f64| x[((x.len() - 1) as f64 * p).round() as usize];
    (q(0.5), q(0.75) - q(0.25))
}

/// The simulator's active-stereo class, fitted to these frames at the depth errors that
/// matter to the registration: on the arm itself, at the reference camera pose, the real
/// sensor's depths differ from the posed model's by a bias of about 1 % of the distance and
/// by smooth blobs of ±10–20 mm (white, glossy, weakly textured links at 1.1–1.3 m). The
/// simulated scan at the same pose must show the same distribution: median within 4 mm, and
/// interquartile range within 30 %. The histograms (printed with `--nocapture`) are the
/// README's.
#[test]
fn the_simulated_active_stereo_depth_errors_on_the_arm_match_the_real_ones() {
    use handeye_calib::sim::{simulate_scan, ScanNoise, SimSettings};
    let Some(set) = handeye_calib::testutil::real_set() else {
        return;
    };
    let settings = SimSettings::for_camera("realsense-d435");
    let exact_settings = SimSettings {
        noise: ScanNoise::none(),
        ..settings
    };
    let (mut real, mut simulated) = (Vec::new(), Vec::new());
    for (k, f) in set.frames.iter().enumerate() {
        let request = |settings: &SimSettings| reference_request(&set, f, settings, k as u64);
        let exact = simulate_scan(&request(&exact_settings)).expect("exact");
        let sim = simulate_scan(&request(&settings)).expect("simulated");
        let mut r = depth_errors_on_the_arm(&f.cloud, &exact);
        let mut s = depth_errors_on_the_arm(&sim.cloud, &exact);
        let ((rm, ri), (sm, si)) = (median_iqr(&mut r), median_iqr(&mut s));
        eprintln!(
            "{}: real median {:.1} mm IQR {:.1} mm ({} px); simulated median {:.1} mm IQR {:.1} mm ({} px)",
            f.source,
            rm * 1e3,
            ri * 1e3,
            r.len(),
            sm * 1e3,
            si * 1e3,
            s.len()
        );
        real.extend(r);
        simulated.extend(s);
    }
    let ((rm, ri), (sm, si)) = (median_iqr(&mut real), median_iqr(&mut simulated));
    eprintln!("depth error on the arm, mm | real | simulated (fraction of pixels)");
    for bin in -12..14 {
        let (lo, hi) = (f64::from(bin) * 2.5e-3, f64::from(bin + 1) * 2.5e-3);
        let share =
            |x: &[f64]| x.iter().filter(|e| (lo..hi).contains(*e)).count() as f64 / x.len() as f64;
        eprintln!(
            "{:6.1} | {:.3} | {:.3}",
            lo * 1e3,
            share(&real),
            share(&simulated)
        );
    }
    eprintln!(
        "all frames: real median {:.1} mm IQR {:.1} mm; simulated median {:.1} mm IQR {:.1} mm",
        rm * 1e3,
        ri * 1e3,
        sm * 1e3,
        si * 1e3
    );
    assert!(
        (rm - sm).abs() < 4e-3 && (0.7..1.3).contains(&(si / ri)),
        "real median {:.1} mm IQR {:.1} mm; simulated median {:.1} mm IQR {:.1} mm",
        rm * 1e3,
        ri * 1e3,
        sm * 1e3,
        si * 1e3
    );
}

/// The real setting simulated, where the truth is known: the active-stereo class rendered at
/// each frame's joints from the reference pose (the truth here), calibrated as the real frames
/// are, with and without the guess. Whatever the registration makes of depth errors like the
/// real ones, an accepted result is within the bar of the truth.
#[test]
fn on_simulated_active_stereo_scans_of_this_setting_nothing_wrong_is_accepted() {
    use handeye_calib::sim::{simulate_scan, SimSettings};
    let Some(set) = handeye_calib::testutil::real_set() else {
        return;
    };
    let settings = SimSettings::for_camera("realsense-d435");
    let frames: Vec<Frame> = set
        .frames
        .iter()
        .enumerate()
        .map(|(k, f)| {
            let req = reference_request(&set, f, &settings, 100 + k as u64);
            Frame {
                cloud: simulate_scan(&req).expect("simulated").cloud,
                source: format!("simulated {}", f.source),
                ..f.clone()
            }
        })
        .collect();
    for guess in [true, false] {
        for f in &frames {
            calibrate_and_check(&set, std::slice::from_ref(f), guess);
        }
    }
    calibrate_and_check(&set, &frames, true);
}

/// With the reference as the guess, the arm is found in each frame near where the guess puts
/// it (every link fitted at its measured joints), and an accepted result agrees with it.
#[test]
fn the_guess_is_honoured_on_every_real_frame() {
    let Some(set) = handeye_calib::testutil::real_set() else {
        return;
    };
    for f in &set.frames {
        let Some(c) = calibrate_and_check(&set, std::slice::from_ref(f), true) else {
            panic!(
                "{}: the arm was not found where the guess puts it",
                f.source
            );
        };
        // Found near the guess: the registration stayed in its basin. (How near is what the
        // real-scan work measures; 10 cm / 5° is the basin, not the accuracy.)
        let (mm, deg) = apart(&c.base_from_camera, &set.reference);
        assert!(
            mm < 100.0 && deg < 5.0,
            "{}: {mm:.1} mm / {deg:.2}°",
            f.source
        );
    }
    // All five configurations fused.
    calibrate_and_check(&set, &set.frames, true);
}

/// Without a guess the global search finds the arm among the second arm, the monitor, cables
/// and boxes, as an object standing on the table: on every frame it ends where the reference
/// as a guess ends (11–36 mm / 0.5–1.1° from it: the frames' depth errors, not the search,
/// keep it there), never half-turned, and nothing it returns is accepted far from the
/// reference.
#[test]
fn without_a_guess_the_arm_is_found_among_the_clutter() {
    let Some(set) = handeye_calib::testutil::real_set() else {
        return;
    };
    assert_found_everywhere(&set, &set.frames);
}

/// Every frame of `frames`, calibrated without a guess, is found: where the reference as a
/// guess ends (not half-turned, not on the second arm), and not accepted unless it agrees
/// with the reference.
fn assert_found_everywhere(set: &RealSet, frames: &[Frame]) {
    for f in frames {
        let apart = search_apart_from_guess(set, f);
        assert!(
            apart.is_some_and(|(mm, deg)| mm <= SAME_MM && deg <= SAME_DEG),
            "{}: the arm was not found ({apart:?} mm / ° from where the guess ends)",
            f.source
        );
    }
}

/// How far (mm, °) the search without a guess ends from where the reference as a guess
/// ends on frame `f`; `None` when it finds nothing. Nothing far from the reference may be
/// accepted ([`calibrate_and_check`]).
fn search_apart_from_guess(set: &RealSet, f: &Frame) -> Option<(f64, f64)> {
    let one = std::slice::from_ref(f);
    let searched = calibrate_and_check(set, one, false)?;
    let guided = calibrate_frames(&set.model, one, &set.options(true)).expect("registered");
    let (mm, deg) = apart(&searched.base_from_camera, &guided.base_from_camera);
    eprintln!(
        "{}: {mm:.1} mm / {deg:.2}° from where the guess ends",
        f.source
    );
    Some((mm, deg))
}

/// A search without a guess that ends this close to where the reference as a guess ends
/// found the arm (a wrong turn of it is 10° or more away, another object decimetres).
const SAME_MM: f64 = 20.0;
const SAME_DEG: f64 = 1.0;

/// Issue 45 (found everywhere): the frames as a coarser and noisier stereo camera gives them
/// (a ZED 2i-like sensor: half the resolution, its depth bent by smooth blobs of 10 mm 1σ a
/// few centimetres wide and 3 mm of pixel noise, 3 % of the pixels dropped), three draws of
/// the errors each (in the third, frames 0 and 1 join the arm to the far background through
/// flying pixels); and one draw with 15 mm blobs and 5 mm of pixel noise, whose noise went
/// unmeasured (every patch's depths spread over more than 2 cm), so that the scan was fitted
/// as a precise one and the arm not found in 19 of 20 frames. Without a guess the arm is found
/// in every one, never half-turned; nothing far from the reference is accepted.
#[test]
fn issue_45_a_coarser_noisier_camera_finds_the_arm_too() {
    let Some(set) = handeye_calib::testutil::real_set() else {
        return;
    };
    for (blob, noise, draw) in [
        (0.01, 0.003, 0),
        (0.01, 0.003, 10),
        (0.01, 0.003, 1020),
        (0.015, 0.005, 1000),
    ] {
        let frames: Vec<Frame> = set
            .frames
            .iter()
            .enumerate()
            .map(|(k, f)| coarser_camera(f, blob, noise, draw + k as u64))
            .collect();
        assert_found_everywhere(&set, &frames);
    }
}

/// `f` as a coarser stereo camera would give it: half the resolution (2×2 blocks averaged,
/// the colour image too), the depth scaled along each ray by a smooth field of `blob_m` 1σ
/// (normal draws on a 24-pixel grid, bilinear) and by `noise_m` of white noise; a block with
/// fewer than three depths, and 3 % of the rest, without depth.
fn coarser_camera(f: &Frame, blob_m: f64, noise_m: f64, seed: u64) -> Frame {
    use nalgebra::{Point3, Vector3};
    use rand::{Rng, SeedableRng};
    use rand_distr::{Distribution, Normal};
    const GRID_PX: usize = 24;
    let (w, h) = (f.cloud.width as usize, f.cloud.height as usize);
    let (w2, h2) = (w / 2, h / 2);
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let (gw, gh) = (w2 / GRID_PX + 2, h2 / GRID_PX + 2);
    let blobs = Normal::new(0.0, blob_m).expect("σ");
    let grid: Vec<f64> = (0..gw * gh).map(|_| blobs.sample(&mut rng)).collect();
    let field = |u: usize, v: usize| {
        let (x, y) = (u as f64 / GRID_PX as f64, v as f64 / GRID_PX as f64);
        let (i, j) = (x as usize, y as usize);
        let (a, b) = (x - i as f64, y - j as f64);
        let at = |i: usize, j: usize| grid[j * gw + i];
        (at(i, j) * (1.0 - a) + at(i + 1, j) * a) * (1.0 - b)
            + (at(i, j + 1) * (1.0 - a) + at(i + 1, j + 1) * a) * b
    };
    let white = Normal::new(0.0, noise_m).expect("σ");
    let block = |u: usize, v: usize| {
        [(0, 0), (1, 0), (0, 1), (1, 1)].map(|(du, dv)| (2 * v + dv) * w + 2 * u + du)
    };
    let mut points = Vec::with_capacity(w2 * h2);
    let mut rgb = Vec::with_capacity(w2 * h2);
    for v in 0..h2 {
        for u in 0..w2 {
            let depths: Vec<Vector3<f32>> = block(u, v)
                .iter()
                .map(|&i| f.cloud.points[i].coords)
                .filter(|p| p.z.is_finite())
                .collect();
            if depths.len() < 3 || rng.random::<f64>() < 0.03 {
                points.push(Point3::new(f32::NAN, f32::NAN, f32::NAN));
            } else {
                let mean = depths.iter().sum::<Vector3<f32>>() / depths.len() as f32;
                let along = 1.0 + (field(u, v) + white.sample(&mut rng)) / f64::from(mean.z);
                points.push(Point3::from(mean * along as f32));
            }
            if let Some(img) = &f.image {
                let sum = |c: usize| {
                    block(u, v)
                        .iter()
                        .map(|&i| u32::from(img.rgb[i][c]))
                        .sum::<u32>()
                };
                rgb.push([0, 1, 2].map(|c| ((sum(c) + 2) / 4) as u8));
            }
        }
    }
    let rgb = f.image.is_some().then_some(rgb);
    resized(
        f,
        (w2, h2),
        points,
        rgb,
        &format!("coarser camera, draw {seed}"),
    )
}

/// `f` as another camera gave it: `points` and `rgb` (when `f` has an image) on a grid of
/// `size` pixels, its source marked with `what`.
fn resized(
    f: &Frame,
    (width, height): (usize, usize),
    points: Vec<nalgebra::Point3<f32>>,
    rgb: Option<Vec<[u8; 3]>>,
    what: &str,
) -> Frame {
    Frame {
        cloud: handeye_hal::PointCloud {
            width: width as u32,
            height: height as u32,
            points,
            intensity: None,
            confidence: None,
        },
        image: rgb.map(|rgb| {
            std::sync::Arc::new(handeye_calib::cloud::ColorImage { width, height, rgb })
        }),
        source: format!("{} ({what})", f.source),
        ..f.clone()
    }
}

/// Where the fixed camera puts the robot base: how far `base_from_camera` is from the reference
/// there (mm), the point the camera looks at and the error that matters for it.
fn base_apart(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    (a.inverse().translation.vector - b.inverse().translation.vector).norm() * 1e3
}

/// With the camera's class named (active stereo) and the depth alone (the frames without their
/// colour image; with it see `issue_45_the_outline_beside_the_depth`), every frame puts the robot base within 10 mm
/// of where the reference puts it, and its reported σ covers how far it is (the base's
/// position within 2σ, the rotation within 2.5σ: against the reference, the frames' depth
/// carries a gradient down the image that a depth-only fit cannot tell from a turn of the arm,
/// 0.8–3.4°). The five
/// configurations fused use every frame and put the base within 5 mm.
#[test]
fn the_robot_base_is_where_the_reference_puts_it_and_the_sigma_covers_the_rest() {
    let Some(set) = handeye_calib::testutil::real_set() else {
        return;
    };
    let calibrate = |frames: &[Frame]| {
        calibrate_frames(&set.model, &depth_only(frames), &set.options(true)).expect("registered")
    };
    for f in &set.frames {
        let c = calibrate(std::slice::from_ref(f));
        let u = c.report.uncertainty;
        let base_mm = base_apart(&c.base_from_camera, &set.reference);
        let (_, deg) = apart(&c.base_from_camera, &set.reference);
        let sigma_mm = u
            .workspace
            .expect("eye-to-hand σ at the base")
            .translation_mm;
        eprintln!(
            "{}: base {base_mm:.1} mm (σ {sigma_mm:.1}), rotation {deg:.2}° (σ {:.2}°)",
            f.source, u.rotation_deg
        );
        assert!(base_mm < 10.0, "{}: base {base_mm:.1} mm", f.source);
        assert!(
            base_mm < 2.0 * sigma_mm,
            "{}: {base_mm:.1} mm, σ {sigma_mm:.1}",
            f.source
        );
        assert!(
            deg < 2.5 * u.rotation_deg,
            "{}: {deg:.2}°, σ {:.2}°",
            f.source,
            u.rotation_deg
        );
    }
    let c = calibrate(&set.frames);
    let base_mm = base_apart(&c.base_from_camera, &set.reference);
    let (_, deg) = apart(&c.base_from_camera, &set.reference);
    eprintln!(
        "fused: base {base_mm:.1} mm, rotation {deg:.2}°, σ {:?}",
        c.report.uncertainty
    );
    assert!(
        c.solution.frames.iter().all(|f| f.used),
        "{:?}",
        c.solution.frames
    );
    assert!(base_mm < 5.0, "fused: base {base_mm:.1} mm");
    assert!(
        deg < 2.0 * c.report.uncertainty.rotation_deg,
        "fused: {deg:.2}°"
    );
}

/// The frames without their colour image: the depth alone.
fn depth_only(frames: &[Frame]) -> Vec<Frame> {
    frames
        .iter()
        .map(|f| Frame {
            image: None,
            ..f.clone()
        })
        .collect()
}

/// Issue 45 (active stereo with colour): the arm's outline in each frame's colour image and the
/// surface the base stands on, fitted with the depth. Per frame and for the five fused: the
/// distance from the reference, σ and error / σ, the split-half agreement (printed with
/// `--nocapture`: the README's table). Nothing far from the reference is accepted; every frame
/// loads with its image and is fitted with it; the five report their split-half agreement; and
/// the frames' rotations are nearer the reference than the depth alone puts them (the tilt a
/// stereo camera's depth gradient fakes, which the support's normal holds).
#[test]
fn issue_45_the_outline_beside_the_depth() {
    let Some(set) = handeye_calib::testutil::real_set() else {
        return;
    };
    assert!(set.frames.iter().all(|f| f.image.is_some()));
    let show = |name: &str, frames: &[Frame]| {
        let c = calibrate_frames(&set.model, frames, &set.options(true)).expect("registered");
        let (mm, deg) = apart(&c.base_from_camera, &set.reference);
        let base = base_apart(&c.base_from_camera, &set.reference);
        let u = c.report.uncertainty;
        let sigma_base = u.workspace.map_or(f64::NAN, |w| w.translation_mm);
        eprintln!(
            "{name}: {mm:.1} mm / {deg:.2}° (base {base:.1} mm), σ base {sigma_base:.1} mm / {:.2}°, error/σ base {:.2} rotation {:.2}; outline {:?}; split half {:?}; accepted {} {:?}",
            u.rotation_deg,
            base / sigma_base,
            deg / u.rotation_deg,
            c.report.outline,
            c.report.split_half,
            c.verdict.passed(),
            c.verdict.reasons
        );
        assert!(
            !c.verdict.passed() || (mm <= AGREE_MM && deg <= AGREE_DEG),
            "{name}: accepted {mm:.1} mm / {deg:.2}° from the reference"
        );
        (c, deg)
    };
    let (mut with, mut without) = (0.0, 0.0);
    for f in &set.frames {
        let (c, deg) = show(&f.source, std::slice::from_ref(f));
        assert!(c.report.outline.is_some(), "{}: no outline", f.source);
        with += deg;
        without += show(
            &format!("{} depth only", f.source),
            &depth_only(std::slice::from_ref(f)),
        )
        .1;
    }
    let n = set.frames.len() as f64;
    assert!(
        with < 0.75 * without,
        "mean rotation from the reference: {:.2}° with the outline, {:.2}° without",
        with / n,
        without / n
    );
    let (fused, deg) = show("fused", &set.frames);
    let split = fused.report.split_half.expect("split half");
    assert_eq!(split.frames, [3, 2]);
    // The fused σ is not below what the two halves' disagreement shows.
    let sigma = fused.report.uncertainty.rotation_deg;
    assert!(
        sigma >= split.rotation_deg / 2.0,
        "σ {sigma:.2}°, {split:?}"
    );
    assert!(deg <= 1.5 * sigma, "fused: {deg:.2}°, σ {sigma:.2}°");
    show("fused depth only", &depth_only(&set.frames));
}

/// Issue 45, by hand (`cargo test --release -p handeye-calib --test realdata -- --ignored
/// --nocapture`): how often the arm is found without a guess on the frames made coarser and
/// noisier, per depth error, over four draws of each frame (the book's real-scan section).
#[test]
#[ignore = "diagnostics, run by hand"]
fn issue_45_how_often_a_coarser_camera_finds_the_arm() {
    let Some(set) = handeye_calib::testutil::real_set() else {
        return;
    };
    for (blob, noise) in [
        (0.01, 0.003),
        (0.01, 0.0005),
        (0.02, 0.003),
        (0.015, 0.005),
        (0.015, 0.008),
    ] {
        let (mut found, mut lost, mut elsewhere) = (0, 0, 0);
        for draw in 100..104u64 {
            for (k, f) in set.frames.iter().enumerate() {
                let frame = coarser_camera(f, blob, noise, draw * 10 + k as u64);
                match search_apart_from_guess(&set, &frame) {
                    None => lost += 1,
                    Some((mm, deg)) if mm <= SAME_MM && deg <= SAME_DEG => found += 1,
                    Some(_) => elsewhere += 1,
                }
            }
        }
        eprintln!(
            "blobs {:.0} mm, pixel noise {:.1} mm: found {found}, not found {lost}, elsewhere (rejected) {elsewhere}",
            blob * 1e3,
            noise * 1e3
        );
    }
}

/// Issue 45 (found everywhere): the frames as a camera of one and a half times the resolution
/// gives them (1920×1080, a ZED 2i at 1080p: each pixel's depth the nearest frame pixel's,
/// placed on the finer pixel's own ray). Without a guess the arm is found in every one.
#[test]
fn issue_45_a_finer_camera_finds_the_arm_too() {
    let Some(set) = handeye_calib::testutil::real_set() else {
        return;
    };
    let frames: Vec<Frame> = set.frames.iter().map(finer_camera).collect();
    assert_found_everywhere(&set, &frames);
}

/// `f` at 1.5 times its resolution: each finer pixel takes the depth (and colour) of the frame
/// pixel it falls in, placed on the finer pixel's ray through the frame's intrinsics scaled.
fn finer_camera(f: &Frame) -> Frame {
    let cam = RangeImage::new(&f.cloud).expect("an organized frame").cam;
    let (w, h) = (f.cloud.width as usize, f.cloud.height as usize);
    let (w2, h2) = (w * 3 / 2, h * 3 / 2);
    let source = |u: usize, v: usize| (v * 2 / 3) * w + u * 2 / 3;
    // A pixel's centre at the finer scale: (u + ½) / 1.5 − ½ in the frame's pixels.
    let ray = |u: usize, v: usize| {
        let x = ((u as f64 + 0.5) / 1.5 - 0.5 - cam.cx) / cam.fx;
        let y = ((v as f64 + 0.5) / 1.5 - 0.5 - cam.cy) / cam.fy;
        (x, y)
    };
    let points = (0..h2)
        .flat_map(|v| (0..w2).map(move |u| (u, v)))
        .map(|(u, v)| {
            let z = f.cloud.points[source(u, v)].z;
            let (x, y) = ray(u, v);
            nalgebra::Point3::new((x * f64::from(z)) as f32, (y * f64::from(z)) as f32, z)
        })
        .collect();
    let rgb = f.image.as_ref().map(|img| {
        (0..h2)
            .flat_map(|v| (0..w2).map(move |u| (u, v)))
            .map(|(u, v)| img.rgb[source(u, v)])
            .collect()
    });
    resized(f, (w2, h2), points, rgb, "finer camera")
}
