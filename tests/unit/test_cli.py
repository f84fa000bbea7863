import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from agf.bench import bench_case, run_bench, timing_summary
from agf.cli import EXIT_USAGE, main
from agf.paths import REPO_ROOT


def run_json(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1, f"--json must print exactly one line, got {out}"
    return code, json.loads(out[0])


def test_help_lists_every_subcommand(capsys):
    assert main(["--help"]) == 0
    text = capsys.readouterr().out
    for command in ("run", "measure", "calibrate", "render", "simulate", "bench"):
        assert command in text


def test_console_script_runs_as_a_process():
    result = subprocess.run(
        [sys.executable, "-m", "agf.cli", "--help"], capture_output=True, text=True, check=False
    )
    assert result.returncode == 0
    assert "measure" in result.stdout


def test_measure_missing_image_is_a_json_error(capsys):
    code, payload = run_json(capsys, "measure", "missing.png", "--json")
    assert code == EXIT_USAGE
    assert payload["ok"] is False
    assert "missing.png" in payload["error"] and "not found" in payload["error"]


def test_broken_config_error_names_the_key(capsys, tmp_path):
    configs = tmp_path / "configs"
    shutil.copytree(REPO_ROOT / "configs", configs)
    text = (configs / "agf.yaml").read_text().replace("length_mm: 1070", "length_mm: long")
    (configs / "agf.yaml").write_text(text)
    code, payload = run_json(capsys, "bench", "--config", str(configs / "agf.yaml"), "--json")
    assert code == EXIT_USAGE
    assert "forks.length_mm" in payload["error"] and "expected a finite number" in payload["error"]


def test_bad_arguments_give_json_not_usage_text(capsys):
    code, payload = run_json(capsys, "simulate", "--random", "many", "--json")
    assert code == EXIT_USAGE
    assert "--random" in payload["error"]


def test_human_error_goes_to_stderr_without_traceback(capsys):
    code = main(["measure", "missing.png"])
    captured = capsys.readouterr()
    assert code == EXIT_USAGE
    assert "agf: error:" in captured.err and "Traceback" not in captured.err


def test_bench_reports_a_failing_case_as_error_not_number():
    @bench_case("test.always_fails", "accuracy")
    def _fails(quick: bool) -> dict:
        raise RuntimeError("measurement untrustworthy: no detections")

    report = run_bench([], quick=True, only="test.")
    assert report["accuracy"]["test.always_fails"] == {
        "error": "RuntimeError: measurement untrustworthy: no detections"
    }


def test_timing_summary_orders_samples():
    summary = timing_summary([0.003, 0.001, 0.002])
    assert summary["median"] == pytest.approx(2.0)
    assert summary["min"] == pytest.approx(1.0) and summary["max"] == pytest.approx(3.0)
    with pytest.raises(ValueError):
        timing_summary([])


@pytest.mark.parametrize("argv", [["--random", "30", "--only", "30"], ["--random", "30", "--only", "-1"],
                                  ["--scene", "configs/scenes/pick.yaml", "--only", "0"]])
def test_simulate_only_names_a_pick_of_the_random_ones(capsys, argv):
    code, payload = run_json(capsys, "simulate", *argv, "--json")
    assert code == EXIT_USAGE
    assert "--only: expected a pick number 0..N-1 of --random N" in payload["error"]


@pytest.mark.parametrize("argv, named", [(["--random", "3", "--pallet-types", "epal,euro-2"], "euro-2 not in it"),
                                         (["--random", "3", "--pallet-types", ","], "got ','"),
                                         (["--scene", "configs/scenes/pick.yaml", "--pallet-types", "epal"],
                                          "give --random N too")])
def test_simulate_pallet_types_must_name_catalogue_pallets_of_random_picks(capsys, argv, named):
    code, payload = run_json(capsys, "simulate", *argv, "--json")
    assert code == EXIT_USAGE
    assert "--pallet-types" in payload["error"] and named in payload["error"], payload["error"]


def test_simulate_refuses_a_non_positive_job_count(capsys):
    code, payload = run_json(capsys, "simulate", "--random", "2", "--jobs", "0", "--json")
    assert code == EXIT_USAGE
    assert "--jobs" in payload["error"]


def test_overlay_name_without_png_suffix_is_an_input_error_not_a_traceback(tmp_path):
    from agf.errors import InputError
    from agf.viz import write_png

    with pytest.raises(InputError, match=r"overlay.*\.png"):
        write_png(tmp_path / "overlay", np.zeros((4, 4, 3), np.uint8))
    write_png(tmp_path / "overlay.png", np.zeros((4, 4, 3), np.uint8))
    assert (tmp_path / "overlay.png").is_file()
