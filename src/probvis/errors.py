"""User-facing errors: reported by the CLI as one line, without a traceback."""


class ProbvisError(Exception):
    """A mistake in the user's input (scene file, option, output path)."""
