"""Two network namespaces joined by a veth pair: two "machines" on one host, for the tests and
the benchmark of the suite split across machines (``crs launch --nodes`` joined by the Zenoh
link).

:func:`netns_pair` creates namespaces ``crs<pid>a<k>`` and ``crs<pid>b<k>`` (this process's id,
a counter), a veth pair with one end in each, addresses ``10.77.<n>.1/24`` and ``10.77.<n>.2/24``
only inside them, and ``lo`` up in each; it yields a :class:`NetnsPair` and always removes the
namespaces and the veth pair, also on an error half-way. Needs root and ``ip netns`` (pure
stdlib plus the ``ip`` command); raises :class:`NetnsUnavailableError` with the reason otherwise (a
test skips on it).

Each namespace has its own loopback, so ``tcp/127.0.0.1`` does not cross between them: use the
veth addresses (``tcp/10.77.<n>.1:PORT``). :meth:`NetnsPair.cut` and :meth:`NetnsPair.restore`
set the veth end in namespace A down and up again, a pulled cable.
"""

from __future__ import annotations

import itertools
import json
import os
import shutil
import subprocess
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

_COUNTER = itertools.count()


class NetnsUnavailableError(RuntimeError):
    """Network namespaces cannot be made here (not root, no ``ip``, or ``ip netns`` fails)."""


def _ip(*arguments: str) -> None:
    """Run ``ip ARGUMENTS``; ``RuntimeError`` with its stderr when it fails."""
    done = subprocess.run(["ip", *arguments], capture_output=True, text=True, timeout=10)
    if done.returncode != 0:
        raise RuntimeError(f"ip {' '.join(arguments)}: {done.stderr.strip()}")


@dataclass(frozen=True)
class NetnsPair:
    """Two namespaces ``a`` and ``b`` joined by a veth pair (``veth_a`` in ``a`` at
    ``address_a``, ``veth_b`` in ``b`` at ``address_b``, both /24)."""

    a: str
    b: str
    address_a: str
    address_b: str
    veth_a: str
    veth_b: str

    def command(self, namespace: str, argv: Sequence[str]) -> list[str]:
        """``argv`` run inside ``namespace`` (``ip netns exec``; same user, directory and
        environment)."""
        return ["ip", "netns", "exec", namespace, *argv]

    def cut(self) -> None:
        """Pull the cable: the veth end in ``a`` down (nothing passes either way)."""
        _ip("-n", self.a, "link", "set", self.veth_a, "down")

    def restore(self) -> None:
        """Plug it back: the veth end in ``a`` up again."""
        _ip("-n", self.a, "link", "set", self.veth_a, "up")

    def bytes_from_a(self) -> tuple[int, int]:
        """Bytes the veth end in ``a`` has sent and received so far (``a`` -> ``b``,
        ``b`` -> ``a``; Ethernet frames, every header counted)."""
        done = subprocess.run(
            ["ip", "-n", self.a, "-s", "-j", "link", "show", self.veth_a],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        )
        stats = json.loads(done.stdout)[0]["stats64"]
        return int(stats["tx"]["bytes"]), int(stats["rx"]["bytes"])


@contextmanager
def netns_pair() -> Iterator[NetnsPair]:
    """Two namespaces joined by a veth pair (:class:`NetnsPair`), removed on exit whatever
    happened; :class:`NetnsUnavailableError` when not root or when ``ip netns`` fails."""
    if os.geteuid() != 0:
        raise NetnsUnavailableError("network namespaces need root (ip netns add)")
    if shutil.which("ip") is None:
        raise NetnsUnavailableError("no ip command (iproute2) to create network namespaces")
    pid, k = os.getpid(), next(_COUNTER)
    subnet = (pid + k) % 250 + 1
    pair = NetnsPair(
        a=f"crs{pid}a{k}",
        b=f"crs{pid}b{k}",
        address_a=f"10.77.{subnet}.1",
        address_b=f"10.77.{subnet}.2",
        veth_a=f"vc{pid}a{k}",
        veth_b=f"vc{pid}b{k}",
    )
    created: list[str] = []
    try:
        try:
            _ip("netns", "add", pair.a)
        except RuntimeError as error:
            raise NetnsUnavailableError(f"ip netns does not work here: {error}") from None
        created.append(pair.a)
        _ip("netns", "add", pair.b)
        created.append(pair.b)
        _ip("link", "add", pair.veth_a, "type", "veth", "peer", "name", pair.veth_b)
        for namespace, veth, address in (
            (pair.a, pair.veth_a, pair.address_a),
            (pair.b, pair.veth_b, pair.address_b),
        ):
            _ip("link", "set", veth, "netns", namespace)
            _ip("-n", namespace, "addr", "add", f"{address}/24", "dev", veth)
            _ip("-n", namespace, "link", "set", veth, "up")
            _ip("-n", namespace, "link", "set", "lo", "up")
        yield pair
    finally:
        # deleting a namespace deletes the veth end in it, and with it its peer; a veth left in
        # this namespace (an error before it moved) is deleted by name
        for namespace in created:
            subprocess.run(["ip", "netns", "del", namespace], capture_output=True, timeout=10)
        subprocess.run(["ip", "link", "del", pair.veth_a], capture_output=True, timeout=10)
