"""Randomised looks (scene key ``look: random``, ``agf render --randomize``): everything about a frame
that is not the pallet's geometry, drawn from the scene's seed.

A :class:`Look` holds the styles of every surface (:mod:`drivers.sim.textures`), the lights (a sun that
may shine through a door, ceiling lamps; both cast hard shadows), the hall's extra geometry (where the
bed's front edge runs, the back wall, rack bays with beams, clutter on the bed) and the sensor (exposure,
white balance, gamma, vignetting, noise, blur, motion blur, JPEG). Lights and geometry are placed
relative to the target pallet in fork axes, so during a pick they stay put while the forks move.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from agf.scene import Scene
from drivers.sim.textures import Style

Array = NDArray[np.float64]

# An integer mixed into the scene seed so a look's draws never share a stream with the scene's own.
LOOK_STREAM = 0x10C0


@dataclass(frozen=True)
class Light:
    """A light in fork axes relative to the target pallet's origin: the sun (``direction`` towards it,
    optionally through a door ``door`` = (centre offset, normal, half width, half height), m) or a lamp
    (``position`` offset, irradiance ``power`` at the pallet). ``colour`` is BGR."""

    power: float
    colour: tuple[float, float, float]
    direction: tuple[float, float, float] | None = None
    position: tuple[float, float, float] | None = None
    door: tuple[tuple[float, ...], tuple[float, ...], float, float] | None = None
    shadows: bool = True


@dataclass(frozen=True)
class CameraLight:
    """A :class:`Light` in the camera frame, as the shader uses it."""

    power: float
    colour: Array
    direction: Array | None  # unit, towards the sun
    position: Array | None
    reference_distance: float  # lamp: distance at which the irradiance is ``power``
    door: tuple[Array, Array, Array, Array, float, float] | None  # centre, normal, u, v, half u, half v
    down: Array  # the hall's down direction
    shadows: bool


@dataclass(frozen=True)
class Clutter:
    """A box standing on the pallet's support beside or behind it (pallet frame, m), and its style role."""

    x: tuple[float, float]
    y: tuple[float, float]
    height: float
    role: str


@dataclass(frozen=True)
class Look:
    """Everything random about one scene's appearance (see the module docstring)."""

    styles: dict[str, Style]
    ambient: float
    sky: tuple[float, float, float]
    lights: tuple[Light, ...]
    exposure: float
    white_balance: tuple[float, float, float]
    gamma: float
    vignetting: float
    sigma: float
    blur_px: float
    motion_px: float
    jpeg_quality: int | None
    bed_edge: float  # x of the support's front edge in the pallet frame (m; > 0: under the pallet)
    wall_distance: float  # behind the pallet's back (m)
    rack: tuple[float, ...] = field(default=())  # beam heights above the pallet origin (m); () no rack
    rack_depth: float = 0.5
    clutter: tuple[Clutter, ...] = ()

    def style(self, material: str, index: int) -> Style:
        """The style of object ``index`` made of ``material``: each object its own seed."""
        style = self.styles[material]
        return Style(style.kind, style.colour, style.seed + 7919 * index, style.wear, style.detail)

    def camera_lights(self, scene: Scene) -> list[CameraLight]:
        """The lights in the camera frame of ``scene`` (anchored at its target pallet)."""
        fork_in_camera = scene.camera_in_fork.inverse()
        anchor = scene.pallet.in_fork.translation if scene.pallet is not None else np.zeros(3)
        R = fork_in_camera.rotation
        out = []
        for light in self.lights:
            direction = position = door = None
            distance = 1.0
            if light.direction is not None:
                direction = R @ np.asarray(light.direction)
            if light.position is not None:
                position = fork_in_camera.apply([anchor + np.asarray(light.position)])[0]
                distance = float(np.linalg.norm(light.position))
            if light.door is not None:
                centre, normal, half_u, half_v = light.door
                n = np.asarray(normal)
                u = np.cross([0.0, 0.0, 1.0], n)
                door = (
                    fork_in_camera.apply([anchor + np.asarray(centre)])[0],
                    R @ n,
                    R @ (u / np.linalg.norm(u)),
                    R @ np.array([0.0, 0.0, 1.0]),
                    half_u,
                    half_v,
                )
            out.append(CameraLight(light.power, np.asarray(light.colour), direction, position, distance, door,
                                   -R[:, 2], light.shadows))
        return out


# What :func:`simplified` can take out of a look, and what each means.
PARTS = {
    "wood": "the pallet's wood grain, knots, plank gaps and wear (plain wood of its colour)",
    "textures": "every surface's texture and wear (plain surfaces of their colours)",
    "shadows": "the lights' hard shadows (the lights stay)",
    "sensor": "the sensor's noise and JPEG compression",
    "optics": "blur, motion blur, vignetting and gamma",
}


