"""The OCamCalib (Scaramuzza) omnidirectional model, and its ``calib_results.txt`` file format.

In OCamCalib's own frame a pixel (row, column) lifts to ``(x, y, pol(r))``: x along rows (down),
y along columns (right), z backwards (``pol[0] < 0``). The forward map goes through ``invpol``,
a polynomial of the elevation angle ``atan(z / sqrt(x^2 + y^2))`` giving the radius; we refine its
result by Newton steps on ``pol`` so projection is the exact inverse of back projection (round
trips to 1e-6 px), and report how far ``invpol`` alone is off (:meth:`OCamCalib.invpol_error_px`).
"""

from __future__ import annotations

import math
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.polynomial import polynomial as P

from agf.camera.base import Array, CameraModel
from agf.camera.viewpoint_shift import ViewpointShift
from agf.errors import ConfigError

INVPOL_WARN_PX = 0.5


class InvpolWarning(UserWarning):
    """A calibration file's ``invpol`` disagrees with its ``pol`` by more than INVPOL_WARN_PX."""


@dataclass(frozen=True, eq=False)
class OCamCalib(CameraModel):
    """Scaramuzza's model. ``pol``, ``invpol`` lowest order first; centre as (row, column) in pixels;
    affine ``c, d, e`` exactly as OCamCalib defines them."""

    pol: Array
    invpol: Array
    center_row: float
    center_col: float
    c: float = 1.0
    d: float = 0.0
    e: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("pol", "invpol"):
            coefficients = np.asarray(getattr(self, name), dtype=float).ravel()
            if coefficients.size < 2 or not np.all(np.isfinite(coefficients)):
                raise ValueError(f"{name}: expected at least 2 finite coefficients, got {coefficients}")
            object.__setattr__(self, name, coefficients)
        if self.pol[0] >= 0:
            raise ValueError(f"pol[0] must be negative (the optical axis looks along -z), got {self.pol[0]}")
        if abs(self.c - self.d * self.e) < 1e-9:
            raise ValueError(f"affine c - d*e must not vanish, got c={self.c} d={self.d} e={self.e}")

    def _project_optical(self, directions: Array) -> tuple[Array, np.ndarray]:
        x, y, z = directions[:, 1], directions[:, 0], -directions[:, 2]  # OCamCalib's axes
        norm = np.hypot(x, y)
        elevation = np.arctan2(z, norm)
        r, ok = self.radius_from_elevation(elevation)
        r = np.where(ok, r, 0.0)
        safe = np.where(norm > 0, norm, 1.0)
        xs, ys = x / safe * r, y / safe * r
        row = xs * self.c + ys * self.d + self.center_row
        col = xs * self.e + ys + self.center_col
        return np.stack([col, row], axis=1), ok

    def _unproject_optical(self, pixels: Array) -> tuple[Array, np.ndarray]:
        du, dv = pixels[:, 0] - self.center_col, pixels[:, 1] - self.center_row
        inv_det = 1.0 / (self.c - self.d * self.e)
        xp = inv_det * (dv - self.d * du)
        yp = inv_det * (-self.e * dv + self.c * du)
        zp = P.polyval(np.hypot(xp, yp), self.pol)
        optical = np.stack([yp, xp, -zp], axis=1)
        return optical, np.all(np.isfinite(optical), axis=1)

    def radius_from_elevation(self, elevation: Array) -> tuple[Array, np.ndarray]:
        """Image radius (px, before the affine part) of rays at OCamCalib ``elevation`` (rad).

        ``invpol`` gives the first guess; Newton on ``atan2(pol(r), r) = elevation`` makes it exact (two or
        three steps from that guess; at most eight).
        """
        dpol = P.polyder(self.pol)
        # Rays far outside the field of view make Newton diverge; they are flagged invalid below.
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            r = _polyval(elevation, self.invpol)
            for _ in range(8):
                z = _polyval(r, self.pol)
                g = np.arctan2(z, r) - elevation
                if not np.any(np.abs(g) > 1e-13):  # converged (NaN rays, outside the model, stay invalid)
                    break
                dg = (_polyval(r, dpol) * r - z) / (r**2 + z**2)
                r = r - g / dg
            ok = np.isfinite(r) & (r >= 0) & (np.abs(np.arctan2(_polyval(r, self.pol), r) - elevation) < 1e-9)
        return r, ok

    def invpol_error_px(self, samples: int = 512) -> float:
        """Largest radius difference (px) between ``invpol`` and the exact inverse of ``pol`` over the FOV."""
        incidence = np.linspace(0.0, self.max_incidence, samples)
        elevation = incidence - math.pi / 2
        exact, ok = self.radius_from_elevation(elevation)
        return float(np.max(np.abs(P.polyval(elevation, self.invpol) - exact)[ok]))


