# depotbench: the two quick-start commands are `make demo` and `make test`.
# Each sets everything up on a fresh machine (system GL library, virtualenv,
# package) and then runs; re-running skips what is already done.

PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
export MUJOCO_GL ?= egl

.PHONY: demo test test-slow lint bench system-deps browser clean

demo: $(VENV)/.installed
	$(BIN)/depotbench demo

# Test files run side by side, one worker per core (at most 4: each renders with Mesa
# and holds MuJoCo, ONNX Runtime and sometimes Ray); a file's tests stay in one worker.
SIDE_BY_SIDE := -n logical --maxprocesses 4 --dist loadfile

test: $(VENV)/.installed browser
	$(BIN)/ruff check .
	$(BIN)/python -m pytest -q $(SIDE_BY_SIDE)

test-slow: $(VENV)/.installed
	$(BIN)/python -m pytest -q -m slow $(SIDE_BY_SIDE)

lint: $(VENV)/.installed
	$(BIN)/ruff check . && $(BIN)/ruff format --check .

# MuJoCo renders off-screen through EGL (Mesa on CPU machines).
system-deps:
	@if ldconfig -p | grep -q 'libEGL.so.1 '; then :; \
	elif command -v apt-get >/dev/null; then \
		echo "installing the EGL/Mesa libraries MuJoCo renders with"; \
		SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
		$$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq libegl1 libgl1-mesa-dri libglx-mesa0 >/dev/null; \
	else echo "error: libEGL.so.1 not found; install your distribution's libegl1 and Mesa DRI drivers" >&2; exit 1; fi

# The HTML report's test opens it in headless Chromium: Debian's package, driven by Playwright
# (Playwright's own browser download cannot reach its servers from CI machines here).
browser:
	@if command -v chromium >/dev/null || command -v chromium-browser >/dev/null; then :; \
	elif command -v apt-get >/dev/null; then \
		echo "installing Chromium (the HTML report test opens the page in it)"; \
		SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
		$$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq chromium >/dev/null; \
	else echo "error: chromium not found; install your distribution's chromium package" >&2; exit 1; fi

$(VENV)/.installed: pyproject.toml | system-deps
	@$(PYTHON) -c 'import sys; assert sys.version_info >= (3, 11), "depotbench needs Python >= 3.11"'
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[dev,viz,orbslam3]'
	touch $@

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .ruff_cache
