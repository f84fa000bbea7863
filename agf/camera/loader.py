"""Pick and build a camera model from a file.

* ``*.txt``: OCamCalib's ``calib_results.txt`` (with this project's optional extension sections);
* a Kalibr camchain YAML (``cam0: {camera_model: ds | eucm | omni | pinhole, ...}``);
* this project's camera YAML (``model: ocamcalib | kannala_brandt | double_sphere | eucm | unified``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from agf.camera.base import Array, CameraModel
from agf.camera.double_sphere import DoubleSphere
from agf.camera.eucm import ExtendedUnified
from agf.camera.kannala_brandt import KannalaBrandt
from agf.camera.ocamcalib import OCamCalib, default_max_incidence, read_calib_results
from agf.camera.unified import Unified
from agf.camera.viewpoint_shift import ViewpointShift
from agf.config import child, read_yaml
from agf.errors import ConfigError

# Our YAML: model name -> (class, required parameter names in constructor order).
_MODELS: dict[str, tuple[type[CameraModel], tuple[str, ...]]] = {
    "kannala_brandt": (KannalaBrandt, ("fx", "fy", "cx", "cy", "k")),
    "double_sphere": (DoubleSphere, ("fx", "fy", "cx", "cy", "xi", "alpha")),
    "eucm": (ExtendedUnified, ("fx", "fy", "cx", "cy", "alpha", "beta")),
    "unified": (Unified, ("fx", "fy", "cx", "cy", "xi", "radtan")),
    "ocamcalib": (OCamCalib, ("pol", "invpol", "center_row", "center_col", "affine")),
}
_COMMON = ("model", "width", "height", "max_incidence_deg", "viewpoint_shift")


def load_camera(path: str | Path) -> CameraModel:
    """The camera model a file describes; :class:`ConfigError` naming the file and key if it is bad."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: camera file not found")
    if path.suffix.lower() == ".txt":
        return read_calib_results(path)
    data = read_yaml(path, what="camera file")
    if not isinstance(data, Mapping):
        raise ConfigError(f"{path}: expected a mapping (our camera YAML or a Kalibr camchain)")
    if "model" in data:
        return camera_from_mapping(data, f"{path}:")
    cameras = sorted(key for key in data if str(key).startswith("cam"))
    if not cameras:
        raise ConfigError(f"{path}: neither 'model' (our camera YAML) nor 'cam0' (Kalibr camchain) found")
    return camera_from_kalibr(data[cameras[0]], f"{path}: {cameras[0]}")


def camera_from_mapping(data: Mapping[str, Any], where: str) -> CameraModel:
    """Build a model from our camera YAML mapping (mm and degrees at this edge)."""
    model = data.get("model")
    if model not in _MODELS:
        raise ConfigError(f"{child(where, 'model')}: expected one of {sorted(_MODELS)}, got {model!r}")
    cls, names = _MODELS[model]
    unknown = set(data) - set(_COMMON) - set(names)
    if unknown:
        raise ConfigError(f"{child(where, sorted(unknown)[0])}: unknown key for model {model}")
    values = {name: _number_or_list(data, name, where) for name in names}
    width, height = (_positive_int(data, key, where) for key in ("width", "height"))
    shift = _shift(data.get("viewpoint_shift"), child(where, "viewpoint_shift"))
    if model == "ocamcalib":
        c, d, e = _vector(values.pop("affine"), 3, child(where, "affine"))
        values.update(c=c, d=d, e=e)
    for key in ("k", "radtan"):
        if key in values:
            values[key] = tuple(_vector(values[key], 4, child(where, key)))
    return _build(cls, width, height, data.get("max_incidence_deg"), shift, values, where)


