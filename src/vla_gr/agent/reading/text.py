"""A request as the reader sees it: any printable Unicode normalised, then split into words.

Curly quotes, accents, dashes and full-width letters are folded to plain lower-case ASCII
(``"I’m"`` -> ``"i'm"``, ``"Zoë"`` -> ``"zoe"``, ``"—"`` -> ``"-"``), a hyphen inside a
word is a space (``"living-room"`` -> ``"living room"``), ``&`` and a lone ``+`` are the
words "and" and "plus" (a second goal joined by them is still a second goal); control characters
become spaces; a request longer than :data:`MAX_REQUEST_CHARS` is refused in one line. Words
are runs of letters or digits (an inner apostrophe kept: ``"isn't"``); punctuation that can
end a clause (``, ; : . ! ? -``) is kept as its own word, since it tells where a clause ends.
"""

from __future__ import annotations

import re

from vla_gr.errors import UserError
from vla_gr.text_fold import fold_to_ascii

__all__ = ["MAX_REQUEST_CHARS", "RequestError", "normalise_request", "request_words"]

#: Longest request read (characters after normalisation); longer ones are refused.
MAX_REQUEST_CHARS = 400

_IN_WORD_HYPHEN = re.compile(r"(?<=[a-z])-(?=[a-z])")  # "living-room" is "living room"
_AMPERSAND = re.compile(r"\s*&\s*")  # "the bed & the sofa" is "the bed and the sofa"
_LONE_PLUS = re.compile(r"(?:^|(?<=\s))\+(?=\s|$)")  # "the bed + the sofa": "plus"
_WORD = re.compile(r"[a-z0-9]+(?:'[a-z]+)*|[,;:.!?]|-")


class RequestError(UserError, ValueError):
    """A request the reader refuses to read (not a str, or longer than the limit)."""


def normalise_request(text) -> str:
    """``text`` folded to lower-case ASCII with single spaces (:func:`fold_to_ascii`;
    RequestError if too long): accents dropped, curly quotes and dashes made plain,
    characters with no ASCII form (emoji, CJK) no word at all."""
    if not isinstance(text, str):
        raise RequestError(f"a request must be a str, got {type(text).__name__}")
    out = fold_to_ascii(text).lower()
    if len(out) > MAX_REQUEST_CHARS:
        raise RequestError(
            f"request of {len(out)} characters is longer than the {MAX_REQUEST_CHARS} read; "
            "say it in fewer words"
        )
    out = _LONE_PLUS.sub("plus", _AMPERSAND.sub(" and ", out)).strip()
    return _IN_WORD_HYPHEN.sub(" ", out)


def request_words(text: str) -> list[str]:
    """The words of normalised ``text`` (punctuation that ends a clause as its own word)."""
    return _WORD.findall(text)
