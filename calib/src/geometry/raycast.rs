//! Exact pinhole ray casting of triangle meshes.
//!
//! Every pixel's ray is intersected with the scene's triangles; the nearest hit wins. Instead
//! of walking a BVH per ray, triangles are projected into the image (after clipping against the
//! near plane) and each covers only the pixels whose rays it can hit; for each such pixel the
//! exact ray–plane intersection gives the depth. This is the same result as per-ray casting and
//! runs in O(triangles + pixels): a 2448×2048 scan of a posed UR arm takes tens of milliseconds.

use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;

use super::Intrinsics;
use crate::model::TriMesh;

/// Rays closer than this (metres) are not cast; geometry nearer the camera is clipped.
pub const NEAR_PLANE_M: f64 = 0.02;

/// Rows per parallel work unit.
const BAND_ROWS: usize = 32;

/// A mesh to ray-cast, in the scene's world frame.
#[derive(Debug, Clone, Copy)]
pub struct SceneMesh<'a> {
    /// Vertices, metres, world frame (already posed).
    pub vertices: &'a [Point3<f64>],
    /// Triangles as vertex indices.
    pub triangles: &'a [[u32; 3]],
    /// Caller's object id, reported per pixel in [`DepthImage::object`].
    pub object: u32,
}

impl<'a> SceneMesh<'a> {
    /// One scene mesh per [`TriMesh`] (already posed in the world frame), the object id being
    /// its index.
    pub fn indexed(meshes: &'a [TriMesh]) -> Vec<Self> {
        meshes
            .iter()
            .enumerate()
            .map(|(i, m)| SceneMesh {
                vertices: &m.vertices,
                triangles: &m.triangles,
                object: i as u32,
            })
            .collect()
    }
}

/// The result of ray casting: per pixel, row-major.
#[derive(Debug, Clone)]
pub struct DepthImage {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Depth (camera z, metres) of the nearest hit; `f64::INFINITY` where nothing was hit.
    pub depth: Vec<f64>,
    /// Object id of the hit, [`DepthImage::NO_HIT`] where nothing was hit.
    pub object: Vec<u32>,
    /// Unit surface normal of the hit triangle in camera frame, facing the camera.
    pub normal: Vec<Vector3<f32>>,
}

impl DepthImage {
    /// Object id of a pixel without a hit.
    pub const NO_HIT: u32 = u32::MAX;

    /// The hit point of pixel `(u, v)` in camera frame, if any.
    pub fn point(&self, intr: &Intrinsics, u: usize, v: usize) -> Option<Point3<f64>> {
        let d = self.depth[v * self.width + u];
        d.is_finite()
            .then(|| Point3::from(intr.ray(u as f64, v as f64) * d))
    }
}

/// A triangle after clipping, in camera frame, with its projection.
#[derive(Debug, Clone, Copy)]
struct ProjectedTriangle {
    /// Pixel coordinates of the corners.
    uv: [[f64; 2]; 3],
    /// Plane `n·X = offset` in camera frame (n not normalised).
    n: Vector3<f64>,
    offset: f64,
    object: u32,
}

