"""A Wi-Fi-like link between a Chronos car and its host: loss, delay, reordering, duplicates
and outages, seeded (ROS-free and transport-free; :mod:`chronos_bridge.emulator_process`
puts it between the car emulator and its socket).

One :class:`ImpairedChannel` per direction: ``up`` is car → host (the car's Wi-Fi uplink),
``down`` host → car. A datagram handed to :meth:`ImpairedChannel.send` at time ``now`` goes
through, in this order:

1. **outage**: sent while the link is out, it is lost (counted ``lost_outage``);
2. **loss** (Gilbert–Elliott): the channel is in a *good* or a *bad* state, which changes once
   per datagram (good → bad with probability ``burst_enter``, bad → good with ``burst_exit``)
   before the datagram's loss is drawn: with probability ``loss`` in the good state (counted
   ``lost_random``) and ``burst_loss`` in the bad one (``lost_burst``). With ``burst_enter = 0``
   the loss is independent (Bernoulli ``loss``). In the stationary regime the bad state holds
   a fraction ``π_bad = burst_enter / (burst_enter + burst_exit)`` of the datagrams, the mean
   loss is ``(1 - π_bad) · loss + π_bad · burst_loss`` (:meth:`ImpairmentSettings.mean_loss`)
   and a stay in the bad state lasts ``1 / burst_exit`` datagrams on average (geometric; with
   ``burst_loss = 1`` and ``loss = 0`` that is the mean length of a run of lost datagrams,
   :meth:`ImpairmentSettings.mean_burst_length`). Bursts count datagrams, not seconds: at
   250 Hz (car → host) a 4-datagram burst is 16 ms;
3. **delay**: ``delay_s + |N(0, jitter_s)|`` (a half-normal jitter of scale ``jitter_s``,
   mean ``0.80 · jitter_s``), drawn independently per datagram, so datagrams sent closer than
   their jitter apart overtake each other. With ``in_order`` a datagram never leaves before the
   one sent before it (head-of-line blocking: its release is at least the previous release);
4. a datagram whose release time falls in an outage is lost too (``lost_outage``), so nothing
   is ever released during an outage;
5. **duplication**: with probability ``dup`` a second copy is scheduled with its own delay
   (steps 3 and 4); ``duplicated`` counts them.

Outages: windows of ``outage_s``, either periodic (starting ``outage_phase_s`` after the
channel's start, then every ``outage_period_s``) or random (a gap drawn exponential with mean
``1 / outage_rate_hz`` before each window, so a fraction ``outage_s / (outage_s + 1 /
outage_rate_hz)`` of the time is out). :func:`make_link` gives both directions one schedule
when their outage settings are equal (a Wi-Fi outage cuts both ways at once).

Every draw comes from a :class:`numpy.random.Generator`: a channel is a pure function of its
seed and the sequence of calls. Times are in s on the caller's clock.
"""

from __future__ import annotations

import bisect
import heapq
import math
import re
from dataclasses import dataclass, fields, replace

import numpy as np

from crs_core.errors import FieldError, parse_finite
from crs_core.settings import Settings, within

#: The preset names of :data:`PRESETS`, in order of severity (a benchmark iterates over them).
PRESET_NAMES = ("clean", "typical", "bad", "outages")
#: Largest delay, jitter, outage or period accepted, s.
MAX_TIME_S = 3600.0


def _probability(default: float) -> float:
    """A field that is a probability, [0, 1]."""
    return within(default, low=0.0, high=1.0)


def _time(default: float) -> float:
    """A field that is a time, [0, :data:`MAX_TIME_S`] s."""
    return within(default, low=0.0, high=MAX_TIME_S, unit="s")


