"""Diagnosis: where a simulation and a recording differ, and why (imaging in :mod:`.imaging`, tactile in :mod:`.tactile`)."""
