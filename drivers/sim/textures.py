"""Procedural textures of the randomised looks (``look: random``): reflectance (BGR, 0..1) of a surface
at points given in its object's frame.

Every texture is a pure function of the point, the object's size, the face the point lies on and an
integer seed, so a scene looks the same wherever it is sampled (any pixel, any sub-sample, the reference
or the fast renderer). Noise is lattice value noise from an integer hash: no tables, no state. The
functions are compiled scalar code (numba): a frame shades millions of points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

Array = NDArray[np.float64]

KINDS = (
    "wood", "carton", "concrete", "epoxy", "tiles", "planks", "checker-plate", "painted", "corrugated", "steel",
    "plain",
)  # fmt: skip


@dataclass(frozen=True)
class Style:
    """How one object looks: texture kind (one of :data:`KINDS`), base colour (BGR, 0..1), seed, wear
    (dirt and stains, 0..1) and a kind-specific ``detail`` (plank gap width m, film strength, holes)."""

    kind: str
    colour: tuple[float, float, float]
    seed: int
    wear: float = 0.3
    detail: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"texture kind {self.kind!r}: expected one of {KINDS}")

    def packed(self) -> Array:
        """(8,) floats for the compiled shader: kind index, colour, seed, wear, detail, 0."""
        return np.array([KINDS.index(self.kind), *self.colour, self.seed, self.wear, self.detail, 0.0])


@njit(cache=True, inline="always")
def hash01(ix: float, iy: float, seed: float) -> float:
    """Uniform 0..1 per integer lattice point (32-bit integer hash)."""
    h = (np.int64(ix) * 374761393 + np.int64(iy) * 668265263 + np.int64(seed) * 2246822519) & 0xFFFFFFFF
    h = ((h ^ (h >> 13)) * 1274126177) & 0xFFFFFFFF
    return ((h ^ (h >> 16)) & 0xFFFFFF) / 16777216.0


@njit(cache=True)
def value_noise(u: float, v: float, seed: float) -> float:
    """Smooth 2-D value noise in 0..1 with unit lattice spacing."""
    iu, iv = math.floor(u), math.floor(v)
    fu, fv = u - iu, v - iv
    fu, fv = fu * fu * (3 - 2 * fu), fv * fv * (3 - 2 * fv)
    a, b = hash01(iu, iv, seed), hash01(iu + 1, iv, seed)
    c, d = hash01(iu, iv + 1, seed), hash01(iu + 1, iv + 1, seed)
    return (a + (b - a) * fu) * (1 - fv) + (c + (d - c) * fu) * fv


@njit(cache=True)
def fbm(u: float, v: float, seed: float, octaves: int) -> float:
    """Fractal value noise in 0..1: octaves of halving amplitude and doubling frequency."""
    total, amplitude, norm, scale = 0.0, 1.0, 0.0, 1.0
    for k in range(octaves):
        total += amplitude * value_noise(u * scale, v * scale, seed + 101 * k)
        norm += amplitude
        amplitude *= 0.5
        scale *= 2.0
    return total / norm


@njit(cache=True, inline="always")
def texel(styles, k, x, y, z, hx, hy, hz, axis):  # pragma: no cover - compiled
    """BGR reflectance of style ``styles[k]`` (see :meth:`Style.packed`) at (x, y, z) on face ``axis``."""
    kind, seed, wear, detail = int(styles[k, 0]), styles[k, 4], styles[k, 5], styles[k, 6]
    cb, cg, cr = styles[k, 1], styles[k, 2], styles[k, 3]
    sx, sy, sz = x + hx, y + hy, z + hz  # from the object's lower corner
    u = sy if axis == 0 else sx
    v = sy if axis == 2 else sz
    if kind == 1:
        b, g, r = _carton(cb, cg, cr, u, v, 2 * (hy if axis == 0 else hx), seed, detail)
    else:
        if kind == 0:
            value = _wood(sx, sy, sz, hx, hy, hz, axis, seed, detail)
        elif kind == 2:
            value = _concrete(u, v, seed)
        elif kind == 3:
            b, g, r = _epoxy(cb, cg, cr, u, v, seed)
            return _wear(u + 3.1 * axis, v, seed, wear, b, g, r)
        elif kind == 4:
            value = _tiles(u, v, seed)
        elif kind == 5:
            value = _planks(u, v, seed)
        elif kind == 6:
            value = _checker_plate(u, v, seed)
        elif kind == 7:
            value = _painted(u, v, seed)
        elif kind == 8:
            value = 0.85 + 0.15 * math.copysign(abs(math.sin(2 * math.pi * u / 0.2)) ** 0.3,
                                                math.sin(2 * math.pi * u / 0.2)) + 0.05 * fbm(u / 1.5, v / 1.5, seed, 3)
        elif kind == 9:
            value = _steel(u, v, y, axis, seed, wear, detail)
        else:
            value = 1.0
        b, g, r = cb * value, cg * value, cr * value
    return _wear(u + 3.1 * axis, v, seed, wear, b, g, r)


@njit(cache=True)
def _wear(u, v, seed, wear, b, g, r):
    """Dirt (broad darkening) and stains (sharp-edged dark brown blotches)."""
    if wear <= 0:
        return b, g, r
    darken = 1 - wear * 0.35 * fbm(u / 0.35, v / 0.35, seed + 7, 3)
    stain = min(max((fbm(u / 0.12, v / 0.12, seed + 13, 2) - 0.8) * 12, 0.0), 1.0) * wear * 0.7
    keep = darken * (1 - stain)
    return b * keep + 0.108 * stain, g * keep + 0.156 * stain, r * keep + 0.198 * stain


@njit(cache=True)
def _wood(sx, sy, sz, hx, hy, hz, axis, seed, detail):
    """Boards: grain along the longest axis, warped; knots; darker end grain; plank gaps across top
    faces and a seam between a deck's two board layers on its front face (``detail`` = gap width)."""
    if hx >= hy and hx >= hz:
        along, long_axis, other = sx, 0, sy
    elif hy >= hz:
        along, long_axis, other = sy, 1, sx
    else:
        along, long_axis, other = sz, 2, sx
    across = other if axis == 2 else sz
    warp = fbm(along / 0.5, across / 0.05, seed, 2)
    grain = math.sin(2 * math.pi * (across / 0.006 + 2.5 * warp))
    value = 0.93 + 0.07 * grain * (0.5 + 0.5 * fbm(along / 0.2, across / 0.02, seed + 3, 2))
    cell = math.floor(along / 0.25)  # knots: at most one per 0.25 m of board
    if hash01(cell, 0.0, seed + 5) < 0.45:
        centre_a = (cell + 0.2 + 0.6 * hash01(cell, cell, seed + 6)) * 0.25
        centre_c = 2 * hz * hash01(cell, cell + 1, seed + 8)
        rr = math.hypot((along - centre_a) / 0.018, (across - centre_c) / 0.009)
        value *= 1 - 0.55 * math.exp(-rr * rr) - 0.12 * math.exp(-(rr / 2.5) ** 2) * (0.5 + 0.5 * math.sin(rr * 6))
    if axis != 2 and axis != long_axis:
        value *= 0.86  # end grain
    if detail > 0 and hz < 0.05:
        board = 0.09 + 0.06 * hash01(seed, 1.0, seed)
        if axis == 2 and sx % board < detail:
            value = 0.25
        if axis == 0 and hz > 0.004 and abs(sz - 1.1 * hz) < 0.0015:
            value *= 0.55
    return value


