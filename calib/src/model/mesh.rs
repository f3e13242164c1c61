use nalgebra::{Isometry3, Matrix4, Point3};

/// A triangle mesh: vertices in metres in the frame of the link that carries it (the URDF
/// `<origin>` and `<mesh scale>` already applied), triangles as vertex-index triples with
/// counter-clockwise winding seen from outside.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TriMesh {
    /// Vertex positions, metres.
    pub vertices: Vec<Point3<f64>>,
    /// Triangles as indices into `vertices`.
    pub triangles: Vec<[u32; 3]>,
}

impl TriMesh {
    /// Axis-aligned bounding box `(min, max)` of the vertices, or `None` for an empty mesh.
    pub fn bounding_box(&self) -> Option<(Point3<f64>, Point3<f64>)> {
        let first = *self.vertices.first()?;
        Some(
            self.vertices
                .iter()
                .fold((first, first), |(lo, hi), v| (lo.inf(v), hi.sup(v))),
        )
    }

    /// Whether the mesh has no triangles.
    pub fn is_empty(&self) -> bool {
        self.triangles.is_empty()
    }

    /// A copy with every vertex mapped through `to_from_self` (a rigid transform).
    pub fn transformed(&self, to_from_self: &Isometry3<f64>) -> TriMesh {
        TriMesh {
            vertices: self.vertices.iter().map(|v| to_from_self * v).collect(),
            triangles: self.triangles.clone(),
        }
    }

    /// Appends `other` with its vertices mapped through the affine `self_from_other`
    /// (homogeneous 4×4; may scale). A mirroring transform (negative determinant) flips the
    /// triangle winding so that it stays counter-clockwise seen from outside.
    pub fn append_transformed(&mut self, other: &TriMesh, self_from_other: &Matrix4<f64>) {
        let base = self.vertices.len() as u32;
        self.vertices.extend(
            other
                .vertices
                .iter()
                .map(|v| self_from_other.transform_point(v)),
        );
        let mirrored = self_from_other.fixed_view::<3, 3>(0, 0).determinant() < 0.0;
        self.triangles
            .extend(other.triangles.iter().map(|&[a, b, c]| {
                if mirrored {
                    [base + a, base + c, base + b]
                } else {
                    [base + a, base + b, base + c]
                }
            }));
    }

    /// Checks that every index is in range and every vertex is finite.
    pub fn validate(&self) -> Result<(), String> {
        if let Some(v) = self
            .vertices
            .iter()
            .find(|v| !v.coords.iter().all(|c| c.is_finite()))
        {
            return Err(format!("non-finite vertex {v}"));
        }
        let n = self.vertices.len();
        if let Some(t) = self
            .triangles
            .iter()
            .find(|t| t.iter().any(|&i| i as usize >= n))
        {
            return Err(format!("triangle {t:?} indexes past the {n} vertices"));
        }
        Ok(())
    }

    /// Signed enclosed volume (m³; positive for a closed mesh wound counter-clockwise seen from
    /// outside). Triangles with out-of-range indices are skipped.
    pub fn signed_volume(&self) -> f64 {
        self.triangles
            .iter()
            .filter_map(|&[a, b, c]| {
                let v = |i: u32| self.vertices.get(i as usize).map(|p| p.coords);
                let (a, b, c) = (v(a)?, v(b)?, v(c)?);
                Some(a.dot(&b.cross(&c)) / 6.0)
            })
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bounding_box_spans_all_vertices() {
        let m = TriMesh {
            vertices: vec![Point3::new(0.0, 1.0, -1.0), Point3::new(2.0, -1.0, 0.5)],
            triangles: vec![],
        };
        let (lo, hi) = m.bounding_box().expect("non-empty");
        assert_eq!(lo, Point3::new(0.0, -1.0, -1.0));
        assert_eq!(hi, Point3::new(2.0, 1.0, 0.5));
        assert!(TriMesh::default().bounding_box().is_none());
    }
}
