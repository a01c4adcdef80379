"""``python -m hil.cli``: the ``hil`` command."""

from hil.cli.main import entry

entry()
