"""The start-up contract of :func:`ros4crs.node_support.run`: every node refuses a bad parameter
at start-up in one line naming it, with exit code 2; so is a bad ``CRS_EXECUTOR``.

The cases run one after the other in one Python process, each through its module's ``main``
with the arguments the launcher gives (``<module> --ros-args -r __ns:=/car1 ...``), which is what
``python -m <module>`` runs: a process per case cost a second or two of imports each, 30 s of
the suite. The executor case starts a real node process. None reaches DDS.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

#: (module, ROS arguments, the one line it must print on stderr; {tmp} is a temporary folder)
CASES = [
    (
        "estimator_node",
        ["-p", "rate_hz:=0"],
        "error: rate_hz: must be a finite number > 0, got 0.0",
    ),
    ("estimator_node", ["-p", "rate_hz:=nan"], "error: rate_hz: must be a finite number > 0"),
    ("estimator_node", ["-p", "rate_hz:=fast"], "error: rate_hz: expected a number, got 'fast'"),
    ("estimator_node", ["-p", "estimator:=ukf"], "error: estimator: must be one of ekf, mhe"),
    ("estimator_node", ["-p", "sensors:=lh+sonar"], "error: sensors: 'lh+sonar' must combine"),
    ("estimator_node", ["-p", "horizon:=1"], "error: horizon: must be in 2..1000, got 1"),
    ("estimator_node", ["-p", "initial_state:=[1.0,2.0]"], "initial_state: must be 6 finite"),
    ("estimator_node", ["-p", "params_file:={tmp}/none.yaml"], "params_file: no such file"),
    ("estimator_node", ["-p", "params_file:={tmp}/bad.yaml"], "params_file: {tmp}/bad.yaml: "),
    ("estimator_node", ["-p", "time_offsets:=lh"], "error: time_offsets: "),
    ("estimator_node", ["-p", "model:=bogus"], "error: model: unknown model 'bogus' (built in:"),
    (
        "controller_node",
        ["-p", "model:=kinematic", "-p", "params_file:={tmp}/dynamic.yaml"],
        "error: model: kinematic contradicts {tmp}/dynamic.yaml, whose parameters are of model "
        "dynamic",
    ),
    ("simulator_node", ["-p", "model:={tmp}/none.py:Car"], "error: model: {tmp}/none.py: no such"),
    ("estimator_node", ["-p", "catch_up_solves:=0"], "error: catch_up_solves: must be in 1..1000"),
    ("estimator_node", ["-p", "max_lag:=-0.1"], "error: max_lag: must be a finite number >= 0"),
    (
        "bridge_node",
        ["-p", "telemetry_hz:=0.0"],
        "error: telemetry_hz: must be a finite number > 0",
    ),
    ("simulator_node", ["-p", "effects:=bogus"], "error: effects: unknown effect 'bogus'"),
    ("simulator_node", ["-p", "blackouts:=lighthouse:1"], "error: blackouts: 'lighthouse:1'"),
    ("simulator_node", ["-p", "tick_hz:=0.0"], "error: tick_hz: must be a finite number > 0"),
    ("simulator_node", ["-p", "seed:=-1"], "error: seed: must be >= 0, got -1"),
    ("controller_node", ["-p", "v_ref:=-1.0"], "error: v_ref: must be a finite number > 0"),
    # parameters of a settings dataclass: its checks, the error naming the parameter
    ("estimator_node", ["-p", "lag:=-0.01"], "error: lag: must be a finite number >= 0, got -0.01"),
    (
        "controller_node",
        ["-p", "speed_ramp:=0.0"],
        "error: speed_ramp: must be a finite number > 0, got 0.0",
    ),
    (
        "controller_node",
        ["-p", "degraded_speed:=inf"],  # refused before it is clamped to the top speed
        "error: degraded_speed: must be a finite number > 0, got inf",
    ),
    (
        "controller_node",
        ["-p", "hold_safe:=sometimes"],
        "error: hold_safe: must be one of after_outage, always, never, got 'sometimes'",
    ),
    (
        "controller_node",
        ["-p", "command_delay:=0.5"],
        "error: command_delay: must not exceed max_delay (0.15 s), got 0.5",
    ),
    ("controller_node", ["-p", "controller:=lqr"], "error: controller: must be one of mpcc, path"),
    ("controller_node", ["-p", "output:=speed"], "error: output: must be one of torque, velocity"),
    (
        "controller_node",
        ["-p", "controller:=path", "-p", "output:=velocity"],
        "error: output: velocity needs controller:=mpcc (the path controller commands torque)",
    ),
    ("simulator_node", ["-p", "onboard:=maybe"], "error: onboard: expected true or false"),
    ("controller_node", ["-p", "track_file:={tmp}/none.yaml"], "error: track_file: no such file"),
    ("controller_node", ["-p", "track_file:={tmp}/bad.yaml"], "error: track_file: {tmp}/bad.yaml"),
    ("controller_node", ["-p", "params_file:={tmp}/bad.yaml"], "params_file: {tmp}/bad.yaml: "),
    ("simulator_node", ["-p", "params_file:={tmp}/bad.yaml"], "params_file: {tmp}/bad.yaml: "),
    ("simulator_node", ["-p", "track_file:={tmp}"], "error: track_file: is a folder, not a file"),
    ("recorder_node", ["-p", "output:={tmp}"], "error: output: exists already"),
    ("recorder_node", ["-p", "storage:=zip"], "error: storage: must be one of mcap, sqlite3"),
    ("replayer_node", ["-p", "bag:={tmp}/none"], "error: bag: {tmp}/none: not a bag folder"),
    ("replayer_node", ["-p", "rate:=0.0"], "error: rate: must be a finite number > 0"),
    ("zenoh_link_node", ["-p", "mode:=hub"], "error: mode: must be one of router, peer, client"),
    ("zenoh_link_node", ["-p", "domain:=300"], "error: domain: must be in 0..232, got 300"),
    ("zenoh_link_node", ["-p", "config_file:={tmp}/none.json5"], "error: config_file: no such"),
    ("zenoh_link_node", ["-p", "mode:=peer"], "error: listen: a peer needs an endpoint to listen"),
    ("zenoh_link_node", ["-p", "mode:=client"], "error: connect: a client needs a router"),
    (
        "zenoh_link_node",
        ["-p", "connect:=10.0.0.1:7447"],
        "error: connect: an endpoint is PROTOCOL/ADDRESS (tcp/10.0.0.1:7447), got '10.0.0.1:7447'",
    ),
    ("bridge_node", ["-p", "imu_sensor:=accel"], "error: imu_sensor: must be one of imu, gyro"),
    ("bridge_node", ["-p", "car_ip:=car.local"], "error: car_ip: not an IPv4 address"),
    ("bridge_node", ["-p", "car_port:=20211"], "error: car_port: needs car_ip"),
    ("bridge_node", ["-p", "port:=0"], "error: port: must be in 1..65535, got 0"),
    # the link's and the sensor output's settings (CarLinkSettings, SensorOutputSettings)
    (
        "bridge_node",
        ["-p", "command_repeat_period:=-0.02"],
        "error: command_repeat_period: must be a finite number >= 0, got -0.02",
    ),
    (
        "bridge_node",
        ["-p", "command_repeat_for:=soon"],
        "error: command_repeat_for: expected a number, got 'soon'",
    ),
    ("bridge_node", ["-p", "port:=70000"], "error: port: must be in 1..65535, got 70000"),
    (
        "simulator_node",
        ["-p", "batch_period:=-0.01"],
        "error: batch_period: must be a finite number >= 0, got -0.01",
    ),
    (
        "simulator_node",
        ["-p", "sensor_messages:=all"],
        "error: sensor_messages: must be one of batch, each, got 'all'",
    ),
]


#: Runs each case of ``argv[1]`` (JSON ``[module, [arguments]]``) through its module's ``main``
#: and prints ``[exit code, stderr]`` per case as JSON (a raised exception: its traceback).
RUNNER = """
import contextlib, importlib, json, sys, tempfile, traceback
results = []
for module, arguments in json.loads(sys.argv[1]):
    err = tempfile.TemporaryFile("w+")  # a real file: the nodes may ask for its descriptor
    with contextlib.redirect_stderr(err):
        try:
            code = importlib.import_module("ros4crs." + module).main(
                [module, "--ros-args", "-r", "__ns:=/car1", *arguments]
            )
        except BaseException:
            code = None
            err.write(traceback.format_exc())
    err.seek(0)
    results.append([code, err.read()])
