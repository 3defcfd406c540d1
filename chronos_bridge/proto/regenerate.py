"""Regenerate ``chronos_pb2.py`` and ``vector3_pb2.py`` from the ``.proto`` files.

Usage, from the repository root (installs nothing itself)::

    python -m venv /tmp/protoc-venv
    /tmp/protoc-venv/bin/pip install grpcio-tools==1.85.1
    /tmp/protoc-venv/bin/python -m chronos_bridge.proto.regenerate

``grpcio-tools==1.85.1`` bundles the protoc whose Python gencode matches the pinned runtime
``protobuf==7.36.2`` (generated files check the runtime version at import; a different protoc
may produce code that warns or refuses to load). The ``.proto`` files import each other by their
path from the repository root, so the generated modules import ``chronos_bridge.proto.*_pb2``.
"""

from __future__ import annotations

import sys
from pathlib import Path

#: The grpcio-tools release whose protoc generated the checked-in code.
GRPCIO_TOOLS_VERSION = "1.85.1"
PROTO_FILES = ("chronos_bridge/proto/vector3.proto", "chronos_bridge/proto/chronos.proto")


def main() -> int:
    root = Path(__file__).resolve().parents[2]
    try:
        from grpc_tools import protoc  # a build tool: imported only here
    except ImportError:
        print(
            f"needs grpcio-tools=={GRPCIO_TOOLS_VERSION} in this Python (a throw-away venv); "
            "see the module docstring",
            file=sys.stderr,
        )
        return 1
    from importlib.metadata import version

    found = version("grpcio-tools")
    if found != GRPCIO_TOOLS_VERSION:
        print(f"warning: grpcio-tools {found}, the checked-in code used {GRPCIO_TOOLS_VERSION}")
    args = ["protoc", f"-I{root}", f"--python_out={root}", f"--pyi_out={root}"]
    args += [str(root / name) for name in PROTO_FILES]
    status = protoc.main(args)
    if status == 0:
        print("regenerated:", ", ".join(n.replace(".proto", "_pb2.py") for n in PROTO_FILES))
    return status


if __name__ == "__main__":
    raise SystemExit(main())
