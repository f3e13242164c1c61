//! The file camera: replays PLY/PCD files in order.

use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use handeye_hal::{CameraInfo, CaptureSettings, DepthCamera, HalError, PointCloud};

use super::{blocking, CameraError};
use crate::cloud::read_cloud;

/// What a [`FileCamera`] does when a capture asks for more frames than files are left.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum WhenExhausted {
    /// Start again from the first file (the default: one recorded scan serves any number of
    /// frames and any number of captures).
    #[default]
    Wrap,
    /// Fail with [`CameraError::Exhausted`] and deliver nothing (for replays that must use each
    /// file exactly once).
    Error,
}

/// A camera that replays PLY/PCD files, in the order given.
///
/// A capture of N frames returns the next N files as N clouds; the position persists across
/// captures. When the files run out it wraps around to the first or fails, as
/// [`WhenExhausted`] says (default: wrap). A file that cannot be read fails the capture with
/// [`CameraError::ReadFile`]; it still counts as consumed, so the next capture moves on.
///
/// Files are read when captured, not when the camera is made (a file replaced between captures
/// is replayed in its new state). Reading runs on tokio's blocking pool. The clouds are what the
/// files hold (metres after the reader's unit handling, the camera frame of whoever recorded
/// them); [`CaptureSettings::exposure`] and `frame_timeout` are ignored.
#[derive(Debug, Clone)]
pub struct FileCamera {
    paths: Arc<[PathBuf]>,
    when_exhausted: WhenExhausted,
    /// Index of the next file to deliver (shared by clones: they are one camera).
    next: Arc<Mutex<usize>>,
}

impl FileCamera {
    /// A camera replaying `paths` (at least one), wrapping around when exhausted.
    /// Does not touch the files.
    pub fn new(paths: impl IntoIterator<Item = PathBuf>) -> Result<Self, CameraError> {
        let paths: Arc<[PathBuf]> = paths.into_iter().collect();
        if paths.is_empty() {
            return Err(CameraError::NoFiles);
        }
        Ok(Self {
            paths,
            when_exhausted: WhenExhausted::default(),
            next: Arc::new(Mutex::new(0)),
        })
    }

    /// Sets what happens when the files run out.
    pub fn when_exhausted(mut self, when: WhenExhausted) -> Self {
        self.when_exhausted = when;
        self
    }

    /// The files, in replay order.
    pub fn paths(&self) -> &[PathBuf] {
        &self.paths
    }

    /// Describes the camera: vendor `file`, model = the first file's name, size from the first
    /// file (read for that; its width × height, or N × 1 for an unorganized cloud).
    pub async fn describe(&self) -> Result<CameraInfo, CameraError> {
        let first = self.paths[0].clone();
        let model = first.file_name().map_or_else(
            || first.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        let cloud = blocking(move || {
            read_cloud(&first).map_err(|source| CameraError::ReadFile {
                path: first,
                source,
            })
        })
        .await?;
        Ok(CameraInfo {
            vendor: "file".to_owned(),
            model,
            serial: String::new(),
            firmware: String::new(),
            width: cloud.width,
            height: cloud.height,
            pixel_formats: Vec::new(),
        })
    }

    /// Replays the next `frames` files (0 frames: nothing read, an empty result).
    pub async fn capture_frames(&self, frames: u32) -> Result<Vec<PointCloud>, CameraError> {
        let chosen = self.take(frames)?;
        blocking(move || {
            chosen
                .into_iter()
                .map(|path| {
                    read_cloud(&path).map_err(|source| CameraError::ReadFile { path, source })
                })
                .collect()
        })
        .await
    }

    /// Picks the next `frames` files and advances the position.
    fn take(&self, frames: u32) -> Result<Vec<PathBuf>, CameraError> {
        let total = self.paths.len();
        // A panic elsewhere cannot leave the index invalid: it is only ever assigned whole.
        let mut next = self.next.lock().unwrap_or_else(|e| e.into_inner());
        let wanted = frames as usize;
        if self.when_exhausted == WhenExhausted::Error && wanted > total - *next {
            return Err(CameraError::Exhausted {
                used: *next,
                total,
                requested: frames,
            });
        }
        let chosen = (0..wanted)
            .map(|i| self.paths[(*next + i) % total].clone())
            .collect();
        *next = match self.when_exhausted {
            WhenExhausted::Wrap => (*next + wanted) % total,
            // At most `total` (checked above): everything replayed stays exhausted.
            WhenExhausted::Error => *next + wanted,
        };
        Ok(chosen)
    }
}

impl DepthCamera for FileCamera {
    async fn info(&self) -> Result<CameraInfo, HalError> {
        Ok(self.describe().await?)
    }

