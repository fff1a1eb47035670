"""The demos: whole runs on a simulated bus that put the layers together.

- :mod:`~ether_ros.demo.trot` — the trot of thesis Table 6.1 over ROS 2 (the console's trot
  sequence, a recording, the thesis's figures);
- :mod:`~ether_ros.demo.arm` — the 6-axis CiA 402 arm moved with a joint trajectory over ROS 2.

They sit at the top beside ``cli`` (docs/architecture.md, "Layers"): a demo may import the
console, the ROS client and the tools; none of those imports a demo.
"""
