"""The suite's ROS 2 message types for rosbags.

:func:`typestore` returns a rosbags ``Typestore`` of ROS 2 Jazzy (``Stores.ROS2_JAZZY``: the
standard messages) with the ``chronos_msgs`` messages registered from their ``.msg`` files, so
bags holding them can be written and read without ROS (rosbags is pure Python). The ``.msg``
files are read from the installed package (``<venv>/share/chronos_msgs/msg``, put there by
``./run.sh setup``), which is what rclpy's generated types were built from; when the package is
not installed they are read from the source tree (``chronos_msgs/msg`` next to this package).
The RIHS01 type hashes rosbags computes from them equal those of the generated types.
"""

from __future__ import annotations

import functools
import sys
from pathlib import Path

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

__all__ = ["PACKAGE", "msg_dir", "typestore"]

PACKAGE = "chronos_msgs"

_INSTALLED_MSG_DIR = Path(sys.prefix) / "share" / PACKAGE / "msg"
_SOURCE_MSG_DIR = Path(__file__).resolve().parent.parent / PACKAGE / "msg"


def msg_dir() -> Path:
    """The directory the ``chronos_msgs`` ``.msg`` files are read from (installed, else source)."""
    for path in (_INSTALLED_MSG_DIR, _SOURCE_MSG_DIR):
        if any(path.glob("*.msg")):
            return path
    raise FileNotFoundError(
        f"no {PACKAGE} .msg files in {_INSTALLED_MSG_DIR} (installed) or {_SOURCE_MSG_DIR} (source)"
    )


@functools.cache
def typestore() -> Typestore:
    """The ROS 2 Jazzy typestore with every ``chronos_msgs/msg/*`` type registered (cached).

    The same object is returned on every call: do not register conflicting types into it.
    """
    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for path in sorted(msg_dir().glob("*.msg")):
        types.update(get_types_from_msg(path.read_text(), f"{PACKAGE}/msg/{path.stem}"))
    store.register(types)
    return store