def _polyval(x: Array, coefficients: Array) -> Array:
    """``numpy.polynomial.polynomial.polyval(x, coefficients)`` for an (N,) ``x``, with its arithmetic (Horner
    from ``coefficients[-1] + 0 x``) in place: numpy's allocates every step, and the projection's Newton solve
    evaluates 14,000 polynomials over the bench's 34 frames (0.45 s of 18 profiled)."""
    value = x * 0.0
    value += coefficients[-1]
    for coefficient in coefficients[-2::-1]:
        value *= x
        value += coefficient
    return value


def default_max_incidence(pol: Array, width: int, height: int, center_row: float, center_col: float) -> float:
    """Incidence (rad) at the farthest image corner, or where ``pol`` stops being monotonic if sooner."""
    corners = np.array([[0, 0], [0, width - 1], [height - 1, 0], [height - 1, width - 1]], dtype=float)
    r_max = float(np.max(np.hypot(corners[:, 0] - center_row, corners[:, 1] - center_col)))
    r = np.linspace(0.0, r_max, 4096)
    incidence = math.pi / 2 + np.arctan2(P.polyval(r, pol), r)
    rising = np.diff(incidence) > 0
    last = int(np.argmin(rising)) if not np.all(rising) else rising.size
    return float(incidence[last])


# -- calib_results.txt --------------------------------------------------------------------------

_SECTIONS = ("pol", "invpol", "centre", "affine", "size")
_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$|^[+-]?(nan|inf)$", re.IGNORECASE)


def read_calib_results(path: str | Path) -> OCamCalib:
    """Read OCamCalib's ``calib_results.txt`` (plus this project's optional extension sections).

    Extensions, each after a comment naming it: ``#viewpoint shift ...`` followed by two lines
    (count and incidence angles in deg; count and pupil offsets in mm, forward positive, zero at
    45 deg), and ``#max incidence ...`` followed by one value in deg.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read camera file ({exc.strerror or exc})") from exc
    lines = _data_lines(text, path)
    if len(lines) < len(_SECTIONS):
        raise ConfigError(
            f"{path}: truncated OCamCalib file: expected {len(_SECTIONS)} data lines "
            f"({', '.join(_SECTIONS)}), found {len(lines)}"
        )
    pol = _counted(lines[0], path, "pol")
    invpol = _counted(lines[1], path, "invpol")
    center_row, center_col = _fixed(lines[2], path, "centre (row column)", 2)
    c, d, e = _fixed(lines[3], path, "affine (c d e)", 3)
    height, width = _fixed(lines[4], path, "image size (height width)", 2)
    if height != int(height) or width != int(width) or height <= 0 or width <= 0:
        raise ConfigError(f"{path}: image size: expected two positive integers (height width), got {lines[4][1]}")
    height, width = int(height), int(width)
    if not (0 <= center_row < height and 0 <= center_col < width):
        raise ConfigError(
            f"{path}: centre (row {center_row}, column {center_col}) lies outside the {width} x {height} image"
        )
    shift, max_incidence = _extensions(lines[len(_SECTIONS) :], path)
    if max_incidence is None:
        max_incidence = default_max_incidence(pol, width, height, center_row, center_col)
    try:
        model = OCamCalib(width, height, max_incidence, shift, pol, invpol, center_row, center_col, c, d, e)
    except ValueError as exc:
        raise ConfigError(f"{path}: {exc}") from exc
    error = model.invpol_error_px()
    if error > INVPOL_WARN_PX:
        warnings.warn(
            f"{path}: invpol disagrees with pol by up to {error:.2f} px over the field of view; "
            "projection is refined on pol, but the file's invpol fit is poor",
            InvpolWarning,
            stacklevel=2,
        )
    return model


def write_calib_results(model: OCamCalib, path: str | Path, header: str = "") -> None:
    """Write ``model`` in OCamCalib's format (with the extension sections when it has them)."""

    def numbers(values: np.ndarray) -> str:
        return " ".join(f"{v:.9e}" for v in values)

    out = [header.rstrip("\n")] if header else []
    out += [
        "#polynomial coefficients for the DIRECT mapping function (ocam_model.ss in MATLAB). "
        "These are used by cam2world",
        "",
        f"{model.pol.size} {numbers(model.pol)}",
        "",
        "#polynomial coefficients for the inverse mapping function (ocam_model.invpol in MATLAB). "
        "These are used by world2cam",
        "",
        f"{model.invpol.size} {numbers(model.invpol)}",
        "",
        '#center: "row" and "column", starting from 0 (C convention)',
        "",
        f"{model.center_row:.6f} {model.center_col:.6f}",
        "",
        '#affine parameters "c", "d", "e"',
        "",
        f"{model.c:.6f} {model.d:.6f} {model.e:.6f}",
        "",
        '#image size: "height" and "width"',
        "",
        f"{model.height} {model.width}",
        "",
        "#max incidence (extension of this project): deg",
        "",
        f"{math.degrees(model.max_incidence):.4f}",
        "",
    ]
    if model.shift is not None and model.shift.angles is not None:
        out += [
            "#viewpoint shift (extension of this project): incidence angles in deg, then entrance-pupil "
            "offsets in mm along the optical axis (forward positive, zero at 45 deg)",
            "",
            f"{model.shift.angles.size} {' '.join(f'{math.degrees(a):.4f}' for a in model.shift.angles)}",
            f"{model.shift.offsets.size} {' '.join(f'{o * 1e3:.4f}' for o in model.shift.offsets)}",
            "",
        ]
    Path(path).write_text("\n".join(out) + "\n")


