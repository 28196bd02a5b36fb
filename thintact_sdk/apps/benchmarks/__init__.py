"""Benchmarks run by ``thintact bench NAME``. Each module here defines
``add_arguments(parser)``, ``run(args) -> int`` and a one-line module docstring."""
