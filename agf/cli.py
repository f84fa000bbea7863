"""The ``agf`` command: ``run | measure | calibrate | render | simulate | report | replay | serve | bench``.

Every sub-command takes ``--config`` and ``--json``. With ``--json`` it prints exactly one JSON
object on stdout; on failure that object is ``{"ok": false, "error": "..."}``. Exit codes:

* 0: success
* 1: the job ran and ended in a stated failure (measurement refused, pick aborted, fault)
* 2: a user error (bad configuration, missing or unusable input, bad arguments)
* 3: the capability is not available (not built yet, or hardware absent)
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from agf.config import Config, load_config
from agf.errors import AgfError, ConfigError, InputError, NotAvailableError
from agf.heap import keep_freed_memory
from agf.pallets import load_pallets
from agf.paths import DEFAULT_CONFIG
from agf.plugins import load_object

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_UNAVAILABLE = 0, 1, 2, 3


class _Parser(argparse.ArgumentParser):
    """argparse that raises instead of exiting, so ``--json`` users get JSON for bad arguments."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise InputError(f"{self.prog}: {message}")


def _existing_file(text: str) -> Path:
    path = Path(text)
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    return path


def _plugin(config: Config, role: str) -> Any:
    spec = config.plugins.get(role)
    if spec is None:
        raise NotAvailableError(f"{config.source}: plugins.{role} is not set, so this command has no {role} to use")
    return load_object(spec, key=f"{config.source}: plugins.{role}")


def _cmd_measure(args: argparse.Namespace, config: Config) -> dict[str, Any]:
    image = _existing_file(args.image)
    measure_command = _capability("agf.commands.measure:measure_command", "pallet measurement (issue 9)")
    return measure_command(
        config,
        image,
        camera=args.camera,
        calibration=args.calibration,
        pallet_type=args.pallet_type,
        prior_json=args.prior_json,
        overlay=args.overlay,
    )


def _cmd_calibrate(args: argparse.Namespace, config: Config) -> dict[str, Any]:
    images = [_existing_file(p) for p in args.images]
    width_mm, height_mm = args.panel
    if width_mm <= 0 or height_mm <= 0:
        raise InputError(f"--panel: width and height must be positive millimetres, got {args.panel}")
    calibrate_command = _capability("agf.commands.calibrate:calibrate_command", "camera-to-fork calibration (issue 6)")
    return calibrate_command(
        config, images, panel_mm=(width_mm, height_mm), camera=args.camera, out=args.out, force=args.force
    )


def _cmd_render(args: argparse.Namespace, config: Config) -> dict[str, Any]:
    scene = _existing_file(args.scene)
    return _plugin(config, "renderer")(
        scene, Path(args.out), Path(args.truth), randomize=args.randomize, reference=args.reference
    )


def _cmd_simulate(args: argparse.Namespace, config: Config) -> dict[str, Any]:
    if args.scene is None and args.random is None:
        raise InputError("agf simulate: give --scene SCENE.yaml or --random N [--seed S]")
    if args.random is not None and args.random <= 0:
        raise InputError(f"--random: expected a positive number of runs, got {args.random}")
    scene = _existing_file(args.scene) if args.scene else None
    if args.jobs is not None and args.jobs <= 0:
        raise InputError(f"--jobs: expected a positive number of picks side by side, got {args.jobs}")
    if args.resume and args.out is None:
        raise InputError("--resume: give --out CAMPAIGN_DIR, the folder of the campaign to finish")
    if args.only is not None and (args.random is None or not 0 <= args.only < args.random):
        raise InputError(f"--only: expected a pick number 0..N-1 of --random N, got {args.only}")
    types = _pallet_types(args.pallet_types, config) if args.pallet_types is not None else ()
    if types and args.random is None:
        raise InputError("--pallet-types: the pallets random picks are drawn from; give --random N too")
    folder = None if args.out else _campaign_folder(args)
    try:
        return _plugin(config, "simulate")(
            config,
            scene=scene,
            runs=args.random,
            seed=args.seed,
            plots=args.plots,
            jobs=args.jobs,
            backend=args.backend,
            address=args.address,
            out=args.out or str(folder),
            resume=args.resume,
            indices=None if args.only is None else [args.only],
            progress=not args.json,
            **({"pallet_types": types} if types else {}),
        )
    except BaseException:
        if folder is not None and not any(folder.iterdir()):
            folder.rmdir()  # a campaign that never started (no Ray, a bad config) leaves no folder behind
        raise


def _pallet_types(text: str, config: Config) -> tuple[str, ...]:
    """``--pallet-types A,B,...``: catalogue names, each once, or InputError naming what is not in the catalogue."""
    names = tuple(dict.fromkeys(name.strip() for name in text.split(",") if name.strip()))
    known = load_pallets(config.vision.pallets)
    unknown = [name for name in names if name not in known]
    if not names or unknown:
        raise InputError(f"--pallet-types: expected names from the pallet catalogue {config.vision.pallets} "
                         f"({', '.join(sorted(known))}), separated by commas; got {text!r}"
                         + (f" ({', '.join(unknown)} not in it)" if unknown else ""))
    return names


