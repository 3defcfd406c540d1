"""The ``crs`` commands, one module each (registered in :mod:`launch_scripts.cli`)."""
