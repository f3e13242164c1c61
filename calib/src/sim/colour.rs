//! The colour image a camera with an RGB imager registers to its depth, pixel for pixel (an
//! active-stereo camera's colour stream aligned to its depth, as the real frames in
//! `../shared/realdata` are): what the registration fits the arm's outline in
//! ([`crate::calib::outline`]).
//!
//! Rendered from the same ray cast as the depth, so its outline is where the scene's is, not
//! where the depth's errors put it: the image does not bend with the depth. What it carries:
//! each surface's reflectance (the values [`super::albedo`] assumes, taken as the same in the
//! visible as in the near infrared: a UR's light covers against its dark caps and base ring, a
//! grey floor, a light plate) lit by the room from above and around; a far background of
//! [`BACKGROUND`] where nothing was hit; the optics' blur (a `[1 2 1] / 4` kernel each way); the
//! imager's noise ([`NOISE_LEVELS`]); whole 8-bit levels; and the factory calibration between
//! the colour imager and the depth off by a shift of `misalignment_px` 1σ per axis, drawn for
//! each scan.

use nalgebra::{UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

use super::albedo::{albedo_image, Surface};
use crate::cloud::ColorImage;
use crate::geometry::raycast::DepthImage;

/// Share of the light that reaches every surface whatever its orientation (the room's walls);
/// the rest falls from above (the model's z).
const AMBIENT: f64 = 0.4;
/// Level of a surface of albedo 1 in full light, 8-bit (an auto-exposed image: the covers
/// facing up nearly saturate).
const EXPOSURE: f64 = 330.0;
/// Level where nothing was hit: the lab's far walls and furniture, 8-bit.
const BACKGROUND: f64 = 90.0;
/// 1σ of the imager's noise, 8-bit levels.
const NOISE_LEVELS: f64 = 2.0;

/// The colour image of `image` (the ray cast of the scene, its object ids indexing `surfaces`),
/// grey in all three channels. `model_from_camera` turns the cast's normals into the model
/// frame, where the light falls along −z. `seed` draws the misalignment and the noise.
pub(crate) fn colour_image(
    image: &DepthImage,
    surfaces: &[Surface],
    model_from_camera: &UnitQuaternion<f64>,
    misalignment_px: f64,
    seed: u64,
) -> ColorImage {
    let (w, h) = (image.width, image.height);
    let albedo = albedo_image(image, surfaces, model_from_camera);
    let lit: Vec<f64> = albedo
        .iter()
        .zip(&image.normal)
        .map(|(&a, n)| {
            if a.is_nan() {
                return BACKGROUND;
            }
            let up = (model_from_camera * n.cast::<f64>()).dot(&Vector3::z());
            EXPOSURE * a * (AMBIENT + (1.0 - AMBIENT) * up.max(0.0))
        })
        .collect();
    let blurred = blur(&lit, w, h);
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let shift = Normal::new(0.0, misalignment_px.max(1e-12)).expect("σ");
    let (dx, dy) = (shift.sample(&mut rng), shift.sample(&mut rng));
    let noise = Normal::new(0.0, NOISE_LEVELS).expect("σ");
    let mut rgb = Vec::with_capacity(w * h);
    for v in 0..h {
        for u in 0..w {
            let level =
                bilinear(&blurred, w, h, u as f64 + dx, v as f64 + dy) + noise.sample(&mut rng);
            let g = level.round().clamp(0.0, 255.0) as u8;
            rgb.push([g, g, g]);
        }
    }
    ColorImage {
        width: w,
        height: h,
        rgb,
    }
}

/// `[1 2 1] / 4` across, then down; the border pixels keep their own weight.
fn blur(levels: &[f64], w: usize, h: usize) -> Vec<f64> {
    let pass = |src: &[f64], step: usize, len: usize, at: &dyn Fn(usize) -> usize| {
        let mut out = src.to_vec();
        for (i, o) in out.iter_mut().enumerate() {
            let k = at(i);
            if k > 0 && k + 1 < len {
                *o = (src[i - step] + 2.0 * src[i] + src[i + step]) / 4.0;
            }
        }
        out
    };
    let across = pass(levels, 1, w, &|i| i % w);
    pass(&across, w, h, &|i| i / w)
}

/// The level at `(x, y)`, bilinear between the four pixels around it, clamped to the image.
fn bilinear(levels: &[f64], w: usize, h: usize, x: f64, y: f64) -> f64 {
    let x = x.clamp(0.0, (w - 1) as f64);
    let y = y.clamp(0.0, (h - 1) as f64);
    let (i, j) = (x.floor() as usize, y.floor() as usize);
    let (i1, j1) = ((i + 1).min(w - 1), (j + 1).min(h - 1));
    let (a, b) = (x - i as f64, y - j as f64);
    let at = |i: usize, j: usize| levels[j * w + i];
    (at(i, j) * (1.0 - a) + at(i1, j) * a) * (1.0 - b)
        + (at(i, j1) * (1.0 - a) + at(i1, j1) * a) * b
}

#[cfg(test)]
mod tests {
    use nalgebra::{Point3, Vector3};

    use super::super::cell::CellPart;
    use super::super::{look_at, Intrinsics};
    use super::*;
    use crate::geometry::raycast::{raycast, SceneMesh};
    use crate::model::TriMesh;

    /// Where along row `v` the level first crosses halfway from the background to the board's,
    /// pixels (linear between the two pixels around the crossing).
    fn crossing(img: &ColorImage, v: usize, mid: f64) -> f64 {
        let level = |u: usize| f64::from(img.rgb[v * img.width + u][0]);
        let u = (1..img.width)
            .find(|&u| (level(u - 1) - mid) * (level(u) - mid) <= 0.0)
            .expect("a crossing");
        let (a, b) = (level(u - 1), level(u));
        (u - 1) as f64 + (mid - a) / (b - a)
    }

    /// Issue 45: a light board 0.5 m in front of the camera with nothing behind it. The colour
    /// image's edge lies on the board's outline as the ray cast sees it (half a pixel before
    /// its first pixel), to a tenth of a pixel along every row; with a misalignment the whole
    /// edge moves by one shift, the same on every row.
    #[test]
    fn issue_45_the_colour_image_shows_the_outline_where_the_scene_is() {
        let board = TriMesh {
            vertices: vec![
                Point3::new(0.0, -0.2, 0.0),
                Point3::new(0.3, -0.2, 0.0),
                Point3::new(0.3, 0.2, 0.0),
                Point3::new(0.0, 0.2, 0.0),
            ],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
        };
        let intr = Intrinsics::preset("realsense-d435")
            .expect("preset")
            .scaled(0.25);
        let model_from_camera = look_at(
            &Point3::new(0.0, 0.0, 0.5),
            &Point3::origin(),
            &Vector3::y(),
        );
        let cast = raycast(
            &SceneMesh::indexed(&[board]),
            &model_from_camera.inverse(),
            &intr,
        );
        let surfaces = [Surface::Cell(CellPart::Plate)];
        let rows: Vec<usize> = (cast.height / 3..2 * cast.height / 3).step_by(4).collect();
        let first_hit = |v: usize| {
            (0..cast.width)
                .find(|&u| cast.object[v * cast.width + u] != DepthImage::NO_HIT)
                .expect("the board is in view") as f64
        };
        let edges = |misalignment: f64| -> Vec<f64> {
            let img = colour_image(
                &cast,
                &surfaces,
                &model_from_camera.rotation,
                misalignment,
                7,
            );
            let v = cast.height / 2;
            let inside = f64::from(img.rgb[v * cast.width + first_hit(v) as usize + 5][0]);
            let mid = (inside + BACKGROUND) / 2.0;
            assert!(
                (inside - BACKGROUND).abs() > 30.0,
                "the board stands out: {inside}"
            );
            rows.iter()
                .map(|&v| crossing(&img, v, mid) - (first_hit(v) - 0.5))
                .collect()
        };
        for off in edges(0.0) {
            assert!(off.abs() < 0.15, "edge {off} px off the outline");
        }
        let shifted = edges(2.0);
        let mean = shifted.iter().sum::<f64>() / shifted.len() as f64;
        assert!(
            mean.abs() > 0.3,
            "a 2 px 1σ shift moved the edge by {mean} px"
        );
        for off in &shifted {
            assert!(
                (off - mean).abs() < 0.15,
                "{off} against {mean}: one shift for the image"
            );
        }
    }
}
