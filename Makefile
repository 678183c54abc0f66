# Two entry points on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
SHELL := /bin/bash
STAMP := $(VENV)/.installed

.PHONY: demo test test-slow interop lint typecheck smoke compile bench clean chrony chromium docs docs-pictures

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

# uv installs the same packages as pip, faster; pip does it when uv cannot be had.
# Bytecode is compiled at install: where PYTHONDONTWRITEBYTECODE is set, as on CI, nothing
# is compiled later, and every process the tests start would compile its imports again.
$(STAMP): $(BIN)/python pyproject.toml
	( $(BIN)/python -m pip install --quiet uv && \
	  $(BIN)/uv pip install --quiet --compile-bytecode --python $(BIN)/python -e '.[all,test,docs]' ) || \
	$(BIN)/python -m pip install --quiet -e '.[all,test,docs]'
	touch $(STAMP)

# our own sources' bytecode, for the same reason (stale files are rewritten); and the test
# modules as pytest rewrites their asserts, which it caches only where it may write
# bytecode: else each pytest worker rewrites all of them again (7 s of CPU a worker). Two
# collections on halves of the files write them; a module that does not import is said
# by the tests themselves.
compile: $(STAMP)
	@$(BIN)/python -m compileall -q -j 0 acq drivers sim config tests bench
	@files=$$(find tests -name 'test_*.py' | sort); n=$$(echo "$$files" | wc -l); \
	echo "$$files" | PYTHONDONTWRITEBYTECODE= xargs -P 2 -n $$(( (n + 1) / 2 )) \
	  $(BIN)/pytest -q --collect-only -p no:cacheprovider > /dev/null 2>&1 || true

demo: $(STAMP)
	$(BIN)/acq demo

RUFF_PATHS := acq drivers sim config tests bench docs

