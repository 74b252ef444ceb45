"""`python -m tdgen`: the tdgen commands without the rest of the twinmesh CLI."""
import click

from tdgen.commands import check_command, tdgen_command


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
def main() -> None:
    """twinmesh robot TD generation."""


main.add_command(tdgen_command)
main.add_command(check_command)

if __name__ == "__main__":
    main()
