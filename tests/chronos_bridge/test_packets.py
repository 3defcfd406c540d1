"""Packets: the typed packet contents validate on construction."""

from __future__ import annotations

import pytest

from chronos_bridge.codec import encode_packet
from chronos_bridge.packets import FieldError, Packet, Reference
from crs_core.errors import FieldError as CoreFieldError
from tests.chronos_bridge.bridge_builders import STAMP_US


def test_oneof_exclusivity_in_the_typed_packets() -> None:
    with pytest.raises(FieldError, match="throttle_reference"):
        Reference(throttle=0.1, longitudinal_velocity=1.0)
    with pytest.raises(FieldError, match="throttle_reference"):
        Reference(angle=0.1)
    with pytest.raises(FieldError, match="steering_reference"):
        Reference(throttle=0.1, angle=0.1, voltage=100)
    assert encode_packet(Packet(Reference(throttle=0.0, voltage=0), STAMP_US))


def test_the_bridge_and_the_core_share_one_error_type() -> None:
    assert FieldError is CoreFieldError
