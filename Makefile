# Two commands do everything:  make view  (install + open the viewer on the demo)  and  make test.
VENV ?= .venv
STAMP := $(VENV)/.installed

.PHONY: view test install lint typecheck bench clean wheel check-wheel

view: $(STAMP)
	$(VENV)/bin/npga-view $(ARGS)

test: $(STAMP)
	$(VENV)/bin/python -m pytest $(PYTEST_ARGS)

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
