"""A sweep family's place in a list and its name on a page.

A family's key is the suite's name and its knobs as ``name=value`` words
(``demo actors.0.count=12``): gate files and ``results.sqlite`` keep that key. Pages and
plots sort families with the numbers in them by value (``count=6`` before ``count=12``, where
text order puts 12 first) and show each one as ``demo: actors[0].count = 12``, a list index
as Python and YAML readers write it."""

from __future__ import annotations

import re

_NUMBER = re.compile(r"(\d+(?:\.\d+)?)")
_INDEX = re.compile(r"\.(\d+)(?=\.|$)")


def family_order(family: str) -> tuple[tuple[str | float, ...], str]:
    """Sort key: text and numbers alternate (``re.split`` keeps the numbers at odd places, so
    two keys compare text with text and number with number); the name breaks ties."""
    parts = _NUMBER.split(family)
    return tuple(float(p) if i % 2 else p for i, p in enumerate(parts)), family


def sorted_families(families) -> list[str]:
    """Distinct family names in natural order."""
    return sorted(set(families), key=family_order)


def _bracketed(match: re.Match) -> str:
    return f"[{match.group(1)}]"


def family_name(family: str) -> str:
    """The family as a reader sees it: ``demo actors.0.count=12 sensor=kinect`` reads
    ``demo: actors[0].count = 12, sensor = kinect``; a family without knobs (a sequence
    folder's name) is shown as it is."""
    words = family.split(" ")
    knobs = [w for w in words if "=" in w]
    if not knobs:
        return family
    suite = " ".join(w for w in words if "=" not in w)
    shown = []
    for knob in knobs:
        name, _, value = knob.partition("=")
        shown.append(f"{_INDEX.sub(_bracketed, name)} = {value}")
    return (f"{suite}: " if suite else "") + ", ".join(shown)
