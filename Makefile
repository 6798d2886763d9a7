# The two quick-start commands: `make demo` (set up, run the default study) and
# `make test` (set up, run the test suite). Both create .venv/ at the repository root.
.PHONY: setup demo test test-all bench lint clean

OUT ?= runs/default
# two pytest-xdist workers: on a 2-core machine they halve the wall time (measured in the
# closing note of the issue that introduced them);
# tests go to the workers by module (--dist loadscope): the tiny study is built once,
# beside the first tests (tests/conftest.py). In pytest-xdist's order (modules with most
# tests first); handed out longest module first, the propagation tests took 2.5 times the
# CPU (the closing note of issue 55)
PYTEST_ARGS ?= -m "not slow and not gpu" -n 2 --dist loadscope --durations=15

setup:
	@bash scripts/setup.sh

demo: setup
	.venv/bin/rfidstudy run --out $(OUT)

# the project's modules compiled once, before the suite: its ~30 interpreters (the xdist
# workers, spawned stages, command-line runs) then read them, not compile them each
# (0.7 s of CPU per interpreter; this matters where PYTHONDONTWRITEBYTECODE is set); only a
# speed-up: a tree it cannot write into runs the suite all the same
COMPILE = .venv/bin/python -m compileall -q -j 2 scenes propagation fuzzymodel pipeline tests

test:
	@bash scripts/setup.sh --test
	-@$(COMPILE)
	.venv/bin/python -m pytest $(PYTEST_ARGS)

test-all:
	@bash scripts/setup.sh --test
	-@$(COMPILE)
	.venv/bin/python -m pytest -m "not gpu" -n 2 --dist loadscope --durations=15

bench: setup
	.venv/bin/python -m pip install -q --disable-pip-version-check -e ".[bench]"
	# each records its output in docs/benchmarks.md (bench/record.py)
	.venv/bin/python bench/record.py trace
	.venv/bin/python bench/record.py acquire
	.venv/bin/python bench/record.py anfis
	.venv/bin/python bench/record.py gen2

lint: setup
	.venv/bin/ruff check scenes propagation fuzzymodel pipeline tests bench

clean:
	rm -rf .venv runs .cache
