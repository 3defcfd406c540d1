"""``crs bench models``: the built-in models and a model of one's own, side by side (issue 41).

Every model runs through the same steps on the same data. The simulated car is always the
dynamic bicycle (a simple model meets a real car this way): the same drive open-loop on the
dynamic and the kinematic model, where the kinematic one departs (its yaw rate against the
dynamic one's and the linear single track's understeer); estimation (EKF and MHE, each model's
default sensors) and identification (``crs sysid``'s FIE from the rough prior, validated by
2 s open-loop predictions on another drive) on simulated recordings; a race of the MPCC with
each model on the simulated car; and identification and estimation on the two real
recordings (validated on the other run; the estimates against the car's on-board estimate).
The third model is docs/own-model.md's example, ``tests/own_model/linear_tyre_car.py``,
loaded from its file as a researcher's would be.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from benchmarks.machine import REAL_DATA
from benchmarks.workflow import run_crs
from crs_core.control.mpcc import Mpcc
from crs_core.control.mpcc_problem import MpccSettings
from crs_core.dataset import Dataset
from crs_core.estimation.factory import make_estimator
from crs_core.estimation.offline import estimate_dataset, reference_comparison
from crs_core.identification.models import ROUGH, identification_model
from crs_core.identification.problem import FieSettings, default_fit
from crs_core.identification.solve import identify
from crs_core.identification.validation import validate
from crs_core.model import CarModel
from crs_core.model.bicycle import cornering_stiffness
from crs_core.model.kinematic import KinematicBicycle
from crs_core.model.plant import Plant
from crs_core.track import load_demo_track
from sim.closed_loop import run_closed_loop
from sim.scenarios import SIM_PROCESS_SCALE, simulate_dataset
from sim.sensors import SensorSuite
from sim.simulator import Simulator

ROOT = Path(__file__).resolve().parents[1]
#: The models compared: label -> spec (the third loaded from its file by path).
MODELS = {
    "dynamic": "dynamic",
    "kinematic": "kinematic",
    "linear_tyre": f"{ROOT / 'tests' / 'own_model' / 'linear_tyre_car.py'}:LinearTyreCar",
}
#: The open-loop drive of the departure: steering held, torque ramped from 0 to this over
#: :data:`RAMP_S` s from a rolling start.
RAMP_TORQUE, RAMP_S, RAMP_STEER, RAMP_START_SPEED = 0.6, 10.0, 0.2, 0.3
#: The plot leaves out the first second of the ramp drive (the dynamic model's turn-in from a
#: straight rolling start).
PLOT_FROM_S = 1.0
#: Simulated recordings: (label, driver, seed), 40 s each; the first trains.
SIMULATED = (("train", "path", 21), ("path", "path", 22), ("joystick", "joystick", 23))
SIM_DURATION_S = 40.0
#: The real recordings.
REAL_RUNS = ("fie_mpc_lighthouse_1", "fie_mpc_lighthouse_2")
#: Validation horizon, s.
HORIZON_S = 2.0
#: The kinematic bicycle's MPCC races planned at these speeds, m/s (its racing speed first).
RACING_SPEEDS = (0.9, 1.05, 1.6)
#: The launched stack's race with the kinematic model, s.
STACK_RACE_S = 60.0


def departure() -> dict[str, Any]:
    """The ramp drive on the dynamic and the kinematic model, every 0.1 s: speed (m/s), yaw
    rate (rad/s) and the lateral acceleration the IMU would read (m/s^2); and the linear
    single track's steady yaw rate :math:`v_x \\delta / (L + K v_x^2)` at the dynamic one's
    speeds, with its understeer gradient K."""
    out: dict[str, Any] = {"steer_rad": RAMP_STEER, "torque_max": RAMP_TORQUE, "ramp_s": RAMP_S}
    dt, every = 0.01, 10
    for label in ("dynamic", "kinematic"):
        model = CarModel(model=label)
        numeric, p = model.numeric, model.parameters.vector()
        x = model.initial_state([0, 0, 0, RAMP_START_SPEED, 0, 0], [RAMP_STEER, 0.0])
        rows: dict[str, list[float]] = {"t": [], "speed": [], "yaw_rate": [], "ay": []}
        for k in range(round(RAMP_S / dt) + 1):
            u = np.array([RAMP_STEER, RAMP_TORQUE * k * dt / RAMP_S])
            if k % every == 0:
                car = numeric.car_state(x, u, p)
                rows["t"].append(round(k * dt, 3))
                rows["speed"].append(round(float(np.hypot(car[3], car[4])), 4))
                rows["yaw_rate"].append(round(float(car[5]), 4))
                rows["ay"].append(round(float(numeric.outputs(x, u, p)["imu"][1]), 4))
            x = numeric.step(x, u, p, dt)
        out[label] = rows
    P = CarModel().parameters.value
    length = P("lf") + P("lr")
    front = cornering_stiffness(P("Df"), P("Cf"), P("Bf"))
    rear = cornering_stiffness(P("Dr"), P("Cr"), P("Br"))
    gradient = P("m") * (P("lr") / front - P("lf") / rear) / length
    speeds = np.asarray(out["dynamic"]["speed"])
    linear = speeds * RAMP_STEER / (length + gradient * speeds**2)
    out["linear_single_track"] = {
        "understeer_gradient_rad_s2_per_m": round(gradient, 5),
        "yaw_rate": np.round(linear, 4).tolist(),
    }
    return out


class KinematicWithPoseNoise(KinematicBicycle):
    """The kinematic bicycle with the dynamic model's pose process noise (the choice the
    built-in one's :attr:`~crs_core.model.plant.Plant.process_std` is measured against)."""

    process_std: ClassVar[dict[str, float]] = {}


