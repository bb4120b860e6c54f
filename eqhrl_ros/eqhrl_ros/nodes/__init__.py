"""ROS 2 nodes: thin adapters between topics/services and eqhrl_ros.core."""
