"""One pick on the wall clock and on the simulated clock: the same setpoints, drive physics and CAN
messages give the same trajectory. And the pick the forks hid the pallet in (random pick 16 of
``agf simulate --random 30 --seed 4242`` as campaigns drew their scenes before each pick had a generator
of its own) now moves the forks to a viewing pose and inserts."""

from __future__ import annotations

import contextlib
import functools
import math
from typing import Any

import numpy as np
import pytest

from agf.clock import Clock, SimulatedClock, WallClock
from agf.config import load_config
from agf.controller import ControllerConfig, PickResult
from agf.errors import DriveFault, MeasurementError
from agf.paths import DEFAULT_CONFIG, repo_path
from agf.scene import Scene, load_scene
from drivers.sim import fast_render
from drivers.sim import world as world_module
from drivers.sim.world import RenderedCamera, SimulatedWorld, pick_summary, simulate_command
from tests.integration.conftest import campaign_scene_of

pytestmark = pytest.mark.usefixtures("point_sampled_texture")  # the frames these tests were written on

CONFIG = load_config(DEFAULT_CONFIG)
SCENE = load_scene(repo_path("configs/scenes/pick.yaml"))
HIDDEN = repo_path("tests/data/scenes/robust/loaded-below-the-forks-hidden.yaml")


class SharedFrames(RenderedCamera):
    """Frames rendered once, by the simulated-clock pick, and handed to the wall-clock pick where its
    forks stand where they stood (within the controller's arrival tolerance, 2 mm), with their
    measurements: the wall-clock pick then computes nothing heavy that could starve its real-time
    threads on a busy machine, and both picks plan from the same measurements."""

    def __init__(self, world: SimulatedWorld, taken: list[tuple[dict[str, float], np.ndarray]]) -> None:
        super().__init__(world)
        self.taken = taken

    def _read(self, timeout: float) -> np.ndarray | None:
        now = self.world.positions()
        for positions, image in self.taken:
            if all(abs(positions[n] - now[n]) <= 2e-3 for n in now):
                return image
        image = super()._read(timeout)
        self.taken.append((now, image))
        return image


def pick_on(clock: Clock, taken: list, measured: dict) -> tuple[dict, dict, dict[str, float]]:
    with SimulatedWorld(CONFIG, SCENE, clock) as world:
        settle(world)
        controller = world.controller()
        controller.frames = SharedFrames(world, taken)
        measure = controller.measure

        def measure_once(frame, prior):
            if id(frame.image) not in measured:
                measured[id(frame.image)] = measure(frame, prior)
            return measured[id(frame.image)]

        controller.measure = measure_once
        if clock.realtime:
            controller.on_cycle = None  # no collision check: less work in the real-time loop
        result = controller.run()
        settle(world)  # on the last setpoints: 0.5 s was not always enough for a loaded machine's late SYNCs
        rest = world.positions()
        counts = {name: abs(axis.drive.counts_per_unit) for name, axis in world.network.axes.items()}
        return {"result": result, "summary": pick_summary(result, world)}, counts, rest


def settle(world: SimulatedWorld) -> None:
    """Let the axes come to rest (their counts unchanged over 0.25 s): on the start pose, so both picks start
    from the same one, and on a pick's last set-points; on a busy machine the wall clock's SYNCs run late."""
    def counts() -> dict[str, int]:
        return {name: round(world.positions()[name] * axis.drive.counts_per_unit)
                for name, axis in world.network.axes.items()}

    # Sleep before comparing: compared at once, the counts were always unchanged, and the wall-clock pick
    # was read where it arrived, anywhere within the 2 mm arrival tolerance of its last set-points.
    before = counts()
    for _ in range(500):
        world.clock.sleep(0.25)
        now = counts()
        if now == before:
            return
        before = now


def rows(result, state: str, key: str, axis: str) -> tuple[np.ndarray, np.ndarray]:
    """Time since the motion's start (s) and one axis's setpoint or actual position. Not since its first
    logged cycle: on a busy machine the wall clock's first cycle came 4 ms after the start, and the
    setpoints compared 4 ms apart differed by 1.2 mm."""
    log = [row for row in result.log if row["state"] == state]
    return np.array([row["motion_t"] for row in log]), np.array([row[key][axis] for row in log])


@pytest.fixture(scope="module")
def both_clocks():
    taken: list = []
    measured: dict = {}
    simulated = pick_on(SimulatedClock(), taken, measured)
    faults = []
    for _ in range(3):  # real time on a machine shared by many: its threads may be starved
        try:
            wall = pick_on(WallClock(), taken, measured)
        except DriveFault as exc:
            faults.append(str(exc))
            continue
        if wall[0]["result"].ok or "drive fault" not in (wall[0]["result"].reason or ""):
            break
        faults.append(wall[0]["result"].reason)
    else:
        pytest.skip(f"the wall-clock pick faulted three times on this busy machine: {faults}")
    assert len(taken) == 2 and len(measured) == 2  # the wall-clock pick saw the same two frames
    return wall, simulated


@pytest.mark.xdist_group("both_clocks")  # one worker makes the two picks for both
def test_a_pick_on_simulated_time_takes_the_same_trajectory_as_on_wall_time(both_clocks):
    (wall, counts, wall_rest), (simulated, _, sim_rest) = both_clocks
    a, b = wall["result"], simulated["result"]
    assert a.ok and b.ok, (a.reason, b.reason)
    assert [m.pallet_in_fork.to_dict() for m in a.measurements] == [m.pallet_in_fork.to_dict() for m in b.measurements]
    for name, count in counts.items():
        one = 1.0 / count
        assert a.plan.align[name] == pytest.approx(b.plan.align[name], abs=one)
        assert a.plan.insert.get(name, 0.0) == pytest.approx(b.plan.insert.get(name, 0.0), abs=one)
        # In counts: a one-count difference, 2e-6 rad on the tilt, failed approx(abs=one) on its float rounding.
        assert abs(round(wall_rest[name] * count) - round(sim_rest[name] * count)) <= 1, (name, wall_rest, sim_rest)
    cycle = CONFIG.sections["drives"]["cycle_ms"] / 1e3
    # The align motion starts from the same pose on both clocks; the insert motion from wherever the
    # align motion arrived, which on the wall clock is anywhere within the arrival tolerance.
    for name, count in counts.items():
        t_wall, set_wall = rows(a, "aligning", "setpoint", name)
        t_sim, set_sim = rows(b, "aligning", "setpoint", name)
        assert np.allclose(np.diff(t_sim), cycle)  # exactly one SYNC per cycle of simulated time
        # The same motion: the simulated setpoints, interpolated at the wall clock's cycle times, within
        # two counts plus the linear interpolation's own error, h**2/8 times the largest acceleration
        # (a second difference of the setpoints is acceleration times h**2). Taking that error as
        # "under a count" failed CI by 0.1 count on a motion that accelerates harder.
        interpolation = np.abs(np.diff(set_sim, 2)).max() / 8
        assert np.abs(np.interp(t_wall, t_sim, set_sim) - set_wall).max() <= 2.0 / count + interpolation
        _, actual_wall = rows(a, "aligning", "actual", name)
        _, actual_sim = rows(b, "aligning", "actual", name)
        # On the wall clock the stream's time counts SYNCs, which a busy machine sends a few cycles late
        # (PickController._watch_motion), so the actual positions follow the same motion later than the logged
        # set-point time, and by a lag that grows whenever a SYNC is late. Compared at the logged time, within two
        # counts and two cycles' travel, CI failed at 2.6 cycles with two other processes busy beside it; with the one
        # delay that fit best, it failed with four (tilt 0.00085 rad off at no delay, on a lag that changed during the
        # motion). So each position is matched at its own lag: under ten cycles, and there within the same two counts
        # and two cycles' travel (idle, it is no delay).
        speed = np.abs(np.gradient(set_sim, t_sim)).max()
        delays = np.arange(0.0, 10 * cycle, cycle / 10)
        misfit = np.abs(np.interp(t_wall[:, None] - delays, t_sim, actual_sim) - actual_wall[:, None])  # (T, D)
        lag = misfit.argmin(axis=1)
        worst = int(np.argmax(misfit.min(axis=1)))
        assert lag.max() < len(delays) - 1, (name, t_wall[lag.argmax()])  # positions lagging 10 cycles or more
        assert misfit[worst, lag[worst]] <= 2.0 / count + 2 * cycle * speed, (
            name, t_wall[worst], delays[lag[worst]], misfit[worst, lag[worst]])