class KinematicUncapped(KinematicBicycle):
    """The kinematic bicycle without its racing speed (the MPCC planning as fast as asked)."""

    racing_speed: ClassVar[float | None] = None


def kinematic_choices(tests: dict[str, Dataset]) -> dict[str, Any]:
    """The kinematic bicycle's defaults against the alternatives: its estimation with the IMU
    (``lh+imu+we``) and with the dynamic model's pose noise, on each simulated drive; and MPCC
    races planned faster than its racing speed."""
    kinematic = CarModel(model="kinematic")
    out: dict[str, Any] = {"estimation": {}, "races": {}}
    for name, dataset in tests.items():
        out["estimation"][name] = {
            "default": _estimation(dataset, kinematic),
            "with_imu": _estimation(dataset, kinematic, "lh+imu+we"),
            "dynamic_pose_noise": _estimation(dataset, CarModel(model=KinematicWithPoseNoise())),
        }
    for speed in RACING_SPEEDS:
        settings = MpccSettings(progress_speed_max=speed)
        out["races"][f"{speed:g}"] = _race(KinematicUncapped(), settings)
    return out


def _estimation(dataset: Dataset, model: CarModel, sensors: str = "auto") -> dict[str, Any]:
    """EKF and MHE position, yaw and speed RMSE (mm, mrad, mm/s) against the reference, on the
    sensors the recording has and the model explains, from 2 s after the first fix."""
    out: dict[str, Any] = {}
    for kind in ("ekf", "mhe"):
        result = estimate_dataset(dataset, kind, sensors, model=model)
        comparison = reference_comparison(result, dataset)
        assert comparison is not None
        rmse = comparison["rmse_settled"]
        out["sensors"] = result.diagnostics["sensors"]
        out["reference"] = comparison["reference"]
        out[kind] = {
            "position_mm": round(1e3 * rmse["position"], 2),
            "yaw_mrad": round(1e3 * rmse["yaw"], 1),
            "vx_mm_s": round(1e3 * rmse["vx"], 1),
        }
    return out


def _identification(
    train: Dataset, tests: dict[str, Dataset], spec: str, process_scale: float
) -> tuple[dict[str, Any], CarModel]:
    """``crs sysid``'s FIE from the rough prior on ``train``; the 2 s open-loop position
    RMSE (m) of the prior and the identified model on each of ``tests``; and the identified
    model."""
    model = identification_model(train, (), ROUGH, model=spec)
    settings = FieSettings(fit=default_fit(model), process_scale=process_scale)
    result = identify(train, model, settings)
    out: dict[str, Any] = {
        "fit": list(result.fit),
        "time_s": round(result.time_s, 1),
        "not_identifiable": [
            n for n, ok in zip(result.fit, result.uncertainty.identifiable, strict=True) if not ok
        ],
    }
    for label, test in tests.items():
        tested = identification_model(test, (), ROUGH, model=spec)
        summary, _ = validate(test, tested, result.parameters, tested.parameters, HORIZON_S)
        out[f"validated_on_{label}_m"] = {
            name: round(value, 4) for name, value in summary["position_rmse_m"].items()
        }
    return out, model.with_parameters(result.parameters)