JOINT = 0.003  # m: a point this close to a carton's border lies on the joint between cartons
JOINT_SHADE = 0.35  # a joint's tone, of the carton's


@njit(cache=True)
def _carton(cb, cg, cr, u, v, u_size, seed, detail):
    """Stacked cartons: staggered joints, a tape stripe over each carton, some labels, stretch film, on a face
    ``u_size`` (m) wide (u from 0 to it, v up from its lower edge)."""
    width = 0.25 + 0.3 * hash01(seed, 2.0, seed)
    height = 0.2 + 0.25 * hash01(seed, 3.0, seed)
    row = math.floor(v / height)
    cu = u + 0.5 * width * (row % 2)
    col = math.floor(cu / width)
    fu, fv = cu / width - col, v / height - row
    tone = (0.9 + 0.2 * hash01(col, row, seed + 1)) * (0.97 + 0.06 * fbm(u / 0.05, v / 0.05, seed + 2, 2))
    b, g, r = cb * tone, cg * tone, cr * tone
    if abs(fu - 0.5) < 0.03 + 0.02 * hash01(seed, 4.0, seed):
        shine = 0.95 + 0.05 * math.sin(v * 400)
        if int(seed) % 3:
            b, g, r = 0.42 * shine, 0.6 * shine, 0.72 * shine
        else:
            b, g, r = 0.86 * shine, 0.87 * shine, 0.88 * shine
    if hash01(col, row, seed + 9) < 0.35 and abs(fu - 0.25) < 0.12 and abs(fv - 0.6) < 0.14:
        ink = math.sin(fv * 260) > 0.3 and abs(fu - 0.25) < 0.09 and abs(fv - 0.6) < 0.1
        b = g = r = 0.15 if ink else 0.92
    # Upright joints lie between cartons, never at a face's sides: drawn there (until session 48: at u = 0, in every
    # other row), a 3 mm seam inside a load's left edge leaned that edge's line 1-8 px over the load's height, and
    # the load's edges gave a pitch 0.2-1.4 deg off at the true pose of loaded random looks, from the left edge alone.
    # The joint along the bottom row's lower edge stays: the dark line where cartons stand on the deck, which a face
    # match reads (without it, campaign seed 7 pick 58 was measured 6.4 mm high).
    upright = min(fu, 1 - fu) * width < JOINT and JOINT <= u <= u_size - JOINT
    if upright or min(fv, 1 - fv) * height < JOINT:
        b, g, r = b * JOINT_SHADE, g * JOINT_SHADE, r * JOINT_SHADE
    if detail > 0:  # stretch film: bright wrap bands and streaks
        film = detail * min(max(fbm(u / 0.6 + v / 0.08, v / 0.15, seed + 11, 2) * 1.6 - 0.5, 0.0), 1.0)
        b, g, r = b * (1 - film) + 0.9 * film, g * (1 - film) + 0.9 * film, r * (1 - film) + 0.9 * film
    return b, g, r


