"""The ``facegeom`` command line (also ``python -m facegeom``): the group, ``info``, ``methods`` and ``main``.

Every other command is defined in its own module, listed in :data:`COMMANDS` and imported only when it is
used, so that ``facegeom --help`` and ``facegeom CMD --help`` load neither numpy nor the other commands.
User mistakes (bad files, bad arguments, missing data) print one line on
stderr, ``facegeom: error: ...``, and exit with status 2; no traceback.
"""
from __future__ import annotations

import sys

import click

from facegeom.cli.context import Context
from facegeom.cli.flags import as_flags
from facegeom.cli.lazy import LazyCommand, LazyGroup
from facegeom.errors import FacegeomError

DEPENDENCIES = ("numpy", "scipy", "libigl", "pymeshlab", "polyscope", "click", "tqdm", "matplotlib", "cholespy")

COMMANDS: dict[str, LazyCommand] = {
    "animate": LazyCommand("facegeom.cli.single", "animate",
                           "Performance-driven animation: a take on an actor -> 80 markers -> retargeted -> "
                           "character mesh per frame."),
    "batch": LazyCommand("facegeom.cli.batch", "batch_cmd",
                         "Run the job in JOB.toml: an operation (fit, drive, retarget, animate, clean) over every "
                         "input, one result file per input and a summary CSV (batch-summary.csv) in the output "
                         "folder."),
    "bench": LazyCommand("facegeom.cli.bench", "bench",
                         "Benchmarks that reproduce the papers' experiments (seeded; CSV + plot + table)."),
    "clean": LazyCommand("facegeom.cli.cleanup", "clean_cmd",
                         "Repair IN into OUT: triangulate, merge duplicate vertices, remove unreferenced vertices, "
                         "duplicate and zero-area faces, repair non-manifold edges and vertices, orient faces "
                         "(pymeshlab filters)."),
    "crop": LazyCommand("facegeom.cli.cleanup", "crop_cmd",
                        "Keep the face region of IN into OUT: the vertices within a geodesic radius of landmark "
                        "vertices, or an id range; faces with a vertex outside are removed."),
    "data": LazyCommand("facegeom.cli.data", "data",
                        "The face data: download the ICT-FaceKit model (verified), build the bundle, show where it "
                        "is."),
    "decimate": LazyCommand("facegeom.cli.cleanup", "decimate_cmd",
                            "Quadric edge-collapse decimation of IN (pymeshlab) to about --vertices vertices, into "
                            "OUT."),
    "demo": LazyCommand("facegeom.cli.demo", "demo",
                        "The product in about two minutes on real data: a face driven by markers, a photo fitted, "
                        "a capture, a real take and a video played on a scanned head and a stylised character; "
                        "pictures and .glb files to open."),
    "detect": LazyCommand("facegeom.cli.detect", "detect_cmd",
                          "Find the faces of a photo (or of every photo in a FOLDER): 68 landmarks as an iBUG .pts "
                          "file."),
    "drive": LazyCommand("facegeom.cli.single", "drive",
                         "Deform MESH so that the vertices of MARKERS (CSV vertex_id,x,y,z) reach their positions."),
    "fit": LazyCommand("facegeom.cli.single", "fit",
                       "Fit the rig's blendshape coefficients to TARGET (a photo, landmarks with a camera, a mesh "
                       "or a point cloud)."),
    "identity": LazyCommand("facegeom.cli.identity", "identity_cmd",
                            "Fit one identity to TARGETS (neutral frames of one person) and write the "
                            "user-specific rig."),
    "live": LazyCommand("facegeom.cli.live", "live_cmd",
                        "Receive a Live Link Face stream (or replay one) and pass it on live."),
    "retarget": LazyCommand("facegeom.cli.single", "retarget",
                            "Retarget the actor's markers SOURCE onto a character known at the frames of LABELS."),
    "solve": LazyCommand("facegeom.cli.solve", "solve_cmd",
                         "Solve the markers of CAPTURE (a marker sequence) to weight curves of the rig, head "
                         "motion removed."),
    "track": LazyCommand("facegeom.cli.track", "track_cmd",
                         "Track the face in VIDEO: its blendshape weights, head pose and gaze per frame, no "
                         "markers."),
    "transfer": LazyCommand("facegeom.cli.transfer", "transfer_cmd",
                            "Give the head HEAD (any topology, units, orientation) the 53 ICT expressions as a "
                            "rig."),
    "view": LazyCommand("facegeom.cli.view", "view",
                        "Look before believing a table: every method's result side by side (polyscope)."),
}
"""The commands defined outside this module: name -> where it is defined and its one-line help (the first
sentence of its docstring, which ``facegeom --help`` shows without importing the command; a test keeps the two
the same)."""