    async fn capture(&self, settings: &CaptureSettings) -> Result<Vec<PointCloud>, HalError> {
        Ok(self.capture_frames(settings.frames).await?)
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use nalgebra::Point3;

    use super::*;
    use crate::camera::PrivateDir;
    use crate::cloud::{write_pcd, write_ply, PlyEncoding};

    /// A 3 × 2 organized cloud whose first point's z is `tag` (to tell files apart), with one
    /// invalid (NaN) pixel.
    fn cloud(tag: f32) -> PointCloud {
        let mut points: Vec<Point3<f32>> = (0..6)
            .map(|i| Point3::new(0.01 * i as f32, -0.02 * i as f32, 0.5 + 0.001 * i as f32))
            .collect();
        points[0].z = tag;
        points[4] = Point3::new(f32::NAN, f32::NAN, f32::NAN);
        PointCloud {
            width: 3,
            height: 2,
            points,
            intensity: None,
            confidence: None,
        }
    }

    fn tag(c: &PointCloud) -> f32 {
        c.points[0].z
    }

    /// Writes tagged clouds 1.0, 2.0, … as PLY/PCD alternately.
    fn write_files(dir: &Path, n: usize) -> Vec<PathBuf> {
        (0..n)
            .map(|i| {
                let c = cloud(1.0 + i as f32);
                if i % 2 == 0 {
                    let p = dir.join(format!("scan{i}.ply"));
                    write_ply(&p, &c, PlyEncoding::BinaryLittleEndian).expect("write ply");
                    p
                } else {
                    let p = dir.join(format!("scan{i}.pcd"));
                    write_pcd(&p, &c, true).expect("write pcd");
                    p
                }
            })
            .collect()
    }

    #[tokio::test]
    async fn replays_ply_and_pcd_in_order_and_wraps() {
        let dir = PrivateDir::new("test-file-camera").expect("temp dir");
        let paths = write_files(dir.path(), 3);
        let cam = FileCamera::new(paths.clone()).expect("camera");

        let info = cam.info().await.expect("info");
        assert_eq!(info.vendor, "file");
        assert_eq!(info.model, "scan0.ply");
        assert_eq!((info.width, info.height), (3, 2));

        let settings = CaptureSettings {
            frames: 2,
            ..CaptureSettings::default()
        };
        let a = cam.capture(&settings).await.expect("capture 1");
        assert_eq!(a.len(), 2);
        assert_eq!(a.iter().map(tag).collect::<Vec<_>>(), [1.0, 2.0]);
        // The PCD round trip keeps the grid and the invalid pixel.
        assert_eq!((a[1].width, a[1].height), (3, 2));
        assert!(a[1].points[4].x.is_nan());
        assert_eq!(a[1].valid_count(), 5);
        assert_eq!(a[0].points[1], cloud(1.0).points[1]);

        // Wraps: file 3, then 1, 2, 3 again.
        let settings = CaptureSettings {
            frames: 4,
            ..CaptureSettings::default()
        };
        let b = cam.capture(&settings).await.expect("capture 2");
        assert_eq!(b.iter().map(tag).collect::<Vec<_>>(), [3.0, 1.0, 2.0, 3.0]);

        let none = cam.capture_frames(0).await.expect("zero frames");
        assert!(none.is_empty());
    }

    #[tokio::test]
    async fn error_mode_fails_when_exhausted_and_delivers_nothing() {
        let dir = PrivateDir::new("test-file-camera").expect("temp dir");
        let paths = write_files(dir.path(), 2);
        let cam = FileCamera::new(paths)
            .expect("camera")
            .when_exhausted(WhenExhausted::Error);
        let one = cam.capture_frames(1).await.expect("first");
        assert_eq!(tag(&one[0]), 1.0);
        let err = cam.capture_frames(2).await.expect_err("only one left");
        assert!(
            matches!(
                err,
                CameraError::Exhausted {
                    used: 1,
                    total: 2,
                    requested: 2
                }
            ),
            "{err:?}"
        );
        // The failed capture consumed nothing.
        let two = cam.capture_frames(1).await.expect("second");
        assert_eq!(tag(&two[0]), 2.0);
        let err = cam.capture_frames(1).await.expect_err("all used");
        assert!(
            matches!(err, CameraError::Exhausted { used: 2, .. }),
            "{err:?}"
        );
        // Through the trait it is a HalError::Backend whose source is our error.
        let err = DepthCamera::capture(&cam, &CaptureSettings::default())
            .await
            .expect_err("all used");
        match &err {
            HalError::Backend { backend, source } => {
                assert_eq!(backend, "file camera");
                assert!(source.downcast_ref::<CameraError>().is_some());
            }
            other => panic!("unexpected {other:?}"),
        }
        let chain = format!("{:#}", anyhow::Error::new(err));
        assert!(chain.contains("give more files"), "{chain}");
    }

    #[test]
    fn no_files_is_an_error() {
        let err = FileCamera::new(Vec::new()).expect_err("empty");
        assert!(matches!(err, CameraError::NoFiles));
    }

    #[tokio::test]
    async fn unreadable_files_name_the_file_and_the_problem() {
        let dir = PrivateDir::new("test-file-camera").expect("temp dir");
        let missing = dir.path().join("missing.ply");
        let garbage = dir.path().join("garbage.ply");
        std::fs::write(&garbage, b"this is not a point cloud").expect("write");
        let cam = FileCamera::new([missing.clone(), garbage.clone()]).expect("camera");

        let err = cam.capture_frames(1).await.expect_err("missing");
        assert!(matches!(&err, CameraError::ReadFile { path, .. } if *path == missing));
        let err = cam.capture_frames(1).await.expect_err("garbage");
        let chain = format!("{:#}", anyhow::Error::new(err));
        assert!(chain.contains("garbage.ply"), "{chain}");
        assert!(chain.contains("not a point-cloud file"), "{chain}");
        // `info` reads the first file, so it fails the same way.
        assert!(cam.describe().await.is_err());
    }
    // Corrupted replay files: the reader is the cloud module's, fuzzed by its `ply` and
    // `pcd` targets (hal::fuzz); `unreadable_files_name_the_file_and_the_problem` covers this
    // camera's side of an error.
}