@dataclass(frozen=True)
class ImpairmentSettings(Settings):
    """One direction's impairment (see the module docstring for the order they act in).

    Attributes
    ----------
    loss : float
        Loss probability per datagram in the good state, [0, 1]; the independent loss when
        ``burst_enter`` is 0.
    burst_enter : float
        Gilbert–Elliott probability per datagram of going from the good to the bad state, [0, 1].
    burst_exit : float
        Probability per datagram of going from the bad to the good state, (0, 1] when
        ``burst_enter > 0``; a stay in the bad state lasts ``1 / burst_exit`` datagrams on
        average.
    burst_loss : float
        Loss probability per datagram in the bad state, [0, 1].
    delay_s : float
        Fixed part of every datagram's delay, s (>= 0).
    jitter_s : float
        Scale σ of the half-normal jitter ``|N(0, σ)|`` added to each datagram's delay
        independently, s (>= 0; mean 0.80 σ, median 0.67 σ, p95 1.96 σ).
    in_order : bool
        Head-of-line blocking: a datagram is never released before the previous one (no
        reordering; the jitter then delays the datagrams behind a late one).
    dup : float
        Probability that a delivered datagram is delivered twice, [0, 1]; the copy has its own
        delay.
    outage_s : float
        Length of each outage, s (>= 0; 0: none); every datagram sent or due during one is lost.
    outage_period_s : float
        Time between the starts of periodic outages, s (> ``outage_s``; 0: not periodic).
    outage_phase_s : float
        Start of the first periodic outage after the channel's start, s (>= 0).
    outage_rate_hz : float
        Random outages instead: rate of the exponential gaps between outages, 1/s (0: none).
    """

    loss: float = _probability(0.0)
    burst_enter: float = _probability(0.0)
    burst_exit: float = _probability(1.0)
    burst_loss: float = _probability(1.0)
    delay_s: float = _time(0.0)
    jitter_s: float = _time(0.0)
    in_order: bool = False
    dup: float = _probability(0.0)
    outage_s: float = _time(0.0)
    outage_period_s: float = _time(0.0)
    outage_phase_s: float = _time(0.0)
    outage_rate_hz: float = within(0.0, low=0.0, high=1e3)

    def _check_relations(self) -> None:
        if self.burst_enter > 0 and self.burst_exit == 0:
            raise FieldError(
                "burst_exit", "must be > 0 when burst_enter > 0 (else bursts never end)"
            )
        periodic, random = self.outage_period_s > 0, self.outage_rate_hz > 0
        if self.outage_s > 0 and periodic == random:
            raise FieldError("outage_s", "needs either outage_period_s or outage_rate_hz (one)")
        if self.outage_s == 0 and (periodic or random):
            raise FieldError("outage_s", "must be > 0 with outage_period_s or outage_rate_hz")
        if periodic and self.outage_period_s <= self.outage_s:
            raise FieldError(
                "outage_period_s",
                f"{self.outage_period_s:g} s must exceed outage_s {self.outage_s:g} s",
            )

    @property
    def clean(self) -> bool:
        """True when this direction changes nothing (no loss, delay, duplicate or outage)."""
        return not (self.mean_loss() or self.delay_s or self.jitter_s or self.dup or self.outage_s)

    def mean_loss(self) -> float:
        """Stationary loss probability per datagram outside outages (see the module docstring)."""
        if self.burst_enter == 0:
            return self.loss
        bad = self.burst_enter / (self.burst_enter + self.burst_exit)
        return (1.0 - bad) * self.loss + bad * self.burst_loss

    def mean_burst_length(self) -> float:
        """Mean number of consecutive datagrams in the bad state (``1 / burst_exit``)."""
        return 1.0 / self.burst_exit if self.burst_enter > 0 else 0.0

    def outages(self) -> tuple[float, float, float, float]:
        """The outage settings alone (length, period, phase, rate): equal tuples, one schedule."""
        return (self.outage_s, self.outage_period_s, self.outage_phase_s, self.outage_rate_hz)


CLEAN = ImpairmentSettings()
#: Burst entry of ``bad``: 8 % mean loss with 4-datagram bursts (π_bad = 0.08, burst_exit 0.25).
_BAD_ENTER = 0.08 * 0.25 / 0.92

#: Named impairments (both directions alike): ``typical`` Wi-Fi, 2 % independent loss and
#: 4 ms + |N(0, 3 ms)| in order; ``bad`` Wi-Fi, 8 % loss in bursts of 4 datagrams on average,
#: 15 ms + |N(0, 10 ms)| reordering, 1 % duplicates; ``outages``: 300 ms every 5 s (the first
#: 5 s after the start), clean otherwise.
PRESETS: dict[str, ImpairmentSettings] = {
    "clean": CLEAN,
    "typical": ImpairmentSettings(loss=0.02, delay_s=0.004, jitter_s=0.003, in_order=True),
    "bad": ImpairmentSettings(
        burst_enter=_BAD_ENTER,
        burst_exit=0.25,
        burst_loss=1.0,
        delay_s=0.015,
        jitter_s=0.010,
        dup=0.01,
    ),
    "outages": ImpairmentSettings(outage_s=0.3, outage_period_s=5.0, outage_phase_s=5.0),
}


