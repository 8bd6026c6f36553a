# `make test` installs what the tests need (Debian's net-snmp tools and chromium; the project with its test
# extra in a fresh virtual environment, so that a dependency installed by hand on this machine can hide nothing)
# and runs the whole suite in it.
.PHONY: test fast deps lint

SUDO := $(shell [ "$$(id -u)" -eq 0 ] || echo sudo)
VENV ?= .venv-test

# Two workers: the tests that wait on real seconds run in one of them, one after another (tests/conftest.py).
test: deps
	$(VENV)/bin/python -m pytest -q -n 2 --dist loadgroup

# The fast loop: the environment `make test` made, without the wall-clock, browser and slow tests.
fast:
	$(VENV)/bin/python -m pytest -q -n 2 -m "not wallclock and not browser and not slow"

# net-snmp's snmpget/snmpset/snmpwalk are the independent client the emulator's agent is tested
# against; snmpd is the independent agent the middleware's SNMP client is tested against.
deps:
	@command -v snmpget >/dev/null && command -v snmpd >/dev/null && command -v chromium >/dev/null || { \
		$(SUDO) apt-get update -qq && \
		DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq snmp snmpd chromium >/dev/null; }
	python3 -m venv --clear $(VENV)
	$(VENV)/bin/pip install -q -e '.[test]'

lint:
	$(VENV)/bin/ruff check .
