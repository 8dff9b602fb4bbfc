"""``facegeom data examples DIR`` and the README section that runs on its files.

(a) the command writes every example file, each reads back with facegeom's own readers, the same face data
    gives the same bytes, a second run refuses without ``--force``, a bad DIR is one line and exit 2, and a
    failed write leaves nothing behind;
(b) every ``facegeom ...`` line of the ```bash blocks of the README section "Try it: every task on example
    inputs" runs as written in a folder made by ``facegeom data examples`` (exit 0, every output it names
    exists); the ``view`` commands skip, with the reason, only where no headless renderer can start;
(c) every ``facegeom ...`` command written inline in the README's prose (without placeholders) names a
    subcommand and options the command line has (click's ``make_context``, nothing invoked);
(d) the how-to pages ``docs/howto/*.md`` the same way: each page's ```bash blocks run as written, in order, in a
    fresh copy of a folder made by ``facegeom data examples`` (exit 0, every output named exists; ``view`` commands
    must use ``--screenshot`` and skip, with the reason, only where no headless renderer starts); then its
    ```python blocks run in that folder, in order, each as its own ``python -c`` with the face data (exit 0);
    every inline ``facegeom ...`` command of its prose parses as in (c).

Convention: a block whose fence line directly follows a line ``<!-- not run -->`` (invisible on the site) is not
run — for examples on the user's own files (``head.obj``) and file contents (TOML). Its ``facegeom ...`` lines are
parsed as in (c) instead, and a marked ```python block is compiled (syntax checked).

Runtime: a command already run successfully in this session — by the README section or an earlier page — with
the same words on input files of the same bytes (the arguments that name existing files or folders) is not run
again: the files it wrote then (every file it created or changed in its folder) are copied into this folder and
its result is reused. The example folders are byte for byte the same, so this is the same command on the same
inputs; pages share the README's long commands (``facegeom transfer face.obj``, the point-cloud identity) for free.
"""
from __future__ import annotations

import hashlib
import os
import re
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import click
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
HOWTO = ROOT / "docs" / "howto"
HOWTO_PAGES = sorted(HOWTO.glob("*.md"))
HOWTO_SECTIONS = ("## Try it", "## With your own files", "## What you get", "## When it goes wrong", "## Further")
NOT_RUN = "<!-- not run -->"
HEADING = "## Try it: every task on example inputs"
OUTPUT_OPTIONS = ("-o", "--output", "--out", "--screenshot", "--mesh-out", "--rig-out", "--markers-out", "--map",
                  "--report", "--save-key-labels")
TASKS = ("drive", "retarget", "animate", "solve", "fit", "identity", "clean", "decimate", "crop", "batch",
         "view drive", "view retarget", "view animate", "view fit", "bench drive", "bench retarget",
         "bench animate", "bench fit", "bench solve")


# --------------------------------------------------------------------------- reading the README


def section(text: str, heading: str = HEADING) -> str:
    """The README section under ``heading``, up to the next ``## `` heading."""
    start = text.index(heading + "\n")
    end = text.find("\n## ", start + len(heading))
    return text[start:] if end < 0 else text[start:end]


def bash_lines(text: str) -> list[str]:
    """The command lines of the section's ```bash blocks, ``\\`` continuations joined into one line each."""
    lines = []
    for block in re.findall(r"^```bash\n(.*?)^```$", text, flags=re.DOTALL | re.MULTILINE):
        pending = ""
        for raw in block.splitlines():
            line = pending + raw.strip()
            if line.endswith("\\"):
                pending = line[:-1].rstrip() + " "
                continue
            pending = ""
            if line:
                lines.append(line)
        assert not pending, f"a README command ends with a line continuation: {pending!r}"
    return lines


def section_commands(text: str) -> list[str]:
    """Every ``facegeom ...`` command of the section's bash blocks (a line may chain ``&& cd DIR``)."""
    out = []
    for line in bash_lines(section(text)):
        for part in line.split("&&"):
            part = part.strip()
            if part.startswith("facegeom "):
                out.append(part)
    return out


def without_comment(command: str) -> str:
    """``command`` without its trailing ``# comment``, whitespace normalised."""
    return " ".join(shlex.split(command, comments=True))


