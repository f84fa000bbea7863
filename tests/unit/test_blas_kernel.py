"""The suite runs numpy on OpenBLAS's SkylakeX kernels on a CPU with AVX-512 (tests/conftest.py says why)."""

from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_info

from tests.conftest import SKYLAKEX_FLAGS, cpu_flags


@pytest.mark.skipif(not set(SKYLAKEX_FLAGS) <= cpu_flags(), reason="no AVX-512: OpenBLAS picks its kernel")
def test_regression_openblas_named_haswell_by_the_environment_runs_skylakex_kernels_on_an_avx_512_cpu():
    np.linalg.lstsq(np.eye(3), np.ones(3), rcond=None)  # OpenBLAS is loaded
    kernels = [i["architecture"] for i in threadpool_info() if i.get("internal_api") == "openblas"]
    assert kernels and set(kernels) == {"SkylakeX"}, kernels
