# Two entry points for a fresh machine: `make demo` and `make test`.
# Each creates .venv (if missing or stale) and installs the project into it, then makes sure the face
# data is there: found by the data lookup, else downloaded once (ICT-FaceKit, about 400 MB, verified) into
# the user cache (`facegeom data fetch`; $FACEGEOM_CACHE, $FACEGEOM_DATA_URL for a mirror), and one public real
# take likewise unless a take is found ($FACEGEOM_TAKES, ../shared; $FACEGEOM_TAKES_URL for a mirror).
PYTHON ?= python3
VENV   ?= .venv
BIN     = $(VENV)/bin
STAMP   = $(VENV)/.facegeom-installed

.PHONY: demo test face-data install images clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

face-data: $(STAMP)
	$(BIN)/facegeom data fetch --if-missing

demo: face-data
	$(BIN)/facegeom demo

test: face-data
	$(BIN)/python -m pytest -q

# the viewer's README images (renders of the ICT face data: generated here, never committed)
images: $(STAMP)
	$(BIN)/python -m facegeom.viewer.make_images --out docs/images

clean:
	rm -rf $(VENV) build *.egg-info