@dataclass(frozen=True)
class LinkSettings:
    """Both directions: ``up`` car → host, ``down`` host → car."""

    up: ImpairmentSettings = CLEAN
    down: ImpairmentSettings = CLEAN


#: Keys of a spec (:func:`parse_spec`): key -> (field, kind); kinds: ``p`` a probability
#: (``0.03`` or ``3%``), ``t`` a time with its unit (``3ms``, ``0.3s``), ``hz`` a rate in 1/s
#: (``0.2``, ``0.2/s`` or ``0.2hz``), ``bool`` (``1``/``0``/``true``/``false``).
SPEC_KEYS: dict[str, tuple[str, str]] = {
    "loss": ("loss", "p"),
    "burst_enter": ("burst_enter", "p"),
    "burst_exit": ("burst_exit", "p"),
    "burst_loss": ("burst_loss", "p"),
    "delay": ("delay_s", "t"),
    "jitter": ("jitter_s", "t"),
    "in_order": ("in_order", "bool"),
    "dup": ("dup", "p"),
    "outage": ("outage_s", "t"),
    "outage_every": ("outage_period_s", "t"),
    "outage_phase": ("outage_phase_s", "t"),
    "outage_rate": ("outage_rate_hz", "hz"),
}
#: The spec's ``--help`` text (argparse: ``%%`` is a percent sign).
SPEC_HELP = (
    f"a preset ({', '.join(PRESET_NAMES)}) and/or KEY=VALUE,... overriding it (from clean "
    "without one), e.g. 'loss=3%%,delay=3ms,jitter=5ms,dup=0.5%%' or 'bad,outage=300ms,"
    "outage_every=5s'; keys: loss, burst_enter, burst_exit, burst_loss, dup (probabilities), "
    "delay, jitter, outage, outage_every, outage_phase (with ms or s), outage_rate (1/s), "
    "in_order (0/1); delay = delay + |N(0, jitter)| per datagram"
)


def _value(key: str, kind: str, text: str) -> float | bool:
    lower = text.strip().lower()
    if kind == "bool":
        if lower in ("1", "true", "yes", "on"):
            return True
        if lower in ("0", "false", "no", "off"):
            return False
        raise FieldError(key, f"{text!r} is not 0/1/true/false")
    scale, number = 1.0, lower
    if kind == "p" and lower.endswith("%"):
        scale, number = 0.01, lower[:-1]
    elif kind == "t":
        for unit, factor in (("ms", 1e-3), ("s", 1.0)):
            if lower.endswith(unit):
                scale, number = factor, lower[: -len(unit)]
                break
        else:
            raise FieldError(key, f"{text!r} needs a unit (ms or s)")
    elif kind == "hz":
        for unit in ("/s", "hz"):
            number = number.removesuffix(unit)
    value = parse_finite(number)
    if value is None:
        raise FieldError(key, f"{text!r} is not a number")
    return value * scale


def parse_spec(text: str) -> ImpairmentSettings:
    """``PRESET``, ``KEY=VALUE,...`` or ``PRESET,KEY=VALUE,...`` (:data:`SPEC_HELP`) -> checked
    settings; ``ValueError`` naming the key (``delay: '3' needs a unit (ms or s)``)."""
    parts = [part.strip() for part in text.split(",") if part.strip()]
    if not parts:
        raise ValueError(f"{text!r} is empty: give a preset or KEY=VALUE")
    settings = CLEAN
    if "=" not in parts[0]:
        if parts[0] not in PRESETS:
            raise ValueError(
                f"{parts[0]!r} is not a preset ({', '.join(PRESET_NAMES)}) or KEY=VALUE"
            )
        settings = PRESETS[parts.pop(0)]
    changes: dict[str, float | bool] = {}
    for part in parts:
        key, sep, value = (s.strip() for s in part.partition("="))
        if not sep:
            raise ValueError(f"{part!r} is not KEY=VALUE (a preset comes first)")
        if key not in SPEC_KEYS:
            raise FieldError(key, f"not a key (keys: {', '.join(SPEC_KEYS)})")
        if SPEC_KEYS[key][0] in changes:
            raise FieldError(key, "given twice")
        field_name, kind = SPEC_KEYS[key]
        changes[field_name] = _value(key, kind, value)
    try:
        return replace(settings, **changes)  # checked when built
    except FieldError as error:  # name the spec's keys, not the fields
        keys = {f: k for k, (f, _) in SPEC_KEYS.items()}
        reason = re.sub(r"\b\w+\b", lambda m: keys.get(m.group(), m.group()), error.reason)
        raise FieldError(keys.get(error.field, error.field), reason) from None