print(json.dumps(results))
"""


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[tuple[int, str, str]]]:
    """The temporary folder, and (exit code, stderr, expected line) per case."""
    tmp = tmp_path_factory.mktemp("startup")
    (tmp / "bad.yaml").write_text("parameters:\n  m: heavy\n")
    (tmp / "dynamic.yaml").write_text("model: dynamic\nparameters:\n  m: 0.2\n")
    env = {**os.environ, "ROS_DOMAIN_ID": "171", "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    cases = [(module, [a.format(tmp=tmp) for a in arguments]) for module, arguments, _ in CASES]
    result = subprocess.run(
        [sys.executable, "-c", RUNNER, json.dumps(cases)],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    results = json.loads(result.stdout.splitlines()[-1])
    out = [
        (code, err, expected.format(tmp=tmp))
        for (code, err), (_, _, expected) in zip(results, CASES, strict=True)
    ]
    return tmp, out


@pytest.mark.parametrize("case", range(len(CASES)), ids=[f"{m}:{a[-1]}" for m, a, _ in CASES])
def test_bad_parameter_is_one_line_naming_it(outcomes, case: int):
    code, err, expected = outcomes[1][case]
    module = CASES[case][0].removesuffix("_node")
    assert code == 2, err
    assert "Traceback" not in err, err
    (line,) = [line for line in err.splitlines() if "error:" in line]
    assert line.startswith(f"/car1/{module}: error: "), err
    assert expected in line, err


def test_nothing_was_written_or_deleted(outcomes):
    """The refused recorder (an existing ``output``) and the others left the folder as it was."""
    tmp, _ = outcomes
    assert sorted(p.name for p in tmp.iterdir()) == ["bad.yaml", "dynamic.yaml"]


def test_unknown_executor_is_a_start_up_error():
    """``CRS_EXECUTOR`` is read before the node is built: a bad value is one line, exit code 2."""
    env = {
        **os.environ,
        "ROS_DOMAIN_ID": "171",
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "CRS_EXECUTOR": "multi",
    }
    command = [sys.executable, "-m", "ros4crs.controller_node", "--ros-args", "-r", "__ns:=/car1"]
    result = subprocess.run(command, capture_output=True, text=True, env=env, timeout=120)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr, result.stderr
    (line,) = [line for line in result.stderr.splitlines() if "error:" in line]
    assert line == "/car1/controller: error: CRS_EXECUTOR: one of events, single, got 'multi'"


def test_a_bad_executor_is_a_field_error_naming_the_variable(monkeypatch) -> None:
    from crs_core.errors import FieldError
    from ros4crs.node_support import make_executor

    monkeypatch.setenv("CRS_EXECUTOR", "multi")
    with pytest.raises(FieldError) as error:
        make_executor()
    assert error.value.field == "CRS_EXECUTOR"


class _Node:
    """What :func:`ros4crs.node_support.declare` asks of a node: ``declare_parameter``, with
    the values given (else the default), recording the names declared."""

    def __init__(self, **values: object) -> None:
        self.values, self.declared = values, []

    def declare_parameter(self, name: str, default: object, descriptor: object):
        from types import SimpleNamespace

        self.declared.append(name)
        return SimpleNamespace(value=self.values.get(name, default))


OWN_MODEL = Path(__file__).resolve().parents[1] / "own_model" / "linear_tyre_car.py"


def test_the_model_parameter_picks_the_nodes_model(tmp_path: Path) -> None:
    """``model`` is declared beside ``params_file``: empty, the file's ``model:`` or else the
    dynamic bicycle; a built-in name or a file of one's own otherwise."""
    from ros4crs.node_support import declare_model

    node = _Node()
    assert declare_model(node).plant.name == "dynamic"
    assert {"model", "params_file"} <= set(node.declared)
    assert declare_model(_Node(model="kinematic")).plant.name == "kinematic"
    assert declare_model(_Node(model=f"{OWN_MODEL}:LinearTyreCar")).plant.name == "linear_tyre"
    params = tmp_path / "kinematic.yaml"
    params.write_text("model: kinematic\nparameters:\n  lf: 0.05\n")
    model = declare_model(_Node(params_file=str(params)))
    assert model.plant.name == "kinematic" and model.parameters.value("lf") == 0.05
    assert declare_model(_Node(params_file=str(params), model="kinematic")).nx == 4


