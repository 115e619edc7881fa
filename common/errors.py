"""One error family: everything the project raises for bad input or an impossible request is a
`CrankError`, so the CLI catches one thing and prints one line.

Subclasses also derive from the built-in exception that fits (ValueError for bad values, OSError
for files that cannot be written, RuntimeError for solvers that fail), so library callers can keep
catching those.
"""

from __future__ import annotations


class CrankError(Exception):
    """Base of every error the `crank` command reports as one line and exit code 2."""


class NoSolutionError(CrankError):
    """The request was valid and the tool worked, but the model has no answer to it: no robust
    torque for this model and task (control/robust.py RobustError). A sweep lists such a step
    as refused, with its reason, rather than as failed."""


class ConfigError(CrankError, ValueError):
    """A configuration value is out of its valid range."""
