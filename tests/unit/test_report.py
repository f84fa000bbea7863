"""``agf report``: the Markdown and plots of a campaign folder written by the campaign machinery (with
the light pick of campaign_picks.py), and the checks on what a results file holds."""

from __future__ import annotations

import functools
import json
import re
from collections import Counter

import cv2
import pytest

from agf.cli import EXIT_OK, EXIT_USAGE, main
from agf.errors import InputError
from agf.report import (
    RESULTS_FILE,
    beyond_stated,
    first_refusals,
    measurement_errors,
    outcomes_by_band,
    read_results,
    write_report,
)
from agf.vision.accuracy import within_bounds
from drivers.sim.campaign import PoolBackend, ResultsFile, run_campaign
from tests.unit.campaign_picks import light_pick

# one pytest-xdist worker runs them all: its tests share one 40-pick campaign
pytestmark = pytest.mark.xdist_group("test_report")

RUNS, SEED = 40, 11


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A 40-pick campaign; two failures carry a recorder log, one of them deleted since."""
    folder = tmp_path_factory.mktemp("campaign") / "c"
    run_campaign(
        functools.partial(light_pick, SEED),
        list(range(RUNS)),
        {"scene": None, "random": RUNS, "seed": SEED},
        out=folder,
        backend=PoolBackend(2),
        progress=False,
    )
    records = read_results(folder)
    failed = [r for r in records if not r["ok"]]
    assert len(failed) >= 2, "the light pick's rules give refusals and faults on this seed"
    logs = folder / "logs"
    logs.mkdir()
    (logs / "pick-kept.mcap").write_bytes(b"\x89MCAP0\r\n")
    failed[0]["log"], failed[1]["log"] = str(logs / "pick-kept.mcap"), str(logs / "pick-deleted.mcap")
    (folder / RESULTS_FILE).unlink()
    for record in records:
        ResultsFile(folder).append(record)
    return folder


def table_rows(markdown: str, heading: str) -> list[list[str]]:
    section = markdown.split(f"## {heading}\n", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in section.splitlines() if line.startswith("| ") and not line.startswith("|---")]
    return [[c.strip() for c in row.strip("|").split(" | ")] for row in rows[1:]]


def test_the_report_counts_outcomes_and_tables_reasons(folder):
    result = write_report(folder)
    records = read_results(folder)
    markdown = (folder / "report.md").read_text()
    counts = Counter(r["outcome"] for r in records)
    outcomes = {row[0]: int(row[1]) for row in table_rows(markdown, "Outcomes")}
    assert outcomes == {o: counts[o] for o in ("inserted", "refused", "faulted", "collided")}
    assert result["inserted"] == counts["inserted"] and result["runs"] == RUNS
    refusals = table_rows(markdown, "Refused: reasons")
    assert [row[0] for row in refusals] == ["measuring: the forks hide #% of the pallet's pocket edges from the camera"]
    assert int(refusals[0][1]) == counts["refused"]
    viewed = sum(r["viewing_moves"] > 0 for r in records)
    assert f"to look once more): {viewed}," in markdown and result["viewing_moves"] == viewed
    withdrawn = [r for r in records if r["withdrawals"] > 0]
    assert f"to measure again: {len(withdrawn)}, of which {sum(r['ok'] for r in withdrawn)} inserted." in markdown
    assert result["withdrawals"] == len(withdrawn) > 0
    confirmed = [r for r in records if r["confirmations"] > 0]
    assert f"at the pitch measured before: {len(confirmed)}, of which {sum(r['ok'] for r in confirmed)} inserted." \
        in markdown
    assert result["confirmations"] == len(confirmed) > 0
    darker = [r for r in records if r["exposure_changes"] > 0]
    assert f"(clipped highlights beside the deck's edges): {len(darker)}, of which {sum(r['ok'] for r in darker)} " \
        "inserted." in markdown
    assert result["exposure_changes"] == len(darker) > 0
    failures = table_rows(markdown, "Failures")
    assert sorted(int(row[0]) for row in failures) == [r["run"] for r in records if not r["ok"]]
    cpu = sum(r["cpu_s"] for r in records)
    assert result["cpu_s"] == pytest.approx(cpu) and f"{cpu / 60:.1f} CPU minutes over {RUNS} picks" in markdown


def test_the_report_tables_the_outcomes_by_pallet_type_where_a_campaign_drew_more_than_one(folder, tmp_path):
    """``agf simulate --pallet-types``: picks, inserted, collided and measurements outside the bounds per type, in the
    Markdown and in the JSON (``by_pallet_type``); a campaign of one type has no such table."""
    types = ("epal", "gma-48x40", "jis-t11")
    mixed = tmp_path / "mixed"
    run_campaign(functools.partial(light_pick, SEED, pallet_types=types), list(range(18)),
                 {"scene": None, "random": 18, "seed": SEED, "pallet_types": list(types)}, out=mixed,
                 backend=PoolBackend(2), progress=False)
    result = write_report(mixed)
    records = read_results(mixed)
    rows = {row[0]: row[1:] for row in table_rows((mixed / "report.md").read_text(), "Outcomes by pallet type")}
    assert sorted(rows) == sorted(types)
    outside = Counter(e["scene"]["pallet_type"] for e in measurement_errors(records) if not within_bounds(e["error"]))
    for kind in types:
        picks = [r for r in records if r["scene"]["pallet_type"] == kind]
        inserted = sum(r["outcome"] == "inserted" for r in picks)
        assert rows[kind] == [str(len(picks)), f"{inserted} ({inserted / len(picks):.0%})", "0", str(outside[kind])]
        assert result["by_pallet_type"][kind] == {"runs": len(picks), "inserted": inserted, "collisions": 0,
                                                  "measurements_outside_bounds": outside[kind]}
    assert sum(outside.values()) == result["measurements_outside_bounds"] > 0
    write_report(folder)
    assert "## Outcomes by pallet type" not in (folder / "report.md").read_text()


def test_first_refusals_count_the_first_frame_s_reason_and_the_pick_s_outcome(folder):
    """A pick that moved to look again ends with its last frame's reason; the report's table of first refusals counts
    the first frame's (its first viewing move's), or the pick's own where it ended on its first frame."""
    write_report(folder)
    records = read_results(folder)
    rows = {row[0]: (int(row[1]), int(row[2])) for row in table_rows((folder / "report.md").read_text(),
                                                                      "First measurement refused: reasons")}
    viewed = [r for r in records if r["viewing_reasons"]]
    ended = [r for r in records if r["outcome"] == "refused" and not r["viewing_reasons"]]
    assert viewed and ended, "the light pick's rules give both on this seed"
    assert rows == {
        "no convincing pallet front face: similarity # < #": (len(viewed), sum(r["ok"] for r in viewed)),
        "the forks hide #% of the pallet's pocket edges from the camera": (len(ended), 0),
    }
    assert first_refusals([{k: v for k, v in r.items() if k != "viewing_reasons"} for r in records]) == {}


