"""A click group whose commands are imported when they are used, so that ``facegeom --help`` stays fast.

The group lists its commands from a table (name -> module, attribute, one-line help) and imports a
command's module only when that command is run or asked for its own help: ``facegeom --help`` imports
no command module, and ``facegeom solve ...`` imports ``facegeom.cli.solve`` and nothing else the other
commands need (numpy, libigl, pymeshlab, ...). tests/test_startup.py checks the table's help against
the commands' own.
"""
from __future__ import annotations

import importlib
from collections.abc import Mapping
from gettext import gettext as _
from typing import NamedTuple

import click

__all__ = ["LazyCommand", "LazyGroup"]


class LazyCommand(NamedTuple):
    """Where a command is defined, and its one-line help as ``facegeom --help`` shows it."""

    module: str
    """The module that defines the command, e.g. ``facegeom.cli.solve``."""
    attribute: str
    """The command object's name in that module, e.g. ``solve_cmd``."""
    summary: str
    """The command's short help: the first sentence of its docstring, whole (the listing shortens it)."""


class LazyGroup(click.Group):
    """A :class:`click.Group` with commands from a table of :class:`LazyCommand`, each imported on first use.

    Commands added the usual way (``@group.command()``, :meth:`add_command`) work as in any group.
    """

    def __init__(self, *args, lazy_commands: Mapping[str, LazyCommand] | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.lazy_commands: dict[str, LazyCommand] = dict(lazy_commands or {})

    def list_commands(self, ctx: click.Context) -> list[str]:
        """Every command's name, sorted: the imported ones and those of the table."""
        return sorted({*super().list_commands(ctx), *self.lazy_commands})

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        """The command ``cmd_name``, its module imported if it is the first use; None if there is no such command."""
        if cmd_name not in self.commands and cmd_name in self.lazy_commands:
            self.add_command(self.load_command(cmd_name), cmd_name)
        return super().get_command(ctx, cmd_name)

    def load_command(self, cmd_name: str) -> click.Command:
        """Import the module of the table's command ``cmd_name`` and return the command object."""
        entry = self.lazy_commands[cmd_name]
        command = getattr(importlib.import_module(entry.module), entry.attribute)
        if not isinstance(command, click.Command):
            raise TypeError(f"{entry.module}.{entry.attribute} is not a click command")
        return command

    def resolve_command(self, ctx: click.Context, args: list[str]):
        """As click resolves a command; an unknown name's "Did you mean" suggestions include the unimported commands."""
        try:
            return super().resolve_command(ctx, args)
        except click.UsageError as exc:
            no_such = getattr(click.exceptions, "NoSuchCommand", None)  # click >= 8.4 suggests close names
            if no_such is None or not isinstance(exc, no_such):
                raise
            raise no_such(exc.command_name, exc.message, possibilities=self.list_commands(ctx), ctx=exc.ctx) from None

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """The "Commands" section of the help, as click writes it, without importing a command not yet used.

        A command not imported yet is listed with the table's summary, shortened to the width as click
        shortens a docstring's first sentence.
        """
        listed = []
        for name in self.list_commands(ctx):
            command = self.commands.get(name) or click.Command(name, help=self.lazy_commands[name].summary)
            if not command.hidden:
                listed.append((name, command))
        if not listed:
            return
        limit = formatter.width - 6 - max(len(name) for name, _command in listed)  # as click.Group.format_commands
        with formatter.section(_("Commands")):
            formatter.write_dl([(name, command.get_short_help_str(limit)) for name, command in listed])
