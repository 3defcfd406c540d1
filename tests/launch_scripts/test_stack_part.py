"""A stack split across machines: ``StackPart`` (``crs launch --nodes`` and the Zenoh options),
the nodes each stack launches with it, the ``zenoh_link`` node, the report of a part without
the recorder, and who may join a listening part (``--zenoh-config`` that authenticates, or
``--zenoh-open``; :mod:`ros4crs.zenoh.admission`). No process starts."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from launch_scripts import sim_stack
from launch_scripts.car_stack import car_nodes
from launch_scripts.cli import main
from launch_scripts.sim_stack import StackOptions, stack_nodes
from launch_scripts.stack_part import StackPart, zenoh_settings
from ros4crs.zenoh.session import ZenohSettings

LISTEN = ZenohSettings("peer", listen=("tcp/0.0.0.0:17647",))
EXAMPLES = Path(__file__).resolve().parents[2] / "docs" / "zenoh"


def _names(nodes) -> list[str]:
    return [spec.full_name for spec in nodes]


def test_the_sim_stack_launches_the_named_nodes_for_every_car_and_its_link(tmp_path: Path):
    part = StackPart(("simulator", "recorder"), LISTEN)
    nodes = stack_nodes(2, StackOptions("ekf", part=part), tmp_path / "bag")
    assert _names(nodes) == ["/car1/simulator", "/car2/simulator", "/recorder", "/zenoh_link"]
    far = stack_nodes(2, StackOptions("ekf", part=StackPart(("estimator", "controller"))), Path())
    assert _names(far) == [
        "/car1/estimator",
        "/car1/controller",
        "/car2/estimator",
        "/car2/controller",
    ]
    assert _names(stack_nodes(1, StackOptions("ekf"), tmp_path / "bag")) == [
        "/car1/simulator",
        "/car1/estimator",
        "/car1/controller",
        "/recorder",
    ]


def test_the_car_stack_launches_the_emulated_car_with_its_bridge(tmp_path: Path):
    def names(nodes: tuple[str, ...]) -> list[str]:
        options = StackOptions("ekf", part=StackPart(nodes))
        return _names(car_nodes(2, options, tmp_path / "bag", tmp_path, True))

    assert names(("bridge",)) == [
        "/car1/bridge",
        "/car2/bridge",
        "/car1/emulator",
        "/car2/emulator",
    ]
    assert names(("estimator", "controller", "recorder")) == [
        "/car1/estimator",
        "/car1/controller",
        "/car2/estimator",
        "/car2/controller",
        "/recorder",
    ]
    real = StackOptions("ekf", part=StackPart(("bridge",)))
    assert _names(car_nodes(1, real, tmp_path / "bag", tmp_path, False, ["10.0.0.5"])) == [
        "/car1/bridge"
    ]


@pytest.mark.parametrize(
    ("nodes", "zenoh", "expected"),
    [
        (None, None, 2),  # one machine: the estimator and the recorder
        (None, LISTEN, 2),  # the link may subscribe too; the local two are awaited
        (("simulator", "recorder"), LISTEN, 2),  # the recorder, and the link for the estimator
        (("simulator",), LISTEN, 1),  # both far: one link subscription in their place
        (("simulator",), None, 2),  # the others on this machine's DDS (another crs launch)
        (("simulator", "estimator", "controller"), LISTEN, 2),
    ],
)
def test_the_simulator_waits_for_the_subscribers_it_can_see(
    nodes: tuple[str, ...] | None, zenoh: ZenohSettings | None, expected: int
):
    """Far subscribers appear as the one subscription of the link node: waiting for each of
    them would hold the clock for ever; the commands are awaited in every part."""
    options = StackOptions("ekf", part=StackPart(nodes, zenoh))
    (simulator,) = [s for s in stack_nodes(1, options, Path("bag")) if s.name == "simulator"]
    assert simulator.parameters["wait_for_subscribers"] == expected
    assert simulator.parameters["wait_for_commands"] is True


def test_the_link_node_gets_the_zenoh_settings(tmp_path: Path):
    config = tmp_path / "zenoh.json5"
    config.write_text("{}")
    settings = ZenohSettings(
        "client", connect=("tcp/10.0.0.1:7447", "tcp/10.0.0.2:7447"), config_file=config
    )
    options = StackOptions("ekf", part=StackPart(("estimator",), settings))
    link = stack_nodes(1, options, tmp_path / "bag")[-1]
    assert (link.name, link.module, link.namespace) == ("zenoh_link", "ros4crs.zenoh_link_node", "")
    assert link.parameters == {
        "mode": "client",
        "listen": "",
        "connect": "tcp/10.0.0.1:7447,tcp/10.0.0.2:7447",
        "config_file": str(config.resolve()),
        "topics": "",
    }
    no_link = stack_nodes(1, StackOptions("ekf"), tmp_path / "bag")
    assert "zenoh_link" not in [spec.name for spec in no_link]


def _launched_options(argv: list[str], out: Path, monkeypatch: pytest.MonkeyPatch) -> StackOptions:
    """The options ``crs launch ARGV --out OUT`` runs its stack with (nothing runs)."""
    seen: list[StackOptions] = []

    def fake_run(cars: int, options: StackOptions, *args: Any) -> dict[str, Any]:
        seen.append(options)
        return {"cars": {}, "nodes": [], "node_deaths": []}

    monkeypatch.setattr(sim_stack, "run_stack", fake_run)
    monkeypatch.setattr(sim_stack, "summary", lambda report, out: "done")
    assert main(["launch", *argv, "--out", str(out)]) == 0
    return seen[0]


def test_zenoh_options_are_repeatable_or_comma_separated_and_peer_by_default(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    assert zenoh_settings(None, None, None, None) is None
    argv = ["sim", "--zenoh-open", "--zenoh-listen", "tcp/0.0.0.0:17600, tcp/[::]:17601"]
    argv += ["--zenoh-listen", "tcp/0.0.0.0:17603", "--zenoh-connect", "tcp/h:17602"]
    options = _launched_options(argv, tmp_path / "out", monkeypatch)
    assert options.part.zenoh == ZenohSettings(
        "peer", ("tcp/0.0.0.0:17600", "tcp/[::]:17601", "tcp/0.0.0.0:17603"), ("tcp/h:17602",)
    )


@pytest.mark.parametrize(
    ("part", "message"),
    [
        (lambda: StackPart(("simulator", "ekf")), "nodes: 'ekf' is not a node"),
        (lambda: StackPart(()), "nodes: name at least one node"),
        (lambda: StackPart(("recorder", "recorder")), "nodes: .* names a node twice"),
    ],
)
def test_bad_parts_are_refused_naming_nodes(part, message: str):
    with pytest.raises(ValueError, match=message):
        part()


def test_a_node_of_the_other_stack_is_refused(tmp_path: Path):
    bridge = StackOptions("ekf", part=StackPart(("bridge",)))
    with pytest.raises(ValueError, match="nodes: bridge: not a node of the sim stack"):
        stack_nodes(1, bridge, tmp_path / "bag")
    simulator = StackOptions("ekf", part=StackPart(("simulator", "estimator")))
    with pytest.raises(ValueError, match="nodes: simulator: not a node of the car stack"):
        car_nodes(1, simulator, tmp_path / "bag", tmp_path, True)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["sim", "--nodes", "simulator,bridge"], "--nodes: bridge: not a node of the sim stack"),
        (["sim", "--nodes", "planner"], "argument --nodes: 'planner' is not a node"),
        (["car", "--emulate", "--nodes", "simulator"], "--nodes: simulator: not a node of"),
        (["sim", "--zenoh-connect", "7447"], "--zenoh-connect: an endpoint is PROTOCOL/ADDRESS"),
        (["sim", "--zenoh-mode", "client"], "--zenoh-connect: a client needs a router"),
        (
            ["sim", "--zenoh-config", "/no/such.json5", "--zenoh-listen", "tcp/0.0.0.0:17600"],
            "--zenoh-config: no such file",
        ),
        (["sim", "--zenoh-mode", "router"], "--zenoh-listen: a router needs an endpoint"),
        (["sim", "--zenoh-open"], "--zenoh-open: only with --zenoh-listen"),
        (
            ["sim", "--zenoh-open", "--zenoh-connect", "tcp/10.0.0.1:17600"],
            "--zenoh-open: only with --zenoh-listen",
        ),
        (["sim", "--nodes", "simulator", "--require-laps", "1"], "--require-laps: laps are"),
    ],
)
def test_crs_launch_refuses_a_bad_part_in_one_line_before_anything_starts(
    argv: list[str], message: str, tmp_path: Path, crs_refuses
):
    out = tmp_path / "out"
    assert message in crs_refuses(["launch", *argv, "--out", str(out)])
    assert not out.exists()


def test_crs_launch_passes_the_part(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    argv = ["sim", "--nodes", "estimator,controller"]
    argv += ["--zenoh-connect", "tcp/10.0.0.1:17600", "--zenoh-mode", "client"]
    assert _launched_options(argv, tmp_path / "out", monkeypatch).part == StackPart(
        ("estimator", "controller"), ZenohSettings("client", connect=("tcp/10.0.0.1:17600",))
    )


def test_a_part_without_the_recorder_reports_its_processes_and_no_bag(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    """No bag to analyse: the settings, the processes launched, their deaths, CPU and memory,
    and the summary says there was no analysis."""
    monkeypatch.setattr(sim_stack, "warm_compile_cache", lambda *args, **kwargs: 0.0)
    monkeypatch.setattr(sim_stack, "run_watched", lambda launcher, duration, after: [])
    figures = {"cpu_percent": {"/car1/estimator": 40.0}, "peak_memory_mib": {}}
    monkeypatch.setattr(sim_stack, "process_figures", lambda launcher: figures)
    part = StackPart(("estimator", "controller"), ZenohSettings("client", connect=("tcp/h:1",)))
    report = sim_stack.run_stack(1, StackOptions("ekf", part=part), 5.0, tmp_path, 155)
    saved = json.loads((tmp_path / "report.json").read_text())
    assert saved == report
    assert report["cars"] == {} and report["bag_analysis"] == sim_stack.NO_BAG
    assert report["nodes"] == ["/car1/estimator", "/car1/controller", "/zenoh_link"]
    assert report["part"] == {
        "nodes": ["estimator", "controller"],
        "zenoh": {"mode": "client", "listen": [], "connect": ["tcp/h:1"], "config_file": None},
    }
    assert report["node_deaths"] == [] and report["cpu_percent"] == {"/car1/estimator": 40.0}
    assert report["estimator"] == "ekf" and report["duration_s"] == 5.0
    text = sim_stack.summary(report, tmp_path)
    assert text.splitlines()[0].startswith("no bag analysis: none on this machine")
    assert "path.png" not in text and not (tmp_path / "bag").exists()


# --- who may join a listening part ----------------------------------------------------------


def test_crs_launch_refuses_to_listen_openly_without_an_authenticating_config(
    tmp_path: Path, crs_refuses
):
    """One line on stderr, exit code 2, naming --zenoh-config and the examples; nothing starts."""
    out = tmp_path / "out"
    argv = ["launch", "sim", "--zenoh-listen", "tcp/0.0.0.0:17600", "--out", str(out)]
    line = crs_refuses(argv)
    assert line.startswith(
        "crs launch: error: --zenoh-listen: tcp/0.0.0.0:17600 admits any machine that reaches "
        "it, and any of them may publish a car's input: give --zenoh-config FILE that "
        "authenticates who joins (examples: docs/zenoh/listener.json5 (user/password), "
        "docs/zenoh/mtls-listener.json5 (mutual TLS);"
    ), line
    assert "or pass --zenoh-open to listen openly" in line
    assert not out.exists()


def test_crs_launch_refuses_a_config_that_authenticates_nobody(tmp_path: Path, crs_refuses):
    out = tmp_path / "out"
    argv = ["launch", "sim", "--zenoh-listen", "tcp/[::]:17600", "--out", str(out)]
    line = crs_refuses([*argv, "--zenoh-config", str(EXAMPLES / "member.json5")])
    assert line.startswith("crs launch: error: --zenoh-config: ")
    assert "member.json5 authenticates nobody" in line and "docs/zenoh/listener.json5" in line
    assert not out.exists()


def test_crs_launch_listens_with_an_authenticating_config(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
):
    monkeypatch.chdir(EXAMPLES)  # listener.json5's dictionary_file is relative
    config = EXAMPLES / "listener.json5"
    argv = ["sim", "--zenoh-listen", "tcp/0.0.0.0:17600", "--zenoh-config", str(config)]
    options = _launched_options(argv, tmp_path / "out", monkeypatch)
    assert options.part.zenoh == ZenohSettings("peer", ("tcp/0.0.0.0:17600",), (), config)
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("listen", ["tcp/127.0.0.1:17600", "tcp/[::1]:17600,tcp/localhost:17601"])
def test_crs_launch_listens_on_loopback_silently(
    listen: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
):
    options = _launched_options(["sim", "--zenoh-listen", listen], tmp_path / "out", monkeypatch)
    assert options.part.zenoh is not None and options.part.zenoh.listen
    assert capsys.readouterr().err == ""


def test_crs_launch_zenoh_open_listens_openly_after_one_warning(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
):
    argv = ["sim", "--zenoh-listen", "tcp/0.0.0.0:17600", "--zenoh-open"]
    options = _launched_options(argv, tmp_path / "out", monkeypatch)
    assert options.part.zenoh == ZenohSettings("peer", ("tcp/0.0.0.0:17600",))
    assert capsys.readouterr().err == (
        "crs launch: warning: --zenoh-listen tcp/0.0.0.0:17600 admits any machine that reaches "
        "it, unauthenticated (--zenoh-open): any of them may publish a car's input\n"
    )
