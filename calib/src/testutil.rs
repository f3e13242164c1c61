//! Helpers shared by the unit tests of the calibration core and (feature `testutil`) of the
//! crates above it.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};

use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion};

use crate::calib::pipeline::{fixed_frame, Frame, PipelineOptions};
use crate::calib::Mount;
use crate::cloud::{read_cloud, read_png};
use crate::geometry::SensorClass;
use crate::model::RobotModel;

/// `../shared/<relative>` (beside the checkout), or `None` (with a SKIP line) when it is
/// absent; panics under CI, where a missing peer must fail, never pass silently.
pub fn shared(relative: &str) -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared")
        .join(relative);
    if dir.is_dir() {
        return Some(dir);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "{} is missing and CI is set",
        dir.display()
    );
    skip(&format!(
        "SKIP: {} not found; this test needs ../shared/{relative}",
        dir.display()
    ));
    None
}

/// `../shared/robots` (see [`shared`]).
pub fn shared_robots() -> Option<PathBuf> {
    shared("robots")
}

/// Prints a SKIP line where the person running the tests sees it: straight to the process's
/// stderr, which the test harness does not capture (`eprintln!` output is shown only for
/// failing tests, so a passing skip would be silent).
pub fn skip(line: &str) {
    use std::io::Write as _;
    let _ = writeln!(std::io::stderr(), "{line}");
}

/// A robot from `../shared/robots` (e.g. `ur/ur5e/ur5e.urdf`), loaded once per test binary.
pub fn shared_robot(relative: &str) -> Option<Arc<RobotModel>> {
    static CACHE: OnceLock<Mutex<HashMap<String, Arc<RobotModel>>>> = OnceLock::new();
    let path = shared_robots()?.join(relative);
    let cache = CACHE.get_or_init(Default::default);
    let mut cache = cache.lock().unwrap_or_else(|e| e.into_inner());
    let model = cache
        .entry(relative.to_string())
        .or_insert_with(|| Arc::new(RobotModel::load(&path).expect("shared robot loads")));
    Some(Arc::clone(model))
}

/// The real scans of `../shared/realdata/xarm7_realsense` (see its README): an Intel
/// RealSense D4xx fixed ~1.3 m from a UFACTORY xArm7, five arm configurations.
#[derive(Debug)]
pub struct RealSet {
    pub model: Arc<RobotModel>,
    pub frames: Vec<Frame>,
    /// `base_from_camera` (`link_base`) as the data's authors estimated it.
    pub reference: Isometry3<f64>,
}

impl RealSet {
    /// The reference as the pipeline's eye-to-hand unknown, `model_from_camera`.
    pub fn model_from_camera(&self) -> Isometry3<f64> {
        fixed_frame(&self.model, "link_base").expect("link_base is fixed") * self.reference
    }

    /// The options of `handeye solve --eye-to-hand --base-frame link_base --sensor
    /// active-stereo`, with the reference as `--guess-base-from-camera` when `guess`.
    pub fn options(&self, guess: bool) -> PipelineOptions {
        let mut opts = PipelineOptions::new(Mount::EyeToHand);
        opts.register = opts.register.for_sensor(SensorClass::ActiveStereo);
        opts.gate = crate::calib::GateThresholds::for_sensor(SensorClass::ActiveStereo);
        opts.base_frame = Some("link_base".into());
        opts.prior = guess.then(|| self.model_from_camera());
        opts
    }
}

/// The real data set, or `None` (with a SKIP line) where `../shared` is absent ([`shared`]).
pub fn real_set() -> Option<RealSet> {
    let dir = shared("realdata/xarm7_realsense")?;
    let text = std::fs::read_to_string(dir.join("manifest.json")).expect("manifest");
    let m: serde_json::Value = serde_json::from_str(&text).expect("manifest is JSON");
    let model = shared_robot("ufactory_xarm7/ufactory_xarm7.urdf")?;
    let frames = m["frames"]
        .as_array()
        .expect("frames")
        .iter()
        .enumerate()
        .map(|(view, f)| {
            let scan = PathBuf::from(f["scan"].as_str().expect("scan name"));
            Frame {
                view,
                cloud: read_cloud(&dir.join(&scan)).expect("the scan reads"),
                joints: f["joints_rad"]
                    .as_array()
                    .expect("joints")
                    .iter()
                    .map(|v| v.as_f64().expect("joint"))
                    .collect(),
                model_from_flange: None,
                source: scan.display().to_string(),
                image: f["color"]
                    .as_str()
                    .map(|name| Arc::new(read_png(&dir.join(name)).expect("the image reads"))),
            }
        })
        .collect();
    Some(RealSet {
        model,
        frames,
        reference: rigid(&m["reference_base_from_camera"]),
    })
}

/// A 4×4 of the manifest, its rotation printed to 9 digits: the nearest rotation.
fn rigid(m: &serde_json::Value) -> Isometry3<f64> {
    let at = |r: usize, c: usize| m[r][c].as_f64().expect("number");
    let rotation = Matrix3::from_fn(at);
    Isometry3::from_parts(
        Translation3::new(at(0, 3), at(1, 3), at(2, 3)),
        UnitQuaternion::from_matrix(&rotation),
    )
}

/// A 2 m square floor (z = 0) meeting a wall (x = 0) along the line x = z = 0: a concave
/// corner where a time-of-flight camera's light bounces between the two (model frame).
pub fn floor_and_wall() -> [crate::model::TriMesh; 2] {
    let quad = |corners: [[f64; 3]; 4]| crate::model::TriMesh {
        vertices: corners
            .iter()
            .map(|c| nalgebra::Point3::new(c[0], c[1], c[2]))
            .collect(),
        triangles: vec![[0, 1, 2], [0, 2, 3]],
    };
    [
        quad([
            [-1.0, -1.0, 0.0],
            [1.0, -1.0, 0.0],
            [1.0, 1.0, 0.0],
            [-1.0, 1.0, 0.0],
        ]),
        quad([
            [0.0, -1.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 1.0, 1.0],
            [0.0, -1.0, 1.0],
        ]),
    ]
}
