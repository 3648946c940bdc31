"""``python -m reports`` runs the full ``dvfc`` command line."""

from dvfc.reports.cli import app

app(prog_name="dvfc")
