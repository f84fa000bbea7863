"""Rendered scene sets, made once per test session (two processes: CI has two cores)."""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import time
from importlib.machinery import SourceFileLoader
from multiprocessing import get_context
from pathlib import Path

import cv2
import pytest

from agf.paths import repo_path

SCENES = repo_path("tests/data/scenes")
SHARED_DATA = repo_path("../shared/data")


def _render(job: tuple[str, str]) -> str:
    from agf.scene import load_scene
    from drivers.sim.render import render

    scene_path, out = job
    image, _ = render(load_scene(scene_path))
    cv2.imwrite(out, image)
    return out


def rendered_paths(scene_paths: list[Path], out_dir: Path) -> dict[str, Path]:
    """``{"<folder>/<name>": PNG in out_dir}`` for each scene file."""
    return {f"{p.parent.name}/{p.stem}": out_dir / f"{p.parent.name}-{p.stem}.png" for p in scene_paths}


def render_all(scene_paths: list[Path], out_dir: Path) -> dict[str, Path]:
    paths = rendered_paths(scene_paths, out_dir)
    with get_context("fork").Pool(2) as pool:
        pool.map(_render, [(str(s), str(png)) for s, png in zip(scene_paths, paths.values(), strict=True)])
    return paths


# Looks of campaign seed 7 drawn before session 39, whose truck bed or dock held the tines' tips at the start
# (random_scene draws such a look again now): their regression tests keep the frames they were written for.
LOOKS_BEFORE_THE_SUPPORT_CHECK = {386: 1234191223, 660: 319796515}


@pytest.fixture
def point_sampled_texture(monkeypatch):
    """The campaign renderer's frames as it drew them until session 60, its texture point-sampled (no texture step
    sub-sampled: ``fast_render.TEXTURE_CONTRAST`` infinite), bit for bit (tests/integration/test_render.py): the
    frames the regression tests of campaign picks and random looks were found on and describe. On the frames drawn
    now most of those picks measure otherwise, while the vision they caught is the same."""
    from drivers.sim import fast_render

    monkeypatch.setattr(fast_render, "TEXTURE_CONTRAST", math.inf)


def tool_module(name: str):
    """The script ``tools/NAME`` (no ``.py``) loaded as a module, for its functions and ``main``."""
    loader = SourceFileLoader(name, str(repo_path(f"tools/{name}")))
    module = importlib.util.module_from_spec(importlib.util.spec_from_loader(loader.name, loader))
    loader.exec_module(module)
    return module


def campaign_scene_of(seed: int, index: int, as_written: bool = True, pallet_types: tuple[str, ...] = ()):
    """Pick ``index`` of the random campaign ``seed`` (of ``pallet_types``, as ``agf simulate --pallet-types``);
    ``as_written``: with the look it had when its regression test was written (:data:`LOOKS_BEFORE_THE_SUPPORT_CHECK`),
    else as the campaign draws it now."""
    from agf.scene import load_scene
    from drivers.sim.world import campaign_scene

    scene = campaign_scene(load_scene(repo_path("configs/scenes/pick.yaml")), seed, index, pallet_types=pallet_types)
    if as_written and seed == 7 and index in LOOKS_BEFORE_THE_SUPPORT_CHECK:
        return dataclasses.replace(scene, seed=LOOKS_BEFORE_THE_SUPPORT_CHECK[index])
    return scene


def campaign_first_frame(seed: int, index: int):
    """Pick ``index`` of the random campaign ``seed`` (:func:`campaign_scene_of`): its scene and the first frame the
    simulated world renders of it (colour)."""
    from drivers.sim.fast_render import render_fast

    scene = campaign_scene_of(seed, index)
    return scene, render_fast(scene)[0]


def scene_files() -> list[Path]:
    files = sorted((SCENES / "paper").glob("*.yaml")) + sorted((SCENES / "robust").glob("*.yaml"))
    if not SHARED_DATA.is_dir():  # the real-lens scene needs ../shared/data
        files = [f for f in files if "shared/data" not in f.read_text()]
    return files


RENDER_WAIT_S = 1800  # a scene takes 5-30 s on one core; a claim left this long was abandoned (its worker died)


def _claimed(png: Path) -> bool:
    """Whether this worker is the first to claim rendering ``png`` (created with O_EXCL: one worker wins)."""
    try:
        png.with_suffix(".claimed").touch(exist_ok=False)
    except FileExistsError:
        return False
    return True


@pytest.fixture(scope="session")
def rendered(tmp_path_factory, worker_id: str) -> dict[str, Path]:
    """``{"paper/<name>" | "robust/<name>": rendered PNG}`` for every scene file, rendered once per run. Under
    pytest-xdist the workers share the run's temporary folder and render the scenes between them: each worker that
    asks claims the scenes nobody has claimed yet, one at a time, and then waits for the others' claims, so the
    renders use every worker that needs them and none waits idle for another to render them all."""
    scenes = scene_files()
    if worker_id == "master":
        return render_all(scenes, tmp_path_factory.mktemp("renders"))
    out = tmp_path_factory.getbasetemp().parent / "renders"  # this run's folder; each worker's basetemp lies in it
    out.mkdir(exist_ok=True)
    paths = rendered_paths(scenes, out)
    for scene, png in zip(scenes, paths.values(), strict=True):
        if _claimed(png):
            _render((str(scene), str(png.with_suffix(".part.png"))))
            png.with_suffix(".part.png").replace(png)  # whole files only: a waiting worker may read it at once
    deadline = time.monotonic() + RENDER_WAIT_S
    while not all(png.exists() for png in paths.values()):
        if time.monotonic() > deadline:
            missing = [key for key, png in paths.items() if not png.exists()]
            pytest.fail(f"another worker claimed these scenes and did not render them in {RENDER_WAIT_S} s: {missing}")
        time.sleep(0.5)
    return paths
