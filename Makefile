# gridfleet: `make run` starts the whole system, `make test` runs every check.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: constraints run test test-fast test-mosquitto pytest-clusters soak-clusters check lint typecheck pytest soak firmware-test firmware-checkout install schemas clean system-deps

# What the tests need from Debian: a real Mosquitto and its clients, headless Chromium for the
# dashboard, doctest and g++ for the firmware's host tests, Prometheus to scrape a fleet's metrics,
# Redis and RabbitMQ for the broker clusters (aedes on Redis, three RabbitMQ nodes).
DEBIAN_PACKAGES := mosquitto mosquitto-clients chromium libnss3-tools doctest-dev g++ make prometheus \
	redis-server rabbitmq-server

# npm: the dashboard's packages, vda-5050-lib for the tests' VDA 5050 2.0.0 vehicles, and aedes for
# the aedes cluster's launcher (broker/aedes), fetched
# while pip installs. pip byte-compiles every module at install: where PYTHONDONTWRITEBYTECODE is
# set, nothing compiled later is kept, and every process of every test would compile again; so
# gridfleet's own modules are compiled here too, and the test modules as pytest rewrites them (a
# collection: the first runs of make test start their pytest processes all at once).
NPM_CI := npm ci --no-audit --no-fund --loglevel=error
$(STAMP): pyproject.toml constraints.txt dashboard/package-lock.json tests/vda5050_lib/package-lock.json \
		broker/aedes/package-lock.json
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	(cd dashboard && $(NPM_CI)) & dashboard=$$!; \
	(cd tests/vda5050_lib && $(NPM_CI)) & vda=$$!; \
	(cd broker/aedes && $(NPM_CI)) & aedes=$$!; \
	$(BIN)/pip install --quiet -c constraints.txt -e ".[test]"; pip=$$?; \
	wait $$dashboard && wait $$vda && wait $$aedes && exit $$pip
	$(BIN)/python -m compileall -q -j 0 -x node_modules gridfleet $(PARTS) tests >/dev/null
	$(KEEP_BYTECODE) $(BIN)/pytest --collect-only -q -p no:cacheprovider >/dev/null || true
	touch $(STAMP)

install: $(STAMP)

run: $(STAMP)
	$(BIN)/gridfleet up

# Everything at once: the chaos soak, the static checks, the firmware's host tests built from a
# clean checkout, and every other test four at a time, all but the soak at a lower priority
# (nice). The soak spends most of its minute waiting on its fleet's clock, and its verdict counts
# a unit that moves later than two steps after a stop: its fleet must never be the one kept
# waiting for a core (five units moved 0.55 s after one, beside mypy and g++ at its priority).
# Then the broker tests on the clusters, alone: beside the four workers (a load of 8 on the two
# cores) aedes' cluster lost states and delivered a QoS 1 message twice in a fresh-clone run.
test: system-deps $(STAMP)
	$(MAKE) --no-print-directory -j4 --output-sync=target soak check firmware-checkout pytest \
		PRIORITY="nice -n 10"
	$(MAKE) --no-print-directory pytest-clusters

# Installs the missing Debian packages as root (or with password-less sudo); otherwise says the
# one command to run, and stops: no test is skipped for want of a tool.
system-deps:
	@missing=""; for p in $(DEBIAN_PACKAGES); do \
		dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -z "$$missing" ]; then exit 0; fi; \
	if [ "$$(id -u)" = 0 ]; then sudo=""; \
	elif sudo -n true 2>/dev/null; then sudo="sudo"; \
	else echo "make test needs:$$missing; install them with: sudo apt-get install$$missing" >&2; exit 2; fi; \
	echo "installing:$$missing"; \
	$$sudo env DEBIAN_FRONTEND=noninteractive apt-get update -q && \
	$$sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends$$missing

check: lint typecheck

lint: $(STAMP)
	$(PRIORITY) $(BIN)/ruff check .
	$(PRIORITY) $(BIN)/ruff format --check .
	cd dashboard && $(PRIORITY) npx --no-install eslint .

