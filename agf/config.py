"""Load and validate the YAML configuration into typed, frozen objects.

Each section of ``configs/agf.yaml`` is a frozen dataclass. :func:`section_from_mapping` builds any
such dataclass from a YAML mapping, generically, from its type hints:

* a field whose metadata has ``unit`` is read from the key ``<name>_<unit>`` and converted to SI
  (``mm`` -> m, ``deg`` -> rad, ``ms`` -> s, ``mm_s`` -> m/s, ``deg_s2`` -> rad/s^2, ...);
* a field whose metadata has ``path=True`` is resolved relative to the directory of the file that
  names it, and must exist;
* nested dataclasses, ``dict[str, Dataclass]``, ``tuple[float, ...]``, ``Literal`` and ``X | None``
  are supported; unknown keys, missing required keys, wrong types and impossible limits are errors
  naming the file, the key path and what was expected.
"""

from __future__ import annotations

import dataclasses
import math
import re
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml

from agf.errors import ConfigError
from agf.geometry import Transform, transform_from_dict

_UNIT_SCALE = {
    "mm": 1e-3,
    "m": 1.0,
    "deg": math.pi / 180.0,
    "rad": 1.0,
    "ms": 1e-3,
    "s": 1.0,
    "mm_s": 1e-3,
    "mm_s2": 1e-3,
    "mm_s3": 1e-3,
    "deg_s": math.pi / 180.0,
    "deg_s2": math.pi / 180.0,
    "deg_s3": math.pi / 180.0,
}


def unit(name: str, default: Any = dataclasses.MISSING) -> Any:
    """A dataclass field read from ``<field>_<name>`` in YAML and stored in SI units."""
    if name not in _UNIT_SCALE:
        raise ValueError(f"unknown unit {name!r}; known: {sorted(_UNIT_SCALE)}")
    return field(default=default, metadata={"unit": name})


def path_field(default: Any = dataclasses.MISSING) -> Any:
    """A dataclass field holding a file path, resolved against the naming file's directory."""
    return field(default=default, metadata={"path": True})


