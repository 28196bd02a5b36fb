"""The paper's decoders and this SDK's closed forms: measurement → scene, one decoder interface
(:class:`thintact_sdk.interfaces.Decoder`).

========================  =================================================================
module                    what it holds
========================  =================================================================
``components``            the registry components (built-in plugin ``thintact-sdk``) and
                          their factories ``factory(profile, settings) -> Decoder``
``noniterative``          ``thintact-noniterative``: the paper's joint DCT filter + closed-form
                          Tikhonov
``t2s_closed_form``       ``t2s-closed-form``: the exact full-T2S Tikhonov minimiser
``iterative``             ``t2s-iterative``: Nesterov on the full T2S problem (baseline)
``flatcam``               ``flatcam``: FlatCam's closed form (baseline)
``identity``              ``identity``: lens-based sensors (no reconstruction)
``closed_form_base``      what the closed forms share; ``shapes``: input shape checks
``modes``                 Tikhonov mode truncation and per-channel τ
``sensor_binning``        solving on the sensor binned ``b × b``
``backend``               the array backend (numpy, torch) the closed forms run on;
                          ``backend_candidates``, ``backend_selection``, ``backend_cache``:
                          the backend measured fastest on this host, and where that is kept
``loading``               the calibration bundle a decoder uses
========================  =================================================================

The core never chooses a decoder by name: the profile's ``decoder.plugin`` names it, and
calibration asks the registry for decoders by their declared traits
(:data:`thintact_sdk.hookspecs.TRAITS`).
"""

from __future__ import annotations

from thintact_sdk.reconstruction.decoders.backend import ArrayBackend
from thintact_sdk.reconstruction.decoders.flatcam import FlatCamDecoder
from thintact_sdk.reconstruction.decoders.identity import IdentityDecoder
from thintact_sdk.reconstruction.decoders.iterative import T2SIterativeDecoder
from thintact_sdk.reconstruction.decoders.noniterative import NonIterativeDecoder
from thintact_sdk.reconstruction.decoders.t2s_closed_form import T2SClosedFormDecoder

__all__ = [
    "ArrayBackend",
    "FlatCamDecoder",
    "IdentityDecoder",
    "NonIterativeDecoder",
    "T2SClosedFormDecoder",
    "T2SIterativeDecoder",
]
