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

# the engine is compiled (or loaded from numba's cache) before the tests, every variant the suite
# runs, side by side in child processes (`bench-ctl warm-up --all`): a compilation inside a test
# would count against that test's time limit, and two pytest workers would compile the same
# variant twice. `make test` leaves out the slow tier (long end-to-end and statistical checks,
# marked `slow`); `make test-slow` runs it, and CI runs both. Each runs as two pytest sessions side
# by side: the tests that wait on a simulated bench's clock (dry runs and the simulated devices,
# marked `realtime` by tests/conftest.py; their timing criteria need a core the moment they wake)
# and the computing ones at the lowest priority (nice 19), which take what the waiting ones leave
# idle. The real-time session's output follows the other's. A test file goes to one worker
# (pytest-xdist --dist loadfile: its module fixtures are built once)
PYTEST = $(BIN)/python -m pytest -q --dist loadfile --durations=15
#: workers of the real-time session (they mostly wait; the computing session has one a core)
RT_WORKERS ?= 2
WARM_UP = $(BIN)/bench-ctl warm-up --all

# $(1): the tier's marker expression. Exit status: the first failing session's (5, no test
# collected, is no failure: a tier may have no real-time test)
define side_by_side
	@rt_log=$$(mktemp); \
	$(PYTEST) -n $(RT_WORKERS) -m "realtime and $(1)" >$$rt_log 2>&1 & rt=$$!; \
	trap 'kill $$rt 2>/dev/null; rm -f $$rt_log; exit 130' INT TERM; \
	echo "$(PYTEST) -n auto -m 'not realtime and $(1)' at nice 19, beside the real-time tests (output below)"; \
	nice -n 19 $(PYTEST) -n auto -m "not realtime and $(1)"; cpu=$$?; \
	wait $$rt; r=$$?; echo "== the real-time tests, run beside those above: $(PYTEST) -n $(RT_WORKERS) -m 'realtime and $(1)'"; \
	cat $$rt_log; rm -f $$rt_log; \
	for c in $$cpu $$r; do [ $$c -eq 0 ] || [ $$c -eq 5 ] || exit $$c; done
endef

test: $(STAMP)
	$(WARM_UP)
	$(call side_by_side,not slow)

test-slow: $(STAMP)
	$(WARM_UP)
	$(call side_by_side,slow)

bench: $(STAMP)
	mkdir -p bench-out
	for b in benchmarks/*.py; do \
	  case $$b in *andes_captures.py|*andes_online.py|*andes_dyr.py|*andes_online_dyr.py|*mvmo_cec.py) continue;; esac; \
	  $(BIN)/python $$b --json bench-out/$$(basename $$b .py).json || exit 1; done

clean:
	rm -rf $(VENV) demo-out bench-out
