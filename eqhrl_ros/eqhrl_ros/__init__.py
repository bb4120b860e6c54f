"""EQ-HRL for ROS 2: ``core`` holds the ROS-free learner, ``nodes`` the thin ROS adapters."""