def test_refused_measurements_count_by_their_first_search_s_reason():
    """Before, every refusal was a row of its own: the other searches' reasons, appended to the first's, differ."""
    from agf.report import reason_class
    from agf.vision.measure import OTHER_SEARCHES

    first = "measuring: no pitch: neither the deck edges (unloaded, ratio {}) nor the load edges (loaded, ratio 0.3)"
    tails = [f"{OTHER_SEARCHES}+-3.0 deg and by regions too: ambiguous pallet)",
             f"{OTHER_SEARCHES}+-3.0 deg and by regions too: pocket edges fit poorly; no pitch)", ""]
    ratios = ("0.12", "0.2", "0.4")
    kinds = {reason_class(first.format(ratio) + tail) for ratio, tail in zip(ratios, tails, strict=True)}
    assert kinds == {first.format("#").replace("0.3", "#")}
    assert reason_class("the deck edges give it only to +-0.058 deg") == "the deck edges give it only to +-# deg"


def test_failure_rows_link_their_recorder_file_when_there_is_one(folder):
    write_report(folder)
    links = {int(row[0]): row[-1] for row in table_rows((folder / "report.md").read_text(), "Failures")}
    with_log = [r for r in read_results(folder) if r.get("log")]
    kept, deleted = with_log[0]["run"], with_log[1]["run"]
    assert links[kept] == "[pick-kept.mcap](logs/pick-kept.mcap)"
    assert links[deleted].endswith("pick-deleted.mcap (missing)")
    assert sum(link == "-" for link in links.values()) == len(links) - 2


