# Two entry points for a fresh machine: `make demo` and `make test`.
# Each creates .venv (if missing or stale) and installs the project into it.
PYTHON ?= python3
VENV   ?= .venv
BIN     = $(VENV)/bin
STAMP   = $(VENV)/.facegeom-installed

.PHONY: demo test install images clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/facegeom demo

test: $(STAMP)
	$(BIN)/python -m pytest -q

# the viewer's README images (renders of the ICT face data: generated here, never committed)
images: $(STAMP)
	$(BIN)/python -m facegeom.viewer.make_images --out docs/images

clean:
	rm -rf $(VENV) build *.egg-info
