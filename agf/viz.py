"""Overlays and plots (PNG) for people: what the vision saw and what the controller did.

Drawing only; nothing here decides anything. Images are BGR uint8, as OpenCV writes them.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from agf.camera.base import CameraModel
from agf.errors import InputError
from agf.geometry import Transform
from agf.pallets import PalletType
from agf.vision.face_model import face_model_from_pallet
from agf.vision.panorama import render_panorama

GREEN, RED, YELLOW, CYAN = (60, 200, 60), (40, 40, 230), (0, 215, 255), (230, 200, 0)


def polyline(image: NDArray, camera: CameraModel, points_c: NDArray, colour, thickness: int = 2) -> None:
    """Draw a 3D polyline (camera frame, densified by the caller) where it projects into ``image``."""
    pixels, valid = camera.project(points_c)
    runs = np.split(np.arange(len(pixels)), np.nonzero(~valid)[0])
    for run in runs:
        run = run[valid[run]]
        if len(run) >= 2:
            cv2.polylines(
                image, [np.round(pixels[run] * 8).astype(np.int32)], False, colour, thickness, cv2.LINE_AA, shift=3
            )


def densify(corners: NDArray, closed: bool = True, n: int = 40) -> NDArray:
    """Points along the segments joining ``corners`` (K, 3), so fisheye curvature is drawn faithfully."""
    ends = np.vstack([corners, corners[:1]]) if closed else corners
    t = np.linspace(0.0, 1.0, n)[:, None]
    return np.concatenate([a + t * (b - a) for a, b in zip(ends[:-1], ends[1:], strict=True)])


def draw_face(image: NDArray, camera: CameraModel, pallet_in_camera: Transform, pallet: PalletType, colour) -> None:
    """The pallet's front face outline and pocket openings at a pose."""
    face = face_model_from_pallet(pallet)
    polyline(image, camera, pallet_in_camera.apply(densify(face.corners())), colour)
    for y0, y1, z0, z1 in face.pockets:
        pocket = np.array([[0, y1, z1], [0, y0, z1], [0, y0, z0], [0, y1, z0]], dtype=float)
        polyline(image, camera, pallet_in_camera.apply(densify(pocket)), colour, 1)


