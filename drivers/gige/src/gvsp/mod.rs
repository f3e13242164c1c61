//! GVSP (GigE Vision Streaming Protocol): the packet codec (both directions, `codec`) and a
//! frame receiver with missing-packet detection, PACKETRESEND and frame timeouts
//! (`receiver`). Datagrams move in batches (`udp_batch`).

mod codec;
mod receiver;

pub use codec::*;
pub use receiver::*;

#[cfg(test)]
mod tests;
