"""The shared value checks name the key and the valid choices."""

import pytest

from vla_gr.validation import check_choice, check_positive, check_positive_int


def test_check_choice_names_key_value_and_choices():
    check_choice("a.b", "x", ("x", "y"))
    with pytest.raises(ValueError, match=r"a\.b='z' is not valid; choose one of \['x', 'y'\]"):
        check_choice("a.b", "z", ("x", "y"))


def test_check_positive_and_positive_int():
    check_positive("k", 0.5)
    check_positive("k", 0, allow_zero=True)
    with pytest.raises(ValueError, match=r"k=0 must be > 0"):
        check_positive("k", 0)
    with pytest.raises(ValueError, match=r"k=-1 must be >= 0"):
        check_positive("k", -1, allow_zero=True)
    check_positive_int("n", 3)
    for bad in (0, -2, 2.0, True):
        with pytest.raises(ValueError, match="n=.* must be a positive int"):
            check_positive_int("n", bad)