def parse_link(both: str | None, up: str | None = None, down: str | None = None) -> LinkSettings:
    """``--link`` (both directions), ``--link-up`` (car → host) and ``--link-down`` (host →
    car; each overrides ``--link`` for its direction) -> :class:`LinkSettings`; ``ValueError``
    prefixed with the option (``--link-up: dup: 'x' is not a number``)."""
    settings = {}
    for option, text in (("--link", both), ("--link-up", up), ("--link-down", down)):
        if text is not None:
            try:
                settings[option] = parse_spec(text)
            except ValueError as error:
                raise FieldError(option, str(error)) from None
    default = settings.get("--link", CLEAN)
    return LinkSettings(settings.get("--link-up", default), settings.get("--link-down", default))


class OutageSchedule:
    """The outage windows ``[start, end)`` (s) of :class:`ImpairmentSettings`, from ``start``
    on, drawn lazily (random ones from ``rng``) so one schedule can serve both directions."""

    def __init__(
        self, settings: ImpairmentSettings, rng: np.random.Generator, start: float = 0.0
    ) -> None:
        self.settings = settings  # checked when built (frozen)
        self._rng = rng
        self._next = start + (settings.outage_phase_s if settings.outage_period_s > 0 else 0.0)
        self.starts: list[float] = []
        self.ends: list[float] = []

    def _extend(self, until: float) -> None:
        s = self.settings
        while s.outage_s > 0 and self._next <= until:
            begin = self._next
            if s.outage_rate_hz > 0:
                begin += self._rng.exponential(1.0 / s.outage_rate_hz)
                self._next = begin + s.outage_s
            else:
                self._next = begin + s.outage_period_s
            self.starts.append(begin)
            self.ends.append(begin + s.outage_s)

    def covers(self, t: float) -> bool:
        """True while the link is out at ``t``."""
        self._extend(t)
        i = bisect.bisect_right(self.starts, t) - 1
        return i >= 0 and t < self.ends[i]

    def windows(self, until: float) -> np.ndarray:
        """``(n, 2)`` ``[start, end)`` of every outage starting before ``until``, s."""
        self._extend(until)
        n = bisect.bisect_left(self.starts, until)
        return np.column_stack([self.starts[:n], self.ends[:n]]).reshape(-1, 2)


#: The counters of :class:`ImpairedChannel`, in the order :meth:`~ImpairedChannel.summary` names.
COUNTERS = (
    "sent",
    "lost_random",
    "lost_burst",
    "lost_outage",
    "duplicated",
    "reordered",
    "delivered",
)