def _show_version(ctx: click.Context, param: click.Parameter, value: bool) -> None:
    """``--version``: print the installed version and exit (the metadata is read only then)."""
    if not value or ctx.resilient_parsing:
        return
    from facegeom.version import __version__

    click.echo(f"facegeom, version {__version__}", color=ctx.color)
    ctx.exit()


@click.group(cls=LazyGroup, lazy_commands=COMMANDS,
             context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.option("--version", is_flag=True, expose_value=False, is_eager=True, callback=_show_version,
              help="Show the version and exit.")
@click.option("--data", "data", type=click.Path(), default=None, envvar=None,
              help="Face data bundle (folder or .npz). Default: $FACEGEOM_DATA, "
                   "else ../shared/data/ict-face-light next to the repository, else the user cache "
                   "(see `facegeom data info`; `facegeom data fetch` downloads it).")
@click.pass_context
def cli(ctx, data):
    """facegeom: face driving, expression retargeting and blendshape fitting on libigl."""
    ctx.obj = Context(data)


def _pkg_version(name: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(name)
    except PackageNotFoundError:
        return "not installed"


@cli.command()
@click.pass_obj
def info(obj: Context):
    """Versions, where the face data was found and what it holds."""
    import platform

    from facegeom.model import locate_data
    from facegeom.version import __version__

    path = locate_data(obj.data)
    model = obj.face_model()
    click.echo(f"facegeom {__version__}  (Python {platform.python_version()}, {platform.machine()})")
    for dep in DEPENDENCIES:
        click.echo(f"  {dep:<11} {_pkg_version(dep)}")
    click.echo(f"face data: {path}")
    for k, v in model.summary().items():
        if k != "path":
            click.echo(f"  {k:<18} {v}")
    click.echo(f"  expression names   {', '.join(model.expression_names[:6])}, ... ({model.n_expressions})")


@cli.command()
@click.option("--kind", type=click.Choice(["deformers", "retargeters", "fitters", "identity"]), default=None,
              help="Only this kind of method.")
def methods(kind):
    """Registered method plugins, by kind (entry points)."""
    from facegeom.registry import KINDS, available

    for k in [kind] if kind else KINDS:
        plugins = available(k)
        click.echo(f"{k}:")
        if not plugins:
            click.echo("  (none)")
        for name, target in plugins.items():
            click.echo(f"  {name:<14} {target}")


def usage_line(exc: click.exceptions.UsageError) -> str:
    """A click usage error as facegeom's one line: ``facegeom: error: <command>: <message> (see `... --help`)``.

    ``<command>`` is the (sub)command the error is about, e.g. ``drive`` or ``bench fit``; an error of the
    ``facegeom`` group itself (an unknown command) names no command.
    """
    message = " ".join(exc.format_message().split()).removesuffix(".")  # click's messages may span lines
    words = exc.ctx.command_path.split()[1:] if exc.ctx is not None else []
    command = " ".join(words)
    where = f"{command}: " if command else ""
    return f"facegeom: error: {where}{message} (see `{' '.join(['facegeom', *words])} --help`)"


def main(argv=None):
    """Entry point: run the CLI, turning user errors into one line and exit 2."""
    try:
        cli.main(args=argv, prog_name="facegeom", standalone_mode=False)
    except click.exceptions.Abort:
        click.echo("facegeom: aborted", err=True)
        sys.exit(130)
    except click.exceptions.NoArgsIsHelpError as exc:  # a group run without a command: its help, as click shows it
        exc.show()
        sys.exit(exc.exit_code)
    except click.exceptions.UsageError as exc:  # bad arguments and options (BadParameter, NoSuchOption, ...)
        click.echo(usage_line(exc), err=True)
        sys.exit(2)
    except click.exceptions.ClickException as exc:
        exc.show()
        sys.exit(exc.exit_code)
    except FacegeomError as exc:  # library messages name Python arguments: print them as flags
        click.echo(f"facegeom: error: {as_flags(str(exc))}", err=True)
        sys.exit(2)
    except (FileNotFoundError, PermissionError, IsADirectoryError) as exc:
        click.echo(f"facegeom: error: {exc.filename}: {exc.strerror}", err=True)
        sys.exit(2)
    except OSError as exc:  # the system refused (disk full, I/O error, ...): one line naming the file, exit 1
        where = f"{exc.filename}: " if exc.filename else ""
        click.echo(f"facegeom: error: {where}{exc.strerror or exc}", err=True)
        sys.exit(1)
    except KeyboardInterrupt:
        click.echo("facegeom: interrupted", err=True)
        sys.exit(130)