def _panorama_panel(gray: NDArray, camera: CameraModel, evidence: Any, height: int) -> NDArray:
    pano, valid = render_panorama(gray, camera, evidence.panorama)
    panel = cv2.cvtColor(np.where(valid, pano, 0).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    for region in evidence.regions:
        c0, c1, r0, r1 = np.round(region).astype(int)
        cv2.rectangle(panel, (c0, r0), (c1, r1), YELLOW, 1)
    for line, region in zip(evidence.lines, evidence.regions, strict=False):
        centre = evidence.panorama.directions_from_pixels(np.array([[region[:2].mean(), region[2:].mean()]]))[0]
        t = np.linspace(-0.6, 0.6, 400)
        start = centre - (centre @ line.normal) * line.normal  # the circle's point nearest the region
        start /= np.linalg.norm(start)
        other = np.cross(line.normal, start)
        points = np.cos(t)[:, None] * start + np.sin(t)[:, None] * other
        pixels = evidence.panorama.pixels_from_directions(points)
        inside = (
            (pixels[:, 0] >= 0)
            & (pixels[:, 0] < panel.shape[1])
            & (pixels[:, 1] >= 0)
            & (pixels[:, 1] < panel.shape[0])
        )
        if inside.sum() >= 2:
            cv2.polylines(
                panel,
                [np.round(pixels[inside]).astype(np.int32)],
                False,
                GREEN if evidence.valid else RED,
                1,
                cv2.LINE_AA,
            )
    label = f"{evidence.hypothesis}: ratio {evidence.ratio:.2f} {'valid' if evidence.valid else 'invalid'}"
    crops = []
    for region in evidence.regions:  # one crop per predicted region: the panorama between them is empty
        c0, c1, r0, r1 = np.round(region).astype(int)
        pad = max((c1 - c0) // 2, 10)
        crop = panel[max(r0 - pad, 0) : r1 + pad, max(c0 - pad, 0) : c1 + pad]
        crops.append(cv2.resize(crop, (max(int(crop.shape[1] * height / max(crop.shape[0], 1)), 1), height)))
    panel = np.hstack(crops) if crops else cv2.resize(panel, (height, height))
    cv2.putText(panel, label, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, CYAN, 1, cv2.LINE_AA)
    return panel


def rectified_face(
    gray: NDArray,
    camera: CameraModel,
    pallet_in_camera: Transform,
    pallet: PalletType,
    pixel: float = 0.002,
    margin: float = 0.04,
) -> tuple[NDArray, NDArray]:
    """The image projected onto the front-face plane at the fitted pose, and the face model, side by side
    material for people (2 mm per pixel, with a margin around the face)."""
    face = face_model_from_pallet(pallet)
    model, ys, zs = face.raster(pixel, margin)
    yy, zz = np.meshgrid(ys, zs)
    points = np.stack([np.zeros(yy.size), yy.ravel(), zz.ravel()], axis=1)
    pixels, valid = camera.project(pallet_in_camera.apply(points))
    maps = [pixels[:, k].reshape(yy.shape).astype(np.float32) for k in (0, 1)]
    rectified = cv2.remap(gray, maps[0], maps[1], cv2.INTER_LINEAR)
    rectified[~valid.reshape(yy.shape)] = 0
    return rectified, (model * 255).astype(np.uint8)


def tolerance_diagram(
    pocket_height: float, forks: Any, sigma_z: float, sigma_pitch: float, sigmas: float = 3.0, size: int = 360
) -> NDArray:
    """Paper Fig. 14: the region of height error against tilt error where the four inequalities of
    section V.A hold (green), with this measurement's uncertainty box (k sigma) at its centre."""
    from agf.insertion import tolerance_slacks

    dz = np.linspace(-pocket_height / 2, pocket_height / 2, size)
    dtheta = np.radians(np.linspace(-3.0, 3.0, size))
    ok = np.array([[tolerance_slacks(z, t, pocket_height, forks).min() > 0 for t in dtheta] for z in dz[::-1]])
    image = np.full((size, size, 3), 255, np.uint8)
    image[ok] = (170, 225, 170)
    cz = (size - 1) / 2
    half_w = sigmas * math.degrees(sigma_pitch) / 6.0 * size
    half_h = sigmas * sigma_z / pocket_height * size
    cv2.rectangle(image, (int(cz - half_w), int(cz - half_h)), (int(cz + half_w), int(cz + half_h)), RED, 2)
    cv2.drawMarker(image, (int(cz), int(cz)), RED, cv2.MARKER_CROSS, 12, 1)
    for text, org in (
        (f"dZ +-{pocket_height * 500:.0f} mm (up)", (6, 16)),
        ("dtheta -3 .. +3 deg", (6, size - 8)),
        (f"box: {sigmas:.0f} sigma", (size - 120, 16)),
    ):
        cv2.putText(image, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return image


def _top_canvas(
    gray: NDArray, camera: CameraModel, pallet: PalletType, pose_in_camera: Any, evidence: Any, colour, text: str
) -> NDArray:
    """The frame with the face drawn at ``pose_in_camera`` (if any) beside the loaded and unloaded
    panoramas (if there is ``evidence``), ``text`` along the bottom."""
    view = cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)
    if pose_in_camera is not None:
        draw_face(view, camera, pose_in_camera, pallet, colour)
    height = 720
    view = cv2.resize(view, (int(view.shape[1] * height / view.shape[0]), height))
    parts = [view]
    if evidence is not None:
        panels = [_panorama_panel(gray, camera, evidence[name], height // 2) for name in ("loaded", "unloaded")]
        width = max(p.shape[1] for p in panels)
        column = np.vstack([cv2.copyMakeBorder(p, 0, 0, 0, width - p.shape[1], cv2.BORDER_CONSTANT) for p in panels])
        parts.append(column[:height])
    canvas = np.hstack(parts)
    cv2.putText(canvas, text, (10, height - 14), cv2.FONT_HERSHEY_SIMPLEX, 0.6, CYAN, 1, cv2.LINE_AA)
    return canvas


def _stack(rows: list[NDArray]) -> NDArray:
    width = max(r.shape[1] for r in rows)
    return np.vstack([cv2.copyMakeBorder(r, 0, 0, 0, width - r.shape[1], cv2.BORDER_CONSTANT) for r in rows])


def measurement_overlay(
    frame: NDArray, camera: CameraModel, pallet: PalletType, detail: Any, out: Path, forks: Any = None
) -> None:
    """The frame with the matched face, beside the loaded and unloaded panoramas with their predicted
    regions (yellow) and detected lines (green valid, red not); below, the image rectified onto the
    face plane next to the face model, and the tolerance diagram with this measurement's uncertainty."""
    gray = frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
    m = detail.measurement
    d = m.pallet_in_fork.to_dict()
    text = (
        f"x {d['x_mm']:.1f} mm  y {d['y_mm']:.1f} mm  z {d['z_mm']:.1f} mm  pitch {d['pitch_deg']:.2f} deg  "
        f"yaw {d['yaw_deg']:.2f} deg  ({'loaded' if m.loaded else 'unloaded'})"
    )
    canvas = _top_canvas(gray, camera, pallet, m.pallet_in_camera, detail.evidence, GREEN, text)
    rectified, model = rectified_face(gray, camera, m.pallet_in_camera, pallet)
    strip = np.vstack([rectified, np.full((6, rectified.shape[1]), 255, np.uint8), model])
    strip = cv2.cvtColor(cv2.resize(strip, (int(strip.shape[1] * 360 / strip.shape[0]), 360)), cv2.COLOR_GRAY2BGR)
    parts = [strip]
    if forks is not None:
        parts.append(tolerance_diagram(pallet.pocket_height, forks, m.sigma_z, m.sigma_pitch))
    write_png(out, _stack([canvas, np.hstack(parts)]))


def refusal_overlay(
    frame: NDArray, camera: CameraModel, pallet: PalletType, found: Any, reason: str, out: Path
) -> None:
    """A refused measurement explained: the frame with the best face candidate the search found (red),
    the panoramas of the edge evidence at it, the image rectified at that candidate, and the reason.

    ``found`` is the :class:`~agf.vision.measure.Findings` the refusal carried (None: nothing found)."""
    gray = frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
    pose = None if found is None else found.pose
    evidence = None if found is None else found.evidence
    if pose is None:
        text = "REFUSED: no face candidate"
    else:
        d = pose.pallet_in_fork.to_dict()
        text = (
            f"REFUSED. Best candidate (red): x {d['x_mm']:.0f} y {d['y_mm']:.0f} z {d['z_mm']:.0f} mm, "
            f"similarity {pose.score:.2f}, margin {pose.margin:.2f}"
        )
    rows = [_top_canvas(gray, camera, pallet, None if pose is None else pose.pallet_in_camera, evidence, RED, text)]
    if pose is not None:
        rectified, model = rectified_face(gray, camera, pose.pallet_in_camera, pallet)
        strip = np.vstack([rectified, np.full((6, rectified.shape[1]), 255, np.uint8), model])
        strip = cv2.resize(strip, (int(strip.shape[1] * 300 / strip.shape[0]), 300))
        rows.append(cv2.cvtColor(strip, cv2.COLOR_GRAY2BGR))
    rows.append(_text_band(reason, max(r.shape[1] for r in rows)))
    write_png(out, _stack(rows))


def _text_band(text: str, width: int, line_px: int = 24) -> NDArray:
    """``text`` wrapped onto a white band ``width`` px wide."""
    chars = max(width // 11, 20)
    words, lines = text.split(), [""]
    for word in words:
        lines[-1:] = [lines[-1] + " " + word] if len(lines[-1]) + len(word) < chars else [lines[-1], word]
    band = np.full((line_px * len(lines) + 12, width, 3), 255, np.uint8)
    for k, line in enumerate(lines):
        origin = (10, line_px * (k + 1))
        cv2.putText(band, line.strip(), origin, cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    return band


def write_png(path: Path, image: NDArray) -> None:
    if path.suffix.lower() != ".png":
        raise InputError(f"{path}: expected a file name ending in .png")
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), image):
        raise OSError(f"{path}: could not write the PNG")


def calibration_overlay(frame: NDArray, camera: CameraModel, fit: Any, out: Path) -> None:
    """The panel image with the fitted panel edges (green) and each edge point's residual (red, x10)."""
    view = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR) if frame.ndim == 2 else frame.copy()
    for (u, v), r in zip(fit.points_px, fit.offsets_px, strict=True):
        cv2.circle(view, (int(round(u)), int(round(v))), 1, GREEN, -1)
        if abs(r) > 0.3:
            cv2.circle(view, (int(round(u)), int(round(v))), int(min(abs(r) * 10, 20)), RED, 1)
    d = fit.camera_in_fork.to_dict()
    text = (
        f"camera_in_fork x {d['x_mm']:.1f} y {d['y_mm']:.1f} z {d['z_mm']:.1f} mm  roll {d['roll_deg']:.2f} "
        f"pitch {d['pitch_deg']:.2f} yaw {d['yaw_deg']:.2f} deg  residual {fit.residual_px:.2f} px"
    )
    cv2.putText(view, text, (20, view.shape[0] - 30), cv2.FONT_HERSHEY_SIMPLEX, 1.0, CYAN, 2, cv2.LINE_AA)
    write_png(out, view)


def pick_plots(result: Any, folder: Path) -> list[str]:
    """Axis setpoints (thin) and actual positions (thick) over the pick, one panel per axis (PNG)."""
    if not result.log:
        return []
    names = list(result.log[0]["actual"])
    t0 = result.log[0]["t"]
    t = np.array([row["t"] - t0 for row in result.log])
    width, panel = 1200, 260
    canvas = np.full((panel * len(names), width, 3), 255, np.uint8)
    for k, name in enumerate(names):
        actual = np.array([row["actual"][name] for row in result.log])
        setpoint = np.array([row["setpoint"].get(name, np.nan) for row in result.log])
        scale = 1e3 if name != "tilt" else np.degrees(1.0)
        unit = "mm" if name != "tilt" else "deg"
        values = np.concatenate([actual, setpoint[np.isfinite(setpoint)]]) * scale
        low, high = float(values.min()), float(values.max())
        span = max(high - low, 1e-6)
        top = k * panel

        def to_px(
            times: NDArray, v: NDArray, top: int = top, low: float = low, span: float = span, scale: float = scale
        ) -> NDArray:
            u = 60 + (times / max(t[-1], 1e-6)) * (width - 80)
            w = top + panel - 30 - (v * scale - low) / span * (panel - 60)
            return np.stack([u, w], 1).astype(np.int32)

        ok = np.isfinite(setpoint)
        cv2.polylines(canvas, [to_px(t[ok], setpoint[ok])], False, (200, 120, 0), 1, cv2.LINE_AA)
        cv2.polylines(canvas, [to_px(t, actual)], False, (30, 30, 200), 2, cv2.LINE_AA)
        cv2.putText(
            canvas,
            f"{name} [{unit}]  {low:.1f} .. {high:.1f}   (blue setpoint, red actual)",
            (60, top + 22),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.55,
            (0, 0, 0),
            1,
            cv2.LINE_AA,
        )
    cv2.putText(
        canvas,
        f"time 0 .. {t[-1]:.1f} s of motion",
        (60, canvas.shape[0] - 8),
        cv2.FONT_HERSHEY_SIMPLEX,
        0.5,
        (0, 0, 0),
        1,
        cv2.LINE_AA,
    )
    path = folder / "pick_axes.png"
    write_png(path, canvas)
    return [str(path)]


def fork_path_side_view(outlines: NDArray, clearances: NDArray, pallet: PalletType, path: Path) -> str:
    """Side view of the fork path through the pocket, with clearances (PNG).

    Parameters
    ----------
    outlines : (T, 4, 3) array
        Per control cycle, the left tine's side outline in the pallet frame P (m): tip top, tip bottom,
        heel bottom, heel top.
    clearances : (T,) array
        The smallest tine-to-pallet clearance of each cycle (m); negative is a collision.
    pallet : PalletType
        Gives the deck and bottom band drawn in grey.
    path : Path
        The PNG to write.

    The height axis is stretched (the factor is printed) so that millimetres of clearance show against
    a metre of fork travel.
    """
    outlines, clearances = np.asarray(outlines, float), np.asarray(clearances, float)
    if outlines.ndim != 3 or outlines.shape[1:] != (4, 3) or clearances.shape != outlines.shape[:1]:
        raise ValueError(f"expected outlines (T, 4, 3) and clearances (T,), got {outlines.shape}, {clearances.shape}")
    width, height, pad = 1400, 560, 60
    x_low, x_high = min(outlines[..., 0].min(), 0.0) - 0.05, max(outlines[..., 0].max(), pallet.length) + 0.05
    z_low = min(outlines[..., 2].min(), pallet.deck_bottom) - 0.03
    z_high = max(outlines[..., 2].max(), pallet.deck_top) + 0.03
    sx = (width - 2 * pad) / (x_high - x_low)
    sz = min((height - 2 * pad) / (z_high - z_low), 8 * sx)

    def to_px(x: NDArray, z: NDArray) -> NDArray[np.int32]:
        return np.stack([pad + (x - x_low) * sx, height - pad - (z - z_low) * sz], -1).round().astype(np.int32)

    canvas = np.full((height, width, 3), 255, np.uint8)
    half = pallet.pocket_height / 2
    solids = [(half, pallet.deck_top)] + ([(pallet.deck_bottom, -half)] if pallet.bottom > 0 else [])
    for z0, z1 in solids:
        corners = to_px(np.array([0.0, pallet.length]), np.array([z0, z1]))
        cv2.rectangle(canvas, tuple(corners[0].tolist()), tuple(corners[1].tolist()), (170, 170, 170), -1)
    for k in np.unique(np.linspace(0, len(outlines) - 1, 9).round().astype(int)):
        cv2.polylines(canvas, [to_px(outlines[k, :, 0], outlines[k, :, 2])], True, (220, 180, 120), 1, cv2.LINE_AA)
    tip = outlines[:, :2].mean(axis=1)
    near = np.where(clearances[:, None] < 0.01, (0, 140, 255), (0, 160, 0))
    colours = np.where(clearances[:, None] < 0, (0, 0, 220), near)
    points = to_px(tip[:, 0], tip[:, 2])
    for a, b, colour in zip(points[:-1], points[1:], colours[1:], strict=True):
        cv2.line(canvas, tuple(a.tolist()), tuple(b.tolist()), tuple(int(c) for c in colour), 2, cv2.LINE_AA)
    worst = int(np.argmin(clearances))
    cv2.circle(canvas, tuple(points[worst].tolist()), 7, (0, 0, 0), 1, cv2.LINE_AA)
    lines = [
        f"fork tip path in the pallet frame; min clearance {clearances[worst] * 1e3:.1f} mm at tip x "
        f"{tip[worst, 0] * 1e3:.0f} mm (circle)",
        f"grey: deck and bottom band; blue: left tine at 9 instants; path green > 10 mm, orange 0-10 mm, red contact; "
        f"height x{sz / sx:.1f}",
    ]
    for i, text in enumerate(lines):
        cv2.putText(canvas, text, (pad, 22 + 20 * i), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    write_png(path, canvas)
    return str(path)
