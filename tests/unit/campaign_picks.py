"""A light pick for campaign and report tests: the real campaign scene of (seed, index), a measurement
error drawn from (seed, index), and an outcome by rule, in the result keys the simulated world writes.
Module level, so process pools and Ray workers can import it."""

from __future__ import annotations

import numpy as np

from agf.paths import repo_path
from agf.scene import load_scene
from drivers.sim.world import campaign_scene, scene_summary

BASE = load_scene(repo_path("configs/scenes/pick.yaml"))


def light_pick(seed: int, index: int, interrupt_at: int | None = None, pallet_types: tuple[str, ...] = ()) -> dict:
    """Refused when the pallet is more than 250 mm below the forks (they hide its pocket edges), faulted
    on every 7th run, else inserted; a viewing move where it is more than 200 mm below, but for every other
    refused pick. ``interrupt_at``: this run stops the campaign as Ctrl-C does; ``pallet_types`` as
    ``agf simulate --pallet-types``."""
    if index == interrupt_at:
        raise KeyboardInterrupt
    scene = campaign_scene(BASE, seed, index, pallet_types=pallet_types)
    truth = scene.pallet.in_fork.to_dict()
    rng = np.random.default_rng([seed, index, 1])
    measured = {k: v + rng.normal(0.0, 2.0 if k.endswith("_mm") else 0.1) for k, v in truth.items()}
    outcome = "refused" if truth["z_mm"] < -250 else "faulted" if index % 7 == 6 else "inserted"
    reason = {
        "refused": f"measuring: the forks hide {40 + index}% of the pallet's pocket edges from the camera",
        "faulted": "aligning: drive fault on reach: over-temperature",
        "inserted": None,
    }[outcome]
    # a viewing move after a first frame refused for its face, except for every other refused pick, which ends there
    views = [f"no convincing pallet front face: similarity 0.4{index % 10} < 0.50"] if truth["z_mm"] < -200 and not (
        outcome == "refused" and index % 2) else []
    return {
        "ok": outcome == "inserted",
        "outcome": outcome,
        "state": "done" if outcome == "inserted" else "fault",
        "reason": reason,
        "collision": False,
        "min_clearance_mm": float(8.0 + rng.uniform(0, 10)) if outcome != "refused" else None,
        "cycle_s": float(20 + rng.uniform(0, 5)),
        "durations_s": {"acquiring": 0.5, "measuring": 1.0, "aligning": float(5 + rng.uniform(0, 2))},
        "measured": [measured] if outcome != "refused" else [],
        # stated at half the drawn noise, so that some errors exceed three of them
        "uncertainty": [{"z_mm": 1.0, "pitch_deg": 0.05}] if outcome != "refused" else [],
        "truth": [truth] if outcome != "refused" else [],
        "scene": scene_summary(scene),
        "viewing_moves": len(views),
        "viewing_reasons": views,
        "withdrawals": int(index % 5 == 0),
        "confirmations": int(index % 4 == 0),
        "exposure_changes": int(index % 7 == 0),
    }