@pytest.mark.xdist_group("both_clocks")  # one worker makes the two picks for both
def test_on_simulated_time_the_vision_takes_no_motion_time(both_clocks):
    (wall, *_), (simulated, *_) = both_clocks
    b = simulated["result"]
    assert b.durations["measuring"] == 0.0 and b.durations["verifying"] == 0.0
    assert b.wall_durations["acquiring"] > 0.1  # rendering took wall time, but no simulated time
    # The motion states last what the motion does, on both clocks.
    for state in ("aligning", "inserting"):
        assert b.durations[state] == pytest.approx(wall["result"].durations[state], abs=0.5)
    assert simulated["summary"]["cycle_s"] > sum(b.durations.values())  # the vision's compute time counted


def test_a_simulated_world_starts_with_its_axes_at_the_start_pose_to_the_count():
    """The simulated truck arrives with its forks at the start pose (its drives are placed there): no setup
    move, which ended within 0.1 mm of it and took 0.6 s of wall time a pick."""
    from drivers.sim.world import START

    with SimulatedWorld(CONFIG, SCENE) as world:
        positions = world.positions()
        counts = {name: axis.drive.counts_per_unit for name, axis in world.axes.items()}
    assert all(abs(positions[name] - START.get(name, 0.0)) * counts[name] < 1 for name in positions), positions


def viewed_pick(scene: Scene) -> tuple[dict[str, float], PickResult, dict[str, Any], list[dict[str, Any]]]:
    """The pick of ``scene`` in a simulated world: the axes at its start, its result, its summary and its log's rows
    in the viewing state."""
    with SimulatedWorld(CONFIG, scene) as world:
        start = world.positions()
        result = world.controller().run()
        summary = pick_summary(result, world)
    return start, result, summary, [row for row in result.log if row["state"] == "viewing"]


def test_forks_hiding_the_pallet_move_to_a_viewing_pose_and_the_pick_inserts():
    scene = load_scene(HIDDEN)
    start, result, summary, viewing = viewed_pick(scene)
    assert result.ok, result.reason
    assert len(result.views) == 1 and "the forks hide" in result.views[0]
    assert summary["viewing_moves"] == 1 and summary["viewing_reasons"] == result.views and not summary["collision"]
    # Lift only, level with the pockets: the pallet stood 292 mm below the forks. The rough pose of a
    # pallet the forks hide errs along the camera's steep line of sight (27 mm at 1.6 m: 16 mm in reach,
    # 22 mm in height since 931c02c): the move must land within a third of the JIS T11's 90 mm pocket.
    assert viewing[-1]["actual"]["lift"] - start["lift"] == pytest.approx(-0.292, abs=0.03)
    assert all(abs(row["actual"]["reach"] - start["reach"]) < 1e-4 for row in viewing)


def test_a_refused_measurement_far_above_the_forks_is_measured_again_from_level_and_the_pick_inserts():
    """Campaign pick 16 of seed 4242: an unloaded pallet 158 mm above the forks, refused from there ("a second
    line runs beside the unloaded edges", the forks hiding nothing); the search's rough pose lifts the forks
    level with it, and from there it is measured and picked. (Should the vision one day measure it from
    below, this test needs another refused pick: it tests the viewing move, not that refusal.)"""
    from drivers.sim.world import campaign_scene

    scene = campaign_scene(load_scene(repo_path("configs/scenes/pick.yaml")), 4242, 16)
    start, result, summary, viewing = viewed_pick(scene)
    assert result.ok, result.reason
    assert len(result.views) == 1 and "the forks hide" not in result.views[0], result.views
    assert summary["viewing_moves"] == 1 and not summary["collision"]
    assert viewing[-1]["actual"]["lift"] - start["lift"] == pytest.approx(0.158, abs=0.03)
    assert all(abs(row["actual"]["reach"] - start["reach"]) < 1e-4 for row in viewing)



def test_a_refused_measurement_with_no_level_view_is_measured_again_from_higher_and_the_pick_inserts():
    """Campaign pick 95 of seed 7: a loaded pallet 12 mm below the forks, pitched -5.0 deg, refused ("no pitch:
    neither the deck edges ... nor the load edges ...") with no view level with it that helps (it lies below:
    view_helps never lowers the forks). The forks rise insertion.look_again_lift_mm (100), lift only, and from there it
    is measured and picked. (Pick 23 showed it until session 48, whose renderer change let the vision measure its
    first frame; should that happen here, this test needs another such pick: it tests the move, not that refusal.)"""
    scene = campaign_scene_of(7, 95)
    start, result, summary, viewing = viewed_pick(scene)
    assert result.ok, result.reason
    assert len(result.views) == 1, result.views
    assert summary["viewing_moves"] == 1 and not summary["collision"]
    assert viewing[-1]["actual"]["lift"] - start["lift"] == pytest.approx(0.1, abs=0.002)
    assert all(row["actual"]["lift"] >= start["lift"] - 0.002 for row in viewing)  # never down
    assert all(abs(row["actual"]["reach"] - start["reach"]) < 1e-4 for row in viewing)


