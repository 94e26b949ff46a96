"""The ``bayes-mr`` command: verbs and flags as ``docs/CONTRACT.md`` fixes them.

* :mod:`.parser` — the argument parser, one sub-parser per verb;
* :mod:`.commands` — one function per verb, :data:`~.commands.VERBS` and :func:`~.commands.main`.
"""

from bayes_mr.cli.commands import VERBS, CLIError, main

__all__ = ["VERBS", "CLIError", "main"]
