"""MLS and random mask designers."""

from __future__ import annotations

import numpy as np
import pytest
from thintact_masks.mls import (
    PRIMITIVE_TAPS,
    MLSDesigner,
    RandomDesigner,
    mls_sequence,
    repeat_to_length,
)

from thintact_sdk.formats.profiles import load_profile


def circular_autocorrelation(s: np.ndarray) -> np.ndarray:
    x = np.fft.rfft(s.astype(np.float64))
    return np.rint(np.fft.irfft(x * np.conj(x), n=s.size)).astype(np.int64)


def test_mls_255_properties() -> None:
    s = mls_sequence(8)
    assert s.shape == (255,)
    assert set(np.unique(s)) == {-1, 1}
    assert int((s == 1).sum()) == 128 and int((s == -1).sum()) == 127  # balance
    ac = circular_autocorrelation(s)
    assert ac[0] == 255
    assert np.all(ac[1:] == -1)  # two-valued


@pytest.mark.parametrize("bits", sorted(PRIMITIVE_TAPS))
def test_every_tabulated_polynomial_is_primitive(bits: int) -> None:
    s = mls_sequence(bits)
    assert s.size == 2**bits - 1
    ac = circular_autocorrelation(s)
    assert np.all(ac[1:] == -1)


def test_paper_baseline_is_mls_repeated_three_times() -> None:
    mask = MLSDesigner().design(765, 20.0)
    assert mask.K == 765 and mask.design == "mls"
    np.testing.assert_array_equal(mask.phi[:255], mask.phi[255:510])
    np.testing.assert_array_equal(mask.phi[:255], mask.phi[510:])
    shipped = np.asarray(load_profile("thintact-paper").mask.phi)
    np.testing.assert_array_equal(mask.phi, shipped)


def test_repeat_truncates_to_any_length() -> None:
    s = mls_sequence(8)
    np.testing.assert_array_equal(repeat_to_length(s, 770)[765:], s[:5])
    np.testing.assert_array_equal(repeat_to_length(s, 100), s[:100])
    with pytest.raises(ValueError):
        repeat_to_length(s, 0)


def test_random_designer_is_seeded() -> None:
    a = RandomDesigner().design(300, 20.0, seed=3)
    b = RandomDesigner().design(300, 20.0, seed=3)
    c = RandomDesigner().design(300, 20.0, seed=4)
    np.testing.assert_array_equal(a.phi, b.phi)
    assert not np.array_equal(a.phi, c.phi)
    assert set(np.unique(a.phi)) == {-1, 1}
    assert a.provenance["seed"] == 3


def test_unknown_mls_order_is_refused() -> None:
    with pytest.raises(ValueError, match="MLS order"):
        mls_sequence(40)