def test_a_pick_refused_from_higher_too_looks_once_more_from_higher_still_and_inserts():
    """Campaign pick 254 of seed 7: an unloaded pallet pitched -3.4 deg whose deck edges were refused at the start
    ("the unloaded edges run 1.9 deg across the pallet's axis") and from 100 mm higher ("no pitch: neither ... were
    found"); from 200 mm higher it is measured and picked (session 42: ``ControllerConfig.views`` 2; with one view
    the pick ended refused). (Should the vision one day measure one of those frames, this test needs another such
    pick: it tests the second move, not those refusals.)"""
    scene = campaign_scene_of(7, 254)
    start, result, summary, viewing = viewed_pick(scene)
    assert result.ok, result.reason
    assert len(result.views) == 2 and summary["viewing_moves"] == 2 and not summary["collision"]
    assert viewing[-1]["actual"]["lift"] - start["lift"] == pytest.approx(0.2, abs=0.002)
    assert all(abs(row["actual"]["reach"] - start["reach"]) < 1e-4 for row in viewing)


def test_a_pick_refused_after_two_viewing_moves_makes_a_third_and_inserts():
    """Campaign pick 205 of seed 7: a loaded pallet 260 mm above the forks, pitched 1.55 deg, refused at the start
    (its load's edges and face lines disagree), level with its rough pose (the same) and 100 mm higher (its top face
    disagrees), is measured after a third move, 100 mm higher still (``ControllerConfig.views`` 3 since session 45),
    and picked. Each move raises the forks by at least 100 mm (``look_again_lift_mm``, or level with the rough pose
    where that is at least ``view_min_lift_mm`` higher). The forks end 460 mm higher. (Picks 57, 4 and 597 showed it
    until sessions 48, 50 and 54 let the vision measure an earlier frame of theirs; should that happen here, this test
    needs another such pick: it tests the third move, not those refusals. Session 55 found this one among seed 7's
    picks 200-499 whose pallet stands over 200 mm above the forks.)"""
    scene = campaign_scene_of(7, 205)
    start, result, summary, viewing = viewed_pick(scene)
    assert result.ok, result.reason
    assert len(result.views) == 3 and summary["viewing_moves"] == 3 and not summary["collision"]
    assert viewing[-1]["actual"]["lift"] - start["lift"] >= 0.3 - 0.002
    assert all(row["actual"]["lift"] >= start["lift"] - 0.002 for row in viewing)  # never down
    assert all(abs(row["actual"]["reach"] - start["reach"]) < 1e-4 for row in viewing)


def test_regression_campaign_pick_379_of_seed_7_a_hidden_pallet_whose_pose_the_image_does_not_confirm_is_no_move():
    """Pick 379 (unloaded, 226 mm below the forks, pitched -4.4 deg) with a third viewing move (session 45): refused
    at the start and from 100 and 200 mm higher, where one search found the pallet hidden by the forks with a pose
    159 mm too low; the viewing move lowered the forks 585 mm, 87.5 mm into the dock under the pallet. A hidden
    pallet's pose now counts only where the image confirms its face edges on average, as any rough pose: the pick
    ends refused, no lower than it started."""
    scene = campaign_scene_of(7, 379)
    start, result, summary, viewing = viewed_pick(scene)
    assert not summary["collision"] and summary["min_support_clearance_mm"] > 0, summary
    assert all(row["actual"]["lift"] >= start["lift"] - 0.002 for row in viewing)


def test_regression_a_pick_hidden_after_looking_again_ends_refused_not_faulted():
    """Seed 7 pick 763 (loaded, 247 mm below the forks): refused at the start, and from 100 mm higher the forks hid
    its pockets with their tips 12 mm from its face, too close for the viewing move. With a second view allowed the
    viewing move's own error ended the pick as faulted; the vision's refusal ends it, the forks where the last look
    left them. Since session 48's renderer change pick 763 is refused for its load's edges instead; pick 342
    (unloaded, 298 mm below the forks) shows the same end after two looks from higher."""
    scene = campaign_scene_of(7, 342)
    with SimulatedWorld(CONFIG, scene) as world:
        start = world.positions()
        result = world.controller().run()
        end = world.positions()
    assert not result.ok and result.refused, result.reason
    assert result.reason.startswith("measuring: the forks hide") and len(result.views) == 2
    assert end["lift"] - start["lift"] == pytest.approx(0.2, abs=0.002)


def test_a_deck_clipped_beside_its_edges_is_measured_again_with_a_shorter_exposure_and_the_pick_inserts():
    """Campaign pick 115 of seed 7: an unloaded pallet whose deck the random look's light clips beside both edges was
    refused ("the top deck is overexposed", session 34). The controller asks the simulated camera for 0.6 of the
    exposure, whose frame is rendered with the scene's light scaled, measures within the bounds and inserts; the
    camera's exposure is set back when the pick ends. (Should the vision one day measure the clipped frame, this
    test needs another such pick: it tests the exposure step, not that refusal.)"""
    inserted_after_shorter_exposures(115, 1, "the top deck is overexposed")


def test_regression_a_deck_edge_blinded_by_light_clipped_in_every_channel_asks_for_a_shorter_exposure():
    """Campaign pick 42 of seed 7: a white deck under three lamps, clipped in every channel beside its edges. No
    channel placed those edge points, so they were dropped, the edges showed over 22 % of their length and the pick
    was refused ("no pitch: neither the deck edges ... nor the load edges were found") with no exposure change. The
    points are now counted as what a shorter exposure would show (87 %): the frame is refused as overexposed, measured
    again at 0.6 of the exposure within the bounds, and the pick inserts."""
    inserted_after_shorter_exposures(42, 1, "with the points beside light clipped in every channel")


def test_regression_a_deck_clipped_with_the_floor_behind_it_asks_for_a_shorter_exposure_though_no_edge_shows():
    """Campaign pick 214 of seed 7: a deck and the floor behind it both clipped in every channel, so neither edge
    showed at all (no point to count as blinded) and the pick was refused ("no pitch: neither the deck edges ... nor
    the load edges were found"). 72 % of the deck's top is clipped (PitchConfig.max_deck_top_clipped) and no load's
    edges were found either: the frame is refused as overexposed, at 0.6 of the exposure again (the deck's edges now
    beside clipped light), and measured within the bounds at 0.36; the pick inserts."""
    inserted_after_shorter_exposures(214, 2, "of it clipped in every channel")


def inserted_after_shorter_exposures(index: int, exposures: int, reason: str) -> None:
    """Campaign pick ``index`` of seed 7 inserts, with no collision, after ``exposures`` shorter exposures, the first
    asked for by a refusal that says ``reason``; every measurement within 0.1 deg of the truth in pitch, and the
    camera's exposure set back when the pick ends."""
    with SimulatedWorld(CONFIG, campaign_scene_of(7, index)) as world:
        controller = world.controller()
        result = controller.run()
        summary = pick_summary(result, world)
        truths = world.measured_truths[: len(result.measurements)]
    assert result.ok, result.reason
    assert len(result.exposures) == exposures and reason in result.exposures[0], result.exposures
    assert summary["exposure_changes"] == exposures and not summary["collision"]
    assert controller.frames.exposure == 1.0
    for measurement, truth in zip(result.measurements, truths, strict=True):
        assert abs(measurement.pallet_in_fork.euler[1] - truth.euler[1]) <= math.radians(0.1)


