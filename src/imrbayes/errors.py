"""Exceptions that the command line turns into one-line messages and exit codes."""


class InputError(ValueError):
    """Bad user input (a file, an option). The CLI prints one line and exits with status 2.

    Parameters
    ----------
    source : str or path-like or None
        The file or option at fault; it starts the message.
    problem : str
        What is wrong, in words a user can act on.
    """

    def __init__(self, source, problem):
        self.source = None if source is None else str(source)
        self.problem = problem
        super().__init__(f"{self.source}: {problem}" if self.source else problem)


class ForwardModelError(RuntimeError):
    """The forward model could not be set up or run (not a per-member solver failure)."""