def camera_from_kalibr(data: Any, where: str) -> CameraModel:
    """Build a model from one camera of a Kalibr camchain."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: expected a mapping")
    try:
        kind, distortion = data["camera_model"], data.get("distortion_model", "none")
        intrinsics = np.asarray(data["intrinsics"], dtype=float)
        coefficients = np.asarray(data.get("distortion_coeffs") or [], dtype=float)
        width, height = (int(v) for v in data["resolution"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: Kalibr camera needs camera_model, intrinsics and resolution ({exc})") from exc
    table: dict[tuple[str, str], tuple[type[CameraModel], int, int]] = {
        ("ds", "none"): (DoubleSphere, 6, 0),
        ("eucm", "none"): (ExtendedUnified, 6, 0),
        ("omni", "radtan"): (Unified, 5, 4),
        ("omni", "none"): (Unified, 5, 0),
        ("pinhole", "equidistant"): (KannalaBrandt, 4, 4),
    }
    if (kind, distortion) not in table:
        raise ConfigError(f"{where}: unsupported Kalibr model {kind} + {distortion}; supported: {sorted(table)}")
    cls, n_intrinsics, n_coefficients = table[(kind, distortion)]
    if intrinsics.size != n_intrinsics or coefficients.size != n_coefficients:
        raise ConfigError(
            f"{where}: {kind}/{distortion} needs {n_intrinsics} intrinsics and {n_coefficients} "
            f"distortion coefficients, got {intrinsics.size} and {coefficients.size}"
        )
    if kind in ("ds", "eucm"):
        a, b, fx, fy, cx, cy = intrinsics
        values = dict(
            fx=fx, fy=fy, cx=cx, cy=cy, **({"xi": a, "alpha": b} if kind == "ds" else {"alpha": a, "beta": b})
        )
    elif kind == "omni":
        xi, fx, fy, cx, cy = intrinsics
        values = dict(
            fx=fx, fy=fy, cx=cx, cy=cy, xi=xi, radtan=tuple(coefficients) if coefficients.size else (0.0,) * 4
        )
    else:
        fx, fy, cx, cy = intrinsics
        values = dict(fx=fx, fy=fy, cx=cx, cy=cy, k=tuple(coefficients))
    return _build(cls, width, height, None, None, values, where)


def _build(
    cls: type[CameraModel],
    width: int,
    height: int,
    max_incidence_deg: Any,
    shift: ViewpointShift | None,
    values: dict[str, Any],
    where: str,
) -> CameraModel:
    try:
        model = cls(width, height, math.pi, shift, **values)
        if max_incidence_deg is not None:
            if not isinstance(max_incidence_deg, int | float) or not 0 < max_incidence_deg <= 180:
                raise ValueError(f"max_incidence_deg: expected a number in (0, 180], got {max_incidence_deg!r}")
            limit = math.radians(max_incidence_deg)
        elif isinstance(model, OCamCalib):
            limit = default_max_incidence(model.pol, width, height, model.center_row, model.center_col)
        else:
            limit = _border_incidence(model)
        return type(model)(**{**_fields(model), "max_incidence": limit})
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where} {exc}") from exc


def _fields(model: CameraModel) -> dict[str, Any]:
    import dataclasses

    return {f.name: getattr(model, f.name) for f in dataclasses.fields(model)}


def _border_incidence(model: CameraModel) -> float:
    """Largest incidence (rad) among image-border pixels the model can lift: its default FOV."""
    t = np.linspace(0.0, 1.0, 257)
    w, h = model.width - 1.0, model.height - 1.0
    border = np.concatenate(
        [
            np.stack([t * w, np.zeros_like(t)], 1),
            np.stack([t * w, np.full_like(t, h)], 1),
            np.stack([np.zeros_like(t), t * h], 1),
            np.stack([np.full_like(t, w), t * h], 1),
        ]
    )
    optical, ok = model._unproject_optical(border)
    incidence = np.arctan2(np.hypot(optical[:, 0], optical[:, 1]), optical[:, 2])
    return float(np.max(incidence[ok])) if np.any(ok) else math.pi


def _number_or_list(data: Mapping[str, Any], key: str, where: str) -> Any:
    if key not in data:
        raise ConfigError(f"{child(where, key)}: missing")
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, int | float | list):
        raise ConfigError(f"{child(where, key)}: expected a number or a list of numbers, got {value!r}")
    if isinstance(value, list):
        return _vector(value, None, child(where, key))
    if not math.isfinite(value):
        raise ConfigError(f"{child(where, key)}: expected a finite number, got {value}")
    return float(value)


def _vector(value: Any, n: int | None, where: str) -> Array:
    try:
        array = np.asarray(value, dtype=float).ravel()
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: expected a list of numbers, got {value!r}") from exc
    if (n is not None and array.size != n) or not np.all(np.isfinite(array)):
        raise ConfigError(f"{where}: expected {n or 'some'} finite numbers, got {value!r}")
    return array


def _positive_int(data: Mapping[str, Any], key: str, where: str) -> int:
    value = data.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise ConfigError(f"{child(where, key)}: expected a positive integer (pixels), got {value!r}")
    return value


def _shift(data: Any, where: str) -> ViewpointShift | None:
    if data is None:
        return None
    if not isinstance(data, Mapping) or not ({"angles_deg", "offsets_mm"} == set(data) or {"poly_mm"} == set(data)):
        raise ConfigError(f"{where}: expected {{angles_deg: [...], offsets_mm: [...]}} or {{poly_mm: [...]}}")
    try:
        if "poly_mm" in data:
            return ViewpointShift(poly=_vector(data["poly_mm"], None, child(where, "poly_mm")) * 1e-3)
        return ViewpointShift(
            angles=np.radians(_vector(data["angles_deg"], None, child(where, "angles_deg"))),
            offsets=_vector(data["offsets_mm"], None, child(where, "offsets_mm")) * 1e-3,
        )
    except ValueError as exc:
        raise ConfigError(f"{where}: {exc}") from exc
