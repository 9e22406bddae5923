"""Sequences in other tools' formats: ``rosbag`` writes a ROS 2 bag for ROS 2 nodes."""
