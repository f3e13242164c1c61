//! The robot's surroundings as the camera sees them: floor, the mounting plate with its bolt
//! heads, the cable leaving the base, and clutter. None of this is in the robot model — it is
//! the CAD mismatch and background that registration must be robust to.

use std::f64::consts::TAU;

use nalgebra::{Isometry3, Point3, Vector3};
use rand::Rng;

use crate::model::TriMesh;

/// What surrounds the robot. All lengths metres, in the model (URDF root) frame: z = 0 is the
/// mounting face of the robot base, z up.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CellOptions {
    /// A floor/table plane under the robot.
    pub floor: bool,
    /// Thickness of a square mounting plate between the base and the floor (0: none). Its
    /// side is the base diameter plus 0.12 m; it carries four corner bolt heads.
    pub plate_thickness_m: f64,
    /// Bolt heads on the base foot (the robot's own mounting bolts), not in the CAD model.
    pub base_bolts: bool,
    /// A cable (Ø 12 mm) leaving the base side and running along the floor.
    pub cable: bool,
    /// Number of random boxes and cylinders on the floor around the robot.
    pub clutter_objects: usize,
}

impl Default for CellOptions {
    fn default() -> Self {
        Self {
            floor: true,
            plate_thickness_m: 0.015,
            base_bolts: true,
            cable: true,
            clutter_objects: 4,
        }
    }
}

/// Most clutter objects (`cell.clutter_objects`) a cell may have.
pub(crate) const MAX_CLUTTER_OBJECTS: usize = 200;
/// Thickest mounting plate (`cell.plate_thickness_m`), metres.
pub(crate) const MAX_PLATE_THICKNESS_M: f64 = 0.5;

impl CellOptions {
    /// Whether the knobs make sense; the message names the key, its unit and range.
    pub fn validate(&self) -> Result<(), String> {
        handeye_hal::limits::check_range(
            "cell.plate_thickness_m",
            self.plate_thickness_m,
            0.0,
            MAX_PLATE_THICKNESS_M,
            "m",
            "0 for no plate",
        )?;
        if self.clutter_objects > MAX_CLUTTER_OBJECTS {
            return Err(format!(
                "cell.clutter_objects = {}: expected 0 <= value <= {MAX_CLUTTER_OBJECTS} (boxes and cylinders on the floor)",
                self.clutter_objects
            ));
        }
        Ok(())
    }

    /// Only the robot, floating in empty space.
    pub fn none() -> Self {
        Self {
            floor: false,
            plate_thickness_m: 0.0,
            base_bolts: false,
            cable: false,
            clutter_objects: 0,
        }
    }
}

/// What a cell mesh is, for ground truth and tests.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum CellPart {
    /// The floor plane.
    Floor,
    /// The mounting plate and its bolt heads.
    Plate,
    /// Bolt heads on the base foot.
    BaseBolts,
    /// The cable.
    Cable,
    /// A clutter object.
    Clutter,
}

