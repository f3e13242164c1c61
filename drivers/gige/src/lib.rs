//! GigE Vision driver: GVCP/GVSP client with GenICam implementing [`handeye_hal::DepthCamera`],
//! and a simulated GigE Vision 3D camera.
#![deny(missing_docs)]