def _campaign_folder(args: argparse.Namespace) -> Path:
    """``campaigns/<UTC time>-random-N-seed-S`` (or ``-scene-NAME``): a new folder for every campaign, made
    here, so that a campaign started in the same second as another (two terminals, a script) gets one of its
    own (``...-2``); the two shared one folder and its results file."""
    stamp = datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
    what = f"random-{args.random}-seed-{args.seed}" if args.random else f"scene-{Path(args.scene).stem}"
    name = f"{stamp}-{what}"
    Path("campaigns").mkdir(exist_ok=True)
    folder, n = Path("campaigns") / name, 1
    while True:
        try:
            folder.mkdir()
            return folder
        except FileExistsError:
            n += 1
            folder = Path("campaigns") / f"{name}-{n}"


def _cmd_report(args: argparse.Namespace, config: Config) -> dict[str, Any]:
    from agf.report import write_report

    return {**write_report(Path(args.campaign)), "ok": True}


def _cmd_run(args: argparse.Namespace, config: Config) -> dict[str, Any]:
    return _plugin(config, "run")(config, plots=args.plots, progress=not args.json)


def _cmd_replay(args: argparse.Namespace, config: Config) -> dict[str, Any]:
    from agf.replay import replay_command

    return replay_command(config, _existing_file(args.log), plots=args.plots)


def _cmd_serve(args: argparse.Namespace, config: Config) -> dict[str, Any]:
    from agf.fleet.service import fleet_settings, serve_command

    fleet_settings(config.fleet, args.broker, args.manufacturer, args.serial)  # bad flags before any plugin starts
    truck = _plugin(config, "fleet_truck")(config)
    return serve_command(
        config, _plugin(config, "fleet"), truck, broker=args.broker, manufacturer=args.manufacturer, serial=args.serial
    )


def _cmd_bench(args: argparse.Namespace, config: Config) -> dict[str, Any]:
    from agf.bench import run_bench

    return run_bench(config.bench.modules, quick=args.quick, only=args.only)


