//! The 3D scan simulator.
