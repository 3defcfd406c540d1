"""The Wi-Fi-like link impairment: statistics against the analytic values (fixed seeds),
outage timing, determinism, the spec parser and the presets."""

from __future__ import annotations

import math
import re
import struct
from dataclasses import replace

import numpy as np
import pytest
from scipy import integrate, stats

from chronos_bridge.impairment import (
    CLEAN,
    PRESET_NAMES,
    PRESETS,
    ImpairedChannel,
    ImpairmentSettings,
    LinkSettings,
    make_link,
    parse_link,
    parse_spec,
)
from crs_core.errors import FieldError

N = 50_000
DT = 0.004  # 250 Hz, as the car's CarStates


def channel(seed: int = 1, **settings) -> ImpairedChannel:
    return ImpairedChannel(ImpairmentSettings(**settings), np.random.default_rng(seed))


def pump(ch: ImpairedChannel, n: int = N, dt: float = DT, t0: float = 0.0):
    """Send datagrams ``0 .. n-1`` (their index, 4 bytes) every ``dt`` s from ``t0`` and collect
    every release at its exact time: ``(send times, released indices, release times)``."""
    sent = t0 + dt * np.arange(n)
    index, released = [], []

    def collect(until: float) -> None:
        while (t := ch.next_release()) is not None and t <= until:
            for datagram in ch.due(t):
                index.append(struct.unpack("<I", datagram)[0])
                released.append(t)

    for i, t in enumerate(sent):
        collect(t)
        ch.send(struct.pack("<I", i), t)
    collect(math.inf)
    return sent, np.array(index, dtype=int), np.array(released)


def loss_runs(lost: np.ndarray) -> np.ndarray:
    """Lengths of the runs of consecutive ``True``."""
    edges = np.diff(np.concatenate([[0], lost.astype(int), [0]]))
    return np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)


def test_independent_loss_rate_and_no_memory() -> None:
    ch = channel(loss=0.05)
    _, index, _ = pump(ch)
    lost = np.ones(N, dtype=bool)
    lost[index] = False
    sigma = math.sqrt(0.05 * 0.95 / N)
    assert abs(lost.mean() - 0.05) < 4 * sigma
    assert ch.lost_random == ch.lost == lost.sum() and ch.lost_burst == 0
    after_loss = lost[1:][lost[:-1]]  # no bursts: P(lost | previous lost) = P(lost)
    assert abs(after_loss.mean() - 0.05) < 4 * math.sqrt(0.05 * 0.95 / after_loss.size)
    assert ch.delivered == index.size == N - ch.lost and ch.reordered == ch.duplicated == 0


def test_gilbert_elliott_stationary_loss_and_mean_burst_length() -> None:
    bad = PRESETS["bad"]
    ch = ImpairedChannel(replace(bad, delay_s=0.0, jitter_s=0.0, dup=0.0), np.random.default_rng(2))
    n = 100_000
    _, index, _ = pump(ch, n)
    lost = np.ones(n, dtype=bool)
    lost[index] = False
    p, r = bad.burst_enter, bad.burst_exit
    pi_bad = p / (p + r)
    assert pi_bad == pytest.approx(0.08) and bad.mean_loss() == pytest.approx(0.08)
    # variance of a two-state Markov chain's mean: pi(1-pi)(1+lambda)/(1-lambda) / n
    lam = 1 - p - r
    sigma = math.sqrt(pi_bad * (1 - pi_bad) * (1 + lam) / (1 - lam) / n)
    assert abs(lost.mean() - 0.08) < 4 * sigma
    runs = loss_runs(lost)  # geometric with mean 1 / r = 4 (loss 0 in good, 1 in bad)
    assert bad.mean_burst_length() == 4.0
    assert abs(runs.mean() - 4.0) < 4 * math.sqrt(1 - r) / r / math.sqrt(runs.size)
    assert abs(np.mean(runs == 1) - r) < 4 * math.sqrt(r * (1 - r) / runs.size)
    assert ch.lost_burst == lost.sum() and ch.lost_random == 0


def test_gilbert_elliott_with_loss_in_both_states() -> None:
    settings = ImpairmentSettings(loss=0.01, burst_enter=0.05, burst_exit=0.2, burst_loss=0.5)
    assert settings.mean_loss() == pytest.approx(0.8 * 0.01 + 0.2 * 0.5)
    ch = ImpairedChannel(settings, np.random.default_rng(3))
    n = 100_000
    for k in range(n):
        ch.send(b"x", k * DT)
    lam = 1 - 0.05 - 0.2
    sigma_bad = math.sqrt(0.2 * 0.8 * (1 + lam) / (1 - lam) / n)  # of the bad-state share
    assert abs(ch.lost_burst / n - 0.2 * 0.5) < 4 * (0.5 * sigma_bad + math.sqrt(0.1 / n))
    assert abs(ch.lost_random / n - 0.8 * 0.01) < 4 * (0.01 * sigma_bad + math.sqrt(0.008 / n))