/// Builds the cell meshes (model frame) around a base of the given radius (metres, the base
/// foot's outer radius) centred on the model origin.
pub fn build_cell(
    opts: &CellOptions,
    base_radius_m: f64,
    rng: &mut impl Rng,
) -> Vec<(CellPart, TriMesh)> {
    let mut out = Vec::new();
    let floor_z = -opts.plate_thickness_m.max(0.0);
    if opts.floor {
        let s = 4.0;
        out.push((
            CellPart::Floor,
            TriMesh {
                vertices: vec![
                    Point3::new(-s, -s, floor_z),
                    Point3::new(s, -s, floor_z),
                    Point3::new(s, s, floor_z),
                    Point3::new(-s, s, floor_z),
                ],
                triangles: vec![[0, 1, 2], [0, 2, 3]],
            },
        ));
    }
    if opts.plate_thickness_m > 0.0 {
        let half = base_radius_m + 0.06;
        let mut plate = cuboid(Vector3::new(half, half, opts.plate_thickness_m / 2.0));
        transform(
            &mut plate,
            &Isometry3::translation(0.0, 0.0, -opts.plate_thickness_m / 2.0),
        );
        for (sx, sy) in [(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)] {
            let mut bolt = prism(0.0065, 0.0053, 6);
            transform(
                &mut bolt,
                &Isometry3::translation(sx * (half - 0.02), sy * (half - 0.02), 0.0),
            );
            append(&mut plate, &bolt);
        }
        out.push((CellPart::Plate, plate));
    }
    if opts.base_bolts {
        let mut bolts = TriMesh::default();
        for k in 0..4 {
            let a = TAU * (k as f64 + 0.5) / 4.0;
            let r = base_radius_m + 0.008;
            let mut bolt = prism(0.0065, 0.0053, 6);
            transform(
                &mut bolt,
                &Isometry3::translation(r * a.cos(), r * a.sin(), 0.0),
            );
            append(&mut bolts, &bolt);
        }
        out.push((CellPart::BaseBolts, bolts));
    }
    if opts.cable {
        // Leaves the base side at 3 cm height, bends down to the floor and runs away.
        let a: f64 = rng.random_range(0.0..TAU);
        let dir = Vector3::new(a.cos(), a.sin(), 0.0);
        let r0 = base_radius_m - 0.002;
        let path: Vec<Point3<f64>> = [
            (r0, 0.03),
            (r0 + 0.03, 0.03),
            (r0 + 0.06, 0.015),
            (r0 + 0.09, floor_z + 0.006),
            (r0 + 0.8, floor_z + 0.006),
        ]
        .iter()
        .map(|&(d, z)| Point3::from(dir * d + Vector3::new(0.0, 0.0, z)))
        .collect();
        out.push((CellPart::Cable, tube(&path, 0.006, 12)));
    }
    for _ in 0..opts.clutter_objects {
        let a: f64 = rng.random_range(0.0..TAU);
        let d: f64 = rng.random_range(base_radius_m + 0.25..base_radius_m + 0.8);
        let yaw: f64 = rng.random_range(0.0..TAU);
        let mut m = if rng.random_bool(0.5) {
            let h = Vector3::new(
                rng.random_range(0.02..0.1),
                rng.random_range(0.02..0.1),
                rng.random_range(0.015..0.08),
            );
            let mut b = cuboid(h);
            transform(&mut b, &Isometry3::translation(0.0, 0.0, h.z));
            b
        } else {
            prism(
                rng.random_range(0.02..0.06),
                rng.random_range(0.03..0.15),
                24,
            )
        };
        transform(
            &mut m,
            &Isometry3::new(
                Vector3::new(d * a.cos(), d * a.sin(), floor_z),
                Vector3::z() * yaw,
            ),
        );
        out.push((CellPart::Clutter, m));
    }
    out
}

/// An axis-aligned box with the given half extents, centred on the origin.
pub(crate) fn cuboid(half: Vector3<f64>) -> TriMesh {
    let vertices = (0..8)
        .map(|i| {
            Point3::new(
                if i & 1 == 0 { -half.x } else { half.x },
                if i & 2 == 0 { -half.y } else { half.y },
                if i & 4 == 0 { -half.z } else { half.z },
            )
        })
        .collect();
    let triangles = vec![
        [0, 2, 1],
        [1, 2, 3], // -z
        [4, 5, 6],
        [5, 7, 6], // +z
        [0, 1, 4],
        [1, 5, 4], // -y
        [2, 6, 3],
        [3, 6, 7], // +y
        [0, 4, 2],
        [2, 4, 6], // -x
        [1, 3, 5],
        [3, 7, 5], // +x
    ];
    TriMesh {
        vertices,
        triangles,
    }
}

/// A closed vertical prism (a cylinder for many sides) of the given radius and height,
/// standing on z = 0.
pub(crate) fn prism(radius: f64, height: f64, sides: u32) -> TriMesh {
    let mut vertices = vec![Point3::new(0.0, 0.0, 0.0), Point3::new(0.0, 0.0, height)];
    for k in 0..sides {
        let a = TAU * f64::from(k) / f64::from(sides);
        vertices.push(Point3::new(radius * a.cos(), radius * a.sin(), 0.0));
        vertices.push(Point3::new(radius * a.cos(), radius * a.sin(), height));
    }
    let mut triangles = Vec::new();
    for k in 0..sides {
        let (b0, t0) = (2 + 2 * k, 3 + 2 * k);
        let (b1, t1) = (2 + 2 * ((k + 1) % sides), 3 + 2 * ((k + 1) % sides));
        triangles.extend([[0, b1, b0], [1, t0, t1], [b0, b1, t1], [b0, t1, t0]]);
    }
    TriMesh {
        vertices,
        triangles,
    }
}

