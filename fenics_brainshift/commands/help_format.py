"""The help's format every command shares: argparse's, with the defaults shown."""

from __future__ import annotations

import argparse


class Defaults(argparse.ArgumentDefaultsHelpFormatter):
    """Defaults in the help where they say something: not for flags (False) or options with
    none, nor twice where the help names its own."""

    def _get_help_string(self, action):
        text = action.help or ""
        if action.default in (None, False, argparse.SUPPRESS) or "default" in text:
            return text
        return super()._get_help_string(action)
