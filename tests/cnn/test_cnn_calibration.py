"""The choice of the decision rule's min_score from the groups a model finds."""

import pytest

from worker.training.calibration import Group, area_f1, choose_min_score


def test_a_separable_set_puts_min_score_above_the_false_alarms_with_a_margin():
    groups = [Group(0.62, 40.0, False), Group(0.66, 10.0, False), Group(0.9, 500.0, True)]
    value, rule = choose_min_score(groups)
    assert value == pytest.approx(0.75)  # 0.66 + 0.05, up to the next 0.05
    assert rule.startswith("above the highest false alarm")
    assert area_f1(groups, value) == 1.0


def test_overlapping_scores_take_the_threshold_with_the_best_kept_area_f1():
    # A large false alarm at 0.874 between real slides: dropping it would cost 1900 m2 of
    # slides; keeping the 8 m2 fragment at 0.779 costs nothing.
    groups = [
        Group(0.96, 1750.0, True),
        Group(0.874, 163.0, False),
        Group(0.865, 920.0, True),
        Group(0.854, 980.0, True),
        Group(0.804, 88.0, False),
        Group(0.779, 8.0, True),
    ]
    value, rule = choose_min_score(groups)
    assert value == pytest.approx(0.854)
    assert rule.startswith("no score separates")
    kept_true, kept_false, dropped_true = 1750 + 920 + 980, 163, 8
    expected = 2 * kept_true / (2 * kept_true + kept_false + dropped_true)
    assert area_f1(groups, value) == pytest.approx(expected)


def test_without_false_alarms_min_score_filters_nothing_the_pixel_rule_keeps():
    value, rule = choose_min_score([Group(0.9, 100.0, True), Group(0.72, 30.0, True)])
    assert value == pytest.approx(0.05)
    assert rule.startswith("above the highest false alarm")