def test_regression_campaign_pick_205_of_seed_7_a_clipped_load_top_is_not_measured_again_darker():
    """Campaign pick 205 of seed 7: a loaded pallet whose load's top is clipped where the deck's top would be. Taken
    for a clipped deck (session 41's first campaign), the frame was refused as overexposed, and at 0.6 of the
    exposure the load's edges gave a pitch 0.185 deg off that was accepted and inserted. A load whose edges were
    found is not a clipped deck: the frame is refused as before (its load's edges and face disagree), and so are the
    frames after the viewing moves (with the third, since session 45, one of them asks for a shorter exposure, and the
    darker frame is refused too). Since session 48's renderer change (no carton joint along a load's side) the pick
    inserts after three viewing moves and a shorter exposure: every measurement it accepts lies within the bounds."""
    assert_no_measurement_outside_bounds(7, 205)


def test_a_verifying_frame_whose_pitch_is_refused_is_confirmed_at_the_measured_pitch_and_the_pick_inserts(tmp_path):
    """Campaign pick 47 of seed 7: an unloaded pallet on a truck bed, pitched 1.53 deg; its first measurement is
    within the bounds, and its verifying frames (from the aligned forks and from 50 mm back, where the reach has no
    room for more) are refused: a second line a few pixels beside a deck edge pairs 0.16 deg from it. The last one's
    face is confirmed 1.5 mm from where the plan expects it, at the first measurement's pitch, and the pick inserts
    (before session 37 it ended refused). Its log replays the confirmation as one (`agf replay`)."""
    from agf.recorder import read_log
    from agf.replay import replay_log
    from tests.config_copy import config_copy

    recorder = {"folder": str(tmp_path / "logs"), "max_total_mb": 500, "flush_period_ms": 200}
    result, summary, truths = run_campaign_pick(7, 47, load_config(config_copy(tmp_path, recorder=recorder)), True)
    assert result.ok, result.reason
    assert len(result.confirmations) == 1 and "a second line runs beside" in result.confirmations[0]
    assert summary["confirmations"] == 1 and not summary["collision"]
    first, confirmed = result.measurements
    assert confirmed.sigma_pitch == first.sigma_pitch and confirmed.loaded == first.loaded
    assert_within_bounds(result.measurements, truths)
    replayed = replay_log(read_log(summary["log"]))
    assert [row["stage"] for row in replayed["measurements"]][-1] == "confirming" and replayed["ok"], replayed


def run_campaign_pick(
    seed: int, index: int, config=CONFIG, logged: bool = False, as_written: bool = True, pallet_types=()
):
    """Campaign pick ``index`` of ``seed`` in a simulated world (``as_written``, ``pallet_types``: see conftest's
    campaign_scene_of): its result, summary (with its log's path when ``logged``, written where ``config`` records)
    and the true pose of each measurement it accepted."""
    from drivers.sim.world import pick_log, world_clock

    scene = campaign_scene_of(seed, index, as_written, pallet_types)
    clock = world_clock(config)
    with contextlib.ExitStack() as stack:
        log = stack.enter_context(pick_log(config, scene, f"pick-{index:03d}", clock)) if logged else None
        world = stack.enter_context(SimulatedWorld(config, scene, clock))
        result = world.controller(recorder=log).run()
        summary = {**pick_summary(result, world), "log": None if log is None else str(log.path)}
        return result, summary, world.measured_truths[: len(result.measurements)]


def assert_no_measurement_outside_bounds(seed: int, index: int, as_written: bool = True) -> None:
    """Run campaign pick ``index`` of ``seed`` (``as_written``: see conftest's campaign_scene_of): every measurement
    it accepts lies within the bounds (pitch 0.1 deg, z 5 mm, x 10 mm)."""
    result, _, truths = run_campaign_pick(seed, index, as_written=as_written)
    assert_within_bounds(result.measurements, truths)


def assert_within_bounds(measurements, truths) -> None:
    """Every measurement lies within the bounds (pitch 0.1 deg, z 5 mm, x 10 mm) of its frame's truth."""
    for measurement, truth in zip(measurements, truths, strict=True):
        est, gt = measurement.pallet_in_fork.to_dict(), truth.to_dict()
        assert abs(est["pitch_deg"] - gt["pitch_deg"]) <= 0.1, (est, gt)
        assert abs(est["z_mm"] - gt["z_mm"]) <= 5 and abs(est["x_mm"] - gt["x_mm"]) <= 10, (est, gt)


def test_regression_campaign_pick_22_of_seed_7_accepts_no_measurement_outside_bounds():
    """An unloaded pallet 99 mm above the forks, pitched 3.9 deg, whose deck edges have lines beside them
    that pair 0.03-0.1 deg from them, all 0.3 deg from the truth. Two rules tried on 2026-11-25 accepted
    them: a pitch probe passing when all its pairings agree (first measurement 0.28 deg off) and the
    middle of an edge's and its neighbour's pitches (verifying 0.32 deg off, the pallet inserted)."""
    assert_no_measurement_outside_bounds(7, 22)


@pytest.mark.parametrize("index", (107, 132))
def test_regression_campaign_picks_of_seed_7_a_rival_pairing_within_0_05_deg_keeps_the_pair_ambiguous(
    index, monkeypatch
):
    """Session 33 let an edge's pairing with a line beside it count as the same pitch up to 0.05 deg instead of 0.03
    (PitchConfig.rival_pitch): 6 more of 574 randomised first frames measured within bounds and none outside, but in
    the 1000-pick campaign pick 132 (loaded) accepted the frame after its viewing move 0.30 deg off, and pick 107
    its verifying frame after a withdrawal 0.114 deg off. At 0.03 neither accepts a measurement outside the bounds.
    With the one viewing move a pick made until session 42: with two, pick 107 sees other frames (its open wrong
    accept below)."""
    monkeypatch.setattr(world_module, "ControllerConfig", functools.partial(ControllerConfig, views=1))
    assert_no_measurement_outside_bounds(7, index)


def test_regression_campaign_pick_107_of_seed_7_verified_outside_the_bounds_after_two_viewing_moves():
    """Seed 7 pick 107 with two viewing moves (session 42): refused from the start and after its first move, measured
    after the second (the forks 486 mm above the start, level with the pallet) within the bounds (pitch 0.004 deg
    off) and inserted with 23.7 mm clearance; but its verifying frame, from the aligned forks, was accepted 0.121 deg
    off in pitch (the plan is not made again from a verifying measurement that agrees with it). Open until session
    48, whose renderer change (no carton joint along a load's side) changed its frames: none of the measurements it
    accepts now lies outside the bounds, which this test keeps."""
    assert_no_measurement_outside_bounds(7, 107)


