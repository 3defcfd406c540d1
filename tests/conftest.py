"""Suite-wide set-up: each pytest-xdist worker (``./run.sh test``'s first phase runs two) talks
DDS in a ROS domain of its own, so that two tests starting ROS nodes at once on the two workers
never see each other's topics. Tests that need a particular domain set it themselves."""

from __future__ import annotations

import os

#: The ROS domain of worker ``gwN`` is this plus N (no test module uses 80..89 explicitly).
WORKER_DOMAIN_BASE = 80


def pytest_configure() -> None:
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    if worker.startswith("gw") and worker[2:].isdigit():
        os.environ["ROS_DOMAIN_ID"] = str(WORKER_DOMAIN_BASE + int(worker[2:]) % 10)