def test_the_plots_are_written_and_linked(folder):
    result = write_report(folder)
    markdown = (folder / "report.md").read_text()
    assert len(result["plots"]) == 5
    for path in result["plots"]:
        image = cv2.imread(path)
        assert image is not None and image.shape[0] > 300 and image.std() > 10
    linked = re.findall(r"!\[[^]]*\]\(([^)]+)\)", markdown)
    assert sorted(linked) == sorted(p.rsplit("/", 1)[-1] for p in result["plots"])


def test_agf_report_on_the_command_line(folder, tmp_path, capsys):
    assert main(["report", str(folder), "--json"]) == EXIT_OK
    out = json.loads(capsys.readouterr().out)
    assert out["report"].endswith("report.md") and out["runs"] == RUNS
    assert main(["report", str(tmp_path / "none"), "--json"]) == EXIT_USAGE
    assert "not a campaign folder" in json.loads(capsys.readouterr().out)["error"]


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ('{"run": 0, "ok": true, "collision": false}', "missing key 'outcome'"),
        ('{"run": 0, "ok": "yes", "outcome": "inserted", "collision": false}', "ok: expected bool"),
        ('{"run": 0, "ok": false, "outcome": "lost", "collision": false}', "outcome: expected one of"),
        ('{"run": 0, "ok": true, "outcome": "inserted", "collision": false, "measured": {}}', "measured: expected"),
        ('{"run": 0, "ok": true, "outcome": "inserted", "collision": false, "measured": [], '
         '"uncertainty": [{"z_mm": 1, "pitch_deg": 0.03}]}', "uncertainty: more entries than measured"),
        ('{"run": 0, "ok": true, "outcome": "inserted", "collision": false, "measured": [{}], '
         '"uncertainty": [{"z_mm": 1}]}', "uncertainty: expected objects of z_mm and pitch_deg"),
        ("not json", "not JSON"),
    ],
)
def test_a_bad_results_line_names_the_file_line_and_key(tmp_path, line, message):
    good = '{"run": 1, "ok": true, "outcome": "inserted", "collision": false}'
    (tmp_path / RESULTS_FILE).write_text(f"{good}\n{line}\n")
    with pytest.raises(InputError, match=rf"{RESULTS_FILE}:2: .*{re.escape(message)}"):
        read_results(tmp_path)


def test_an_unfinished_last_line_is_left_out_and_a_repeated_run_is_an_error(tmp_path):
    good = '{"run": 1, "ok": true, "outcome": "inserted", "collision": false}'
    (tmp_path / RESULTS_FILE).write_text(f'{good}\n{{"run": 2, "ok": tr')
    assert [r["run"] for r in read_results(tmp_path)] == [1]
    (tmp_path / RESULTS_FILE).write_text(f"{good}\n{good}\n")
    with pytest.raises(InputError, match="run 1 appears twice"):
        read_results(tmp_path)


def test_the_report_counts_accepted_measurements_outside_the_accuracy_bounds(folder):
    result = write_report(folder)

    def off(m, t):  # |x| <= 10 mm, |z| <= 5 mm, |pitch| <= 0.1 deg: docs/accuracy.md's bounds
        dx, dz, dpitch = (abs(m[k] - t[k]) for k in ("x_mm", "z_mm", "pitch_deg"))
        return dx > 10 or dz > 5 or dpitch > 0.1

    outside = sorted({r["run"] for r in read_results(folder)
                      for m, t in zip(r["measured"], r["truth"], strict=True) if off(m, t)})
    assert outside, "the light pick's 0.1 deg pitch noise puts some measurements outside the bounds"
    count = result["measurements_outside_bounds"]
    assert count >= len(outside)
    markdown = (folder / "report.md").read_text()
    assert f"**{count}**, in runs {', '.join(map(str, outside))}." in markdown


