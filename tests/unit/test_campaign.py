"""Campaigns: results streamed per pick, resumed after an interruption, the same on a process pool and
on Ray; each pick reproducible from (seed, run index) alone."""

from __future__ import annotations

import dataclasses
import functools
import json
import sys
from types import SimpleNamespace

import pytest

from agf.cli import EXIT_UNAVAILABLE, EXIT_USAGE, main
from agf.config import ForkGeometry
from agf.errors import InputError, NotAvailableError
from agf.report import RESULTS_FILE, read_results
from drivers.sim.campaign import CampaignInterrupted, PoolBackend, make_backend, run_campaign
from drivers.sim.render import catalogued
from drivers.sim.world import SUPPORT_GAP, campaign_scene, pick_outcome, scene_summary, support_gap
from tests.unit.campaign_picks import BASE, light_pick

IDENTITY = {"scene": None, "random": 12, "seed": 5}


def campaign(folder, pick=None, *, resume=False, backend=None, indices=range(12)):
    return run_campaign(
        pick or functools.partial(light_pick, 5),
        list(indices),
        IDENTITY,
        out=folder,
        backend=backend or PoolBackend(2),
        resume=resume,
        progress=False,
    )


def without_timing(results):
    return [{k: v for k, v in r.items() if k not in ("wall_s", "cpu_s")} for r in results]


def test_a_pick_scene_depends_on_its_seed_and_run_index_only():
    def scene(seed, index):
        return scene_summary(campaign_scene(BASE, seed, index))

    alone = scene(7, 3)
    assert [scene(7, k) for k in range(5)][3] == alone
    assert scene(7, 4) != alone and scene(8, 3) != alone


def test_pallet_types_draw_a_pick_s_pallet_and_leave_the_rest_of_its_scene_as_drawn():
    """``--pallet-types``: each pick's pallet drawn from its own stream of (seed, run), every type in turn over a
    campaign, the load 50 mm inside the pallet's sides; the other draws as without it, and one type named alone
    that the base scene has already gives the same scenes as no option (campaigns written before it stay)."""
    types = ("epal", "gma-48x40", "jis-t11")
    drawn = [campaign_scene(BASE, 7, k, pallet_types=types) for k in range(60)]
    plain = [campaign_scene(BASE, 7, k) for k in range(60)]
    assert {s.pallet.type for s in drawn} == set(types)
    assert [s.pallet.type for s in drawn] == [campaign_scene(BASE, 7, k, pallet_types=types).pallet.type
                                              for k in range(60)]
    for mixed, alone in zip(drawn, plain, strict=True):
        assert mixed.pallet.in_fork.to_dict() == alone.pallet.in_fork.to_dict()
        assert mixed.environment == alone.environment
        assert (mixed.load is None) == (alone.load is None)
        kind = catalogued(mixed.pallet.type)
        if mixed.load is not None:
            assert mixed.load.size[:2] == pytest.approx((kind.length - 0.1, kind.width - 0.1))
            assert mixed.load.size[2] == alone.load.size[2]
    assert [scene_summary(campaign_scene(BASE, 7, k, pallet_types=("jis-t11",))) for k in range(60)] == [
        scene_summary(s) for s in plain]
    assert all(s.load is None or s.load.size[:2] == (1.0, 1.0) for s in plain)


def test_campaign_scenes_start_with_the_tines_clear_of_the_slab_their_pallet_stands_on():
    """A random look's truck bed or dock reaches up to 0.35 m before the pallet's face; with the pallet above the
    forks it held the tines' tips in 105 of the first 1000 scenes of campaign seed 7 (a truck cannot start there)."""
    gaps = [support_gap(campaign_scene(BASE, 7, k), ForkGeometry()) for k in range(200)]
    assert min(gaps) >= SUPPORT_GAP


def test_regression_campaign_pick_386_of_seed_7_a_dock_holding_the_tines_is_drawn_again():
    """Pick 386's look (seed 1234191223, before session 39) put its truck bed 47 mm past the tines' tips, 144 mm
    above them: that look is drawn again."""
    scene = campaign_scene(BASE, 7, 386)
    before = dataclasses.replace(scene, seed=1234191223)
    assert support_gap(before, ForkGeometry()) < -0.04
    assert scene.seed != before.seed and support_gap(scene, ForkGeometry()) >= SUPPORT_GAP


def test_results_stream_one_line_per_pick(tmp_path):
    summary = campaign(tmp_path / "c")
    lines = (tmp_path / "c" / RESULTS_FILE).read_text().splitlines()
    assert len(lines) == 12 and sorted(json.loads(line)["run"] for line in lines) == list(range(12))
    results = read_results(tmp_path / "c")
    assert summary["runs"] == 12
    assert summary["inserted"] + summary["refused"] + summary["faulted"] == 12
    assert summary["inserted"] == sum(r["outcome"] == "inserted" for r in results)
    assert {f["run"] for f in summary["failures"]} == {r["run"] for r in results if not r["ok"]}
    assert all(f["reason"] for f in summary["failures"])


def test_an_interrupted_campaign_keeps_its_results_and_resumes_to_the_same_ones(tmp_path):
    whole = tmp_path / "whole"
    campaign(whole)
    cut = tmp_path / "cut"
    with pytest.raises(CampaignInterrupted, match="after 4 of 12 picks.*--resume"):
        campaign(cut, functools.partial(light_pick, 5, interrupt_at=4), backend=PoolBackend(1))
    assert [r["run"] for r in read_results(cut)] == [0, 1, 2, 3]
    with (cut / RESULTS_FILE).open("a") as f:
        f.write('{"run": 4, "ok": tr')  # a write the interruption cut short
    summary = campaign(cut, resume=True)
    assert summary["runs"] == 12
    assert without_timing(read_results(cut)) == without_timing(read_results(whole))


