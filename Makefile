# Two entry points on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-slow lint compile bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

# uv installs the same packages as pip in half the time (16 s vs 30 s here); pip does it
# when uv cannot be had. Bytecode compiled at install (pip does that by itself): where
# PYTHONDONTWRITEBYTECODE is set, as on CI here, nothing is compiled later, and every
# process the tests start would compile its imports again (0.4 s more per recorder).
$(STAMP): $(BIN)/python pyproject.toml
	( $(BIN)/python -m pip install --quiet uv && \
	  $(BIN)/uv pip install --quiet --compile-bytecode --python $(BIN)/python -e '.[test]' ) || \
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

# our own sources' bytecode, for the same reason (stale files are rewritten)
compile: $(STAMP)
	@$(BIN)/python -m compileall -q -j 0 acq drivers sim tests bench

demo: $(STAMP)
	$(BIN)/acq demo

lint: $(STAMP)
	$(BIN)/ruff format --check acq drivers sim tests bench
	$(BIN)/ruff check acq drivers sim tests bench
	$(BIN)/mypy acq drivers

# Real-time tests alone (tests/conftest.py), then the rest on both cores. Running the
# rest beside them, even at nice 19, made the demo's live camera miss its cadence.
test: lint compile
	$(BIN)/pytest -q -m "not slow and realtime"
	$(BIN)/pytest -q -m "not slow and not realtime" -n 2

test-slow: $(STAMP)
	$(BIN)/pytest -q -m slow

bench: $(STAMP)
	@for f in bench/*.py; do $(BIN)/python $$f || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info .mypy_cache .pytest_cache .ruff_cache
