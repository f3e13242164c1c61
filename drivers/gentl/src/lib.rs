//! GenTL consumer: any GenICam camera through its vendor's GenTL producer (a `.cti` shared
//! library, loaded at run time), implementing [`handeye_hal::DepthCamera`].
//!
//! Layout: [`ffi`](crate) (the GenTL C ABI, resolved from the `.cti`), `producer` (safe,
//! self-closing wrappers of the library, system, interface, device, port and stream modules,
//! every value the producer returns checked), `device` (find, open, configure, capture and
//! decode), [`host`] (the process that loads the producer and runs `device`: `handeye
//! gentl-host`), `wire` (the pipe between them), [`camera`] (the `DepthCamera`: a task that
//! owns the host process, watches each producer call's deadline and replaces the host when a
//! call blocks or the producer ends it). The GenICam node map and the PFNC 3D decoders are
//! `handeye-gige`'s.
#![deny(missing_docs)]

pub mod camera;
mod device;
mod error;
mod ffi;
pub mod host;
mod producer;
mod wire;

pub use camera::{
    check_producer, list_devices, probe_device, producers_on_path, resolve_producer, GentlCamera,
    GentlOptions, GentlStats, InterfaceDevices, DEFAULT_CALL_TIMEOUT, HOST_SUBCOMMAND,
};
pub use error::{GentlError, Result};
pub use producer::DeviceInfo;
pub use wire::FailureClass;