def _race(spec: str | Plant, settings: MpccSettings | None = None, seed: int = 1) -> dict[str, Any]:
    """The MPCC (``settings``; its speed capped by the model's racing speed) and the MHE with
    the model, on the simulated dynamic car: 3 laps (at most 45 s) from the start line."""
    track = load_demo_track()
    model = CarModel(model=spec)
    mpcc = Mpcc(track, model, settings)
    estimator = make_estimator("mhe", None, model)
    simulator = Simulator(CarModel(), SensorSuite(), seed=seed)
    result = run_closed_loop(
        simulator,
        track,
        lambda t, x: mpcc(x),
        mpcc.stop,
        mpcc.settings.rate_hz,
        laps=3,
        max_duration=45.0,
        estimator=estimator,
        status_of=lambda: mpcc.status.mode,
    )
    summary = result.summary()
    rmse = summary["estimation_rmse"]
    return {
        "progress_speed_max_m_s": mpcc.settings.progress_speed_max,
        "laps": summary["laps"],
        "lap_times_s": summary["lap_times_s"],
        "boundary_violations": summary["boundary_violations"],
        "max_outside_m": summary["max_outside_m"],
        "estimation_position_mm": round(1e3 * rmse["position"], 2),
    }


def stack_race(work: Path, spec: str = "kinematic", duration_s: float = STACK_RACE_S) -> dict:
    """``crs launch sim --model SPEC --duration S`` (the simulated car dynamic, the MHE): its
    report's laps, lap times, estimation RMSE and the model it ran."""
    out = work / f"launch_{spec}"
    run_crs(
        [
            "launch",
            "sim",
            "--model",
            spec,
            "--duration",
            f"{duration_s:g}",
            "--out",
            str(out),
            "--overwrite",
        ]
    )
    report = json.loads((out / "report.json").read_text())
    car = report["cars"]["car1"]
    return {
        "command": f"crs launch sim --model {spec} --duration {duration_s:g}",
        "model": report["model"],
        "car_model": report["car_truth"]["model"],
        "laps": car["laps_completed"],
        "lap_times_s": car["lap_times_s"],
        "estimation_rmse": car["estimation_rmse"],
        "node_deaths": report["node_deaths"],
    }


def models_benchmark(work: Path, say: Callable[[str], None] = print) -> dict[str, Any]:
    """Every section of the module docstring, per model of :data:`MODELS`, and the
    kinematic model's race in the launched stack (run folder in ``work``)."""
    started = time.perf_counter()
    say("departure: the ramp drive on the dynamic and the kinematic model")
    out: dict[str, Any] = {"models": MODELS, "departure": departure()}
    simulated = {
        label: simulate_dataset(SIM_DURATION_S, seed, driver=driver)
        for label, driver, seed in SIMULATED
    }
    train, tests = simulated["train"], {k: v for k, v in simulated.items() if k != "train"}
    real = {name: Dataset.load(REAL_DATA / name) for name in REAL_RUNS}
    for label, spec in MODELS.items():
        say(f"{label}: simulator (estimation, identification, race)")
        estimation = {name: _estimation(d, CarModel(model=spec)) for name, d in tests.items()}
        identification, _ = _identification(train, tests, spec, SIM_PROCESS_SCALE)
        row: dict[str, Any] = {
            "simulator": {
                "estimation": estimation,
                "identification": identification,
                "race": _race(spec),
            }
        }
        say(f"{label}: real recordings (identification, estimation with the identified model)")
        row["real"] = {}
        for name, dataset in real.items():
            others = {other: real[other] for other in REAL_RUNS if other != name}
            identification, identified = _identification(dataset, others, spec, 1.0)
            row["real"][name] = {
                "identification": identification,
                "estimation": _estimation(dataset, identified),
            }
        out[label] = row
    say("kinematic: its sensors, pose noise and racing speed against the alternatives")
    out["kinematic_choices"] = kinematic_choices(tests)
    say(f"kinematic: crs launch sim --model kinematic --duration {STACK_RACE_S:g}")
    out["stack"] = stack_race(work)
    out["time_s"] = round(time.perf_counter() - started, 1)
    return out


