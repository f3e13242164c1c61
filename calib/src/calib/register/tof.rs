//! Time of flight: the scan pixels a time-of-flight camera's range is biased on, found from
//! the scan's own evidence and left out of every fit (with
//! [`super::RegisterOptions::multipath_clearance_m`] set, the time-of-flight tuning; the posed
//! model's concave corners are left out besides, `ModelSurface::mark_multipath`).
//!
//! - **Multipath where the scan is concave**: light bounced off a surface that faces the
//!   pixel's surface arrives late. The scan shows those surfaces whether or not they are in
//!   the model (the mounting plate, the floor, bolts, the cable): a pixel with at least
//!   [`MIN_FACING`] samples of a sparse window around it ([`REACH_M`] across, projected) whose
//!   surfaces face its own, and that it faces, is left out. The posed model's corners alone
//!   missed the shoulder's side facing the plate and the base's top several centimetres away
//!   (`handeye bench --camera helios2`, UR3 view 8: 1 250 pixels pushed 1.1 mm long on
//!   surface the fit used, the pose 3.6 and 4.5 mm off and accepted).
//! - **Dark surfaces by the amplitude image** (the cloud's intensity, when the camera gives
//!   it): a dark surface reads long and noisy. Amplitude × range² / cos(incidence) is the
//!   surface's reflectivity up to the camera's constant; a pixel below [`DARK_FRACTION`] of the
//!   scan's bright surfaces (its 90th percentile) is left out (a UR's dark caps and base ring
//!   against its light covers).

use handeye_hal::PointCloud;
use nalgebra::Vector3;
use rayon::prelude::*;

use crate::calib::range::RangeImage;

/// How far around a pixel the scan is searched for surfaces facing it, metres (projected at
/// the pixel's depth, [`MIN_WINDOW_PX`]–[`MAX_WINDOW_PX`] pixels half-width).
const REACH_M: f64 = 0.05;
const MIN_WINDOW_PX: f64 = 12.0;
const MAX_WINDOW_PX: f64 = 24.0;
/// Facing samples (of the window's 80) that mark a pixel: one is noise in the normals.
const MIN_FACING: usize = 3;
/// Smallest cosine between a surface's normal and the direction to another surface for the
/// two to face each other (10° above its plane).
const FACING_COS: f64 = 0.17;
/// Radius of the normals the facing test uses, metres: wide enough that a time-of-flight
/// camera's millimetre of noise tilts them by a few degrees.
const NORMAL_RADIUS_M: f64 = 0.008;
/// A pixel whose reflectivity is below this fraction of the scan's bright surfaces' is dark.
const DARK_FRACTION: f64 = 0.35;

/// Per pixel of `range` (the grid of `scan`): whether a time-of-flight camera's range there is
/// biased by multipath or by a dark surface, as the scan itself shows.
pub(super) fn biased_pixels(range: &RangeImage<'_>, scan: &PointCloud) -> Vec<bool> {
    let (w, h) = (range.cam.width as usize, range.cam.height as usize);
    let n = range.points.len();
    let normals: Vec<Option<Vector3<f64>>> = (0..n)
        .into_par_iter()
        .map(|i| range.normal(i, NORMAL_RADIUS_M))
        .collect();
    let point = |i: usize| range.point(i).map(|p| p.coords.cast::<f64>());
    let mut biased: Vec<bool> = (0..n)
        .into_par_iter()
        .map(|i| {
            let (Some(p), Some(np)) = (point(i), normals[i]) else {
                return false;
            };
            let reach = (REACH_M * range.cam.fx / p.z).clamp(MIN_WINDOW_PX, MAX_WINDOW_PX) as i64;
            let stride = (reach / 4).max(1);
            let (u, v) = ((i % w) as i64, (i / w) as i64);
            let mut facing = 0;
            for dv in (-reach..=reach).step_by(stride as usize) {
                for du in (-reach..=reach).step_by(stride as usize) {
                    let (x, y) = (u + du, v + dv);
                    if (du, dv) == (0, 0) || x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
                        continue;
                    }
                    let j = y as usize * w + x as usize;
                    let (Some(q), Some(nq)) = (point(j), normals[j]) else {
                        continue;
                    };
                    let d = q - p;
                    let dist = d.norm();
                    if dist > 1e-6
                        && np.dot(&d) > FACING_COS * dist
                        && -nq.dot(&d) > FACING_COS * dist
                    {
                        facing += 1;
                        if facing >= MIN_FACING {
                            return true;
                        }
                    }
                }
            }
            false
        })
        .collect();
    // The amplitude image is the scan's own grid only when the range image is.
    if let Some(amplitude) = scan
        .intensity
        .as_deref()
        .filter(|a| range.organized && a.len() == n)
    {
        let reflectivity: Vec<Option<f64>> = (0..n)
            .map(|i| {
                let p = point(i)?;
                let a = f64::from(amplitude[i]);
                let cos = normals[i].map_or(1.0, |m| m.dot(&-p.normalize()).abs().max(0.2));
                (a.is_finite() && a >= 0.0).then(|| a * p.norm_squared() / cos)
            })
            .collect();
        let mut known: Vec<f64> = reflectivity.iter().flatten().copied().collect();
        if known.len() >= 100 {
            let k = known.len() * 9 / 10;
            let bright = *known.select_nth_unstable_by(k, f64::total_cmp).1;
            for (b, r) in biased.iter_mut().zip(&reflectivity) {
                if r.is_some_and(|r| r < DARK_FRACTION * bright) {
                    *b = true;
                }
            }
        }
    }
    biased
}

