"""Where and how a benchmark figure was measured: the machine, and per-call timing."""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from crs_core.analysis.statistics import summary

#: The two real Chronos recordings, in the shared data beside the project folder (read-only).
REAL_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "chronos_real"


def machine() -> dict[str, Any]:
    """Where a figure was measured."""
    cpu = platform.processor()
    try:
        with open("/proc/cpuinfo") as info:
            cpu = next(line.split(":", 1)[1].strip() for line in info if "model name" in line)
    except (OSError, StopIteration):
        pass
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "platform": platform.platform(),
    }


def timing(call: Callable[[], object], repeats: int) -> dict[str, float]:
    """Median, p95 and max wall time of ``call`` in microseconds."""
    call()
    samples = np.empty(repeats)
    for k in range(repeats):
        start = time.perf_counter()
        call()
        samples[k] = time.perf_counter() - start
    return {f"{key}_us": value for key, value in summary(samples * 1e6, digits=2).items()}


def format_ms(value: float) -> str:
    """A time for a table (in ms in most, µs in ``crs bench model``'s): 3 significant digits,
    whole units from 1000 on (no exponent)."""
    return f"{value:.3g}" if abs(value) < 1000 else f"{value:.0f}"
