"""``agf bench`` cases of the pick (group ``control``): motion planning time, frame-to-motion latency
and the whole pick cycle in the simulated world in real time (as ``agf run``), and the wall seconds
of one pick on simulated time (as ``agf simulate``)."""

from __future__ import annotations

import statistics
import time
from typing import Any

from agf.axis import AxisLimits
from agf.bench import bench_case, time_calls, timing_summary
from agf.clock import SimulatedClock, WallClock
from agf.config import load_config
from agf.motion import plan_move
from agf.paths import DEFAULT_CONFIG, repo_path
from agf.scene import load_scene
from drivers.sim.world import SimulatedWorld

LIMITS = {
    "lift": AxisLimits(0.0, 3.0, 0.4, 0.8, 4.0),
    "reach": AxisLimits(0.0, 1.3, 0.25, 0.5, 2.5),
    "tilt": AxisLimits(-0.1, 0.1, 0.07, 0.14, 0.7),
}


@bench_case("motion.plan_us", "control")
def motion_plan_us(quick: bool) -> dict[str, Any]:
    """One time-synchronised three-axis align plan with Ruckig, microseconds."""
    start, target = {"lift": 0.6, "reach": 0.3, "tilt": 0.0}, {"lift": 0.83, "reach": 0.25, "tilt": 0.03}
    samples = time_calls(lambda: plan_move(start, target, LIMITS), repeats=200 if quick else 2000)
    return timing_summary(samples, scale=1e6)


@bench_case("pick", "control")
def pick(quick: bool) -> dict[str, Any]:
    """Whole simulated picks in real time (``agf run``): frame-to-motion (measure + plan, ms) and the
    pick cycle (s)."""
    config = load_config(DEFAULT_CONFIG)
    scene = load_scene(repo_path("configs/scenes/pick.yaml"))
    frame_to_motion, cycles, ok = [], [], 0
    for _ in range(1 if quick else 3):
        with SimulatedWorld(config, scene, WallClock()) as world:
            result = world.controller().run()
        ok += result.ok
        frame_to_motion.append((result.durations.get("measuring", 0) + result.durations.get("planning", 0)) * 1e3)
        cycles.append(sum(result.durations.values()))
    return {
        "picks": len(cycles),
        "inserted": ok,
        "frame_to_motion_ms": {"median": statistics.median(frame_to_motion), "max": max(frame_to_motion)},
        "cycle_s": {"median": statistics.median(cycles), "max": max(cycles)},
        "note": "cycle_s includes rendering two 1920 x 1920 frames (render.frame_s each), which a camera does not take",
    }


@bench_case("pick.sim_s", "control")
def pick_sim_s(quick: bool) -> dict[str, Any]:
    """Wall seconds per pick on simulated time (``agf simulate``), start-up included, and where they go:
    rendering the frames, the vision's compute, and the motion (control loop, CAN, drive physics and
    the collision check each cycle) against the simulated seconds it stands for."""
    config = load_config(DEFAULT_CONFIG)
    scene = load_scene(repo_path("configs/scenes/pick.yaml"))
    picks: list[dict[str, float]] = []
    for _ in range(1 if quick else 3):
        start, cpu = time.perf_counter(), time.process_time()
        with SimulatedWorld(config, scene, SimulatedClock()) as world:
            ready = time.perf_counter()
            result = world.controller().run()
        if not result.ok:
            return {"error": f"the simulated pick failed: {result.reason}"}
        wall = result.wall_durations
        vision = sum(m.timing_ms.get("total", 0.0) for m in result.measurements) / 1e3
        motion = ("connecting", "planning", "aligning", "viewing", "inserting")
        picks.append({
            "wall_s": time.perf_counter() - start,
            "cpu_s": time.process_time() - cpu,  # the figure a busy machine does not inflate
            "setup_s": ready - start,
            "render_s": sum(wall.get(s, 0.0) for s in ("acquiring", "measuring", "verifying")) - vision,
            "vision_s": vision,
            "motion_wall_s": sum(wall.get(s, 0.0) for s in motion),
            "motion_simulated_s": sum(result.durations.get(s, 0.0) for s in motion),
        })
    middle = sorted(picks, key=lambda p: p["wall_s"])[len(picks) // 2]
    return {
        "picks": len(picks),
        "median": middle["wall_s"],
        "max": max(p["wall_s"] for p in picks),
        "median_pick": middle,
        "note": "wall seconds per simulated pick of configs/scenes/pick.yaml; render_s is the renderer's",
    }
