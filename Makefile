# depotbench: the two quick-start commands are `make demo` and `make test`.
# Each sets everything up on a fresh machine (system GL library, virtualenv,
# package) and then runs; re-running skips what is already done.

PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
export MUJOCO_GL ?= egl
PACKAGE := -e '.[dev,viz,orbslam3,ros]'

.PHONY: demo test test-slow lint docs bench system-deps browser shells ultralytics clean readme-images

demo: $(VENV)/.installed
	$(BIN)/depotbench demo

# Test files run side by side, one worker per core (at most 4: each renders with Mesa
# and holds MuJoCo, ONNX Runtime and sometimes Ray); a file's tests stay in one worker,
# and the heaviest files go first (tests/conftest.py: FILE_SECONDS).
SIDE_BY_SIDE := -n logical --maxprocesses 4 --dist loadfile --no-loadscope-reorder

# The documentation site (MkDocs with Material, mkdocs.yml): any warning, such as a broken
# link or anchor, fails the build, and make test builds it too.
DOCS := NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict -d build/site

test: $(VENV)/.installed browser shells
	$(BIN)/ruff check .
	$(DOCS)
	$(BIN)/python tests/prepare.py
	$(BIN)/python -m pytest -q $(SIDE_BY_SIDE)

test-slow: $(VENV)/.installed ultralytics
	$(BIN)/python tests/prepare.py
	$(BIN)/python -m pytest -q -m slow $(SIDE_BY_SIDE)

lint: $(VENV)/.installed
	$(BIN)/ruff check . && $(BIN)/ruff format --check .

docs: $(VENV)/.installed
	$(DOCS)
	@echo "the site is in build/site (open build/site/index.html)"

# The README's pictures, taken again whenever the generator's output changes: the default
# scenario (seed 0, frames 5, 45 and 85: RGB | depth | instances with boxes, halved), the
# cat alone at eight headings on seeds 1 and 2, labelled with YOLOX-nano's scores, and the
# demo's sweep report (its first screen, and the full crowd's best run) in Chromium, and the
# dense maps of walking_xyz seed 21 without and with rejection, their ghosts in red; the
# documentation site shows the same files (docs/images links to assets/readme).
JPEG := $(BIN)/python -c "import sys, cv2; image = cv2.imread(sys.argv[1]); \
	image = cv2.resize(image, None, fx=float(sys.argv[3]), fy=float(sys.argv[3]), interpolation=cv2.INTER_AREA); \
	cv2.imwrite(sys.argv[2], image, [cv2.IMWRITE_JPEG_QUALITY, 85])"

readme-images: $(VENV)/.installed browser
	rm -rf build/readme
	$(BIN)/depotbench generate default -o build/readme/default --seed 0 --frames 90
	$(BIN)/depotbench preview build/readme/default --frames 5 45 85 -o build/readme/default.png
	$(JPEG) build/readme/default.png assets/readme/default_scenario.jpg 0.5
	$(BIN)/python benchmarks/actor_views.py --kind cat --seeds 1 2 --moments 1 --sheet build/readme/cat_views.png
	$(JPEG) build/readme/cat_views.png assets/readme/cat_views.jpg 1
	$(BIN)/depotbench demo -o build/readme/demo
	$(BIN)/python benchmarks/screenshots.py build/readme/demo/report/index.html \
		--top assets/readme/report_sweep.png --run "actors[0].count = 12: best" assets/readme/report_run.jpg
	$(BIN)/python benchmarks/ghost_pictures.py --scenario walking_xyz --seed 21 --frames 90 \
		--strategies none box_epipolar_flow -o build/readme/ghosts.png
	$(JPEG) build/readme/ghosts.png assets/readme/ghosts.jpg 1

# MuJoCo renders off-screen through EGL (Mesa on CPU machines).
system-deps:
	@if ldconfig -p | grep -q 'libEGL.so.1 '; then :; \
	elif command -v apt-get >/dev/null; then \
		echo "installing the EGL/Mesa libraries MuJoCo renders with"; \
		SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
		$$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq libegl1 libgl1-mesa-dri libglx-mesa0 >/dev/null; \
	else echo "error: libEGL.so.1 not found; install your distribution's libegl1 and Mesa DRI drivers" >&2; exit 1; fi

# The slow suite runs Ultralytics' own dataset check on an export (tests/test_coco_names.py).
# Ultralytics needs torch, installed only where a CPU wheel is at hand (/opt/wheels on this
# machine image: 183 MB, 695 MB installed): PyPI's default torch pulls 3 GB of CUDA libraries,
# and Ultralytics' own dependencies a second, non-headless OpenCV. Test-only: nothing at run
# time imports torch.
TORCH_CPU := $(firstword $(wildcard /opt/wheels/torch-*+cpu-*.whl))
ultralytics: $(VENV)/.installed
	@if YOLO_CONFIG_DIR=$(CURDIR)/build/ultralytics $(BIN)/python -c "import ultralytics.data.utils" 2>/dev/null; then :; \
	elif [ -n "$(TORCH_CPU)" ]; then \
		echo "installing torch (CPU) and Ultralytics for the slow suite's dataset check"; \
		$(BIN)/uv pip install -q --python $(BIN)/python "$(TORCH_CPU)" && \
		$(BIN)/uv pip install -q --python $(BIN)/python --no-deps torchvision==0.28.0 ultralytics==8.4.190 ultralytics-thop; \
	else echo "no CPU torch wheel here: the slow suite's Ultralytics check will say it did not run"; fi

# The completion test loads `depotbench completion zsh` in zsh itself (bash is always there).
shells:
	@if command -v zsh >/dev/null; then :; \
	elif command -v apt-get >/dev/null; then \
		echo "installing zsh (the shell completion test loads the script in it)"; \
		SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
		$$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq zsh >/dev/null; \
	fi

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
	@# uv resolves the same versions as pip and installs them in a fifth of the time (20 s
	@# against 97 s from a clean clone, no cache: docs/performance.md); pip where uv cannot.
	@# Bytecode is compiled at install, as pip does (uv does not): where PYTHONDONTWRITEBYTECODE
	@# is set, as in CI and container images, each process otherwise compiles every module it
	@# imports, ~1 s a process on 2 cores (the test run starts hundreds).
	$(BIN)/python -m pip install -q uv && $(BIN)/uv pip install -q --compile-bytecode --python $(BIN)/python $(PACKAGE) \
		|| $(BIN)/python -m pip install -q $(PACKAGE)
	touch $@

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .ruff_cache
