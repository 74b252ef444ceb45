"""MkDocs hook: the CLI reference sees every `twinmesh` command.

The root group loads its heavy commands (tdgen, robot, ...) only when asked for them; mkdocs-click reads a
group's `commands` as they are, so before the pages are rendered each lazy command is loaded and added.
"""
from __future__ import annotations


def on_config(config, **kwargs):
    import click

    from devices.cli.main import main

    ctx = click.Context(main, info_name="twinmesh")
    for name in main.list_commands(ctx):
        command = main.get_command(ctx, name)
        if command is not None and name not in main.commands:
            main.add_command(command, name)
    return config
