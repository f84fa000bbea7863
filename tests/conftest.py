"""Every test process (the xdist workers too) keeps the memory it frees, as ``agf``'s command line does
(:mod:`agf.heap`): the suite's frames would otherwise fault their pages in again and again.

And on a CPU with AVX-512, OpenBLAS runs its SkylakeX kernels, whatever the environment names. The regression tests
of campaign picks hold the frames and measurements of the machines they were found on, to the last bit, and numpy's
linear algebra (least squares) rounds by OpenBLAS's kernel: the machine of session 68 (AMD EPYC, AVX-512) set
OPENBLAS_CORETYPE=Haswell in its environment, and four of those tests measured otherwise there; with the SkylakeX
kernels, which OpenBLAS picks by itself on such a CPU, every test passes as where it was written. OpenBLAS reads
the variable when numpy loads it, so this comes before any import of numpy (pytest and its plugins import none).
Intel IPP, inside OpenCV, picks its path by the CPU too: its AVX-512 path is the one those machines took; a machine
without AVX-512 (session 51's) draws campaign frames otherwise (the two hashes of each random look in
tests/integration/test_render.py), and some of those tests may fail there.
"""

from __future__ import annotations

import os
from pathlib import Path

SKYLAKEX_FLAGS = ("avx512f", "avx512cd", "avx512bw", "avx512dq", "avx512vl")  # what OpenBLAS's SkylakeX kernels use


def cpu_flags() -> set[str]:
    cpuinfo = Path("/proc/cpuinfo")
    lines = cpuinfo.read_text().splitlines() if cpuinfo.is_file() else []
    return {flag for line in lines if line.startswith("flags") for flag in line.split(":", 1)[1].split()}


SKYLAKEX_CPU = set(SKYLAKEX_FLAGS) <= cpu_flags()
if SKYLAKEX_CPU:
    os.environ["OPENBLAS_CORETYPE"] = "SkylakeX"

from agf.heap import keep_freed_memory  # noqa: E402 (after the kernel is chosen: it imports numpy)


def pytest_configure(config) -> None:
    keep_freed_memory()
