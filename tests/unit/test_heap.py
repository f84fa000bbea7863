"""The heap's policy (agf.heap): a freed frame-sized block is reused, not mapped and faulted in again."""

from __future__ import annotations

import subprocess
import sys

import pytest

from agf.heap import keep_freed_memory

# Allocates, frees and allocates again 256 MB (a block glibc would otherwise map on its own), and prints the page
# faults the second allocation took.
REALLOCATE = """
import resource, sys
import numpy as np
from agf.heap import keep_freed_memory
if sys.argv[1] == "keep":
    assert keep_freed_memory()
block = np.ones(32_000_000)
del block
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
block = np.ones(32_000_000)
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults_of_a_second_allocation(policy: str) -> int:
    run = subprocess.run([sys.executable, "-c", REALLOCATE, policy], capture_output=True, text=True, check=True)
    return int(run.stdout)


@pytest.mark.skipif(not keep_freed_memory(), reason="the C library is not glibc: its heap is left as it is")
def test_a_freed_block_is_reused_without_faulting_its_pages_in_again():
    """With glibc's default a freed 256 MB block is unmapped and the next one faults its pages in again (670 faults
    here, most pages huge ones); kept, the next allocation reuses its pages without a fault."""
    assert _faults_of_a_second_allocation("default") >= 100
    assert _faults_of_a_second_allocation("keep") < 10
