"""Two "machines" in network namespaces (:mod:`benchmarks.netns`): a Zenoh router in
namespace A and a client in namespace B exchange samples over the veth pair, which stop while the
cable is cut and flow again once it is back. A few seconds; needs root (skipped otherwise)."""

from __future__ import annotations

import queue
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import pytest

from tests.integration.netns import NetnsPair, netns_pair

pytestmark = pytest.mark.integration

PORT = 17641
#: Namespace A: a router listening on the veth; prints ``ready``, then each sample's payload.
ROUTER = """
import sys, time
from ros4crs.zenoh.session import ZenohSettings, open_session
with open_session(ZenohSettings("router", listen=(sys.argv[1],))) as session:
    session.declare_subscriber(
        "crs/netns/**", lambda s: print(s.payload.to_bytes().decode(), flush=True)
    )
    print("ready", flush=True)
    time.sleep(60)
"""
#: Namespace B: a client of that router putting ``0``, ``1``, ... every 50 ms.
CLIENT = """
import itertools, sys, time
from ros4crs.zenoh.session import ZenohSettings, open_session
with open_session(ZenohSettings("client", connect=(sys.argv[1],))) as session:
    for n in itertools.count():
        session.put("crs/netns/sample", str(n))
        time.sleep(0.05)
"""


@contextmanager
def python_in(pair: NetnsPair, namespace: str, script: str, endpoint: str) -> Iterator[queue.Queue]:
    """``script`` run in ``namespace`` with ``endpoint`` as its argument; yields a queue of its
    stdout lines (stopped and reaped on exit)."""
    process = subprocess.Popen(
        pair.command(namespace, [sys.executable, "-c", script, endpoint]),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    lines: queue.Queue = queue.Queue()
    threading.Thread(
        target=lambda: [lines.put(ln.strip()) for ln in process.stdout], daemon=True
    ).start()
    try:
        yield lines
    finally:
        process.kill()
        process.wait(10)


def next_line(lines: queue.Queue, timeout: float) -> str:
    try:
        return lines.get(timeout=timeout)
    except queue.Empty:
        raise AssertionError(f"nothing within {timeout:g} s") from None


def drain(lines: queue.Queue) -> list[str]:
    out = []
    while not lines.empty():
        out.append(lines.get_nowait())
    return out


def test_samples_cross_stop_while_the_cable_is_cut_and_flow_after_it_is_back():
    with netns_pair() as pair:
        endpoint = f"tcp/{pair.address_a}:{PORT + 1}"
        with python_in(pair, pair.a, ROUTER, endpoint) as router:
            assert next_line(router, 10.0) == "ready"
            with python_in(pair, pair.b, CLIENT, endpoint):
                first = next_line(router, 10.0)  # a sample from namespace B crossed
                assert first.isdigit()
                pair.cut()
                time.sleep(0.3)  # what was on the way when the cable went
                before = max(int(line) for line in [first, *drain(router)])
                time.sleep(1.5)
                assert drain(router) == [], "samples crossed a cut cable"
                pair.restore()
                assert int(next_line(router, 10.0)) > before


def test_the_namespaces_and_the_veth_pair_are_removed_on_an_error():
    with pytest.raises(RuntimeError, match="a failing test"), netns_pair() as pair:
        raise RuntimeError("a failing test")
    namespaces = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    links = subprocess.run(["ip", "link"], capture_output=True, text=True).stdout
    assert pair.a not in namespaces and pair.b not in namespaces
    assert pair.veth_a not in links and pair.veth_b not in links
