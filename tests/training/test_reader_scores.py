"""The reader's scores on a hand-computed set: ECE, reading accuracy, refusals."""

import pytest

from vla_gr.agent.reading import Reading
from vla_gr.training.reader_training import expected_calibration_error, reading_scores


def test_ece_is_the_weighted_gap_between_confidence_and_accuracy_per_bin():
    # bin 0.9: confidence 0.9, accuracy 0.5 (gap 0.4, half the items); bin 0.1: 0.1 vs 0 (0.1)
    assert expected_calibration_error([0.9, 0.9, 0.1, 0.1], [1, 0, 0, 0]) == pytest.approx(0.25)
    assert expected_calibration_error([1.0, 1.0], [1, 1]) == pytest.approx(0.0)
    assert expected_calibration_error([], []) == 0.0


def test_scores_of_three_asks_and_two_refusals():
    sure = {"category": 1.0, "color": 1.0, "room": 1.0, "anchor": 1.0}
    rows = [
        {"request": "a", "refuse": False, "fields": {"category": "chair", "color": "red",
                                                     "room": None, "near": None}},
        {"request": "b", "refuse": False, "fields": {"category": "sofa", "color": None,
                                                     "room": "kitchen", "near": None}},
        {"request": "c", "refuse": False, "fields": {"category": "bed", "color": None,
                                                     "room": None, "near": "tv_monitor"}},
        {"request": "d", "refuse": True, "fields": {}},
        {"request": "e", "refuse": True, "fields": {}},
    ]  # fmt: skip
    readings = [
        Reading("a", "chair", "red", confidence=sure, understood=True),  # right
        Reading("b", "sofa", None, None, confidence=sure, understood=True),  # room missed
        Reading("c", "bed", None, None, "tv_monitor", confidence=sure, understood=False),
        Reading("d", understood=False, confidence=sure),
        Reading("e", "chair", confidence=sure, understood=True),  # acted on: wrong
    ]
    s = reading_scores(readings, rows)
    assert s["requests"] == 3 and s["refusals"] == 2
    assert s["reading_accuracy"] == pytest.approx(2 / 3)
    assert s["field_accuracy"]["room"] == pytest.approx(2 / 3)
    assert s["understood"] == pytest.approx(2 / 3)
    assert s["understood_and_right"] == pytest.approx(1 / 3)
    assert s["acted_on_wrongly"] == 1 and s["refused"] == pytest.approx(0.5)
    assert s["ece"] == pytest.approx(1 / 12)  # 12 fields at confidence 1, 11 right
