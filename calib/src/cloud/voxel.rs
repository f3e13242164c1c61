//! Voxel-grid downsampling.
use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use nalgebra::Point3;

/// One centroid per occupied cubic voxel of side `voxel_m` (metres), in the order the voxels
/// are first met. Non-finite points are dropped. With `voxel_m` not finite or ≤ 0 the finite
/// points are returned unchanged.
///
/// Voxels are aligned to the origin (`floor(p / voxel_m)`); sums are in `f64`, so centroids
/// of many points stay exact to `f32` precision.
pub fn voxel_downsample(points: &[Point3<f32>], voxel_m: f32) -> Vec<Point3<f32>> {
    let finite = |p: &&Point3<f32>| p.coords.iter().all(|c| c.is_finite());
    if !(voxel_m.is_finite() && voxel_m > 0.0) {
        return points.iter().filter(finite).copied().collect();
    }
    let inv = 1.0 / f64::from(voxel_m);
    let key = |p: &Point3<f32>| {
        // `as` saturates: points beyond ±2^31 voxels share the edge voxel.
        let k = |c: f32| (f64::from(c) * inv).floor() as i32;
        (k(p.x), k(p.y), k(p.z))
    };
    let mut index: HashMap<(i32, i32, i32), u32, BuildHasherDefault<VoxelHasher>> =
        HashMap::default();
    let mut sums: Vec<([f64; 3], u32)> = Vec::new();
    for p in points.iter().filter(finite) {
        let slot = *index.entry(key(p)).or_insert_with(|| {
            sums.push(([0.0; 3], 0));
            (sums.len() - 1) as u32
        });
        let (s, n) = &mut sums[slot as usize];
        s[0] += f64::from(p.x);
        s[1] += f64::from(p.y);
        s[2] += f64::from(p.z);
        *n += 1;
    }
    sums.into_iter()
        .map(|(s, n)| {
            let n = f64::from(n);
            Point3::new((s[0] / n) as f32, (s[1] / n) as f32, (s[2] / n) as f32)
        })
        .collect()
}

/// A fast multiplicative hasher for small integer keys (FxHash's scheme; the keys are not
/// attacker-controlled in a way that matters: worst case is slower downsampling).
#[derive(Debug, Default)]
struct VoxelHasher(u64);

impl Hasher for VoxelHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(u64::from(b));
        }
    }
    fn write_i32(&mut self, i: i32) {
        self.write_u64(u64::from(i as u32));
    }
    fn write_u64(&mut self, i: u64) {
        self.0 = (self.0.rotate_left(5) ^ i).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_centroid_per_voxel() {
        let pts = [
            Point3::new(0.01, 0.01, 0.01),
            Point3::new(0.03, 0.05, 0.07),
            Point3::new(0.15, 0.0, 0.0),
            Point3::new(f32::NAN, 0.0, 0.0),
            Point3::new(-0.01, 0.0, 0.0),
        ];
        let out = voxel_downsample(&pts, 0.1);
        assert_eq!(out.len(), 3);
        assert!((out[0] - Point3::new(0.02, 0.03, 0.04)).norm() < 1e-6);
        assert_eq!(out[1], Point3::new(0.15, 0.0, 0.0));
        assert_eq!(out[2], Point3::new(-0.01, 0.0, 0.0));
    }

    #[test]
    fn dense_grid_reduces_to_voxel_count() {
        // 20×20×20 points 1 mm apart, voxels 5 mm: 4×4×4 voxels of 125 points each.
        let mut pts = Vec::new();
        for i in 0..20 {
            for j in 0..20 {
                for k in 0..20 {
                    pts.push(Point3::new(
                        i as f32 * 1e-3 + 5e-4,
                        j as f32 * 1e-3 + 5e-4,
                        k as f32 * 1e-3 + 5e-4,
                    ));
                }
            }
        }
        let out = voxel_downsample(&pts, 5e-3);
        assert_eq!(out.len(), 64);
        for p in &out {
            // Centroid of 5 points at 0.5..4.5 mm inside each voxel: 2.5 mm from its corner.
            for c in p.coords.iter() {
                let r = (c * 1e3 - 2.5) / 5.0;
                assert!((r - r.round()).abs() < 1e-3, "{p:?}");
            }
        }
    }

    #[test]
    fn bad_voxel_size_keeps_finite_points() {
        let pts = [
            Point3::new(1.0, 2.0, 3.0),
            Point3::new(f32::INFINITY, 0.0, 0.0),
        ];
        assert_eq!(
            voxel_downsample(&pts, 0.0),
            vec![Point3::new(1.0, 2.0, 3.0)]
        );
        assert_eq!(voxel_downsample(&pts, f32::NAN).len(), 1);
    }
}
