"""The pallet catalogue: front-face geometry of each pallet type, in SI units.

Frame P (DESIGN.md): origin at the centre of the front face at pocket mid-height, X into the
pallet, Y left along the front face, Z up from the deck.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from agf.config import child, read_yaml, require_positive, section_from_mapping, unit
from agf.errors import ConfigError


@dataclass(frozen=True)
class Block:
    """A block (or stringer) of the front face: centre ``y`` and ``width`` (m); ``depth`` None = full."""

    y: float = unit("mm")
    width: float = unit("mm")
    depth: float | None = unit("mm", None)

    def __post_init__(self) -> None:
        require_positive("width_mm", self.width)
        if self.depth is not None:
            require_positive("depth_mm", self.depth)


@dataclass(frozen=True)
class PalletType:
    """One catalogued pallet type (m).

    The front face, top to bottom: a solid band ``top``, the pockets between ``blocks``, a solid
    band ``bottom`` (0 = pockets open to the floor).
    """

    name: str
    length: float = unit("mm")
    width: float = unit("mm")
    height: float = unit("mm")
    top: float = unit("mm")
    bottom: float = unit("mm")
    blocks: tuple[Block, ...] = ()

    def __post_init__(self) -> None:
        for name in ("length", "width", "height"):
            require_positive(f"{name}_mm", getattr(self, name))
        if self.top < 0 or self.bottom < 0:
            raise ValueError("top_mm and bottom_mm must not be negative")
        if self.pocket_height <= 0:
            raise ValueError(f"top_mm + bottom_mm leave no pocket in a pallet {self.height * 1000:.0f} mm high")
        if len(self.blocks) < 2:
            raise ValueError("a pallet needs at least two blocks to form a pocket")
        edges = sorted((b.y - b.width / 2, b.y + b.width / 2) for b in self.blocks)
        if edges[0][0] < -self.width / 2 - 1e-9 or edges[-1][1] > self.width / 2 + 1e-9:
            raise ValueError("a block reaches beyond the pallet's width")
        if any(a[1] > b[0] for a, b in zip(edges, edges[1:], strict=False)):
            raise ValueError("blocks overlap")

    @property
    def pocket_height(self) -> float:
        """PH: height of the pocket opening (m)."""
        return self.height - self.top - self.bottom

    @property
    def deck_top(self) -> float:
        """Height of the top deck's upper surface above the frame-P origin (m)."""
        return self.pocket_height / 2 + self.top

    @property
    def deck_bottom(self) -> float:
        """Height of the pallet's underside below the frame-P origin (m), negative."""
        return -self.pocket_height / 2 - self.bottom

    def pockets(self) -> NDArray[np.float64]:
        """Pocket openings as (K, 2) arrays of ``[y_right, y_left]`` (m), right to left."""
        edges = sorted((b.y - b.width / 2, b.y + b.width / 2) for b in self.blocks)
        return np.array([(a[1], b[0]) for a, b in zip(edges, edges[1:], strict=False)])


def load_pallets(path: str | Path) -> dict[str, PalletType]:
    """Read a pallet catalogue YAML into ``{name: PalletType}``.

    Raises
    ------
    ConfigError
        Naming the file, the pallet and the key that is wrong.
    """
    path = Path(path)
    data = read_yaml(path, what="pallet catalogue")
    if not isinstance(data, Mapping) or not data:
        raise ConfigError(f"{path}: expected a mapping of pallet names to their geometry")
    catalogue = {}
    for name, entry in data.items():
        where = child(f"{path}:", name)
        if not isinstance(entry, Mapping):
            raise ConfigError(f"{where}: expected a mapping, got {type(entry).__name__}")
        catalogue[str(name)] = section_from_mapping(PalletType, {"name": str(name), **entry}, where)
    return catalogue


def pallet_type(catalogue: Mapping[str, PalletType], name: str) -> PalletType:
    """Look a pallet type up by name with an error that lists the catalogued ones."""
    try:
        return catalogue[name]
    except KeyError:
        raise ConfigError(f"unknown pallet type {name!r}; the catalogue has {sorted(catalogue)}") from None
