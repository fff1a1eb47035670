"""Operator console: talks to the running node over ROS 2; never to a shell."""
