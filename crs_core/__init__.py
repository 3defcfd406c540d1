"""ROS-free core of the Chronos/CRS suite: models, sensors, estimation, control, datasets."""
