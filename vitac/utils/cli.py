"""argparse types for the tools' counts: a bad value is refused by argparse, naming the flag, before any work."""

from __future__ import annotations

import argparse


def _checked(convert, kind: str, accept, allowed: str):
    def parse(text: str):
        try:
            value = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {kind}") from None
        if not accept(value):
            raise argparse.ArgumentTypeError(f"{value} is not allowed: expected {allowed}")
        return value

    parse.__name__ = allowed  # argparse names the type in its messages
    return parse


def int_at_least(minimum: int):
    """An argparse `type` accepting integers >= `minimum`."""
    return _checked(int, "an integer", lambda value: value >= minimum, f"an integer >= {minimum}")


def number_above(bound: float):
    """An argparse `type` accepting numbers > `bound`."""
    return _checked(float, "a number", lambda value: value > bound, f"a number > {bound}")
