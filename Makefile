# Two commands on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-slow install clean bench

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/bench-ctl demo

# the engine is compiled (or loaded from numba's cache) before the tests: the variants the suite
# runs (tests/engine_variants.txt, 12 of `warm-up --all`'s 17) and the simulated bench's real-time
# loops, side by side in child processes: a compilation inside a test would count against that
# test's time limit, and two pytest workers would compile the same variant twice. The suite fails
# when a test compiles a variant the list leaves out, or anything after the warm-up
# (tests/compile_guard.py). `make test` leaves out the slow tier (long end-to-end and statistical
# checks, marked `slow`); `make test-slow` runs it, and CI runs both (its warm-up then finds the
# cache full: 3.5 s). On an empty cache the list compiles in 333-348 CPU s, `--all` in 418 (a
# shared 2-core machine). One pytest worker a core (pytest-xdist), a test file to one worker (its
# module fixtures are built once)
PYTEST = $(BIN)/python -m pytest -q -n auto --dist loadfile --durations=25
WARM_UP = $(BIN)/bench-ctl warm-up --variants tests/engine_variants.txt

test: $(STAMP)
	$(WARM_UP)
	$(PYTEST) -m "not slow"

test-slow: $(STAMP)
	$(WARM_UP)
	$(PYTEST) -m slow

bench: $(STAMP)
	mkdir -p bench-out
	for b in benchmarks/*.py; do \
	  case $$b in *andes_captures.py|*andes_online.py|*andes_dyr.py|*andes_online_dyr.py|*mvmo_cec.py) continue;; esac; \
	  $(BIN)/python $$b --json bench-out/$$(basename $$b .py).json || exit 1; done

clean:
	rm -rf $(VENV) demo-out bench-out
