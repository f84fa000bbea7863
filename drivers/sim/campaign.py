"""Campaigns of simulated picks: many picks side by side, each result streamed to disk as it finishes.

A campaign folder holds ``campaign.json`` (what was run: scene or random count, seed, config) and
``results.jsonl``, one JSON object per finished pick, written with one ``write`` and flushed to disk, so
a campaign interrupted at pick 700 keeps 700 results and ``--resume`` runs only the picks it lacks.
``agf report`` (:mod:`agf.report`) reads the folder.

Picks run on a :class:`CampaignBackend`: a process pool on this machine (the default), or Ray tasks on
a local Ray or an existing cluster. Back ends override :meth:`CampaignBackend.imap` only. A pick is a
picklable function of its run index alone, so any pick is reproducible without the others.
"""

from __future__ import annotations

import collections
import contextlib
import functools
import json
import multiprocessing
import os
import tempfile
import time
import traceback
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from tqdm import tqdm

from agf.errors import AgfError, ConfigError, InputError, NotAvailableError
from agf.heap import keep_freed_memory
from agf.report import CAMPAIGN_FILE, RESULTS_FILE, campaign_figures, read_results, validate_result

Pick = Callable[[int], dict[str, Any]]

# Picks in flight per Ray CPU: enough to keep every worker busy, few enough that waiting on them is cheap
# (ray.wait scans its whole list, so 100,000 submitted at once would cost more than the picks).
RAY_IN_FLIGHT_PER_CPU = 2


class CampaignInterrupted(AgfError):
    """The operator stopped a campaign; the results so far are kept and ``--resume`` finishes it."""


def run_one(pick: Pick, index: int) -> tuple[int, dict[str, Any]]:
    """``pick(index)`` with its run index, wall time (``wall_s``, unless the pick gives its own) and the CPU time its
    process spent on it (``cpu_s``, every thread: a worker runs one pick at a time; unlike wall time, it does not
    grow with what else the machine runs); a pick that crashes is recorded as faulted with the exception, so one
    bug does not lose a night's campaign."""
    keep_freed_memory()  # a Ray worker's process was not started by agf's command line, which keeps it
    start, cpu = time.monotonic(), time.process_time()
    try:
        record = pick(index)
    except (ConfigError, InputError):  # the user's mistake, the same for every pick: stop and say so
        raise
    except Exception as exc:  # noqa: BLE001 - recorded with its reason, counted as a fault
        where = traceback.extract_tb(exc.__traceback__)[-1]
        reason = f"the pick crashed: {type(exc).__name__}: {exc} ({Path(where.filename).name}:{where.lineno})"
        record = {"ok": False, "outcome": "faulted", "reason": reason, "collision": False, "min_clearance_mm": None}
    return index, {"run": index, "wall_s": time.monotonic() - start, **record, "cpu_s": time.process_time() - cpu}


class CampaignBackend(ABC):
    """Runs picks side by side. ``jobs``: picks at once (None: one per core or cluster CPU)."""

    def __init__(self, jobs: int | None = None) -> None:
        if jobs is not None and jobs <= 0:
            raise InputError(f"--jobs: expected a positive number of picks side by side, got {jobs}")
        self.jobs = jobs

    def describe(self) -> str:
        return type(self).__name__

    def close(self) -> None:  # noqa: B027 - optional hook: the process pool holds nothing between campaigns
        """Release what the back end started."""

    @abstractmethod
    def imap(self, pick: Pick, indices: Sequence[int]) -> Iterator[tuple[int, dict[str, Any]]]:
        """``run_one(pick, index)`` for every index, yielded as each finishes (in any order)."""


def _own_core(counter: Any) -> None:
    """Pin a pool worker to a core of its own: jobs rendering on every core starved the others' drive
    threads into heartbeat and following-error faults (5 of 200 picks)."""
    with counter.get_lock():
        index = counter.value
        counter.value += 1
    cores = sorted(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {cores[index % len(cores)]})


