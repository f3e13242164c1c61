//! Tests of the robot model against the 21 robots in `../shared/robots`, plus synthetic URDFs.

use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Point3, Vector3};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use super::*;

/// `../shared/robots`, or `None` (with a message) when it is absent; panics under CI.
fn shared_robots() -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/robots");
    if dir.is_dir() {
        return Some(dir);
    }
    assert!(std::env::var_os("CI").is_none(), "{} is missing and CI is set", dir.display());
    eprintln!("SKIP: {} not found; robot model tests need ../shared/robots", dir.display());
    None
}

fn urdfs(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).expect("readable dir").flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "urdf") {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

fn ur_urdf(dir: &Path, name: &str) -> PathBuf {
    dir.join("ur").join(name).join(format!("{name}.urdf"))
}

/// Largest per-axis difference of two bounding boxes (m).
fn bbox_diff(a: &TriMesh, b: &TriMesh) -> f64 {
    let (alo, ahi) = a.bounding_box().expect("non-empty");
    let (blo, bhi) = b.bounding_box().expect("non-empty");
    (alo - blo).abs().max().max((ahi - bhi).abs().max())
}

#[test]
fn every_shared_robot_loads_with_a_chain_and_meshes() {
    let Some(dir) = shared_robots() else { return };
    let files = urdfs(&dir);
    assert_eq!(files.len(), 21, "{files:?}");
    for f in files {
        let m = RobotModel::load(&f).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
        assert!(matches!(m.dof(), 6 | 7), "{}: dof {}", m.name(), m.dof());
        assert_eq!(m.joint_limits().len(), m.dof());
        assert!(!m.geometry(GeometryKind::Visual).is_empty(), "{}", m.name());
        assert!(!m.geometry(GeometryKind::Collision).is_empty(), "{}", m.name());
        for g in m.geometry(GeometryKind::Visual).iter().chain(m.geometry(GeometryKind::Collision)) {
            g.mesh.validate().expect("valid mesh");
        }
        let q = vec![0.1; m.dof()];
        let posed = m.posed_geometry(&q, GeometryKind::Visual).expect("posed");
        assert_eq!(posed.len(), m.geometry(GeometryKind::Visual).len());
        assert_eq!(m.chain_depth(m.root_link()), Some(0));
        assert_eq!(m.chain_depth(m.flange_link()), Some(m.dof()));
        eprintln!("{}: root {}, flange {}, dof {}", m.name(), m.root_link(), m.flange_link(), m.dof());
    }
}

/// Allowed visual-vs-collision bounding-box difference for one link (m). The loose ones are
/// the legitimate differences listed in `shared/robots/README.md`; everything else is tight
/// enough to catch the mesh-loader Collada bugs (UR20 wrist 2: 6.65 mm, UR30 arms: 0.85 m).
/// Measured: every UR link but the CB3 UR10 upper arm ≤ 1.0 mm.
fn bbox_tolerance(robot: &str, link: &str) -> f64 {
    match (robot, link) {
        ("crx5ia", "base_link") => 0.090, // visual has the rear connector box: 86 mm
        ("crx10ia", "base_link") => 0.004, // 3.2 mm
        ("ur10", "upper_arm_link") => 0.030, // CB3 collision hull: 26 mm
        (r, _) if r.contains("iiwa") => 0.040, // padded collision meshes: ~33 mm
        (r, _) if r.contains("fr3") => 0.008, // coarse collision hulls: ~6 mm
        (r, _) if r.starts_with("ur") => 0.0015,
        _ => 0.002,
    }
}

#[test]
fn visual_and_collision_bounding_boxes_agree_per_link() {
    let Some(dir) = shared_robots() else { return };
    let mut failures = Vec::new();
    for f in urdfs(&dir) {
        let m = RobotModel::load(&f).expect("loads");
        for v in m.geometry(GeometryKind::Visual) {
            let Some(c) = m.geometry(GeometryKind::Collision).iter().find(|c| c.link == v.link) else { continue };
            let d = bbox_diff(&v.mesh, &c.mesh);
            let tol = bbox_tolerance(m.name(), &v.link);
            eprintln!("{:>16} {:>24}: {:7.2} mm (tolerance {:5.1} mm)", m.name(), v.link, d * 1e3, tol * 1e3);
            if d > tol {
                failures.push(format!("{} {}: {:.2} mm > {:.1} mm", m.name(), v.link, d * 1e3, tol * 1e3));
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
