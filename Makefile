# railhil — the two commands: `make run` and `make test` (both bootstrap .venv).
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: build run test test-slow test-vcan fuzz bench profile soak lint docs docs-figures lock vcan clean

# the versions CI tested come from constraints.txt (make lock writes it)
$(STAMP): pyproject.toml constraints.txt
	@command -v $(PYTHON) >/dev/null || { echo "error: $(PYTHON) not found; install Python 3.11 or run 'make PYTHON=python3 ...'"; exit 2; }
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip 'setuptools>=77' wheel
	RAILHIL_PURE=1 $(PY) -m pip install --quiet -c constraints.txt -e '.[test,docs]'
	touch $(STAMP)

# the modules mypyc compiles (hil/build.py COMPILED): the install above is pure Python (its build has none of
# the dependencies whose types mypyc reads); here they are compiled in place by the venv's pinned mypy, with
# every dependency installed, and again when one of them changed since (`make build`; every target that needs
# the install). RAILHIL_PURE=1 make ... keeps it pure
COMPILED_SRC := $(shell grep -o '"[a-z_]*/[a-z0-9_/]*\.py"' hil/build.py | tr -d '"')
BUILT := $(VENV)/.built
$(BUILT): $(STAMP) $(COMPILED_SRC) hil/build.py setup.py
	$(PY) -m pip install --quiet --no-deps --no-build-isolation -c constraints.txt -e .
	touch $(BUILT)

## make build: compile the hot modules again with mypyc (after an edit of one of them; `make test` and `make
## run` do it too); the build that runs: `railhil --version`
build: $(BUILT)
	@$(VENV)/bin/railhil --version

## make run: the default scenario as a real-time HIL (the ECUs in one process, the plant in another, on
## udp_multicast; the verdict against the real-time budget and the machine's own floor in the summary)
run: $(BUILT)
	$(VENV)/bin/railhil run scenarios/default.toml --realtime --fallback-lockstep

## make test: ruff (as make lint: a lint error fails the build), mypy --strict on the compiled modules, then
## the test suite on the compiled build (excludes tests marked slow): the lockstep and unit tests on TEST_JOBS
## pytest-xdist workers (default: one per core), the golden traces again on the pure build (RAILHIL_PURE=1:
## byte-identical to the compiled one), then the real-time tests alone, one at a time, so that their node
## processes do not compete with other tests for the CPUs. Under 15 minutes on a 2-core machine: what takes
## longer is marked slow
## (worksteal: an idle worker takes queued tests from the busy one, so that no long test ends the run alone)
TEST_JOBS ?= auto
LINT_PATHS = firmware_py plant_sim hil tests bench dbc examples tools
test: $(BUILT)
	$(VENV)/bin/ruff check $(LINT_PATHS)
	$(VENV)/bin/mypy
	$(PY) -m pytest -q -rs -n $(TEST_JOBS) --dist worksteal -m "not slow and not realtime and not socketcan"
	RAILHIL_PURE=1 $(PY) -m pytest -q -rs -n $(TEST_JOBS) tests/test_golden.py
	$(PY) -m pytest -q -rs -m "realtime and not slow and not socketcan"

## make test-slow: the long suites too
test-slow: $(BUILT)
	$(PY) -m pytest -q -rs -n $(TEST_JOBS) --dist worksteal -m "not realtime and not socketcan"
	$(PY) -m pytest -q -rs -m "realtime and not socketcan"

## make test-vcan: the SocketCAN tests (marked socketcan: tests/can/test_socketcan.py) on vcan0 and vcan1,
## on this machine where its kernel has SocketCAN, else in a Debian kernel booted under qemu by virtme-ng with
## this checkout and its .venv inside, read-only (software emulation; VCAN_KVM=1 for KVM); tools/vcan_suite.py.
## Installs what it needs where missing: Debian's qemu-system-x86, linux-image-amd64, busybox-static and
## can-utils (apt-get, as root or through sudo) and virtme-ng (the vcan extra). The suite's JUnit XML:
## runs/test-vcan/junit.xml. Under 15 minutes on a 2-core machine
test-vcan: $(STAMP)
	$(PY) tools/vcan_suite.py

