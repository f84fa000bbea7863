"""The ``agf bench`` harness: named benchmark cases, each returning figures.

A case is a function ``run(quick: bool) -> dict`` registered with :func:`bench_case` under a dotted
name and one of the report groups of DESIGN.md (``vision_ms``, ``accuracy``, ``control``). Cases
live next to what they measure, in modules listed under ``bench.modules`` in the configuration (so
driver benchmarks are found without ``agf`` importing ``drivers``).

A case that cannot produce a trustworthy figure raises; the harness reports the error under the
case's name instead of a number.
"""

from __future__ import annotations

import importlib
import statistics
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

GROUPS = ("vision_ms", "accuracy", "control")


@dataclass(frozen=True)
class BenchCase:
    """One registered benchmark case."""

    name: str
    group: str
    run: Callable[[bool], dict[str, Any]]


_REGISTRY: dict[str, BenchCase] = {}


def bench_case(name: str, group: str) -> Callable[[Callable[[bool], dict[str, Any]]], Callable[[bool], dict[str, Any]]]:
    """Register ``run(quick) -> figures`` as the case ``name`` in report group ``group``."""
    if group not in GROUPS:
        raise ValueError(f"bench group must be one of {GROUPS}, got {group!r}")

    def register(run: Callable[[bool], dict[str, Any]]) -> Callable[[bool], dict[str, Any]]:
        _REGISTRY[name] = BenchCase(name, group, run)
        return run

    return register


def timing_summary(samples_s: Iterable[float], scale: float = 1000.0) -> dict[str, float]:
    """Median, p90, min and max of timing samples, scaled (default: seconds to ms)."""
    values = sorted(float(v) * scale for v in samples_s)
    if not values:
        raise ValueError("no timing samples")
    p90 = values[min(len(values) - 1, int(round(0.9 * (len(values) - 1))))]
    return {"median": statistics.median(values), "p90": p90, "min": values[0], "max": values[-1], "n": len(values)}


def time_calls(fn: Callable[[], object], repeats: int, warmup: int = 1) -> list[float]:
    """Wall-clock durations (s) of ``repeats`` calls of ``fn`` after ``warmup`` untimed calls."""
    for _ in range(warmup):
        fn()
    durations = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        durations.append(time.perf_counter() - start)
    return durations


def registered_cases(modules: Iterable[str]) -> dict[str, BenchCase]:
    """Import the case modules and return every registered case by name."""
    for module in modules:
        importlib.import_module(module)
    return dict(_REGISTRY)


def run_bench(modules: Iterable[str], *, quick: bool, only: str | None = None) -> dict[str, dict[str, Any]]:
    """Run the cases (those whose name starts with ``only`` if given) and group their figures."""
    report: dict[str, dict[str, Any]] = {group: {} for group in GROUPS}
    for name, case in sorted(registered_cases(modules).items()):
        if only and not name.startswith(only):
            continue
        try:
            report[case.group][name] = case.run(quick)
        except Exception as exc:  # a failed case is reported, never turned into a number
            report[case.group][name] = {"error": f"{type(exc).__name__}: {exc}"}
    return report
