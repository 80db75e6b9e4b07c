"""Exceptions that carry a one-line, user-facing message.

The CLI prints ``str(exc)`` of these and exits non-zero without a traceback;
anything else escaping is a bug in varint.
"""

__all__ = ["VarintError", "SceneError", "SolverError", "OutputError"]


class VarintError(Exception):
    """Base class of the errors the CLI reports as one line per problem."""


class SceneError(VarintError):
    """An invalid scene: one line per problem, each naming the key path.

    Parameters
    ----------
    problems : list of str
        Lines of the form ``"fluid.gamma: must be > 1, got 0.9"``.
    source : str, optional
        The scene file name, prefixed to every line.
    """

    def __init__(self, problems, source=None):
        if isinstance(problems, str):
            problems = [problems]
        self.problems = list(problems)
        self.source = source
        prefix = f"{source}: " if source else ""
        super().__init__("\n".join(prefix + p for p in self.problems))


class SolverError(VarintError):
    """Newton failed to converge; the message names step, time, residual and rate.  ``cure``: what the message already
    names to run it (a scheme or a scene section), or None."""

    def __init__(self, message, step=None, time=None, residual=None, rate=None, cure=None):
        super().__init__(message)
        self.step, self.time, self.residual, self.rate, self.cure = step, time, residual, rate, cure


class OutputError(VarintError):
    """A run file cannot be written, read or resumed."""
