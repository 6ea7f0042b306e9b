"""Any printable Unicode text folded to plain printable ASCII (pure functions).

Shared by the world (an episode's instruction, :mod:`vla_gr.envs.nav_env`) and the
instruction reader, so that both see the same text:

    "I’m looking for the sofa — the “blue” one…"  ->  "I'm looking for the sofa - the "blue" one..."
    "Zoë’s café chair 🪑"                          ->  "Zoe's cafe chair"

Steps: NFKC (full-width letters, ligatures); curly quotes and apostrophes to ``'`` and ``"``;
every Unicode dash to ``-``; ellipsis to ``...``; accents dropped (NFKD, combining marks
removed) and a few letters NFKD keeps whole spelled out (``ß`` -> ``ss``); format characters
(zero-width space, soft hyphen) removed; control characters and characters with no ASCII
form (emoji, CJK) to a space; runs of whitespace to one space; stripped. Case is kept.
"""

from __future__ import annotations

import re
import unicodedata

__all__ = ["fold_to_ascii"]

_QUOTES = {
    **dict.fromkeys("\u2018\u2019\u201a\u201b\u2032\u2035\u02bc\u02bb\u2039\u203a", "'"),
    **dict.fromkeys("\u201c\u201d\u201e\u201f\u2033\u2036\u00ab\u00bb\u301d\u301e", '"'),
}
_ELLIPSIS = {"\u2026": "...", "\u22ef": "..."}
#: Letters that NFKD leaves whole but that have a usual ASCII spelling.
_LETTERS = {
    "ß": "ss", "ẞ": "SS", "æ": "ae", "Æ": "AE", "œ": "oe", "Œ": "OE", "ø": "o", "Ø": "O",
    "ł": "l", "Ł": "L", "đ": "d", "Đ": "D", "ð": "d", "Ð": "D", "þ": "th", "Þ": "Th", "ı": "i",
}  # fmt: skip
_TABLE = str.maketrans({**_QUOTES, **_ELLIPSIS, **_LETTERS, "\u2212": "-"})
_SPACES = re.compile(r"\s+")
#: ASCII control characters (0-31, 127) to a space.
_ASCII_CONTROLS = str.maketrans(dict.fromkeys([*range(32), 127], " "))
_DROPPED = ("Mn", "Me", "Cf")  # combining marks, enclosing marks, format characters


def fold_to_ascii(text: str) -> str:
    """``text`` as printable ASCII (characters 32-126), single-spaced and stripped; see the
    module docstring for each step. ``TypeError`` when ``text`` is not a str."""
    if not isinstance(text, str):
        raise TypeError(f"text must be a str, got {type(text).__name__}")
    if text.isascii():  # every step but the last two is the identity on ASCII
        return _SPACES.sub(" ", text.translate(_ASCII_CONTROLS)).strip()
    return _fold_unicode(text)


def _fold_unicode(text: str) -> str:
    """:func:`fold_to_ascii` of any str, step by step (the module docstring)."""
    text = unicodedata.normalize("NFKC", text).translate(_TABLE)
    text = "".join("-" if unicodedata.category(c) == "Pd" else c for c in text)
    kept = []
    for char in unicodedata.normalize("NFKD", text):
        if unicodedata.category(char) in _DROPPED:
            continue  # an accent ("e\u0301" -> "e"), a variation selector, a zero-width space
        kept.append(char if 32 <= ord(char) < 127 else " ")
    return _SPACES.sub(" ", "".join(kept)).strip()
