"""``crs car-emulator``: an emulated Chronos car on UDP, for tests and demos of other hosts.

Like a car configured with the host's IP: it binds ``--bind``:``--port`` (default
127.0.0.1:20211), sends every datagram to ``--host``:``--host-port`` and nowhere else, and
accepts datagrams only from ``--host`` (others are counted as rejected, reason ``source``).
The core is :class:`chronos_bridge.emulator.CarEmulator`; this module only paces it:

- one :meth:`~chronos_bridge.emulator.CarEmulator.step` per 4 ms against ``time.monotonic()``;
  before each step every pending datagram is read (non-blocking) and handed to the emulator;
- each step runs at its scheduled time and is stamped with it, so the simulated car, its
  Lighthouse deck ticks and its packet stamps stay on one clock; a tick that starts more than
  one period late is counted (``late ticks``) and the overdue steps follow back to back (a short
  burst of packets, as from a car whose Wi-Fi stalled); only more than
  :data:`MAX_CATCH_UP_S` behind the schedule is re-anchored to now (counted in ``skips``: the
  simulated car then falls that far behind the wall clock). Re-anchoring at every late tick
  made the car's physics and deck ticks drift from its packet stamps under load, and the host's
  estimator diverged;
- packets are stamped with the wall clock (``time.time()`` at the start plus the scheduled
  monotonic time), like an SNTP-synchronised car; ``--no-timestamp`` leaves the stamp out;
- a send or receive error (e.g. ICMP port unreachable while no host listens) is counted and
  the loop goes on;
- SIGINT / SIGTERM (or ``--duration``) stop it cleanly with a one-line summary on stdout;
- each motor cut-off (200 ms without a reference) and each resumption is one line on stderr;
- ``--link PRESET|SPEC`` (both directions), ``--link-up`` (car → host), ``--link-down``
  (host → car) put a Wi-Fi-like link (:mod:`chronos_bridge.impairment`, seeded by
  ``--link-seed``, default ``--seed``) between the emulator and its socket: each outgoing
  datagram is sent at its release time (the loop sleeps until the next release or tick, so
  to within the sleep's accuracy); each datagram read is handed to the emulator at the first
  tick at or after its release time (the firmware's loop reads once per 4 ms tick too; the
  delay counts from the tick that read it). An outage longer than 200 ms cuts the motors
  (one line on stderr, as any cut-off). The link's settings are one line on stderr at the
  start when not clean, and its counters end the summary line;
- ``--params FILE`` and ``--effect NAME[.PARAM][=VALUE]`` (repeatable) make the emulated car
  differ from the defaults, and from the host's model: its truth is its own (a car to identify);
  ``--model SPEC`` is its model (``dynamic``, the default unless ``--params`` names another,
  ``kinematic``, or ``FILE.py:CLASS``: :func:`~crs_core.model.plants.load_plant`);
- ``--truth-out FILE`` writes, on exit, an ``.npz`` with the emulator's ground truth and the
  link's timing log (:func:`write_truth`), all on the clock of its packet stamps (Unix s), so
  a host's estimates and latencies can be checked against them (``crs launch car --emulate``).

It prints one line when it is up: ``crs car-emulator: listening on ADDR:PORT, sending to
HOST:PORT`` (with ``--port 0`` the port the system chose).
"""

from __future__ import annotations

import argparse
import ipaddress
import math
import signal
import socket
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from chronos_bridge import DEFAULT_PORT
from chronos_bridge.impairment import (
    SPEC_HELP,
    ImpairedChannel,
    describe,
    make_link,
    parse_link,
)
from crs_core.errors import FieldError, parse_finite
from crs_core.model import CarModel
from crs_core.model.effects import effect_spec, parse_effect
from crs_core.model.plants import load_plant, resolve_model
from sim.drift import DriftSchedule, load_drift

