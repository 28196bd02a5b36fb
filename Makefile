# The two commands of the README:
#   make demo   set everything up, then run the demo on the built-in virtual sensor
#   make test   set everything up, then lint, type-check and run the test suite
.PHONY: setup demo test lint bench

setup:
	bash tools/bootstrap.sh

demo: setup
	.venv/bin/thintact demo --out demo-output --force

lint: setup
	.venv/bin/ruff check thintact_sdk plugins tests tools
	.venv/bin/mypy
	.venv/bin/lint-imports

# Two test processes with one BLAS/OpenMP thread each: both cores busy, and no BLAS threads
# spin-waiting for a core the other process holds (docs/architecture.md, "Tests").
test: lint
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 .venv/bin/python -m pytest -q -n 2

bench: setup
	.venv/bin/thintact bench reconstruct
	.venv/bin/thintact bench tactile