def _capability(spec: str, what: str) -> Callable[..., dict[str, Any]]:
    """Import a command implementation that lives in ``agf``; say plainly if it is not built yet."""
    module_name, _, attr = spec.partition(":")
    try:
        module = __import__(module_name, fromlist=[attr])
        return getattr(module, attr)
    except (ImportError, AttributeError) as exc:
        raise NotAvailableError(f"{what} is not available in this build ({exc})") from exc


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``agf`` command (also used to document the CLI)."""
    common = _Parser(add_help=False)
    common.add_argument("--config", default=str(DEFAULT_CONFIG), help="configuration file (default: %(default)s)")
    common.add_argument("--json", action="store_true", help="print one JSON object instead of a summary")

    parser = _Parser(prog="agf", description="Fork-insertion controller for an autonomous reach truck.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    p = sub.add_parser("run", parents=[common], help="one pick with the hardware the config names")
    p.add_argument("--plots", metavar="DIR", help="write trajectory and side-view plots (PNG) here")
    p.set_defaults(handler=_cmd_run)

    p = sub.add_parser("measure", parents=[common], help="measure the pallet in one fisheye image")
    p.add_argument("image", help="fisheye image file")
    p.add_argument("--camera", help="camera model file (overrides the config)")
    p.add_argument("--calibration", help="camera_in_fork calibration YAML (overrides the config)")
    p.add_argument("--pallet-type", help="pallet type from the catalogue (overrides the config)")
    p.add_argument("--prior-json", help="JSON with a prior pallet_in_fork pose")
    p.add_argument("--overlay", help="write an overlay PNG here")
    p.set_defaults(handler=_cmd_measure)

    p = sub.add_parser("calibrate", parents=[common], help="camera-to-fork calibration from panel images")
    p.add_argument("images", nargs="+", help="fisheye image(s) of the panel lying on the forks")
    p.add_argument("--panel", nargs=2, type=float, metavar=("W_MM", "H_MM"), required=True, help="panel size, mm")
    p.add_argument("--camera", help="camera model file (overrides the config)")
    p.add_argument("--out", help="calibration YAML to write (default: the one the config names)")
    p.add_argument("--force", action="store_true", help="overwrite an existing calibration file")
    p.set_defaults(handler=_cmd_calibrate)

    p = sub.add_parser("render", parents=[common], help="render a scene file to a fisheye image")
    p.add_argument("scene", help="scene YAML")
    p.add_argument("--out", required=True, help="output PNG")
    p.add_argument("--truth", required=True, help="output ground-truth JSON")
    p.add_argument(
        "--randomize", action="store_true", help="a random look drawn from the scene's seed (as 'look: random')"
    )
    p.add_argument(
        "--reference", action="store_true", help="the reference renderer (4 rays per pixel everywhere; slow)"
    )
    p.set_defaults(handler=_cmd_render)

    p = sub.add_parser("simulate", parents=[common], help="whole picks in the simulated world over CAN")
    p.add_argument("--scene", help="scene YAML")
    p.add_argument("--random", type=int, metavar="N", help="number of random scenes")
    p.add_argument("--seed", type=int, default=1, help="seed of the random scenes (default: %(default)s)")
    p.add_argument("--plots", metavar="DIR", help="write plots (PNG) here")
    p.add_argument("--jobs", type=int, metavar="J", help="picks run side by side (default: one per core or Ray CPU)")
    p.add_argument("--backend", choices=("pool", "ray"), default="pool", help="where picks run (default: %(default)s)")
    p.add_argument("--address", metavar="ADDR", help="Ray cluster to join (auto, HOST:PORT, ray://HOST:10001)")
    p.add_argument("--out", metavar="CAMPAIGN_DIR", help="campaign folder (default: a new one under campaigns/)")
    p.add_argument("--resume", action="store_true", help="finish the campaign in --out: run only missing picks")
    p.add_argument("--only", type=int, metavar="K",
                   help="run only pick K (0-based) of --random N --seed S, exactly as in the whole campaign")
    p.add_argument("--pallet-types", metavar="TYPE[,TYPE...]",
                   help="draw each random pick's pallet from these catalogue types (default: the scene's, jis-t11)")
    p.set_defaults(handler=_cmd_simulate)

    p = sub.add_parser("replay", parents=[common], help="re-run the measurement on a pick's logged frames")
    p.add_argument("log", help="the pick's MCAP log (see docs/recorder.md)")
    p.add_argument("--plots", metavar="DIR", help="draw the pick from the log alone (PNG) here")
    p.set_defaults(handler=_cmd_replay)

    p = sub.add_parser("serve", parents=[common], help="a VDA 5050 2.1 vehicle on an MQTT broker (docs/fleet.md)")
    p.add_argument("--broker", metavar="URL", help="mqtt://HOST:PORT or mqtts://HOST:PORT (overrides fleet.broker)")
    p.add_argument("--manufacturer", help="VDA 5050 manufacturer, a topic level (overrides fleet.manufacturer)")
    p.add_argument("--serial", help="VDA 5050 serial number, a topic level (overrides fleet.serial_number)")
    p.set_defaults(handler=_cmd_serve)

    p = sub.add_parser("report", parents=[common], help="Markdown report with plots of a simulation campaign")
    p.add_argument("campaign", metavar="CAMPAIGN_DIR", help="folder written by agf simulate (--out)")
    p.set_defaults(handler=_cmd_report)

    p = sub.add_parser("bench", parents=[common], help="speed and accuracy figures")
    p.add_argument("--quick", action="store_true", help="reduced set, fast enough for CI")
    p.add_argument("--only", metavar="PREFIX", help="run only the cases whose name starts with PREFIX")
    p.set_defaults(handler=_cmd_bench)
    return parser


def _summary(result: dict[str, Any], indent: int = 0) -> str:
    lines = []
    for key, value in result.items():
        if isinstance(value, dict):
            lines.append(" " * indent + f"{key}:")
            lines.append(_summary(value, indent + 2))
        elif isinstance(value, list) and value and all(isinstance(item, dict) for item in value):
            lines.append(" " * indent + f"{key}:")
            lines.extend(" " * (indent + 2) + "-\n" + _summary(item, indent + 4) for item in value)
        elif isinstance(value, float):
            lines.append(" " * indent + f"{key}: {value:.4g}")
        else:
            lines.append(" " * indent + f"{key}: {value}")
    return "\n".join(line for line in lines if line)


def _emit(result: dict[str, Any], as_json: bool, stream: Any) -> None:
    if as_json:
        print(json.dumps(result, allow_nan=False), file=stream)
    else:
        print(_summary(result), file=stream)


def _exit_code(exc: AgfError) -> int:
    if isinstance(exc, ConfigError | InputError):
        return EXIT_USAGE
    if isinstance(exc, NotAvailableError):
        return EXIT_UNAVAILABLE
    return EXIT_FAILED


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``agf`` console script; returns the exit code."""
    keep_freed_memory()
    argv = list(sys.argv[1:] if argv is None else argv)
    as_json = "--json" in argv
    parser = build_parser()
    if not argv or argv[0] in ("-h", "--help"):
        parser.print_help()
        return EXIT_OK
    try:
        args = parser.parse_args(argv)
        config = load_config(args.config)
        result = args.handler(args, config)
    except AgfError as exc:
        if as_json:
            _emit({"ok": False, "error": str(exc)}, True, sys.stdout)
        else:
            print(f"agf: error: {exc}", file=sys.stderr)
        return _exit_code(exc)
    except KeyboardInterrupt:
        if as_json:
            _emit({"ok": False, "error": "interrupted by the operator"}, True, sys.stdout)
        else:
            print("agf: interrupted by the operator", file=sys.stderr)
        return EXIT_FAILED
    _emit(result, as_json, sys.stdout)
    return EXIT_OK if result.get("ok", True) else EXIT_FAILED


if __name__ == "__main__":
    raise SystemExit(main())
