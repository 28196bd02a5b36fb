"""The report skeleton both diagnoses write (``report.json``, CONTRACTS §6).

Every diagnosis report holds, in this order: ``noise_rms_dn``, ``baseline`` and ``final``
(:func:`fit_section`), ``located`` (where the baseline's residual sits), ``findings`` (one
:func:`finding_entry` per accepted effect, in the order accepted) and ``unexplained``
(:func:`unexplained_section`). A diagnosis adds its own keys around them with
:func:`diagnosis_report`. Rounding is the caller's: the values are written as given.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

SECTIONS = ("noise_rms_dn", "baseline", "located", "findings", "final", "unexplained")
"""The CONTRACTS §6 sections, in the order they are written."""


def fit_section(rms_dn: float, chi2_per_dof: float, **extra: Any) -> dict[str, Any]:
    """``baseline`` / ``final``: rms of measured − predicted (the report's DN) and χ² per
    value; ``extra`` (e.g. ``bic``) after them."""
    return {"rms_dn": rms_dn, "chi2_per_dof": chi2_per_dof, **extra}


def finding_entry(effect: str, params: Mapping[str, Any], rms_dn_after: float,
                  chi2_per_dof_after: float, evidence: str, alternatives: Sequence[str],
                  **extra: Any) -> dict[str, Any]:
    """One ``findings`` entry: the effect, its fitted parameters (the vocabulary's units),
    the fit once it is in, the evidence in words and the effects that explain the data as
    well; ``extra`` (e.g. ``delta_bic``) before the evidence."""
    return {"effect": effect, "params": params, "rms_dn_after": rms_dn_after,
            "chi2_per_dof_after": chi2_per_dof_after, **extra, "evidence": evidence,
            "alternatives": list(alternatives)}


def unexplained_section(significant: bool, summary: str,
                        hotspots: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """``unexplained``: whether structure the named effects leave is significant, in words,
    and the regions (``Hotspot.to_json`` rows) where it sits."""
    return {"significant": bool(significant), "summary": summary, "hotspots": list(hotspots)}


def diagnosis_report(*, noise_rms_dn: Any, baseline: dict[str, Any], located: dict[str, Any],
                     findings: list[dict[str, Any]], final: dict[str, Any],
                     unexplained: dict[str, Any], head: Mapping[str, Any] | None = None,
                     after: Mapping[str, Mapping[str, Any]] | None = None,
                     tail: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The report: ``head`` keys first, then the :data:`SECTIONS`, each followed by the keys
    ``after[section]`` names, then ``tail``.

    Raises
    ------
    KeyError
        When ``after`` names a section that is not one of :data:`SECTIONS`.
    """
    values = {"noise_rms_dn": noise_rms_dn, "baseline": baseline, "located": located,
              "findings": findings, "final": final, "unexplained": unexplained}
    extra = dict(after or {})
    unknown = set(extra) - set(SECTIONS)
    if unknown:
        raise KeyError(f"not a report section: {sorted(unknown)}")
    report: dict[str, Any] = dict(head or {})
    for name in SECTIONS:
        report[name] = values[name]
        report.update(extra.get(name, {}))
    report.update(tail or {})
    return report
