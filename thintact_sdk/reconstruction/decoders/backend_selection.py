"""Choose a decoder's array backend by measuring it on this host (never by assumption).

For one decoder and operator shape, every candidate backend (:func:`candidate_specs`) is
built, checked for accuracy against float64 on probe scenes and timed on the real frame size;
the fastest whose PSNR cost is within ``bound_db`` (default 0.1 dB) is used. A decoder whose τ can be changed is
checked and timed at the τ that decodes the probes best on float64 (:func:`probe_tau`), not at
the τ it happens to be built with: how much a cheaper backend (bfloat16, a binned sensor) costs
depends on the regularisation, and at an unregularised τ every backend decodes noise alike. The
measurements are cached per host fingerprint and operator shape (:class:`BackendCache`), so the
next decoder of that shape is built directly. A user preference (``THINTACT_BACKEND`` or a
profile's ``decoder.settings``) is honoured only where it is accurate and not slower than the
best by more than ``slack`` (20 %); otherwise a :class:`BackendPreferenceWarning` says why not.
"""

from __future__ import annotations

import threading
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from typing import Any

import numpy as np

from thintact_sdk.formats.profiles import NoiseSpec
from thintact_sdk.interfaces import Decoder, DecoderInput
from thintact_sdk.reconstruction.decoders.backend_cache import BackendCache
from thintact_sdk.reconstruction.decoders.backend_candidates import BackendSpec
from thintact_sdk.reconstruction.metrics import psnr
from thintact_sdk.reconstruction.t2s import SystemMatrices

PSNR_BOUND_DB = 0.1
PREFERENCE_SLACK = 0.2
PROBE_SCENES = (("usaf", 0), ("gelsight", 20))
MEASURED_AT = "probe-tau"
"""How the measurements are made (part of every cache key): backends are compared at the τ
:func:`probe_tau` finds. Entries cached under another rule are measured again."""
PROBE_TAU_DECADES = 8
""":func:`probe_tau` searches τ over this many decades either side of the decoder's own τ."""


class BackendPreferenceWarning(UserWarning):
    """A requested backend was not used (slower, less accurate, or not native here)."""


@dataclass(frozen=True)
class Probe:
    """One probe frame: raw binned DN (``R × S × C`` uint16, black level included) and the
    scene it shows (``N × M × C`` display units)."""

    raw: np.ndarray
    black_dn: float
    truth: np.ndarray


def make_probes(sm: SystemMatrices, noise: NoiseSpec, seed: int = 0) -> list[Probe]:
    """Raw frames of the bench scenes (USAF, a GelSight press) through ``sm`` with the sensor
    noise of ``noise`` (fixed seed): accuracy is judged where it matters, on noisy frames."""
    from thintact_sdk.reconstruction.filter_training import scene_for_channels
    from thintact_sdk.simulation.noise import signal_to_dn
    from thintact_sdk.simulation.scenes import make_scene

    n, m = sm.scene_shape
    rng = np.random.default_rng(seed)
    probes = []
    for name, index in PROBE_SCENES:
        x = scene_for_channels(make_scene(name, n, m, index), sm.channels)
        dn = signal_to_dn(np.clip(sm.forward(x), 0, None), noise, rng)
        raw = np.clip(np.round(dn), 0, 65535).astype(np.uint16)
        probes.append(Probe(raw, float(noise.black_level_dn), x))
    return probes


