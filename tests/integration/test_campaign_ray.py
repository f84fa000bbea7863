"""Real simulated picks as Ray tasks on a local Ray, against the same picks on the process pool. On the
simulated clock a pick is a function of (seed, run index): the records must be identical but for the
timing fields (wall seconds, the cycle's measured vision compute time) and the recorder file's name."""

from __future__ import annotations

import pytest

from agf.config import load_config
from agf.paths import DEFAULT_CONFIG
from agf.report import read_results
from drivers.sim.world import simulate_command

pytest.importorskip("ray", reason="Ray is an optional extra: pip install -e '.[cluster]'")

CONFIG = load_config(DEFAULT_CONFIG)
TIMING = ("wall_s", "cpu_s", "cycle_s", "log")


def picks_on(backend: str, folder) -> dict[int, dict]:
    """Picks 0 (refused) and 4 (inserted) of seed 4242 on ``backend``, by run index, without their timing fields."""
    out = folder / backend
    summary = simulate_command(
        CONFIG, scene=None, runs=30, seed=4242, indices=[0, 4], jobs=2, backend=backend, out=str(out), progress=False
    )
    assert summary["runs"] == 2 and summary["collisions"] == 0
    return {r["run"]: {k: v for k, v in r.items() if k not in TIMING} for r in read_results(out)}


@pytest.mark.slow
def test_real_picks_on_ray_give_the_pools_records(tmp_path):
    pool, ray = picks_on("pool", tmp_path), picks_on("ray", tmp_path)
    assert sorted(pool) == [0, 4]
    assert ray == pool
    assert any(record["measured"] for record in pool.values())  # a pick measured something to compare
