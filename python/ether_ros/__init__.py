"""ether_ros: a real-time EtherCAT master for Linux with a ROS 2 interface.

The package is Python; the cyclic real-time path and the simulator's frame processing live in the
Rust extension ``ether_ros._native``. See docs/architecture.md for how the parts fit together.
"""

__version__ = "0.1.0"
