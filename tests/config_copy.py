"""A copy of the default configuration in a test's folder, with some sections changed."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from agf.paths import DEFAULT_CONFIG


def default_config() -> dict[str, Any]:
    """The default configuration as YAML data."""
    return yaml.safe_load(DEFAULT_CONFIG.read_text())


def config_copy(folder: Path, **sections: Any) -> Path:
    """``folder/agf.yaml``: the default config with its files named absolutely and ``sections`` replaced."""
    data = {**default_config(), **sections}
    for key in ("camera", "calibration", "pallets"):
        data["vision"][key] = str(DEFAULT_CONFIG.parent / data["vision"][key])
    for axis in data["drives"]["axes"].values():
        axis["eds"] = str(DEFAULT_CONFIG.parent / axis["eds"])
    path = folder / "agf.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path