def simplified(look: Look, parts: Iterable[str]) -> Look:
    """``look`` without some of its :data:`PARTS`, all else (geometry, colours, lights, exposure) as drawn: what a
    measurement's error owes to each part is its error on the full look against its error without the part
    (``tools/error_budget``)."""
    parts = set(parts)
    unknown = parts - PARTS.keys()
    if unknown:
        raise ValueError(f"look parts {sorted(unknown)}: expected some of {sorted(PARTS)}")
    styles = dict(look.styles)
    for material in styles if "textures" in parts else ("wood",) if "wood" in parts else ():
        styles[material] = Style("plain", styles[material].colour, styles[material].seed, 0.0, 0.0)
    changes: dict = {"styles": styles}
    if "shadows" in parts:
        changes["lights"] = tuple(replace(light, shadows=False) for light in look.lights)
    if "sensor" in parts:
        changes.update(sigma=0.0, jpeg_quality=None)
    if "optics" in parts:
        changes.update(blur_px=0.0, motion_px=0.0, vignetting=0.0, gamma=1.0)
    return replace(look, **changes)


def _pick(rng: np.random.Generator, options: list):
    return options[int(rng.integers(len(options)))]


def _colour(rng: np.random.Generator, base: tuple[float, float, float], spread: float = 0.08) -> tuple:
    return tuple(float(np.clip(c * rng.uniform(1 - spread, 1 + spread), 0.02, 0.95)) for c in base)


def draw_look(scene: Scene) -> Look:
    """The random look of ``scene``, a pure function of its seed (and its noise settings, which it scales)."""
    rng = np.random.default_rng([LOOK_STREAM, scene.seed])
    seed = int(rng.integers(1 << 20))
    wood = _pick(rng, [(0.55, 0.74, 0.88), (0.5, 0.62, 0.72), (0.56, 0.58, 0.6), (0.3, 0.42, 0.55),
                       (0.62, 0.4, 0.2), (0.25, 0.28, 0.62)])
    carton = _pick(rng, [(0.35, 0.52, 0.68), (0.5, 0.64, 0.76), (0.82, 0.83, 0.84), (0.27, 0.38, 0.5)])
    floor_kind, floor = _pick(rng, [("concrete", (0.5, 0.5, 0.5)), ("concrete", (0.36, 0.38, 0.4)),
                                    ("epoxy", (0.4, 0.55, 0.35)), ("epoxy", (0.5, 0.5, 0.48)),
                                    ("tiles", (0.6, 0.6, 0.58))])
    bed_kind, bed = _pick(rng, [("planks", (0.25, 0.36, 0.46)), ("checker-plate", (0.42, 0.43, 0.44)),
                                ("plain", (0.18, 0.19, 0.2)), ("concrete", (0.45, 0.46, 0.47))])
    wall_kind, wall = _pick(rng, [("painted", (0.72, 0.72, 0.7)), ("painted", (0.6, 0.72, 0.78)),
                                  ("corrugated", (0.62, 0.63, 0.63)), ("corrugated", (0.62, 0.45, 0.3))])
    upright = _pick(rng, [(0.6, 0.3, 0.1), (0.1, 0.45, 0.9), (0.5, 0.5, 0.5), (0.1, 0.72, 0.85)])
    wear = float(rng.uniform(0.0, 0.8))
    styles = {
        "wood": Style("wood", _colour(rng, wood), seed, wear, float(rng.choice([0.0, 0.006, 0.012]))),
        "carton": Style("carton", _colour(rng, carton), seed + 1, wear * 0.6,
                        float(rng.uniform(0.2, 0.6)) if rng.random() < 0.5 else 0.0),
        "concrete": Style(floor_kind, _colour(rng, floor), seed + 2, float(rng.uniform(0.1, 0.9))),
        "truck-bed": Style(bed_kind, _colour(rng, bed), seed + 3, float(rng.uniform(0.1, 0.9))),
        "dock": Style("concrete", _colour(rng, (0.48, 0.48, 0.47)), seed + 4, float(rng.uniform(0.1, 0.9))),
        "wall": Style(wall_kind, _colour(rng, wall), seed + 5, float(rng.uniform(0.0, 0.6))),
        "upright": Style("steel", _colour(rng, upright), seed + 6, wear, 1.0),
        "beam": Style("steel", _colour(rng, _pick(rng, [(0.1, 0.4, 0.9), (0.1, 0.7, 0.85)])), seed + 7, wear),
        "steel": Style("steel", _colour(rng, (0.2, 0.2, 0.21), 0.3), seed + 8, float(rng.uniform(0.0, 0.5))),
        "panel": Style("plain", (0.86, 0.86, 0.86), seed + 9, 0.0),
        "clutter": Style("carton", _colour(rng, _pick(rng, [carton, (0.3, 0.3, 0.75), (0.6, 0.45, 0.2)])),
                         seed + 10, wear),
    }
    noise = scene.noise
    return Look(
        styles=styles,
        ambient=float(rng.uniform(0.2, 0.5)),
        sky=_colour(rng, (0.6, 0.6, 0.6), 0.3),
        lights=_lights(rng),
        exposure=float(rng.uniform(0.6, 1.35)),
        white_balance=tuple(float(g) for g in np.exp(rng.normal(0.0, 0.08, 3))),
        gamma=float(rng.uniform(0.85, 1.2)),
        vignetting=float(rng.uniform(0.1, 0.6)),
        sigma=float(noise.sigma * rng.uniform(0.7, 2.5) + rng.uniform(0.0, 1.5)),
        blur_px=float(noise.blur_px * rng.uniform(0.6, 2.0)),
        motion_px=float(rng.uniform(0.5, 2.5)) if rng.random() < 0.25 else 0.0,
        jpeg_quality=int(rng.integers(55, 96)) if noise.jpeg_quality is not None or rng.random() < 0.5 else None,
        bed_edge=float(rng.uniform(-0.01, 0.015)) if rng.random() < 0.35 else float(rng.uniform(-0.35, -0.03)),
        wall_distance=float(rng.uniform(2.0, 7.0)),
        rack=tuple(sorted(rng.uniform(0.3, 2.5, int(rng.integers(1, 4))))) if rng.random() < 0.6 else (),
        rack_depth=float(rng.uniform(0.1, 1.5)),
        clutter=tuple(_clutter(rng) for _ in range(int(rng.integers(0, 5)))),
    )