# mypy cannot follow the editable install's mapping of the checkout's folders into gridfleet.*, so
# it checks a tree of links laid out as the installed package is.
PARTS := broker coordinator robots dashboard device console alerts system bench
typecheck: $(STAMP)
	rm -rf build/typecheck && mkdir -p build/typecheck/gridfleet
	cd build/typecheck/gridfleet && ln -s ../../../gridfleet/*.py ../../../gridfleet/protocol . && \
		for part in $(PARTS); do ln -s ../../../$$part $$part; done
	cd build/typecheck && $(PRIORITY) ../../$(BIN)/mypy --config-file ../../pyproject.toml -p gridfleet
	cd build/typecheck && $(PRIORITY) ../../$(BIN)/mypy --config-file ../../pyproject.toml ../../script/gen_protocol.py

# pytest rewrites each test module's asserts on import and keeps the result beside it, unless
# PYTHONDONTWRITEBYTECODE is set (it is on these machines): then each test worker rewrote every
# test module again on every run, 7 of the 10 CPU-seconds it spent collecting. The tests keep them
# (and what their processes compile) in the __pycache__ folders git ignores.
KEEP_BYTECODE := PYTHONDONTWRITEBYTECODE=

# The tests run TEST_WORKERS at a time (pytest-xdist; 0: one at a time), each on its own ports
# (a band of them per worker: gridfleet/ports.py), folders and topic root. Most of a test's time is
# waiting on a broker, a browser or a clock, so four keep 2 cores busy. (Handing out the long
# tests first, side by side, made a vda-5050-lib test fail in 3 of 6 fresh-clone runs: its
# vehicles lost for seconds beside the other whole-system runs.)
TEST_WORKERS ?= 4
XDIST := $(if $(filter 0,$(TEST_WORKERS)),,-n $(TEST_WORKERS) --dist worksteal)

# The edit-test loop: every test but the browser, soak and slow end-to-end ones (no lint).
test-fast: $(STAMP)
	$(KEEP_BYTECODE) GRIDFLEET_FEWER_EXAMPLES=1 $(BIN)/pytest -q $(XDIST) -m "not browser and not soak and not slow"

# The one-minute chaos soak. Its verdict is about the fleet under injected faults, not about a
# machine shared with four test workers (a job still under way at the end of the drain failed a CI
# run that way, before the tests beside it ran niced): make test runs it first in line for the
# cores, on ports of a band no test worker takes (its broker comes back on the port it was given).
soak: $(STAMP)
	$(KEEP_BYTECODE) GRIDFLEET_PORT_BAND=10 $(BIN)/pytest -q -m "soak and not cluster_soak"

# Chaos on each broker cluster (aedes, RabbitMQ): the one-minute soaks, a fleet across its nodes'
# deaths (tests/system/test_cluster_node_death.py) and the page across its node's
# (test_cluster_page_node_death.py), some ten minutes (bench/README.md, "Chaos soak on a
# cluster"); not in make test.
soak-clusters: $(STAMP)
	$(KEEP_BYTECODE) GRIDFLEET_PORT_BAND=10 $(BIN)/pytest -q -m cluster_soak

# The firmware's host tests, built with g++ from the files git tracks alone (tests/device/test_firmware.py).
firmware-checkout: $(STAMP)
	$(KEEP_BYTECODE) $(PRIORITY) $(BIN)/pytest -q -m firmware

# Every test but the soak and the firmware's build (make test runs those beside it); each test that
# talks to the suite's broker on the embedded amqtt, on Debian's Mosquitto, or on both when what it
# checks is the broker's doing (`every_broker`; tests/conftest.py starts them on free loopback
# ports), in one run: as two runs, each ended waiting for its own slowest tests while cores idled.
pytest: $(STAMP)
	$(KEEP_BYTECODE) GRIDFLEET_TEST_BROKER=amqtt,mosquitto $(PRIORITY) $(BIN)/pytest $(XDIST) \
		-m "not soak and not firmware and not cluster_soak"

# The tests whose verdict is the broker's doing (`every_broker`) on the two clusters too: aedes
# instances sharing a Redis, and three RabbitMQ nodes (tests/support/aedes.py, rabbitmq.py), each
# client of a test starting on the next node. Two workers, each with a cluster of each kind, on
# port bands of their own (6 and 7) beside the main run's.
pytest-clusters: $(STAMP)
	$(KEEP_BYTECODE) GRIDFLEET_TEST_BROKER=aedes,rabbitmq GRIDFLEET_PORT_BAND=6+ $(PRIORITY) \
		$(BIN)/pytest -n 2 --dist worksteal -m "every_broker and not soak and not firmware"

# Only the tests that talk to the suite's broker, on Mosquitto alone; the tests about amqtt itself
# stay out.
test-mosquitto: system-deps $(STAMP)
	$(KEEP_BYTECODE) GRIDFLEET_TEST_BROKER=mosquitto $(BIN)/pytest $(XDIST)

firmware-test:
	@if [ -f firmware/Makefile ]; then $(MAKE) -C firmware test; fi

# Pin what `make install` gets to what this venv has now (after changing the dependencies).
constraints: $(STAMP)
	$(BIN)/pip install --quiet -e ".[test]"
	{ sed -n '1,2p' constraints.txt; $(BIN)/pip freeze --exclude-editable | grep -v '^gridfleet'; } > constraints.new
	mv constraints.new constraints.txt

# The protocol's generated files, written from gridfleet/protocol/ (a tool of the checkout, not of
# the package: script/).
schemas: $(STAMP)
	$(BIN)/python script/gen_protocol.py

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache dashboard/node_modules tests/vda5050_lib/node_modules \
		broker/aedes/node_modules