def test_delay_is_base_plus_half_normal_jitter() -> None:
    ch = channel(seed=4, delay_s=0.004, jitter_s=0.003)
    sent, index, released = pump(ch)
    delays = released - sent[index]
    assert index.size == N and np.all(np.diff(released) >= 0)  # released in release order
    reference = stats.halfnorm(loc=0.004, scale=0.003)
    assert stats.kstest(delays, reference.cdf).pvalue > 1e-3
    for q in (0.05, 0.5, 0.95, 0.99):
        x = reference.ppf(q)
        standard_error = math.sqrt(q * (1 - q) / N) / reference.pdf(x)
        assert abs(np.quantile(delays, q) - x) < 4 * standard_error, q
    assert delays.min() >= 0.004


def test_jitter_reorders_as_the_analytic_probability_and_in_order_never() -> None:
    sigma, base = 0.010, 0.015
    ch = channel(seed=5, delay_s=base, jitter_s=sigma)
    _, index, _ = pump(ch)
    # independent count: a release is reordered when an earlier-sent index is released later
    suffix_min = np.minimum.accumulate(index[::-1])[::-1]
    later_min = np.append(suffix_min[1:], np.iinfo(int).max)
    assert ch.reordered == int(np.sum(later_min < index))
    # P(reordered) = 1 - E_J[prod_k F(J + k dt)], J, J_k iid |N(0, sigma)|
    half = stats.halfnorm(scale=sigma)
    k = np.arange(1, 40)
    in_order, _ = integrate.quad(
        lambda j: half.pdf(j) * np.prod(half.cdf(j + k * DT)), 0, 10 * sigma
    )
    assert abs(ch.reordered / N - (1 - in_order)) < 0.015
    assert 0.2 < ch.reordered / N < 0.6

    blocked = channel(seed=5, delay_s=base, jitter_s=sigma, in_order=True)
    sent, index, released = pump(blocked)
    assert blocked.reordered == 0 and np.all(np.diff(index) > 0) and index.size == N
    assert np.all(released - sent >= base)


def test_duplicates_have_their_own_delay_and_each_copy_is_released_once() -> None:
    ch = channel(seed=6, dup=0.05, loss=0.02, delay_s=0.001, jitter_s=0.005)
    _, index, released = pump(ch)
    assert abs(ch.duplicated / N - 0.98 * 0.05) < 4 * math.sqrt(0.05 / N)
    counts = np.bincount(index, minlength=N)
    assert counts.max() == 2 and np.sum(counts == 2) == ch.duplicated
    assert ch.delivered == index.size == N - ch.lost + ch.duplicated
    assert ch.next_release() is None and ch.due(math.inf) == []
    twice = np.flatnonzero(counts == 2)
    times = {i: released[index == i] for i in twice[:200]}
    assert all(t[0] != t[1] for t in times.values())  # each copy drew its own jitter


@pytest.mark.parametrize("delay", [0.0, 0.02])
def test_periodic_outages_drop_exactly_what_is_sent_or_due_inside(delay: float) -> None:
    settings = ImpairmentSettings(
        delay_s=delay, outage_s=0.3, outage_period_s=1.0, outage_phase_s=0.5
    )
    ch = ImpairedChannel(settings, np.random.default_rng(7), start=2.0)
    # 2 .. 12 s, every ms, half a ms off the windows' edges (floats, exactly)
    sent, index, released = pump(ch, n=10_000, dt=0.001, t0=2.0005)
    windows = ch.outages.windows(12.0)
    expected_starts = 2.5 + np.arange(10)
    np.testing.assert_allclose(windows, np.column_stack([expected_starts, expected_starts + 0.3]))

    def out(t: np.ndarray) -> np.ndarray:
        phase = (t - 2.5) % 1.0
        return (t >= 2.5) & (phase < 0.3)

    assert not np.any(out(released))
    kept = ~out(sent) & ~out(sent + delay)
    np.testing.assert_array_equal(index, np.flatnonzero(kept))
    assert ch.lost_outage == ch.lost == np.sum(~kept)


def test_random_outages_have_exponential_gaps() -> None:
    settings = ImpairmentSettings(outage_s=0.2, outage_rate_hz=0.5)
    ch = ImpairedChannel(settings, np.random.default_rng(8))
    windows = ch.outages.windows(4000.0)
    np.testing.assert_allclose(windows[:, 1] - windows[:, 0], 0.2)
    gaps = windows[1:, 0] - windows[:-1, 1]
    assert abs(gaps.mean() - 2.0) < 4 * 2.0 / math.sqrt(gaps.size)
    assert stats.kstest(gaps, stats.expon(scale=2.0).cdf).pvalue > 1e-3
    assert ch.outages.covers(windows[3, 0] + 0.1) and not ch.outages.covers(windows[3, 1])


def test_both_directions_share_one_outage_schedule_when_alike() -> None:
    random = ImpairmentSettings(outage_s=0.2, outage_rate_hz=1.0)
    up, down = make_link(LinkSettings(random, replace(random, loss=0.1)), seed=3)
    assert up.outages is down.outages
    up, down = make_link(LinkSettings(random, CLEAN), seed=3)
    assert up.outages is not down.outages and down.outages.windows(100.0).size == 0


