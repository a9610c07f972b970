"""The help's format every command shares: argparse's, with the defaults shown."""

from __future__ import annotations

import argparse


class Defaults(argparse.ArgumentDefaultsHelpFormatter):
    """Defaults in the help where they say something: not for flags (False), options with none
    or an empty list (repeatable ones), nor twice where the help names its own."""

    def _get_help_string(self, action):
        text = action.help or ""
        if action.default in (None, False, [], argparse.SUPPRESS) or "default" in text:
            return text
        return super()._get_help_string(action)


class Parser(argparse.ArgumentParser):
    """argparse's parser, whose errors are one line as every other input error's (argparse
    prints the whole usage first): the message, and where the full usage is."""

    def error(self, message: str):
        self.exit(2, f"brainshift: error: {message} (see {self.prog} --help)\n")


def add_overwrite(parser, what: str, *aliases: str) -> None:
    """--overwrite, the one way past a refusal to write over another kind's results (a run, a
    fit, an update, an image) in the same place."""
    parser.add_argument(
        "--overwrite",
        *aliases,
        dest="overwrite",
        action="store_true",
        help=f"write {what} even where it would replace another command's results (a run, a fit, an "
        "update, the image warped): refused otherwise, naming them",
    )
