"""The diagnosis engine imaging and tactile share (issue 31).

Both diagnoses run the same loop: a baseline fit, the residual located along the problem's
axes, effects named one at a time by an information criterion, the final fit, a report. What
is shared lives here; each diagnosis supplies its forward model, data and effect vocabulary.

- :mod:`.residual_stats`: the contract statistics of a prediction (χ² per value, rms).
- :mod:`.residual_axes`: where a residual sits (excess-χ² map, hotspots, χ² binned along any
  axis or inside any mask).
- :mod:`.forward_selection`: the greedy loop and its BIC criterion; a diagnosis plugs in
  through the :class:`~.forward_selection.EffectSearch` protocol (propose fitted candidates,
  admit, accept, name alternatives).
- :mod:`.report_sections`: the report skeleton (CONTRACTS §6 sections and their order).
"""
