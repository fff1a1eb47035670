//! The virtual EtherCAT network: a tree of virtual slave controllers (ESCs) that process real
//! frames, with device applications (firmware models) and fault injection.

#![warn(missing_docs)]

pub mod chip;
pub(crate) mod coe;
pub(crate) mod dc;
pub mod device;
pub mod devices;
pub mod esc;
pub mod faults;
pub mod firmware;
pub(crate) mod fmmu;
pub mod foe;
pub mod network;
pub mod od;
pub(crate) mod pdo;
pub mod pi_mutex;
pub mod runner;
pub mod sii;
pub(crate) mod sm;
pub mod soe;
pub mod spec;
pub(crate) mod topology;

pub use foe::FoeSpec;
pub use network::Network;
pub use spec::{MailboxSpec, SlaveSpec, SpecError};
