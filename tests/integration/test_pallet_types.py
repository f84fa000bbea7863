"""``agf simulate --pallet-types``: whole campaign picks on the catalogue's other pallets, end to end (the command
line, the simulated world measuring and planning for the pick's pallet, the campaign folder and its report)."""

from __future__ import annotations

import json

import pytest

from agf.cli import EXIT_OK, EXIT_USAGE, main
from agf.report import RESULTS_FILE, read_results
from tests.integration.test_clock_pick import assert_within_bounds, run_campaign_pick

pytestmark = pytest.mark.usefixtures("point_sampled_texture")  # the frames these tests were written on

TYPES = "epal,gma-48x40,jis-t11"
# Picks of `agf simulate --random 60 --seed 4242 --pallet-types epal,gma-48x40,jis-t11` (session 59): an unloaded
# EUR pallet 37 mm below the forks and an unloaded GMA stringer pallet 158 mm above them, both inserted with no
# viewing move.
PICKS = {5: "epal", 16: "gma-48x40"}


def simulate(capsys, *argv: str) -> tuple[int, dict]:
    code = main(["simulate", "--random", "60", "--seed", "4242", *argv, "--json"])
    return code, json.loads(capsys.readouterr().out)


def test_picks_of_other_pallet_types_insert_with_every_measurement_within_the_bounds(capsys, tmp_path):
    out = tmp_path / "campaign"
    for index in PICKS:
        code, summary = simulate(capsys, "--pallet-types", TYPES, "--only", str(index), "--out", str(out),
                                 *(["--resume"] if out.exists() else []))
        assert code == EXIT_OK, summary
    records = {r["run"]: r for r in read_results(out)}
    assert {run: r["scene"]["pallet_type"] for run, r in records.items()} == PICKS
    for record in records.values():
        assert record["outcome"] == "inserted" and not record["collision"], record.get("reason")
        assert record["viewing_moves"] == 0 and len(record["measured"]) >= 2
    by_type = summary["by_pallet_type"]
    assert {kind: (c["runs"], c["inserted"], c["measurements_outside_bounds"]) for kind, c in by_type.items()} == {
        "epal": (1, 1, 0), "gma-48x40": (1, 1, 0)}
    assert json.loads((out / "campaign.json").read_text())["pallet_types"] == TYPES.split(",")
    assert len((out / RESULTS_FILE).read_text().splitlines()) == 2


# `agf simulate --random 300 --seed 7 --pallet-types epal,gma-48x40` (session 59, the vision of session 55): 155
# inserted, no collision, and 15 of its 331 accepted measurements outside the bounds in these 13 picks (the JIS T11
# campaign of seed 7: 18 of 1277). Most are 0.10-0.15 deg off in pitch; three are off in position: pick 88 (GMA,
# loaded, 439 mm above the forks) verified 71 mm nearer and 71 mm higher, its face matched at another depth along
# the line of sight with 3 % of its face ends agreeing (the verifying check against the plan refused the pick), pick
# 263 (GMA, loaded) measured 44 mm too far and 43 mm low after two viewing moves (refused later), pick 253 (GMA,
# loaded, inserted) verified 8 mm low.
# Session 60: 9, 95 and 116 no longer (test_regression_..._report_the_pitch_measured below).
# Session 61: 120 no longer (test_regression_pallet_types_campaign_pick_120_of_seed_7_... below).
# Session 65: 263 no longer: its first frame measures within the bounds (its face's similarity, 0.46 and 0.08 below a
# rival's, settled by its edges agreeing 79 %), so the pick makes no viewing move; the frame of its second view is
# still accepted outside the bounds (open: tests/data/scenes/open-wrong-accepts/pallet-types-7-pick-263-two-views-up).
OPEN_PALLET_TYPE_WRONG_ACCEPTS = (30, 36, 63, 88, 166, 209, 253, 261)
CAMPAIGN_TYPES = ("epal", "gma-48x40")


@pytest.mark.xfail(
    strict=True, raises=AssertionError, reason="accepted a measurement outside the bounds: open, see issue 17"
)
@pytest.mark.parametrize("index", OPEN_PALLET_TYPE_WRONG_ACCEPTS)
def test_open_wrong_accepts_of_the_pallet_types_campaign_of_seed_7(index):
    result, _, truths = run_campaign_pick(7, index, pallet_types=CAMPAIGN_TYPES)
    assert_within_bounds(result.measurements, truths)