PROG = "crs car-emulator"
DESCRIPTION = (
    "An emulated Chronos car on UDP, like a car configured with the host's IP: it sends a "
    "250 Hz CarState and a discovery ping every 5 s to --host:--host-port (and nowhere else), "
    "listens on --bind:--port and takes datagrams only from --host, tracks throttle or velocity "
    "references with its onboard loop and cuts the motors 200 ms after the last one. "
    "SIGINT/SIGTERM stop it with a one-line summary."
)
#: Largest datagram read (the emulator rejects anything over 256 bytes anyway).
RECEIVE_BUFFER = 4096
#: Furthest the loop catches up on overdue steps, s; beyond it the schedule is re-anchored.
MAX_CATCH_UP_S = 0.5


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The emulator's options (validated by :func:`options`, errors naming the option)."""
    parser.add_argument("--host", required=True, help="the host's IPv4 address (sent to)")
    parser.add_argument("--host-port", required=True, help="the host's UDP port (sent to)")
    parser.add_argument(
        "--port", default=str(DEFAULT_PORT), help=f"own UDP port (default {DEFAULT_PORT}; 0: any)"
    )
    parser.add_argument(
        "--bind", default="127.0.0.1", help="own IPv4 address to bind (default 127.0.0.1)"
    )
    parser.add_argument("--seed", default="0", help="seed of the simulation's noise (default 0)")
    parser.add_argument(
        "--params",
        help="the emulated car's parameter YAML (its truth; default the Chronos defaults): a car "
        "that is not the host's model",
    )
    parser.add_argument(
        "--model",
        metavar="MODEL",
        help="the emulated car's model: dynamic (default), kinematic, or FILE.py:CLASS / "
        "MODULE:CLASS (docs/own-model.md); by default the one --params names",
    )
    parser.add_argument(
        "--effect",
        action="append",
        metavar="NAME[.PARAM][=VALUE]",
        help="a hidden effect of the emulated car (repeatable), e.g. steering_lag=0.05",
    )
    parser.add_argument(
        "--drift",
        metavar="FILE.yaml",
        help="the car changes while it races, as this schedule says (sim.drift: a list of "
        "{parameter or effect, at_s or from_s/to_s, factor or value}, seconds since the car "
        "applied its first command); --truth-out records the changed parameters",
    )
    parser.add_argument(
        "--duration", help="stop after this many s (default: run until SIGINT/SIGTERM)"
    )
    parser.add_argument(
        "--no-timestamp",
        action="store_true",
        help="leave Packet.timestamp out (an unsynchronised car; the host stamps on receipt)",
    )
    parser.add_argument(
        "--truth-out",
        help="on exit write FILE (.npz): the true state at every step and the link's timing "
        "log (commands read, motor cut-offs, outages, link counters), stamped like the packets "
        "(Unix s)",
    )
    parser.add_argument(
        "--link",
        help="impair the link both ways like Wi-Fi (default clean): " + SPEC_HELP,
    )
    parser.add_argument("--link-up", help="car -> host only (overrides --link that way): SPEC")
    parser.add_argument("--link-down", help="host -> car only (overrides --link that way): SPEC")
    parser.add_argument(
        "--link-seed", help="seed of the link's draws (default: --seed; independent streams)"
    )


def add_command(subparsers) -> None:
    """Add ``car-emulator`` to the ``crs`` command line."""
    sub = subparsers.add_parser(
        "car-emulator",
        help="an emulated Chronos car on UDP (for tests of other hosts)",
        description=DESCRIPTION,
    )
    add_arguments(sub)
    sub.set_defaults(handler=run)


def _port(name: str, text: str, allow_zero: bool) -> int:
    try:
        value = int(text)
    except ValueError:
        raise FieldError(name, f"{text!r} is not an integer") from None
    low = 0 if allow_zero else 1
    if not low <= value <= 65535:
        raise FieldError(name, f"{value} outside {low}..65535")
    return value


def _address(name: str, text: str) -> ipaddress.IPv4Address:
    try:
        return ipaddress.IPv4Address(text)
    except ValueError:
        raise FieldError(name, f"{text!r} is not an IPv4 address") from None


def options(args: argparse.Namespace) -> dict:
    """Checked options; ``ValueError`` naming the option (``--host-port: 70000 outside ...``)."""
    host = _address("--host", args.host)
    bind = _address("--bind", args.bind)
    if host.is_unspecified or host.is_multicast or host == ipaddress.IPv4Address("255.255.255.255"):
        raise FieldError("--host", f"{host} is not one host's address")
    if bind.is_loopback and not host.is_loopback:
        raise FieldError(
            "--bind", f"{bind} cannot reach --host {host}; bind 0.0.0.0 or an interface"
        )
    seed = _seed("--seed", args.seed)
    link_seed = seed if args.link_seed is None else _seed("--link-seed", args.link_seed)
    duration = None
    if args.duration is not None:
        duration = parse_finite(args.duration)
        if duration is None or not duration > 0:
            raise FieldError("--duration", f"{args.duration!r} is not a number of seconds > 0")
    model = _car_model(args.params, args.effect or [], args.model)
    return {
        "model": model,
        "drift": _drift(args.drift, model),
        "host": (str(host), _port("--host-port", args.host_port, allow_zero=False)),
        "bind": (str(bind), _port("--port", args.port, allow_zero=True)),
        "seed": seed,
        "duration": duration,
        "timestamps": not args.no_timestamp,
        "truth_out": _truth_path(args.truth_out),
        "link": parse_link(args.link, args.link_up, args.link_down),
        "link_seed": link_seed,
    }