def test_outcomes_by_band_put_each_pick_in_the_band_of_its_start_pose(folder):
    records = read_results(folder)
    counts = outcomes_by_band(records, "z_mm", 100.0)
    assert sum(c.total() for bands in counts.values() for c in bands.values()) == len(records)
    for record in records:
        z, loaded = record["scene"]["pallet_in_fork"]["z_mm"], record["scene"]["loaded"]
        [low] = [low for low in counts[loaded] if low <= z < low + 100.0]
        assert low % 100.0 == 0.0
    # the light pick refuses a pallet more than 250 mm below the forks, and only there
    refused = [low for bands in counts.values() for low, c in bands.items() if c["refused"]]
    assert refused and max(refused) < -200.0
    with pytest.raises(ValueError, match="band width must be positive"):
        outcomes_by_band(records, "z_mm", 0.0)


def test_the_report_tables_the_inserted_share_by_pallet_height_and_load(folder):
    write_report(folder)
    rows = table_rows((folder / "report.md").read_text(), "Outcomes by pallet height and load")
    records = read_results(folder)
    assert rows and [row[0] for row in rows] == sorted((row[0] for row in rows), key=lambda b: float(b.split()[0]))
    for band, *cells in rows:
        low = float(band.split()[0])
        mine = [r for r in records if low <= r["scene"]["pallet_in_fork"]["z_mm"] < low + 100.0]
        for cell, chosen in zip(cells, ([r for r in mine if not r["scene"]["loaded"]],
                                        [r for r in mine if r["scene"]["loaded"]], mine), strict=True):
            inserted = sum(r["outcome"] == "inserted" for r in chosen)
            assert cell.split(" (")[0] == f"{inserted} / {len(chosen)}"


def test_the_report_counts_measurements_that_erred_beyond_three_of_their_stated_sigmas(folder):
    result = write_report(folder)
    records = read_results(folder)
    pairs = [(m, t, u) for r in records for m, t, u in zip(r["measured"], r["truth"], r["uncertainty"], strict=True)]
    beyond = {key: sum(abs(m[key] - t[key]) > 3 * u[key] for m, t, u in pairs) for key in ("z_mm", "pitch_deg")}
    assert 0 < beyond["pitch_deg"] < len(pairs), "the light pick states half its noise: some errors exceed 3 sigma"
    counted = beyond_stated(measurement_errors(records))
    assert {key: len(runs) for key, runs in counted.items()} == beyond == result["measurements_beyond_stated"]
    markdown = (folder / "report.md").read_text()
    stated = f"Of the {len(pairs)} measurements that state their uncertainty (1 sigma), {beyond['z_mm']} in z_mm"
    assert stated in markdown and "erred by more than 3 of their sigmas" in markdown
    assert f"and {beyond['pitch_deg']} in pitch_deg (runs " in markdown
    assert beyond_stated(iter(measurement_errors(records))) == counted  # a single pass over the errors serves both keys
    with pytest.raises(ValueError, match="sigmas must be positive"):
        beyond_stated([], 0.0)


def test_a_campaign_whose_results_state_no_uncertainty_is_reported_as_such(folder, tmp_path):
    """Campaigns from before session 69 carry no ``uncertainty``: the report says so instead of counting nothing."""
    for record in read_results(folder):
        record.pop("uncertainty")
        ResultsFile(tmp_path).append(record)
    write_report(tmp_path)
    markdown = (tmp_path / "report.md").read_text()
    assert "No measurement states its uncertainty" in markdown and "erred by more than" not in markdown
    assert beyond_stated(measurement_errors(read_results(tmp_path))) == {"z_mm": [], "pitch_deg": []}
