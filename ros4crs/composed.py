"""Several of the suite's nodes in one process: a car's simulator (or bridge), estimator and
controller spun by one executor.

``python -m ros4crs.composed --node /car1/simulator=ros4crs.simulator_node:PARAMS ...`` makes
each node with its own name, namespace and parameter file (the remaps a node process takes on
its command line, here given to that node alone) and spins them together. The topics, their
types and QoS are those of the separate processes, so recorders, viewers, bags and other
machines see the same graph; what a car saves is the processes themselves (one interpreter, one
DDS participant, one set of imports) and the wake-ups of three executors. The launcher starts
one per car unless told to keep a process per node (``crs launch ... --process-per-node``).
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable, Sequence
from functools import partial

from rclpy.node import Node

from ros4crs.node_support import run_nodes

#: The node classes that may share a process, by module.
COMPOSABLE = {
    "ros4crs.simulator_node": "SimulatorNode",
    "ros4crs.estimator_node": "EstimatorNode",
    "ros4crs.controller_node": "ControllerNode",
    "ros4crs.bridge_node": "BridgeNode",
}


def node_argument(text: str) -> tuple[str, str, str]:
    """``/ns/name=module:params_file`` -> ``(full name, module, params file)``."""
    full_name, _, target = text.partition("=")
    module, _, params = target.partition(":")
    if not full_name.startswith("/") or not module or not params:
        raise argparse.ArgumentTypeError(f"expected /ns/name=module:params_file, got {text!r}")
    if module not in COMPOSABLE:
        raise argparse.ArgumentTypeError(
            f"module {module!r} cannot share a process: one of {', '.join(COMPOSABLE)}"
        )
    return full_name, module, params


def node_maker(full_name: str, module: str, params: str) -> Callable[[], Node]:
    """The factory of node ``full_name`` of ``module`` with its parameter file."""
    namespace, _, name = full_name.rpartition("/")
    node_class = getattr(importlib.import_module(module), COMPOSABLE[module])
    remaps = ["--ros-args", "-r", f"__node:={name}", "--params-file", params]
    return partial(node_class, namespace=namespace or "/", cli_args=remaps)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ros4crs.composed", description=__doc__)
    parser.add_argument(
        "--node",
        action="append",
        type=node_argument,
        required=True,
        help="a node: /ns/name=module:params_file (in the order they are made)",
    )
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    makers = [(name, node_maker(name, module, params)) for name, module, params in args.node]
    return run_nodes(makers, [sys.argv[0]])


if __name__ == "__main__":
    raise SystemExit(main())
