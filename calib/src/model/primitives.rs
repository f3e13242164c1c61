//! Tessellation of the URDF primitives (box, cylinder, sphere, capsule) into [`TriMesh`]es,
//! centred on their own origin as URDF defines them (cylinder and capsule along z).

use std::f64::consts::{FRAC_PI_2, TAU};

use nalgebra::Point3;

use super::TriMesh;

/// Segments around the circumference of round primitives (error ≤ 0.5 % of the radius).
const SEGMENTS: u32 = 32;
/// Latitude rings per hemisphere of spheres and capsules.
const RINGS: u32 = 8;

/// A box of full extents `size` (x, y, z), centred on the origin.
pub(crate) fn cuboid(size: [f64; 3]) -> TriMesh {
    let h = size.map(|s| s / 2.0);
    let vertices = (0..8)
        .map(|i| {
            let s = |bit: u32| if i & (1 << bit) != 0 { 1.0 } else { -1.0 };
            Point3::new(s(0) * h[0], s(1) * h[1], s(2) * h[2])
        })
        .collect();
    // Vertex i has x from bit 0, y from bit 1, z from bit 2; faces wound CCW from outside.
    let quads: [[u32; 4]; 6] = [
        [0, 2, 3, 1], // -z
        [4, 5, 7, 6], // +z
        [0, 1, 5, 4], // -y
        [2, 6, 7, 3], // +y
        [0, 4, 6, 2], // -x
        [1, 3, 7, 5], // +x
    ];
    let triangles = quads
        .iter()
        .flat_map(|&[a, b, c, d]| [[a, b, c], [a, c, d]])
        .collect();
    TriMesh {
        vertices,
        triangles,
    }
}

/// A closed cylinder of `radius` and `length` along z, centred on the origin.
pub(crate) fn cylinder(radius: f64, length: f64) -> TriMesh {
    let h = length / 2.0;
    // Two rings, then the two cap centres.
    lathe(&[(h, radius), (-h, radius)], Some(h), Some(-h))
}

/// A UV sphere of `radius` centred on the origin.
pub(crate) fn sphere(radius: f64) -> TriMesh {
    capsule(radius, 0.0)
}

/// A capsule: a cylinder of `radius` and `length` along z with hemispherical caps.
pub(crate) fn capsule(radius: f64, length: f64) -> TriMesh {
    let h = length / 2.0;
    let mut rings = Vec::new();
    // Upper hemisphere from just below the pole to the equator, lower from equator to pole.
    for i in 1..=RINGS {
        let lat = FRAC_PI_2 - FRAC_PI_2 * f64::from(i) / f64::from(RINGS);
        rings.push((h + radius * lat.sin(), radius * lat.cos()));
    }
    for i in 0..RINGS {
        let lat = -FRAC_PI_2 * f64::from(i) / f64::from(RINGS);
        rings.push((-h + radius * lat.sin(), radius * lat.cos()));
    }
    lathe(&rings, Some(h + radius), Some(-h - radius))
}

/// A surface of revolution about z: `rings` are `(z, r)` from top to bottom, closed by a top
/// and a bottom apex (cap centre or pole) at the given heights.
fn lathe(rings: &[(f64, f64)], top: Option<f64>, bottom: Option<f64>) -> TriMesh {
    let n = SEGMENTS;
    let mut m = TriMesh::default();
    for &(z, r) in rings {
        for j in 0..n {
            let a = TAU * f64::from(j) / f64::from(n);
            m.vertices.push(Point3::new(r * a.cos(), r * a.sin(), z));
        }
    }
    let ring = |k: usize, j: u32| (k as u32) * n + (j % n);
    for k in 0..rings.len().saturating_sub(1) {
        for j in 0..n {
            let (a, b) = (ring(k, j), ring(k, j + 1));
            let (c, d) = (ring(k + 1, j), ring(k + 1, j + 1));
            // Ring k is above ring k+1; CCW seen from outside.
            m.triangles.push([a, c, d]);
            m.triangles.push([a, d, b]);
        }
    }
    if let Some(z) = top {
        let apex = m.vertices.len() as u32;
        m.vertices.push(Point3::new(0.0, 0.0, z));
        for j in 0..n {
            m.triangles.push([apex, ring(0, j), ring(0, j + 1)]);
        }
    }
    if let Some(z) = bottom {
        let apex = m.vertices.len() as u32;
        m.vertices.push(Point3::new(0.0, 0.0, z));
        let last = rings.len().saturating_sub(1);
        for j in 0..n {
            m.triangles.push([apex, ring(last, j + 1), ring(last, j)]);
        }
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn rel_err(a: f64, b: f64) -> f64 {
        (a - b).abs() / b.abs()
    }

    #[test]
    fn primitives_are_closed_outward_wound_and_of_the_right_size() {
        let b = cuboid([0.1, 0.2, 0.3]);
        assert!(rel_err(b.signed_volume(), 0.006) < 1e-12);
        let (lo, hi) = b.bounding_box().expect("box");
        assert!((hi - lo - nalgebra::Vector3::new(0.1, 0.2, 0.3)).norm() < 1e-12);

        let c = cylinder(0.05, 0.2);
        assert!(rel_err(c.signed_volume(), PI * 0.05 * 0.05 * 0.2) < 0.01);
        let (lo, hi) = c.bounding_box().expect("cylinder");
        assert!(
            (lo.z + 0.1).abs() < 1e-12 && (hi.z - 0.1).abs() < 1e-12 && (hi.x - 0.05).abs() < 1e-12
        );

        let s = sphere(0.1);
        assert!(rel_err(s.signed_volume(), 4.0 / 3.0 * PI * 1e-3) < 0.03);
        let (lo, hi) = s.bounding_box().expect("sphere");
        assert!((lo.z + 0.1).abs() < 1e-12 && (hi.z - 0.1).abs() < 1e-12);

        let k = capsule(0.1, 0.4);
        let want = PI * 0.01 * 0.4 + 4.0 / 3.0 * PI * 1e-3;
        assert!(rel_err(k.signed_volume(), want) < 0.03);
        for m in [b, c, s, k] {
            m.validate().expect("valid");
        }
    }
}
