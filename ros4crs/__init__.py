"""Thin rclpy nodes around the crs_core objects (the ROS4CRS layer)."""