def _car_model(params: str | None, effects: list[str], model: str | None = None) -> CarModel:
    """The emulated car: the model, the parameter file and the effects given (``--model``,
    ``--params``, ``--effect``; a ``--model`` that contradicts the file's ``model:`` is
    refused naming it)."""
    parsed = []
    for text in effects:
        try:
            parsed.append(parse_effect(text))
        except ValueError as error:
            raise FieldError("--effect", str(error)) from None
    if params is not None and not Path(params).is_file():
        raise FieldError("--params", f"{params!r} is not a file")
    plant = load_plant(resolve_model(model, params))  # errors name --model
    try:
        return CarModel.from_file(params, effect_spec(parsed), model=plant)
    except (ValueError, KeyError) as error:
        message = error.args[0] if isinstance(error, KeyError) else str(error)
        raise FieldError("--params", str(message)) from None


def _drift(path: str | None, model: CarModel) -> DriftSchedule | None:
    """``--drift``: the schedule, checked against the emulated car (errors name the option)."""
    if path is None:
        return None
    try:
        schedule = load_drift(path)
        schedule.model_for(model)
    except FieldError as error:
        raise FieldError(f"--drift: {error.field}", error.reason) from None
    return schedule


def _describe_car(args: argparse.Namespace) -> str:
    """``params FILE, effects a, b`` for the start-up line of a car that is not the default."""
    parts = [f"model {args.model}"] if args.model is not None else []
    parts += [f"params {args.params}"] if args.params is not None else []
    if args.effect:
        parts.append("effects " + ", ".join(args.effect))
    if args.drift is not None:
        parts.append(f"drift {args.drift}")
    return "; ".join(parts)


def _seed(name: str, text: str) -> int:
    try:
        seed = int(text)
    except ValueError:
        raise FieldError(name, f"{text!r} is not an integer") from None
    if seed < 0:
        raise FieldError(name, f"{seed} must be >= 0")
    return seed


def _truth_path(text: str | None):
    if text is None:
        return None
    path = Path(text)
    if path.suffix != ".npz":
        raise FieldError("--truth-out", f"{text!r} must end in .npz")
    if not path.parent.is_dir():
        raise FieldError("--truth-out", f"folder {str(path.parent)!r} does not exist")
    return path


