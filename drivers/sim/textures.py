"""Procedural textures of the randomised looks (``look: random``): reflectance (BGR, 0..1) of a surface
at points given in its object's frame.

Every texture is a pure function of the point, the object's size, the face the point lies on and an
integer seed, so a scene renders identically wherever it is sampled (any pixel, any sub-sample, the
reference or the fast renderer). Noise is lattice value noise from an integer hash: no tables, no state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Style:
    """How one object looks: texture kind, base colour (BGR, 0..1), seed and wear (dirt, stains 0..1)."""

    kind: str
    colour: tuple[float, float, float]
    seed: int
    wear: float = 0.3
    detail: float = 0.0  # kind-specific extra (film strength, gap width, ...)


def _hash(ix: NDArray, iy: NDArray, seed: int) -> Array:
    """Uniform 0..1 per integer lattice point (vectorised 32-bit integer hash)."""
    h = (ix.astype(np.int64) * 374761393 + iy.astype(np.int64) * 668265263 + seed * 2246822519) & 0xFFFFFFFF
    h = ((h ^ (h >> 13)) * 1274126177) & 0xFFFFFFFF
    return ((h ^ (h >> 16)) & 0xFFFFFF) / float(0x1000000)


def value_noise(u: Array, v: Array, seed: int) -> Array:
    """Smooth 2-D value noise in 0..1 with unit lattice spacing."""
    iu, iv = np.floor(u), np.floor(v)
    fu, fv = u - iu, v - iv
    fu, fv = fu * fu * (3 - 2 * fu), fv * fv * (3 - 2 * fv)
    a, b = _hash(iu, iv, seed), _hash(iu + 1, iv, seed)
    c, d = _hash(iu, iv + 1, seed), _hash(iu + 1, iv + 1, seed)
    return (a + (b - a) * fu) * (1 - fv) + (c + (d - c) * fu) * fv


def fbm(u: Array, v: Array, seed: int, octaves: int = 3) -> Array:
    """Fractal value noise in about 0..1: octaves of halving amplitude and doubling frequency."""
    total, amplitude, norm = np.zeros_like(u), 1.0, 0.0
    for k in range(octaves):
        scale = 2.0**k
        total += amplitude * value_noise(u * scale, v * scale, seed + 101 * k)
        norm += amplitude
        amplitude *= 0.5
    return total / norm


def face_coordinates(local: Array, half: Array, axis: NDArray) -> tuple[Array, Array]:
    """In-face coordinates (m) from the face's lower corner: (along the longer in-face axis of a front
    or side face: horizontal; vertical) for vertical faces, (x, y) for horizontal ones."""
    shifted = local + half
    u = np.where(axis == 0, shifted[:, 1], shifted[:, 0])
    v = np.where(axis == 2, shifted[:, 1], shifted[:, 2])
    return u, v


def reflectance(style: Style, local: Array, half: Array, axis: NDArray) -> Array:
    """BGR reflectance (N, 3) of ``style`` at object-frame points ``local`` (N, 3) on faces ``axis`` (N,)
    (0: x faces, 1: y faces, 2: z faces) of an object of half extents ``half`` (3,), m."""
    u, v = face_coordinates(local, half, axis)
    texture = _KINDS[style.kind](style, u, v, local, half, axis)
    colour = np.asarray(style.colour)[None, :] * texture[:, None] if texture.ndim == 1 else texture
    return _wear(style, u + 3.1 * axis, v, colour)


def _wear(style: Style, u: Array, v: Array, colour: Array) -> Array:
    """Dirt (broad darkening) and stains (sharp-edged dark brown blotches)."""
    if style.wear <= 0:
        return colour
    dirt = fbm(u / 0.35, v / 0.35, style.seed + 7)
    stain = np.clip((fbm(u / 0.12, v / 0.12, style.seed + 13, 2) - 0.8) * 12, 0, 1) * style.wear * 0.7
    darken = 1 - style.wear * 0.35 * dirt
    brown = np.array([0.18, 0.26, 0.33])
    return (colour * darken[:, None]) * (1 - stain[:, None]) + brown * stain[:, None] * 0.6


def _wood(style: Style, u: Array, v: Array, local: Array, half: Array, axis: NDArray) -> Array:
    """Boards: grain along the longest in-face axis, warped; knots; darker end grain on the short faces;
    plank gaps across the top faces; a seam between the deck's two board layers on the front face."""
    seed = style.seed
    long_axis = int(np.argmax(half))
    shifted = local + half
    along = shifted[:, long_axis]
    across = np.where(axis == 2, shifted[:, (long_axis + 1) % 3], shifted[:, 2])
    warp = fbm(along / 0.5, across / 0.05, seed, 2)
    grain = np.sin(2 * np.pi * (across / 0.006 + 2.5 * warp))
    value = 0.93 + 0.07 * grain * (0.5 + 0.5 * fbm(along / 0.2, across / 0.02, seed + 3, 2))
    # knots: at most one per 0.25 m cell along the board, dark cores with a halo of bent grain
    cell = np.floor(along / 0.25)
    has = _hash(cell, np.zeros_like(cell), seed + 5) < 0.45
    centre_a = (cell + 0.2 + 0.6 * _hash(cell, cell, seed + 6)) * 0.25
    centre_c = 2 * half[2] * _hash(cell, cell + 1, seed + 8) if half[2] > 0 else 0.0
    r = np.hypot((along - centre_a) / 0.018, (across - centre_c) / 0.009)
    knot = has * np.exp(-(r**2))
    value *= 1 - 0.55 * knot - 0.12 * has * np.exp(-((r / 2.5) ** 2)) * (0.5 + 0.5 * np.sin(r * 6))
    end_grain = (axis != 2) & (axis != long_axis)
    value = np.where(end_grain, value * 0.86, value)
    # plank gaps: dark bands across the top face every board width (only where boards are wide)
    if style.detail > 0 and half[2] < 0.05:
        board = 0.09 + 0.06 * _hash(np.array([seed]), np.array([1]), seed)[0]
        gap = (shifted[:, 0] % board) < style.detail
        value = np.where((axis == 2) & gap, 0.25, value)
        seam = np.abs(shifted[:, 2] - 0.55 * 2 * half[2]) < 0.0015
        value = np.where((axis == 0) & seam & (half[2] > 0.008), value * 0.55, value)
    return value


