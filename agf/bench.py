"""The ``agf bench`` harness: named benchmark cases, each returning figures.

A case is a function ``run(quick: bool) -> dict`` registered with :func:`bench_case` under a dotted
name and one of the report groups of DESIGN.md (``vision_ms``, ``accuracy``, ``control``). Cases
live next to what they measure, in modules listed under ``bench.modules`` in the configuration (so
driver benchmarks are found without ``agf`` importing ``drivers``).

A case that cannot produce a trustworthy figure raises; the harness reports the error under the
case's name instead of a number.

Timings differ between machines (the same measurement took 137 ms on one 2-core machine and 343 ms
on another), so every run also times a fixed OpenCV + numpy workload, ``machine.reference_ms``, and
reports every timing also as a multiple of it (``x_reference``): figures from two machines compare.
``machine.code_paths`` names the code paths two libraries chose by the CPU (Intel IPP inside OpenCV, OpenBLAS
under numpy), which change last bits and so a few picks' outcomes (docs/campaigns.md): accuracy figures from two
machines compare pick by pick only where those agree.
"""

from __future__ import annotations

import importlib
import os
import statistics
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

GROUPS = ("vision_ms", "accuracy", "control")
# Units of a case's timings, by the suffix of its name or of a figure's key, in ms.
_UNITS_MS = {"ms": 1.0, "s": 1e3, "us": 1e-3}
_STATISTICS = ("median", "p50", "p90", "p99", "min", "max")


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


def reference_workload() -> None:
    """A fixed mix of what the vision spends its time on: a blur, a remap and a Sobel on a 1280 x 1280
    frame, a matrix product and a sort (tens of milliseconds on a 2-core machine)."""
    import cv2
    import numpy as np

    rng = np.random.default_rng(0)
    image = rng.integers(0, 255, (1280, 1280), dtype=np.uint8).astype(np.float32)
    grid = np.indices((1280, 1280), dtype=np.float32)[::-1] * 0.9 + 40.0
    blurred = cv2.GaussianBlur(image, (0, 0), 2.0)
    warped = cv2.remap(blurred, grid[0], grid[1], cv2.INTER_LINEAR)
    cv2.Sobel(warped, cv2.CV_32F, 1, 0, ksize=3)
    matrix = rng.standard_normal((300, 300))
    np.sort((matrix @ matrix.T).ravel())


def machine_reference(repeats: int = 7) -> dict[str, Any]:
    """``reference_ms``: the median time of :func:`reference_workload` on this machine, now."""
    samples = time_calls(reference_workload, repeats=repeats)
    return {"reference_ms": statistics.median(samples) * 1e3, "cores": os.cpu_count()}


def code_paths() -> dict[str, Any]:
    """The CPU-chosen code paths that change last bits: ``opencv_ipp`` (IPP's version and path, or "off"),
    ``openblas`` (the kernels OpenBLAS runs, by library), and the ``OPENCV_IPP`` and ``OPENBLAS_CORETYPE`` the
    environment named (None where it named none)."""
    import cv2
    import numpy as np
    from threadpoolctl import threadpool_info

    np.linalg.lstsq(np.eye(2), np.ones(2), rcond=None)  # OpenBLAS is loaded
    return {
        "opencv": cv2.__version__,
        "opencv_ipp": cv2.ipp.getIppVersion() if cv2.ipp.useIPP() else "off",
        "openblas": {i["filepath"].rsplit("/", 1)[-1]: i.get("architecture") for i in threadpool_info()
                     if i.get("internal_api") == "openblas"},
        "environment": {name: os.environ.get(name) for name in ("OPENCV_IPP", "OPENBLAS_CORETYPE")},
    }


def in_reference_units(name: str, figures: dict[str, Any], reference_ms: float) -> dict[str, Any]:
    """The timing statistics among ``figures`` as multiples of ``reference_ms``, found by unit suffix:
    the case's own name (``pose.ms``, ``render.frame_s``, ``control.sync_jitter_us``) for its statistics,
    a nested figure's key (``timing_ms_median``, ``cycle_s``) for that figure's."""
    out: dict[str, Any] = {}
    scale = _unit_ms(name)
    if scale is not None:
        # Statistics of one timing, or (``timing_ms_median``) one timing per stage.
        keys = [k for k in _STATISTICS if k in figures] or list(figures)
        out |= {k: figures[k] * scale / reference_ms for k in keys if _is_number(figures[k])}
    for key, value in figures.items():
        if isinstance(value, dict) and key != "x_reference":
            nested = in_reference_units(key, value, reference_ms)
            if nested:
                out[key] = nested
    return out


def _unit_ms(name: str) -> float | None:
    for word in reversed(name.replace(".", "_").split("_")):
        if word in _UNITS_MS:
            return _UNITS_MS[word]
    return None


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def run_bench(modules: Iterable[str], *, quick: bool, only: str | None = None) -> dict[str, dict[str, Any]]:
    """Run the cases (those whose name starts with ``only`` if given) and group their figures, with
    ``machine.reference_ms`` timed in the same run and each case's timings in its units (``x_reference``)."""
    report: dict[str, dict[str, Any]] = {group: {} for group in GROUPS}
    machine = machine_reference()
    for name, case in sorted(registered_cases(modules).items()):
        if only and not name.startswith(only):
            continue
        try:
            figures = case.run(quick)
        except Exception as exc:  # a failed case is reported, never turned into a number
            report[case.group][name] = {"error": f"{type(exc).__name__}: {exc}"}
            continue
        relative = in_reference_units(name, figures, machine["reference_ms"])
        report[case.group][name] = figures | ({"x_reference": relative} if relative else {})
    # Timed again at the end: a machine whose speed changed during the run (another load) shows it here.
    after = machine_reference()["reference_ms"]
    report["machine"] = machine | {"reference_ms_after": after, "code_paths": code_paths()}
    return report
