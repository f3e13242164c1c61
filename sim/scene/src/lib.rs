//! The simulated 3D camera's scene: the robot rendered by the scan simulator as a camera on
//! its flange sees it, at a generated view of its base or following a (simulated) UR
//! controller over RTDE, or the built-in plane + sphere test pattern. One scene for every
//! transport: `handeye sim camera` and `handeye sim rig` serve it over GigE Vision, the GenTL
//! producer (`sim/gentl`, a `.cti`) through GenTL.
//!
//! Layout: [`scene`] (the robot as a [`FrameSource`](handeye_gige::sim::FrameSource), the RTDE
//! follower), [`args`] (the `sim camera` options that choose the scene, and the robot parsers
//! they share with the rest of the command line), [`pose`] (poses given as text).

pub mod args;
pub mod pose;
pub mod scene;

pub use args::{
    factory_arm, imitation, parse_imitation, resolve_robot, robots_dir, robots_dir_candidates,
    SceneArgs, DEFAULT_HEIGHT, DEFAULT_WIDTH, MAX_PIXELS, MIN_PIXELS, PACKAGED_ROBOTS,
};
pub use pose::{check_mount, check_pose_distance, parse_pose, MAX_MOUNT_DISTANCE_M};
pub use scene::{
    parse_robot_addr, read_mount_file, LiveJoints, RobotScene, SceneJoints, SceneMount,
    DEFAULT_MOUNT,
};