class TruthLog:
    """What ``--truth-out`` records, on the clock of the packet stamps (Unix s).

    ``t`` / ``x``: the stamp of each step's ``CarState`` (``unix_offset + now``) and the true
    base state ``[x, y, yaw, v_x, v_y, omega]`` its measurements were sampled at (after the
    step). ``command_read_t``: when the loop read each valid reference from the socket (the
    wall clock at ``recvfrom``; the loop reads once per 4 ms tick, before the step);
    ``command_host_t``: that reference's ``Packet.timestamp`` (the host's send time; NaN when
    unstamped). ``pause_t`` / ``pause_last_command_t``: each motor cut-off (the tick's time) and
    the read time of the reference before it; ``resume_t``: each reference that ended a pause.
    With ``--link``, a reference is "read" when the link releases it to the emulator.
    ``link_{up,down}_outage_start_t`` / ``..._end_t``: the outage windows ``[start, end)`` of
    the car → host (``up``) and host → car (``down``) channels that began before the end of
    the run; ``link_{up,down}_{counter}``: that channel's counters
    (:data:`chronos_bridge.impairment.COUNTERS`).
    """

    def __init__(self, unix_offset: float) -> None:
        self.offset = unix_offset
        self.t: list[float] = []
        self.x: list = []
        self.command_read_t: list[float] = []
        self.command_host_t: list[float] = []
        self.pause_t: list[float] = []
        self.pause_last_command_t: list[float] = []
        self.resume_t: list[float] = []
        self.link: dict[str, object] = {}
        #: With a drift schedule: each changed parameter at every step, by name.
        self.drifted: dict[str, list[float]] = {}

    def record_step(self, stamp: float, x: object, drifted: dict[str, float]) -> None:
        """One step: its stamp, the true base state and the drifted parameters' values."""
        self.t.append(stamp)
        self.x.append(x)
        for name, value in drifted.items():
            self.drifted.setdefault(name, []).append(value)

    def record_link(self, channels: dict[str, ImpairedChannel], until: float) -> None:
        """The outage windows (started before ``until``, the loop's clock) and counters of
        the ``up`` and ``down`` channels."""
        for direction, channel in channels.items():
            windows = channel.outages.windows(until) + self.offset
            self.link[f"link_{direction}_outage_start_t"] = windows[:, 0]
            self.link[f"link_{direction}_outage_end_t"] = windows[:, 1]
            for name, value in channel.counters().items():
                self.link[f"link_{direction}_{name}"] = value

    def write(self, path) -> None:
        import numpy as np

        arrays = {
            "t": np.asarray(self.t, dtype=float),
            "x": np.asarray(self.x, dtype=float).reshape(-1, 6),
            **{
                name: np.asarray(getattr(self, name), dtype=float)
                for name in (
                    "command_read_t",
                    "command_host_t",
                    "pause_t",
                    "pause_last_command_t",
                    "resume_t",
                )
            },
            **{name: np.asarray(value) for name, value in self.link.items()},
            **{f"drift_{name}": np.asarray(v, dtype=float) for name, v in self.drifted.items()},
        }
        partial = path.with_name(path.name + ".partial.npz")
        np.savez(partial, **arrays)
        partial.replace(path)


class _Stop:
    def __init__(self) -> None:
        self.requested = False

    def __call__(self, signum: int, frame: object) -> None:
        self.requested = True


def run(args: argparse.Namespace) -> int:
    """Run the emulator with parsed ``args`` until SIGINT/SIGTERM or ``--duration``."""
    opts = options(args)
    from chronos_bridge.emulator import TICK_S, CarEmulator

    host, bind = opts["host"], opts["bind"]
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind(bind)
    except OSError as error:
        sock.close()
        raise FieldError("--port", f"cannot bind {bind[0]}:{bind[1]} ({error.strerror})") from None
    sock.setblocking(False)
    stop = _Stop()
    previous = {s: signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)}
    start = time.monotonic()
    emulator = CarEmulator(
        model=opts["model"],
        seed=opts["seed"],
        drift=opts["drift"],
        unix_offset=time.time() - start,
        timestamps=opts["timestamps"],
    )
    link = opts["link"]
    up, down = make_link(link, opts["link_seed"], start)
    print(
        f"{PROG}: listening on {bind[0]}:{sock.getsockname()[1]}, sending to {host[0]}:{host[1]}",
        flush=True,
    )
    if args.model is not None or args.params is not None or args.effect or args.drift is not None:
        print(f"{PROG}: car {_describe_car(args)}", file=sys.stderr, flush=True)
    if not (link.up.clean and link.down.clean):
        print(
            f"{PROG}: link car -> host {describe(link.up)}; host -> car {describe(link.down)}; "
            f"link seed {opts['link_seed']}",
            file=sys.stderr,
            flush=True,
        )
    late = skips = send_errors = receive_errors = 0
    log = TruthLog(emulator.unix_offset)
    last_command: list[float | None] = [None]
    pauses = 0
    try:
        next_tick = time.monotonic()
        while not stop.requested:
            now = time.monotonic()
            if opts["duration"] is not None and now - start >= opts["duration"]:
                break
            send_errors += _send(sock, up.due(now), host)
            if now < next_tick:  # sleep until the tick or the next datagram's release
                release = up.next_release()
                wake = next_tick if release is None else min(next_tick, release)
                time.sleep(max(0.0, wake - now))
                continue
            if now - next_tick > MAX_CATCH_UP_S:  # hopelessly behind: re-anchor
                skips += 1
                next_tick = now
            elif now - next_tick > TICK_S:  # late: this and the overdue steps follow at once
                late += 1
            now = next_tick  # the step's own time: one clock for the car, its ticks and stamps
            was_paused = emulator.paused and emulator.commands > 0
            receive_errors += _drain(sock, emulator.rejected, host[0], down, now)
            _deliver(down.due(now), emulator, now, log, last_command)
            if was_paused and not emulator.paused:
                log.resume_t.append(log.command_read_t[-1])
                print(f"{PROG}: references again: drives", file=sys.stderr, flush=True)
            if opts["truth_out"] is not None:  # the car at this tick's stamp, before it steps
                log.record_step(
                    emulator.unix_offset + now, emulator.truth().copy(), emulator.session.drifted
                )
            datagrams = emulator.step(now)
            if emulator.pauses != pauses:
                pauses = emulator.pauses
                t_pause, t_last = emulator.unix_offset + now, last_command[0]
                log.pause_t.append(t_pause)
                log.pause_last_command_t.append(math.nan if t_last is None else t_last)
                gap = f"{1e3 * (t_pause - t_last):.0f} ms" if t_last is not None else "?"
                print(
                    f"{PROG}: no reference for {gap}: motors cut (pause {pauses})",
                    file=sys.stderr,
                    flush=True,
                )
            for datagram in datagrams:
                up.send(datagram, now)
            send_errors += _send(sock, up.due(now), host)
            next_tick += TICK_S
    finally:
        sock.close()
        for s, handler in previous.items():
            signal.signal(s, handler)
        if opts["truth_out"] is not None:
            log.record_link({"up": up, "down": down}, time.monotonic())
            log.write(opts["truth_out"])
    reasons = ", ".join(f"{k} {v}" for k, v in sorted(emulator.rejected.items()))
    print(
        f"{PROG}: stopped after {emulator.steps} steps ({time.monotonic() - start:.1f} s), "
        f"{late} late ticks, {skips} skips, {emulator.commands} commands received, "
        f"{emulator.rejected_total} rejected{f' ({reasons})' if reasons else ''}, "
        f"{emulator.pauses} pauses, {emulator.pings_sent} pings sent, "
        f"{send_errors + receive_errors} socket errors; "
        f"link car -> host: {up.summary()}; host -> car: {down.summary()}",
        flush=True,
    )
    return 0


