"""The protocol's statistics (rliable underneath) on synthetic data with known answers."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sdhn_experiments import protocol_stats as ps


def test_iqm_is_the_mean_of_the_middle_half() -> None:
    assert ps.iqm(np.arange(1.0, 9.0)) == pytest.approx(4.5)  # mean(3, 4, 5, 6)
    # an outlier run moves the mean, not the IQM
    assert ps.iqm([0.9, 0.9, 0.9, 0.0]) == pytest.approx(0.9)


def test_interval_estimates_cover_the_true_mean() -> None:
    """95 % intervals of the mean of 10 N(0.5, 0.1) runs contain 0.5 in most of 30 datasets
    (a bootstrap percentile interval with 10 runs under-covers a little)."""
    rng = np.random.default_rng(0)
    hits = 0
    for k in range(30):
        est = ps.interval_estimates({"a": rng.normal(0.5, 0.1, size=10)}, reps=200, seed=k)["a"]
        m = est["mean"]
        assert m.low <= m.point <= m.high
        hits += m.low <= 0.5 <= m.high
    assert 0.8 <= hits / 30 <= 1.0


def test_interval_of_identical_runs_is_a_point() -> None:
    est = ps.interval_estimates({"a": [0.7, 0.7, 0.7]}, reps=100)["a"]
    assert (est["iqm"].low, est["iqm"].point, est["iqm"].high) == pytest.approx((0.7,) * 3)


def test_interval_separates_clearly_different_methods() -> None:
    est = ps.interval_estimates({"good": [0.9, 0.92, 0.95, 0.91, 0.93],
                                 "bad": [0.5, 0.55, 0.52, 0.48, 0.51]}, reps=300)
    assert est["bad"]["mean"].high < est["good"]["mean"].low


def test_probability_of_improvement_known_values() -> None:
    assert ps.probability_of_improvement([3, 4, 5], [0, 1, 2]).point == 1.0
    assert ps.probability_of_improvement([0, 1, 2], [3, 4, 5]).point == 0.0
    # pairs: 3>2, 3<4, 5>2, 5>4, 6>2, 6>4 -> 5 of 6
    assert ps.probability_of_improvement([3, 5, 6], [2, 4]).point == pytest.approx(5 / 6)
    # ties count a half: (1,2) 0, (2,2) 0.5, (3,2) 1 -> 1.5 / 3
    assert ps.probability_of_improvement([1, 2, 3], [2, 2, 2]).point == pytest.approx(0.5)
    sure = ps.probability_of_improvement([3, 4, 5], [0, 1, 2], reps=100)
    assert sure.low == sure.high == 1.0
    unsure = ps.probability_of_improvement([0.8, 0.9, 0.7, 0.85], [0.75, 0.88, 0.8, 0.82],
                                           reps=100)
    assert unsure.low < 0.5 < unsure.high


def test_intervals_are_reproducible_whatever_ran_before() -> None:
    # rliable resamples from NumPy's global RNG: the report must not depend on who used it last
    # (one command regenerates a suite's tables), and must leave the global RNG as it found it.
    x = np.array([0.90, 0.85, 0.92, 0.88, 0.91, 0.87, 0.93, 0.89, 0.86, 0.90])
    y = np.array([0.91, 0.90, 0.92, 0.90, 0.905])
    first = ps.probability_of_improvement(x, y, reps=500)
    np.random.seed(123)  # noqa: NPY002 (rliable's global RNG)
    np.random.rand(17)  # noqa: NPY002 (rliable's global RNG)
    before = np.random.get_state()[1].copy()  # noqa: NPY002 (rliable's global RNG)
    assert ps.probability_of_improvement(x, y, reps=500) == first
    # ...and the seeding is undone
    assert np.array_equal(np.random.get_state()[1], before)  # noqa: NPY002
    assert ps.interval_estimates({"x": x}, reps=500) == ps.interval_estimates({"x": x}, reps=500)
    assert ps.probability_of_improvement(x, y, reps=500, seed=1) != first  # the seed matters


def test_ratio_of_means() -> None:
    r = ps.ratio_of_means([2.0, 2.0, 2.0], [4.0, 4.0, 4.0], reps=200)
    assert (r.low, r.point, r.high) == pytest.approx((0.5, 0.5, 0.5))
    r = ps.ratio_of_means([50, 55, 60], [100, 110, 120], reps=300)
    assert r.point == pytest.approx(0.5) and r.low < 0.5 < r.high


def test_curve_estimates_are_the_per_point_iqm() -> None:
    rng = np.random.default_rng(1)
    curves = rng.uniform(size=(6, 1, 4))
    point, lo, hi = ps.curve_estimates({"a": curves}, reps=200)["a"]
    np.testing.assert_allclose(point, [ps.iqm(curves[:, :, t]) for t in range(4)])
    assert np.all(lo <= point) and np.all(point <= hi)


def test_bad_scores_are_refused() -> None:
    with pytest.raises(ValueError, match="finite"):
        ps.interval_estimates({"a": [0.5, float("nan")]})
    with pytest.raises(ValueError, match="same tasks"):
        ps.probability_of_improvement(np.ones((3, 2)), np.ones((3, 1)))


def test_marl_eval_json_format() -> None:
    runs = [{"env": "MAIF", "task": "maif-10", "algorithm": "sdhn", "run": str(s),
             "steps": [(100, {"success_rate": [0.5]}), (200, {"success_rate": [0.7]})],
             "absolute": {"success_rate": [1.0, 0.0, 1.0]}} for s in (1, 2)]
    data = json.loads(json.dumps(ps.marl_eval_json(runs)))
    run = data["MAIF"]["maif-10"]["sdhn"]["2"]
    assert run["step_1"] == {"step_count": 200, "success_rate": [0.7]}
    assert run["absolute_metrics"] == {"success_rate": [1.0, 0.0, 1.0]}
    assert sorted(data["MAIF"]["maif-10"]["sdhn"]) == ["1", "2"]
    with pytest.raises(ValueError, match="twice"):
        ps.marl_eval_json(runs + runs[:1])
    with pytest.raises(ValueError, match="commas"):
        ps.marl_eval_json([{**runs[0], "algorithm": "sdhn,1"}])
