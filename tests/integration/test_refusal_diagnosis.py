"""tools/refusal_diagnosis: a campaign's picks drawn and measured again at their truth."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from agf.config import load_config
from agf.geometry import Transform
from agf.pallets import load_pallets
from agf.paths import DEFAULT_CONFIG, repo_path
from agf.report import CAMPAIGN_FILE
from agf.vision.edge_agreement import line_of_sight
from agf.vision.face_model import face_model_from_pallet
from drivers.sim.campaign import ResultsFile
from tests.integration.conftest import tool_module

SEED, INSERTED, REFUSED = 4242, 4, 20  # unloaded picks of `agf simulate --random 30 --seed 4242` (docs/campaigns.md)


@pytest.fixture(scope="module")
def tool():
    return tool_module("refusal_diagnosis")


@pytest.fixture
def folder(tmp_path):
    (tmp_path / CAMPAIGN_FILE).write_text(json.dumps({"scene": None, "random": 30, "seed": SEED}))
    results = ResultsFile(tmp_path)
    for run, outcome in ((INSERTED, "inserted"), (REFUSED, "refused")):
        results.append({"run": run, "ok": outcome == "inserted", "outcome": outcome, "collision": False})
    return tmp_path


def test_an_inserted_pick_drawn_again_measures_within_the_bounds_at_its_truth(tool, folder, capsys):
    """The frame and truth the tool draws are the campaign's: a pick that inserted measures within the bounds with
    its true pose as the prior, and its deck edges at the true pose give its pitch (a scene drawn with other forks
    or from another seed would not)."""
    assert tool.main([str(folder), "--runs", str(INSERTED), "--json"]) == 0
    [record] = json.loads(capsys.readouterr().out)
    assert record["run"] == INSERTED and not record["loaded"]
    assert record["with_true_prior"] == "measured within the bounds", record
    assert record["from_true_start"] == "measured within the bounds", record
    grey = record["edges_at_truth_grey"]
    assert grey["finding"] == "valid" and abs(grey["pitch_error_deg"]) <= 0.1
    assert record["as_campaign"] == "measured" and record["first_search"] == "at the truth", record
    assert math.hypot(*record["first_search_mm"].values()) <= 10


def test_a_pose_moved_along_and_across_the_line_of_sight_is_placed_so(tool):
    """sight_offset splits a pose's offset from the truth into its part along the line of sight to the true face's
    centre and the rest, whatever the poses (seeded), and first_search_text names the three places."""
    config = load_config(DEFAULT_CONFIG)
    face = face_model_from_pallet(load_pallets(config.vision.pallets)["jis-t11"])
    rng = np.random.default_rng(66)
    for _ in range(20):
        truth = Transform.from_euler(*rng.uniform([0.1, -0.2, -0.4], [0.5, 0.2, 0.4]), 0.0,
                                     *np.radians(rng.uniform(-5, 5, 2)))
        camera = Transform.from_euler(-0.7, 0.0, 1.05, 0.0, *np.radians(rng.uniform(-30, 0, 1)), 0.0)
        sight = line_of_sight(truth, camera, face)
        across = np.cross(sight, rng.normal(size=3))
        across /= np.linalg.norm(across)
        along_m, across_m = rng.uniform(-0.3, 0.3), rng.uniform(0.0, 0.1)
        found = Transform(truth.rotation, truth.translation + along_m * sight + across_m * across)
        assert np.allclose(tool.sight_offset(found, truth, camera, face), (along_m, across_m), atol=1e-12)
    assert tool.first_search_text(0.006, 0.006) == "at the truth"
    assert tool.first_search_text(-0.21, 0.03) == "on the line of sight, nearer"
    assert tool.first_search_text(0.12, 0.01) == "on the line of sight, further"
    assert tool.first_search_text(0.02, 0.3) == "elsewhere"


def test_only_the_refused_picks_are_diagnosed_unless_all_are_asked_for(tool, folder, monkeypatch, capsys):
    diagnosed = []

    def record(config, base, seed, run, pallet_types=()):
        assert base == repo_path("configs/scenes/pick.yaml")  # the scene agf simulate draws random picks from
        diagnosed.append((seed, run, *pallet_types))
        return {"run": run, "pallet_type": "jis-t11", "loaded": False, "z_mm": 0, "with_true_prior": "refused: x",
                "from_true_start": "refused: y", "as_campaign": "refused: z", "first_search": "elsewhere",
                "first_search_mm": {"along": 120.0, "across": 300.0},
                **{f"edges_at_truth_{n}": {"finding": "edges not found", "ratio": 0.0, "pitch_error_deg": None,
                                           "candidates_deg": []} for n in ("grey", "colour")}}

    monkeypatch.setattr(tool, "diagnose", record)
    assert tool.main([str(folder)]) == 0
    assert diagnosed == [(SEED, REFUSED)]
    assert "1 picks diagnosed" in capsys.readouterr().out
    diagnosed.clear()
    assert tool.main([str(folder), "--all"]) == 0
    assert diagnosed == [(SEED, INSERTED), (SEED, REFUSED)]
    diagnosed.clear()
    meta = json.loads((folder / CAMPAIGN_FILE).read_text())
    (folder / CAMPAIGN_FILE).write_text(json.dumps({**meta, "pallet_types": ["epal", "gma-48x40"]}))
    assert tool.main([str(folder)]) == 0
    assert diagnosed == [(SEED, REFUSED, "epal", "gma-48x40")]  # drawn as the campaign drew them


def test_a_run_with_no_result_or_a_campaign_of_one_scene_is_refused_with_the_reason(tool, folder, capsys):
    assert tool.main([str(folder), "--runs", "99"]) == 2
    assert "no result for run(s) 99" in capsys.readouterr().err
    (folder / CAMPAIGN_FILE).write_text(json.dumps({"scene": "configs/scenes/pick.yaml", "random": None}))
    assert tool.main([str(folder)]) == 2
    assert "not a random campaign" in capsys.readouterr().err