@pytest.mark.parametrize("index", (9, 95, 116))
def test_regression_pallet_types_campaign_picks_of_seed_7_report_the_pitch_measured(index):
    """Open wrong accepts until session 60, 0.10-0.15 deg off in pitch: reported at the pitch their edges measured,
    not the one the pose was last searched at (measure._at_pitch; see test_clock_pick), they accept nothing outside
    the bounds."""
    result, _, truths = run_campaign_pick(7, index, pallet_types=CAMPAIGN_TYPES)
    assert_within_bounds(result.measurements, truths)


def test_regression_pallet_types_campaign_pick_120_of_seed_7_deck_edges_with_close_rival_pairings_give_their_midpoint():
    """An open wrong accept until session 61: an unloaded pallet measured 0.102 deg off in pitch (the pick refused
    when verifying). Deck edges whose pairings with a line beside them lie within 0.1 deg now give their midpoint
    (pitch._between_rivals): both measurements 0.015 deg off, the pallet inserted."""
    result, _, truths = run_campaign_pick(7, 120, pallet_types=CAMPAIGN_TYPES)
    assert_within_bounds(result.measurements, truths)


def test_a_campaign_of_several_pallet_types_resumes_only_with_them(capsys, tmp_path):
    """A folder that records pallet types is another campaign for a resume without them, or with others: its picks
    would be drawn on other pallets."""
    out = tmp_path / "campaign"
    out.mkdir()
    (out / "campaign.json").write_text(json.dumps({"scene": None, "random": 60, "seed": 4242,
                                                   "pallet_types": TYPES.split(",")}))
    for argv in ([], ["--pallet-types", "epal"]):
        code, payload = simulate(capsys, *argv, "--only", "5", "--out", str(out), "--resume")
        assert code == EXIT_USAGE
        assert "holds another campaign" in payload["error"] and "pallet_types" in payload["error"], payload["error"]
    assert not (out / RESULTS_FILE).exists() or not (out / RESULTS_FILE).read_text()


def test_the_bench_counts_each_pallet_type_s_frames():
    """``agf bench``'s ``accuracy.pallet_types`` (quick: two paper geometries, each with every pallet type): every
    frame counted once, under its own pallet type, and none accepted outside the bounds."""
    from drivers.sim.vision_bench import PALLET_TYPES, pallet_types_accuracy

    summary = pallet_types_accuracy(quick=True)
    counts = summary["by_pallet_type"]
    assert list(counts) == list(PALLET_TYPES) and summary["scenes"] == 2 * len(PALLET_TYPES)
    for kind, count in counts.items():
        assert count["scenes"] == 2 == count["within_bounds"] + count["refused"] + count["wrong_accepts"], kind
    assert sum(c["refused"] for c in counts.values()) == len(summary["refused"])
    assert sum(c["within_bounds"] for c in counts.values()) == summary["within_bounds"]
    assert sum(c["wrong_accepts"] for c in counts.values()) == summary["wrong_accepts"] == 0


def test_regression_a_cached_render_is_never_read_half_written(tmp_path, monkeypatch):
    """An `agf bench --only pallet_types` beside this file's bench test read a frame the test was still writing into
    the render cache (libpng "Read Error", the case failed). A frame is written beside its name and renamed: at its
    name there is nothing or the whole frame, and nothing else is left."""
    import cv2
    import numpy as np

    from drivers.sim import vision_bench

    image = np.random.default_rng(0).integers(0, 255, (64, 48, 3), dtype=np.uint8)
    path = tmp_path / "cache" / "frame.png"
    written = []
    real_imwrite = cv2.imwrite

    def imwrite(name, pixels):
        written.append((name, path.exists()))
        return real_imwrite(name, pixels)

    monkeypatch.setattr(vision_bench.cv2, "imwrite", imwrite)
    vision_bench._cache(path, image)
    [(name, existed)] = written
    assert name != str(path) and not existed  # written under another name, the frame's name still free
    assert np.array_equal(cv2.imread(str(path), cv2.IMREAD_COLOR), image)
    assert [p.name for p in path.parent.iterdir()] == ["frame.png"]
