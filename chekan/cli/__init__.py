"""The ``chekan`` command line (:mod:`chekan.cli.commands`); ``python -m chekan.cli``."""