def test_regression_campaign_pick_386_of_seed_7_ends_refused_not_in_the_pallet():
    """An unloaded pallet pitched 2.28 deg on a truck bed, a shadow's edge beside a deck edge: its first frame was
    accepted 1.58 deg low, its verifying frame 38 mm low, and the pick re-planned on the latter and drove the tines
    10 mm into the pallet (session 26). The two measurements contradict each other (a pallet is not lowered while the
    forks align): the pick must insert clear of the pallet or end refused, never re-plan on either. Its look put the
    truck bed around the tines' tips (a scene no truck starts in, drawn again since session 39; conftest's
    campaign_scene_of keeps it), so the pallet alone is judged here, not the bed."""
    with SimulatedWorld(CONFIG, campaign_scene_of(7, 386)) as world:
        result = world.controller().run()
        assert min(world.clearances, default=math.inf) >= 0, min(world.clearances)
    assert result.ok or "refusing rather than guessing" in result.reason, result.reason


def test_regression_campaign_pick_386_of_seed_7_deck_edges_turned_from_the_face_give_no_pitch():
    """Pick 386's frame after its viewing move was accepted 1.9 deg off in pitch and 34 mm low: the lines taken for
    the deck's edges (a shadow's edges on the truck bed beside them) ran 1.22 deg in yaw from the face's match, the
    image did not confirm the pose they put the pallet at, and the face's own pose kept their pitch. Since session
    34 the face's pose keeps the deck edges' pitch only when their yaw agrees with it
    (MeasureConfig.face_fallback_yaw)."""
    assert_no_measurement_outside_bounds(7, 386)


def test_regression_campaign_pick_986_of_seed_7_edges_found_on_the_way_must_give_the_same_pitch():
    """Pick 986 (a loaded pallet pitched 3.95 deg) was accepted 0.29 deg off: searched 0.05 deg from where it settled,
    its load's edges offered a pairing 0.08 deg from the truth beside the one that agreed with the lines on the load's
    face, and the iteration followed the face. The probe 0.3 deg either side found only the latter. Since session 34
    every search of the iteration within the probe's reach counts as a probe (measure_pallet's check_pitch_stable)."""
    assert_no_measurement_outside_bounds(7, 986)


@pytest.mark.parametrize("index", (660, 707, 735, 858, 930))
def test_regression_campaign_picks_of_seed_7_a_deck_clipped_in_one_channel_gives_no_pitch(index):
    """These picks accepted unloaded pitches 0.13-0.34 deg off: their decks were clipped in one or two colour channels
    beside both edges (grey 170-200, under the overexposure check's 240), the blur had spread the light past the
    outline before the sensor clipped it, and their JPEG left no channel to find the edges again in. Since session 34
    the overexposure check reads the brightest channel (PitchConfig.max_deck_highlight)."""
    assert_no_measurement_outside_bounds(7, index)

# The picks of `agf simulate --random 200 --seed 7` that accepted a measurement outside the bounds (all in
# pitch, 0.10-0.39 deg; 2026-11-25). Open wrong accepts of issue 17: each must pass when it is fixed. Picks 134,
# 163 and 173 left the list unfixed: since the simulated drives start at the start pose instead of moving there
# (within 0.1 mm), their frames differ by that much and their measurements happen to stay within the bounds.
# Pick 49's came after a viewing move on a rough pose the image did not confirm; no such move is made now. Picks 52
# (a loaded pallet pitched 4.4 deg: its load edges and face lines agree 0.21 deg off) and 177 (a verifying frame
# 0.43 deg off, then refused) joined on 2026-11-26, and pick 159 the same day: its verifying frame, refused before,
# was accepted 0.1004 deg off once the face's edges were read in colour. Picks 52 and 177 were fixed on 2026-11-26
# (session 24): test_regression_campaign_picks_of_seed_7_with_a_loose_pitch_accept_no_measurement_outside_bounds.
# Pick 386 of the 1000-pick campaign (session 26) collided: an unloaded pallet pitched 2.28 deg accepted 1.58 deg low,
# its verifying frames 35-37 mm off in height. Pick 38 was fixed in session 28:
# test_regression_campaign_pick_38_of_seed_7_an_overexposed_deck_gives_no_pitch. Pick 159 left the list in session 30
# with the deck edges pinned by their front corners (its verifying frame 0.083 deg off; kept as a regression test,
# though its margin is small): test_regression_campaign_pick_159_of_seed_7_accepts_no_measurement_outside_bounds.
# Session 31: every pick of the 1000-pick campaign (`agf simulate --random 1000 --seed 7`, on 3ca4536) that accepted a
# measurement outside the bounds joined the list, 28 in all: the pitch 0.10-0.34 deg off in 26 (the tails of the
# pitch's scatter, no rule broken: 0.045 deg standard deviation on 604 randomised first frames), z 5.006 mm off in one
# (pick 762), and pick 386 (above). Pick 206 (a loaded pallet accepted 2.88 deg off from its load
# edges alone) was fixed that session, test_regression_campaign_pick_206_of_seed_7_... in test_measure.py; pick 554's
# verifying frame, refused before, was accepted 0.104 deg off after that fix. Pick 139 left the list the same session
# (test_regression_campaign_pick_139_of_seed_7_load_edges_against_the_top_face_are_refused). Pick 386 left it in
# session 34 (test_regression_campaign_pick_386_of_seed_7_deck_edges_turned_from_the_face_give_no_pitch), and pick 986
# (test_regression_campaign_pick_986_of_seed_7_edges_found_on_the_way_must_give_the_same_pitch), and picks 660, 707,
# 735, 858 and 930 (test_regression_campaign_picks_of_seed_7_a_deck_clipped_in_one_channel_gives_no_pitch).
# Pick 764 joined in session 35: refused for an overexposed deck before, it is measured again at 0.6 of its exposure
# and accepted 0.12 deg off (0.11-0.12 at the true pose at 0.6 and 0.36 of its light: not the exposure's doing).
# Pick 948 left it the same session (test_regression_campaign_picks_of_seed_7_a_deck_edge_clipped_in_part_gives_...).
# Session 36: pick 474 left it (test_regression_campaign_pick_474_of_seed_7_a_pose_fitted_again_along_the_line_...);
# picks 435, 634 and 724 joined: each accepted a verifying frame outside the bounds (pitch -0.18 and -0.106 deg, z
# 5.03 mm) that the vision before the session measures the same; the first measurements, a fraction of a millimetre
# and 0.02-0.03 deg apart, aligned the forks a little differently, and so the verifying frames were other frames.
# Session 37: the last refused verifying frame's face is confirmed at the pitch measured before (confirm_pallet); the
# list is unchanged. Five of its picks (413, 488, 674, 764, 791) had a first measurement accepted 0.10-0.30 deg off and
# their verifying frames refused; 413, 674 and 764 are refused by their deck edges (check_kept_pitch), 791's face is
# not confirmed, and 488 (loaded, 0.146 deg off) now inserts at that pitch (clearance 24.1 mm) instead of ending
# refused.
# Session 39: the list is every pick of `agf simulate --random 1000 --seed 7` on b8defc9 that accepted a measurement
# outside the bounds, each as the campaign draws it now. Picks 8, 762 and 808 left it: each accepted after a viewing
# move down on a rough pose, which is no longer made (they end refused). 129 picks have another look since a look
# whose truck bed held the tines is drawn again: 993 left the list with its old look, 82 (-0.14 deg), 324 (+0.126),
# 638 (+0.101, twice) and 660 (-0.127 and -0.155; its old look keeps its own regression test above) joined with
# their new ones.
# Session 40: a first measurement refused with no view level with the pallet to move to is taken once more with the
# forks raised 100 mm (PickPlanner.look_again_motion); 396 picks of the campaign on its code did, and 39 of them
# inserted. Of the 82 measurements those picks accepted, two lay outside the bounds: 808 (loaded, first frame -0.12 deg)
# and 890 (unloaded, first frame +0.136 deg and z 4.47 mm) joined; every other pick accepted what it did before.
# Session 45: a third viewing move (ControllerConfig.views 3). 617 (inserted after it) joined: its verifying frame was
# accepted -0.199 deg off in pitch, its first measurement, from 300 mm higher, within the bounds.
# Session 48: the campaign renderer no longer draws a carton joint along a face's side, which changed the frames of
# every loaded pick (and of a few with carton clutter). Picks 221, 488, 634, 638, 724, 729 and 808 left the list: none
# of their accepted measurements lies outside the bounds now (most of them loaded, refused or measured within them).
# Found by `agf simulate --random 1000 --seed 7` on that code, picks 209, 227, 530, 694, 700, 742 and 952 joined (see
# docs/campaigns.md, session 48).
# Session 50: a load face whose lines fix the pitch loosely counts as no face where it agrees with the load's edges
# (pitch.py _without_vague_face). 723 left the list (its own regression test above); 488 joined: it inserts now, its
# first measurement 0.053 deg off, its verifying frame 0.102 deg (found by the campaign's picks 0-728 on that code).
# Session 53: 82, 324, 435, 674, 764 and 791 left it, deck edges turned in yaw from the deck's front edge being refused
# (their test follows the list).
# Session 56: 433 joined, found by `agf simulate --random 1000 --seed 7` on session 55's vision (picks 0-554): a
# loaded pallet 158 mm below the forks whose verifying frame was accepted 0.184 deg off in pitch (its first
# measurement within the bounds); the pick was refused, the two pitches too far apart for their sigmas.
# Session 57: the same campaign's picks 555-999 on the same vision: 573, 776 and 854 joined. 573 (loaded, 84 mm below
# the forks): its verifying frame was placed 13 mm high and 26 mm short, and the pick was refused, the verifying
# measurement 15 mm above the plan's; 776 (loaded, level with the forks): its frame after a viewing move was accepted
# 0.134 deg off, and the pick was refused when verifying (the two pitches 3.8 of their sigmas apart); 854 (loaded, 416
# mm above the forks) inserted after three viewing moves, both its measurements 0.111 deg off in pitch.
# Session 60: 433, 488, 554 and 573 no longer (see the test of measure._at_pitch below); 936 joined, on that change.
# Session 61: 890 no longer (its regression test follows the list).
OPEN_CAMPAIGN_WRONG_ACCEPTS = (55, 336, 413, 480, 617, 632, 660, 742, 776, 854, 936)


