use nalgebra::Point3;

/// A point cloud in the camera frame: metres, OpenCV axes (x right, y down, z forward).
///
/// Organized clouds keep the sensor's pixel grid (`width × height`, row-major, one entry per
/// pixel); pixels without a measurement hold NaN coordinates. Unorganized clouds have
/// `height == 1` and `width == points.len()`. `f32` keeps a 5 M-point scan at 60 MB.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointCloud {
    /// Pixel-grid width (number of columns), or the point count for unorganized clouds.
    pub width: u32,
    /// Pixel-grid height (number of rows), 1 for unorganized clouds.
    pub height: u32,
    /// Coordinates in metres; NaN marks a pixel with no valid measurement.
    pub points: Vec<Point3<f32>>,
    /// Per-point intensity/grey value when the camera delivers one (same length as `points`).
    pub intensity: Option<Vec<f32>>,
    /// Per-point confidence in [0, 1] when the camera delivers one (same length as `points`).
    pub confidence: Option<Vec<f32>>,
}

impl PointCloud {
    /// An unorganized cloud from points (no intensity, no confidence).
    pub fn from_points(points: Vec<Point3<f32>>) -> Self {
        let width = u32::try_from(points.len()).unwrap_or(u32::MAX);
        Self { width, height: 1, points, intensity: None, confidence: None }
    }

    /// Whether the cloud keeps a sensor pixel grid (more than one row).
    pub fn is_organized(&self) -> bool {
        self.height > 1
    }

    /// Number of entries, valid or not.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether the cloud has no entries at all.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Iterator over the valid (finite) points.
    pub fn valid_points(&self) -> impl Iterator<Item = &Point3<f32>> + '_ {
        self.points.iter().filter(|p| p.coords.iter().all(|c| c.is_finite()))
    }

    /// Number of valid (finite) points.
    pub fn valid_count(&self) -> usize {
        self.valid_points().count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn invalid_points_are_not_counted() {
        let c = PointCloud::from_points(vec![
            Point3::new(0.0, 0.0, 1.0),
            Point3::new(f32::NAN, f32::NAN, f32::NAN),
            Point3::new(0.1, 0.0, 1.0),
        ]);
        assert_eq!(c.len(), 3);
        assert_eq!(c.valid_count(), 2);
        assert!(!c.is_organized());
    }
}
