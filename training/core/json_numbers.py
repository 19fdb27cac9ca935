"""JSON text read with every number a float can hold: the rule for the files we read that a user or a tool may write
(a project's manifest, a camera path, a .glb's JSON chunk).

Python's json reads a whole number of any length as an int, and an int beyond a float's range (about 1.8e308, 309
digits) then fails wherever it is first used as a number, with an ``OverflowError`` or numpy's "ufunc 'isfinite' not
supported", far from the file; past 4300 digits the parse itself fails with a ValueError about Python's digit limit.
Here such a number is refused while the text is parsed, in words that say what it is.
"""

from __future__ import annotations

import json

# a float's largest finite value has 309 digits before the point: a longer whole number cannot be one
FLOAT_DIGITS = 309


class NumberOutOfRange(ValueError):
    """A whole number in the JSON that no float holds."""


def _whole_number(text: str) -> int:
    digits = len(text.lstrip("-"))
    if digits > FLOAT_DIGITS:
        raise NumberOutOfRange(f"holds a whole number of {digits} digits, beyond any number it may hold (a float "
                               "reaches about 1.8e308)")
    value = int(text)
    try:
        float(value)
    except OverflowError:
        raise NumberOutOfRange(f"holds a whole number of {digits} digits, beyond any number it may hold (a float "
                               "reaches about 1.8e308)") from None
    return value


def parse_json(text: str | bytes):
    """``json.loads`` whose whole numbers are those a float holds: NumberOutOfRange (a ValueError) for one beyond,
    ValueError for text that is not JSON, RecursionError for nesting deeper than the interpreter's stack."""
    return json.loads(text, parse_int=_whole_number)
