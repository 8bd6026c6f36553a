# `make test` installs what the tests need (Debian's net-snmp tools, the Python test extra) and runs them.
.PHONY: test deps lint

SUDO := $(shell [ "$$(id -u)" -eq 0 ] || echo sudo)

test: deps
	python -m pytest -q

# net-snmp's snmpget/snmpset/snmpwalk are the independent client the emulator's agent is tested
# against; snmpd is the independent agent the middleware's SNMP client is tested against.
deps:
	@command -v snmpget >/dev/null && command -v snmpd >/dev/null && command -v chromium >/dev/null || { \
		$(SUDO) apt-get update -qq && \
		DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq snmp snmpd chromium >/dev/null; }
	pip install -q -e '.[test]'

lint:
	ruff check .
