"""Suite-wide set-up: each pytest-xdist worker (``./run.sh test`` runs two) talks DDS in a ROS
domain of its own, so that two tests starting ROS nodes at once on the two workers never see
each other's topics (tests that need a particular domain set it themselves); and the tests are
grouped for ``--dist loadgroup``: a module's tests stay on one worker (its fixtures are built
once), the integration tests (ROS 2 stacks racing in real time) all on one, one after the other,
first, while the other worker runs the rest."""

from __future__ import annotations

import os

import pytest

#: The ROS domain of worker ``gwN`` is this plus N (no test module uses 80..89 explicitly).
WORKER_DOMAIN_BASE = 80


def pytest_configure() -> None:
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    if worker.startswith("gw") and worker[2:].isdigit():
        os.environ["ROS_DOMAIN_ID"] = str(WORKER_DOMAIN_BASE + int(worker[2:]) % 10)


#: The xdist group of every integration test: one worker runs them, one at a time.
INTEGRATION_GROUP = "integration"


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook turns the groups into scopes
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        integration = item.get_closest_marker("integration") is not None
        group = INTEGRATION_GROUP if integration else item.nodeid.split("::")[0]
        item.add_marker(pytest.mark.xdist_group(group))
    # the longest group first: the other worker fills the time beside it
    items.sort(key=lambda item: item.get_closest_marker("integration") is None)
