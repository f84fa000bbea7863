"""Overlays and plots (PNG) for people: what the vision saw and what the controller did.

Drawing only; nothing here decides anything. Image overlays are drawn with OpenCV on BGR uint8
frames; plots (axes over time, the fork path) are matplotlib figures, drawn without pyplot so they
need no display and no global state.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from numpy.typing import NDArray

from agf.camera.base import CameraModel
from agf.errors import InputError
from agf.geometry import Transform
from agf.pallets import PalletType
from agf.vision.face_model import face_model_from_pallet
from agf.vision.panorama import render_panorama

GREEN, RED, YELLOW, CYAN = (60, 200, 60), (40, 40, 230), (0, 215, 255), (230, 200, 0)
PATH_COLOURS = ("#00a000", "#ff8c00", "#dc0000")  # matplotlib RGB: clear, within 10 mm, contact


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


def _save_figure(figure: Figure, path: Path) -> str:
    if path.suffix.lower() != ".png":
        raise InputError(f"{path}: expected a file name ending in .png")
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=100)
    return str(path)


def _shade_states(ax: Any, t: NDArray, states: list[str]) -> None:
    """Alternating background bands per controller state, labelled at the top of the panel; a pause
    without samples between motions (the verify measurement) is its own band, ``no motion``."""
    pause = np.diff(t) > max(10 * float(np.median(np.diff(t))), 0.2) if len(t) > 1 else np.zeros(0, bool)
    bands, a = [], 0
    for i in range(1, len(t)):
        if pause[i - 1]:
            bands += [(t[a], t[i - 1], states[a]), (t[i - 1], t[i], "no motion")]
            a = i
        elif states[i] != states[a]:
            bands.append((t[a], t[i], states[a]))
            a = i
    bands.append((t[a], t[-1], states[a]))
    for k, (start, end, label) in enumerate(bands):
        colour = "white" if label == "no motion" else "0.90" if k % 2 == 0 else "0.96"
        ax.axvspan(start, end, color=colour, zorder=0)
        ax.annotate(
            label,
            ((start + end) / 2, 1.0),
            xycoords=("data", "axes fraction"),
            ha="center",
            va="bottom",
            fontsize="small",
            color="0.35",
        )


def pick_plots(result: Any, folder: Path) -> list[str]:
    """Axis setpoints (dashed, on top) and actual positions (solid) over the pick's motions, one panel per
    axis, with the controller state in the background (``pick_axes.png`` in ``folder``)."""
    if not result.log:
        return []
    names = list(result.log[0]["actual"])
    t0 = result.log[0]["t"]
    t = np.array([row["t"] - t0 for row in result.log])
    figure = Figure(figsize=(12, 2.6 * len(names) + 0.6), layout="constrained")
    axes = figure.subplots(len(names), 1, sharex=True, squeeze=False)[:, 0]
    for ax, name in zip(axes, names, strict=True):
        scale, unit = (np.degrees(1.0), "deg") if name == "tilt" else (1e3, "mm")
        actual = np.array([row["actual"][name] for row in result.log]) * scale
        setpoint = np.array([row["setpoint"].get(name, np.nan) for row in result.log]) * scale
        _shade_states(ax, t, [row["state"] for row in result.log])
        ax.plot(t, actual, color="tab:red", linewidth=2.2, label="actual", zorder=2)
        ax.plot(t, setpoint, color="tab:blue", linewidth=1.2, linestyle="--", label="setpoint", zorder=3)
        ax.set_ylabel(f"{name} [{unit}]")
        ax.grid(True, alpha=0.5)
        ax.legend(loc="best", fontsize="small")
    axes[-1].set_xlabel("time from the first motion [s]")
    path = folder / "pick_axes.png"
    return [_save_figure(figure, path)]


def fork_path_side_view(outlines: NDArray, clearances: NDArray, pallet: PalletType, path: Path) -> str:
    """Side view of the fork path through the pocket, and the clearance along it (PNG).

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

    The height axis is stretched against the length axis (both in mm) so that millimetres of
    clearance show against a metre of fork travel. The tip's path is green with more than 10 mm of
    clearance, orange below, red at contact.
    """
    outlines, clearances = np.asarray(outlines, float), np.asarray(clearances, float)
    if outlines.ndim != 3 or outlines.shape[1:] != (4, 3) or clearances.shape != outlines.shape[:1]:
        raise ValueError(f"expected outlines (T, 4, 3) and clearances (T,), got {outlines.shape}, {clearances.shape}")
    mm = 1e3
    figure = Figure(figsize=(14, 7), layout="constrained")
    side, along = figure.subplots(2, 1, sharex=True, height_ratios=(2, 1))
    half = pallet.pocket_height / 2
    solids = [(half, pallet.deck_top)] + ([(pallet.deck_bottom, -half)] if pallet.bottom > 0 else [])
    for k, (z0, z1) in enumerate(solids):
        side.add_patch(
            Rectangle(
                (0, z0 * mm),
                pallet.length * mm,
                (z1 - z0) * mm,
                color="0.7",
                label="deck and bottom band" if k == 0 else None,
            )
        )
    for n, k in enumerate(np.unique(np.linspace(0, len(outlines) - 1, 9).round().astype(int))):
        closed = np.vstack([outlines[k], outlines[k, :1]]) * mm
        side.plot(
            closed[:, 0],
            closed[:, 2],
            color="tab:blue",
            linewidth=0.8,
            alpha=0.6,
            label="left tine at 9 instants" if n == 0 else None,
        )
    tip = outlines[:, :2].mean(axis=1) * mm
    classes = np.where(clearances < 0, 2, np.where(clearances < 0.01, 1, 0))
    labels = ("clearance > 10 mm", "clearance 0-10 mm", "contact")
    segments = np.stack([tip[:-1][:, [0, 2]], tip[1:][:, [0, 2]]], axis=1)
    side.add_collection(LineCollection(segments, colors=[PATH_COLOURS[c] for c in classes[1:]], linewidths=2.5))
    for c in np.unique(classes[1:]):
        side.plot([], [], color=PATH_COLOURS[c], linewidth=2.5, label=f"tip path, {labels[c]}")
    worst = int(np.argmin(clearances))
    side.plot(
        tip[worst, 0],
        tip[worst, 2],
        "o",
        markersize=12,
        markerfacecolor="none",
        color="black",
        label=f"least clearance {clearances[worst] * mm:.1f} mm",
    )
    side.set_ylabel("height in the pallet frame [mm]")
    side.set_title("fork tip path in the pallet frame (side view; height axis stretched)")
    side.grid(True, alpha=0.5)
    side.legend(loc="upper left", fontsize="small")
    side.autoscale_view()
    along.plot(tip[:, 0], clearances * mm, color="black", linewidth=1.2)
    along.axhline(10.0, color="tab:orange", linestyle=":", linewidth=1.0)
    along.axhline(0.0, color="black", linewidth=0.8)
    along.set_xlabel("fork tip x in the pallet frame [mm] (0: the pallet's front face)")
    along.set_ylabel("clearance [mm]")
    along.grid(True, alpha=0.5)
    return _save_figure(figure, path)