def test_regression_campaign_pick_890_of_seed_7_deck_edges_with_close_rival_pairings_give_their_midpoint():
    """An open wrong accept until session 61: an unloaded pallet measured and verified 0.136 deg off in pitch and
    inserted. Deck edges whose pairings with a line beside them lie within 0.1 deg now give their midpoint
    (pitch._between_rivals), and both measurements are 0.034 deg off."""
    assert_no_measurement_outside_bounds(7, 890)


@pytest.mark.parametrize("index", (122, 209, 580, 694, 700, 952))
def test_regression_campaign_picks_of_seed_7_a_face_agreeing_with_the_edges_is_averaged_with_them(index):
    """Open wrong accepts until session 54, all loaded, each accepting one frame 0.107-0.335 deg off in pitch (the
    verifying frame of picks 122, 209, 694 and 952, the first of 580 and 700). With the Hough peaks alone they still
    did; with session 54's loaded rules as well (agf/vision/pitch.py loaded_evidence: a face agreeing with the edges
    averaged with them, a face choosing no pitch among two it agrees with, the top face's check) none does, the worst
    0.091 deg off (700's first frame; its verifying frame is then refused and the pick faults). Which rule each pick
    needed was not traced."""
    assert_no_measurement_outside_bounds(7, index, as_written=False)


@pytest.mark.parametrize("index", (227, 530))
def test_regression_campaign_picks_of_seed_7_a_band_of_texture_beside_a_load_edge_no_longer_outvotes_it(index):
    """Open wrong accepts until session 54, both loaded: pick 227 accepted its first frame 0.182 deg off in pitch,
    pick 530 its verifying frame 0.116 deg off. Since the Hough transform fits a line from up to three peaks of its
    accumulator and keeps the one with the most points (agf/vision/hough.py), pick 227 is measured after a viewing
    move 0.015 deg off and pick 530's verifying frames are refused and confirmed: neither accepts a measurement
    outside the bounds."""
    assert_no_measurement_outside_bounds(7, index)


@pytest.mark.parametrize("index", (82, 324, 435, 674, 764, 791))
def test_regression_campaign_picks_of_seed_7_deck_edges_turned_from_the_front_edge_accept_nothing_outside_the_bounds(
    index,
):
    """Open wrong accepts until session 53: each accepted a measurement outside the bounds in pitch (pick 82 its
    first frame, unloaded, 0.14 deg off, its deck edges 0.13 deg off in yaw at the true pose). Deck edges whose yaw
    differs by over 0.08 deg from the yaw the top deck's front edge gives alone are now refused
    (MeasureConfig.deck_front_yaw), and none of these picks accepts a measurement outside the bounds."""
    assert_no_measurement_outside_bounds(7, index)


@pytest.mark.parametrize("index", (394, 691, 751, 850))
def test_regression_campaign_picks_of_seed_7_a_deck_line_through_the_corner_keeps_the_pitch_check(index):
    """With the deck edges pinned by their front corners (session 30), these picks accepted unloaded pitches
    0.17-1.55 deg off: a line through the corner at half the strength of a stronger one beside it, both shadows'
    edges agreeing on the wrong pitch (751, 691), and a stronger line dropped without a pitch check where its rival
    passed through the corner (394, 850). A pinned line is now 0.8 as strong at least, and the stronger one always
    stays a rival that the pitch must agree with."""
    assert_no_measurement_outside_bounds(7, index)


def test_regression_campaign_pick_139_of_seed_7_load_edges_against_the_top_face_are_refused():
    """Pick 139 accepted a loaded pallet pitched 4.51 deg 0.12 deg off from its load edges alone (4.63 deg), no line
    on its face confirming them; its top face gives 4.43 deg. Since session 31 edges no face line confirms must not
    disagree with a top face fitted to +-0.035 deg (agf/vision/pitch.py _checked_by_load_top), and it is refused."""
    assert_no_measurement_outside_bounds(7, 139)