def _lights(rng: np.random.Generator) -> tuple[Light, ...]:
    """A sun (most scenes; often through a door) and one to three ceiling lamps above everything in the
    scene; the sun and the first lamp cast shadows (more shadows cost more than they show)."""
    lights = []
    if rng.random() < 0.7:
        elevation, azimuth = rng.uniform(math.radians(15), math.radians(60)), rng.uniform(-math.pi, math.pi)
        direction = np.array([math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth),
                              math.sin(elevation)])
        door = None
        if rng.random() < 0.7:
            horizontal = direction * [1, 1, 0]
            normal = horizontal / np.linalg.norm(horizontal)
            aim = np.array([rng.uniform(-0.5, 1.5), rng.uniform(-1.5, 1.5), rng.uniform(-0.3, 1.0)])
            distance = rng.uniform(4.0, 9.0)
            centre = aim + direction * distance / math.cos(elevation)
            door = (tuple(centre), tuple(normal), float(rng.uniform(0.6, 2.0)), float(rng.uniform(1.0, 2.5)))
        colour = _colour(rng, (0.85, 0.95, 1.0), 0.05)
        lights.append(Light(float(rng.uniform(0.6, 1.6)), colour, direction=tuple(direction), door=door))
    for n in range(int(rng.integers(1, 4))):
        position = (rng.uniform(-2.0, 4.0), rng.uniform(-3.0, 3.0), rng.uniform(3.7, 6.0))
        colour = _pick(rng, [(1.0, 1.0, 1.0), (0.6, 0.85, 1.0), (1.0, 0.95, 0.85), (0.9, 1.0, 0.9)])
        lights.append(Light(float(rng.uniform(0.3, 0.9)), colour, position=position, shadows=n == 0))
    return tuple(lights)


def _clutter(rng: np.random.Generator) -> Clutter:
    """A box on the support beside the pallet's footprint or behind it, never between camera and pallet."""
    depth, width, height = rng.uniform(0.3, 1.0), rng.uniform(0.3, 1.0), rng.uniform(0.2, 1.4)
    if rng.random() < 0.5:  # beside: clear of the pallet's side by 0.1 m plus any neighbour's width
        side = float(rng.choice([-1, 1]))
        y0 = side * rng.uniform(0.75, 2.6)
        x0 = rng.uniform(0.0, 1.5)
    else:  # behind
        y0, x0 = rng.uniform(-1.5, 1.5), rng.uniform(1.3, 2.5)
    y = (y0, y0 + width) if y0 > 0 else (y0 - width, y0)
    role = "clutter" if rng.random() < 0.7 else "wood"
    return Clutter((float(x0), float(x0 + depth)), (float(y[0]), float(y[1])), float(height), role)

