//! Universal Robots driver: RTDE, dashboard and script clients implementing
//! [`handeye_hal::Robot`], and a UR controller simulator that real clients (`ur-rtde`) accept.
#![deny(missing_docs)]
