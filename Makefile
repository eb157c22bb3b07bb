# tactex: `make demo` and `make test` each build .venv from uv.lock on a fresh machine, then run.
#
# Set-up: pip puts the pinned uv (tools/uv-requirements.txt, hash-checked) into .tools/, and uv
# builds .venv with exactly the versions in uv.lock (`uv sync --frozen`: it never re-resolves).
# EXTRAS picks the optional extras; the venv holds exactly those (uv sync removes the others).
# franka is in by default: the real-robot tests run against tactex twin (franky-sim) on loopback.
# `make test-distributed` (and CI) add the distributed extra: the Ray tests run instead of skipping.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
UV := .tools/bin/uv
EXTRAS ?= dev fast franka
OUT ?= runs/demo

empty :=
space := $(empty) $(empty)
STAMP := $(VENV)/.synced-$(subst $(space),-,$(strip $(EXTRAS)))
# uv uses the Python we name and never downloads one; UV_PROJECT_ENVIRONMENT keeps it on .venv.
UV_ENV := UV_PROJECT_ENVIRONMENT=$(VENV) UV_PYTHON_DOWNLOADS=never
SYNC := $(UV_ENV) $(UV) sync --frozen --python $(PYTHON) $(foreach e,$(EXTRAS),--extra $(e))

.PHONY: demo test bench readme-status lint lock lock-check test-latest test-franka test-distributed clean-venv \
	franka-sim-env test-franka-sim fuzz

$(UV): tools/uv-requirements.txt
	$(PYTHON) -m pip install --quiet --disable-pip-version-check --require-hashes --upgrade \
		--target .tools -r tools/uv-requirements.txt
	touch $(UV)

$(STAMP): $(UV) uv.lock pyproject.toml
	rm -f $(VENV)/.synced-*
	$(SYNC)
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/tactex demo --out $(OUT)

test: $(STAMP)
	$(VENV)/bin/ruff check tactex tests bench examples tools
	$(PY) -m pytest -q --durations=30

bench: $(STAMP)
	$(PY) bench/run.py --out bench/results.json
	$(PY) tools/readme_status.py

# The README's Status table from bench/results.json, and every figure marked <!-- fig KEY | STEPS --> in
# README.md and docs/ from its committed source (make test fails when any of them differs).
readme-status: $(STAMP)
	$(PY) tools/readme_status.py

lint: $(STAMP)
	$(VENV)/bin/ruff check tactex tests bench examples tools

# Re-resolve uv.lock deliberately (new releases within pyproject.toml's ranges), then run
# `make test` and `make bench` and commit uv.lock with what changed.
lock: $(UV)
	$(UV_ENV) $(UV) lock --upgrade --python $(PYTHON)

# Proves that .venv is exactly uv.lock: uv's own check, then the installed set against the lock.
lock-check: $(STAMP)
	$(UV_ENV) $(UV) lock --check --python $(PYTHON)
	$(SYNC) --check

# The newest releases that pyproject.toml's ranges admit, in a throw-away venv (not the lock):
# a warning of what the next `make lock` brings. Never part of CI.
test-latest: $(UV)
	rm -rf .venv-latest
	$(PYTHON) -m venv .venv-latest
	VIRTUAL_ENV=.venv-latest $(UV) pip install --quiet --python .venv-latest/bin/python \
		--resolution highest --refresh -e '.[dev,fast,franka]'
	.venv-latest/bin/python -m pytest -q -p no:cacheprovider

test-distributed:
	$(MAKE) test EXTRAS="$(EXTRAS) distributed"

# franka-sim (PyPI, an independent emulator of the Franka's FCI checks: motion limits, torque rate,
# lost commands) pins numpy 1.26 and mujoco < 3.3, so it gets an environment of its own, built from
# its own lock (tools/franka-sim/uv.lock; re-lock with `$(UV) lock --project tools/franka-sim`).
# tests/test_franka_sim.py start it as a separate process and skip while this environment is absent;
# CI builds it. docs/twin.md: what it checks and what it does not.
FS_VENV := .venv-franka-sim
FS_STAMP := $(FS_VENV)/.synced
$(FS_STAMP): $(UV) tools/franka-sim/uv.lock tools/franka-sim/pyproject.toml
	UV_PROJECT_ENVIRONMENT=$(CURDIR)/$(FS_VENV) UV_PYTHON_DOWNLOADS=never \
		$(UV) sync --frozen --project tools/franka-sim --python $(PYTHON)
	touch $(FS_STAMP)

franka-sim-env: $(FS_STAMP)

# Our real-robot paths against franka-sim with its checks enforced (robot check, joint moves, the
# wipe's and the clean's approaches, dry run, a reflex).
test-franka-sim: $(STAMP) $(FS_STAMP)
	$(PY) -m pytest -q tests/test_franka_sim.py

# Fuzz the file readers (tools/fuzz/, atheris from the fuzz extra): each for FUZZ_SECONDS, under nice,
# FUZZ_JOBS at a time. Crashes and the figures go to fuzz/ (fuzz/results.json is committed), and docs/fuzzing.md's
# figures are written from it. Not in CI.
FUZZ_SECONDS ?= 600
FUZZ_JOBS ?= 1
FUZZ_READERS ?= ply pcd_ascii pcd_binary pcd_binary_compressed npz obj stl hand_eye study_spec
fuzz:
	$(MAKE) EXTRAS="$(EXTRAS) fuzz" $(VENV)/.synced-$(subst $(space),-,$(strip $(EXTRAS) fuzz))
	mkdir -p fuzz
	printf '%s\n' $(FUZZ_READERS) | xargs -P $(FUZZ_JOBS) -I READER \
		sh -c 'nice -n 10 $(PY) tools/fuzz/run.py READER --seconds $(FUZZ_SECONDS) --out fuzz > fuzz/READER.log 2>&1'
	$(PY) tools/fuzz/summary.py fuzz
	$(PY) tools/readme_status.py

clean-venv:
	rm -rf $(VENV) .tools .venv-latest $(FS_VENV)