#[cfg(test)]
mod tests {
    use handeye_hal::PointCloud;
    use nalgebra::{Point3, Vector3};
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    use super::*;
    use crate::geometry::raycast::{raycast, SceneMesh};
    use crate::sim::{look_at, Intrinsics};

    /// Issue 45: a time-of-flight scan (1 mm at 1 m of noise) of a floor meeting a wall, 0.7 m
    /// away, with a dark patch on the floor far from the corner. The scan's own geometry marks
    /// the corner, where light bounces between the two (no model needed: the plate, the floor
    /// and the cable are not in it); the amplitude image marks the dark patch; the open floor
    /// and wall are kept.
    #[test]
    fn issue_45_the_scans_concave_corner_and_dark_surfaces_are_marked_biased() {
        let meshes = crate::testutil::floor_and_wall();
        let intr = Intrinsics::helios2_640x480().scaled(0.5);
        let model_from_camera = look_at(
            &Point3::new(-0.5, 0.1, 0.5),
            &Point3::new(0.0, 0.0, 0.0),
            &-Vector3::z(),
        );
        let image = raycast(
            &SceneMesh::indexed(&meshes),
            &model_from_camera.inverse(),
            &intr,
        );
        let w = image.width;
        let mut rng = rand::rngs::StdRng::seed_from_u64(5);
        let (mut points, mut amplitude, mut world) = (Vec::new(), Vec::new(), Vec::new());
        for (i, &z) in image.depth.iter().enumerate() {
            let ray = intr.ray((i % w) as f64, (i / w) as f64);
            if !z.is_finite() {
                points.push(Point3::new(f32::NAN, f32::NAN, f32::NAN));
                amplitude.push(f32::NAN);
                world.push(None);
                continue;
            }
            let truth = Point3::from(ray * z);
            let in_model = model_from_camera * truth;
            let dark = in_model.x < -0.2 && in_model.y.abs() < 0.05;
            let noisy = z + Normal::new(0.0, 0.001 * z).expect("σ").sample(&mut rng);
            let p = ray * noisy;
            points.push(Point3::new(p.x as f32, p.y as f32, p.z as f32));
            let albedo = if dark { 0.08 } else { 0.6 };
            let cos = image.normal[i].cast::<f64>().dot(&-ray.normalize()).abs();
            amplitude.push((albedo * cos / p.norm_squared()) as f32);
            world.push(Some((in_model, dark)));
        }
        let scan = PointCloud {
            width: w as u32,
            height: image.height as u32,
            points,
            intensity: Some(amplitude),
            confidence: None,
        };
        let range = RangeImage::new(&scan).expect("range image");
        let biased = biased_pixels(&range, &scan);
        let share = |pick: &dyn Fn(&Point3<f64>, bool) -> bool| {
            let v: Vec<bool> = world
                .iter()
                .zip(&biased)
                .filter_map(|(m, b)| m.filter(|(p, d)| pick(p, *d)).map(|_| *b))
                .collect();
            assert!(v.len() > 200, "{} pixels", v.len());
            v.iter().filter(|b| **b).count() as f64 / v.len() as f64
        };
        // Distance from the corner line (x = z = 0); right at it the normals straddle both
        // surfaces.
        let corner = share(&|p, d| !d && (0.005..0.02).contains(&p.x.hypot(p.z)));
        let open = share(&|p, d| !d && p.x.hypot(p.z) > 0.15 && (p.x + 0.2).abs() > 0.06);
        let dark = share(&|p, d| d && (p.y.abs() < 0.04 && p.x < -0.21));
        eprintln!("corner {corner}, open {open}, dark {dark}");
        assert!(corner > 0.8, "corner {corner}");
        assert!(open < 0.02, "open surfaces {open}");
        assert!(dark > 0.95, "dark patch {dark}");
        // Without an amplitude image only the geometry speaks.
        let depth_only = PointCloud {
            intensity: None,
            ..scan.clone()
        };
        let geometric = biased_pixels(&range, &depth_only);
        assert!(geometric.iter().filter(|b| **b).count() < biased.iter().filter(|b| **b).count());
    }
}
