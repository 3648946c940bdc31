"""``python -m analysis`` runs the ``dvfc`` command line."""

from dvfc.analysis.cli import app

app(prog_name="dvfc")
