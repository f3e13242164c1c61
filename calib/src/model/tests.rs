//! Tests of the robot model against the 21 robots in `../shared/robots`, plus synthetic URDFs.

use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Point3, Vector3};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use super::load::{from_scene, parse_mesh, read_mesh};
use super::*;
use crate::testutil::shared_robots;

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
    let files = find_urdfs(&dir);
    assert_eq!(files.len(), 21, "{files:?}");
    for f in files {
        let m = RobotModel::load(&f).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
        assert!(matches!(m.dof(), 6 | 7), "{}: dof {}", m.name(), m.dof());
        assert_eq!(m.joint_limits().len(), m.dof());
        assert!(!m.geometry(GeometryKind::Visual).is_empty(), "{}", m.name());
        assert!(
            !m.geometry(GeometryKind::Collision).is_empty(),
            "{}",
            m.name()
        );
        for g in m
            .geometry(GeometryKind::Visual)
            .iter()
            .chain(m.geometry(GeometryKind::Collision))
        {
            g.mesh.validate().expect("valid mesh");
        }
        let q = vec![0.1; m.dof()];
        let posed = m.posed_geometry(&q, GeometryKind::Visual).expect("posed");
        assert_eq!(posed.len(), m.geometry(GeometryKind::Visual).len());
        assert_eq!(m.chain_depth(m.root_link()), Some(0));
        assert_eq!(m.chain_depth(m.flange_link()), Some(m.dof()));
        eprintln!(
            "{}: root {}, flange {}, dof {}",
            m.name(),
            m.root_link(),
            m.flange_link(),
            m.dof()
        );
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
    for f in find_urdfs(&dir) {
        let m = RobotModel::load(&f).expect("loads");
        for v in m.geometry(GeometryKind::Visual) {
            let Some(c) = m
                .geometry(GeometryKind::Collision)
                .iter()
                .find(|c| c.link == v.link)
            else {
                continue;
            };
            let d = bbox_diff(&v.mesh, &c.mesh);
            let tol = bbox_tolerance(m.name(), &v.link);
            eprintln!(
                "{:>16} {:>24}: {:7.2} mm (tolerance {:5.1} mm)",
                m.name(),
                v.link,
                d * 1e3,
                tol * 1e3
            );
            if d > tol {
                failures.push(format!(
                    "{} {}: {:.2} mm > {:.1} mm",
                    m.name(),
                    v.link,
                    d * 1e3,
                    tol * 1e3
                ));
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// mesh-loader 0.1.13 composes nested Collada node transforms in the wrong order. For these
/// files (whose URDF visual and collision origins are equal) the bounding box of mesh-loader's
/// result is far from the collision STL's, and ours is within the test tolerance above, so the
/// per-link test would fail with the plain mesh-loader path.
#[test]
fn collada_reader_fixes_the_mesh_loader_node_transform_bug() {
    let Some(dir) = shared_robots() else { return };
    let cases = [
        (
            "ur20",
            "ur20/visual/wrist2.dae",
            "ur20/collision/wrist2.stl",
            0.006,
        ),
        (
            "ur30",
            "ur30/visual/upperarm.dae",
            "ur30/collision/upperarm.stl",
            0.3,
        ),
        (
            "ur30",
            "ur30/visual/forearm.dae",
            "ur30/collision/forearm.stl",
            0.8,
        ),
    ];
    for (robot, visual, collision, mesh_loader_error_at_least) in cases {
        let meshes = dir.join("ur").join(robot).join("meshes");
        let ours = read_mesh(&meshes.join(visual), "test").expect("our reader");
        let stl = read_mesh(&meshes.join(collision), "test").expect("collision STL");
        let scene = mesh_loader::Loader::default()
            .load_collada(meshes.join(visual))
            .expect("mesh-loader reads it");
        let theirs = from_scene(&scene).expect("valid");
        let (d_ours, d_theirs) = (bbox_diff(&ours, &stl), bbox_diff(&theirs, &stl));
        eprintln!(
            "{visual}: ours {:.2} mm, mesh-loader {:.2} mm off the collision STL",
            d_ours * 1e3,
            d_theirs * 1e3
        );
        assert!(
            d_ours < bbox_tolerance(robot, "any"),
            "{visual}: ours {d_ours}"
        );
        assert!(
            d_theirs > mesh_loader_error_at_least,
            "{visual}: mesh-loader {d_theirs}; bug fixed upstream?"
        );
        // Same triangles, only placed differently.
        assert_eq!(ours.triangles.len(), theirs.triangles.len(), "{visual}");
    }
}

/// `base_from_tool0` at joint values `q`, from the URDF.
fn urdf_base_from_tool0(m: &RobotModel, q: &[f64]) -> Isometry3<f64> {
    let model_from_base = m.frame_pose("base", q).expect("base");
    let model_from_tool0 = m.frame_pose("tool0", q).expect("tool0");
    model_from_base.inverse() * model_from_tool0
}

#[test]
fn ur_zero_pose_matches_the_published_check_vectors() {
    let Some(dir) = shared_robots() else { return };
    for (name, want) in [
        ("ur5e", Vector3::new(-0.8172, -0.2329, 0.0628)),
        ("ur10e", Vector3::new(-1.18425, -0.2907, 0.06085)),
    ] {
        let m = RobotModel::load(&ur_urdf(&dir, name)).expect("loads");
        let t = urdf_base_from_tool0(&m, &[0.0; 6]);
        assert!(
            (t.translation.vector - want).norm() < 1e-9,
            "{name}: {}",
            t.translation.vector
        );
        // R = Rx(+90°).
        let rx90 = nalgebra::UnitQuaternion::from_axis_angle(
            &Vector3::x_axis(),
            std::f64::consts::FRAC_PI_2,
        );
        assert!(t.rotation.angle_to(&rx90) < 1e-9, "{name}");
        // `base` is `base_link` turned by π about z.
        let base_link_from_base = m
            .frame_pose("base_link", &[0.0; 6])
            .expect("base_link")
            .inverse()
            * m.frame_pose("base", &[0.0; 6]).expect("base");
        let want = crate::frames::ur_base_from_base_link().inverse();
        assert!((base_link_from_base.to_homogeneous() - want.to_homogeneous()).norm() < 1e-12);
    }
}

#[test]
fn ur_dh_tables_match_the_urdfs_at_random_joints() {
    let Some(dir) = shared_robots() else { return };
    let cases = [
        ("ur3", UrModel::Ur3),
        ("ur5", UrModel::Ur5),
        ("ur10", UrModel::Ur10),
        ("ur3e", UrModel::Ur3e),
        ("ur5e", UrModel::Ur5e),
        ("ur5e", UrModel::Ur7e),
        ("ur10e", UrModel::Ur10e),
        ("ur10e", UrModel::Ur12e),
        ("ur16e", UrModel::Ur16e),
        ("ur20", UrModel::Ur20),
        ("ur30", UrModel::Ur30),
    ];
    let mut rng = StdRng::seed_from_u64(7);
    for (file, ur) in cases {
        let m = RobotModel::load(&ur_urdf(&dir, file)).expect("loads");
        if ur.name() == file {
            assert_eq!(m.ur_model(), Some(ur));
        }
        let dh = ur.dh();
        let mut worst = (0.0f64, 0.0f64);
        for _ in 0..50 {
            let q: [f64; 6] = std::array::from_fn(|_| {
                rng.random_range(-std::f64::consts::PI..std::f64::consts::PI)
            });
            let urdf = urdf_base_from_tool0(&m, &q);
            let dh = dh.forward(&q);
            worst.0 = worst
                .0
                .max((urdf.translation.vector - dh.translation.vector).norm());
            worst.1 = worst.1.max(urdf.rotation.angle_to(&dh.rotation));
        }
        assert!(
            worst.0 < 1e-6 && worst.1 < 1e-6,
            "{ur} via {file}.urdf: {:.3e} m, {:.3e} rad",
            worst.0,
            worst.1
        );
    }
}

#[test]
fn ur5e_joints_limits_depths_and_errors() {
    let Some(dir) = shared_robots() else { return };
    let m = RobotModel::load(&ur_urdf(&dir, "ur5e")).expect("loads");
    assert_eq!(m.name(), "ur5e");
    assert_eq!(m.root_link(), "world");
    assert_eq!(m.flange_link(), "tool0");
    let joints = [
        "shoulder_pan_joint",
        "shoulder_lift_joint",
        "elbow_joint",
        "wrist_1_joint",
        "wrist_2_joint",
        "wrist_3_joint",
    ];
    assert_eq!(m.joint_names(), joints);
    let l = m.joint_limits()[0];
    assert!(
        (l.lower + std::f64::consts::TAU).abs() < 1e-12
            && (l.upper - std::f64::consts::TAU).abs() < 1e-12
    );
    assert!((l.velocity - std::f64::consts::PI).abs() < 1e-12);
    assert!(
        (m.joint_limits()[2].upper - std::f64::consts::PI).abs() < 1e-12,
        "elbow ±π"
    );
    for (link, depth) in [
        ("base_link", 0),
        ("base", 0),
        ("base_link_inertia", 0),
        ("shoulder_link", 1),
        ("upper_arm_link", 2),
        ("forearm_link", 3),
        ("wrist_3_link", 6),
        ("tool0", 6),
    ] {
        assert_eq!(m.chain_depth(link), Some(depth), "{link}");
    }
    assert_eq!(m.chain_depth("nope"), None);
    let tool0 = m.link_index("tool0").expect("tool0");
    assert_eq!(m.link_names()[tool0], "tool0");
    assert_eq!(
        m.link_poses(&[0.0; 6]).expect("poses").len(),
        m.link_names().len()
    );

    let e = m.link_poses(&[0.0; 5]).expect_err("must fail");
    assert!(
        matches!(
            e,
            ModelError::JointCount {
                expected: 6,
                got: 5,
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("shoulder_pan_joint"), "{e}");
    let e = m
        .frame_pose("tool0", &[0.0, f64::NAN, 0.0, 0.0, 0.0, 0.0])
        .expect_err("must fail");
    assert!(
        matches!(e, ModelError::NonFiniteJoint { index: 1, .. }),
        "{e}"
    );
    let e = m.frame_pose("tool", &[0.0; 6]).expect_err("must fail");
    assert!(matches!(e, ModelError::UnknownFrame { .. }), "{e}");
    assert!(e.to_string().contains("tool0"), "{e}");
    let e = m
        .frame_pose("wrist3_link", &[0.0; 6])
        .expect_err("must fail")
        .to_string();
    assert!(e.contains("wrist_3_link"), "{e}");
    assert!(m
        .posed_geometry(&[0.0; 7], GeometryKind::Collision)
        .is_err());
}

#[test]
fn ur_models_are_detected_by_name_as_whole_tokens() {
    assert_eq!(detect_ur("ur5e"), Some(UrModel::Ur5e));
    assert_eq!(detect_ur("UR10e_cell"), Some(UrModel::Ur10e));
    assert_eq!(detect_ur("my-ur10"), Some(UrModel::Ur10));
    assert_eq!(detect_ur("ur3"), Some(UrModel::Ur3));
    assert_eq!(detect_ur("ur30"), Some(UrModel::Ur30));
    assert_eq!(detect_ur("fanuc_crx10ia"), None);
    assert_eq!(detect_ur("tour5e"), None);
    assert_eq!(detect_ur("ur5ex"), None);
}

/// A scratch directory unique to this test process and tag, emptied first.
fn scratch(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("handeye-model-{}-{tag}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("scratch dir");
    d
}

/// One triangle in millimetres, as ASCII STL.
const STL_MM: &str = "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 100 0 0\nvertex 0 200 0\nendloop\nendfacet\nendsolid t\n";
const OBJ: &str = "mtllib missing.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n";
const DAE: &str = r##"<?xml version="1.0"?>
<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
  <asset><unit meter="1"/><up_axis>Z_UP</up_axis></asset>
  <library_geometries><geometry id="g"><mesh>
    <source id="p"><float_array id="pa" count="9">0 0 0 1 0 0 0 1 0</float_array>
      <technique_common><accessor source="#pa" count="3" stride="3"/></technique_common></source>
    <vertices id="v"><input semantic="POSITION" source="#p"/></vertices>
    <triangles count="1"><input semantic="VERTEX" source="#v" offset="0"/><p>0 1 2</p></triangles>
  </mesh></geometry></library_geometries>
  <library_visual_scenes><visual_scene id="s">
    <node><matrix>1 0 0 0 0 1 0 0 0 0 1 0.5 0 0 0 1</matrix>
      <node><translate>0.25 0 0</translate><instance_geometry url="#g"/></node></node>
  </visual_scene></library_visual_scenes>
  <scene><instance_visual_scene url="#s"/></scene>
</COLLADA>"##;

/// A small arm: fixed base with a box, revolute + continuous + prismatic chain, a mimic finger.
fn synthetic_urdf(abs_obj: &Path) -> String {
    format!(
        r#"<?xml version="1.0"?>
<robot name="ur5e">
  <link name="world"/>
  <link name="base_link">
    <visual><origin xyz="0 0 0.05"/><geometry><box size="0.2 0.2 0.1"/></geometry></visual>
    <collision><geometry><mesh filename="parts/t.stl" scale="0.001 0.001 0.001"/></geometry></collision>
  </link>
  <link name="a"><visual><origin xyz="0 0 1" rpy="0 0 1.5707963267948966"/><geometry><mesh filename="parts/t.dae"/></geometry></visual>
    <collision><geometry><cylinder radius="0.05" length="0.2"/></geometry></collision></link>
  <link name="b"><visual><geometry><mesh filename="{}"/></geometry></visual>
    <collision><geometry><sphere radius="0.1"/></geometry></collision></link>
  <link name="c"/>
  <link name="finger"/>
  <link name="tip"/>
  <joint name="fix" type="fixed"><parent link="world"/><child link="base_link"/></joint>
  <joint name="j1" type="revolute"><origin xyz="0 0 0.1"/><parent link="base_link"/><child link="a"/>
    <axis xyz="0 0 1"/><limit lower="-1" upper="2" velocity="0.5" effort="1"/></joint>
  <joint name="j2" type="continuous"><origin xyz="1 0 0"/><parent link="a"/><child link="b"/><axis xyz="0 1 0"/></joint>
  <joint name="j3" type="prismatic"><parent link="b"/><child link="c"/><axis xyz="0 0 2"/>
    <limit lower="0" upper="0.3" velocity="0.1" effort="1"/></joint>
  <joint name="jf" type="prismatic"><parent link="b"/><child link="finger"/><axis xyz="1 0 0"/>
    <limit lower="0" upper="0.04" velocity="0.1" effort="1"/><mimic joint="j3" multiplier="0.5" offset="0.01"/></joint>
  <joint name="jt" type="fixed"><origin xyz="0 0 0.1"/><parent link="c"/><child link="tip"/></joint>
</robot>"#,
        abs_obj.display()
    )
}

#[test]
fn synthetic_urdf_kinematics_meshes_and_primitives() {
    let dir = scratch("synthetic");
    std::fs::create_dir_all(dir.join("parts")).expect("dir");
    std::fs::write(dir.join("parts/t.stl"), STL_MM).expect("write");
    std::fs::write(dir.join("parts/t.dae"), DAE).expect("write");
    let obj = dir.join("parts/quad.obj");
    std::fs::write(&obj, OBJ).expect("write");
    let urdf = dir.join("arm.urdf");
    std::fs::write(&urdf, synthetic_urdf(&obj)).expect("write");
    let m = RobotModel::load(&urdf).expect("loads");

    assert_eq!(m.joint_names(), ["j1", "j2", "j3"]);
    assert_eq!(m.flange_link(), "tip", "no tool0/flange: the chain tip");
    let lim = m.joint_limits();
    assert_eq!(
        lim[0],
        JointLimit {
            lower: -1.0,
            upper: 2.0,
            velocity: 0.5
        }
    );
    assert_eq!(
        (lim[1].lower, lim[1].upper),
        (-std::f64::consts::TAU, std::f64::consts::TAU),
        "continuous"
    );
    assert_eq!(
        (0..4).map(|i| m.joint_is_continuous(i)).collect::<Vec<_>>(),
        [false, true, false, false]
    );
    assert_eq!(
        m.chain_depth("finger"),
        Some(2),
        "the mimic finger is not a chain joint"
    );

    // FK: j1 turns about z at (0,0,0.1); j2 about y at (1,0,0); j3 slides along z (unit axis).
    let q = [std::f64::consts::FRAC_PI_2, 0.0, 0.2];
    let tip = m.frame_pose("tip", &q).expect("tip").translation.vector;
    assert!((tip - Vector3::new(0.0, 1.0, 0.4)).norm() < 1e-12, "{tip}");
    let finger = m
        .frame_pose("finger", &q)
        .expect("finger")
        .translation
        .vector;
    // Finger slides 0.5·0.2 + 0.01 = 0.11 along b's x, which j1 turned to +y.
    assert!(
        (finger - Vector3::new(0.0, 1.11, 0.1)).norm() < 1e-12,
        "{finger}"
    );
    assert_eq!(m.ur_model(), Some(UrModel::Ur5e));
    // No `base` link: derived from base_link.
    let base = m.frame_pose("base", &q).expect("virtual base");
    assert!((base * Point3::new(1.0, 0.0, 0.0) - Point3::new(-1.0, 0.0, 0.0)).norm() < 1e-12);

    let visual = m.geometry(GeometryKind::Visual);
    let collision = m.geometry(GeometryKind::Collision);
    assert_eq!(
        visual.iter().map(|g| g.link.as_str()).collect::<Vec<_>>(),
        ["base_link", "a", "b"]
    );
    let (lo, hi) = visual[0].mesh.bounding_box().expect("box");
    assert!(
        (lo - Point3::new(-0.1, -0.1, 0.0)).norm() < 1e-12
            && (hi - Point3::new(0.1, 0.1, 0.1)).norm() < 1e-12
    );
    // STL in mm, scaled to metres.
    let (_, hi) = collision[0].mesh.bounding_box().expect("stl");
    assert!((hi - Point3::new(0.1, 0.2, 0.0)).norm() < 1e-6, "{hi}");
    // DAE: node z 0.5 then child x 0.25, then the URDF origin (z 1, yaw 90°): (1,0,0) → (0,1.25,1.5).
    let dae = &visual[1].mesh;
    assert!(
        dae.vertices
            .iter()
            .any(|v| (v - Point3::new(0.0, 1.25, 1.5)).norm() < 1e-9),
        "{:?}",
        dae.vertices
    );
    // OBJ quad (absolute path, missing .mtl ignored) → two triangles.
    assert_eq!(visual[2].mesh.triangles.len(), 2);
    let posed = m
        .posed_geometry(&q, GeometryKind::Collision)
        .expect("posed");
    assert_eq!(posed.len(), 3);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_mesh_references_are_clear_errors() {
    let dir = scratch("badrefs");
    let urdf = dir.join("r.urdf");
    let write = |mesh: &str| {
        let text = format!(
            r#"<robot name="r"><link name="l"><visual><geometry><mesh filename="{mesh}"/></geometry></visual></link></robot>"#
        );
        std::fs::write(&urdf, text).expect("write");
        RobotModel::load(&urdf).expect_err("must fail")
    };
    let e = write("package://ur_description/meshes/base.stl");
    assert!(matches!(e, ModelError::UnsupportedMeshUri { .. }), "{e}");
    let e = write("missing.stl");
    assert!(
        matches!(&e, ModelError::MissingMesh { link, .. } if link == "l"),
        "{e}"
    );
    assert!(e.to_string().contains("missing.stl"), "{e}");
    std::fs::write(dir.join("m.ply"), "ply").expect("write");
    let e = write("m.ply");
    assert!(matches!(e, ModelError::UnsupportedMeshFormat { .. }), "{e}");
    std::fs::write(dir.join("bad.dae"), "<COLLADA><library_visual_scenes><visual_scene><node><instance_geometry url=\"#x\"/></node></visual_scene></library_visual_scenes></COLLADA>").expect("write");
    let e = write("bad.dae");
    assert!(matches!(e, ModelError::MalformedMesh { .. }), "{e}");
    let e = RobotModel::load(&dir.join("absent.urdf")).expect_err("must fail");
    assert!(matches!(e, ModelError::ReadUrdf { .. }), "{e}");
    std::fs::write(
        &urdf,
        "<robot name='r'><link name='a'/><link name='b'/></robot>",
    )
    .expect("write");
    let e = RobotModel::load(&urdf).expect_err("must fail");
    assert!(e.to_string().contains("several root links"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A binary STL: header, count, one facet.
fn binary_stl() -> Vec<u8> {
    let mut binary = vec![0u8; 80];
    binary.extend(1u32.to_le_bytes());
    for v in [
        0.0f32, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0,
    ] {
        binary.extend(v.to_le_bytes());
    }
    binary.extend([0, 0]);
    binary
}

/// The bytes of files of `../shared/robots` (none when it is absent on a developer's machine).
fn shared_files(relative: &[&str]) -> Vec<Vec<u8>> {
    let Some(dir) = shared_robots() else {
        return Vec::new();
    };
    relative
        .iter()
        .map(|r| std::fs::read(dir.join(r)).expect("read a shared mesh"))
        .collect()
}

/// One mesh fuzz target (hal::fuzz): mutated files of extension `ext` parse to a valid mesh
/// or are refused with an error naming the file and the link.
fn fuzz_mesh(name: &str, ext: &str, seeds: Vec<Vec<u8>>) {
    let path = PathBuf::from(format!("fuzz/part.{ext}"));
    handeye_hal::fuzz::Target::new(name, seeds).run(|b| {
        match parse_mesh(b, ext, &path, "fuzz_link") {
            Ok(mesh) => {
                if let Err(e) = mesh.validate() {
                    panic!("a mesh that loaded is invalid: {e}");
                }
                Ok(())
            }
            Err(e) => {
                let msg = e.to_string();
                assert!(msg.contains("part.") && msg.contains("fuzz_link"), "{msg}");
                Err(msg)
            }
        }
    });
}

/// Fuzz target `stl`: ASCII and binary STL, synthetic and the UR5e's and FR3's collision meshes.
#[test]
fn fuzz_stl() {
    let mut seeds = vec![STL_MM.as_bytes().to_vec(), binary_stl()];
    seeds.extend(shared_files(&[
        "ur/ur5e/meshes/ur5e/collision/wrist3.stl",
        "franka_fr3/meshes/fr3/collision/link4.stl",
    ]));
    fuzz_mesh("stl", "stl", seeds);
}

/// Fuzz target `obj`: Wavefront OBJ (quads, a material library that is never read).
#[test]
fn fuzz_obj() {
    let tri = "o t\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nvt 0 0\nvt 1 0\nvt 0 1\ng g\nusemtl m\nf 1/1/1 2/2/1 3/3/1\n";
    fuzz_mesh(
        "obj",
        "obj",
        vec![OBJ.as_bytes().to_vec(), tri.as_bytes().to_vec()],
    );
}

/// Fuzz target `collada` (our own reader): the synthetic nested-node file and real UR visual
/// meshes (UR3 wrist 3, UR20 wrist 2: nested transforms, several materials).
#[test]
fn fuzz_collada() {
    let mut seeds = vec![DAE.as_bytes().to_vec()];
    seeds.extend(shared_files(&[
        "ur/ur3/meshes/ur3/visual/wrist3.dae",
        "ur/ur20/meshes/ur20/visual/wrist2.dae",
    ]));
    fuzz_mesh("collada", "dae", seeds);
}

/// Issue 23 (found by the `dae` fuzz target): a control character where the XML parser
/// expected `>` was echoed raw into the error message; now escaped.
#[test]
fn issue_23_collada_xml_error_escapes_control_characters() {
    let e = parse_mesh(
        b"<?x?><C m=\"\" n=\"\"><s\x07",
        "dae",
        Path::new("p.dae"),
        "l",
    )
    .expect_err("not XML");
    let msg = e.to_string();
    assert!(msg.contains("not well-formed XML"), "{msg}");
    assert!(!msg.chars().any(char::is_control), "{msg:?}");
}

/// Fuzz target `urdf`: the synthetic arm (every joint type, mimic, primitives, meshes) and the
/// UR5e's real URDF with its meshes swapped for small ones; a loaded model evaluates.
#[test]
fn fuzz_urdf() {
    let dir = scratch("fuzz-urdf");
    std::fs::create_dir_all(dir.join("parts")).expect("dir");
    let obj = dir.join("parts/quad.obj");
    std::fs::write(dir.join("parts/t.stl"), STL_MM).expect("write");
    std::fs::write(dir.join("parts/t.dae"), DAE).expect("write");
    std::fs::write(&obj, OBJ).expect("write");
    let mut seeds = vec![synthetic_urdf(&obj).into_bytes()];
    for real in shared_files(&["ur/ur5e/ur5e.urdf"]) {
        let text = String::from_utf8(real).expect("UTF-8");
        let mut out = String::new();
        // Every mesh reference → the small Collada file (metres), keeping the structure.
        for (i, piece) in text.split("filename=\"").enumerate() {
            if i == 0 {
                out.push_str(piece);
                continue;
            }
            let rest = piece.split_once('"').map_or("", |(_, r)| r);
            out.push_str(&format!("filename=\"parts/t.dae\"{rest}"));
        }
        seeds.push(out.into_bytes());
    }
    let urdf = dir.join("arm.urdf");
    handeye_hal::fuzz::Target::new("urdf", seeds).run(|b| {
        std::fs::write(&urdf, b).expect("write");
        let m = RobotModel::load(&urdf).map_err(|e| e.to_string())?;
        m.link_poses(&vec![0.3; m.dof()])
            .map(|_| ())
            .map_err(|e| format!("BUG: a loaded model does not evaluate: {e}"))
    });
    let _ = std::fs::remove_dir_all(&dir);
}

/// Largest difference of two sets of poses: (metres, radians).
fn worst_pose_difference(a: &[Isometry3<f64>], b: &[Isometry3<f64>]) -> (f64, f64) {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).fold((0.0f64, 0.0f64), |(t, r), (x, y)| {
        (
            t.max((x.translation.vector - y.translation.vector).norm()),
            r.max(x.rotation.angle_to(&y.rotation)),
        )
    })
}

#[test]
fn controller_dh_poses_the_urdf_where_the_physical_arm_is() {
    let Some(dir) = shared_robots() else { return };
    let mut rng = StdRng::seed_from_u64(11);
    for name in ["ur5e", "ur10e", "ur3"] {
        let m = RobotModel::load(&ur_urdf(&dir, name)).expect("loads");
        let ur = m.ur_model().expect("a UR arm");
        let nominal = ur.dh();
        let arm = handeye_hal::ur_dh::PhysicalArm::factory(ur, 3);
        let calibrated = arm.controller_dh();
        assert!(calibrated.d[1].abs() > 1.0, "{name}: {:?}", calibrated.d);
        let random: [f64; 6] =
            std::array::from_fn(|_| rng.random_range(-std::f64::consts::PI..std::f64::consts::PI));
        for q in [[0.0; 6], random] {
            // Nominal DH: the URDF's own poses.
            let same = m
                .link_poses_with_controller_dh(&q, &nominal)
                .expect("posed");
            let (t, r) = worst_pose_difference(&same, &m.link_poses(&q).expect("fk"));
            assert!(t < 1e-9 && r < 1e-9, "{name}: {t:.2e} m {r:.2e} rad");
            // The controller's DH: the flange is where the controller reports it.
            let poses = m
                .link_poses_with_controller_dh(&q, &calibrated)
                .expect("posed");
            let tool0 = poses[m.link_index("tool0").expect("tool0")];
            let model_from_base = m.frame_pose("base", &q).expect("base");
            let (t, r) =
                worst_pose_difference(&[tool0], &[model_from_base * calibrated.forward(&q)]);
            assert!(t < 1e-9 && r < 1e-9, "{name}: flange {t:.2e} m {r:.2e} rad");
            // The base stays; no link is where its 400 m DH frame is, each is within what the
            // joints' errors move it of the physical arm's (the rest is what the DH cannot
            // tell, see DhParams::link_frames).
            let (t, _) = worst_pose_difference(
                &[poses[m.link_index("base_link").expect("base_link")]],
                &[m.frame_pose("base_link", &q).expect("base_link")],
            );
            assert!(t < 1e-12, "{name}: the base never moves");
            let physical = m.link_poses_of_arm(&q, &arm).expect("physical");
            let (t, r) = worst_pose_difference(&poses, &physical);
            assert!(
                t < 3e-3 && r < 3e-3,
                "{name}: {t} m {r} rad off the physical arm"
            );
            let (t, _) = worst_pose_difference(&physical, &m.link_poses(&q).expect("fk"));
            assert!(
                t > 1e-5 && t < 5e-3,
                "{name}: the joints' errors moved links by {t} m"
            );
            // The calibrated axes in the model frame: joint k + 1 turns about z of DH frame k.
            let axes = m.dh_axes(&q, &calibrated).expect("axes");
            let dh_frames = calibrated.link_poses(&q);
            for (k, axis) in axes.iter().enumerate() {
                let (p, u) = (Point3::from(axis.point), axis.direction);
                let f = if k == 0 {
                    model_from_base
                } else {
                    model_from_base * dh_frames[k - 1]
                };
                assert!((f * Vector3::z()).cross(&u).norm() < 1e-9);
                let off = f.inverse() * p;
                assert!(off.coords.xy().norm() < 1e-6, "{name} axis {k}: {off}");
            }
        }
    }
}

/// The derivation behind [`RobotModel::link_poses_with_controller_dh`]: every link of chain
/// depth k is rigid with nominal DH frame k (`DH_k(q)⁻¹ · base_from_model · model_from_link`
/// does not depend on q).
#[test]
fn ur_links_are_rigid_with_their_dh_frames() {
    let Some(dir) = shared_robots() else { return };
    let mut rng = StdRng::seed_from_u64(5);
    for name in ["ur5e", "ur3", "ur20"] {
        let m = RobotModel::load(&ur_urdf(&dir, name)).expect("loads");
        let dh = m.ur_model().expect("UR").dh();
        let base_from_model = m.frame_pose("base", &[0.0; 6]).expect("base").inverse();
        let constant = |q: &[f64; 6]| {
            let frames = dh.link_poses(q);
            m.link_poses(q)
                .expect("fk")
                .iter()
                .zip(m.link_names())
                .map(|(pose, link)| match m.chain_depth(link).expect("depth") {
                    0 => base_from_model * pose,
                    k => frames[k - 1].inverse() * base_from_model * pose,
                })
                .collect::<Vec<_>>()
        };
        let at_zero = constant(&[0.0; 6]);
        for _ in 0..10 {
            let q: [f64; 6] = std::array::from_fn(|_| rng.random_range(-3.0..3.0));
            let (t, r) = worst_pose_difference(&constant(&q), &at_zero);
            assert!(t < 1e-6 && r < 1e-6, "{name}: {t:.2e} m {r:.2e} rad");
        }
    }
}

#[test]
fn controller_dh_needs_a_six_joint_ur_arm() {
    let Some(dir) = shared_robots() else { return };
    let dh = UrModel::Ur5e.dh();
    let m = RobotModel::load(&dir.join("franka_fr3/franka_fr3.urdf"));
    let Ok(m) = m else {
        assert!(
            std::env::var_os("CI").is_none(),
            "franka_fr3/franka_fr3.urdf does not load and CI is set"
        );
        crate::testutil::skip("SKIP: no franka_fr3/franka_fr3.urdf");
        return;
    };
    let q = vec![0.0; m.dof()];
    let e = m
        .link_poses_with_controller_dh(&q, &dh)
        .expect_err("not a UR arm");
    assert!(matches!(e, ModelError::NotUrArm { .. }), "{e}");
    assert!(e.to_string().contains("UR"), "{e}");
    let ur = RobotModel::load(&ur_urdf(&dir, "ur5e")).expect("loads");
    let e = ur
        .link_poses_with_controller_dh(&[0.0; 5], &dh)
        .expect_err("5 joints");
    assert!(matches!(e, ModelError::JointCount { .. }), "{e}");
}

/// Issue 16: structure-aware hostile inputs — nesting far beyond any real file (the parsers
/// behind URDF and Collada recurse per element), sizes and counts that parse but cannot be a
/// robot. Each must be a clear error, quickly, never a stack overflow or an allocation abort.
#[test]
fn issue_16_deep_nesting_and_huge_sizes_are_clear_errors() {
    let dir = scratch("hostile");
    let urdf = dir.join("r.urdf");
    let load = |text: &str| {
        std::fs::write(&urdf, text).expect("write");
        let t = std::time::Instant::now();
        let r = RobotModel::load(&urdf);
        assert!(t.elapsed().as_secs_f64() < 5.0, "took {:?}", t.elapsed());
        r
    };
    let mesh_urdf = |file: &str, scale: &str| {
        format!(
            r#"<robot name="r"><link name="l"><visual><geometry><mesh filename="{file}" {scale}/></geometry></visual></link></robot>"#
        )
    };
    let n = 50_000;
    let nest = |tag: &str| {
        format!(
            "{}{}",
            format!("<{tag}>").repeat(n),
            format!("</{tag}>").repeat(n)
        )
    };
    // URDF nested in every place a parser descends into.
    for text in [
        format!("<robot name=\"r\"><link name=\"l\"/>{}</robot>", nest("x")),
        format!(
            "<robot name=\"r\"><link name=\"l\"><visual>{}</visual></link></robot>",
            nest("geometry")
        ),
        format!(
            "{}<robot name=\"r\"/>{}",
            "<robot>".repeat(n),
            "</robot>".repeat(n)
        ),
    ] {
        let e = load(&text).expect_err("too deep").to_string();
        assert!(e.contains("nested more than"), "{e}");
    }
    // Collada nested: elements, scene nodes.
    let dae = |body: &str| {
        format!(
            r#"<?xml version="1.0"?><COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">{body}</COLLADA>"#
        )
    };
    for body in [
        format!("<library_visual_scenes><visual_scene id=\"s\">{}</visual_scene></library_visual_scenes>", nest("node")),
        format!("<asset>{}</asset>", nest("contributor")),
    ] {
        std::fs::write(dir.join("deep.dae"), dae(&body)).expect("write");
        let e = load(&mesh_urdf("deep.dae", "")).expect_err("too deep").to_string();
        assert!(e.contains("nested more than"), "{e}");
        assert!(collada::parse(dae(&body).as_bytes()).is_err());
    }
    // A few hundred bytes that instance a node tree of 2^60 triangles.
    let mut nodes = String::from(r##"<node id="n0"><instance_geometry url="#g"/></node>"##);
    for i in 1..60 {
        let p = i - 1;
        nodes += &format!(
            r##"<node id="n{i}"><instance_node url="#n{p}"/><instance_node url="#n{p}"/></node>"##
        );
    }
    let geometry = &DAE[DAE.find("<library_geometries>").expect("has")
        ..DAE.find("<library_visual_scenes>").expect("has")];
    let bomb = dae(&format!(
        r##"{geometry}<library_nodes>{nodes}</library_nodes><library_visual_scenes><visual_scene id="s"><node><instance_node url="#n59"/></node></visual_scene></library_visual_scenes><scene><instance_visual_scene url="#s"/></scene>"##
    ));
    std::fs::write(dir.join("bomb.dae"), &bomb).expect("write");
    let e = load(&mesh_urdf("bomb.dae", ""))
        .expect_err("too many")
        .to_string();
    assert!(e.contains("more than"), "{e}");
    // A binary STL header claiming four billion triangles, in 144 bytes.
    let mut stl = vec![0u8; 80];
    stl.extend(4_000_000_000u32.to_le_bytes());
    stl.extend([0u8; 60]);
    std::fs::write(dir.join("huge.stl"), &stl).expect("write");
    load(&mesh_urdf("huge.stl", "")).expect_err("lying header");
    // Issue 23: meshes that read as nothing are errors naming the file and the link, never an
    // empty link: a 0-triangle STL, a Collada without geometry.
    let mut empty = vec![0u8; 80];
    empty.extend(0u32.to_le_bytes());
    std::fs::write(dir.join("empty.stl"), &empty).expect("write");
    std::fs::write(dir.join("empty.dae"), dae("<asset/>")).expect("write");
    for file in ["empty.stl", "empty.dae"] {
        let e = load(&mesh_urdf(file, "")).expect_err(file).to_string();
        assert!(e.contains(file) && e.contains("no triangles"), "{e}");
    }
    // Sizes that parse but are no robot: primitives, scale, origin.
    std::fs::write(dir.join("t.stl"), STL_MM).expect("write");
    for (text, says) in [
        (r#"<robot name="r"><link name="l"><visual><geometry><cylinder radius="1e300" length="1"/></geometry></visual></link></robot>"#.to_string(), "larger than 20 m"),
        (r#"<robot name="r"><link name="l"><visual><geometry><box size="1 1e12 1"/></geometry></visual></link></robot>"#.to_string(), "larger than 20 m"),
        (mesh_urdf("t.stl", r#"scale="1e30 1e30 1e30""#), "farther than 20 m"),
        (r#"<robot name="r"><link name="l"><visual><origin xyz="1e200 0 0"/><geometry><sphere radius="0.1"/></geometry></visual></link></robot>"#.to_string(), "farther than 20 m"),
    ] {
        let e = load(&text).expect_err(&text).to_string();
        assert!(e.contains(says), "{text}: {e}");
    }
    // Joint origins, limits and mimic factors that parse but are no robot.
    let arm = |joint: &str| {
        format!(
            r#"<robot name="r"><link name="a"/><link name="b"/><link name="c"/><link name="d"/>{joint}<joint name="k" type="revolute"><parent link="b"/><child link="c"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" velocity="1" effort="1"/></joint><joint name="m" type="prismatic"><parent link="a"/><child link="d"/><axis xyz="0 0 1"/><limit lower="0" upper="1" velocity="1" effort="1"/><mimic joint="j" multiplier="1e300"/></joint></robot>"#
        )
    };
    for (joint, says) in [
        (
            r#"<joint name="j" type="revolute"><origin xyz="1e300 0 0"/><parent link="a"/><child link="b"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" velocity="1" effort="1"/></joint>"#,
            "from its parent link",
        ),
        (
            r#"<joint name="j" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/><limit lower="-1e300" upper="1" velocity="1" effort="1"/></joint>"#,
            "has limits",
        ),
        (
            r#"<joint name="j" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" velocity="1" effort="1"/></joint>"#,
            "mimic",
        ),
    ] {
        let e = load(&arm(joint)).expect_err(joint).to_string();
        assert!(e.contains(says), "{joint}: {e}");
    }
    // Millimetre meshes scaled to metres still load.
    load(&mesh_urdf("t.stl", r#"scale="0.001 0.001 0.001""#)).expect("mm mesh at scale 0.001");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 16: a URDF or mesh path that is a FIFO would block the read forever; a directory is
/// no file either. Both are refused before they are opened.
#[cfg(unix)]
#[test]
fn issue_16_special_files_are_refused_without_blocking() {
    let dir = scratch("fifo");
    let fifo = dir.join("r.urdf");
    let status = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .expect("mkfifo runs");
    assert!(status.success());
    let e = RobotModel::load(&fifo).expect_err("a FIFO").to_string();
    assert!(e.contains("FIFO"), "{e}");
    let e = RobotModel::load(&dir).expect_err("a directory").to_string();
    assert!(e.contains("directory"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 16: seeded structure-aware fuzzing — random nesting depths around the limit, random
/// repetition counts and huge numbers spliced into URDF and Collada; loading is Ok or Err,
/// quickly, never a crash.
#[test]
fn issue_16_structured_fuzz_of_nesting_counts_and_numbers() {
    let dir = scratch("structfuzz");
    let urdf = dir.join("r.urdf");
    let mut rng = StdRng::seed_from_u64(16);
    let numbers = [
        "1e308",
        "-1e308",
        "1e-320",
        "0",
        "-0",
        "nan",
        "inf",
        "4294967296",
        "1e30",
    ];
    let t0 = std::time::Instant::now();
    for round in 0..120 {
        let depth = rng.random_range(1..400);
        let reps = rng.random_range(0..2000);
        let num = numbers[rng.random_range(0..numbers.len())];
        let tag = ["x", "node", "visual", "geometry", "link"][round % 5];
        let inner = format!(
            "{}{}",
            format!("<{tag}>").repeat(depth),
            format!("</{tag}>").repeat(depth)
        );
        let text = format!(
            r#"<robot name="r"><link name="l"><visual><origin xyz="{num} 0 0"/><geometry><cylinder radius="{num}" length="0.1"/></geometry></visual>{inner}</link>{}</robot>"#,
            "<link name=\"l\"/>".repeat(reps.min(3))
        );
        std::fs::write(&urdf, text).expect("write");
        let _ = RobotModel::load(&urdf);
        let dae = format!(
            r#"<COLLADA><asset><unit meter="{num}"/></asset><library_visual_scenes><visual_scene id="s">{}{}{}</visual_scene></library_visual_scenes></COLLADA>"#,
            "<node><scale>1e30 1e30 1e30</scale>".repeat(depth),
            "<node/>".repeat(reps),
            "</node>".repeat(depth)
        );
        let _ = collada::parse(dae.as_bytes());
    }
    assert!(t0.elapsed().as_secs() < 20, "took {:?}", t0.elapsed());
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 36: a binary STL whose header's triangle count disagrees with the file's length — a
/// huge count over a few triangles, or a count short of what the file holds — is refused with
/// both numbers, instead of loading part of the mesh (or none of it) as the link's shape.
/// ASCII and well-formed binary STLs (also one whose header begins with `solid`) still load.
#[test]
fn issue_36_an_stl_whose_count_disagrees_with_its_length_is_refused() {
    let path = Path::new("parts/base.stl");
    let one = binary_stl();
    let mut three = one.clone();
    three[80..84].copy_from_slice(&3u32.to_le_bytes());
    let facet = one[84..].to_vec();
    three.extend(&facet);
    three.extend(&facet);
    let mut solid = three.clone();
    solid[..5].copy_from_slice(b"solid");
    for ok in [&one, &three, &solid, &STL_MM.as_bytes().to_vec()] {
        parse_mesh(ok, "stl", path, "base_link").expect("a well-formed STL loads");
    }
    for (count, bytes) in [
        (u32::MAX, &one),
        (1_000_000, &three),
        (1, &three),
        (2, &solid),
    ] {
        let mut b = bytes.clone();
        b[80..84].copy_from_slice(&count.to_le_bytes());
        let e = parse_mesh(&b, "stl", path, "base_link").expect_err("count disagrees");
        let msg = e.to_string();
        assert!(
            msg.contains(&format!("claims {count} triangles"))
                && msg.contains(&format!("holds {} bytes", b.len()))
                && msg.contains("base_link"),
            "{msg}"
        );
    }
}