def test_a_channel_is_a_function_of_its_seed_and_calls() -> None:
    def run(seed: int):
        up, _ = make_link(parse_link("bad,outage=100ms,outage_rate=1"), seed)
        _, index, released = pump(up, n=5000)
        return index, released, up.counters(), up.outages.windows(30.0)

    first, again, other = run(11), run(11), run(12)
    for i in (0, 1, 3):
        np.testing.assert_array_equal(first[i], again[i])
    assert first[2] == again[2] and first[2] != other[2]
    assert first[3].shape != other[3].shape or not np.array_equal(first[3], other[3])


def test_presets() -> None:
    assert PRESET_NAMES == tuple(PRESETS) == ("clean", "typical", "bad", "outages")
    assert PRESETS["clean"].clean and not any(PRESETS[n].clean for n in PRESET_NAMES[1:])
    typical = PRESETS["typical"]
    assert (typical.mean_loss(), typical.delay_s, typical.jitter_s) == (0.02, 0.004, 0.003)
    assert typical.in_order and typical.burst_enter == 0 and typical.dup == 0
    bad = PRESETS["bad"]
    assert bad.mean_loss() == pytest.approx(0.08) and bad.mean_burst_length() == 4.0
    assert (bad.delay_s, bad.jitter_s, bad.dup, bad.in_order) == (0.015, 0.010, 0.01, False)
    outages = PRESETS["outages"]
    assert (outages.outage_s, outages.outage_period_s) == (0.3, 5.0)
    assert replace(outages, outage_s=0, outage_period_s=0, outage_phase_s=0) == CLEAN
    for name in PRESET_NAMES:
        assert parse_link(name) == LinkSettings(PRESETS[name], PRESETS[name])


def test_spec_parser() -> None:
    spec = parse_spec("loss=0.03,delay=3ms,jitter=5ms,dup=0.5%")
    assert spec == ImpairmentSettings(loss=0.03, delay_s=0.003, jitter_s=0.005, dup=0.005)
    assert parse_spec("bad,in_order=1,outage=0.3s,outage_rate=0.2/s") == replace(
        PRESETS["bad"], in_order=True, outage_s=0.3, outage_rate_hz=0.2
    )
    link = parse_link("typical", up="clean", down=None)
    assert link == LinkSettings(CLEAN, PRESETS["typical"])
    assert parse_link(None) == LinkSettings(CLEAN, CLEAN)


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("delay=3", "delay: '3' needs a unit (ms or s)"),
        ("jitter=-1ms", "jitter: must be within [0, 3600] s, got -0.001"),
        ("loss=1.5", "loss: must be within [0, 1], got 1.5"),
        ("outage=1s,outage_rate=2000", "outage_rate: must be within [0, 1000], got 2000.0"),
        ("dup=x", "dup: 'x' is not a number"),
        ("in_order=maybe", "in_order: 'maybe' is not 0/1/true/false"),
        ("wifi=1", "wifi: not a key (keys: loss, "),
        ("loss=1%,loss=2%", "loss: given twice"),
        ("outage=300ms", "outage: needs either outage_every or outage_rate (one)"),
        ("outage=1s,outage_every=0.5s", "outage_every: 0.5 s must exceed outage 1 s"),
        ("burst_enter=0.1,burst_exit=0", "burst_exit: must be > 0 when burst_enter > 0"),
        ("bda", "'bda' is not a preset (clean, typical, bad, outages) or KEY=VALUE"),
    ],
)
def test_spec_errors_name_the_key(spec: str, message: str) -> None:
    with pytest.raises(ValueError, match="^" + re.escape(message)) as error:
        parse_spec(spec)
    if not message.startswith("'"):  # a key (not a preset) is wrong: the error's field
        assert isinstance(error.value, FieldError)
        assert error.value.field == message.split(":")[0]
    with pytest.raises(FieldError, match="^" + re.escape(f"--link-down: {message}")) as error:
        parse_link("clean", down=spec)
    assert error.value.field == "--link-down"


def test_settings_are_checked_when_built_naming_the_field() -> None:
    with pytest.raises(
        FieldError, match=r"^jitter_s: must be within \[0, 3600\] s, got nan$"
    ) as error:
        ImpairmentSettings(jitter_s=math.nan)
    assert error.value.field == "jitter_s"
    with pytest.raises(FieldError, match=r"^outage_rate_hz: ") as error:
        ImpairmentSettings(outage_s=0.1, outage_rate_hz=-1.0)
    assert error.value.field == "outage_rate_hz"
    with pytest.raises(FieldError, match=r"^outage_s: must be > 0 with") as error:
        ImpairmentSettings(outage_period_s=5.0)
    assert error.value.field == "outage_s"
    with pytest.raises(FieldError, match=r"^dup: must be within \[0, 1\], got 2$"):
        replace(CLEAN, dup=2)