def test_resume_refuses_another_campaigns_folder_and_a_new_campaign_refuses_a_used_one(tmp_path):
    campaign(tmp_path / "c", indices=range(2))
    with pytest.raises(InputError, match="already holds"):
        campaign(tmp_path / "c", indices=range(2))
    with pytest.raises(InputError, match="seed: 5 there, 6 now"):
        run_campaign(
            light_pick,
            [0],
            {**IDENTITY, "seed": 6},
            out=tmp_path / "c",
            backend=PoolBackend(1),
            resume=True,
            progress=False,
        )


def test_a_pick_that_crashes_is_a_fault_with_its_reason(tmp_path):
    def crash(index):
        raise ZeroDivisionError("division by zero")

    summary = campaign(tmp_path / "c", crash, backend=PoolBackend(1), indices=[0])
    assert summary["faulted"] == 1 and "crashed: ZeroDivisionError" in summary["failures"][0]["reason"]


def test_ray_backend_without_ray_is_not_available(monkeypatch, capsys, tmp_path):
    """Refused with the install command, and the default campaign folder made for it is gone again."""
    monkeypatch.setitem(sys.modules, "ray", None)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(NotAvailableError, match=r"pip install -e '.\[cluster\]'"):
        make_backend("ray")
    assert main(["simulate", "--random", "1", "--backend", "ray", "--json"]) == EXIT_UNAVAILABLE
    assert "needs Ray" in json.loads(capsys.readouterr().out)["error"]
    assert list((tmp_path / "campaigns").iterdir()) == []


def test_resume_needs_the_campaign_folder_and_address_needs_ray(capsys):
    assert main(["simulate", "--random", "2", "--resume", "--json"]) == EXIT_USAGE
    assert "--out CAMPAIGN_DIR" in json.loads(capsys.readouterr().out)["error"]
    with pytest.raises(InputError, match="--backend ray"):
        make_backend("pool", address="auto")


def test_ray_gives_the_process_pools_results(tmp_path):
    pytest.importorskip("ray", reason="Ray is an optional extra: pip install -e '.[cluster]'")
    campaign(tmp_path / "pool")
    summary = campaign(tmp_path / "ray", backend=make_backend("ray", jobs=2))
    assert summary["backend"] == "local Ray"
    assert without_timing(read_results(tmp_path / "ray")) == without_timing(read_results(tmp_path / "pool"))


@pytest.mark.parametrize(
    ("ok", "reason", "refused", "plan_safe", "clearance", "outcome"),
    [
        (True, None, False, True, 0.02, "inserted"),
        (True, None, False, True, -0.001, "collided"),
        (False, "measuring: the forks hide 37% of the pocket edges", True, None, float("inf"), "refused"),
        (False, "verifying: the verifying measurement puts the pallet 38.1 mm lower", True, True, 0.2, "refused"),
        (False, "planning: insertion refused: height margin -3 mm", False, False, 0.2, "refused"),
        (False, "aligning: drive fault on lift: following error", False, True, 0.1, "faulted"),
        (False, "acquiring: simulated camera: no frame within 60.00 s", False, None, float("inf"), "faulted"),
    ],
)
def test_a_pick_outcome_is_what_ended_it(ok, reason, refused, plan_safe, clearance, outcome):
    plan = None if plan_safe is None else SimpleNamespace(safe=plan_safe)
    result = SimpleNamespace(ok=ok, reason=reason, plan=plan, refused=refused)
    assert pick_outcome(result, SimpleNamespace(min_clearance=clearance)) == outcome


def test_regression_two_campaigns_started_in_the_same_second_get_folders_of_their_own(tmp_path, monkeypatch):
    """Two `agf simulate --only K` started in one second wrote into one default folder and its results file."""
    import argparse
    from datetime import UTC, datetime

    from agf import cli

    class Frozen:
        @staticmethod
        def now(tz):
            return datetime(2026, 11, 26, 2, 45, 38, tzinfo=UTC)

    monkeypatch.setattr(cli, "datetime", Frozen)
    monkeypatch.chdir(tmp_path)
    args = argparse.Namespace(random=200, seed=7, scene=None)
    folders = [cli._campaign_folder(args) for _ in range(3)]
    name = "20261126-024538-random-200-seed-7"
    assert [f.name for f in folders] == [name, f"{name}-2", f"{name}-3"]
    assert all(f.is_dir() for f in folders)


def busy_pick(index: int) -> dict:
    """A pick that computes for 0.3 s of CPU (run 0) or sleeps for 0.3 s (run 1)."""
    import time

    if index == 0:
        end = time.process_time() + 0.3
        while time.process_time() < end:
            pass
    else:
        time.sleep(0.3)
    return {"ok": True, "outcome": "inserted", "collision": False}


def test_each_pick_records_the_cpu_time_its_process_spent_on_it(tmp_path):
    """``cpu_s``: what a pick computed, which waiting does not add to (the wall time counts both); the summary sums
    it over the campaign."""
    summary = campaign(tmp_path / "c", busy_pick, backend=PoolBackend(1), indices=[0, 1])
    computed, slept = sorted(read_results(tmp_path / "c"), key=lambda r: r["run"])
    assert computed["cpu_s"] >= 0.29 and computed["wall_s"] >= 0.29
    assert slept["cpu_s"] < 0.1 < 0.29 <= slept["wall_s"]
    assert summary["cpu_s"] == pytest.approx(computed["cpu_s"] + slept["cpu_s"])