# mypy reads the package as the wheel lays it out (drivers/ and sim/ inside acq/): it cannot
# follow the editable install's import hook, so it reads a tree of links (.typed/acq).
typecheck: $(STAMP)
	@rm -rf .typed && mkdir -p .typed/acq && ln -s $(CURDIR)/acq/* .typed/acq/ && \
	ln -s $(CURDIR)/drivers .typed/acq/drivers && ln -s $(CURDIR)/sim .typed/acq/sim && \
	ln -s $(CURDIR)/config .typed/acq/config
	@MYPYPATH=.typed $(BIN)/mypy -p acq | sed -e 's|^\.typed/acq/drivers/|drivers/|' \
	  -e 's|^\.typed/acq/sim/|sim/|' -e 's|^\.typed/||'; exit $${PIPESTATUS[0]}

lint: $(STAMP)
	$(BIN)/ruff format --check $(RUFF_PATHS)
	$(BIN)/ruff check $(RUFF_PATHS)
	$(MAKE) --no-print-directory typecheck

# a wheel of the project in a throwaway venv, its commands run outside the checkout
smoke: $(STAMP)
	tests/smoke/wheel.sh $(CURDIR)/$(BIN)/python

# the time-base tests run a real chronyd (-x: it never sets the clock): Debian's chrony,
# installed when missing and we are root; without it those tests skip, saying why
chrony:
	@command -v chronyd >/dev/null || test -x /usr/sbin/chronyd || \
	( test "$$(id -u)" -eq 0 && export DEBIAN_FRONTEND=noninteractive && \
	  { apt-get install -y -qq chrony || { apt-get update -qq && apt-get install -y -qq chrony; }; } \
	  >/dev/null 2>&1 ) || echo "chrony not installed: the tests that run chronyd skip"

# the page tests drive Debian's chromium headless (tests/browser.py), installed the same way;
# without it they skip, saying why (on CI, env CI=true, they fail instead)
chromium:
	@test -x /usr/bin/chromium || \
	( test "$$(id -u)" -eq 0 && export DEBIAN_FRONTEND=noninteractive && \
	  { apt-get install -y -qq chromium || { apt-get update -qq && apt-get install -y -qq chromium; }; } \
	  >/dev/null 2>&1 ) || echo "chromium not installed: the page tests skip (fail where CI=true)"

# ruff first; then the real-time tests three at a time (they mostly wait on their devices:
# two at a time used a third of the two cores), with mypy and the documentation site
# (`make docs`, strict: a broken link or a stale reference fails) beside them at nice 19
# (they take only the CPU the tests leave); then the rest on both cores, with the wheel's
# smoke beside them at the default priority: it runs rigs in real time itself (the demo,
# simulators against the recorder), which starved at nice 19 (a camera without a frame
# within 1 s, seen on CI). Once the tests are done, mypy and the docs go back to the
# default priority where we may (root), so that on a busy machine they do not starve
# behind its other work. worksteal: a worker that runs out takes tests queued on another,
# so none idles through another's long tail.
# setsid: each in a process group of its own, for renice -g (and killed with make test).
# A new session is also a scheduler autogroup of its own where the kernel has them, and
# nice ranks processes only within their autogroup: beside the real-time tests each would
# take CPU as their equal (an idle run's real-time phase 4:41 instead of 3:13), so their
# autogroup is set to nice 19 too (LOW), and back to 0 with them.
LOW = { echo 19 > /proc/self/autogroup; } 2> /dev/null;
test: $(STAMP) compile chrony chromium
	$(BIN)/ruff format --check $(RUFF_PATHS)
	$(BIN)/ruff check $(RUFF_PATHS)
	@setsid sh -c "$(LOW) exec nice -n 19 $(MAKE) --no-print-directory typecheck" > .mypy.out 2>&1 & mypy=$$!; \
	setsid sh -c "$(LOW) exec nice -n 19 $(MAKE) --no-print-directory docs" > .docs.out 2>&1 & docs=$$!; \
	smoke=; trap 'kill -- -$$mypy -$$docs $${smoke:+-$$smoke} 2> /dev/null' EXIT; \
	$(BIN)/pytest -q -m "not slow and realtime and not interop" -n 3 --dist worksteal; realtime=$$?; \
	setsid $(MAKE) --no-print-directory smoke > .smoke.out 2>&1 & smoke=$$!; \
	$(BIN)/pytest -q -m "not slow and not realtime and not interop" -n 2 --dist worksteal; rest=$$?; \
	renice -n 0 -g $$mypy $$docs > /dev/null 2>&1 || true; \
	for p in $$mypy $$docs; do echo 0 > /proc/$$p/autogroup; done 2> /dev/null || true; \
	wait $$mypy; typed=$$?; wait $$smoke; smoked=$$?; wait $$docs; documented=$$?; \
	echo "mypy:"; cat .mypy.out; echo "wheel smoke:"; cat .smoke.out; echo "docs:"; cat .docs.out; \
	rm -f .mypy.out .smoke.out .docs.out; \
	test $$realtime -eq 0 && test $$rest -eq 0 && test $$typed -eq 0 && test $$smoked -eq 0 && \
	test $$documented -eq 0

test-slow: $(STAMP)
	$(BIN)/pytest -q -m slow

# our files opened in the readers users open them with: the `interop` extra (Open3D,
# trimesh) from PyPI; the TypeScript MCAP reader Foxglove uses (@mcap/core) from npm, when
# Node.js is installed; PCL's and CloudCompare's tools from the system when installed
# (Debian: pcl-tools, cloudcompare, xvfb), skipped otherwise
interop: $(STAMP)
	( $(BIN)/uv pip install --quiet --python $(BIN)/python -e '.[all,test,interop]' ) || \
	$(BIN)/python -m pip install --quiet -e '.[all,test,interop]'
	if command -v npm >/dev/null; then cd tests/interop/node && npm ci --silent; fi
	$(BIN)/pytest -q -rs -m interop tests/interop

# the documentation site into site/, strict: a broken link, a page missing from the nav or
# a warning fails; the reference pages are generated from the code as it is built
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --quiet

# the pictures the pages show, drawn from the simulated rig (committed: `make docs` uses them)
docs-pictures: $(STAMP) chromium
	PYTHONPATH=. $(BIN)/python docs/pictures.py docs/pictures

bench: $(STAMP)
	@for f in bench/*.py; do $(BIN)/python $$f || exit 1; done

clean:
	rm -rf $(VENV) build site .typed *.egg-info .mypy_cache .pytest_cache .ruff_cache
