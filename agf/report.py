"""Campaign results and their report (``agf report CAMPAIGN_DIR``): Markdown with PNG plots.

A campaign folder holds ``campaign.json`` (what was run) and ``results.jsonl``, one JSON object per
finished pick (the simulated world's ``pick_summary`` with its run index). The report counts inserted,
refused, faulted and collided picks, tables the refusal and fault reasons, plots the measurement error
against the pallet's pitch, height, yaw and the light, the clearance distribution and the cycle times,
counts the outcomes by the pallet's height and pitch at the start and its load (where the controller picks
and where it refuses) and, where the campaign drew more than one, by pallet type, and links every failure
to its pick's recorder file when the pick wrote one.
"""

from __future__ import annotations

import json
import math
import os
import re
import statistics
from collections import Counter
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from agf.errors import OTHER_SEARCHES, InputError
from agf.vision.accuracy import BOUNDS, within_bounds

CAMPAIGN_FILE, RESULTS_FILE, REPORT_FILE = "campaign.json", "results.jsonl", "report.md"
MEASURING = "measuring: "  # the prefix of a pick's reason when its first measurement (no plan yet) was refused
OUTCOMES = ("inserted", "refused", "faulted", "collided")
POSE_KEYS = ("x_mm", "y_mm", "z_mm", "pitch_deg", "yaw_deg")
# Per-pick keys every result carries (type checked); the others are optional: a pick that crashed or
# was refused before the world existed has no measurements, durations or scene.
REQUIRED = {"run": int, "ok": bool, "outcome": str, "collision": bool}
OPTIONAL = {
    "reason": (str, type(None)),
    "min_clearance_mm": (int, float, type(None)),
    "min_support_clearance_mm": (int, float, type(None)),
    "cycle_s": (int, float),
    "cpu_s": (int, float),
    "durations_s": dict,
    "measured": list,
    "uncertainty": list,
    "truth": list,
    "scene": dict,
    "log": (str, type(None)),
    "viewing_moves": int,
    "viewing_reasons": list,
    "withdrawals": int,
    "confirmations": int,
    "exposure_changes": int,
}
# The pose keys a measurement states its uncertainty (1 sigma) for, and how many of its sigmas an error may reach
# before the report counts it as erring beyond what the measurement stated.
STATED = ("z_mm", "pitch_deg")
SIGMAS = 3.0
COLOURS = {"inserted": "tab:green", "refused": "tab:orange", "faulted": "tab:purple", "collided": "tab:red"}
# The pallet's start pose keys the outcomes are counted by (band width, axis label): 100 mm of height is about
# what a viewing move changes; a degree of pitch what one step of the first searches covers.
BANDS = {"z_mm": (100.0, "pallet height at the start, in fork frame [mm]"), "pitch_deg": (1.0, "pallet pitch [deg]")}


def _measured_again(results: list[dict[str, Any]], key: str, what: str) -> list[str]:
    """The report's line on the picks whose ``key`` count is positive, ``what`` they are, and how many inserted
    (none where no result has the key: a campaign from before it was counted)."""
    if not any(key in r for r in results):
        return []
    again = [r for r in results if r.get(key, 0) > 0]
    return [f"{what}: {len(again)}, of which {sum(r['ok'] for r in again)} inserted.", ""]


def validate_result(record: Any, where: str) -> dict[str, Any]:
    """One line of ``results.jsonl`` checked for the keys the report reads; InputError names what is wrong."""
    if not isinstance(record, dict):
        raise InputError(f"{where}: expected a JSON object per line, got {type(record).__name__}")
    for key, kind in REQUIRED.items():
        if key not in record:
            raise InputError(f"{where}: missing key {key!r}")
        if not isinstance(record[key], kind) or (kind is int and isinstance(record[key], bool)):
            raise InputError(f"{where}: {key}: expected {kind.__name__}, got {record[key]!r}")
    for key, kinds in OPTIONAL.items():
        if key in record and not isinstance(record[key], kinds):
            raise InputError(f"{where}: {key}: expected {kinds}, got {type(record[key]).__name__}")
    if record["outcome"] not in OUTCOMES:
        raise InputError(f"{where}: outcome: expected one of {', '.join(OUTCOMES)}, got {record['outcome']!r}")
    if record["run"] < 0:
        raise InputError(f"{where}: run: expected a run index >= 0, got {record['run']}")
    for key in ("truth", "uncertainty"):
        if len(record.get(key, [])) > len(record.get("measured", [])):
            raise InputError(f"{where}: {key}: more entries than measured")
    for sigma in record.get("uncertainty", []):
        if not (isinstance(sigma, dict) and all(isinstance(sigma.get(k), (int, float)) for k in STATED)):
            raise InputError(f"{where}: uncertainty: expected objects of {' and '.join(STATED)} (1 sigma), "
                             f"got {sigma!r}")
    return record


