"""fold_to_ascii: any printable Unicode to single-spaced printable ASCII, case kept."""

import numpy as np
import pytest

from vla_gr.text_fold import fold_to_ascii


@pytest.mark.parametrize(
    "text, folded",
    [
        ("I\u2019m looking for the sofa", "I'm looking for the sofa"),
        (
            "\u2018the\u2019 \u201cblue\u201d \u201elamp\u201f \u00abbed\u00bb",
            '\'the\' "blue" "lamp" "bed"',
        ),
        (
            "sofa \u2014 chair \u2013 bed \u2010 tv \u2212 plant \u2e3a x",
            "sofa - chair - bed - tv - plant - x",
        ),
        ("wait\u2026 the chair", "wait... the chair"),
        ("Zo\u00eb's caf\u00e9 na\u00efve \u00c5NGSTR\u00d6M", "Zoe's cafe naive ANGSTROM"),
        ("e\u0301e\u0300", "ee"),  # combining accents already decomposed
        ("Stra\u00dfe \u00e6 \u00f8", "Strasse ae o"),
        ("\uff26\uff49\uff4e\uff44 the \uff34\uff36", "Find the TV"),  # full width (NFKC)
        ("\ufb01nd", "find"),  # a ligature (NFKC)
        ("the chair \U0001fa91 please", "the chair please"),
        ("chair\U0001f642sofa", "chair sofa"),
        ("\u2764\ufe0f red", "red"),  # emoji with a variation selector
        ("\u6c99\u53d1 sofa", "sofa"),  # CJK has no ASCII form
        ("so\u00adfa\u200b!", "sofa!"),  # soft hyphen, zero-width space: removed
        ("find\tthe\nred\r\nchair\x07\x1b now\x7f", "find the red chair now"),
        ("  Find   THE  Chair  ", "Find THE Chair"),
        ("", ""),
        ("\t \u3000 ", ""),
    ],
)
def test_folding(text, folded):
    assert fold_to_ascii(text) == folded


def test_the_result_is_printable_ascii_and_folding_twice_changes_nothing():
    text = "\u00bfD\u00f3nde est\u00e1 la \u201csilla\u201d roja?\u2014\u2026 \U0001f600\x00\u0301"
    once = fold_to_ascii(text)
    assert once == 'Donde esta la "silla" roja?-...'
    assert all(32 <= ord(c) < 127 for c in once) and "  " not in once
    assert fold_to_ascii(once) == once
    plain = "find the red chair in the kitchen, next to the tv!"
    assert fold_to_ascii(plain) == plain


def test_ascii_takes_a_short_way_to_the_same_result():
    from vla_gr.text_fold import _fold_unicode

    rng = np.random.default_rng(0)
    texts = [
        "".join(map(chr, rng.integers(0, 128, size=int(n)))) for n in rng.integers(0, 40, 2000)
    ]
    texts += ["find the red chair\x00\x7f", " \t\n", "a - b -- c ... 'x' \"y\""]
    for text in texts:
        assert fold_to_ascii(text) == _fold_unicode(text), repr(text)


def test_a_non_str_is_a_type_error():
    with pytest.raises(TypeError, match="must be a str, got bytes"):
        fold_to_ascii(b"find the chair")