SECTION_TEXT = section(README.read_text(encoding="utf-8"))
COMMANDS = section_commands(README.read_text(encoding="utf-8"))


# --------------------------------------------------------------------------- reading the how-to pages


def runnable(text: str) -> str:
    """``text`` without its blocks marked ``<!-- not run -->`` (the marker line and the block)."""
    return re.sub(rf"^{re.escape(NOT_RUN)}\n```\w*\n.*?^```$\n?", "", text, flags=re.DOTALL | re.MULTILINE)


def marked_blocks(text: str, lang: str) -> list[str]:
    """The bodies of the ```lang blocks marked ``<!-- not run -->``."""
    return re.findall(rf"^{re.escape(NOT_RUN)}\n```{lang}\n(.*?)^```$", text, flags=re.DOTALL | re.MULTILINE)


def python_blocks(text: str) -> list[str]:
    """The bodies of the ```python blocks of ``text``."""
    return re.findall(r"^```python\n(.*?)^```$", text, flags=re.DOTALL | re.MULTILINE)


def facegeom_parts(lines: list[str]) -> list[str]:
    """The ``facegeom ...`` commands of command lines (a line may chain commands with ``&&``)."""
    parts = (p.strip() for line in lines for p in line.split("&&"))
    return [p for p in parts if p.startswith("facegeom ")]


def page_commands(text: str) -> list[str]:
    """Every ``facegeom ...`` command of a how-to page's ```bash blocks that run (not marked)."""
    return facegeom_parts(bash_lines(runnable(text)))


PAGES = {p.stem: p.read_text(encoding="utf-8") for p in HOWTO_PAGES}
PAGE_COMMANDS = [c for text in PAGES.values() for c in page_commands(text)]
TRY_TEXT = SECTION_TEXT + "".join(runnable(text) for text in PAGES.values())  # all the commands users run as written


def test_the_page_extractor():
    text = ("# p\n## Try it\n```bash\nfacegeom drive a.obj m.csv \\\n  -o x.ply   # c\n```\n"
            "<!-- not run -->\n```bash\nfacegeom transfer head.obj -o h.glb\n```\n"
            "```python\nprint(1)\n```\n<!-- not run -->\n```python\nimport nothing_here\n```\n")
    assert page_commands(text) == ["facegeom drive a.obj m.csv -o x.ply   # c"]
    assert marked_blocks(text, "bash") == ["facegeom transfer head.obj -o h.glb\n"]
    assert python_blocks(runnable(text)) == ["print(1)\n"]
    assert marked_blocks(text, "python") == ["import nothing_here\n"]


@pytest.mark.parametrize("page", sorted(PAGES), ids=str)
def test_howto_page_follows_the_template(page):
    text = PAGES[page]
    assert text.startswith("# "), f"{page}.md: starts with its title"
    at = [text.find("\n" + h + "\n") for h in HOWTO_SECTIONS]
    assert all(i >= 0 for i in at) and at == sorted(at), f"{page}.md: sections {HOWTO_SECTIONS} in this order"
    try_it = section(text, "## Try it")
    assert bash_lines(runnable(try_it)), f"{page}.md: `Try it` has commands that run"
    for line in bash_lines(runnable(text)):
        assert line.startswith("facegeom "), f"{page}.md: a command that runs starts with `facegeom`: {line!r}"
    assert text.count(NOT_RUN) == sum(len(marked_blocks(text, lang)) for lang in ("bash", "python", "toml", "text")), \
        f"{page}.md: every `{NOT_RUN}` line is followed directly by a fenced block"
    assert not re.search(r"\b[Ii]ssues? \d|\bstop \d", text), f"{page}.md: user-facing text names no issue numbers"
    for code in marked_blocks(text, "python"):  # not run, but valid Python
        compile(code, f"docs/howto/{page}.md", "exec")


def test_the_extractor():
    text = ("# t\n## Try it: every task on example inputs\n```bash\nfacegeom data examples ex && cd ex\n```\n"
            "text `facegeom nope`\n```bash\nfacegeom clean a.obj b.obj \\\n    --map m.csv   # c\nls\n```\n"
            "## Next\n```bash\nfacegeom later\n```\n")
    assert section_commands(text) == ["facegeom data examples ex", "facegeom clean a.obj b.obj --map m.csv   # c"]
    assert without_comment("facegeom clean a.obj b.obj --map m.csv   # c") == "facegeom clean a.obj b.obj --map m.csv"


