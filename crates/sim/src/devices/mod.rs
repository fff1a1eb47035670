//! Device applications (firmware models) the simulator can run behind a virtual ESC.

pub mod cia402;
pub(crate) mod generic_io;
pub mod laelaps_leg;
pub(crate) mod leg_kinematics;
pub(crate) mod leg_physics;
pub(crate) mod loopback;
pub(crate) mod od_slots;
pub(crate) mod period_clock;
pub(crate) mod servo_motor;
pub(crate) mod trajectory;

use crate::device::DeviceApp;

/// Device kinds `create` knows, for error messages and documentation.
pub const KINDS: &[&str] = &["laelaps_leg", "generic_io", "cia402", "loopback", "none"];

/// Create a device application by its config name. `params` come from the bus config
/// (`sim.params` of a slave); unknown names are an error naming the kind. `links` are the
/// output → input pairs of the `loopback` model (ignored by the others).
pub fn create(
    kind: &str,
    params: &[(String, f64)],
    links: &[loopback::Link],
) -> Result<Option<Box<dyn DeviceApp>>, String> {
    match kind {
        "none" | "" => {
            if let Some((name, _)) = params.first() {
                return Err(format!(
                    "simulated device kind 'none' takes no parameters, got '{name}'"
                ));
            }
            Ok(None)
        }
        "laelaps_leg" => {
            let config = laelaps_leg::LaelapsLegConfig::from_params(params)?;
            Ok(Some(Box::new(laelaps_leg::LaelapsLeg::new(config))))
        }
        "generic_io" => Ok(Some(Box::new(generic_io::GenericIo::from_params(params)?))),
        "cia402" => {
            let config = cia402::Cia402Config::from_params(params)?;
            Ok(Some(Box::new(cia402::Cia402Drive::new(config))))
        }
        "loopback" => {
            if let Some((name, _)) = params.first() {
                return Err(format!(
                    "simulated device kind 'loopback' takes no parameters, got '{name}'"
                ));
            }
            Ok(Some(Box::new(loopback::Loopback::new(links))))
        }
        other => Err(format!(
            "unknown simulated device kind '{other}' (known: {})",
            KINDS.join(", ")
        )),
    }
}