def _carton(style: Style, u: Array, v: Array, local: Array, half: Array, axis: NDArray) -> Array:
    """Stacked cartons: staggered joints, a tape stripe over each carton, some labels, stretch film."""
    seed = style.seed
    width = 0.25 + 0.3 * _hash(np.array([seed]), np.array([2]), seed)[0]
    height = 0.2 + 0.25 * _hash(np.array([seed]), np.array([3]), seed)[0]
    row = np.floor(v / height)
    cu = u + 0.5 * width * (row % 2)
    col = np.floor(cu / width)
    fu, fv = cu / width - col, v / height - row
    base = np.asarray(style.colour)
    tone = 0.9 + 0.2 * _hash(col, row, seed + 1)
    colour = base[None, :] * (tone * (0.97 + 0.06 * fbm(u / 0.05, v / 0.05, seed + 2, 2)))[:, None]
    tape = np.abs(fu - 0.5) < 0.03 + 0.02 * _hash(np.array([seed]), np.array([4]), seed)[0]
    tape_colour = np.array([0.42, 0.6, 0.72]) if seed % 3 else np.array([0.86, 0.87, 0.88])
    colour = np.where(tape[:, None], tape_colour * (0.95 + 0.05 * np.sin(v * 400))[:, None], colour)
    label = (_hash(col, row, seed + 9) < 0.35) & (np.abs(fu - 0.25) < 0.12) & (np.abs(fv - 0.6) < 0.14)
    bars = (np.sin(fv * 260) > 0.3) & (np.abs(fu - 0.25) < 0.09) & (np.abs(fv - 0.6) < 0.1)
    colour = np.where(label[:, None], np.where(bars[:, None], 0.15, 0.92), colour)
    joint = (np.minimum(fu, 1 - fu) * width < 0.003) | (np.minimum(fv, 1 - fv) * height < 0.003)
    colour = np.where(joint[:, None], colour * 0.35, colour)
    if style.detail > 0:  # stretch film: bright wrap bands and streaks
        band = fbm(u / 0.6 + v / 0.08, v / 0.15, seed + 11, 2)
        film = style.detail * np.clip(band * 1.6 - 0.5, 0, 1)
        colour = colour * (1 - film[:, None]) + 0.9 * film[:, None]
    return colour


def _concrete(style: Style, u: Array, v: Array, local: Array, half: Array, axis: NDArray) -> Array:
    """Mottled concrete with saw-cut joints every few metres."""
    value = 0.85 + 0.2 * fbm(u / 0.4, v / 0.4, style.seed) + 0.06 * value_noise(u / 0.01, v / 0.01, style.seed + 1)
    joints = (np.abs(((u + 50) % 4.0) - 2.0) > 1.996) | (np.abs(((v + 50) % 4.0) - 2.0) > 1.996)
    return np.where(joints, value * 0.5, value)


