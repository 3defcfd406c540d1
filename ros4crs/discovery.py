"""DDS discovery settings of every process of the suite (nodes, launcher, ``crs ros`` tools).

Fast DDS 2.14 (the PyPI wheels) sends a new participant's first announcement before its
receivers are registered (``RTPSParticipantImpl::enable``), so the running nodes' immediate
replies to a process that just started (``crs ros topics``, a node joining a running stack) are
dropped about half the time; the newcomer then sees a node only at that node's next periodic
announcement, every 3 s by default, while ``crs ros topics`` waits 1 s. With every process
announcing every 0.25 s (``fastdds_profile.xml``) a newcomer sees the nodes within about 0.5 s
on a loaded machine (measured: ``crs ros topics`` missed the nodes in 4-7 of 12-20 calls before,
0 of 72 after; ``tests/integration/test_tools.py``).

Only the environment is set, and only where the user has not chosen a profile of their own.
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping
from pathlib import Path

#: The suite's Fast DDS profile (0.25 s participant announcements).
FASTDDS_PROFILE = Path(__file__).with_name("fastdds_profile.xml")


#: The environment variable naming the folder where nodes write their timing statistics when
#: they stop (:func:`ros4crs.node_support.run_nodes`; the launcher sets it to its log folder).
STATS_DIR_VARIABLE = "CRS_NODE_STATS"


def set_discovery_environment(env: MutableMapping[str, str] = os.environ) -> None:
    """Discovery on this machine only (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) and the
    suite's Fast DDS profile, unless ``env`` already sets them. Call before the DDS
    participant is created (``rclpy.init``)."""
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", str(FASTDDS_PROFILE))