@njit(cache=True)
def _concrete(u, v, seed):
    """Mottled concrete with saw-cut joints every 4 m."""
    value = 0.85 + 0.2 * fbm(u / 0.4, v / 0.4, seed, 3) + 0.06 * value_noise(u / 0.01, v / 0.01, seed + 1)
    if abs((u + 50) % 4.0 - 2.0) > 1.996 or abs((v + 50) % 4.0 - 2.0) > 1.996:
        value *= 0.5
    return value


@njit(cache=True)
def _epoxy(cb, cg, cr, u, v, seed):
    """Painted floor with a yellow safety line."""
    if abs((v + 50) % 3.3 - 1.2) < 0.05:
        return 0.1, 0.75, 0.85
    value = 0.95 + 0.08 * fbm(u / 0.8, v / 0.8, seed, 3)
    return cb * value, cg * value, cr * value


@njit(cache=True)
def _tiles(u, v, seed):
    """Square tiles with dark grout and a tone per tile."""
    size = 0.3 + 0.3 * (int(seed) % 3)
    iu, iv = math.floor(u / size), math.floor(v / size)
    fu, fv = u / size - iu, v / size - iv
    if min(fu, 1 - fu) * size < 0.004 or min(fv, 1 - fv) * size < 0.004:
        return 0.45
    return 0.88 + 0.2 * hash01(iu, iv, seed)


@njit(cache=True)
def _planks(u, v, seed):
    """A wooden truck bed: planks along the truck with dark gaps, each plank its own tone."""
    width = 0.12 + 0.04 * (int(seed) % 3)
    i = math.floor(u / width)
    if (u / width - i) * width < 0.008:
        return 0.3
    grain = math.sin(2 * math.pi * (u / 0.005 + 3 * fbm(v / 0.8, u / 0.05, seed, 2)))
    return (0.8 + 0.35 * hash01(i, i, seed)) * (0.95 + 0.05 * grain)


@njit(cache=True)
def _checker_plate(u, v, seed):
    """Steel checker plate: diagonal raised lozenges, plate seams every 1.25 m."""
    if abs((v + 50) % 1.25 - 0.6) > 0.62:
        return 0.35
    a, b = (u + v) / 0.03, (u - v) / 0.03
    ra = round(a)
    lozenge = abs(a - ra) < 0.12 and abs(round(b + (ra % 2) * 0.5) - b) < 0.35
    return 0.9 + 0.15 * fbm(u / 0.5, v / 0.5, seed, 3) + (0.25 if lozenge else 0.0)


@njit(cache=True)
def _painted(u, v, seed):
    """Painted block wall with mortar joints."""
    row = math.floor(v / 0.2)
    cu = u + 0.2 * (row % 2)
    mortar = v % 0.2 < 0.01 or cu % 0.4 < 0.01
    return (0.8 if mortar else 1.0) * (0.92 + 0.1 * fbm(u / 0.6, v / 0.6, seed, 3))


@njit(cache=True)
def _steel(u, v, y, axis, seed, wear, detail):
    """Painted steel with bright scuffs; punched holes every 50 mm on racking (``detail`` > 0)."""
    value = 0.9 + 0.1 * fbm(u / 0.1, v / 0.3, seed, 2)
    value += 1.5 * wear * min(max((value_noise(u / 0.02, v / 0.2, seed + 4) - 0.8) * 8, 0.0), 1.0)
    if detail > 0 and axis == 0 and abs(v % 0.05 - 0.025) < 0.008 and abs(y) < 0.012:
        value = 0.15
    return value
