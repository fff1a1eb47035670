//! The raw-socket runner reports a missing interface instead of starting a useless thread.

use std::sync::{Arc, Mutex};

use ether_ros_sim::runner::Runner;
use ether_ros_sim::Network;

#[test]
fn a_missing_interface_is_an_error_naming_it() {
    let net = Arc::new(Mutex::new(Network::new()));
    let err = Runner::start(net, "nosuchif0")
        .err()
        .expect("no such interface");
    assert!(err.to_string().contains("nosuchif0"), "{err}");
}