class PoolBackend(CampaignBackend):
    """Forked worker processes on this machine, one per core by default, each pinned to its core."""

    def describe(self) -> str:
        return "process pool"

    def imap(self, pick: Pick, indices: Sequence[int]) -> Iterator[tuple[int, dict[str, Any]]]:
        jobs = min(self.jobs or len(os.sched_getaffinity(0)), len(indices))
        call = functools.partial(run_one, pick)
        if jobs <= 1:
            yield from map(call, indices)
            return
        context = multiprocessing.get_context("fork")
        with context.Pool(jobs, _own_core, (context.Value("i", 0),)) as pool:
            yield from pool.imap_unordered(call, indices)


class RayBackend(CampaignBackend):
    """Ray tasks (one CPU each): on the cluster at ``address`` (``auto``, ``HOST:PORT`` or
    ``ray://HOST:10001``), else on a local Ray started for the campaign and shut down after it. The
    cluster's nodes need this package, its configs and camera files at the paths this machine uses
    (the pick carries the loaded config and scene, whose files are named by absolute path)."""

    def __init__(self, jobs: int | None = None, address: str | None = None) -> None:
        super().__init__(jobs)
        try:
            import ray
        except ImportError as exc:
            raise NotAvailableError(
                "--backend ray needs Ray, which is not installed: pip install -e '.[cluster]' "
                "(or python3 -m pip install 'ray[default]'); the default --backend pool needs nothing more"
            ) from exc
        self.ray, self.address, self._started = ray, address, False

    def describe(self) -> str:
        return f"Ray at {self.address}" if self.address else "local Ray"

    def _connect(self) -> None:
        if self.ray.is_initialized():
            return
        local = {} if self.address else {"num_cpus": self.jobs or len(os.sched_getaffinity(0))}
        try:
            self.ray.init(address=self.address, include_dashboard=False, log_to_driver=False, **local)
        except Exception as exc:  # noqa: BLE001 - Ray raises bare Exception when its local node does not start
            where = (
                f"--address {self.address}: could not connect to a Ray cluster"
                if self.address
                else ("could not start a local Ray for the campaign")
            )
            raise NotAvailableError(f"{where} ({exc})") from exc
        self._started = True

    def imap(self, pick: Pick, indices: Sequence[int]) -> Iterator[tuple[int, dict[str, Any]]]:
        self._connect()
        task = self.ray.remote(num_cpus=1)(run_one)
        pick_ref = self.ray.put(pick)
        limit = self.jobs or max(int(self.ray.cluster_resources().get("CPU", 1)), 1)
        waiting, pending = collections.deque(indices), []
        try:
            while waiting or pending:
                while waiting and len(pending) < limit * RAY_IN_FLIGHT_PER_CPU:
                    pending.append(task.remote(pick_ref, waiting.popleft()))
                done, pending = self.ray.wait(pending, num_returns=1)
                yield self.ray.get(done[0])
        finally:
            for ref in pending:
                self.ray.cancel(ref, force=True)

    def close(self) -> None:
        if self._started:
            self.ray.shutdown()
            self._started = False


def make_backend(name: str, *, jobs: int | None = None, address: str | None = None) -> CampaignBackend:
    """The back end ``--backend`` names: ``pool`` or ``ray``."""
    if name == "pool":
        if address is not None:
            raise InputError("--address names a Ray cluster: use it with --backend ray")
        return PoolBackend(jobs)
    if name == "ray":
        return RayBackend(jobs, address)
    raise InputError(f"--backend: expected pool or ray, got {name!r}")


class ResultsFile:
    """``results.jsonl`` of a campaign folder, appended one whole line per pick."""

    def __init__(self, folder: Path) -> None:
        self.path = folder / RESULTS_FILE

    def repair(self) -> None:
        """Cut a last line that an interrupted write left without its newline (that pick runs again)."""
        if not self.path.is_file():
            return
        data = self.path.read_bytes()
        keep = data.rfind(b"\n") + 1
        if keep < len(data):
            with self.path.open("r+b") as f:
                f.truncate(keep)

    def append(self, record: dict[str, Any]) -> None:
        line = (json.dumps(record, allow_nan=False) + "\n").encode()
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            written = os.write(fd, line)
            while written < len(line):  # a regular file takes the line in one write; loop for the rule
                written += os.write(fd, line[written:])
            os.fsync(fd)
        finally:
            os.close(fd)


