"""ROS 2 over rmw_zenoh: mrosd's ROS 1 topics on the keys, tokens and types a ROS 2 node uses (docs/ros2.md)."""
