"""argparse types for the tools' counts: a bad value is refused by argparse, naming the flag, before any work."""

from __future__ import annotations

import argparse


def int_at_least(minimum: int):
    """An argparse `type` accepting integers >= `minimum`."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"{value} is not allowed: expected an integer >= {minimum}")
        return value

    parse.__name__ = f"integer >= {minimum}"  # argparse names the type in its messages
    return parse


def number_above(bound: float):
    """An argparse `type` accepting numbers > `bound`."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not value > bound:
            raise argparse.ArgumentTypeError(f"{value} is not allowed: expected a number > {bound}")
        return value

    parse.__name__ = f"number > {bound}"
    return parse
