"""Errors a user can cause and fix: each carries one message that says what and where."""


class JackboxError(Exception):
    """Base of the errors that the CLI reports as one line, without a traceback."""


class SceneError(JackboxError):
    """A scene that cannot be simulated: names the file, the key and the problem."""

    def __init__(self, source: str, key: str, problem: str):
        self.source, self.key, self.problem = source, key, problem
        where = f"{source}: {key}" if key else source
        super().__init__(f"{where}: {problem}")


class SimulationError(JackboxError):
    """A run that cannot go on (non-finite state, bad arguments)."""


class RunStoppedError(SimulationError):
    """A run that started and could not finish (CLI exit status 1)."""


class NonFiniteStateError(RunStoppedError):
    """The state became NaN or infinite during a run (CLI exit status 1)."""


class StalledError(RunStoppedError):
    """(Kept for callers that catch it: the exact method no longer stalls, its fallback takes such steps.)"""


class SolverWarning(UserWarning):
    """A contact solver inside the engine did not converge; the run went on (the trajectory says where)."""


class CacheWarning(UserWarning):
    """The cache needed mending (a damaged entry rebuilt, an unwritable folder avoided)."""
