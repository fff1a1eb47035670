"""ROS 2 interface: the lifecycle node and message conversion."""
