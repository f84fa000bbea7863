"""The suite runs numpy on OpenBLAS's SkylakeX kernels on a CPU with AVX-512 (tests/conftest.py says why)."""

from __future__ import annotations

import pytest

from agf.bench import code_paths
from tests.conftest import SKYLAKEX_CPU


@pytest.mark.skipif(not SKYLAKEX_CPU, reason="no AVX-512: OpenBLAS picks its kernel")
def test_regression_openblas_named_haswell_by_the_environment_runs_skylakex_kernels_on_an_avx_512_cpu():
    kernels = code_paths()["openblas"]
    assert kernels and set(kernels.values()) == {"SkylakeX"}, kernels
