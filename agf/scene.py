"""Scene files: what ``agf render`` draws and ``agf simulate --scene`` picks (DESIGN.md's format).

```yaml
camera: configs/cameras/thetav_front.txt      # repository-relative
camera_in_fork: {x_mm: -705, z_mm: 1055}
pallet: {type: jis-t11, in_fork: {x_mm: 201, z_mm: 355, pitch_deg: 1.65}}
load: {size_mm: [1000, 1000, 800]}            # or null / absent: unloaded
environment: {floor: truck-bed, clutter_verticals: 8, light: 1.0, neighbours: 0}
noise: {sigma: 2.0, blur_px: 0.5, jpeg_quality: 90}
seed: 7
look: fixed                                   # or random: textures, lights, sensor drawn from the seed
```

A calibration scene has ``panel: {size_mm: [W, H], thickness_mm: T}`` instead of ``pallet`` and
``load``: W across the forks (fork Y), H along them (fork X), lying on the forks with its front
edge centred on the fork origin. Defaults: no load, a level concrete floor, no clutter, light 1.0,
no neighbours, noise sigma 2.0 grey levels, blur 0.5 px, JPEG quality 90 (null: no JPEG), seed 0,
look fixed. ``look: random`` draws the scene's appearance from its seed (surface textures, lights and
hard shadows, where the support ends, rack and clutter, exposure, white balance, noise, blur, JPEG;
the scene's ``light`` then scales the drawn exposure and ``noise`` the drawn noise and blur); the
pallet's geometry, and so the ground truth, stays exactly as given.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from agf.config import child, read_yaml, require_positive, section_from_mapping, unit
from agf.errors import ConfigError
from agf.geometry import Transform
from agf.pallets import load_pallets
from agf.paths import repo_path


@dataclass(frozen=True)
class PalletPlacement:
    """Which catalogued pallet stands where (frame P in the fork frame)."""

    type: str
    in_fork: Transform


@dataclass(frozen=True)
class Load:
    """A carton stack on the deck, front flush with the pallet's front face: length (x), width (y), height (m)."""

    size: tuple[float, float, float] = unit("mm")

    def __post_init__(self) -> None:
        for name, value in zip(("length", "width", "height"), self.size, strict=True):
            require_positive(f"size_mm {name}", value)


@dataclass(frozen=True)
class Environment:
    """Surroundings of the pallet."""

    floor: Literal["floor", "truck-bed"] = "floor"
    clutter_verticals: int = 0
    light: float = 1.0
    neighbours: int = 0

    def __post_init__(self) -> None:
        if not 0 <= self.clutter_verticals <= 40:
            raise ValueError(f"clutter_verticals: expected 0..40, got {self.clutter_verticals}")
        if not 0 <= self.neighbours <= 2:
            raise ValueError(f"neighbours: expected 0, 1 or 2 (pallets beside the target), got {self.neighbours}")
        if not 0.05 <= self.light <= 4.0:
            raise ValueError(f"light: expected an exposure factor in 0.05..4, got {self.light}")


@dataclass(frozen=True)
class Noise:
    """Sensor noise (grey levels), blur (px, Gaussian sigma) and JPEG quality (None: lossless)."""

    sigma: float = 2.0
    blur_px: float = 0.5
    jpeg_quality: int | None = 90

    def __post_init__(self) -> None:
        if not 0 <= self.sigma <= 50 or not 0 <= self.blur_px <= 10:
            raise ValueError(f"sigma must be in 0..50 and blur_px in 0..10, got {self.sigma}, {self.blur_px}")
        if self.jpeg_quality is not None and not 1 <= self.jpeg_quality <= 100:
            raise ValueError(f"jpeg_quality: expected 1..100 or null, got {self.jpeg_quality}")


@dataclass(frozen=True)
class Panel:
    """Calibration panel lying on the forks: width across (fork Y), depth along (fork X), thickness (m)."""

    size: tuple[float, float] = unit("mm")
    thickness: float = unit("mm", 0.005)

    def __post_init__(self) -> None:
        require_positive("size_mm width", self.size[0])
        require_positive("size_mm depth", self.size[1])
        require_positive("thickness_mm", self.thickness)


@dataclass(frozen=True)
class Scene:
    """A parsed scene file; ``camera`` is resolved against the repository root."""

    camera: Path
    camera_in_fork: Transform
    pallet: PalletPlacement | None = None
    load: Load | None = None
    environment: Environment = field(default_factory=Environment)
    noise: Noise = field(default_factory=Noise)
    seed: int = 0
    panel: Panel | None = None
    look: Literal["fixed", "random"] = "fixed"

    @property
    def loaded(self) -> bool:
        return self.load is not None


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene file; :class:`ConfigError` names the file and key on any mistake."""
    path = Path(path)
    data = read_yaml(path, what="scene file")
    where = f"{path}:"
    scene = section_from_mapping(Scene, data, where)
    camera = repo_path(scene.camera)
    if not camera.is_file():
        raise ConfigError(f"{child(where, 'camera')}: camera file {camera} not found (paths are repository-relative)")
    if (scene.pallet is None) == (scene.panel is None):
        raise ConfigError(f"{where} give either 'pallet' (a pick scene) or 'panel' (a calibration scene)")
    if scene.panel is not None and scene.load is not None:
        raise ConfigError(f"{child(where, 'load')}: a calibration scene has no load")
    if scene.pallet is not None:
        catalogue = load_pallets(repo_path("configs/pallets.yaml"))
        if scene.pallet.type not in catalogue:
            raise ConfigError(
                f"{child(where, 'pallet.type')}: unknown pallet type {scene.pallet.type!r}; "
                f"the catalogue configs/pallets.yaml has {sorted(catalogue)}"
            )
    return dataclasses.replace(scene, camera=camera)
