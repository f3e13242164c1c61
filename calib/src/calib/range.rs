//! The scan as a range image: a pinhole grid of camera-frame points, so that "what does the
//! camera see along this ray" is one array lookup (used for hypothesis scoring, free-space
//! checks and coverage), plus neighbour-based normals.
//!
//! An organized cloud is used as is, with its pinhole intrinsics estimated from the points
//! themselves (`u = fx·x/z + cx`); an unorganized cloud is splatted into a synthetic pinhole
//! image centred on the camera origin (nearest point per pixel).

use std::borrow::Cow;

use handeye_hal::PointCloud;
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use super::CalibError;
use crate::geometry::Intrinsics;

/// A range image of the scan (camera frame, metres; NaN = no measurement).
#[derive(Debug)]
pub struct RangeImage<'a> {
    /// The grid's pinhole model (`width`×`height` = `points.len()`).
    pub cam: Intrinsics,
    pub points: Cow<'a, [Point3<f32>]>,
    /// Whether the grid is the camera's own (true) or a synthetic splat of an unorganized cloud.
    #[cfg_attr(not(test), allow(dead_code))]
    pub organized: bool,
}

impl<'a> RangeImage<'a> {
    /// One valid pixel per cell of a regular grid whose spacing gives about `target` valid
    /// pixels (the first valid one of the cell, row by row), the valid count being estimated
    /// from every `sample_step`-th pixel. Per cell, not per grid point: a scan whose invalid
    /// pixels repeat with the grid's period (every 7th pixel, a sensor's dead columns) would
    /// leave a grid of points nothing.
    pub fn grid(&self, target: usize, sample_step: usize) -> impl Iterator<Item = usize> + '_ {
        let valid = self
            .points
            .iter()
            .step_by(sample_step)
            .filter(|p| p.z > 0.0)
            .count()
            * sample_step;
        let stride = ((valid as f64 / target as f64).sqrt().floor() as usize).max(1);
        let (w, h) = (self.cam.width as usize, self.cam.height as usize);
        let n = self.points.len();
        (0..h).step_by(stride).flat_map(move |v0| {
            (0..w).step_by(stride).filter_map(move |u0| {
                (v0..(v0 + stride).min(h))
                    .flat_map(|v| (u0..(u0 + stride).min(w)).map(move |u| v * w + u))
                    .find(|&i| i < n && self.point(i).is_some())
            })
        })
    }

    /// Wraps a scan; fails when it has too few valid points to be a scan of anything.
    pub fn new(scan: &'a PointCloud) -> Result<Self, CalibError> {
        let valid = scan.valid_count();
        if valid < 500 {
            return Err(CalibError::EmptyScan {
                valid_points: valid,
            });
        }
        if scan.is_organized() && scan.width > 1 && scan.height > 1 {
            if let Some(cam) = estimate_intrinsics(scan) {
                return Ok(RangeImage {
                    cam,
                    points: Cow::Borrowed(&scan.points),
                    organized: true,
                });
            }
        }
        Ok(splat(scan))
    }

    /// The scan's measurement noise, metres: the median RMS distance of the points of small
    /// patches (7×7 pixels on a 16-pixel grid) from their best plane. Patches across a depth
    /// edge (depths spread over more than 2 cm and more than [`EDGE_SPREAD`] times what the
    /// patch's own pixel-to-pixel differences show, or points along a line rather than a
    /// surface) and patches with fewer than 30 points are left out. `None` when fewer than 50
    /// patches qualify. It measures the sensor as it measured this scan: its noise at the
    /// depths the scan holds, its depth quantisation, and the roughness of what it saw within a
    /// few millimetres. A fixed 2 cm spread would leave out every patch of a camera whose pixels
    /// scatter by 5 mm (a consumer stereo camera at a few metres), and the scan would be taken
    /// for a precise one. Pixels scattered by more than about a tenth of the patch's width
    /// measure low (the best plane tilts to take some of it: 5 mm at 2 mm a pixel measures
    /// 3.5 mm).
    pub fn noise_m(&self) -> Option<f64> {
        const HALF: usize = 3;
        const STEP: usize = 16;
        let (w, h) = (self.cam.width as usize, self.cam.height as usize);
        if w < 2 * HALF + 1 || h < 2 * HALF + 1 {
            return None;
        }
        // Every registration measures it: the rows of patches in parallel (a 2448×2048 scan
        // has ~19 000 of them).
        let mut rms: Vec<f64> = (HALF..h - HALF)
            .into_par_iter()
            .step_by(STEP)
            .flat_map_iter(|v| (HALF..w - HALF).step_by(STEP).map(move |u| (u, v)))
            .filter_map(|(u, v)| {
                // The patch's points on the stack: no allocation per patch.
                const SIDE: usize = 2 * HALF + 1;
                let mut buf = [Vector3::<f64>::zeros(); SIDE * SIDE];
                let mut depth = [f64::NAN; SIDE * SIDE];
                let mut count = 0;
                for (k, i) in (v - HALF..=v + HALF)
                    .flat_map(|y| (u - HALF..=u + HALF).map(move |x| y * w + x))
                    .enumerate()
                {
                    if let Some(p) = self.point(i) {
                        buf[count] = p.coords.cast::<f64>();
                        depth[k] = buf[count].z;
                        count += 1;
                    }
                }
                let pts = &buf[..count];
                if pts.len() < 30 {
                    return None;
                }
                let (lo, hi) = pts.iter().fold((f64::MAX, f64::MIN), |(lo, hi), p| {
                    (lo.min(p.z), hi.max(p.z))
                });
                if hi - lo > EDGE_JUMP_M && hi - lo > EDGE_SPREAD * pixel_scatter(&depth, SIDE)? {
                    return None;
                }
                let n = pts.len() as f64;
                let c = pts.iter().sum::<Vector3<f64>>() / n;
                let cov = pts
                    .iter()
                    .map(|p| (p - c) * (p - c).transpose())
                    .sum::<nalgebra::Matrix3<f64>>()
                    / n;
                let mut e = cov.symmetric_eigenvalues();
                e.as_mut_slice().sort_by(f64::total_cmp);
                // A surface spreads the patch in two directions; a line (a thin edge, a cable
                // seen end-on) in one.
                (e[1] > 0.1 * e[2]).then(|| e[0].max(0.0).sqrt())
            })
            .collect();
        if rms.len() < 50 {
            return None;
        }
        let mid = rms.len() / 2;
        Some(*rms.select_nth_unstable_by(mid, f64::total_cmp).1)
    }

    /// The measured point at pixel `i`, or `None` where the scan has no data.
    #[inline]
    pub fn point(&self, i: usize) -> Option<Point3<f32>> {
        let p = self.points[i];
        if p.z.is_finite() && p.x.is_finite() && p.y.is_finite() && p.z > 0.0 {
            Some(p)
        } else {
            None
        }
    }

    /// The measured depth (z, metres) at pixel `i`, NaN where the scan has no data.
    #[inline]
    pub fn depth(&self, i: usize) -> f32 {
        let p = self.points[i];
        if p.z > 0.0 {
            p.z
        } else {
            f32::NAN
        }
    }

    /// Unit normal at pixel `i` from the points about `radius_m` away along the grid (oriented
    /// towards the camera), or `None` where neighbours are missing or lie on another surface.
    pub fn normal(&self, i: usize, radius_m: f64) -> Option<Vector3<f64>> {
        let p = self.point(i)?;
        let w = self.cam.width as usize;
        let (u, v) = ((i % w) as isize, (i / w) as isize);
        let k0 = ((radius_m * self.cam.fx / p.z as f64).round() as isize).clamp(1, 40);
        let mut k = k0;
        while k >= 1 {
            let get = |du: isize, dv: isize| -> Option<Vector3<f64>> {
                let (uu, vv) = (u + du, v + dv);
                if uu < 0 || vv < 0 || uu >= w as isize || vv >= self.cam.height as isize {
                    return None;
                }
                let q = self.point(vv as usize * w + uu as usize)?;
                let d = (q - p).cast::<f64>();
                // A neighbour much farther than expected is across a depth edge.
                if d.norm() > 4.0 * radius_m.max(k as f64 * p.z as f64 / self.cam.fx) {
                    return None;
                }
                Some(d)
            };
            let dx = match (get(k, 0), get(-k, 0)) {
                (Some(a), Some(b)) => Some(a - b),
                (Some(a), None) => Some(a),
                (None, Some(b)) => Some(-b),
                _ => None,
            };
            let dy = match (get(0, k), get(0, -k)) {
                (Some(a), Some(b)) => Some(a - b),
                (Some(a), None) => Some(a),
                (None, Some(b)) => Some(-b),
                _ => None,
            };
            if let (Some(dx), Some(dy)) = (dx, dy) {
                let n = dx.cross(&dy);
                let norm = n.norm();
                if norm > 0.0 {
                    let n = n / norm;
                    let to_cam = -p.coords.cast::<f64>();
                    return Some(if n.dot(&to_cam) < 0.0 { -n } else { n });
                }
            }
            k /= 2;
        }
        None
    }
}