@dataclass
class BackendChoice:
    """What the selection measured and chose for one decoder.

    Attributes
    ----------
    chosen
        Key of the backend in use (``numpy-float32``, …).
    measured_ms
        Median ms per frame of every candidate measured (``decode(raw, black_level_dn)`` of a probe frame).
    psnr_cost_db
        PSNR below the float64 reconstruction, worst probe scene, per candidate (dB).
    unavailable
        Candidates not measured or failed, with the reason.
    note
        The warning given when a preference was not honoured, else None.
    from_cache
        True when the measurements came from the cache (nothing measured now).
    bound_db
        The accuracy bound used.
    """

    chosen: str
    measured_ms: dict[str, float]
    psnr_cost_db: dict[str, float]
    unavailable: dict[str, str] = field(default_factory=dict)
    note: str | None = None
    from_cache: bool = False
    bound_db: float = PSNR_BOUND_DB

    def summary(self) -> str:
        """One line: chosen backend and the measured alternatives."""
        alts = ", ".join(f"{k} {v:.1f} ms ({self.psnr_cost_db.get(k, float('nan')):+.3f} dB)"
                         for k, v in sorted(self.measured_ms.items(), key=lambda kv: kv[1]))
        skipped = "; ".join(f"{k}: {why}" for k, why in self.unavailable.items())
        src = "cached" if self.from_cache else "measured now"
        return (f"{self.chosen} ({src}; candidates: {alts}"
                + (f"; not candidates: {skipped}" if skipped else "") + ")")


def decide(
    measured_ms: dict[str, float], psnr_cost_db: dict[str, float], preferred: str | None = None,
    bound_db: float = PSNR_BOUND_DB, slack: float = PREFERENCE_SLACK,
    unavailable: dict[str, str] | None = None, preferred_from: str = "preference",
) -> tuple[str, str | None]:
    """``(chosen key, note)``: the fastest accurate backend, or the preferred one where it is
    accurate and at most ``slack`` slower than that; ``note`` explains an overruled preference
    (or, when no backend is within ``bound_db``, that the most accurate one was taken).

    Raises
    ------
    ValueError
        When nothing was measured at all.
    """
    if not measured_ms:
        raise ValueError("no backend could be measured")
    accurate = {k: v for k, v in measured_ms.items() if psnr_cost_db.get(k, np.inf) <= bound_db}
    if not accurate:
        closest = min(measured_ms, key=lambda k: psnr_cost_db.get(k, np.inf))
        return closest, (f"no backend reconstructs within {bound_db} dB of float64 "
                         f"({', '.join(f'{k} {v:+.2f} dB' for k, v in psnr_cost_db.items())}); using the most "
                         f"accurate, {closest}")
    best = min(accurate, key=accurate.__getitem__)
    if preferred is None or preferred == best:
        return best, None
    used = f"using {best} ({accurate[best]:.1f} ms per frame)"
    if preferred not in measured_ms:
        why = (unavailable or {}).get(preferred, "not available on this host")
        return best, f"backend {preferred} from {preferred_from} not used: {why}; {used}"
    if preferred not in accurate:
        return best, (f"backend {preferred} from {preferred_from} not used: it costs "
                      f"{psnr_cost_db[preferred]:.2f} dB against float64 (bound {bound_db} dB); {used}")
    if accurate[preferred] <= (1.0 + slack) * accurate[best]:
        return preferred, None
    slower = accurate[preferred] / accurate[best] - 1.0
    return best, (f"backend {preferred} from {preferred_from} not used: {accurate[preferred]:.1f} ms per "
                  f"frame, {slower:.0%} slower than the best (limit {slack:.0%}); {used}")


def _decode_fn(decoder: Decoder, probe: Probe) -> Callable[[], np.ndarray]:
    """What a Sensor would call: the raw probe frame and its black level for a decoder
    declaring ``input`` ``"raw"`` or ``"binned"`` (which bins the full frame itself), the
    signal above black otherwise."""
    if DecoderInput.of(decoder).kind != "signal":
        return lambda: decoder.decode(probe.raw, probe.black_dn)
    signal = probe.raw.astype(np.float32) - np.float32(probe.black_dn)
    return lambda: decoder.decode(signal)


def _scores(decoder: Decoder, probes: Sequence[Probe]) -> list[float]:
    return [psnr(np.clip(_decode_fn(decoder, p)(), 0.0, 1.0), p.truth) for p in probes]


