"""Start, watch and stop sets of node processes (there is no ``ros2 launch`` from PyPI)."""