def test_regression_campaign_pick_159_of_seed_7_accepts_no_measurement_outside_bounds():
    """Pick 159's second measurement (verifying, unloaded) was accepted 0.1004 deg off in pitch; since the deck
    edge through the deck's front corner beats a stronger line beside it (agf/vision/pitch.py), 0.083 deg."""
    assert_no_measurement_outside_bounds(7, 159)


def test_regression_campaign_pick_38_of_seed_7_an_overexposed_deck_gives_no_pitch():
    """Pick 38 accepted an unloaded pallet 0.146 deg off in pitch: its deck, grey 250 beside both edges, read both
    edges outwards (clipped highlights under blur and JPEG). A deck that bright now gives no pitch
    (PitchConfig.max_deck_highlight)."""
    assert_no_measurement_outside_bounds(7, 38)


@pytest.mark.parametrize("index", (360, 948))
def test_regression_campaign_picks_of_seed_7_a_deck_edge_clipped_in_part_gives_no_pitch(index):
    """Refused for an overexposed deck until session 35, pick 360 was measured again at 0.6 of its exposure and
    accepted 0.15 deg off in pitch, and inserted: its deck edges' median highlights were 227 and 218, under the
    overexposure check's 240, but 36 % of one edge's points were beside a clipped channel. A deck with a fifth of
    either edge clipped now gives no pitch (PitchConfig.max_deck_clipped), and the controller shortens the exposure
    once more. Pick 948 (an open wrong accept since session 31) inserts within the bounds so, after two shorter
    exposures."""
    assert_no_measurement_outside_bounds(7, index)


def test_regression_campaign_pick_474_of_seed_7_a_pose_fitted_again_along_the_line_of_sight_keeps_the_pitch():
    """Pick 474 (loaded, pitched -4.6 deg, 140 mm below the forks) accepted its verifying frame 0.17 deg off in
    pitch, an open wrong accept since session 31. With every pose searched compared with itself moved along the
    line of sight, and fitted again from there where the face's edges agree better (MeasureConfig.sight_shifts,
    session 36), it inserts within the bounds (its verifying pitch 0.003 deg off); without that step it still
    accepts 0.17 deg off."""
    assert_no_measurement_outside_bounds(7, 474)


@pytest.mark.parametrize("index", (52, 177))
def test_regression_campaign_picks_of_seed_7_with_a_loose_pitch_accept_no_measurement_outside_bounds(index):
    """Pick 52 accepted a loaded pallet pitched 4.4 deg 0.21 deg off (its load edges and face lines agreeing, from
    the search started 3 deg away), pick 177 a verifying frame 0.43 deg off (2026-11-26). Both stated a pitch
    standard deviation over 0.05 deg; a measurement must now give one within it (MeasureConfig.max_sigma_pitch,
    half the bound), and both picks are refused."""
    assert_no_measurement_outside_bounds(7, index)


@pytest.mark.parametrize("index", (384, 390, 655, 964))
def test_regression_campaign_picks_of_seed_7_edges_searched_again_at_their_own_pitch_accept_nothing_outside(index):
    """Session 43 tried searching the pose once more at the edges' own pitch where a rival line beside them had made
    them ambiguous at the assumed pitch: on the first frames of picks 0-199 it measured 6 more within the bounds and
    none outside, but in `agf simulate --random 1000 --seed 7` it accepted these picks' frames 0.10-0.18 deg off in
    pitch (384, 655 and 964 their verifying frames, which a rival a few pixels beside a deck or load edge had
    refused; 390 and 936 after viewing moves), where without it they were refused or measured within the bounds.
    Not kept; a rival found near the pallet's own pitch must keep refusing. Pick 936 is open since session 60: with
    the pose reported at the pitch its edges measured (measure._at_pitch), not the one searched 0.02 deg beside it,
    a frame after its viewing move is 0.107 deg off (OPEN_CAMPAIGN_WRONG_ACCEPTS)."""
    assert_no_measurement_outside_bounds(7, index)


@pytest.mark.parametrize("index", (42, 120))
def test_regression_campaign_picks_of_seed_7_beside_clipped_light_accept_no_measurement_outside_bounds(index):
    """Picks 42 and 120 accepted pitches 0.1-0.2 deg off (2026-11-25): pick 42's deck, lit past the sensor's range
    in two colour channels, read 0.5-1.2 px wide through the blur. Fixed on 2026-11-26 by reading edge points beside
    clipped light in the colour channel that does not clip (and the grey as agf bench reads it)."""
    assert_no_measurement_outside_bounds(7, index)


@pytest.mark.parametrize("index", (433, 488, 554, 573))
def test_regression_campaign_picks_of_seed_7_report_the_pitch_measured_not_the_one_searched_at(index):
    """Open wrong accepts until session 60 (OPEN_CAMPAIGN_WRONG_ACCEPTS), 0.10-0.18 deg off in pitch or placed off:
    the converged pose was reported at the pitch it was last searched at, up to MeasureConfig.pitch_tolerance (0.03
    deg) from the pitch its edges measured there. Reported at the measured pitch (measure._at_pitch), these picks
    accept nothing outside the bounds; without it they do (checked on these frames, session 60)."""
    assert_no_measurement_outside_bounds(7, index, as_written=False)


@pytest.mark.xfail(
    strict=True, raises=AssertionError, reason="accepted a measurement outside the bounds: open, see issue 17"
)
@pytest.mark.parametrize("index", OPEN_CAMPAIGN_WRONG_ACCEPTS)
def test_open_campaign_wrong_accepts_of_seed_7(index):
    assert_no_measurement_outside_bounds(7, index, as_written=False)


# Session 61: `agf simulate --random 1000 --seed 7` on the frames the campaign renderer draws since session 60 (texture
# steps sub-sampled, fast_render.TEXTURE_CONTRAST 0.2) and session 60's vision (58e91d6): 624 inserted, no collision,
# and 29 accepted measurements outside the bounds in 25 picks, all 0.10-0.25 deg off in pitch (none off in position).
# With session 61's vision (pitch._between_rivals) 23 of those picks still accept one; 537 is refused and 920 measures
# within the bounds (their test follows).
# Session 66: the same campaign on session 65's vision (e930f2f), stopped at pick 205 to free the machine: 108, 141,
# 147 and 173 of this list accepted a measurement outside the bounds again, and 148 joined (unloaded, 106 mm above the
# forks, pitched -0.28 deg): its first measurement within the bounds, its verifying frame -0.224 deg off; the pick was
# refused, the two pitches 3.3 of their sigmas apart.
# Session 67: the whole campaign on the same vision (0f9b645): 653 inserted, no collision, 30 accepted measurements
# outside the bounds in 27 picks, all 0.10-0.25 deg off in pitch. Every pick of this list again, and three joined, each
# on a verifying frame after a first measurement within the bounds: 281 (loaded, 361 mm above the forks, verifying
# frame -0.111 deg off after a withdrawal; inserted), 533 (loaded, -0.122 deg) and 647 (unloaded, -0.208 deg), both
# refused for their two pitches 3.2 and 3.9 of their sigmas apart.
OPEN_SUB_SAMPLED_CAMPAIGN_WRONG_ACCEPTS = (108, 141, 147, 148, 173, 211, 214, 219, 281, 336, 379, 413, 468, 533, 547,
                                           647, 660, 683, 708, 800, 810, 834, 895, 925, 952, 955, 962)
