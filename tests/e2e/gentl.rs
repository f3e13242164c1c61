//! The GenTL backend against a producer we did not write: the EMVA reference producer
//! `viky.cti` (shipped by PyPI `genicam`, installed into `$REPO/.venv` by
//! `.ci/install.d/gentl.sh`), read point by point against harvesters, a GenTL consumer we did
//! not write either (`tests/python/gentl_harvesters.py`). Without the venv the tests print SKIP,
//! and fail when env `CI` is set.

use std::path::{Path, PathBuf};

use crate::support::{run, secs, skip, TempDir};

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
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/gentl_harvesters.py");
    let out = std::process::Command::new(py)
        .arg(script)
        .args(args)
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
    let bytes = std::fs::read(&reference).expect("reference");
    let word = |i: usize| [bytes[i], bytes[i + 1], bytes[i + 2], bytes[i + 3]];
    let (w, h) = (u32::from_le_bytes(word(0)), u32::from_le_bytes(word(4)));
    assert_eq!((w, h), (400, 400));
    let theirs: Vec<f32> = (0..(w * h * 3) as usize)
        .map(|k| f32::from_le_bytes(word(8 + 4 * k)))
        .collect();
    assert_eq!(ours.points.len(), theirs.len() / 3);
    let mut max = [0f32; 3];
    for (i, p) in ours.points.iter().enumerate() {
        let t = &theirs[3 * i..3 * i + 3];
        assert_eq!(
            [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()],
            [t[0].to_bits(), t[1].to_bits(), t[2].to_bits()],
            "point {i}: ours {p:?}, harvesters {t:?}"
        );
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