/// Least-squares `u = fx·x/z + cx`, `v = fy·y/z + cy` over a sample of valid pixels, with one
/// round of outlier rejection; `None` when the grid is not a pinhole image (residual > 0.5 px).
fn estimate_intrinsics(scan: &PointCloud) -> Option<Intrinsics> {
    let (w, h) = (scan.width as usize, scan.height as usize);
    let n = w * h;
    let step = (n / 20000).max(1);
    let samples: Vec<(f64, f64, f64, f64)> = (0..n)
        .step_by(step)
        .filter_map(|i| {
            let p = scan.points[i];
            if !(p.z > 1e-4 && p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
                return None;
            }
            Some((
                (i % w) as f64,
                (i / w) as f64,
                p.x as f64 / p.z as f64,
                p.y as f64 / p.z as f64,
            ))
        })
        .collect();
    if samples.len() < 50 {
        return None;
    }
    let fit = |pairs: &mut dyn Iterator<Item = (f64, f64)>| -> Option<(f64, f64)> {
        let (mut s1, mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for (x, y) in pairs {
            s1 += 1.0;
            sx += x;
            sy += y;
            sxx += x * x;
            sxy += x * y;
        }
        let det = s1 * sxx - sx * sx;
        if s1 < 10.0 || det.abs() < 1e-12 {
            return None;
        }
        let f = (s1 * sxy - sx * sy) / det;
        Some((f, (sy - f * sx) / s1))
    };
    let (mut fx, mut cx) = fit(&mut samples.iter().map(|s| (s.2, s.0)))?;
    let (mut fy, mut cy) = fit(&mut samples.iter().map(|s| (s.3, s.1)))?;
    for _ in 0..2 {
        let keep: Vec<&(f64, f64, f64, f64)> = samples
            .iter()
            .filter(|s| (fx * s.2 + cx - s.0).abs() < 1.0 && (fy * s.3 + cy - s.1).abs() < 1.0)
            .collect();
        if keep.len() < samples.len() / 2 {
            return None;
        }
        (fx, cx) = fit(&mut keep.iter().map(|s| (s.2, s.0)))?;
        (fy, cy) = fit(&mut keep.iter().map(|s| (s.3, s.1)))?;
    }
    let good = samples
        .iter()
        .filter(|s| (fx * s.2 + cx - s.0).abs() < 0.5 && (fy * s.3 + cy - s.1).abs() < 0.5)
        .count();
    (fx > 0.0 && fy > 0.0 && good * 10 >= samples.len() * 8).then_some(Intrinsics {
        width: scan.width,
        height: scan.height,
        fx,
        fy,
        cx,
        cy,
    })
}

/// Splats an unorganized cloud into a synthetic pinhole image (nearest point per pixel).
fn splat(scan: &PointCloud) -> RangeImage<'static> {
    let pts: Vec<&Point3<f32>> = scan.valid_points().filter(|p| p.z > 1e-4).collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in &pts {
        let t = [p.x as f64 / p.z as f64, p.y as f64 / p.z as f64];
        for d in 0..2 {
            lo[d] = lo[d].min(t[d]);
            hi[d] = hi[d].max(t[d]);
        }
    }
    // About one point per pixel.
    let span = ((hi[0] - lo[0]) * (hi[1] - lo[1])).max(1e-9);
    let f = (pts.len() as f64 / span).sqrt().clamp(10.0, 4000.0);
    let width = (((hi[0] - lo[0]) * f).ceil() as usize + 1).clamp(2, 8192);
    let height = (((hi[1] - lo[1]) * f).ceil() as usize + 1).clamp(2, 8192);
    let cam = Intrinsics {
        width: width as u32,
        height: height as u32,
        fx: f,
        fy: f,
        cx: -lo[0] * f,
        cy: -lo[1] * f,
    };
    let mut grid = vec![Point3::new(f32::NAN, f32::NAN, f32::NAN); width * height];
    for p in pts {
        if let Some(i) = cam.pixel_index(&p.cast::<f64>()) {
            if grid[i].z.is_nan() || p.z < grid[i].z {
                grid[i] = *p;
            }
        }
    }
    RangeImage {
        cam,
        points: Cow::Owned(grid),
        organized: false,
    }
}