def test_the_section_covers_every_task():
    """Every task has a command users run as written: in the README section or on a how-to page."""
    lines = bash_lines(SECTION_TEXT)
    assert lines[1] == "facegeom data examples examples && cd examples", "the section starts by making the folder"
    words = [shlex.split(c, comments=True) for c in COMMANDS + PAGE_COMMANDS]
    heads = {" ".join(w[1:3]) for w in words} | {w[1] for w in words}
    missing = [t for t in TASKS if t not in heads]
    assert not missing, f"tasks without a command in the README section or a how-to page: {missing}"
    joined = "\n".join(COMMANDS + PAGE_COMMANDS)
    for needle in ("-m all", "--rig ict", "-o anim.npz", "capture.c3d -o curves.npz", "capture.c3d -o curves.glb",
                   "capture.c3d -o curves.csv", "photo.pts --image photo.png", "scan.ply", "landmarks.csv",
                   "--screenshot"):
        assert needle in joined, needle
    for c in COMMANDS + PAGE_COMMANDS:
        if shlex.split(c, comments=True)[1] == "view":
            assert "--screenshot" in shlex.split(c, comments=True), f"a view command must render headless: {c}"


ACTIVATE = ["source", ".venv/bin/activate"]
"""The Try-it section's first line: the virtualenv ``make demo`` and ``make test`` make, activated."""


def test_try_it_activates_the_virtualenv_first():
    """The section works as pasted into a new shell: its first command activates ``.venv`` (where ``facegeom``
    is), and from the checkout's root, where that virtualenv is, the activated shell finds ``facegeom``."""
    lines = bash_lines(SECTION_TEXT)
    assert shlex.split(lines[0], comments=True) == ACTIVATE, lines[0]
    venv = README.parent / ".venv" / "bin" / "activate"
    if not venv.is_file():
        pytest.skip(f"no virtualenv at {venv.parent.parent} (make test makes it)")
    r = subprocess.run(["bash", "--noprofile", "--norc", "-c", f"{lines[0]} && command -v facegeom && facegeom --version"],
                       cwd=README.parent, env={"PATH": "/usr/bin:/bin", "HOME": os.environ.get("HOME", "/tmp")},
                       capture_output=True, text=True, timeout=60, check=False)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[0] == str(venv.parent / "facegeom") and "facegeom, version" in r.stdout


def test_readme_txt_commands_are_in_the_section():
    from facegeom.pipelines.examples import FILES

    ran = {without_comment(c) for c in COMMANDS + PAGE_COMMANDS}
    for f in FILES:
        assert without_comment(f.command) in ran, \
            f"README.txt's command for {f.name} is neither in the README section nor on a how-to page: {f.command}"


# --------------------------------------------------------------------------- (a) the command


def _env(face_model) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}  # headless views
    env["FACEGEOM_DATA"] = face_model.path
    # one BLAS thread per command: on a busy 2-core machine, BLAS threads fighting other processes for the
    # cores made single commands 5-7x slower (a point-cloud fit 31 s against 4.3 s; bench fit 34 s against 6 s)
    for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env[k] = "1"
    return env


