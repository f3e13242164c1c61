//! The robot model: URDF, meshes (visual and collision), forward kinematics, joint limits.

mod mesh;

pub use mesh::TriMesh;
