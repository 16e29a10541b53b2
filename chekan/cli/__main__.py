"""``python -m chekan.cli``: the ``chekan`` command (:func:`chekan.cli.commands.entry`)."""

from chekan.cli.commands import entry

entry()
