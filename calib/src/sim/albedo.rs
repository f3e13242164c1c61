//! How much light the scene's surfaces return: the albedo a time-of-flight camera's amplitude,
//! noise, range bias and multipath depend on ([`super::ScanNoise::reference_albedo`]).
//!
//! Assumed values in the near infrared (no measured spectra of these parts are at hand): a
//! UR's light grey covers 0.6, its dark joint caps and the base's ring 0.08 (the caps face
//! along the joint axis: in a UR URDF the link frame's z), a grey floor 0.3, a machined
//! plate 0.5, bolt heads 0.3, a black cable 0.05, clutter 0.4.

use nalgebra::{UnitQuaternion, Vector3};

use super::cell::CellPart;
use crate::geometry::raycast::DepthImage;

/// A UR's light covers.
pub(crate) const COVER_ALBEDO: f64 = 0.6;
/// A UR's dark joint caps and base ring.
pub(crate) const CAP_ALBEDO: f64 = 0.08;
/// A link surface is a cap where its normal is within this angle's cosine of the link's z
/// (the joint axis of a UR link frame): 25°.
const CAP_COS: f64 = 0.906;

/// What a scene object is made of.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Surface {
    /// A robot link whose housing stands at this rotation in the model frame
    /// (`model_from_link`).
    Link(UnitQuaternion<f64>),
    /// A part of the cell.
    Cell(CellPart),
}

impl Surface {
    /// The albedo of this surface where its normal is `n_model` (model frame).
    fn albedo(&self, n_model: &Vector3<f64>) -> f64 {
        match self {
            Surface::Link(model_from_link) => {
                let n_link = model_from_link.inverse() * n_model;
                if n_link.z.abs() > CAP_COS {
                    CAP_ALBEDO
                } else {
                    COVER_ALBEDO
                }
            }
            Surface::Cell(CellPart::Floor) => 0.3,
            Surface::Cell(CellPart::Plate) => 0.5,
            Surface::Cell(CellPart::BaseBolts) => 0.3,
            Surface::Cell(CellPart::Cable) => 0.05,
            Surface::Cell(CellPart::Clutter) => 0.4,
        }
    }
}

/// The albedo of every pixel's surface (`surfaces` indexed by the image's object ids; NaN
/// where nothing was hit). `model_from_camera` turns the image's normals into the model frame.
pub(crate) fn albedo_image(
    image: &DepthImage,
    surfaces: &[Surface],
    model_from_camera: &UnitQuaternion<f64>,
) -> Vec<f64> {
    image
        .object
        .iter()
        .zip(&image.normal)
        .map(|(&o, n)| {
            surfaces.get(o as usize).map_or(f64::NAN, |s| {
                s.albedo(&(model_from_camera * n.cast::<f64>()))
            })
        })
        .collect()
}

/// The amplitude a time-of-flight camera measures on a surface of `albedo` seen at
/// `cos_incidence`, `range_m` away: 1 for a white surface 1 m away head-on.
pub(crate) fn amplitude(albedo: f64, cos_incidence: f64, range_m: f64) -> f64 {
    albedo * cos_incidence / (range_m * range_m).max(1e-6)
}

#[cfg(test)]
mod tests {
    use nalgebra::{Point3, Vector3};

    use super::super::scan::measure;
    use super::super::{look_at, Intrinsics, ScanNoise};
    use super::*;
    use crate::geometry::raycast::{raycast, SceneMesh};
    use crate::model::TriMesh;

