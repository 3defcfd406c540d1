"""The discovery environment of every process: localhost only and the suite's Fast DDS profile
(participants announce every 0.25 s), unless the user chose otherwise."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import pytest

from ros4crs.discovery import FASTDDS_PROFILE, set_discovery_environment

NS = {"p": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}


def test_an_empty_environment_gets_localhost_and_the_suite_profile() -> None:
    env: dict[str, str] = {}
    set_discovery_environment(env)
    assert env == {
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "FASTRTPS_DEFAULT_PROFILES_FILE": str(FASTDDS_PROFILE),
    }


def test_the_profile_is_the_default_and_announces_every_quarter_second() -> None:
    participant = ET.parse(FASTDDS_PROFILE).getroot().find("p:participant", NS)
    assert participant is not None and participant.get("is_default_profile") == "true"
    lease = participant.find("p:rtps/p:builtin/p:discovery_config/p:leaseAnnouncement", NS)
    assert lease is not None
    seconds = (
        int(lease.findtext("p:sec", namespaces=NS))
        + int(lease.findtext("p:nanosec", namespaces=NS)) * 1e-9
    )
    assert seconds == pytest.approx(0.25, abs=1e-12)


def test_what_the_user_set_is_kept() -> None:
    env = {
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET",
        "FASTRTPS_DEFAULT_PROFILES_FILE": "/etc/my_profile.xml",
        "OTHER": "x",
    }
    set_discovery_environment(env)
    assert env == {
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET",
        "FASTRTPS_DEFAULT_PROFILES_FILE": "/etc/my_profile.xml",
        "OTHER": "x",
    }
    partial = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}
    set_discovery_environment(partial)
    assert partial["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SUBNET"
    assert partial["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(FASTDDS_PROFILE)
