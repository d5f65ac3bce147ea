"""Argument types for the command line: numbers that are finite and in range.

`number(lo, hi)` is the one argparse type for every float option: NaN, inf
and anything outside [lo, hi] (or (lo, hi] with ``lo_open``) is refused by
the parser with one line naming the range, so no command computes with an
absurd value. `count(lo, hi)` is the same for a whole number (a count of
folds, terms...: a huge one would make a command run for hours). `port` is a
TCP port (0 = a free one).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from dataclasses import dataclass


def number(lo: float, hi: float, *, lo_open: bool = False,
           hi_open: bool = False) -> Callable[[str], float]:
    """An argparse type: a finite float in [lo, hi] (open ends as asked)."""
    left, right = "(" if lo_open else "[", ")" if hi_open else "]"
    span = f"{left}{lo:g}, {hi:g}{right}"

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be a finite number in {span}: {text!r}")
        below = value <= lo if lo_open else value < lo
        above = value >= hi if hi_open else value > hi
        if below or above:
            raise argparse.ArgumentTypeError(f"must be in {span}: {text!r}")
        return value

    parse.__name__ = "number"  # argparse names the type in its messages
    return parse


def count(lo: int, hi: int) -> Callable[[str], int]:
    """An argparse type: a whole number in lo … hi."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be {lo} … {hi}: {text!r}")
        return value

    parse.__name__ = "count"
    return parse


@dataclass(frozen=True)
class Wholes:
    """How `distinct_wholes` names a list and its values in its messages."""

    one: str       #: one value, with its article: "a spindle speed"
    whole: str     #: what a valid value is: "whole number of rpm"
    unit: str      #: as written after a value: "rpm", "%"
    each: str      #: one value, bare: "speed"
    many: str      #: several values: "speeds"
    listing: str   #: the whole list: "spindle speeds in rpm"
    example: str   #: a valid list: "1250,2500,5000"


def distinct_wholes(text: str, hi: int, most: int, words: Wholes) -> list[int]:
    """Comma-separated whole numbers, distinct, each 1 … `hi`, at most `most` of them:
    a list a plan visits in turn (spindle speeds, axis duties)."""
    parts = [p.strip() for p in text.split(",")]
    if not text.strip() or any(not p for p in parts):
        raise argparse.ArgumentTypeError(f"a comma-separated list of {words.listing}, "
                                         f"e.g. {words.example}; got {text!r}")
    values: list[int] = []
    for part in parts:
        try:
            value = float(part)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not {words.one}: {part!r}") from None
        if not math.isfinite(value) or value != int(value) or not 1 <= value <= hi:
            raise argparse.ArgumentTypeError(f"{words.one} is a {words.whole}, "
                                             f"1 … {hi}: {part!r}")
        if int(value) in values:
            raise argparse.ArgumentTypeError(f"{part} {words.unit} is given twice; each "
                                             f"{words.each} once (the plan visits each "
                                             f"twice by itself)")
        values.append(int(value))
    if len(values) > most:
        raise argparse.ArgumentTypeError(f"at most {most} {words.many}, got {len(values)}")
    return values


def port(text: str) -> int:
    """A TCP port number 0..65535 (0: let the system pick a free one)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a port number: {text!r}") from None
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"a port is 0..65535 (0: a free one), got {text!r}")
    return value


def seed(text: str) -> int:
    """A random seed: a whole number 0 … 2**63 - 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"a seed is a whole number, got {text!r}") from None
    if not 0 <= value < 2**63:
        raise argparse.ArgumentTypeError(f"a seed is 0 … 2**63-1, got {text!r}")
    return value


class RenamedOption(argparse.Action):
    """An option with a new name and an old spelling that still works: the old
    one stores the same value and says, in one line on stderr, to use the new
    one (e.g. ``--column`` for the CSV column, whose old spelling ``--output``
    `compd fit` still takes, while ``--output`` names a file in `compd export`).
    The new name is the first option string."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: object, option_string: str | None = None) -> None:
        new = self.option_strings[0]
        if option_string is not None and option_string != new:
            import sys

            print(f"{parser.prog}: {option_string} is deprecated, use {new} (same meaning)",
                  file=sys.stderr)
        setattr(namespace, self.dest, values)
