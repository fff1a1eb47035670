//! `ether_ros._native`: the Rust core seen from Python. Each part registers its own classes so
//! the simulator and the engine bindings stay in their own files.

use pyo3::prelude::*;

mod command_bindings;
mod contracts;
mod engine_bindings;
mod errors;
mod protocol_bindings;
mod sim_bindings;
mod sim_faults;

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    sim_bindings::register(m)?;
    sim_faults::register(m)?;
    engine_bindings::register(m)?;
    contracts::register(m)?;
    command_bindings::register(m)?;
    protocol_bindings::register(m)?;
    Ok(())
}
