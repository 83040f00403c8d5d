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

# the kernel is compiled (or loaded from numba's cache) before the tests: a fresh compilation takes
# minutes, and inside a test it would count against that test's time limit. `make test` leaves
# out the slow tier (long end-to-end and statistical checks, marked `slow`); `make test-slow`
# runs it, and CI runs both. One pytest worker a core (pytest-xdist), a test file to one worker
# (its module fixtures are built once)
PYTEST = $(BIN)/python -m pytest -q -n auto --dist loadfile --durations=25
WARM_UP = $(BIN)/python -c 'from bench_ctl.identification.identify import warm_up; \
	  from bench_ctl.model import online, simulate; from bench_ctl.model.unit import reference_unit; \
	  print(f"kernel compiled or loaded from its cache in {warm_up(reference_unit()):.0f} s"); \
	  print(f"on-line machine in {online.warm_up(simulate.param_matrix(reference_unit().values())):.0f} s"); \
	  from bench_ctl.model import online_plant; print(f"on-line plant in {online_plant.warm_up():.0f} s")'

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
