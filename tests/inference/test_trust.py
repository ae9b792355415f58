"""The shipped models' checked answers on fresh frames: accuracy, calibrated bounds, and what gets flagged.

Fresh frames come from seeds no training, validation, test or calibration set used
(inference/simulation/catalogue.py); the truth is the simulator's. The calibration (trust.json) was
fitted on other frames (seed 70000), so these tests hold it against data it never saw.
"""

import numpy as np
import pytest

from inference.runtime import Estimator
from inference.simulation.catalogue import FRESH_SEED, KINDS, bad_frames, good_frames
from inference.trust import load_checkers

N_GOOD = 200
N_BAD = 6  # about a second a frame (library search and fit); bench.trust measures the flag rates on more


@pytest.fixture(scope="module")
def shipped():
    est = Estimator.load()
    checkers = load_checkers(est.model_dir, est.img_size)
    return est, checkers.get(checkers.default)


@pytest.fixture(scope="module")
def good(shipped):
    est, checker = shipped
    frames, truth, snr = good_frames(N_GOOD, FRESH_SEED)
    res = est.estimate(frames)
    checks = checker.check_many(frames, res.enhanced, res.angles_deg)  # one by one's answers, on every core
    return truth, snr, res.angles_deg, checks


def test_the_fit_is_more_accurate_than_swin(good):
    truth, _, swin, checks = good
    fitted = np.array([c.angles_deg for c in checks])
    mae_fit = np.abs(fitted - truth).mean(axis=0)
    mae_swin = np.abs(swin - truth).mean(axis=0)
    assert np.all(mae_fit < mae_swin), (mae_fit, mae_swin)
    assert np.all(mae_fit <= 0.3), mae_fit  # the goal is 0.25 (BENCHMARKS.md has the figures)


def test_the_90_percent_bounds_hold_on_fresh_frames(good):
    truth, _, _, checks = good
    err = np.abs(np.array([c.angles_deg for c in checks]) - truth)
    bound = np.array([c.quality.uncertainty_deg for c in checks])
    coverage = (err <= bound).mean(axis=0)
    assert np.all((coverage >= 0.85) & (coverage <= 0.95)), coverage


def test_the_bounds_covariance_holds_the_errors_jointly(good):
    """The 90 % bounds' covariance (what a pass fuses with): its diagonal is the per-axis bounds squared, and the
    errors fall inside its 90 % ellipsoid (chi-square, 3 degrees of freedom: 6.25) about as often as that says.
    Measured: 88 % of 198 frames (86 % for the diagonal alone); y and x correlate by a median 0.31."""
    truth, _, _, checks = good
    inside = []
    for c, t in zip(checks, truth, strict=True):
        if c.bound_cov_deg2 is None:
            continue
        np.testing.assert_allclose(np.sqrt(np.diag(c.bound_cov_deg2)), c.quality.uncertainty_deg, atol=6e-4)
        assert np.all(np.linalg.eigvalsh(c.bound_cov_deg2) > 0)
        e = np.asarray(c.angles_deg) - t
        inside.append(e @ np.linalg.solve(c.bound_cov_deg2 / 1.6448536**2, e) <= 6.2514)
    assert len(inside) >= 0.9 * len(checks)
    assert 0.8 <= np.mean(inside) <= 0.97, np.mean(inside)


def test_few_good_frames_are_flagged(good):
    *_, checks = good
    flagged = np.mean([not c.quality.trusted for c in checks])
    assert flagged <= 0.05, [c.quality.reasons for c in checks if not c.quality.trusted]
    assert all(c.quality.reasons == [] for c in checks if c.quality.trusted)


@pytest.mark.parametrize("kind", KINDS)
def test_untrustworthy_frames_are_flagged(shipped, kind):
    est, checker = shipped
    frames = bad_frames(kind, N_BAD)
    res = est.estimate(frames)
    checks = checker.check_many(frames, res.enhanced, res.angles_deg)
    flagged = np.mean([not c.quality.trusted for c in checks])
    assert flagged >= 0.95, (kind, flagged)
    assert all(c.quality.reasons for c in checks if not c.quality.trusted)


def test_frames_checked_on_several_threads_get_the_answers_they_get_one_by_one(shipped):
    est, checker = shipped
    frames, _, _ = good_frames(6, FRESH_SEED + 900)
    res = est.estimate(frames)
    alone = [checker.check(frames[k], res.enhanced[k], res.angles_deg[k]) for k in range(len(frames))]
    threads = checker.threads
    try:
        checker.threads = 3
        together = checker.check_many(frames, res.enhanced, res.angles_deg)
    finally:
        checker.threads = threads
    for a, b in zip(alone, together, strict=True):
        np.testing.assert_array_equal(a.angles_deg, b.angles_deg)
        assert a.quality == b.quality
        np.testing.assert_array_equal(a.bound_cov_deg2, b.bound_cov_deg2)
