"""Normalising a request: any printable Unicode folded, punctuation kept as words, a limit."""

import pytest

from vla_gr.agent.reading.text import (
    MAX_REQUEST_CHARS,
    RequestError,
    normalise_request,
    request_words,
)


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("I\u2019m looking for the sofa", ["i'm", "looking", "for", "the", "sofa"]),
        ("Zo\u00eb\u2019s \u201cTV\u201d \u2014 now", ["zoe's", "tv", "-", "now"]),
        ("GREEN  plant\tby the desk...", ["green", "plant", "by", "the", "desk", ".", ".", "."]),
        ("the chair that isn't red", ["the", "chair", "that", "isn't", "red"]),
        ("\U0001f6cb\ufe0f sofa \x00\x07", ["sofa"]),
        ("\uff26\uff29\uff2e\uff24 the bed", ["find", "the", "bed"]),  # full-width letters
        ("", []),
        ("   \t ", []),
    ],
)
def test_requests_are_folded_to_plain_lower_case_words(text, words):
    assert request_words(normalise_request(text)) == words


def test_a_request_over_the_limit_is_refused_in_one_line_naming_it():
    normalise_request("a" * MAX_REQUEST_CHARS)  # at the limit: read
    with pytest.raises(RequestError) as err:
        normalise_request("a" * (MAX_REQUEST_CHARS + 1))
    assert str(MAX_REQUEST_CHARS) in str(err.value) and "\n" not in str(err.value)


def test_a_non_string_is_refused():
    with pytest.raises(RequestError, match="must be a str"):
        normalise_request(b"find the sofa")


def test_a_hyphen_inside_a_word_is_a_space_and_a_dash_between_words_is_kept():
    assert request_words(normalise_request("Living-room chair - go")) == [
        "living", "room", "chair", "-", "go"
    ]  # fmt: skip


@pytest.mark.parametrize(
    "text, words",
    [
        ("the bed & the couch", ["the", "bed", "and", "the", "couch"]),
        ("bed&sofa", ["bed", "and", "sofa"]),
        ("the bed + the sofa", ["the", "bed", "plus", "the", "sofa"]),
        ("+ the sofa", ["plus", "the", "sofa"]),
        ("c++", ["c"]),  # a plus inside a word is no "plus"
    ],
)
def test_an_ampersand_and_a_lone_plus_are_words(text, words):
    assert request_words(normalise_request(text)) == words
