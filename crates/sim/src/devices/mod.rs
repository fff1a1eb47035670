//! Device applications (firmware models) the simulator can run behind a virtual ESC.

use crate::device::DeviceApp;

/// Create a device application by its config name. `params` come from the bus config
/// (`sim.params` of a slave); unknown names are an error naming the kind.
pub fn create(kind: &str, _params: &[(String, f64)]) -> Result<Option<Box<dyn DeviceApp>>, String> {
    match kind {
        "none" | "" => Ok(None),
        other => Err(format!("unknown simulated device kind '{other}'")),
    }
}
