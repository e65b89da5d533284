"""The one exception type the CLI turns into a one-line message and a non-zero exit."""


class PvedError(Exception):
    """Bad input or a failed check that the user can act on (unknown name, wrong dims,
    corrupt file, NaN in training). The message is one line naming the problem."""