def probe_tau(decoder: Decoder, probes: Sequence[Probe]) -> float | None:
    """The τ (DN², the decoder's units) at which ``decoder`` decodes ``probes`` best (mean
    PSNR): whole powers of ten over :data:`PROBE_TAU_DECADES` decades either side of its own
    τ, then quarter decades around the best. The grid is fixed in absolute terms (``10^(k/4)``),
    so every starting τ within reach finds the same τ. ``None`` for a decoder without
    ``set_tau``; the decoder is left at the τ found."""
    if not hasattr(decoder, "set_tau") or not hasattr(decoder, "tau"):
        return None
    own = float(decoder.tau)
    centre = int(round(np.log10(own))) if np.isfinite(own) and own > 0 else 0
    scores: dict[float, float] = {}

    def mean_psnr(exponent: float) -> float:
        if exponent not in scores:
            decoder.set_tau(10.0 ** exponent)  # type: ignore[attr-defined]
            scores[exponent] = float(np.mean(_scores(decoder, probes)))
        return scores[exponent]

    best = max(range(centre - PROBE_TAU_DECADES, centre + PROBE_TAU_DECADES + 1), key=mean_psnr)
    chosen = max((best + q / 4.0 for q in range(-3, 4)), key=mean_psnr)
    decoder.set_tau(10.0 ** chosen)  # type: ignore[attr-defined]
    return float(10.0 ** chosen)


def _own_tau(decoder: Decoder) -> Any:
    """The τ ``decoder`` was built with (per channel where it has one), to restore it."""
    return np.array(decoder.channel_tau) if hasattr(decoder, "channel_tau") else float(decoder.tau)  # type: ignore[attr-defined]


def _time_ms(fn: Callable[[], Any], repeats: int, give_up_ms: float) -> float:
    """Median ms of ``repeats`` calls after one warm-up; stops early once two calls both took
    longer than ``give_up_ms`` (a candidate that cannot win is not measured to the end)."""
    fn()
    times: list[float] = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
        if len(times) >= 2 and min(times) > give_up_ms:
            break
    return float(np.median(times))


def build_for(build: Callable[..., Decoder], spec: BackendSpec) -> Decoder:
    """``build(backend)``, or ``build(backend, sensor_bin)`` for a binned spec."""
    return build(spec.make()) if spec.sensor_bin == 1 else build(spec.make(), spec.sensor_bin)


def measure_backends(
    build: Callable[..., Decoder], probes: Sequence[Probe], specs: Sequence[BackendSpec],
    repeats: int = 5,
) -> tuple[dict[str, float], dict[str, float], dict[str, str], dict[str, Decoder]]:
    """Time and score every spec: ``(measured_ms, psnr_cost_db, failed, decoders)``.

    ``build(backend)`` makes the decoder (``build(backend, sensor_bin)`` a binned one); the
    reference is ``build`` on numpy float64, unbinned. Every candidate is scored and timed at
    the reference's :func:`probe_tau` (where the decoder can change τ) and handed back at the
    τ it was built with. A spec that is the reference itself (numpy float64, unbinned) is
    timed on the reference decoder and costs 0 dB, neither built nor scored twice.
    """
    ref_spec = BackendSpec("numpy", "cpu", "float64", "float64", 1)
    ref_decoder = build(ref_spec.make())
    # probe_tau leaves the reference at the τ it finds; it is handed back at its own
    ref_own = _own_tau(ref_decoder) if hasattr(ref_decoder, "tau") else None
    tau = probe_tau(ref_decoder, probes)
    reference = _scores(ref_decoder, probes)
    measured: dict[str, float] = {}
    cost: dict[str, float] = {}
    failed: dict[str, str] = {}
    decoders: dict[str, Decoder] = {}
    for spec in specs:
        try:
            is_ref = spec == ref_spec
            decoder = ref_decoder if is_ref else build_for(build, spec)
            own = None if tau is None else ref_own if is_ref else _own_tau(decoder)
            if tau is not None:
                decoder.set_tau(tau)  # type: ignore[attr-defined]
            give_up = 3.0 * min(measured.values()) if measured else np.inf
            measured[spec.key] = _time_ms(_decode_fn(decoder, probes[0]), repeats, give_up)
            cost[spec.key] = 0.0 if is_ref else float(max(
                r - s for r, s in zip(reference, _scores(decoder, probes), strict=True)))
            if own is not None:
                decoder.set_tau(own)  # type: ignore[attr-defined]
            decoders[spec.key] = decoder
        except Exception as err:  # noqa: BLE001 - a backend that fails here is simply not a candidate
            failed[spec.key] = f"failed ({type(err).__name__}: {err})"
    return measured, cost, failed, decoders