def _open_folder(folder: Path, identity: dict[str, Any], resume: bool) -> dict[int, dict[str, Any]]:
    """Prepare ``folder`` for the campaign ``identity``; the results it already holds when resuming."""
    meta = folder / CAMPAIGN_FILE
    results = ResultsFile(folder)
    if resume:
        if not meta.is_file():
            raise InputError(f"--resume: {folder} holds no campaign ({CAMPAIGN_FILE} not found)")
        try:
            recorded = json.loads(meta.read_text())
        except json.JSONDecodeError as exc:
            raise InputError(f"--resume: {meta}: not JSON ({exc.msg})") from exc
        # Keys either side holds: a key only the folder records (a campaign of several pallet types) differs too.
        keys = dict.fromkeys([*identity, *(k for k in recorded if k != "created_utc")])
        differs = {k: (recorded.get(k), identity.get(k)) for k in keys if recorded.get(k) != identity.get(k)}
        if differs:
            detail = ", ".join(f"{k}: {a!r} there, {b!r} now" for k, (a, b) in differs.items())
            raise InputError(f"--resume: {folder} holds another campaign ({detail})")
        results.repair()
        return {r["run"]: r for r in read_results(folder)}
    if results.path.is_file() and results.path.stat().st_size:
        raise InputError(
            f"--out {folder}: already holds a campaign's results; add --resume to finish it, or choose a new --out"
        )
    folder.mkdir(parents=True, exist_ok=True)
    created = datetime.now(UTC).isoformat(timespec="seconds")
    meta.write_text(json.dumps({**identity, "created_utc": created}, indent=2) + "\n")
    return {}


def run_campaign(
    pick: Pick,
    indices: Sequence[int],
    identity: dict[str, Any],
    *,
    out: Path | None,
    backend: CampaignBackend,
    resume: bool = False,
    progress: bool = True,
) -> dict[str, Any]:
    """Run ``pick(index)`` for every index the folder ``out`` does not hold yet, appending each result
    to its ``results.jsonl`` as it finishes, with a progress bar on stderr when ``progress``.

    Parameters
    ----------
    pick : callable
        ``pick(index) -> dict``, picklable (it runs in other processes or on other machines), with the
        per-pick keys :func:`agf.report.validate_result` checks.
    indices : sequence of int
        The campaign's run indices to have results for.
    identity : dict
        What the campaign is (scene, random count, seed, ...); ``--resume`` refuses a folder whose
        ``campaign.json`` differs.
    out : Path or None
        The campaign folder; None: a temporary one, removed afterwards.
    backend : CampaignBackend
        Where the picks run; closed when the campaign ends.

    Returns
    -------
    dict
        :func:`agf.report.campaign_figures` over every result of the folder, the folder (``out``) and
        the back end.
    """
    with contextlib.ExitStack() as stack:
        stack.callback(backend.close)
        folder = out if out is not None else Path(stack.enter_context(tempfile.TemporaryDirectory()))
        done = _open_folder(folder, identity, resume)
        todo = [k for k in indices if k not in done]
        results = ResultsFile(folder)
        bar = stack.enter_context(
            tqdm(
                total=len(indices),
                initial=len(indices) - len(todo),
                desc="agf simulate",
                unit="pick",
                disable=not progress,
                dynamic_ncols=True,
                bar_format="{desc}: {n_fmt}/{total_fmt} picks |{bar}| {elapsed}<{remaining}{postfix}",
            )
        )
        wanted = set(indices)
        inserted = sum(r["ok"] for k, r in done.items() if k in wanted)
        bar.set_postfix_str(f"{inserted} inserted")
        try:
            for index, record in stack.enter_context(contextlib.closing(backend.imap(pick, todo))):
                results.append(validate_result(record, f"{folder}: the result of run {index}"))
                done[index] = record
                inserted += record["ok"]
                bar.set_postfix_str(f"{inserted} inserted", refresh=False)
                bar.update()
        except KeyboardInterrupt:
            kept = sum(k in done for k in wanted)
            raise CampaignInterrupted(
                f"interrupted by the operator after {kept} of {len(indices)} picks; the results are kept in "
                f"{folder}: the same command with --resume --out {folder} finishes the campaign"
            ) from None
        figures = campaign_figures(read_results(folder))
    return {**figures, **({"out": str(out)} if out is not None else {}), "backend": backend.describe()}