## make fuzz: 10^6 fuzzed frames through decode + SecOC + E2E, twice: the protocol layers alone and the
## node runtime of the default train (RAILHIL_FUZZ_FRAMES=N for more, RAILHIL_FUZZ_SEED=S for another seed)
fuzz: $(STAMP)
	$(PY) -m pytest -q -s -m slow -k fuzzed tests/can/test_e2e.py tests/runtime/test_fuzz.py

## make bench: speed figures, railhil next to plain python-can/cantools, measured in one run, then every
## figure that has a goal next to it. Not timed; the 10^6-frame bus run takes minutes: shorten it with
## `make bench BENCH_FRAMES=100000`; BENCH_RT_S=S cuts the real-time runs (default: the whole scenario, about
## 30 s each), BENCH_ONLY=bench_realtime,bench_bus runs only those
bench: $(STAMP)
	$(PY) bench/run_all.py

## make profile: where the default lockstep run's wall goes, per component (controllers, node dispatch, event
## loop, bus, codec, E2E, SecOC, plant, trace writer): py-spy samples bench_lockstep's traced run, on the
## build that runs (the compiled one: its native stacks; RAILHIL_PURE=1 make profile: the pure one); installs
## py-spy (the profile extra's one package) where missing. PROFILE_RUNS=N runs counted (default 8)
PROFILE_RUNS ?= 8
profile: $(BUILT)
	test -x $(VENV)/bin/py-spy || $(PY) -m pip install --quiet 'py-spy>=0.3.14'
	$(PY) bench/profile_lockstep.py --runs $(PROFILE_RUNS)

## make soak: 10 consecutive real-time runs of the default scenario (about 6 minutes), each judged against
## the [realtime.deadline] budget; the count held and each run's misses (SOAK_RUNS=N for another count)
soak: $(STAMP)
	$(PY) bench/soak_realtime.py

## make lock: constraints.txt, the dependency versions make installs: resolved by uv (fast, reproducible)
## from pyproject.toml for Python 3.11, preferring the versions of the current .venv (those the tests passed
## with). Run it after changing a dependency, then make test, and commit constraints.txt with the change
lock: $(STAMP)
	$(PY) -m pip install --quiet uv
	$(PY) -m pip freeze --exclude-editable | grep -v '^uv==' > $(VENV)/tested.txt
	$(VENV)/bin/uv pip compile pyproject.toml --extra test --extra docs --extra vcan --python-version 3.11 --no-annotate \
	  --constraint $(VENV)/tested.txt -o constraints.txt

## make docs: the docs site under docs/ built strictly into site/ (a warning is an error)
docs: $(STAMP)
	$(VENV)/bin/mkdocs build --strict

## make docs-figures: the docs' figures and printed outputs made again by the code as it is (docs/img/plot.png,
## the lockstep run's printed summary and kpis.json in README.md and docs/, make run's output in getting
## started, docs/img/report.png in headless Chromium); a lockstep and a real-time run, about a minute
docs-figures: $(STAMP)
	$(PY) docs/hooks/figures.py

lint: $(STAMP)
	$(VENV)/bin/ruff check $(LINT_PATHS)

## make vcan: create vcan0 where the kernel has SocketCAN (needs root)
vcan:
	@if ! modprobe vcan 2>/dev/null && ! [ -d /sys/module/vcan ]; then \
	  echo "make vcan: this kernel has no vcan module (SocketCAN unavailable); use the default udp_multicast bus or --lockstep"; exit 1; fi
	@ip link show vcan0 >/dev/null 2>&1 || ip link add dev vcan0 type vcan
	ip link set up vcan0
	@echo "vcan0 is up: railhil run SCENARIO --realtime --interface socketcan --channel vcan0"

clean:
	rm -rf $(VENV) runs site .pytest_cache
