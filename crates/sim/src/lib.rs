//! The virtual EtherCAT network: a line of virtual slave controllers (ESCs) that process real
//! frames, with device applications (firmware models) and fault injection.

pub mod device;
pub mod devices;
pub mod od;