def facegeom(args, cwd, env, timeout=300) -> subprocess.CompletedProcess:
    """Run ``python -m facegeom ARGS`` in ``cwd``."""
    return subprocess.run([sys.executable, "-m", "facegeom", *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=timeout, check=False)


def digests(folder: Path) -> dict[str, str]:
    """SHA-256 of every file below ``folder`` by relative path."""
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def made(tmp_path_factory, face_model):
    """A folder written by ``facegeom data examples`` (a subprocess, as a user runs it)."""
    folder = tmp_path_factory.mktemp("made") / "examples"
    r = facegeom(["data", "examples", str(folder)], cwd=folder.parent, env=_env(face_model))
    assert r.returncode == 0, r.stderr
    assert "README.txt" in r.stdout and "Traceback" not in r.stderr
    return folder


def test_writes_every_file_and_nothing_else(made):
    from facegeom.pipelines.examples import example_paths

    names = sorted(digests(made))
    assert names == sorted(example_paths())
    assert not [p for p in made.rglob(".*")], "temporary files left behind"
    assert len(example_paths()) >= 30
    assert sum(p.stat().st_size for p in made.rglob("*") if p.is_file()) < 5e6, "the examples should stay small"


def test_every_file_reads_back(made, face_model):
    from facegeom.io import (
        image_size,
        read_landmarks,
        read_marker_sequence,
        read_markers,
        read_mesh,
        read_point_cloud,
        read_pts,
        read_retarget_inputs,
        read_take,
        read_weights,
    )
    from facegeom.constants import FACE_AREA
    from facegeom.model import ict80
    from facegeom.pipelines.batch import load_job
    from facegeom.pipelines.examples import FILES, JOB_FITS, TAKE_FPS

    n = face_model.n_vertices
    V, F = read_mesh(made / "face.obj")
    assert V.shape == (n, 3) and np.array_equal(F, face_model.triangles)
    assert np.abs(V - face_model.neutral).max() > 0.1, "face.obj is an identity, not the generic face"
    T, _ = read_mesh(made / "target.obj")
    ids, pos = read_markers(made / "markers.csv", n_vertices=n)
    assert np.array_equal(ids, ict80(face_model)) and np.allclose(pos, T[ids])
    assert np.linalg.norm(pos - V[ids], axis=1).max() > 0.3, "the markers move (cm)"

    for name in ("landmarks.csv", "neutral_front.csv", "neutral_side.csv", "job/landmarks/01.csv"):
        lid, uv = read_landmarks(made / name)
        assert np.array_equal(lid, face_model.landmarks), name
        assert (uv > 0).all() and (uv[:, 0] < 640).all() and (uv[:, 1] < 480).all(), name
    pts = read_pts(made / "photo.pts")
    assert pts.shape == (68, 2) and (pts > 0).all() and (pts[:, 0] < 640).all() and (pts[:, 1] < 480).all()
    assert image_size(made / "photo.png") == (640, 480)

    cloud = read_point_cloud(made / "scan.ply")
    size = np.ptp(cloud, axis=0).max()
    assert 1000 < cloud.shape[0] < 6000 and 100 < size < 300, "a partial face scan in mm"
    Vs, Fs = read_mesh(made / "scan_mesh.obj")
    assert Vs.shape[0] > n and Fs.shape[0] > F.shape[0]

    take = read_take(made / "take.csv")
    assert take.weights.shape[0] == 120 and take.weights.max() > 0.5
    cap = read_marker_sequence(made / "capture.c3d")
    assert cap.positions.shape == (120, 80, 3) and cap.unit == "mm" and cap.fps == pytest.approx(TAKE_FPS)
    assert np.isnan(cap.positions).any() and not np.isnan(cap.positions).all(axis=2).all(axis=0).any()
    assert cap.names == tuple(f"v{i}" for i in ict80(face_model))
    src, _, lab, _ = read_retarget_inputs(made / "actor.csv", made / "labels.csv")
    assert src.positions.shape == (60, 80, 3) and lab.n_frames == 6 and src.names == cap.names

    job = load_job(made / "job.toml")
    assert job.operation == "fit" and job.output.resolve() == (made / "job" / "fit").resolve()
    truth = [read_weights(made / f"job/truth/{k:02d}.json", face_model.expression_names) for k in range(1, 9)]
    assert len(truth) == JOB_FITS and all(0 < (w > 0).sum() <= 5 for w in truth)

    text = (made / "README.txt").read_text(encoding="utf-8")
    for f in FILES:
        assert f.name in text and f.command in text, f.name
    nose = int(face_model.landmarks[30])
    assert f"--from-vertices {nose} " in text and f"--from-vertices {nose} " in TRY_TEXT, "the nose tip's vertex"
    assert f"--id-range 0:{FACE_AREA} " in TRY_TEXT


def test_second_run_refuses_then_force_rewrites_the_same_bytes(made, face_model):
    env = _env(face_model)
    before = digests(made)
    r = facegeom(["data", "examples", str(made)], cwd=made.parent, env=env)
    assert r.returncode == 2 and r.stdout == ""
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert r.stderr.startswith(f"facegeom: error: {made}: already holds example files") and "--force" in r.stderr
    assert digests(made) == before
    r = facegeom(["data", "examples", str(made), "--force"], cwd=made.parent, env=env)
    assert r.returncode == 0, r.stderr
    assert digests(made) == before, "the same face data gives the same files"


def test_other_files_in_the_folder_are_fine(tmp_path, face_model):
    (tmp_path / "notes.txt").write_text("mine")
    r = facegeom(["data", "examples", str(tmp_path)], cwd=tmp_path, env=_env(face_model))
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "notes.txt").read_text() == "mine" and (tmp_path / "face.obj").is_file()


