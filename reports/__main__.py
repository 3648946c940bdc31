"""``python -m reports`` runs the full ``dvfc`` command line."""

from reports.cli import app

app(prog_name="dvfc")
