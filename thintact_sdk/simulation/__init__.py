"""The contract simulator (CONTRACTS §4) and its effects (CONTRACTS §5, in :mod:`.effects`), the noise model and the scene library."""