def _data_lines(text: str, path: Path) -> list[tuple[str, list[str]]]:
    """Non-comment lines as (the last comment before them, their tokens)."""
    comment, lines = "", []
    for raw in text.splitlines():
        line = raw.strip()
        if not line:
            continue
        if line.startswith("#"):
            comment = line.lower()
            continue
        lines.append((comment, line.split()))
    return lines


def _floats(tokens: list[str], path: Path, what: str) -> np.ndarray:
    bad = [t for t in tokens if not _NUMBER.match(t)]
    if bad:
        raise ConfigError(f"{path}: {what}: expected numbers, got {bad[0]!r}")
    values = np.array([float(t) for t in tokens])
    if not np.all(np.isfinite(values)):
        raise ConfigError(f"{path}: {what}: values must be finite, got {' '.join(tokens)}")
    return values


def _counted(line: tuple[str, list[str]], path: Path, what: str) -> np.ndarray:
    tokens = line[1]
    count = tokens[0]
    if not re.fullmatch(r"\d+", count):
        raise ConfigError(f"{path}: {what}: the line must start with the coefficient count, got {count!r}")
    values = _floats(tokens[1:], path, what)
    if int(count) != values.size or values.size < 2:
        raise ConfigError(f"{path}: {what}: declares {count} coefficients but gives {values.size}")
    return values


def _fixed(line: tuple[str, list[str]], path: Path, what: str, n: int) -> np.ndarray:
    values = _floats(line[1], path, what)
    if values.size != n:
        raise ConfigError(f"{path}: {what}: expected {n} numbers, got {values.size}")
    return values


def _extensions(lines: list[tuple[str, list[str]]], path: Path) -> tuple[ViewpointShift | None, float | None]:
    shift, max_incidence, i = None, None, 0
    while i < len(lines):
        comment = lines[i][0]
        if "viewpoint shift" in comment and i + 1 < len(lines):
            angles = _counted(lines[i], path, "viewpoint shift angles")
            offsets = _counted(lines[i + 1], path, "viewpoint shift offsets")
            try:
                shift = ViewpointShift(angles=np.radians(angles), offsets=offsets * 1e-3)
            except ValueError as exc:
                raise ConfigError(f"{path}: {exc}") from exc
            i += 2
        elif "max incidence" in comment:
            (value,) = _fixed(lines[i], path, "max incidence (deg)", 1)
            if not 0 < value <= 180:
                raise ConfigError(f"{path}: max incidence: expected a value in (0, 180] deg, got {value}")
            max_incidence, i = math.radians(value), i + 1
        else:
            raise ConfigError(f"{path}: unexpected data line {' '.join(lines[i][1])!r} after the image size")
    return shift, max_incidence
