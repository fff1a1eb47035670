"""ROS 2 interface: the lifecycle node and everything around it (see docs/ros.md).

- :mod:`~ether_ros.ros.node` — the ``ether_ros`` lifecycle node (topics, services, parameters);
- :mod:`~ether_ros.ros.sample_publisher` — the thread that publishes the engine's samples;
- :mod:`~ether_ros.ros.bridge` — the node's view of the master's ``Bus`` (layout, samples,
  writes, statistics);
- :mod:`~ether_ros.ros.diagnostics` — ``diagnostic_msgs`` for the master and the slaves;
- :mod:`~ether_ros.ros.layout`, :mod:`~ether_ros.ros.values` — layout and typed values without
  ROS (shared with the console);
- :mod:`~ether_ros.ros.convert` — layout to and from ``ether_ros_msgs``;
- :mod:`~ether_ros.ros.client` — a ROS 2 client of the node (console, demo, tests, benchmarks);
- :mod:`~ether_ros.ros.rig` — simulator + node + client on a veth pair;

Importing this package does not import rclpy; the modules that need it do.
"""
