# Entry points for a fresh machine: `make demo`, `make test`, `make bench` and `make docs`.
# Each creates .venv (if missing or stale) and installs the project into it, then makes sure the face
# data is there: found by the data lookup, else downloaded once (ICT-FaceKit, about 400 MB, verified) into
# the user cache (`facegeom data fetch`; $FACEGEOM_CACHE, $FACEGEOM_DATA_URL for a mirror), and one public real
# take likewise unless a take is found ($FACEGEOM_TAKES, ../shared; $FACEGEOM_TAKES_URL for a mirror).
PYTHON ?= python3
VENV   ?= .venv
BIN     = $(VENV)/bin
STAMP   = $(VENV)/.facegeom-installed
DOCS_STAMP = $(VENV)/.facegeom-docs-installed

.PHONY: demo test bench fuzz face-data install images docs clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	@echo "installing facegeom and its dependencies into $(VENV) (a minute or two; pip says what it does)"
	$(BIN)/python -m pip install --progress-bar off -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

face-data: $(STAMP)
	$(BIN)/facegeom data fetch --if-missing

demo: face-data
	$(BIN)/facegeom demo

# the method comparisons at a small size (BENCH_CASES cases or sequences each, one BLAS thread), tables and plots
# into BENCH_OUT; each `facegeom bench ...` command documents its full protocol and options (--help)
BENCH_CASES ?= 5
BENCH_OUT ?= bench-out
bench: face-data
	OPENBLAS_NUM_THREADS=1 $(BIN)/facegeom bench drive --cases $(BENCH_CASES) --realistic-cases $(BENCH_CASES) --out $(BENCH_OUT)/drive
	OPENBLAS_NUM_THREADS=1 $(BIN)/facegeom bench retarget --sequences $(BENCH_CASES) --labels 10,20 --out $(BENCH_OUT)/retarget
	OPENBLAS_NUM_THREADS=1 $(BIN)/facegeom bench fit --cases $(BENCH_CASES) --realistic-cases $(BENCH_CASES) --experiments landmarks,meshes --out $(BENCH_OUT)/fit
	OPENBLAS_NUM_THREADS=1 $(BIN)/facegeom bench solve --cases $(BENCH_CASES) --frames 300 --out $(BENCH_OUT)/solve

# one test process per core (pytest-xdist; a test file stays on one process, so its fixtures are made once), each
# with single-threaded BLAS so the processes do not oversubscribe the cores. The package is compiled to bytecode
# first: hundreds of tests run `facegeom` as a child process, and where PYTHONDONTWRITEBYTECODE is set each child
# would compile every module it imports again (about 0.25 s each).
test: face-data
	$(BIN)/python -m compileall -q facegeom tests
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 $(BIN)/python -m pytest -q -n auto --dist loadfile

# long fuzz campaigns of every file reader, not part of `make test`: FUZZ_MINUTES (default 10) of CPU time per
# reader, split evenly over its seeds, one campaign per core; a table of examples, CPU and wall minutes at the end
# (from the log FUZZ_LOG). A failing example is printed as hypothesis found it, and the make exits non-zero.
FUZZ_MINUTES ?= 10
FUZZ_LOG ?= fuzz-campaign.jsonl
fuzz: $(STAMP)
	rm -f $(FUZZ_LOG)
	FACEGEOM_FUZZ_MINUTES=$(FUZZ_MINUTES) FACEGEOM_FUZZ_LOG=$(abspath $(FUZZ_LOG)) OPENBLAS_NUM_THREADS=1 \
	OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 $(BIN)/python -m pytest -q -n auto --dist worksteal \
	  tests/test_fuzz_readers.py tests/test_fuzz_gltf_rig.py -k "mutated or fuzzed or changed"; \
	status=$$?; $(BIN)/python -m tests.fuzzing $(FUZZ_LOG); exit $$status

# the viewer's README images (renders of the ICT face data: generated here, never committed)
images: $(STAMP)
	$(BIN)/python -m facegeom.viewer.make_images --out docs/images

# the documentation site into site/: the pictures from the face data (docs/make_images.py; redrawn only when
# the code or the data changed), then `mkdocs build --strict` (every warning is an error)
$(DOCS_STAMP): pyproject.toml $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[docs]'
	touch $(DOCS_STAMP)

docs: face-data $(DOCS_STAMP)
	$(BIN)/python docs/make_images.py --out docs/images
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

clean:
	rm -rf $(VENV) build *.egg-info site
