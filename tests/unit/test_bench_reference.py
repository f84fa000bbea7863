"""``machine.reference_ms`` and the timings in its units, so that figures from two machines compare."""

import cv2
import pytest
from threadpoolctl import threadpool_info

from agf.bench import bench_case, in_reference_units, run_bench


@pytest.mark.parametrize(
    ("name", "figures", "expected"),
    [
        ("pose.ms", {"median": 90.0, "p90": 120.0, "n": 10}, {"median": 2.0, "p90": 120.0 / 45.0}),
        ("render.frame_s", {"median": 0.45}, {"median": 10.0}),
        ("control.setpoint_latency_us", {"p50": 4500.0, "p99": 9000.0}, {"p50": 0.1, "p99": 0.2}),
    ],
)
def test_statistics_are_divided_by_the_reference_in_the_units_of_the_name(name, figures, expected):
    assert in_reference_units(name, figures, 45.0) == pytest.approx(expected)


def test_nested_timings_take_the_unit_of_their_key_and_other_figures_are_left_out():
    figures = {"scenes": 33, "median": {"x_mm": 2.5}, "timing_ms_median": {"pose": 90.0, "total": 135.0}}
    assert in_reference_units("measure", figures, 45.0) == {"timing_ms_median": {"pose": 2.0, "total": 3.0}}


def test_bench_report_has_the_machine_reference_and_each_timing_in_its_units():
    @bench_case("zz_reference_test.ms", "vision_ms")
    def _case(quick):
        return {"median": 10.0, "p90": 12.0}

    report = run_bench([], quick=True, only="zz_reference_test")
    machine = report["machine"]
    assert machine["reference_ms"] > 0 and machine["reference_ms_after"] > 0
    figures = report["vision_ms"]["zz_reference_test.ms"]
    assert figures["x_reference"]["median"] == pytest.approx(10.0 / machine["reference_ms"])


def test_bench_report_names_the_code_paths_the_cpu_chose_for_opencv_s_ipp_and_openblas():
    """They change last bits, and so a few picks (docs/campaigns.md): a report says which it ran."""
    report = run_bench([], quick=True, only="zz_no_case")
    paths = report["machine"]["code_paths"]
    assert paths["opencv"] == cv2.__version__
    assert paths["opencv_ipp"] == (cv2.ipp.getIppVersion() if cv2.ipp.useIPP() else "off")
    kernels = {i["architecture"] for i in threadpool_info() if i.get("internal_api") == "openblas"}
    assert kernels and set(paths["openblas"].values()) == kernels
    assert set(paths["environment"]) == {"OPENCV_IPP", "OPENBLAS_CORETYPE"}