@pytest.mark.parametrize("where", ["a-file", "a-file/below", "folder-in-the-way"])
def test_bad_folder_is_one_line(tmp_path, face_model, where):
    (tmp_path / "a-file").write_text("x")
    (tmp_path / "folder-in-the-way" / "face.obj").mkdir(parents=True)
    r = facegeom(["data", "examples", where], cwd=tmp_path, env=_env(face_model))
    assert r.returncode == 2 and r.stdout == ""
    assert len(r.stderr.strip().splitlines()) == 1 and r.stderr.startswith(f"facegeom: error: {where}: "), r.stderr
    assert "Traceback" not in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-file", "folder-in-the-way"]


def test_a_failed_write_leaves_nothing(tmp_path, face_model, monkeypatch):
    import facegeom.pipelines.examples as examples

    def broken(path, *args, **kwargs):
        Path(path).write_bytes(b"half a file")
        raise OSError(28, "No space left on device", str(path))

    monkeypatch.setattr(examples, "write_c3d", broken)
    (tmp_path / "kept").mkdir()
    (tmp_path / "kept" / "notes.txt").write_text("mine")
    for target in (tmp_path / "new" / "examples", tmp_path / "kept"):
        with pytest.raises(OSError):
            examples.write_examples(face_model, target)
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*")) == ["kept", "kept/notes.txt"]


def test_the_data_option_is_honoured(tmp_path, face_model):
    env = _env(face_model)
    env["FACEGEOM_DATA"] = str(tmp_path / "nowhere")
    r = facegeom(["--data", face_model.path, "data", "examples", "ex"], cwd=tmp_path, env=env)
    assert r.returncode == 0, r.stderr
    r = facegeom(["--data", str(tmp_path / "nowhere"), "data", "examples", "ex2"], cwd=tmp_path, env=env)
    assert r.returncode == 2 and "nowhere" in r.stderr and not (tmp_path / "ex2").exists()


# --------------------------------------------------------------------------- (b) the README commands


def outputs_of(args: list[str]) -> list[str]:
    """The files and folders a command names as outputs (``-o``, ``--out``, ``--screenshot``, ...; OUT of
    ``clean / decimate / crop``)."""
    out = [args[i + 1] for i, a in enumerate(args[:-1]) if a in OUTPUT_OPTIONS]
    out += [a.split("=", 1)[1] for a in args if a.startswith(tuple(o + "=" for o in OUTPUT_OPTIONS if o[1] == "-"))]
    if args and args[0] in ("clean", "decimate", "crop") and len(args) > 2 and not args[2].startswith("-"):
        out.append(args[2])
    return out


def test_outputs_of():
    assert outputs_of(["drive", "a.obj", "m.csv", "-o", "x.ply"]) == ["x.ply"]
    assert outputs_of(["clean", "a.obj", "b.obj", "--map", "m.csv", "--report=r.json"]) == ["m.csv", "r.json", "b.obj"]
    assert outputs_of(["view", "fit", "--screenshot", "v.png"]) == ["v.png"]


def _files(folder: Path) -> dict[str, tuple[int, int]]:
    """Size and modification time of every file below ``folder`` by relative path."""
    return {p.relative_to(folder).as_posix(): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in folder.rglob("*") if p.is_file()}