TEXTURE_CONTRAST_FOUND_AT = 0.2  # fast_render.TEXTURE_CONTRAST they were found at: the frames they describe


@pytest.mark.xfail(
    strict=True, raises=AssertionError, reason="accepted a measurement outside the bounds: open, see issue 17"
)
@pytest.mark.parametrize("index", OPEN_SUB_SAMPLED_CAMPAIGN_WRONG_ACCEPTS)
def test_open_campaign_wrong_accepts_of_seed_7_on_the_frames_drawn_now(index, monkeypatch):
    monkeypatch.setattr(fast_render, "TEXTURE_CONTRAST", TEXTURE_CONTRAST_FOUND_AT)
    assert_no_measurement_outside_bounds(7, index, as_written=False)


@pytest.mark.parametrize("index", (537, 920))
def test_regression_campaign_picks_of_seed_7_on_the_frames_drawn_now_accept_nothing_outside_the_bounds(
    index, monkeypatch
):
    """Each accepted a measurement 0.11 deg off in pitch on session 60's vision and inserted (537, loaded: both 0.109
    off; 920, unloaded: the verifying one 0.108 off); on session 61's 537 is refused and 920 measures within the
    bounds."""
    monkeypatch.setattr(fast_render, "TEXTURE_CONTRAST", TEXTURE_CONTRAST_FOUND_AT)
    assert_no_measurement_outside_bounds(7, index, as_written=False)


def test_regression_campaign_pick_723_of_seed_7_a_vague_load_face_no_longer_sends_it_to_a_third_view():
    """Pick 723 (loaded, 375 mm above the forks) was refused at the start for the loose lines on its load's face,
    viewed three times, and measured and confirmed 0.100 deg off in pitch (open until session 50). With such a face
    counting as no face (pitch.py _without_vague_face) its first frame is measured 0.003 deg off and the pick inserts
    with no viewing move, its verifying frame 0.003 deg off too: no measurement it accepts lies outside the bounds."""
    assert_no_measurement_outside_bounds(7, 723, as_written=False)


def test_regression_campaign_pick_480_of_seed_7_two_pitches_further_apart_than_their_sigmas_refuse_the_pick():
    """Pick 480 planned on a first measurement 0.103 deg off in pitch and inserted, its verifying frame within the
    bounds and 0.14 deg from it: 3.3 times the +-0.042 deg the two stated together. Since session 47 a verifying
    pitch more than PickSettings.verify_pitch_sigmas (3) of them from the plan's refuses the pick: one of the two
    measurements is further off than it says, and the plan's tilt margins take three sigmas of its own."""
    result, _, truths = run_campaign_pick(7, 480, as_written=False)
    assert not result.ok and result.state != "done"
    assert "times the" in result.reason and "the two state together (at most 3)" in result.reason, result.reason
    assert len(result.measurements) == 2  # the plan's and the verifying one: nothing inserted on either


def test_regression_campaign_pick_268_of_seed_7_a_verifying_frame_counts_its_blank_face_edges():
    """With the deck edges' pose judged by the face edges the image shows a step beside (session 49), pick 268's
    verifying frame, refused before for face edges agreeing 34 % (its face top 0 %), was accepted 0.115 deg off in
    pitch, its first measurement 0.007 deg off, and the pick inserted. A verifying frame counts its blank face edges
    as before (measure_pallet's ``verifying``)."""
    assert_no_measurement_outside_bounds(7, 268, as_written=False)


@pytest.mark.parametrize("index", (868, 992))
def test_regression_campaign_picks_of_seed_7_a_face_edge_the_light_leaves_blank_does_not_refuse_the_confirmation(
    index,
):
    """Measured within the bounds, these picks' verifying frames were refused twice, and their confirmations too,
    for face edges agreeing 39-49 % with one group at 0 %: a face edge with no step beside it (a face top lit as the
    deck top behind it) counted against the pose. A confirmation looks for the face where the plan placed it, and
    since session 47 counts only the points where the image shows a step (EdgeAgreementConfig.blank_disagrees);
    both insert, every measurement within the bounds."""
    result, _, truths = run_campaign_pick(7, index, as_written=False)
    assert result.ok and len(result.confirmations) == 1, result.reason
    assert_within_bounds(result.measurements, truths)


def test_regression_campaign_pick_32_of_seed_7_a_face_confirmed_on_its_edges_whatever_its_similarity(monkeypatch):
    """Pick 32 (loaded, 193 mm above the forks): its verifying frames were refused for the pitch, and the
    confirmation found the face where the plan expects it at a similarity of 0.36, its face edges agreeing 74 %.
    Refused for the similarity until session 65, it is now settled by the edges as a measurement's face is
    (MeasureConfig.similarity_excused_by_edges): the pick inserts, every measurement within the bounds."""
    monkeypatch.setattr(fast_render, "TEXTURE_CONTRAST", TEXTURE_CONTRAST_FOUND_AT)
    result, _, truths = run_campaign_pick(7, 32, as_written=False)
    assert result.ok and len(result.confirmations) == 1, result.reason
    assert_within_bounds(result.measurements, truths)


def test_only_runs_one_pick_of_a_campaign_as_the_campaign_draws_it(monkeypatch, tmp_path):
    drawn: list = []

    class Refused:  # records the scene it is given; the pick itself is tested above
        def __init__(self, config, scene, *args, **kwargs):
            drawn.append(scene)
            raise MeasurementError("not picked")

    monkeypatch.setattr(world_module, "SimulatedWorld", Refused)
    monkeypatch.setattr(world_module, "pick_log", lambda *args: contextlib.nullcontext(None))
    whole = simulate_command(CONFIG, scene=None, runs=30, seed=4242, jobs=1, out=str(tmp_path / "all"),
                             progress=False)
    assert whole["runs"] == 30 and len(drawn) == 30
    campaign, drawn[:] = list(drawn), []
    alone = simulate_command(CONFIG, scene=None, runs=30, seed=4242, jobs=1, indices=[16],
                             out=str(tmp_path / "one"), progress=False)
    [scene] = drawn
    assert alone["runs"] == 1 and alone["failures"][0]["run"] == 16
    key = lambda s: (s.seed, s.pallet.in_fork.to_dict(), s.load, s.environment)  # noqa: E731
    assert key(scene) == key(campaign[16]) and key(scene) != key(campaign[15])