def format_markdown(result: dict[str, Any]) -> str:
    """The tables of docs/own-model.md: the simulator, then the real recordings."""
    labels = [label for label in MODELS if label in result]
    lines = [
        "| model | EKF / MHE position RMSE, path drive (mm) | joystick drive (mm) | 2 s open-loop "
        "prediction, path / joystick (m): rough prior → identified | MPCC race on the "
        "simulated car: laps, lap (s), violations, estimation (mm) |",
        "|---|---|---|---|---|",
    ]
    for label in labels:
        sim = result[label]["simulator"]
        est, ident, race = sim["estimation"], sim["identification"], sim["race"]
        lap = min(race["lap_times_s"][1:] or race["lap_times_s"] or [float("nan")])
        cells = [
            f"`{label}` ({est['path']['sensors']})",
            f"{est['path']['ekf']['position_mm']:.1f} / {est['path']['mhe']['position_mm']:.1f}",
            f"{est['joystick']['ekf']['position_mm']:.1f} / "
            f"{est['joystick']['mhe']['position_mm']:.1f}",
            " / ".join(
                f"{ident[f'validated_on_{d}_m']['prior']:.3f} → "
                f"{ident[f'validated_on_{d}_m']['identified']:.3f}"
                for d in ("path", "joystick")
            ),
            f"{race['laps']}, {lap:.2f}, {race['boundary_violations']}, "
            f"{race['estimation_position_mm']:.1f} (speed cap "
            f"{race['progress_speed_max_m_s']:g} m/s)",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    lines += [
        "",
        "| model | run 1 → run 2: 2 s open-loop (m), rough prior → identified | run 2 → run 1 | "
        "EKF / MHE position RMSE against the on-board estimate, run 1 / run 2 (mm) | not "
        "identifiable (run 1) |",
        "|---|---|---|---|---|",
    ]
    first, second = REAL_RUNS
    for label in labels:
        real = result[label]["real"]
        forward = real[first]["identification"][f"validated_on_{second}_m"]
        backward = real[second]["identification"][f"validated_on_{first}_m"]
        est = [real[name]["estimation"] for name in REAL_RUNS]
        cells = [
            f"`{label}` ({est[0]['sensors']})",
            f"{forward['prior']:.3f} → {forward['identified']:.3f}",
            f"{backward['prior']:.3f} → {backward['identified']:.3f}",
            " / ".join(
                f"{e['ekf']['position_mm']:.1f}, {e['mhe']['position_mm']:.1f}" for e in est
            ),
            ", ".join(real[first]["identification"]["not_identifiable"]) or "none",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    choices = result.get("kinematic_choices")
    if choices:
        lines += [
            "",
            "| kinematic bicycle, drive | its defaults (lh+we, own pose noise): position mm, "
            "v_x mm/s | with the IMU (lh+imu+we) | with the dynamic model's pose noise |",
            "|---|---|---|---|",
        ]
        for name, rows in choices["estimation"].items():
            cells = [
                f"{rows[k]['mhe']['position_mm']:.1f}, {rows[k]['mhe']['vx_mm_s']:.0f}"
                for k in ("default", "with_imu", "dynamic_pose_noise")
            ]
            lines.append(f"| {name} (MHE) | " + " | ".join(cells) + " |")
        races = ", ".join(
            f"{speed} m/s: {race['boundary_violations']} violations, "
            f"{race['max_outside_m'] * 100:.1f} cm furthest out"
            for speed, race in choices["races"].items()
        )
        lines += ["", f"Kinematic MPCC races planned at {races} (3 laps each)."]
    stack = result.get("stack")
    if stack:
        rmse = stack["estimation_rmse"]
        lines += [
            "",
            f"`{stack['command']}` (the simulated car {stack['car_model']}): "
            f"{stack['laps']} laps, "
            + ", ".join(f"{t:.2f}" for t in stack["lap_times_s"])
            + f" s; estimation RMSE x {1e3 * rmse['x']:.1f} mm, y {1e3 * rmse['y']:.1f} mm, "
            f"yaw {1e3 * rmse['yaw']:.1f} mrad; nodes lost: {len(stack['node_deaths'])}.",
        ]
    departure = result["departure"]["linear_single_track"]
    lines += [
        "",
        f"Understeer gradient of the dynamic model's linear tyres: "
        f"{departure['understeer_gradient_rad_s2_per_m']:g} rad s²/m; the whole run took "
        f"{result['time_s']:.0f} s.",
    ]
    return "\n".join(lines)


def plot(result: dict[str, Any], path: Path) -> None:
    """The departure: each model's yaw rate against its speed on the ramp drive (from
    :data:`PLOT_FROM_S` on), and the linear single track's; and the lateral acceleration each
    would read."""
    from matplotlib.figure import Figure

    departure = result["departure"]
    fig = Figure(figsize=(9, 4))
    left, right = fig.subplots(1, 2)
    settled = np.asarray(departure["dynamic"]["t"]) >= PLOT_FROM_S
    for label, style in (("dynamic", "k"), ("kinematic", "C1")):
        rows = {k: np.asarray(v)[settled] for k, v in departure[label].items()}
        left.plot(rows["speed"], rows["yaw_rate"], style, label=f"{label} model")
        right.plot(rows["speed"], rows["ay"], style, label=f"{label} model")
    left.plot(
        np.asarray(departure["dynamic"]["speed"])[settled],
        np.asarray(departure["linear_single_track"]["yaw_rate"])[settled],
        "k:",
        label="linear single track (understeer)",
    )
    left.set_xlabel("speed [m/s]")
    left.set_ylabel("yaw rate [rad/s]")
    left.set_title(f"steering held at {departure['steer_rad']} rad, torque ramped")
    left.legend()
    right.set_xlabel("speed [m/s]")
    right.set_ylabel("lateral acceleration [m/s²]")
    right.set_title("what the IMU reads")
    right.legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