def _send(sock: socket.socket, datagrams: list[bytes], host: tuple[str, int]) -> int:
    """Send ``datagrams`` to ``host``; the socket errors seen."""
    errors = 0
    for datagram in datagrams:
        try:
            sock.sendto(datagram, host)
        except OSError:
            errors += 1
    return errors


def _drain(
    sock: socket.socket, rejected: dict, host: str, channel: ImpairedChannel, now: float
) -> int:
    """Hand every pending datagram from ``host`` to the host → car ``channel`` at ``now`` (the
    step's scheduled time); others count in ``rejected["source"]``. The socket errors seen."""
    errors = 0
    while True:
        try:
            data, source = sock.recvfrom(RECEIVE_BUFFER)
        except BlockingIOError:
            return errors
        except OSError:  # e.g. ECONNREFUSED from an earlier send; try the next one
            errors += 1
            if errors > 100:
                return errors
            continue
        if source[0] != host:
            rejected["source"] += 1
            continue
        channel.send(data, now)


def _deliver(
    datagrams: list[bytes], emulator, now: float, log: TruthLog, last_command: list
) -> None:
    """Hand the released ``datagrams`` to the emulator at ``now`` (the step's time); each valid
    reference's actual delivery time (for latencies) and host stamp go to ``log``, and the
    step's time to ``last_command[0]``."""
    for data in datagrams:
        commands = emulator.commands
        emulator.receive(data, now)
        if emulator.commands != commands:
            log.command_read_t.append(log.offset + time.monotonic())
            log.command_host_t.append(_host_stamp(data))
            last_command[0] = log.offset + now  # on the emulator's clock, as its timeout counts


def _host_stamp(datagram: bytes) -> float:
    """A valid reference's ``Packet.timestamp`` in s (NaN when it has none)."""
    from chronos_bridge.codec import decode_from_host

    stamp = decode_from_host(datagram).timestamp_us
    return math.nan if stamp is None else stamp * 1e-6


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def main(argv: Sequence[str] | None = None) -> int:
    """``crs car-emulator`` on its own (``python -m chronos_bridge.emulator_process``)."""
    parser = _Parser(prog=PROG, description=DESCRIPTION)
    add_arguments(parser)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exit_:
        return int(exit_.code or 0)
    try:
        return run(args)
    except ValueError as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