_KEY_LOCKS: dict[str, threading.Lock] = {}
_KEY_LOCKS_GUARD = threading.Lock()


def _key_lock(cache_key: str) -> threading.Lock:
    """The lock of one cache key (created on first use)."""
    with _KEY_LOCKS_GUARD:
        return _KEY_LOCKS.setdefault(cache_key, threading.Lock())


def select_backend(
    build: Callable[..., Decoder], probes: Callable[[], Sequence[Probe]],
    specs: Sequence[BackendSpec], cache_key: str, preferred: BackendSpec | None = None,
    preferred_from: str = "preference", not_candidates: dict[str, str] | None = None,
    cache: BackendCache | None = None, bound_db: float = PSNR_BOUND_DB, slack: float = PREFERENCE_SLACK,
    repeats: int = 5, remeasure: bool = False,
) -> tuple[Decoder, BackendChoice]:
    """Build the decoder on the best backend for this host; measure only on a cache miss
    (or when ``remeasure``; the new measurements replace the cached ones).

    Parameters
    ----------
    build
        ``build(backend) -> Decoder`` for the operator at hand (``build(backend, sensor_bin)``
        when ``specs`` holds binned candidates).
    probes
        Called on a cache miss for the probe frames (:func:`make_probes`).
    specs
        The candidates (:func:`~thintact_sdk.reconstruction.decoders.backend_candidates.candidate_specs`).
    cache_key
        Host fingerprint and operator shape.
    preferred, preferred_from
        A requested backend and where the request came from (for the warning).
    not_candidates
        Backends left out on purpose, with the reason (reported, e.g. emulated bfloat16).
    """
    cache = cache or BackendCache()
    unavailable = dict(not_candidates or {})
    built: dict[str, Decoder] = {}
    # one measurement per key at a time: two threads building the same decoder (the
    # calibration's lanes) would each time the candidates against the other's load and could
    # choose differently; the second waits and takes the first's record
    with _key_lock(cache_key):
        record = None if remeasure else cache.get(cache_key)
        from_cache = record is not None and {s.key for s in specs} <= (
            set(record.get("measured_ms", {})) | set(record.get("unavailable", {})))
        if record is not None and from_cache:
            # Only today's candidates may be chosen: a cached entry can hold a backend that is
            # not one here now (e.g. bfloat16 measured before the host lost native support).
            keys = {s.key for s in specs}
            measured = {k: float(v) for k, v in record["measured_ms"].items() if k in keys}
            cost = {k: float(v) for k, v in record["psnr_cost_db"].items() if k in keys}
            unavailable.update({k: v for k, v in record.get("unavailable", {}).items() if k in keys})
        else:
            measured, cost, failed, built = measure_backends(build, probes(), specs, repeats)
            unavailable.update(failed)
            cache.put(cache_key, {"measured_ms": measured, "psnr_cost_db": cost, "unavailable": failed,
                                  "bound_db": bound_db,
                                  "measured_at": datetime.now(UTC).isoformat(timespec="seconds")})
    chosen, note = decide(measured, cost, preferred.key if preferred else None, bound_db, slack,
                          unavailable, preferred_from)
    if note is not None:
        warnings.warn(note, BackendPreferenceWarning, stacklevel=3)
    spec = next(s for s in specs if s.key == chosen)
    choice = BackendChoice(chosen, measured, cost, unavailable, note, from_cache, bound_db)
    decoder = built[chosen] if chosen in built else build_for(build, spec)
    decoder.backend_choice = choice  # type: ignore[attr-defined]
    return decoder, choice


def choice_as_dict(choice: BackendChoice) -> dict[str, Any]:
    """JSON-ready form of a :class:`BackendChoice`."""
    return asdict(choice)