def read_results(folder: Path) -> list[dict[str, Any]]:
    """The validated results of a campaign folder, by run index. A last line without its newline is a
    write the campaign did not finish (it is still running, or was killed) and is left out."""
    path = Path(folder) / RESULTS_FILE
    if not path.is_file():
        raise InputError(f"{path}: not found (a campaign folder holds {RESULTS_FILE}, written by agf simulate)")
    text = path.read_text()
    lines = text.split("\n")[:-1]  # the part after the last newline is unfinished (usually empty)
    results: dict[int, dict[str, Any]] = {}
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        where = f"{path}:{number}"
        try:
            record = validate_result(json.loads(line), where)
        except json.JSONDecodeError as exc:
            raise InputError(f"{where}: not JSON ({exc.msg})") from exc
        if record["run"] in results:
            raise InputError(f"{where}: run {record['run']} appears twice")
        results[record["run"]] = record
    return [results[k] for k in sorted(results)]


def campaign_figures(results: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    """The campaign's summary (``agf simulate``'s JSON): counts, clearance, cycle time and the failures."""
    results = list(results)
    counts = Counter(r["outcome"] for r in results)
    cycles = [r["cycle_s"] for r in results if r["ok"] and "cycle_s" in r]
    clearances = [r["min_clearance_mm"] for r in results if r.get("min_clearance_mm") is not None]
    timed = [r for r in results if "cpu_s" in r]  # campaigns since session 59
    errors = measurement_errors(results)
    failures = [
        {
            "run": r["run"],
            "outcome": r["outcome"],
            "reason": r.get("reason"),
            **({"pallet_in_fork": r["scene"]["pallet_in_fork"]} if "scene" in r else {}),
            **({"log": r["log"]} if r.get("log") else {}),
        }
        for r in results
        if not r["ok"]
    ]
    return {
        "ok": not any(r["collision"] for r in results),
        "runs": len(results),
        "inserted": counts["inserted"],
        "refused": counts["refused"],
        "faulted": counts["faulted"],
        "collisions": sum(r["collision"] for r in results),
        "viewing_moves": sum(r.get("viewing_moves", 0) for r in results),
        "withdrawals": sum(r.get("withdrawals", 0) for r in results),
        "confirmations": sum(r.get("confirmations", 0) for r in results),
        "exposure_changes": sum(r.get("exposure_changes", 0) for r in results),
        "measurements_outside_bounds": sum(not within_bounds(e["error"]) for e in errors),
        "measurements_beyond_stated": {k: len(runs) for k, runs in beyond_stated(errors).items()},
        "min_clearance_mm": min(clearances) if clearances else None,
        "median_cycle_s": statistics.median(cycles) if cycles else None,
        "cpu_s": sum(r["cpu_s"] for r in timed) if timed else None,
        "by_pallet_type": by_pallet_type(results),
        "failures": failures,
    }


def by_pallet_type(results: Iterable[Mapping[str, Any]]) -> dict[str, dict[str, int]]:
    """Per pallet type of the picks' scenes (``agf simulate --pallet-types``): ``{type: {"runs", "inserted",
    "collisions", "measurements_outside_bounds"}}``, types in name order. Picks without a scene (refused before
    the world existed) are left out."""
    results = [r for r in results if r.get("scene")]
    outside = Counter(e["scene"]["pallet_type"] for e in measurement_errors(results) if not within_bounds(e["error"]))
    counts: dict[str, dict[str, int]] = {}
    for r in sorted(results, key=lambda r: r["scene"]["pallet_type"]):
        kind = r["scene"]["pallet_type"]
        row = counts.setdefault(kind, {"runs": 0, "inserted": 0, "collisions": 0,
                                       "measurements_outside_bounds": outside[kind]})
        row["runs"] += 1
        row["inserted"] += r["outcome"] == "inserted"
        row["collisions"] += bool(r["collision"])
    return counts


def reason_class(reason: str | None) -> str:
    """A reason with its numbers replaced by ``#``, so refusals of one kind count together (numbers inside
    words, such as ``0x8130`` or ``cia402``, are part of the kind); of a refused measurement, the first
    search's reason only (what the other searches found made every refusal a kind of its own)."""
    first = (reason or "(no reason given)").split(OTHER_SEARCHES, 1)[0]
    return re.sub(r"(?<![\w.+])[-+]?\d+(\.\d+)?(?!\w)", "#", first)  # "+-0.07" keeps its "+-"


def first_refusals(results: Iterable[Mapping[str, Any]]) -> dict[str, Counter]:
    """The outcomes of the picks whose first measurement was refused, per kind (:func:`reason_class`) of that
    refusal: the reason of the first viewing move (``viewing_reasons``), or the pick's own where it ended on its first
    frame, refused while measuring with no viewing move. The final reason of a pick that moved is its last frame's;
    this is what the first look at the pallet failed on, and the outcomes say how often looking again helped. Only
    results that carry ``viewing_reasons`` count (campaigns since session 57)."""
    kinds: dict[str, Counter] = {}
    for r in results:
        if "viewing_reasons" not in r:
            continue
        if r["viewing_reasons"]:
            first = r["viewing_reasons"][0]
        elif r["outcome"] == "refused" and (r.get("reason") or "").startswith(MEASURING):
            first = r["reason"].removeprefix(MEASURING)
        else:
            continue
        kinds.setdefault(reason_class(first), Counter())[r["outcome"]] += 1
    return dict(sorted(kinds.items(), key=lambda kind: -kind[1].total()))


def outcomes_by_band(results: Iterable[Mapping[str, Any]], key: str, width: float) -> dict[bool, dict[float, Counter]]:
    """The outcomes counted per band of the pallet's start pose, for unloaded (False) and loaded (True) pallets.

    Parameters
    ----------
    key : str
        A key of the scene's ``pallet_in_fork`` (``"z_mm"``, ``"pitch_deg"``, ...).
    width : float
        Band width in the key's unit; a band is named by its lower end, a multiple of ``width``.

    Returns
    -------
    dict
        ``{loaded: {band_low: Counter(outcome -> picks)}}``, bands in increasing order. Picks without a scene
        (refused before the world existed) are left out.
    """
    if not width > 0:
        raise ValueError(f"band width must be positive, got {width}")
    counts: dict[bool, dict[float, Counter]] = {False: {}, True: {}}
    for record in results:
        scene = record.get("scene")
        if scene:
            low = math.floor(scene["pallet_in_fork"][key] / width) * width
            counts[bool(scene.get("loaded"))].setdefault(low, Counter())[record["outcome"]] += 1
    return {loaded: dict(sorted(bands.items())) for loaded, bands in counts.items()}


def measurement_errors(results: Iterable[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Every measurement with its truth: ``{"run", "index", "error": {key: measured - true}, "sigma", "scene"}``,
    ``sigma`` the uncertainty it stated (:data:`STATED`, 1 sigma) or None where the result has none."""
    rows = []
    for r in results:
        stated = r.get("uncertainty", [])
        for i, (measured, true) in enumerate(zip(r.get("measured", []), r.get("truth", []), strict=False)):
            error = {k: measured[k] - true[k] for k in POSE_KEYS}
            sigma = stated[i] if i < len(stated) else None
            rows.append({"run": r["run"], "index": i, "error": error, "sigma": sigma, "scene": r.get("scene")})
    return rows


def beyond_stated(errors: Iterable[Mapping[str, Any]], sigmas: float = SIGMAS) -> dict[str, list[int]]:
    """Per key of :data:`STATED`, the runs of the measurements (among ``errors``, :func:`measurement_errors`, that
    state their uncertainty) whose error exceeds ``sigmas`` times the sigma they stated: a measurement surer of
    itself than it had reason to be."""
    if sigmas <= 0:
        raise ValueError(f"sigmas must be positive, got {sigmas}")
    errors = list(errors)  # read once per key
    return {key: [e["run"] for e in errors if e["sigma"] is not None
                  and abs(e["error"][key]) > sigmas * e["sigma"][key]] for key in STATED}


def _save(figure: Figure, path: Path) -> str:
    figure.savefig(path, dpi=110)
    return path.name


def _error_plot(errors: list[dict[str, Any]], path: Path) -> str:
    """Height and pitch error (rows) against the pallet's pitch, height, yaw and the light (columns)."""
    against = [
        ("true pitch [deg]", lambda s: s["pallet_in_fork"]["pitch_deg"]),
        ("true height z [mm]", lambda s: s["pallet_in_fork"]["z_mm"]),
        ("true yaw [deg]", lambda s: s["pallet_in_fork"]["yaw_deg"]),
        ("light (exposure factor)", lambda s: s["light"]),
    ]
    rows = [("z_mm", "height error [mm]"), ("pitch_deg", "pitch error [deg]")]
    figure = Figure(figsize=(14, 6.5), layout="constrained")
    axes = figure.subplots(len(rows), len(against), sharey="row", squeeze=False)
    usable = [e for e in errors if e["scene"]]
    for column, (xlabel, value) in enumerate(against):
        for row, (key, ylabel) in enumerate(rows):
            ax = axes[row, column]
            for index, (label, marker) in enumerate((("first measurement", "o"), ("verify (aligned)", "^"))):
                chosen = [e for e in usable if (e["index"] > 0) == bool(index)]
                ax.scatter(
                    [value(e["scene"]) for e in chosen],
                    [e["error"][key] for e in chosen],
                    s=18,
                    marker=marker,
                    alpha=0.75,
                    label=label,
                )
            ax.axhline(0.0, color="black", linewidth=0.8)
            ax.grid(True, alpha=0.4)
            ax.set_xlabel(xlabel)
            if column == 0:
                ax.set_ylabel(ylabel)
    axes[0, 0].legend(loc="best", fontsize="small")
    figure.suptitle("measurement error (measured - true pallet_in_fork) against the scene")
    return _save(figure, path)


def _uncertainty_plot(errors: list[dict[str, Any]], path: Path) -> str:
    """Each measurement's absolute height and pitch error against the sigma it stated, with the line of
    :data:`SIGMAS` sigmas and the accuracy bound; measurements outside the bounds in red."""
    figure = Figure(figsize=(11, 4.5), layout="constrained")
    axes = figure.subplots(1, len(STATED), squeeze=False)[0]
    stated = [e for e in errors if e["sigma"] is not None]
    units = {"z_mm": "height [mm]", "pitch_deg": "pitch [deg]"}
    for ax, key in zip(axes, STATED, strict=True):
        for inside, colour, label in ((True, "tab:blue", "within the bounds"), (False, "tab:red", "outside")):
            chosen = [e for e in stated if within_bounds(e["error"]) == inside]
            ax.scatter([e["sigma"][key] for e in chosen], [abs(e["error"][key]) for e in chosen], s=14, alpha=0.7,
                       color=colour, label=label)
        top = max([e["sigma"][key] for e in stated], default=1.0)
        ax.plot([0.0, top], [0.0, SIGMAS * top], "k--", linewidth=1, label=f"{SIGMAS:g} stated sigmas")
        ax.axhline(BOUNDS[key], color="tab:red", linewidth=0.8, label="accuracy bound")
        ax.set_xlabel(f"stated uncertainty, 1 sigma, {units[key]}")
        ax.set_ylabel(f"absolute error, {units[key]}")
        ax.grid(True, alpha=0.4)
    axes[0].legend(loc="best", fontsize="small")
    if not stated:
        figure.text(0.5, 0.5, "no measurement states its uncertainty", ha="center")
    figure.suptitle("measurement error against the uncertainty each measurement stated")
    return _save(figure, path)


def _clearance_plot(results: list[Mapping[str, Any]], path: Path) -> str:
    figure = Figure(figsize=(8, 4), layout="constrained")
    ax = figure.subplots()
    groups = {
        o: [r["min_clearance_mm"] for r in results if r["outcome"] == o and r.get("min_clearance_mm") is not None]
        for o in OUTCOMES
    }
    groups = {o: v for o, v in groups.items() if v}
    if groups:
        values = np.concatenate([v for v in groups.values()])
        low, high = math.floor(min(values.min(), 0.0)), math.ceil(values.max()) + 1
        bins = np.arange(low, high + 1, max(1, math.ceil((high - low) / 200)))  # 1 mm bins up to 200 of them
        ax.hist(list(groups.values()), bins=bins, stacked=True, label=list(groups), color=[COLOURS[o] for o in groups])
        ax.legend()
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.axvline(0.0, color="red", linestyle="--", linewidth=1.2, label="contact")
    ax.set_xlabel("smallest tine-to-pallet clearance over the pick [mm]")
    ax.set_ylabel("picks")
    ax.grid(True, alpha=0.4)
    ax.set_title("clearance distribution (left of the red line: collision)")
    return _save(figure, path)


def _outcome_plot(results: list[Mapping[str, Any]], path: Path) -> str:
    """Stacked outcome counts per band (:data:`BANDS`, columns) of unloaded and loaded pallets (rows)."""
    figure = Figure(figsize=(13, 6.5), layout="constrained")
    axes = figure.subplots(2, len(BANDS), squeeze=False)
    for column, (key, (width, xlabel)) in enumerate(BANDS.items()):
        by_load = outcomes_by_band(results, key, width)
        for row, loaded in enumerate((False, True)):
            ax, bands = axes[row, column], by_load[loaded]
            lows = np.array(list(bands), float)
            bottom = np.zeros(len(lows))
            for outcome in OUTCOMES:
                heights = np.array([bands[low][outcome] for low in bands], float)
                if heights.any():
                    ax.bar(lows + width / 2, heights, width * 0.9, bottom=bottom, color=COLOURS[outcome],
                           label=outcome)
                    bottom += heights
            ax.yaxis.set_major_locator(MaxNLocator(integer=True))
            ax.grid(True, alpha=0.4)
            ax.set_xlabel(xlabel)
            ax.set_ylabel(f"{'loaded' if loaded else 'unloaded'} pallets: picks")
            if bands:
                ax.legend(loc="best", fontsize="small")
    figure.suptitle("outcomes by the pallet's start pose and load")
    return _save(figure, path)


def _height_rows(results: list[Mapping[str, Any]]) -> list[tuple[str, str, str, str]]:
    """The table of :func:`_markdown`'s outcomes by height: band, then inserted / picks of unloaded, loaded, all."""
    width = BANDS["z_mm"][0]
    by_load = outcomes_by_band(results, "z_mm", width)
    rows = []
    for low in sorted(set(by_load[False]) | set(by_load[True])):
        cells = [by_load[loaded].get(low, Counter()) for loaded in (False, True)]
        cells.append(cells[0] + cells[1])
        rows.append((f"{low:+.0f} to {low + width:+.0f}",
                     *(f"{c['inserted']} / {c.total()}" + (f" ({c['inserted'] / c.total():.0%})" if c.total() else "")
                       for c in cells)))
    return rows


def _cycle_plot(results: list[Mapping[str, Any]], path: Path) -> str:
    inserted = [r for r in results if r["ok"] and "cycle_s" in r]
    figure = Figure(figsize=(12, 4), layout="constrained")
    left, right = figure.subplots(1, 2)
    left.hist([r["cycle_s"] for r in inserted], bins=30, color=COLOURS["inserted"])
    left.set_xlabel("pick cycle [s]")
    left.set_ylabel("inserted picks")
    left.yaxis.set_major_locator(MaxNLocator(integer=True))
    left.set_title("cycle time of the inserted picks")
    left.grid(True, alpha=0.4)
    states = list(dict.fromkeys(s for r in inserted for s in r.get("durations_s", {})))
    if states:
        spread = [[r.get("durations_s", {}).get(s, 0.0) for r in inserted] for s in states]
        right.boxplot(spread, tick_labels=states, orientation="horizontal")
    right.set_xlabel("time in state [s]")
    right.set_title("where the time goes (inserted picks)")
    right.grid(True, alpha=0.4)
    return _save(figure, path)


def _table(header: list[str], rows: Iterable[Iterable[Any]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c).replace("|", "\\|") for c in row) + " |" for row in rows]
    return lines + [""]


def _log_link(log: str | None, folder: Path) -> str:
    if not log:
        return "-"
    path = Path(log) if Path(log).is_absolute() else Path(log).resolve()
    if not path.is_file():
        return f"{log} (missing)"
    return f"[{path.name}]({os.path.relpath(path, folder.resolve())})"


def _pose_text(record: Mapping[str, Any]) -> str:
    if "scene" not in record:
        return "-"
    p = record["scene"]["pallet_in_fork"]
    return f"x {p['x_mm']:.0f}, z {p['z_mm']:.0f} mm, pitch {p['pitch_deg']:.2f}, yaw {p['yaw_deg']:.2f} deg"


def _percentile(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else math.nan


def _markdown(folder: Path, meta: Mapping[str, Any], results: list[dict[str, Any]], plots: dict[str, str]) -> str:
    figures = campaign_figures(results)
    runs = len(results)
    what = f"{meta['random']} random picks, seed {meta['seed']}" if meta.get("random") else f"scene {meta.get('scene')}"
    lines = [f"# Simulation campaign: {what}", ""]
    lines += [f"{runs} results in `{RESULTS_FILE}` (campaign started {meta.get('created_utc', '?')}).", ""]
    if meta.get("random") and runs < meta["random"]:
        lines += [f"The campaign is unfinished ({runs} of {meta['random']} picks): `--resume --out` runs the rest.", ""]
    lines += ["## Outcomes", ""]
    counts = Counter(r["outcome"] for r in results)
    lines += _table(
        ["outcome", "picks", "share"], [(o, counts[o], f"{counts[o] / max(runs, 1):.1%}") for o in OUTCOMES]
    )
    clearance, cycle = figures["min_clearance_mm"], figures["median_cycle_s"]
    lines += [
        f"Smallest clearance over all picks: {'-' if clearance is None else f'{clearance:.1f} mm'}; "
        f"median cycle of the inserted picks: {'-' if cycle is None else f'{cycle:.1f} s'}.",
        "",
    ]
    cpu = [r["cpu_s"] for r in results if "cpu_s" in r]
    if cpu:
        lines += [f"Computing: {sum(cpu) / 60:.1f} CPU minutes over {len(cpu)} picks, {statistics.median(cpu):.1f} s "
                  f"a pick (median), {max(cpu):.1f} s at most; the wall time of the campaign is about this over the "
                  "cores it ran on.", ""]
    if any("viewing_moves" in r for r in results):
        viewed = sum(r.get("viewing_moves", 0) > 0 for r in results)
        lines += [
            f"Picks that needed a viewing move to measure again (the forks hid the pallet, or a refused "
            f"measurement's confirmed pose lay well above them, and the lift moved level with it; or a refused "
            f"first measurement had no such move, and the lift rose a little to look once more): {viewed}, "
            f"with {figures['viewing_moves']} moves in all.",
            "",
        ]
    lines += _measured_again(results, "withdrawals", "Picks whose verifying measurement was refused, so that the "
                             "forks withdrew along their insertion line to measure again")
    lines += _measured_again(results, "confirmations", "Picks whose last verifying frame was refused and its face "
                             "confirmed where the plan expects it, at the pitch measured before")
    lines += _measured_again(results, "exposure_changes", "Picks measured again with a shorter exposure (clipped "
                             "highlights beside the deck's edges)")
    lines += ["## Outcomes by pallet height and load", ""]
    heights = _height_rows(results)
    if heights:
        lines += ["Inserted of the picks, by the pallet's height at the start: its front face's centre at pocket "
                  "mid-height above the point between the fork tips (fork frame z), unloaded and loaded.", ""]
        lines += _table(["height [mm]", "unloaded", "loaded", "all"], heights)
    else:
        lines += ["No result carries its scene.", ""]
    lines += [f"![outcomes by scene]({plots['outcomes']})", ""]
    kinds = figures["by_pallet_type"]
    if len(kinds) > 1:
        lines += ["## Outcomes by pallet type", ""]
        lines += _table(["pallet type", "picks", "inserted", "collided", "measurements outside the bounds"],
                        [(kind, c["runs"], f"{c['inserted']} ({c['inserted'] / c['runs']:.0%})", c["collisions"],
                          c["measurements_outside_bounds"]) for kind, c in kinds.items()])
    failed = [r for r in results if not r["ok"]]
    for outcome in ("refused", "faulted", "collided"):
        reasons = Counter(reason_class(r.get("reason")) for r in failed if r["outcome"] == outcome)
        if reasons:
            lines += [f"## {outcome.capitalize()}: reasons", ""]
            lines += _table(["reason", "picks"], reasons.most_common())
    firsts = first_refusals(results)
    if firsts:
        lines += ["## First measurement refused: reasons", ""]
        lines += ["Picks whose first frame was refused, by why (a pick's own reason is its last frame's), and how many "
                  "inserted in the end, after viewing moves or shorter exposures.", ""]
        lines += _table(["reason", "picks", "inserted in the end"],
                        [(kind, c.total(), c["inserted"]) for kind, c in firsts.items()])
    lines += ["## Failures", ""]
    if failed:
        rows = [
            (r["run"], r["outcome"], r.get("reason") or "-", _pose_text(r), _log_link(r.get("log"), folder))
            for r in failed
        ]
        lines += _table(["run", "outcome", "reason", "pallet at the start (in fork)", "recorder log"], rows)
    else:
        lines += ["None: every pick inserted.", ""]
    errors = measurement_errors(results)
    lines += ["## Measurement error", ""]
    if errors:
        stats = []
        for key in POSE_KEYS:
            values = [abs(e["error"][key]) for e in errors]
            stats.append((key, f"{np.median(values):.2f}", f"{_percentile(values, 95):.2f}", f"{max(values):.2f}"))
        lines += [f"{len(errors)} measurements against the rendered truth (absolute error, mm and deg).", ""]
        lines += _table(["pallet_in_fork", "median", "95th percentile", "max"], stats)
        wrong = [e for e in errors if not within_bounds(e["error"])]
        bounds = ", ".join(f"|{key}| <= {bound:g}" for key, bound in BOUNDS.items())
        runs = ", ".join(str(run) for run in sorted({e["run"] for e in wrong}))
        lines += [f"Accepted measurements outside the accuracy bounds ({bounds}): **{len(wrong)}**"
                  + (f", in runs {runs}." if wrong else "."), ""]
        lines += _stated_lines(errors)
    lines += [f"![measurement error]({plots['error']})", "", f"![stated uncertainty]({plots['uncertainty']})", "",
              "## Clearance", "", f"![clearance]({plots['clearance']})"]
    lines += ["", "## Cycle times", "", f"![cycle times]({plots['cycle']})", ""]
    return "\n".join(lines)


def _stated_lines(errors: list[dict[str, Any]]) -> list[str]:
    """The report's line on how the measurements' errors compare with the uncertainty they stated."""
    stated = sum(e["sigma"] is not None for e in errors)
    if not stated:
        return ["No measurement states its uncertainty (a campaign from before results carried it).", ""]
    beyond = beyond_stated(errors)

    def count(key: str) -> str:
        runs = sorted(set(beyond[key]))
        return f"{len(beyond[key])} in {key}" + (f" (runs {', '.join(map(str, runs))})" if runs else "")

    return [f"Of the {stated} measurements that state their uncertainty (1 sigma), {' and '.join(map(count, STATED))} "
            f"erred by more than {SIGMAS:g} of their sigmas: such a measurement was surer of itself than it had reason "
            "to be.", ""]


def write_report(folder: Path) -> dict[str, Any]:
    """Write ``report.md`` and its PNG plots into the campaign ``folder``; the campaign's figures and the
    files written."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: not a campaign folder (agf simulate --out writes one)")
    results = read_results(folder)
    meta_path = folder / CAMPAIGN_FILE
    try:
        meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
    except json.JSONDecodeError as exc:
        raise InputError(f"{meta_path}: not JSON ({exc.msg})") from exc
    errors = measurement_errors(results)
    plots = {
        "error": _error_plot(errors, folder / "measurement_error.png"),
        "uncertainty": _uncertainty_plot(errors, folder / "stated_uncertainty.png"),
        "clearance": _clearance_plot(results, folder / "clearance.png"),
        "cycle": _cycle_plot(results, folder / "cycle_times.png"),
        "outcomes": _outcome_plot(results, folder / "outcomes_by_scene.png"),
    }
    report = folder / REPORT_FILE
    report.write_text(_markdown(folder, meta, results, plots))
    figures = campaign_figures(results)
    return {**figures, "report": str(report), "plots": [str(folder / p) for p in plots.values()]}
