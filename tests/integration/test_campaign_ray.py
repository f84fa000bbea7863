"""A real simulated pick as a Ray task on a local Ray, against the same pick on the process pool: the
same scene, the same outcome, the same measurement within what wall-clock timing can move."""

from __future__ import annotations

import pytest

from agf.config import load_config
from agf.paths import DEFAULT_CONFIG
from agf.report import read_results
from drivers.sim.world import simulate_command

pytest.importorskip("ray", reason="Ray is an optional extra: pip install -e '.[cluster]'")

CONFIG = load_config(DEFAULT_CONFIG)


def pick_on(backend: str, folder) -> dict:
    """Pick 0 of seed 4242 on ``backend``; run again (at most three times) when it faulted: on the wall
    clock, drive heartbeats starved by other processes fault a pick, which is not what this compares."""
    for attempt in range(3):
        out = folder / f"{backend}-{attempt}"
        summary = simulate_command(
            CONFIG, scene=None, runs=30, seed=4242, indices=[0], jobs=1, backend=backend, out=str(out), progress=False
        )
        assert summary["runs"] == 1 and summary["collisions"] == 0
        (record,) = read_results(out)
        if record["outcome"] != "faulted":
            break
    return record


@pytest.mark.slow
def test_a_real_pick_on_ray_gives_the_pools_result(tmp_path):
    pool, ray = pick_on("pool", tmp_path), pick_on("ray", tmp_path)
    # The backends are compared, not the vision: a random look may be refused, on both alike. The frames
    # are rendered where the forks are on the wall clock, so a refusal's wording may differ between runs.
    assert ray["scene"] == pool["scene"] and ray["outcome"] == pool["outcome"] in ("inserted", "refused")
    assert len(ray["measured"]) == len(pool["measured"])
    for a, b in zip(ray["measured"], pool["measured"], strict=True):
        assert abs(a["z_mm"] - b["z_mm"]) < 1.0 and abs(a["pitch_deg"] - b["pitch_deg"]) < 0.05
