"""``thintact doctor``: host capabilities and the backend a profile's decoder chooses here."""

from __future__ import annotations

import json

from thintact_sdk.apps.cli.main import main


def test_doctor_reports_host_and_chosen_backend(capsys) -> None:
    assert main(["doctor", "--profile", "virtual-mini", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["host"]["simd"] and out["host"]["blas"] and out["sgemm_gflops"] > 0
    backend = out["backend"]
    assert backend["chosen"] in backend["measured_ms"] and "numpy-float32" in backend["measured_ms"]
    if not out["host"]["native_bf16"]:
        assert "torch-bfloat16" in backend["not_candidates"] and "torch-bfloat16" not in backend["measured_ms"]
    assert main(["doctor", "--profile", "virtual-mini"]) == 0
    text = capsys.readouterr().out
    assert "SIMD:" in text and "BLAS (numpy):" in text and "backend: " in text and "cached" in text


def test_doctor_remeasures_and_explains_a_missing_bundle(capsys) -> None:
    assert main(["doctor", "--profile", "virtual-mini", "--remeasure", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["backend"]["from_cache"] is False
    assert main(["doctor", "--profile", "virtual-mini", "--json"]) == 0  # the new record is cached
    assert json.loads(capsys.readouterr().out)["backend"]["from_cache"] is True
    assert main(["doctor", "--profile", "no-such-profile"]) == 2
    assert "no-such-profile" in capsys.readouterr().err


def test_the_library_report_is_the_commands(capsys) -> None:
    """``host_report`` gives what ``thintact doctor --json`` prints, the GEMM rate (measured
    anew each time) aside."""
    from thintact_sdk.apps.benchmarks.host_report import host_report
    from thintact_sdk.formats.profiles import load_profile

    host_report(load_profile("virtual-mini"))  # this host's backend record cached for both below
    assert main(["doctor", "--profile", "virtual-mini", "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    report = host_report(load_profile("virtual-mini"))
    lib = json.loads(json.dumps(report.data))
    assert printed.pop("sgemm_gflops") > 0 and lib.pop("sgemm_gflops") == round(report.sgemm_gflops, 1)
    assert lib == printed