/// An open tube of the given radius along a polyline.
pub(crate) fn tube(path: &[Point3<f64>], radius: f64, sides: u32) -> TriMesh {
    let mut mesh = TriMesh::default();
    for (i, p) in path.iter().enumerate() {
        let tangent = match (i.checked_sub(1).and_then(|j| path.get(j)), path.get(i + 1)) {
            (Some(a), Some(b)) => b - a,
            (None, Some(b)) => b - p,
            (Some(a), None) => p - a,
            (None, None) => Vector3::x(),
        }
        .normalize();
        let helper = if tangent.z.abs() < 0.9 {
            Vector3::z()
        } else {
            Vector3::x()
        };
        let u = tangent.cross(&helper).normalize();
        let v = tangent.cross(&u);
        for k in 0..sides {
            let a = TAU * f64::from(k) / f64::from(sides);
            mesh.vertices.push(p + (u * a.cos() + v * a.sin()) * radius);
        }
    }
    for i in 0..path.len().saturating_sub(1) as u32 {
        for k in 0..sides {
            let (a, b) = (i * sides + k, i * sides + (k + 1) % sides);
            let (c, d) = (a + sides, b + sides);
            mesh.triangles.extend([[a, b, d], [a, d, c]]);
        }
    }
    mesh
}

/// Moves every vertex by `t`.
pub(crate) fn transform(mesh: &mut TriMesh, t: &Isometry3<f64>) {
    for v in &mut mesh.vertices {
        *v = t * *v;
    }
}

/// Appends `other` to `mesh`.
pub(crate) fn append(mesh: &mut TriMesh, other: &TriMesh) {
    let base = mesh.vertices.len() as u32;
    mesh.vertices.extend_from_slice(&other.vertices);
    mesh.triangles
        .extend(other.triangles.iter().map(|t| t.map(|i| i + base)));
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn default_cell_has_every_part_around_the_base_and_under_it() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let parts = build_cell(&CellOptions::default(), 0.075, &mut rng);
        let kinds: Vec<CellPart> = parts.iter().map(|p| p.0).collect();
        for k in [
            CellPart::Floor,
            CellPart::Plate,
            CellPart::BaseBolts,
            CellPart::Cable,
            CellPart::Clutter,
        ] {
            assert!(kinds.contains(&k), "{k:?} missing");
        }
        for (kind, mesh) in &parts {
            let (lo, hi) = mesh.bounding_box().expect("non-empty");
            assert!(lo.z >= -0.015 - 1e-9, "{kind:?} below the floor");
            if *kind == CellPart::Clutter {
                // clutter stays clear of the base
                let c = (lo.coords + hi.coords) / 2.0;
                assert!(c.xy().norm() > 0.2, "{kind:?} too close: {c}");
            }
        }
        assert!(build_cell(&CellOptions::none(), 0.075, &mut rng).is_empty());
    }

    #[test]
    fn primitives_are_closed_where_they_should_be() {
        // every edge of a closed mesh is shared by exactly two triangles
        for mesh in [cuboid(Vector3::new(0.1, 0.2, 0.3)), prism(0.05, 0.1, 8)] {
            let mut edges = std::collections::HashMap::new();
            for t in &mesh.triangles {
                for k in 0..3 {
                    let (a, b) = (t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3]));
                    *edges.entry((a, b)).or_insert(0) += 1;
                }
            }
            assert!(edges.values().all(|&n| n == 2));
        }
        let t = tube(
            &[
                Point3::origin(),
                Point3::new(1.0, 0.0, 0.0),
                Point3::new(1.0, 1.0, 0.0),
            ],
            0.01,
            6,
        );
        assert_eq!(t.vertices.len(), 18);
        for v in &t.vertices[..6] {
            assert!((v.coords.yz().norm() - 0.01).abs() < 1e-12);
        }
    }
}
