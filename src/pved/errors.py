"""The one exception type the CLI turns into a one-line message and a non-zero exit."""

from __future__ import annotations


class PvedError(Exception):
    """Bad input or a failed check that the user can act on (unknown name, wrong dims,
    corrupt file, NaN in training). The message is one line naming the problem."""


class OptionError(PvedError):
    """A value an option does not take: the message names the option, what it takes and
    the value given, ``--beta must be a finite number >= 0, got -1.0``.

    A config names its own fields (``beta``); the function that fills a config from its
    arguments knows what the user called the value (``--beta``) and re-raises the error
    under that name (:func:`pved.checks.named_options`)."""

    def __init__(self, option: str, value: object, rule: str) -> None:
        self.option, self.value, self.rule = option, value, rule
        # a value a program made up can be long, or an array printed over lines: the
        # message stays one line
        shown = repr(value).replace("\n", " ")
        shown = shown if len(shown) <= 80 else shown[:77] + "..."
        super().__init__(f"{option} must be {rule}, got {shown}")

    def renamed(self, option: str) -> OptionError:
        """The same refusal under the name the user knows the value by."""
        return OptionError(option, self.value, self.rule)