def _inputs(args: list[str], cwd: Path) -> tuple:
    """SHA-256 of the existing files and folders that ``args`` name in ``cwd``, outputs left out."""
    outs = set(outputs_of(args))
    named = [a for a in args if a not in outs] + [a.split("=", 1)[1] for a in args if a.startswith("--") and "=" in a]
    found = []
    for a in dict.fromkeys(named):
        path = cwd / a
        if a.startswith("-") or not path.exists():
            continue
        files = [path] if path.is_file() else sorted(q for q in path.rglob("*") if q.is_file())
        found.append((a, tuple((q.relative_to(cwd).as_posix(), hashlib.sha256(q.read_bytes()).hexdigest())
                                for q in files)))
    return tuple(found)


@pytest.fixture(scope="module")
def done():
    """Commands run successfully so far in this module: ``{(args, inputs): (folder, written files, result)}``."""
    return {}


def run_once(args: list[str], cwd: Path, env: dict, done: dict) -> tuple[subprocess.CompletedProcess, bool]:
    """Run ``facegeom ARGS`` in ``cwd`` -> ``(result, reused)``; a command already run successfully with the same
    arguments on inputs of the same bytes is not run again: the files it wrote are copied here (module docstring)."""
    key = (tuple(args), _inputs(args, cwd))
    if key in done and done[key][0] != cwd:  # in its own folder a command runs again (a second batch run resumes)
        folder, written, r = done[key]
        if all((folder / rel).is_file() and _sha(folder / rel) == sha for rel, sha in written):  # not overwritten since
            for rel, _ in written:
                (cwd / rel).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(folder / rel, cwd / rel)
            return r, True
    before = _files(cwd)
    r = facegeom(args, cwd=cwd, env=env)
    if r.returncode == 0:
        written = [(rel, _sha(cwd / rel)) for rel, sig in _files(cwd).items() if before.get(rel) != sig]
        done[key] = (cwd, written, r)
    return r, False


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def readme_run(tmp_path_factory, face_model, done):
    """Run the section's commands in order in a fresh folder, as written (``cd`` moves the runner):
    ``[(command, args, folder, result, seconds)]``."""
    env = _env(face_model)
    cwd = tmp_path_factory.mktemp("readme")
    runs = []
    t_all = time.perf_counter()
    for line in bash_lines(SECTION_TEXT):
        for part in (p.strip() for p in line.split("&&")):
            words = shlex.split(part, comments=True)
            if not words:
                continue
            if words[0] == "cd":
                cwd = cwd / words[1]
                assert cwd.is_dir(), f"README: `{line}`: no folder {cwd}"
                continue
            if words == ACTIVATE:  # this test runs facegeom with its own interpreter (test_try_it_activates)
                continue
            assert words[0] == "facegeom", f"README section: only facegeom commands and cd run here: {line!r}"
            t = time.perf_counter()
            r, _ = run_once(words[1:], cwd, env, done)
            runs.append((part, words[1:], cwd, r, time.perf_counter() - t))
    print(f"\nREADME section: {len(runs)} commands in {time.perf_counter() - t_all:.1f} s")
    for part, _, _, r, s in runs:
        print(f"  {s:5.1f} s  rc={r.returncode}  {part}")
    return runs


def _failure(part, cwd, r, where="README") -> str:
    return (f"{where} command failed (exit {r.returncode}) in {cwd}:\n  {part}\n"
            f"stdout (end):\n{r.stdout[-1500:]}\nstderr (end):\n{r.stderr[-2500:]}")


def _check(runs, where="README") -> list[str]:
    problems = []
    for part, args, cwd, r, _ in runs:
        if r.returncode != 0:
            problems.append(_failure(part, cwd, r, where))
            continue
        missing = [o for o in outputs_of(args) if not (cwd / o).exists()]
        if missing:
            problems.append(f"{where} command exited 0 but did not write {', '.join(missing)} in {cwd}:\n  {part}")
    return problems


def test_readme_commands_run(readme_run):
    runs = [x for x in readme_run if x[1][0] != "view"]
    assert len(runs) >= 30
    problems = _check(runs)
    assert not problems, "\n\n".join(problems)
    for _, args, cwd, _, _ in runs:
        if args[0] == "batch":  # its output folder is in the job file
            assert (cwd / "job" / "fit" / "batch-summary.csv").is_file(), "facegeom batch job.toml wrote no summary"


