//! The geometry of a 3D camera, shared by the simulator, registration, view planning and the
//! report picture: the pinhole model ([`Intrinsics`]) and exact ray casting of triangle meshes
//! through it ([`raycast`]). No camera backend lives here.

mod intrinsics;
pub mod raycast;

pub use intrinsics::{Intrinsics, SensorClass};
