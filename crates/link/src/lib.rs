//! The links that carry whole EtherCAT frames between a master and its slaves, shared by the
//! master's engine (`ether-ros-engine`) and the simulator (`ether-ros-sim`), so both ends of a
//! veth pair move frames the same way:
//!
//! - [`RawSocketLink`]: an AF_PACKET raw socket bound to one interface and EtherType 0x88A4
//!   (the master's side: non-blocking, kernel receive timestamps, qdisc bypass);
//! - [`SlaveSocket`]: the same raw socket as the simulator serves it (promiscuous, one blocking
//!   receive per frame with an idle timeout);
//! - [`XdpLink`]: an AF_XDP socket fed by the XDP program of `bpf.rs` (either side);
//! - [`InProcessLink`]: a direct call into an in-process responder (the simulator without a
//!   network interface).
//!
//! A link is owned by one thread at a time, so its methods take `&mut self` and need no lock.
//! `send` and `recv` never allocate: the real-time thread of the engine calls them every cycle
//! (the audits of tests/acceptance/test_rt_path.py hold them to that and to their syscalls).
//! See docs/engine.md ("Links").

#![warn(missing_docs)]

mod bpf;
pub mod clock;
mod packet;
mod xdp;

pub use clock::{now_ns, realtime_ns, sleep_until};
pub use packet::{
    InProcessLink, Link, LinkKind, LinkOptions, RawSocketLink, Received, Responder, SlaveSocket,
    SLAVE_IDLE_POLL_US,
};
pub use xdp::{XdpLink, XdpMode};
