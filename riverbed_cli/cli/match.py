"""`riverbed match` (being written)."""
import click


@click.command("match")
def match_cmd():
    """Match a rectified pair (being written)."""
