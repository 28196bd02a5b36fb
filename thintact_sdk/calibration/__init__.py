"""Calibration of the T2S system matrices from slit scans (paper §D, Algorithms 1-3).

Modules:

- :mod:`~thintact_sdk.calibration.lowrank`: per-slit rank-k compression (bounded memory);
- :mod:`~thintact_sdk.calibration.slits`: compressed slit stacks of one channel;
- :mod:`~thintact_sdk.calibration.solver`: Algorithms 1-3 (``paper``) and joint least squares (``lsq``);
- :mod:`~thintact_sdk.calibration.gauge`: the T2S gauge, its canonical fix and gauge-free comparison;
- :mod:`~thintact_sdk.calibration.classify`, :mod:`~thintact_sdk.calibration.collect`: slits, dark
  and validation frames found from a recording's scenes, streamed and compressed;
- :mod:`~thintact_sdk.calibration.sumrule`: the white frame as the sum of the slits (dark level,
  per-frame gains);
- :mod:`~thintact_sdk.calibration.pipeline`: solve, filter training, τ, validation, bundle;
- :mod:`~thintact_sdk.calibration.plan`, :mod:`~thintact_sdk.calibration.pattern_capture`,
  :mod:`~thintact_sdk.calibration.registration`, :mod:`~thintact_sdk.calibration.wizard`: the LCD
  wizard with resume;
- :mod:`~thintact_sdk.calibration.unit_report`: the HTML report;
- :mod:`~thintact_sdk.calibration.synthetic`, :mod:`~thintact_sdk.calibration.stress_cases`: synthetic
  systems and the robustness benchmark.

See ``docs/calibration.md``.
"""
