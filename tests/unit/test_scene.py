"""Scene files: DESIGN.md's format parses; every mistake names the file and the key."""

from __future__ import annotations

import math

import pytest

from agf.errors import ConfigError
from agf.paths import repo_path
from agf.scene import load_scene

GOOD = """\
camera: configs/cameras/thetav_front.txt
camera_in_fork: {x_mm: -705, y_mm: 0, z_mm: 1055, roll_deg: 0, pitch_deg: 0, yaw_deg: 0}
pallet:
  type: jis-t11
  in_fork: {x_mm: 201, y_mm: 0, z_mm: 355, pitch_deg: 1.65, yaw_deg: 0}
load: {size_mm: [1000, 1000, 800]}
environment: {floor: truck-bed, clutter_verticals: 8, light: 1.0, neighbours: 0}
noise: {sigma: 2.0, blur_px: 0.5, jpeg_quality: 90}
seed: 7
"""


def write(tmp_path, text):
    path = tmp_path / "scene.yaml"
    path.write_text(text)
    return path


def test_design_md_example_parses_into_si(tmp_path):
    scene = load_scene(write(tmp_path, GOOD))
    assert scene.pallet.in_fork.translation == pytest.approx([0.201, 0.0, 0.355])
    assert scene.pallet.in_fork.euler[1] == pytest.approx(math.radians(1.65))
    assert scene.load.size == pytest.approx((1.0, 1.0, 0.8)) and scene.loaded
    assert scene.camera == repo_path("configs/cameras/thetav_front.txt")


def test_defaults_for_missing_optional_keys(tmp_path):
    text = "\n".join(line for line in GOOD.splitlines() if line.split(":")[0] not in ("load", "environment", "noise"))
    scene = load_scene(write(tmp_path, text))
    assert not scene.loaded and scene.environment.light == 1.0 and scene.noise.jpeg_quality == 90


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (("seed: 7", "seed: 7\ncolour: red"), "unknown key"),
        (("light: 1.0", "light: bright"), "environment.light: expected a finite number"),
        (("light: 1.0", "light: 0"), "light: expected an exposure factor"),
        (("floor: truck-bed", "floor: ice"), "environment.floor: expected one of"),
        (("thetav_front.txt", "nope.txt"), "camera: camera file"),
        (("jpeg_quality: 90", "jpeg_quality: 300"), "jpeg_quality"),
        (("x_mm: 201", "x_mm: wide"), "in_fork.x_mm: expected a finite number"),
        (("load: {size_mm: [1000, 1000, 800]}", "load: {size_mm: [1000, -5, 800]}"), "size_mm"),
        (("seed: 7", "seed: 7\npanel: {size_mm: [1000, 600]}"), "either 'pallet'"),
        (("type: jis-t11", "type: euro-2"), "pallet.type: unknown pallet type"),
    ],
)
def test_bad_scene_is_refused_with_file_and_key(tmp_path, change, message):
    path = write(tmp_path, GOOD.replace(*change))
    with pytest.raises(ConfigError, match=message) as info:
        load_scene(path)
    assert str(path) in str(info.value)


def test_not_yaml_is_a_clear_error(tmp_path):
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_scene(write(tmp_path, "camera: [unclosed"))
