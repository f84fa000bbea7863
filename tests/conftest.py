"""Every test process (the xdist workers too) keeps the memory it frees, as ``agf``'s command line does
(:mod:`agf.heap`): the suite's frames would otherwise fault their pages in again and again."""

from __future__ import annotations

from agf.heap import keep_freed_memory


def pytest_configure(config) -> None:
    keep_freed_memory()
