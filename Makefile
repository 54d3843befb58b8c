# Two commands do everything:  make view  (install + open the viewer on the demo)  and  make test.
VENV ?= .venv
STAMP := $(VENV)/.installed

.PHONY: view test install lint bench clean

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

clean:
	rm -rf $(VENV) build *.egg-info
