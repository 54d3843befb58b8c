# Two commands do everything:  make view  (install + open the viewer on the demo)  and  make test.
# The quick loop:  make test-fast  (every test but the slow and the window ones: under 3 min on 2 cores).
VENV ?= .venv
STAMP := $(VENV)/.installed

.PHONY: view test test-fast test-gui install lint typecheck bench clean wheel check-wheel

view: $(STAMP)
	$(VENV)/bin/npga-view $(ARGS)

# in TEST_WORKERS processes (pytest-xdist), each test file whole in one of them; TEST_WORKERS=0: in this process
TEST_WORKERS ?= 2
XDIST = $(if $(filter 0,$(TEST_WORKERS)),,-n $(TEST_WORKERS) --dist loadfile)

test: $(STAMP)
	$(VENV)/bin/python -m pytest $(XDIST) $(PYTEST_ARGS)

# markers in pyproject.toml: slow (over ~10 s each), gui (the real window under Xvfb)
test-fast: $(STAMP)
	$(VENV)/bin/python -m pytest $(XDIST) -q -m "not slow and not gui" $(PYTEST_ARGS)

test-gui: $(STAMP)
	$(VENV)/bin/python -m pytest $(XDIST) -q -m gui $(PYTEST_ARGS)

install: $(STAMP)

$(STAMP): pyproject.toml scripts/install.sh
	bash scripts/install.sh $(VENV)
	touch $(STAMP)

lint: $(STAMP)
	$(VENV)/bin/ruff check .

# mypy on both packages (settings in pyproject.toml [tool.mypy])
typecheck: $(STAMP)
	$(VENV)/bin/python -m mypy npga_core npga_view

# the sdist and the wheel in dist/ (what `pip install .` builds)
wheel: $(STAMP)
	$(VENV)/bin/python -m build --outdir dist .

# build, install the wheel into a fresh venv outside the checkout and use it from another folder (as CI does)
check-wheel: $(STAMP)
	bash scripts/check_wheel.sh $(VENV)/bin/python

clean:
	rm -rf $(VENV) build dist *.egg-info
