"""Compile the car stack's functions before its processes start.

On a cold compile cache (a fresh clone, a new parameter file) every node compiles its CasADi
functions with gcc when it starts: the MPCC about 7 s and the MHE about 18 s on this 2-core
machine. A car (or the car emulator) does not wait for that: its data flow into an estimator
that shares two cores with the compilers of the others, and on fresh clones the controller came
about 7 s after the rest; a race of ``--duration`` s raced for 20 s less. :func:`warm_compile_cache`
builds the same objects the nodes build, one after the other in the launcher, so that every node
then loads its functions from the cache (about 1.5 s for all of them when they are there).

``python -m launch_scripts.warm_cache`` is the last step of ``./run.sh``'s set-up: it compiles
the functions of the main job's stack and of the EKF, so that a fresh clone's first run, and its
test suite, start from a warm cache.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

__all__ = ["warm_compile_cache"]

#: What this process has warmed already: (estimator, controller, output, parameter text,
#: car effects, the stack's and the car's model, cache folder) of each call (a second call finds
#: the same files in the cache).
_warmed: set[tuple] = set()


def warm_compile_cache(
    estimator: str,
    controller: str,
    output: str,
    params_file: Path | None = None,
    label: str = "[launch]",
    car_effects: Sequence[tuple[str, str | None, float | None]] = (),
    model: str | None = None,
    car_model: str | None = None,
) -> float:
    """Build (and so compile and cache) the estimator's, the controller's and the simulated
    car's functions with the nodes' default settings, with a line before and after on stdout;
    returns the time taken, s. A call this process has made before (the same arguments, the
    same parameter file's text and cache folder) builds nothing, says so and returns 0.

    Parameters
    ----------
    estimator : {"ekf", "mhe"}
        The estimator node's kind (its default sensors: ``lh+imu+we``, of those the model
        explains).
    controller : {"mpcc", "path"}
        The controller node's kind (only the MPCC compiles).
    output : {"torque", "velocity"}
        The controller's output.
    params_file : Path, optional
        The parameter YAML the nodes get.
    label : str
        Prefix of the two lines printed.
    car_effects : sequence of parsed effects, optional
        The simulated or emulated cars' hidden effects (their truth model's structure; its
        parameter values do not change the compiled code).
    model : str, optional
        The estimator's and controller's model, a spec (default: the one ``params_file`` names,
        else the dynamic bicycle).
    car_model : str, optional
        The simulated or emulated cars' model, a spec (default: the dynamic bicycle).
    """
    from chronos_bridge.emulator import CarEmulator
    from crs_core.codegen import cache_dir
    from crs_core.control.mpcc import Mpcc
    from crs_core.control.mpcc_problem import MpccSettings
    from crs_core.estimation import EkfSettings, MheSettings, make_estimator
    from crs_core.estimation.realtime import RealtimeSettings
    from crs_core.model import CarModel
    from crs_core.model.effects import effect_spec
    from crs_core.track import load_demo_track

    parameters = None  # a file that cannot be read: CarModel.from_file says why below
    if params_file is not None and Path(params_file).is_file():
        parameters = Path(params_file).read_text()
    key = (
        estimator,
        controller,
        output,
        parameters,
        tuple(car_effects),
        model,
        car_model,
        str(cache_dir()),
    )
    if key in _warmed:
        print(f"{label} compiled model functions ready (warmed earlier in this process)")
        return 0.0
    print(f"{label} preparing the compiled model functions (compiled once, then cached)")
    started = time.perf_counter()
    stack_model = CarModel.from_file(params_file, model=model)
    # the nodes' defaults: the estimator's rate is RealtimeSettings', the MPCC's MpccSettings'
    rate_hz = RealtimeSettings.rate_hz
    settings = MheSettings(rate_hz=rate_hz) if estimator == "mhe" else EkfSettings()
    make_estimator(estimator, None, stack_model, settings)  # the node's default sensors
    if controller == "mpcc":
        Mpcc(load_demo_track(), stack_model, MpccSettings(), output=output)
    # the simulator's truth model with the onboard loop
    CarEmulator(model=CarModel(effect_spec(car_effects), model=car_model))
    elapsed = time.perf_counter() - started
    _warmed.add(key)
    print(f"{label} compiled model functions ready in {elapsed:.1f} s")
    return elapsed


def main() -> int:
    """Compile the main job's stack (MHE, MPCC, the simulated car); the MHE's build compiles
    the EKF's functions too (both input modes), which it starts from."""
    warm_compile_cache("mhe", "mpcc", "torque", label="[setup]")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
