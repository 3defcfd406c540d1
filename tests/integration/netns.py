"""The network-namespace pair of :mod:`benchmarks.netns` for tests: skipped with the reason where
namespaces cannot be made (not root, no ``ip netns``)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import pytest

from benchmarks.netns import NetnsPair, NetnsUnavailableError
from benchmarks.netns import netns_pair as _netns_pair

__all__ = ["NetnsPair", "netns_pair"]


@contextmanager
def netns_pair() -> Iterator[NetnsPair]:
    """:func:`benchmarks.netns.netns_pair`, skipping the calling test when it is unavailable
    (raised only before the pair exists)."""
    try:
        with _netns_pair() as pair:
            yield pair
    except NetnsUnavailableError as error:
        pytest.skip(str(error))