def test_readme_view_commands_render_headless(readme_run):
    runs = [x for x in readme_run if x[1][0] == "view"]
    assert len(runs) >= 4
    no_renderer = [r for *_, r, _ in runs if r.returncode != 0 and "could not start a renderer" in r.stderr]
    if no_renderer:
        pytest.skip(f"headless rendering unavailable here: {no_renderer[0].stderr.strip()}")
    problems = _check(runs)
    assert not problems, "\n\n".join(problems)
    for _, args, cwd, r, _ in runs:
        png = cwd / outputs_of(args)[0]
        assert png.stat().st_size > 10_000, f"{png.name}: an almost empty image"


# --------------------------------------------------------------------------- (c) commands in the prose


PLACEHOLDER = re.compile(r"(^|[^A-Za-z0-9_-])([A-Z][A-Z0-9_]+|[A-Z])(?![a-z])")


def inline_commands(text: str) -> list[str]:
    """``facegeom ...`` written inline (in single backticks) in the README's prose, without placeholders."""
    prose = re.sub(r"^```.*?^```$", "", text, flags=re.DOTALL | re.MULTILINE)
    out = []
    for span in re.findall(r"`(facegeom [^`]+)`", prose):
        span = " ".join(span.split())
        if any(s in span for s in ("...", "[", "|", " / ")) or PLACEHOLDER.search(span):
            continue  # syntax with placeholders, alternatives or optional parts
        out.append(span)
    return out


def parse_command(words: list[str]) -> None:
    """Resolve ``facegeom WORDS`` against the click command tree; raise click's error when a subcommand or an
    option does not exist. A mention that leaves out required arguments (or the value of the option it names last)
    passes; nothing is invoked."""
    from facegeom.cli.main import cli

    cmd, ctx, name, args = cli, None, "facegeom", list(words)
    while True:
        try:
            ctx = cmd.make_context(name, list(args), parent=ctx)
        except click.MissingParameter:
            return
        except click.BadOptionUsage as exc:  # `facegeom fit --image`: an option named without its value
            if exc.option_name == args[-1]:
                return
            raise
        except click.exceptions.Exit:  # --help, --version
            return
        if not isinstance(cmd, click.Group):
            return
        protected = getattr(ctx, "_protected_args", None)
        rest = [*(protected if protected is not None else ctx.protected_args), *ctx.args]
        if not rest:
            return
        if "/" in rest[0]:  # `data fetch/build/info`: each one must exist
            for alt in rest[0].split("/"):
                cmd.resolve_command(ctx, [alt])
            return
        name, cmd, args = cmd.resolve_command(ctx, rest)


INLINE = list(dict.fromkeys(inline_commands(README.read_text(encoding="utf-8"))))
# the how-to pages: inline commands, and the commands of their blocks marked not run (parsed, never run)
HOWTO_INLINE = list(dict.fromkeys(
    [(page, c) for page, text in PAGES.items() for c in inline_commands(text)]
    + [(page, " ".join(shlex.split(c, comments=True))) for page, text in PAGES.items()
       for c in facegeom_parts(bash_lines("".join(f"```bash\n{b}```\n" for b in marked_blocks(text, "bash"))))
       if not PLACEHOLDER.search(" ".join(shlex.split(c, comments=True)))]))


def test_the_inline_extractor():
    text = ("Run `facegeom bench fit --cases 1` or `facegeom fit TARGET -o W`,\n`facegeom bench solve\n--frames 20`"
            " and `facegeom data fetch/build/info`.\n```\nfacegeom nope\n```\n`facegeom view animate --input FILE`")
    assert inline_commands(text) == ["facegeom bench fit --cases 1", "facegeom bench solve --frames 20",
                                     "facegeom data fetch/build/info"]
    parse_command(["bench", "fit", "--cases", "1"])
    with pytest.raises(click.NoSuchOption):
        parse_command(["bench", "fit", "--no-such-option"])
    with pytest.raises(click.UsageError):
        parse_command(["bench", "no-such-command"])
    with pytest.raises(click.UsageError):
        parse_command(["data", "fetch/nope"])


