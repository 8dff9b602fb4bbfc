"""The ``facegeom`` command line (also ``python -m facegeom``): the group, ``info``, ``methods`` and ``main``.

Every other command is defined in its own module and added here.
User mistakes (bad files, bad arguments, missing data) print one line on
stderr, ``facegeom: error: ...``, and exit with status 2; no traceback.
"""
from __future__ import annotations

import platform
import sys
from importlib.metadata import PackageNotFoundError, version

import click

from facegeom.cli.batch import batch_cmd
from facegeom.cli.bench import bench
from facegeom.cli.cleanup import clean_cmd, crop_cmd, decimate_cmd
from facegeom.cli.context import Context
from facegeom.cli.data import data
from facegeom.cli.demo import demo
from facegeom.cli.detect import detect_cmd
from facegeom.cli.flags import as_flags
from facegeom.cli.identity import identity_cmd
from facegeom.cli.live import live_cmd
from facegeom.cli.single import animate, drive, fit, retarget
from facegeom.cli.solve import solve_cmd
from facegeom.cli.track import track_cmd
from facegeom.cli.transfer import transfer_cmd
from facegeom.cli.view import view
from facegeom.errors import FacegeomError
from facegeom.version import __version__

DEPENDENCIES = ("numpy", "scipy", "libigl", "pymeshlab", "polyscope", "click", "tqdm", "matplotlib", "cholespy")


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="facegeom")
@click.option("--data", "data", type=click.Path(), default=None, envvar=None,
              help="Face data bundle (folder or .npz). Default: $FACEGEOM_DATA, "
                   "else ../shared/data/ict-face-light next to the repository, else the user cache "
                   "(see `facegeom data info`; `facegeom data fetch` downloads it).")
@click.pass_context
def cli(ctx, data):
    """facegeom: face driving, expression retargeting and blendshape fitting on libigl."""
    ctx.obj = Context(data)


def _pkg_version(name: str) -> str:
    try:
        return version(name)
    except PackageNotFoundError:
        return "not installed"


@cli.command()
@click.pass_obj
def info(obj: Context):
    """Versions, where the face data was found and what it holds."""
    from facegeom.model import locate_data

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


cli.add_command(drive)
cli.add_command(retarget)
cli.add_command(fit)
cli.add_command(detect_cmd)
cli.add_command(animate)
cli.add_command(bench)
cli.add_command(demo)
cli.add_command(clean_cmd)
cli.add_command(decimate_cmd)
cli.add_command(crop_cmd)
cli.add_command(view)
cli.add_command(batch_cmd)
cli.add_command(data)
cli.add_command(identity_cmd)
cli.add_command(solve_cmd)
cli.add_command(transfer_cmd)
cli.add_command(track_cmd)
cli.add_command(live_cmd)
