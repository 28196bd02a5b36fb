"""Issue 34 item 5: report.html shows the full-size and window checks that report.json
carries (``full_size``, ``binned.unbinned_stage``): χ²/dof, σ, value count, verdict."""

from __future__ import annotations

from typing import Any

import pytest

from thintact_sdk.diagnosis.imaging.html import check_rows, checks_html, render_html


def _binned_report() -> dict[str, Any]:
    return {
        "binned": {"factor": 8, "unbinned_stage": {"before": {"rms_dn": 12.5, "chi2_per_dof": 1.0031},
                                                   "excess_z": 8.7, "ran": True}},
        "full_size": {"final": {"rms_dn": 12.4, "chi2_per_dof": 1.0002},
                      "before_unbinned_stage": {"rms_dn": 12.5, "chi2_per_dof": 1.0031}},
    }


def _window_report() -> dict[str, Any]:
    return {"full_size": {
        "not_evaluated": "the rotated kernel needs 48 windows (6.6 GiB)",
        "windows": {"rms_dn": 12.1, "chi2_per_dof": 1.0124, "excess_z": 12.3, "n_values": 1966080,
                    "where": "6 of 48 windows of the unbinned sensor"}}}


def test_whole_sensor_checks_give_sigma_and_verdict() -> None:
    rows = check_rows(_binned_report(), n_unbinned_values=12 * 1024 * 1280 * 3)
    assert [r["check"].split(",")[1].strip() for r in rows] == [
        "binned model (before the unbinned stage)", "final model"]
    before, final = rows
    assert before["z"] == pytest.approx(8.7) and before["verdict"].startswith("in excess")
    n = 12 * 1024 * 1280 * 3
    assert final["z"] == pytest.approx(0.0002 * (n / 2) ** 0.5)
    assert final["z_approx"] and final["verdict"].startswith("consistent with the noise")


def test_without_a_value_count_the_final_check_has_no_sigma() -> None:
    rows = check_rows(_binned_report())
    assert rows[1]["z"] is None and "no σ" in rows[1]["verdict"]


def test_windows_and_the_reason_the_sensor_was_not_evaluated() -> None:
    rows = check_rows(_window_report())
    assert rows[0]["verdict"].startswith("not evaluated: the rotated kernel")
    win = rows[1]
    assert win["values"] == 1966080 and win["z"] == pytest.approx(12.3)
    assert win["verdict"].startswith("in excess")
    page = checks_html(_window_report())
    assert "Full-size and window checks" in page
    for text in ("1.0124", "+12.3", "1,966,080", "6 of 48 windows", "not evaluated: the rotated kernel"):
        assert text in page


def test_window_check_not_evaluated_either() -> None:
    rep = {"full_size": {"not_evaluated": "too large", "windows": {"not_evaluated": "no window fits"}}}
    verdicts = [r["verdict"] for r in check_rows(rep)]
    assert verdicts == ["not evaluated: too large", "not evaluated: no window fits"]


def test_no_checks_no_section() -> None:
    assert checks_html({}) == ""


def test_the_page_carries_the_section() -> None:
    """The whole report.html of a (toy) diagnosis with window checks in its report."""
    from tests.diagnose.test_diagnose_toy import OPTS, _data, toy_simulate, toy_variance
    from thintact_sdk.diagnosis.imaging.engine import diagnose

    d = diagnose(_data({}), toy_simulate, toy_variance, OPTS)
    assert "Full-size and window checks" not in render_html(d)
    d.report.update(_window_report())
    page = render_html(d)
    assert "Full-size and window checks" in page and "1.0124" in page and "in excess" in page
