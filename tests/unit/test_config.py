import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from agf.config import SearchVolume, load_calibration, load_config
from agf.errors import ConfigError
from agf.pallets import load_pallets, pallet_type
from agf.paths import REPO_ROOT

CONFIGS = REPO_ROOT / "configs"


@pytest.fixture
def config_dir(tmp_path: Path) -> Path:
    """A copy of configs/ that a test may break."""
    target = tmp_path / "configs"
    shutil.copytree(CONFIGS, target)
    return target


def _edit(path: Path, change) -> None:
    data = yaml.safe_load(path.read_text())
    change(data)
    path.write_text(yaml.safe_dump(data))


def test_default_config_loads_in_si_units():
    config = load_config(CONFIGS / "agf.yaml")
    assert config.forks.thickness == pytest.approx(0.036)
    assert config.forks.length == pytest.approx(1.070)
    assert config.vision.search.yaw_max == pytest.approx(0.17453292519943295)
    assert config.vision.camera.is_file()


def test_unknown_key_is_named_with_file(config_dir):
    _edit(config_dir / "agf.yaml", lambda d: d["forks"].update(thicknes_mm=36))
    with pytest.raises(ConfigError, match=r"agf\.yaml: forks: unknown key\(s\) \['thicknes_mm'\]"):
        load_config(config_dir / "agf.yaml")


def test_wrong_type_names_key_path(config_dir):
    _edit(config_dir / "agf.yaml", lambda d: d["vision"]["search"].update(x_min_mm="near"))
    with pytest.raises(ConfigError, match=r"vision\.search\.x_min_mm: expected a finite number"):
        load_config(config_dir / "agf.yaml")


def test_impossible_limits_are_refused(config_dir):
    _edit(config_dir / "agf.yaml", lambda d: d["vision"]["search"].update(z_min_mm=600, z_max_mm=500))
    with pytest.raises(ConfigError, match=r"vision\.search: z_mm: minimum .* must be below maximum"):
        load_config(config_dir / "agf.yaml")


def test_missing_named_file_is_refused(config_dir):
    (config_dir / "calibration.yaml").unlink()
    with pytest.raises(ConfigError, match=r"vision\.calibration: file .*calibration\.yaml does not exist"):
        load_config(config_dir / "agf.yaml")


def test_missing_config_file_and_bad_yaml(tmp_path):
    with pytest.raises(ConfigError, match="configuration file not found"):
        load_config(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("vision: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(bad)


def test_calibration_file_loads_camera_in_fork():
    camera_in_fork = load_calibration(CONFIGS / "calibration.yaml")
    assert camera_in_fork.translation[0] == pytest.approx(-0.705)
    assert camera_in_fork.translation[2] == pytest.approx(1.055)


def test_calibration_with_bad_pose_key(tmp_path):
    path = tmp_path / "cal.yaml"
    path.write_text("camera_in_fork: {x_mm: 1, pitch: 2}\n")
    with pytest.raises(ConfigError, match="camera_in_fork: unknown key"):
        load_calibration(path)


def test_pallet_catalogue_matches_reference():
    reference_file = REPO_ROOT.parent / "shared" / "reference" / "pallets.yaml"
    if not reference_file.is_file():
        pytest.skip("../shared/reference/pallets.yaml is absent")
    reference = yaml.safe_load(reference_file.read_text())
    catalogue = load_pallets(CONFIGS / "pallets.yaml")
    for name, ref in reference.items():
        pallet = catalogue[name]
        assert pallet.height == pytest.approx(ref["height"] / 1000)
        assert pallet.top == pytest.approx(ref["top_mm"] / 1000)
        assert [b.y for b in pallet.blocks] == pytest.approx([b["y"] / 1000 for b in ref["blocks"]])
    assert catalogue["jis-t11"].pocket_height == pytest.approx(0.090)


def test_pallet_overlapping_blocks_are_refused(tmp_path):
    path = tmp_path / "pallets.yaml"
    path.write_text(
        "bad:\n  length_mm: 1000\n  width_mm: 1000\n  height_mm: 140\n  top_mm: 20\n  bottom_mm: 20\n"
        "  blocks: [{y_mm: 0, width_mm: 100}, {y_mm: 40, width_mm: 100}]\n"
    )
    with pytest.raises(ConfigError, match="bad: blocks overlap"):
        load_pallets(path)
    with pytest.raises(ConfigError, match="unknown pallet type 'nope'"):
        pallet_type(load_pallets(CONFIGS / "pallets.yaml"), "nope")


def test_search_volume_corners_follow_its_limits_and_a_lift():
    volume = SearchVolume(x_min=0.2, x_max=0.7, y_min=-0.1, y_max=0.2, z_min=-0.3, z_max=0.4)
    np.testing.assert_array_equal(volume.low, [0.2, -0.1, -0.3])
    np.testing.assert_array_equal(volume.high, [0.7, 0.2, 0.4])
    lifted = volume.lifted(0.25)
    np.testing.assert_allclose(lifted.low, [0.2, -0.1, -0.55])
    np.testing.assert_allclose(lifted.high, [0.7, 0.2, 0.15])
