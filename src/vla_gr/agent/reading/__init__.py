"""Reading a request: any printable text in, a structured :class:`Reading` out (goal category,
colour, room, relation and anchor, the words not placed, a confidence per field, understood or
not). :mod:`.text` normalises and splits, :mod:`.vocabulary` knows the words (WordNet),
:mod:`.tagger` gives each word its role, :mod:`.reader` puts them together."""

from vla_gr.agent.reading.reader import (
    FIELDS,
    InstructionReader,
    ReaderConfig,
    Reading,
    display_name,
)
from vla_gr.agent.reading.tagger import TAGS, RequestTagger
from vla_gr.agent.reading.text import MAX_REQUEST_CHARS, RequestError, normalise_request

__all__ = [
    "FIELDS",
    "MAX_REQUEST_CHARS",
    "TAGS",
    "InstructionReader",
    "Reading",
    "ReaderConfig",
    "RequestError",
    "RequestTagger",
    "display_name",
    "normalise_request",
]
