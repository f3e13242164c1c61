use nalgebra::Point3;

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
        Some(self.vertices.iter().fold((first, first), |(lo, hi), v| (lo.inf(v), hi.sup(v))))
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
