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
N_BAD = 12  # about a second a frame (library search and fit); bench.trust measures the flag rates on more


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
    checks = [checker.check(frames[k], res.enhanced[k], res.angles_deg[k]) for k in range(N_GOOD)]
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
    checks = [checker.check(frames[k], res.enhanced[k], res.angles_deg[k]) for k in range(N_BAD)]
    flagged = np.mean([not c.quality.trusted for c in checks])
    assert flagged >= 0.95, (kind, flagged)
    assert all(c.quality.reasons for c in checks if not c.quality.trusted)
