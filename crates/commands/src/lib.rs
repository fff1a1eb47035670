//! The ROS 2 command path in native code.
//!
//! A `WriteVariable` published on `pdo_listener` used to go through the Python executor, which
//! on a busy node (publishing process data every cycle) waits for the GIL and costs milliseconds.
//! Here a native thread waits on the subscription through rcl (the library rclpy has already
//! loaded; see [`rcl`]), takes the message in its serialized form, decodes it ([`cdr`]), resolves
//! it against a table of the bus's output variables built by Python ([`table`]) and writes the
//! value straight into the engine's output buffer ([`receiver`]). Python is never on this path.
//!
//! `joint_commands` (`sensor_msgs/JointState` for CiA 402 axes) takes the same path with its own
//! thread: decoded here, resolved against the axes ([`joints`]) and written into the engine's
//! axis command slots (`Engine::axis_setpoint`).
//!
//! The operator console's panic key is read here too ([`panic_keys`]): a native thread reads the
//! terminal and sends the node's `panic` request through rcl without waiting for Python.
//!
//! Only requests that are certainly valid take the fast path. Malformed data and structurally
//! invalid joint commands are refused here, with the words Python uses; anything else (text
//! values, unknown names, values out of range) is handed to the node's Python code, which owns
//! those error messages, so both paths accept exactly the same writes. The queue for Python is
//! fair per publisher, and with the control lease on ([`lease`]) only the holder's publishers
//! get past the first check.

#![warn(missing_docs)]

pub mod cdr;
pub mod joints;
pub mod lease;
pub mod panic_keys;
pub(crate) mod rcl;
pub mod receiver;
pub mod table;

pub use cdr::{
    check_joint_trajectory, decode_joint_state, decode_write_variable, encode_write_result,
    write_variable_request_id, CdrError, JointCommand, WriteRequest,
};
pub use joints::{JointEntry, JointTable, Setpoint};
pub use lease::{Gid, LeaseGate, LeaseState, Verdict};
pub use panic_keys::{PanicKeyHandles, PanicKeys, Sent, PANIC_KEYS};
pub use receiver::{CommandReceiver, ReceiverCounters, ReceiverHandles};
pub use table::{CommandTable, Kind, Resolution, SlaveEntry, VariableEntry};