def read_yaml(path: str | Path, *, what: str = "file") -> Any:
    """Parse a YAML file, turning I/O and syntax errors into a :class:`ConfigError`."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: {what} not found")
    try:
        with path.open(encoding="utf-8") as stream:
            return yaml.safe_load(stream)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({exc})") from exc
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc})") from exc


def section_from_mapping(cls: type, data: Any, where: str, base_dir: Path | None = None) -> Any:
    """Build the frozen dataclass ``cls`` from the YAML mapping ``data``.

    Parameters
    ----------
    cls : dataclass type
    data : mapping from the YAML file
    where : str
        ``"file.yaml: key.path"`` used as the prefix of every error.
    base_dir : Path, optional
        Directory that relative paths are resolved against.

    Raises
    ------
    ConfigError
        Unknown or missing keys, wrong types, missing files, or a failed ``validate()`` of ``cls``.
    """
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: expected a mapping, got {_type_name(data)}")
    hints = typing.get_type_hints(cls)
    values: dict[str, Any] = {}
    known: set[str] = set()
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        unit_name = f.metadata.get("unit")
        key = f"{f.name}_{unit_name}" if unit_name else f.name
        known.add(key)
        if key not in data:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise ConfigError(f"{child(where, key)}: missing required key")
            continue
        value = _convert(hints[f.name], data[key], child(where, key), base_dir)
        if unit_name and value is not None:
            value = _scale(value, _UNIT_SCALE[unit_name])
        if f.metadata.get("path") and value is not None:
            value = _resolve_path(value, child(where, key), base_dir)
        values[f.name] = value
    unknown = sorted(set(data) - known)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; expected some of {sorted(known)}")
    try:
        return cls(**values)
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"{where}: {exc}") from exc


def child(where: str, key: object) -> str:
    """Key path of ``key`` below ``where`` (``"file.yaml: a.b"``), for error messages."""
    return f"{where} {key}" if where.endswith(":") else f"{where}.{key}"


def _scale(value: Any, scale: float) -> Any:
    if isinstance(value, tuple):
        return tuple(v * scale for v in value)
    return value * scale


def _resolve_path(value: str, where: str, base_dir: Path | None) -> Path:
    path = Path(value)
    if not path.is_absolute() and base_dir is not None:
        path = base_dir / path
    if not path.exists():
        raise ConfigError(f"{where}: file {path} does not exist")
    return path


def _type_name(value: Any) -> str:
    return "nothing (null)" if value is None else type(value).__name__


def _convert(tp: Any, value: Any, where: str, base_dir: Path | None) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        (inner,) = [a for a in args if a is not type(None)]
        return _convert(inner, value, where, base_dir)
    if origin is Literal:
        if value not in args:
            raise ConfigError(f"{where}: expected one of {list(args)}, got {value!r}")
        return value
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{where}: expected a list, got {_type_name(value)}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, f"{where}[{i}]", base_dir) for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(f"{where}: expected a list of {len(args)} items, got {len(value)}")
        pairs = enumerate(zip(args, value, strict=True))
        return tuple(_convert(a, v, f"{where}[{i}]", base_dir) for i, (a, v) in pairs)
    if origin is dict:
        if not isinstance(value, Mapping):
            raise ConfigError(f"{where}: expected a mapping, got {_type_name(value)}")
        return {str(k): _convert(args[1], v, child(where, k), base_dir) for k, v in value.items()}
    if tp is Transform:  # a dataclass too, but written in the {x_mm, ..., yaw_deg} form
        try:
            return transform_from_dict(value, where=where)
        except ValueError as exc:
            raise ConfigError(str(exc)) from exc
    if dataclasses.is_dataclass(tp):
        return section_from_mapping(tp, value, where, base_dir)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected a whole number, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise ConfigError(f"{where}: expected a finite number, got {value!r}")
        return float(value)
    if tp in (str, Path):
        if not isinstance(value, str) or not value:
            raise ConfigError(f"{where}: expected a non-empty string, got {value!r}")
        return value
    if tp is Any:
        return value
    raise TypeError(f"config field type {tp!r} is not supported by section_from_mapping")


def require_range(name: str, low: float, high: float) -> None:
    """Raise ``ValueError`` unless ``low < high`` (used by sections' ``__post_init__``)."""
    if not low < high:
        raise ValueError(f"{name}: minimum {low!r} must be below maximum {high!r}")


def require_positive(name: str, value: float) -> None:
    """Raise ``ValueError`` unless ``value > 0``."""
    if not value > 0:
        raise ValueError(f"{name}: must be positive, got {value!r}")


# --------------------------------------------------------------------------------------------------
# Sections of configs/agf.yaml


@dataclass(frozen=True)
class ForkGeometry:
    """The forks (paper section V.A): FT thickness, FL length; fork width and centre spacing."""

    thickness: float = unit("mm", 0.036)
    length: float = unit("mm", 1.070)
    width: float = unit("mm", 0.120)
    spacing: float = unit("mm", 0.600)

    def __post_init__(self) -> None:
        for name in ("thickness", "length", "width", "spacing"):
            require_positive(name, getattr(self, name))
        if self.spacing <= self.width:
            raise ValueError(f"spacing ({self.spacing} m) must exceed the fork width ({self.width} m)")

    def tip_corners(self) -> np.ndarray:
        """The corners of both tines' tips (8, 3), fork frame (m): the tips lie at x = 0."""
        return np.array([[0.0, side * self.spacing / 2 + edge * self.width / 2, height * self.thickness / 2]
                         for side in (-1, 1) for edge in (-1, 1) for height in (-1, 1)])


@dataclass(frozen=True)
class SearchVolume:
    """Where, in the fork frame, the pallet's front-face centre is searched without a prior."""

    x_min: float = unit("mm", 0.100)
    x_max: float = unit("mm", 0.800)
    y_min: float = unit("mm", -0.300)
    y_max: float = unit("mm", 0.300)
    z_min: float = unit("mm", -0.400)
    z_max: float = unit("mm", 0.500)
    yaw_max: float = unit("deg", math.radians(10.0))
    pitch_max: float = unit("deg", math.radians(6.0))

    def __post_init__(self) -> None:
        for axis in "xyz":
            require_range(f"{axis}_mm", getattr(self, f"{axis}_min"), getattr(self, f"{axis}_max"))
        require_positive("yaw_max_deg", self.yaw_max)
        require_positive("pitch_max_deg", self.pitch_max)

    @property
    def low(self) -> np.ndarray:
        """The volume's lower corner (x, y, z), m, shape (3,)."""
        return np.array([self.x_min, self.y_min, self.z_min])

    @property
    def high(self) -> np.ndarray:
        """The volume's upper corner (x, y, z), m, shape (3,)."""
        return np.array([self.x_max, self.y_max, self.z_max])

    def lifted(self, lift: float) -> SearchVolume:
        """This volume after the forks rose by ``lift`` (m), for a volume anchored to the floor rather than to the
        forks (a fleet pick's ``height`` narrows it at the forks' height when the pick starts): the pallet stays
        where it is, so in the fork frame its z range moves down by ``lift``."""
        return dataclasses.replace(self, z_min=self.z_min - lift, z_max=self.z_max - lift)


@dataclass(frozen=True)
class VisionConfig:
    """The camera, its commissioning calibration and the pallet being picked."""

    camera: Path = path_field()
    calibration: Path = path_field()
    pallets: Path = path_field()
    pallet_type: str = "jis-t11"
    search: SearchVolume = field(default_factory=SearchVolume)


@dataclass(frozen=True)
class BenchConfig:
    """Modules whose ``@bench_case`` functions ``agf bench`` runs."""

    modules: tuple[str, ...] = ()


_TOPIC_LEVEL = re.compile(r"[A-Za-z0-9_.:-]+")


def _require_topic_level(name: str, value: str) -> None:
    """VDA 5050 6.3: a topic level holds A-Z a-z 0-9 _ . : - (no '/', '$' or MQTT wildcards)."""
    if not _TOPIC_LEVEL.fullmatch(value):
        raise ValueError(f"{name}: {value!r} may hold only A-Z a-z 0-9 _ . : - (it is an MQTT topic level)")


@dataclass(frozen=True)
class BrokerConfig:
    """The MQTT broker of the fleet; the password comes from an environment variable or a file, never
    from the configuration itself."""

    host: str = "127.0.0.1"
    port: int = 1883
    tls: bool = False
    ca_file: Path | None = path_field(None)
    username: str | None = None
    password_env: str | None = None
    password_file: Path | None = path_field(None)
    keepalive: float = unit("s", 15.0)
    reconnect_min: float = unit("s", 1.0)
    reconnect_max: float = unit("s", 30.0)

    def __post_init__(self) -> None:
        if not 0 < self.port < 65536:
            raise ValueError(f"port: expected 1..65535, got {self.port}")
        if self.password_env and self.password_file:
            raise ValueError("give password_env or password_file, not both")
        if (self.password_env or self.password_file) and not self.username:
            raise ValueError("a password needs a username")
        if self.ca_file and not self.tls:
            raise ValueError("ca_file is given but tls is false")
        require_positive("keepalive_s", self.keepalive)
        require_positive("reconnect_min_s", self.reconnect_min)
        if self.reconnect_max < self.reconnect_min:
            raise ValueError(f"reconnect_max_s ({self.reconnect_max}) is below reconnect_min_s ({self.reconnect_min})")


@dataclass(frozen=True)
class TruckFacts:
    """What the VDA 5050 factsheet says about the truck that the rest of the configuration does not."""

    series_name: str = "AGF reach truck"
    length: float = unit("mm", 2.4)
    width: float = unit("mm", 1.2)
    height_max: float = unit("mm", 3.5)
    max_load_kg: float = 1400.0

    def __post_init__(self) -> None:
        for name in ("length", "width", "height_max"):
            require_positive(f"{name}_mm", getattr(self, name))
        require_positive("max_load_kg", self.max_load_kg)


@dataclass(frozen=True)
class FleetConfig:
    """The VDA 5050 interface (``agf serve``): topics ``interface_name/v2/manufacturer/serial_number/...``."""

    interface_name: str = "uagv"
    manufacturer: str = "agf"
    serial_number: str = "sim-0001"
    map_id: str = "hall"
    state_period: float = unit("s", 30.0)
    node_deviation: float = unit("mm", 0.5)
    height_window: float = unit("mm", 0.1)
    pick_time: float = unit("s", 60.0)
    broker: BrokerConfig = field(default_factory=BrokerConfig)
    truck: TruckFacts = field(default_factory=TruckFacts)

    def __post_init__(self) -> None:
        for name in ("interface_name", "manufacturer", "serial_number"):
            _require_topic_level(name, getattr(self, name))
        if not 0 < self.state_period <= 30.0:
            raise ValueError(f"state_period_s: VDA 5050 wants a state at least every 30 s, got {self.state_period}")
        for name, key in (("node_deviation", "_mm"), ("height_window", "_mm"), ("pick_time", "_s")):
            require_positive(name + key, getattr(self, name))


@dataclass(frozen=True)
class RecorderConfig:
    """Where every pick's MCAP log goes (``folder``, relative to the config file), how much of it is
    kept (``max_total_mb``, oldest logs deleted first) and how often it reaches the disk."""

    folder: str = "../logs"
    max_total_mb: float = 2000.0
    flush_period: float = unit("ms", 0.5)

    def __post_init__(self) -> None:
        require_positive("max_total_mb", self.max_total_mb)
        if not 0.01 <= self.flush_period <= 1.0:
            raise ValueError(f"flush_period_ms must be within 10..1000 ms (at least once per second), "
                             f"got {self.flush_period * 1e3:g} ms")


@dataclass(frozen=True)
class Config:
    """The whole configuration, SI units throughout."""

    source: Path
    vision: VisionConfig
    forks: ForkGeometry = field(default_factory=ForkGeometry)
    plugins: dict[str, str] = field(default_factory=dict)
    bench: BenchConfig = field(default_factory=BenchConfig)
    fleet: FleetConfig = field(default_factory=FleetConfig)
    sections: dict[str, Any] = field(default_factory=dict)
    recorder: RecorderConfig = field(default_factory=RecorderConfig)

    @property
    def root(self) -> Path:
        """Directory of the configuration file; relative paths in it are resolved from here."""
        return self.source.parent


@dataclass(frozen=True)
class _ConfigFile:
    vision: VisionConfig
    forks: ForkGeometry = field(default_factory=ForkGeometry)
    plugins: dict[str, str] = field(default_factory=dict)
    bench: BenchConfig = field(default_factory=BenchConfig)
    recorder: RecorderConfig = field(default_factory=RecorderConfig)
    fleet: FleetConfig = field(default_factory=FleetConfig)
    # Sections whose typed parsers live with the code that uses them (drives, motion, insertion,
    # controller, simulation); each is validated by that code's own ``from_mapping``.
    drives: Any = None
    bus: Any = None
    motion: Any = None
    insertion: Any = None
    controller: Any = None
    camera_source: Any = None
    simulation: Any = None
    mast: Any = None


SECTION_NAMES = ("drives", "bus", "motion", "insertion", "controller", "camera_source", "simulation", "mast")


def load_config(path: str | Path) -> Config:
    """Load ``configs/agf.yaml`` (or another file) into a :class:`Config`.

    Raises
    ------
    ConfigError
        With the file, the key path and what was expected.
    """
    path = Path(path)
    data = read_yaml(path, what="configuration file")
    if data is None:
        raise ConfigError(f"{path}: the configuration file is empty")
    parsed = section_from_mapping(_ConfigFile, data, f"{path}:", base_dir=path.parent)
    sections = {name: getattr(parsed, name) for name in SECTION_NAMES if getattr(parsed, name) is not None}
    return Config(
        source=path,
        vision=parsed.vision,
        forks=parsed.forks,
        plugins=parsed.plugins,
        bench=parsed.bench,
        fleet=parsed.fleet,
        sections=sections,
        recorder=parsed.recorder,
    )


def load_calibration(path: str | Path) -> Transform:
    """Read the commissioning calibration file: ``camera_in_fork: {x_mm, ..., yaw_deg}``."""
    path = Path(path)
    data = read_yaml(path, what="calibration file")
    if not isinstance(data, Mapping) or "camera_in_fork" not in data:
        raise ConfigError(f"{path}: expected a mapping with the key 'camera_in_fork'")
    unknown = sorted(set(data) - {"camera_in_fork", "residual_px", "spread", "images", "note", "created"})
    if unknown:
        raise ConfigError(f"{path}: unknown key(s) {unknown}")
    try:
        return transform_from_dict(data["camera_in_fork"], where=f"{path}: camera_in_fork")
    except ValueError as exc:
        raise ConfigError(str(exc)) from exc