    /// Issue 45: a time-of-flight camera on a flat board 0.6 m away, half of it a UR's light
    /// cover, half a dark cap. The dark half reads long by the class's 3 mm scaled by how much
    /// darker it is (2.6 mm), is √(0.6 / 0.08) = 2.7 × noisier, and the amplitude image the
    /// cloud carries shows it 0.08 / 0.6 as bright; each scan's range offset drifts by its
    /// own draw of 1.5 mm 1σ. Surfaces all alike (structured light) give no amplitude image
    /// and the same depths as before the albedo existed.
    #[test]
    fn issue_45_dark_surfaces_read_long_and_noisy_and_the_amplitude_image_shows_them() {
        let board = TriMesh {
            vertices: vec![
                Point3::new(-1.0, -1.0, 0.0),
                Point3::new(1.0, -1.0, 0.0),
                Point3::new(1.0, 1.0, 0.0),
                Point3::new(-1.0, 1.0, 0.0),
            ],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
        };
        let intr = Intrinsics::helios2_640x480().scaled(0.5);
        let model_from_camera = look_at(
            &Point3::new(0.0, 0.0, 0.6),
            &Point3::origin(),
            &Vector3::y(),
        );
        let meshes = [board];
        let image = raycast(
            &SceneMesh::indexed(&meshes),
            &model_from_camera.inverse(),
            &intr,
        );
        let w = image.width;
        let albedo: Vec<f64> = (0..image.depth.len())
            .map(|i| {
                if i % w < w / 2 {
                    COVER_ALBEDO
                } else {
                    CAP_ALBEDO
                }
            })
            .collect();
        let tof = ScanNoise {
            multipath_m: 0.0,
            flying_pixel_probability: 0.0,
            random_dropout_probability: 0.0,
            depth_step_m: 0.0,
            depth_offset_m: 0.0,
            depth_scale_error: 0.0,
            offset_drift_m: 0.0,
            ..ScanNoise::time_of_flight()
        };
        let cloud = measure(&image, &intr, &tof, &albedo, 3);
        let amplitude = cloud.intensity.as_ref().expect("an amplitude image");
        // Per half: mean and spread of the measured − true depth, mean amplitude.
        let half = |dark: bool| {
            let (mut d, mut a) = (Vec::new(), Vec::new());
            for (i, p) in cloud.points.iter().enumerate() {
                let u = i % w;
                // Away from the seam and the image border.
                if p.z.is_nan() || (u < w / 2) == dark || u.abs_diff(w / 2) < 4 {
                    continue;
                }
                // Along the ray: the bias is on the range.
                let ray = intr.ray(u as f64, (i / w) as f64).norm();
                d.push((f64::from(p.z) - image.depth[i]) * ray);
                a.push(f64::from(amplitude[i]));
            }
            let n = d.len() as f64;
            let mean = d.iter().sum::<f64>() / n;
            let sd = (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n).sqrt();
            (mean, sd, a.iter().sum::<f64>() / n)
        };
        let (light_bias, light_sd, light_amp) = half(false);
        let (dark_bias, dark_sd, dark_amp) = half(true);
        let expected = 0.003 * (1.0 - CAP_ALBEDO / COVER_ALBEDO);
        assert!(light_bias.abs() < 1e-4, "{light_bias}");
        assert!(
            (dark_bias - light_bias - expected).abs() < 2e-4,
            "dark surface {dark_bias} m, light {light_bias} m"
        );
        // 1 mm at 1 m, linear in z, on the covers: 0.6 mm here (a little more off-axis).
        assert!((0.0006..0.0008).contains(&light_sd), "{light_sd}");
        let ratio = dark_sd / light_sd;
        assert!(
            (ratio - (COVER_ALBEDO / CAP_ALBEDO).sqrt()).abs() < 0.2,
            "{ratio}"
        );
        let amp_ratio = dark_amp / light_amp;
        assert!(
            (amp_ratio - CAP_ALBEDO / COVER_ALBEDO).abs() < 0.01,
            "{amp_ratio}"
        );
        // The offset drifts from scan to scan: 1.5 mm 1σ.
        let drifts: Vec<f64> = (0..400)
            .map(|seed| ScanNoise::time_of_flight().drifted(seed).depth_offset_m - 0.001)
            .collect();
        let sd = (drifts.iter().map(|d| d * d).sum::<f64>() / drifts.len() as f64).sqrt();
        assert!((sd - 0.0015).abs() < 0.0002, "{sd}");
        // Structured light: no albedo effects, no amplitude image.
        let sl = ScanNoise::default();
        assert_eq!(sl.drifted(7), sl);
        let plain = measure(&image, &intr, &sl, &[], 3);
        assert!(plain.intensity.is_none());
    }
}