@pytest.mark.parametrize("command", INLINE, ids=str)
def test_inline_readme_command_parses(command):
    try:
        parse_command(shlex.split(command)[1:])
    except click.UsageError as exc:
        pytest.fail(f"README prose names `{command}`, which the command line does not accept: {exc.format_message()}")


@pytest.mark.parametrize("page,command", HOWTO_INLINE, ids=[f"{p}: {c}" for p, c in HOWTO_INLINE])
def test_inline_howto_command_parses(page, command):
    try:
        parse_command(shlex.split(command)[1:])
    except click.UsageError as exc:
        pytest.fail(f"docs/howto/{page}.md names `{command}`, which the command line does not accept: "
                    f"{exc.format_message()}")


# --------------------------------------------------------------------------- (d) the how-to pages


@pytest.fixture(scope="module")
def howto_runs(tmp_path_factory, made, face_model, done):
    """Each page's commands, in order, in a fresh copy of the examples folder, then its python blocks there:
    ``{page: ([(command, args, folder, result, seconds)], [(block, result)])}``."""
    env = _env(face_model)
    out = {}
    t_all = time.perf_counter()
    lines = []
    for page, text in PAGES.items():
        cwd = tmp_path_factory.mktemp("howto") / page
        shutil.copytree(made, cwd)
        runs, blocks = [], []
        for part in page_commands(text):
            words = shlex.split(part, comments=True)
            t = time.perf_counter()
            r, reused = run_once(words[1:], cwd, env, done)
            runs.append((part, words[1:], cwd, r, time.perf_counter() - t))
            lines.append(f"  {time.perf_counter() - t:5.1f} s  rc={r.returncode}{' reused' if reused else ''}  "
                         f"{page}: {without_comment(part)}")
        for code in python_blocks(runnable(text)):
            t = time.perf_counter()
            r = subprocess.run([sys.executable, "-c", code], cwd=cwd, env=env, capture_output=True, text=True,
                               timeout=300, check=False)
            blocks.append((code, r))
            lines.append(f"  {time.perf_counter() - t:5.1f} s  rc={r.returncode}  {page}: python block {len(blocks)}")
        out[page] = (runs, blocks)
    print(f"\nhow-to pages: {sum(len(r) for r, _ in out.values())} commands and "
          f"{sum(len(b) for _, b in out.values())} python blocks in {time.perf_counter() - t_all:.1f} s")
    print("\n".join(lines))
    return out


@pytest.mark.parametrize("page", sorted(PAGES), ids=str)
def test_howto_commands_run(howto_runs, page):
    runs = [x for x in howto_runs[page][0] if x[1][0] != "view"]
    problems = _check(runs, f"docs/howto/{page}.md")
    assert not problems, "\n\n".join(problems)


@pytest.mark.parametrize("page", sorted(p for p, t in PAGES.items()
                                        if any(shlex.split(c, comments=True)[1] == "view" for c in page_commands(t))),
                         ids=str)
def test_howto_view_commands_render_headless(howto_runs, page):
    runs = [x for x in howto_runs[page][0] if x[1][0] == "view"]
    for part, args, *_ in runs:
        assert "--screenshot" in args, f"docs/howto/{page}.md: a view command that runs must render headless: {part}"
    no_renderer = [r for *_, r, _ in runs if r.returncode != 0 and "could not start a renderer" in r.stderr]
    if no_renderer:
        pytest.skip(f"headless rendering unavailable here: {no_renderer[0].stderr.strip()}")
    problems = _check(runs, f"docs/howto/{page}.md")
    assert not problems, "\n\n".join(problems)
    for _, args, cwd, _, _ in runs:
        png = cwd / outputs_of(args)[0]
        assert png.stat().st_size > 10_000, f"{png.name}: an almost empty image"


@pytest.mark.parametrize("page", sorted(p for p, t in PAGES.items() if python_blocks(runnable(t))), ids=str)
def test_howto_python_blocks_run(howto_runs, page):
    for code, r in howto_runs[page][1]:
        assert r.returncode == 0 and "Traceback" not in r.stderr, \
            f"docs/howto/{page}.md: a python block failed (exit {r.returncode}):\n{code}\nstderr (end):\n{r.stderr[-2500:]}"
