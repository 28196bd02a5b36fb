"""Writing a diagnosis to its output directory (CONTRACTS §6)."""

from __future__ import annotations

import json
import os
from pathlib import Path

from thintact_sdk.diagnosis.imaging.engine import Diagnosis
from thintact_sdk.diagnosis.imaging.html import write_html, write_pngs
from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import write_profile


def write_outputs(d: Diagnosis, out_dir: str | os.PathLike[str], png: bool = False) -> dict[str, Path]:
    """Write ``report.json``, ``fitted_profile.json`` and ``report.html`` into ``out_dir``
    (and, with ``png``, the figures as ``figures/*.png``).

    Raises
    ------
    ThinTactError
        When the directory cannot be created or written.
    """
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        rep = out / "report.json"
        rep.write_text(json.dumps(d.report, indent=1, ensure_ascii=False) + "\n", encoding="utf-8")
        prof = write_profile(d.fitted_profile, out / "fitted_profile.json")
        page = write_html(d, out / "report.html")
        if png:
            write_pngs(d, out / "figures")
    except OSError as err:
        raise ThinTactError(f"cannot write the diagnosis to {out}: {err}") from None
    return {"report": rep, "fitted_profile": prof, "html": page}
