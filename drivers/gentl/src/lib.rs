//! GenTL consumer: any GenICam camera through its vendor's GenTL producer (a `.cti` shared
//! library, loaded at run time), implementing [`handeye_hal::DepthCamera`].
//!
//! Layout: [`ffi`](crate) (the GenTL C ABI, resolved from the `.cti`), `producer` (safe,
//! self-closing wrappers of the library, system, interface, device, port and stream modules),
//! [`camera`] (the `DepthCamera`: one thread owns the handles). The GenICam node map and the
//! PFNC 3D decoders are `handeye-gige`'s.
#![deny(missing_docs)]

pub mod camera;
mod error;
mod ffi;
mod producer;

pub use camera::{
    list_devices, producers_on_path, resolve_producer, GentlCamera, GentlOptions, GentlStats,
    InterfaceDevices,
};
pub use error::{GentlError, Result};
pub use producer::DeviceInfo;
