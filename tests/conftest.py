"""Suite-wide set-up: each pytest-xdist worker (``./run.sh test`` runs two) talks DDS in a ROS
domain of its own, so that two tests starting ROS nodes at once on the two workers never see
each other's topics (tests that need a particular domain set it themselves); and with ``--dist
loadfile`` a module's tests stay on one worker (its fixtures are built once), the integration
tests (ROS 2 stacks racing in real time, :data:`INTEGRATION_FOLDER`) all on one, one after the
other and first, while the other worker runs the rest. (xdist's own ``loadgroup`` does not group
under pytest 9: it renames a test by an attribute pytest no longer reads.)"""

from __future__ import annotations

import os

import pytest

#: The ROS domain of worker ``gwN`` is this plus N (no test module uses 80..89 explicitly).
WORKER_DOMAIN_BASE = 80


def pytest_configure() -> None:
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    if worker.startswith("gw") and worker[2:].isdigit():
        os.environ["ROS_DOMAIN_ID"] = str(WORKER_DOMAIN_BASE + int(worker[2:]) % 10)


#: The tests that run one after the other on one worker (whose timing the others would disturb).
INTEGRATION_FOLDER = "tests/integration/"


def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object | None:
    """With ``--dist loadfile``: xdist's scheduling by file, the integration tests one unit."""
    if config.getvalue("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling

    class IntegrationTogether(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            if nodeid.startswith(INTEGRATION_FOLDER):
                return INTEGRATION_FOLDER
            return super()._split_scope(nodeid)

    return IntegrationTogether(config, log)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    # the integration tests first: the other worker fills the time beside them
    items.sort(key=lambda item: not item.nodeid.startswith(INTEGRATION_FOLDER))
