//! The virtual EtherCAT network: a tree of virtual slave controllers (ESCs) that process real
//! frames, with device applications (firmware models) and fault injection.

pub mod chip;
pub mod coe;
pub mod dc;
pub mod device;
pub mod devices;
pub mod esc;
pub mod faults;
pub mod firmware;
pub mod fmmu;
pub mod network;
pub mod od;
pub mod pdo;
pub mod pi_mutex;
pub mod runner;
pub mod sii;
pub mod sm;
pub mod soe;
pub mod spec;
pub mod topology;

pub use network::Network;
pub use spec::{MailboxSpec, SlaveSpec, SpecError};
