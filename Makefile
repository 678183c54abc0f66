# Two entry points on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-slow lint bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/acq demo

lint: $(STAMP)
	$(BIN)/ruff format --check acq drivers sim tests bench
	$(BIN)/ruff check acq drivers sim tests bench
	$(BIN)/mypy acq drivers

# The real-time tests (tests/conftest.py) run in front; the rest run at the same time on
# both cores at the lowest CPU priority (nice 19), in the real-time tests' idle time, so
# the latter keep their deadlines. Both outputs are printed; either failing fails.
test: lint
	@rm -f .pytest-rest.log .pytest-rest.rc
	@( nice -n 19 $(BIN)/pytest -q -m "not slow and not realtime" -n 2 -p no:cacheprovider \
	    > .pytest-rest.log 2>&1; echo $$? > .pytest-rest.rc ) & \
	$(BIN)/pytest -q -m "not slow and realtime"; rt=$$?; wait; \
	echo "--- the other tests (nice 19, 2 workers):"; cat .pytest-rest.log; \
	rest=$$(cat .pytest-rest.rc); rm -f .pytest-rest.log .pytest-rest.rc; \
	test $$rt -eq 0 && test $$rest -eq 0

test-slow: $(STAMP)
	$(BIN)/pytest -q -m slow

bench: $(STAMP)
	@for f in bench/*.py; do $(BIN)/python $$f || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info .mypy_cache .pytest_cache .ruff_cache