def _epoxy(style: Style, u: Array, v: Array, local: Array, half: Array, axis: NDArray) -> Array:
    """Painted floor with a yellow safety line."""
    colour = np.asarray(style.colour)[None, :] * (0.95 + 0.08 * fbm(u / 0.8, v / 0.8, style.seed))[:, None]
    line = np.abs(((v + 50) % 3.3) - 1.2) < 0.05
    return np.where(line[:, None], np.array([0.1, 0.75, 0.85]), colour)


def _tiles(style: Style, u: Array, v: Array, local: Array, half: Array, axis: NDArray) -> Array:
    """Square tiles with dark grout and a tone per tile."""
    size = 0.3 + 0.3 * (style.seed % 3)
    iu, iv = np.floor(u / size), np.floor(v / size)
    grout = (np.minimum(u / size - iu, 1 - u / size + iu) * size < 0.004) | (
        np.minimum(v / size - iv, 1 - v / size + iv) * size < 0.004
    )
    return np.where(grout, 0.45, 0.88 + 0.2 * _hash(iu, iv, style.seed))


def _planks(style: Style, u: Array, v: Array, local: Array, half: Array, axis: NDArray) -> Array:
    """A wooden truck bed: long planks along the truck with dark gaps, each plank its own tone."""
    width = 0.12 + 0.08 * (style.seed % 3) / 2
    i = np.floor(u / width)
    grain = np.sin(2 * np.pi * (u / 0.005 + 3 * fbm(v / 0.8, u / 0.05, style.seed, 2)))
    value = (0.8 + 0.35 * _hash(i, i, style.seed)) * (0.95 + 0.05 * grain)
    return np.where((u / width - i) * width < 0.008, 0.3, value)


def _checker_plate(style: Style, u: Array, v: Array, local: Array, half: Array, axis: NDArray) -> Array:
    """Steel checker plate: diagonal raised lozenges, plate seams every metre or so."""
    a = (u + v) / 0.03
    b = (u - v) / 0.03
    lozenge = (np.abs(a - np.round(a)) < 0.12) & (np.abs(np.round(b + (np.round(a) % 2) * 0.5) - b) < 0.35)
    value = 0.9 + 0.15 * fbm(u / 0.5, v / 0.5, style.seed) + 0.25 * lozenge
    seam = np.abs(((v + 50) % 1.25) - 0.6) > 0.62
    return np.where(seam, 0.35, value)


def _painted(style: Style, u: Array, v: Array, local: Array, half: Array, axis: NDArray) -> Array:
    """Painted block wall: mortar grid, darker lower band."""
    row = np.floor(v / 0.2)
    cu = u + 0.2 * (row % 2)
    mortar = ((v % 0.2) < 0.01) | ((cu % 0.4) < 0.01)
    return np.where(mortar, 0.8, 1.0) * (0.92 + 0.1 * fbm(u / 0.6, v / 0.6, style.seed))


def _corrugated(style: Style, u: Array, v: Array, local: Array, half: Array, axis: NDArray) -> Array:
    """Corrugated metal cladding: ridges every 0.2 m (shading depends on the ridge side), panel seams."""
    ridge = np.sin(2 * np.pi * u / 0.2)
    return 0.85 + 0.15 * np.sign(ridge) * np.abs(ridge) ** 0.3 + 0.05 * fbm(u / 1.5, v / 1.5, style.seed)


def _steel(style: Style, u: Array, v: Array, local: Array, half: Array, axis: NDArray) -> Array:
    """Painted steel with bright scuffs; punched holes every 50 mm on racking (``detail`` > 0)."""
    value = 0.9 + 0.1 * fbm(u / 0.1, v / 0.3, style.seed, 2)
    scuff = np.clip((value_noise(u / 0.02, v / 0.2, style.seed + 4) - 0.8) * 8, 0, 1)
    value = value + 1.5 * scuff * style.wear
    if style.detail > 0:
        holes = (np.abs((v % 0.05) - 0.025) < 0.008) & (np.abs(local[:, 1]) < 0.012) & (axis == 0)
        value = np.where(holes, 0.15, value)
    return value


def _plain(style: Style, u: Array, v: Array, local: Array, half: Array, axis: NDArray) -> Array:
    return np.ones(len(u))


_KINDS = {
    "wood": _wood,
    "carton": _carton,
    "concrete": _concrete,
    "epoxy": _epoxy,
    "tiles": _tiles,
    "planks": _planks,
    "checker-plate": _checker_plate,
    "painted": _painted,
    "corrugated": _corrugated,
    "steel": _steel,
    "plain": _plain,
}