@pytest.mark.parametrize(
    ("values", "field", "message"),
    [
        ({"model": "bogus"}, "model", "unknown model 'bogus'"),
        ({"model": "nowhere.py:Car"}, "model", "nowhere.py: no such file"),
        ({"model": f"{OWN_MODEL}:Nothing"}, "model", "has no Plant subclass Nothing"),
        ({"model": "dynamic", "params_file": "KIN"}, "model", "dynamic contradicts KIN, whose"),
        ({"params_file": "BAD_MODEL"}, "params_file", "BAD_MODEL: model: must be a model name"),
    ],
)
def test_a_bad_model_parameter_is_refused_naming_it(
    values: dict, field: str, message: str, tmp_path: Path
) -> None:
    from ros4crs.node_support import ParameterError, declare_model

    files = {"KIN": tmp_path / "kinematic.yaml", "BAD_MODEL": tmp_path / "bad_model.yaml"}
    files["KIN"].write_text("model: kinematic\nparameters:\n  lf: 0.05\n")
    files["BAD_MODEL"].write_text("model: 3\nparameters:\n  m: 0.2\n")
    values = {name: str(files.get(value, value)) for name, value in values.items()}
    for key, path in files.items():
        message = message.replace(key, str(path))
    with pytest.raises(ParameterError) as raised:
        declare_model(_Node(**values))
    assert raised.value.field == field and message in raised.value.reason, raised.value
