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

test: lint
	.venv/bin/python -m pytest -q

bench: setup
	.venv/bin/thintact bench reconstruct
	.venv/bin/thintact bench tactile
