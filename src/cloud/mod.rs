//! Point-cloud files (PLY, PCD) and cloud utilities. The cloud type itself is
//! [`handeye_hal::PointCloud`].