/// Depths of a patch spread over more than this are a depth edge unless the patch's own pixel
/// scatter explains them ([`EDGE_SPREAD`]), metres.
const EDGE_JUMP_M: f64 = 0.02;
/// A patch whose depths spread over more than this many times its pixel scatter
/// ([`pixel_scatter`]) holds a depth edge: 49 normal draws spread over about 5σ, 7σ at most.
const EDGE_SPREAD: f64 = 10.0;

/// The depth scatter of one pixel of a `side`×`side` patch (row-major, NaN where empty),
/// metres, from its neighbours: the median absolute deviation of the differences between
/// neighbouring pixels, across and down, each about its own median (the surface's slope), over
/// √2. An edge through the patch changes a few of the differences and not the median. `None`
/// with fewer than ten differences.
fn pixel_scatter(depth: &[f64], side: usize) -> Option<f64> {
    let mut diffs = [0.0; 128];
    let mut all = 0;
    for (dx, dy) in [(1, 0), (0, 1)] {
        let start = all;
        for y in 0..side - dy {
            for x in 0..side - dx {
                let d = depth[(y + dy) * side + x + dx] - depth[y * side + x];
                if d.is_finite() && all < diffs.len() {
                    diffs[all] = d;
                    all += 1;
                }
            }
        }
        let along = &mut diffs[start..all];
        if along.is_empty() {
            continue;
        }
        let mid = along.len() / 2;
        let median = *along.select_nth_unstable_by(mid, f64::total_cmp).1;
        for d in along.iter_mut() {
            *d = (*d - median).abs();
        }
    }
    if all < 10 {
        return None;
    }
    let mid = all / 2;
    let mad = *diffs[..all].select_nth_unstable_by(mid, f64::total_cmp).1;
    Some(1.4826 * mad / std::f64::consts::SQRT_2)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane_scan(w: u32, h: u32) -> PointCloud {
        let (fx, fy, cx, cy) = (300.0, 310.0, w as f64 / 2.0 - 0.5, h as f64 / 2.0 + 0.3);
        let mut pts = Vec::new();
        for v in 0..h {
            for u in 0..w {
                // Tilted plane z = 0.6 + 0.2·x.
                let (a, b) = ((u as f64 - cx) / fx, (v as f64 - cy) / fy);
                let z = 0.6 / (1.0 - 0.2 * a);
                pts.push(Point3::new((a * z) as f32, (b * z) as f32, z as f32));
            }
        }
        PointCloud {
            width: w,
            height: h,
            points: pts,
            intensity: None,
            confidence: None,
        }
    }

    #[test]
    fn intrinsics_are_recovered_from_an_organized_cloud() {
        let scan = plane_scan(160, 120);
        let r = RangeImage::new(&scan).expect("valid");
        assert!(r.organized);
        assert!((r.cam.fx - 300.0).abs() < 0.1 && (r.cam.fy - 310.0).abs() < 0.1);
        assert!((r.cam.cx - 79.5).abs() < 0.05 && (r.cam.cy - 60.3).abs() < 0.05);
        let n = r.normal(60 * 160 + 80, 0.005).expect("normal");
        let expected = Vector3::new(0.2, 0.0, -1.0).normalize();
        assert!((n - expected).norm() < 1e-3, "{n}");
    }

    /// The noise of a plane with a 10 cm step across it, each depth scattered along its ray
    /// by `sigma_m`.
    fn noisy_step(sigma_m: f64, seed: u64) -> PointCloud {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let noise = Normal::new(0.0, sigma_m).expect("σ");
        let mut scan = plane_scan(320, 240);
        for (i, p) in scan.points.iter_mut().enumerate() {
            let step = if i % 320 < 160 { 0.0 } else { 0.1 };
            let along = 1.0 + (step + noise.sample(&mut rng)) / f64::from(p.z);
            *p = Point3::from(p.coords * along as f32);
        }
        scan
    }

    /// A consumer stereo camera's pixels scatter by millimetres: its noise is measured as
    /// such (a fixed 2 cm limit on a patch's depth spread had left out every patch at 5 mm and
    /// measured nothing, and the scan was fitted as a precise one), and the depth edge stays
    /// out of it.
    #[test]
    fn a_noisy_scan_measures_its_noise_and_not_its_edges() {
        for (sigma, seed) in [(0.0003, 1), (0.002, 2), (0.005, 3)] {
            let scan = noisy_step(sigma, seed);
            let noise = RangeImage::new(&scan).expect("valid").noise_m();
            let noise = noise.unwrap_or_else(|| panic!("σ {sigma}: the noise was not measured"));
            assert!(
                (0.6..1.15).contains(&(noise / sigma)),
                "σ {sigma}: measured {noise}"
            );
        }
    }

    #[test]
    fn unorganized_cloud_is_splatted() {
        let mut scan = plane_scan(160, 120);
        scan.width = scan.points.len() as u32;
        scan.height = 1;
        let r = RangeImage::new(&scan).expect("valid");
        assert!(!r.organized);
        let p = scan.points[5000].cast::<f64>();
        let i = r.cam.pixel_index(&p).expect("inside");
        assert!((r.depth(i) as f64 - p.z).abs() < 0.01);
    }

    #[test]
    fn empty_scan_is_an_error() {
        let scan = PointCloud {
            width: 10,
            height: 10,
            points: vec![Point3::new(f32::NAN, f32::NAN, f32::NAN); 100],
            intensity: None,
            confidence: None,
        };
        assert!(matches!(
            RangeImage::new(&scan),
            Err(CalibError::EmptyScan { .. })
        ));
    }
}