class ImpairedChannel:
    """One direction of the link: :meth:`send` schedules 0, 1 or 2 copies, :meth:`due`
    releases them (module docstring).

    Parameters
    ----------
    settings : ImpairmentSettings
        Validated here.
    rng : numpy.random.Generator
        Every per-datagram draw; the outage schedule, unless given, draws from a child of it.
    start : float
        Time the periodic outages count from, s.
    outages : OutageSchedule, optional
        A schedule shared with the other direction (:func:`make_link`).

    Counters (attributes): ``sent``, ``lost_random``, ``lost_burst``, ``lost_outage``,
    ``duplicated`` (extra copies scheduled), ``reordered`` (copies released while a datagram
    sent earlier was still waiting for a later release), ``delivered`` (copies released).
    """

    def __init__(
        self,
        settings: ImpairmentSettings,
        rng: np.random.Generator,
        start: float = 0.0,
        outages: OutageSchedule | None = None,
    ) -> None:
        self.settings = settings  # checked when built (frozen)
        self._rng = rng
        self.outages = outages or OutageSchedule(settings, rng.spawn(1)[0], start)
        self._bad = False
        self._heap: list[tuple[float, int, bool, bytes]] = []
        self._sequence = 0
        self._last_release = -math.inf  # of the previous datagram (head-of-line)
        self._latest_release = -math.inf  # of any copy scheduled so far
        for name in COUNTERS:
            setattr(self, name, 0)

    @property
    def lost(self) -> int:
        """Datagrams lost for any reason."""
        return self.lost_random + self.lost_burst + self.lost_outage

    def send(self, datagram: bytes, now: float) -> None:
        """Hand ``datagram`` to the link at ``now`` (s): lost, or scheduled once or twice."""
        s, rng = self.settings, self._rng
        self.sent += 1
        if self.outages.covers(now):
            self.lost_outage += 1
            return
        if s.burst_enter > 0:
            self._bad = rng.random() < (1.0 - s.burst_exit if self._bad else s.burst_enter)
        p = s.burst_loss if self._bad else s.loss
        if p > 0 and rng.random() < p:
            if self._bad:
                self.lost_burst += 1
            else:
                self.lost_random += 1
            return
        earlier = self._latest_release
        if not self._schedule(datagram, now, earlier):
            self.lost_outage += 1
            return
        if s.dup > 0 and rng.random() < s.dup and self._schedule(datagram, now, earlier):
            self.duplicated += 1

    def _schedule(self, datagram: bytes, now: float, earlier: float) -> bool:
        """One copy; False when its release falls in an outage. ``earlier``: the latest
        release of the datagrams sent before this one."""
        s = self.settings
        release = now + s.delay_s
        if s.jitter_s > 0:
            release += abs(self._rng.normal(0.0, s.jitter_s))
        if s.in_order:
            release = max(release, self._last_release)
        if self.outages.covers(release):
            return False
        self._last_release = max(self._last_release, release)
        self._latest_release = max(self._latest_release, release)
        self._sequence += 1
        heapq.heappush(self._heap, (release, self._sequence, release < earlier, datagram))
        return True

    def next_release(self) -> float | None:
        """The earliest pending release time, s (None: nothing pending)."""
        return self._heap[0][0] if self._heap else None

    def due(self, now: float) -> list[bytes]:
        """The copies whose release time is ``<= now``, in release order."""
        out = []
        while self._heap and self._heap[0][0] <= now:
            _, _, reordered, datagram = heapq.heappop(self._heap)
            self.reordered += reordered
            self.delivered += 1
            out.append(datagram)
        return out

    def counters(self) -> dict[str, int]:
        """Every counter by name (:data:`COUNTERS`)."""
        return {name: getattr(self, name) for name in COUNTERS}

    def summary(self) -> str:
        """``sent 500, lost 40 (random 0, burst 38, outage 2), duplicated 5, reordered 31,
        delivered 465``."""
        return (
            f"sent {self.sent}, lost {self.lost} (random {self.lost_random}, burst "
            f"{self.lost_burst}, outage {self.lost_outage}), duplicated {self.duplicated}, "
            f"reordered {self.reordered}, delivered {self.delivered}"
        )


def make_link(
    link: LinkSettings, seed: int, start: float = 0.0
) -> tuple[ImpairedChannel, ImpairedChannel]:
    """The ``(up, down)`` channels of ``link`` from one seed (independent child streams of
    ``numpy.random.SeedSequence(seed)``, so not the streams of ``default_rng(seed)``); one
    outage schedule for both when their outage settings are equal."""
    outage_seq, up_seq, down_seq = np.random.SeedSequence(seed).spawn(3)
    shared = None
    if link.up.outages() == link.down.outages():
        shared = OutageSchedule(link.up, np.random.default_rng(outage_seq), start)
    up = ImpairedChannel(link.up, np.random.default_rng(up_seq), start, shared)
    down = ImpairedChannel(link.down, np.random.default_rng(down_seq), start, shared)
    return up, down


def describe(settings: ImpairmentSettings) -> str:
    """The non-default fields, ``key=value`` (``clean`` when none)."""
    changed = [
        f"{f.name}={getattr(settings, f.name):g}"
        for f in fields(settings)
        if getattr(settings, f.name) != f.default
    ]
    return ",".join(changed) or "clean"
