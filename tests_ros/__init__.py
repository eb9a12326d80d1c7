"""Tests of the ROS 2 side against a fake FR3 cell of real rclpy endpoints."""