/// Ray-casts `meshes` (world frame) from a camera at `camera_from_world` with intrinsics `intr`.
pub fn raycast(
    meshes: &[SceneMesh<'_>],
    camera_from_world: &Isometry3<f64>,
    intr: &Intrinsics,
) -> DepthImage {
    let (w, h) = (intr.width as usize, intr.height as usize);
    let tris: Vec<ProjectedTriangle> = meshes
        .par_iter()
        .flat_map_iter(|m| {
            let cam: Vec<Point3<f64>> = m.vertices.iter().map(|v| camera_from_world * v).collect();
            let mut out = Vec::new();
            for t in m.triangles {
                let Some(abc) = t
                    .iter()
                    .map(|&i| cam.get(i as usize).copied())
                    .collect::<Option<Vec<_>>>()
                else {
                    continue;
                };
                clip_and_project([abc[0], abc[1], abc[2]], intr, m.object, &mut out);
            }
            out
        })
        .collect();

    // Bin triangles into row bands by their pixel extent.
    let bands = h.div_ceil(BAND_ROWS);
    let mut binned: Vec<Vec<u32>> = vec![Vec::new(); bands];
    for (i, t) in tris.iter().enumerate() {
        let vmin =
            t.uv.iter()
                .map(|p| p[1])
                .fold(f64::INFINITY, f64::min)
                .ceil()
                .max(0.0);
        let vmax =
            t.uv.iter()
                .map(|p| p[1])
                .fold(f64::NEG_INFINITY, f64::max)
                .floor();
        if vmax < 0.0 || vmin > (h - 1) as f64 {
            continue;
        }
        let (b0, b1) = (
            vmin as usize / BAND_ROWS,
            (vmax as usize).min(h - 1) / BAND_ROWS,
        );
        for band in binned.iter_mut().take(b1 + 1).skip(b0) {
            band.push(i as u32);
        }
    }

    let mut depth = vec![f64::INFINITY; w * h];
    let mut winner = vec![u32::MAX; w * h];
    depth
        .par_chunks_mut(BAND_ROWS * w)
        .zip(winner.par_chunks_mut(BAND_ROWS * w))
        .enumerate()
        .for_each(|(band, (depth, winner))| {
            let row0 = band * BAND_ROWS;
            let rows = depth.len() / w;
            for &ti in &binned[band] {
                rasterize(&tris[ti as usize], ti, intr, row0, rows, w, depth, winner);
            }
        });

    let (object, normal) = winner
        .par_iter()
        .map(|&ti| match tris.get(ti as usize) {
            None => (DepthImage::NO_HIT, Vector3::zeros()),
            Some(t) => {
                let n = t.n.normalize();
                let n = if n.z > 0.0 { -n } else { n }; // face the camera
                (t.object, Vector3::new(n.x as f32, n.y as f32, n.z as f32))
            }
        })
        .unzip();
    DepthImage {
        width: w,
        height: h,
        depth,
        object,
        normal,
    }
}

/// Writes the triangle's depth into the band where it is nearer than what is there.
#[allow(clippy::too_many_arguments)]
fn rasterize(
    t: &ProjectedTriangle,
    index: u32,
    intr: &Intrinsics,
    row0: usize,
    rows: usize,
    w: usize,
    depth: &mut [f64],
    winner: &mut [u32],
) {
    for_each_covered_pixel(t, row0, rows, w, intr, |u, v, z| {
        let i = (v - row0) * w + u;
        if z < depth[i] {
            depth[i] = z;
            winner[i] = index;
        }
    });
}

/// Calls `f(u, v, depth)` for every pixel of rows `row0..row0+rows` whose centre ray hits `t`.
fn for_each_covered_pixel(
    t: &ProjectedTriangle,
    row0: usize,
    rows: usize,
    w: usize,
    intr: &Intrinsics,
    mut f: impl FnMut(usize, usize, f64),
) {
    let [a, b, c] = t.uv;
    let area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
    if area.abs() < 1e-12 {
        return;
    }
    let umin = a[0].min(b[0]).min(c[0]).ceil().max(0.0) as usize;
    let umax = a[0].max(b[0]).max(c[0]).floor();
    let vmin = a[1].min(b[1]).min(c[1]).ceil().max(row0 as f64) as usize;
    let vmax = a[1].max(b[1]).max(c[1]).floor();
    if umax < 0.0 || vmax < row0 as f64 {
        return;
    }
    let umax = (umax as usize).min(w - 1);
    let vmax = (vmax as usize).min(row0 + rows - 1);
    let edge = |p: [f64; 2], q: [f64; 2], x: f64, y: f64| {
        (q[0] - p[0]) * (y - p[1]) - (q[1] - p[1]) * (x - p[0])
    };
    let s = area.signum();
    for v in vmin..=vmax {
        let y = v as f64;
        for u in umin..=umax {
            let x = u as f64;
            let (e0, e1, e2) = (
                edge(b, c, x, y) * s,
                edge(c, a, x, y) * s,
                edge(a, b, x, y) * s,
            );
            if e0 < 0.0 || e1 < 0.0 || e2 < 0.0 {
                continue;
            }
            let d = intr.ray(x, y);
            let denom = t.n.dot(&d);
            if denom.abs() < 1e-15 {
                continue;
            }
            let z = t.offset / denom;
            if z > NEAR_PLANE_M {
                f(u, v, z);
            }
        }
    }
}

/// Clips a camera-frame triangle against the near plane and appends the projected pieces.
fn clip_and_project(
    p: [Point3<f64>; 3],
    intr: &Intrinsics,
    object: u32,
    out: &mut Vec<ProjectedTriangle>,
) {
    let n = (p[1] - p[0]).cross(&(p[2] - p[0]));
    if n.norm_squared() < 1e-24 {
        return;
    }
    let offset = n.dot(&p[0].coords);
    let inside = |q: &Point3<f64>| q.z >= NEAR_PLANE_M;
    let mut poly: Vec<Point3<f64>> = Vec::with_capacity(4);
    for i in 0..3 {
        let (cur, nxt) = (p[i], p[(i + 1) % 3]);
        if inside(&cur) {
            poly.push(cur);
        }
        if inside(&cur) != inside(&nxt) {
            let s = (NEAR_PLANE_M - cur.z) / (nxt.z - cur.z);
            poly.push(cur + (nxt - cur) * s);
        }
    }
    if poly.len() < 3 {
        return;
    }
    let uv: Vec<[f64; 2]> = poly
        .iter()
        .map(|q| [intr.fx * q.x / q.z + intr.cx, intr.fy * q.y / q.z + intr.cy])
        .collect();
    for k in 1..uv.len() - 1 {
        out.push(ProjectedTriangle {
            uv: [uv[0], uv[k], uv[k + 1]],
            n,
            offset,
            object,
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad(z: f64, half: f64) -> (Vec<Point3<f64>>, Vec<[u32; 3]>) {
        (
            vec![
                Point3::new(-half, -half, z),
                Point3::new(half, -half, z),
                Point3::new(half, half, z),
                Point3::new(-half, half, z),
            ],
            vec![[0, 1, 2], [0, 2, 3]],
        )
    }

    #[test]
    fn nearest_surface_wins_and_depth_is_exact() {
        let intr = Intrinsics::from_fov(64, 48, 1.0);
        let (v1, t1) = quad(1.0, 10.0);
        let (v2, t2) = quad(0.5, 0.05);
        let meshes = [
            SceneMesh {
                vertices: &v1,
                triangles: &t1,
                object: 1,
            },
            SceneMesh {
                vertices: &v2,
                triangles: &t2,
                object: 2,
            },
        ];
        let img = raycast(&meshes, &Isometry3::identity(), &intr);
        let c = 24 * 64 + 32;
        assert_eq!(img.object[c], 2);
        assert!((img.depth[c] - 0.5).abs() < 1e-12);
        assert_eq!(img.object[0], 1);
        assert!((img.depth[0] - 1.0).abs() < 1e-12);
        assert!((img.normal[c] - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-6);
    }

    #[test]
    fn geometry_behind_the_camera_is_clipped_not_mirrored() {
        let intr = Intrinsics::from_fov(32, 32, 1.0);
        // a floor-like plane crossing the near plane: y = 0.2, from z = -5 to z = +5
        let v = vec![
            Point3::new(-5.0, 0.2, -5.0),
            Point3::new(5.0, 0.2, -5.0),
            Point3::new(5.0, 0.2, 5.0),
            Point3::new(-5.0, 0.2, 5.0),
        ];
        let t = vec![[0, 1, 2], [0, 2, 3]];
        let img = raycast(
            &[SceneMesh {
                vertices: &v,
                triangles: &t,
                object: 0,
            }],
            &Isometry3::identity(),
            &intr,
        );
        for vpx in 0..32 {
            for upx in 0..32 {
                let i = vpx * 32 + upx;
                if let Some(p) = img.point(&intr, upx, vpx) {
                    assert!((p.y - 0.2).abs() < 1e-9, "hit off the plane: {p}");
                    assert!(p.z > 0.0 && p.z <= 5.0 + 1e-9);
                } else {
                    // rays looking up (v above the principal point) never meet the plane
                    assert!(
                        (vpx as f64) <= intr.cy + 0.5
                            || img.depth[i] > 5.0
                            || !img.depth[i].is_finite()
                    );
                }
            }
        }
    }
}
