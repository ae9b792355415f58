"""The shipped models' checked answers on fresh frames: accuracy, calibrated bounds, and what gets flagged.

Fresh frames come from seeds no training, validation, test or calibration set used
(inference/simulation/catalogue.py); the truth is the simulator's. The calibration (trust.json) was
fitted on other frames (seed 70000), so these tests hold it against data it never saw.
"""

import numpy as np
import pytest

from inference.checked import Checked, Quality
from inference.rotations import euler_difference, geodesic_deg, reversed_reading
from inference.runtime import Estimator
from inference.simulation.catalogue import (
    FRESH_SEED,
    KINDS,
    SINGLE_FRAME_UNFLAGGABLE,
    bad_frames,
    bad_frames_truth,
    good_frames,
)
from inference.trust import library_iou_threshold, library_limits, load_checkers

N_GOOD = 200
N_SO3 = 60  # about 0.27 s a frame (most are searched); bench.so3 measures 200 a set
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
    checks = checker.check_many(
        frames, res.enhanced, res.angles_deg, search_enhancer=est.search_enhancer
    )  # one by one's answers, on every core
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


@pytest.mark.parametrize("kind", [k for k in KINDS if k not in SINGLE_FRAME_UNFLAGGABLE])
def test_untrustworthy_frames_are_flagged(shipped, kind):
    est, checker = shipped
    frames = bad_frames(kind, N_BAD)
    res = est.estimate(frames)
    checks = checker.check_many(frames, res.enhanced, res.angles_deg, search_enhancer=est.search_enhancer)
    flagged = np.mean([not c.quality.trusted for c in checks])
    assert flagged >= 0.95, (kind, flagged)
    assert all(c.quality.reasons for c in checks if not c.quality.trusted)


def test_frames_checked_on_several_threads_get_the_answers_they_get_one_by_one(shipped):
    est, checker = shipped
    frames, _, _ = good_frames(6, FRESH_SEED + 900)
    res = est.estimate(frames)
    alone = [
        checker.check(frames[k], res.enhanced[k], res.angles_deg[k], search_enhancer=est.search_enhancer)
        for k in range(len(frames))
    ]
    threads = checker.threads
    try:
        checker.threads = 3
        together = checker.check_many(frames, res.enhanced, res.angles_deg, search_enhancer=est.search_enhancer)
    finally:
        checker.threads = threads
    for a, b in zip(alone, together, strict=True):
        np.testing.assert_array_equal(a.angles_deg, b.angles_deg)
        assert a.quality == b.quality
        np.testing.assert_array_equal(a.bound_cov_deg2, b.bound_cov_deg2)


@pytest.fixture(scope="module")
def over_so3(shipped):
    est, checker = shipped
    frames, truth, _ = good_frames(N_SO3, FRESH_SEED + 43, attitudes="so3")
    res = est.estimate(frames)
    return truth, checker.check_many(frames, res.enhanced, res.angles_deg, search_enhancer=est.search_enhancer)


def test_the_shipped_calibration_holds_the_library_search_to_its_own_figures(shipped):
    """gsa calibrate --frames 600 --seed 70000 --so3-frames 1000: the library search's answers have their own
    thresholds and bounds, and no +-50 deg limit (the next test holds them against fresh frames)."""
    _, checker = shipped
    cal = checker.calibration
    assert cal.covers_library and cal.made["library_frames"] >= 500
    assert cal.library_iou_min < cal.iou_min and cal.library_doubt_max > cal.doubt_max
    assert cal.library_max_bound_deg <= cal.max_bound_deg


def test_a_cross_range_flipped_frame_is_read_as_the_attitude_it_shows(shipped):
    """Reversed columns are exactly the frame of the attitude turned half about the line of sight
    (tests/inference/simulation/test_scene.py), so over SO(3) no check of one frame can flag it: the service reads it
    as that attitude, whose reversed reading (the answer's attitude_reversed) is the truth. What must hold is that its
    trusted answers are right about what the frame shows, as for any frame."""
    est, checker = shipped
    n = 2 * N_BAD
    frames, truth = bad_frames("cross-range-flipped", n), bad_frames_truth("cross-range-flipped", n)
    res = est.estimate(frames)
    checks = checker.check_many(frames, res.enhanced, res.angles_deg, search_enhancer=est.search_enhancer)
    err = geodesic_deg(np.array([reversed_reading(c.angles_deg) for c in checks]), truth)
    trusted = np.array([c.quality.trusted for c in checks])
    assert np.median(err) <= 3.0, err
    # Measured: 6 of the 7 trusted within 3 deg; one 14.6 deg off, as the fit answers that attitude's own frame
    # (BENCHMARKS.md "Any attitude": the goal's "none beyond 10 deg trusted" is missed there).
    assert trusted.sum() >= 3 and np.mean(err[trusted] <= 5.0) >= 0.8, (err, trusted)


def test_answers_over_so3_are_held_to_the_library_search_s_own_calibration(over_so3):
    """Attitudes uniform over SO(3), a seed the calibration never saw: the search's answers are checked against the
    thresholds and bounds calibrated on its own answers (gsa calibrate --so3-frames), so a correct one far outside
    the networks' cube can be trusted, none over 10 deg off is, and the bounds cover most errors. Before, every
    answer outside +-50 deg was flagged (92 % of the correct ones; bench.so3 measures 200 frames a set)."""
    truth, checks = over_so3
    answers = np.array([c.angles_deg for c in checks])
    err = geodesic_deg(answers, truth)
    trusted = np.array([c.quality.trusted for c in checks])
    assert not np.any(trusted & (err > 10.0)), err[trusted].max()
    good = err <= 2.0
    # Measured with the search UNet++ (its silhouettes are what the search fits): 93 % good, 88 % of them trusted
    # (bench.so3 before it: 73 % of the good answers trusted, 27 % flagged).
    assert good.mean() >= 0.85 and trusted[good].mean() >= 0.7, (good.mean(), trusted[good].mean())
    assert np.any(trusted & (np.max(np.abs(answers), axis=1) > 90.0))
    bound = np.array([c.quality.uncertainty_deg for c in checks])
    coverage = (np.abs(euler_difference(answers, truth)) <= bound).mean(axis=0)
    assert np.all(coverage >= 0.75), coverage
    assert all(c.quality.reasons == [] for c in checks if c.quality.trusted)


def test_the_library_threshold_rises_above_every_wrong_answer_no_other_check_flags(shipped):
    """The rule, on made-up answers: under the correct answers' 1st percentile, and above a wrong answer (30 deg
    off) that passes every other check, but not above one whose bound already flags it."""
    _, checker = shipped

    def answer(angles, iou, raw):
        feats = {"median": 0.3, "doubt": 0.05, "iou": iou, "searched": 1.0, **{f"raw_{a}": raw for a in "zyx"}}
        return Checked(np.array(angles, float), None, True, Quality(iou, (1.0,) * 3, True, []), [], feats)

    truth = np.tile([120.0, 0.0, 0.0], (42, 1))  # outside the networks' cube, where the library's thresholds hold
    checks = [answer((120.5, 0.0, 0.0), iou, 1.0) for iou in np.linspace(0.80, 0.95, 40)]
    checks.append(answer((150.0, 0.0, 0.0), 0.91, 1.0))  # wrong, nothing else flags it
    checks.append(answer((120.0, 40.0, 0.0), 0.94, 1e3))  # wrong, but its bound is far over 5 deg
    cal = checker.calibration
    t = library_iou_threshold(checker, cal, checks, truth, np.ones(42, bool))
    assert 0.91 < t <= 0.912, t
    t_alone = library_iou_threshold(checker, cal, checks[:40], truth[:40], np.ones(40, bool))
    assert t_alone == pytest.approx(np.quantile(np.linspace(0.80, 0.95, 40), 0.01) - 0.005, abs=1e-4)


def test_a_calibration_with_too_few_so3_frames_is_a_one_line_error(capsys):
    from app.cli import main

    assert main(["calibrate", "--so3-frames", "10", "--out", "never.json"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--so3-frames 10" in err, err


def test_a_negative_count_of_robust_so3_frames_is_a_one_line_error(capsys):
    from app.cli import main

    assert main(["calibrate", "--so3-robust-frames", "-5", "--out", "never.json"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--so3-robust-frames -5" in err, err


def test_the_library_bound_limit_chosen_trusts_the_most_correct_answers(shipped):
    """The rule, on made-up answers: wrong ones (30 deg off) that fit the silhouette well but are loosely bounded
    (raw curvature 12: a 90 % bound of about 4 deg) force a high IoU threshold under a loose bound limit; a limit
    under their bounds flags them instead, so the threshold drops to the correct answers' 1st percentile and all
    the correct ones (bounds under 1 deg) are trusted. The chosen limit is that one."""
    _, checker = shipped

    def answer(angles, iou, raw):
        feats = {"median": 0.3, "doubt": 0.05, "iou": iou, "searched": 1.0, **{f"raw_{a}": raw for a in "zyx"}}
        return Checked(np.array(angles, float), None, True, Quality(iou, (1.0,) * 3, True, []), [], feats)

    ious = np.linspace(0.80, 0.95, 40)
    checks = [answer((120.5, 0.0, 0.0), iou, 1.0) for iou in ious]
    checks += [answer((150.0, 0.0, 0.0), 0.93, 12.0), answer((120.0, 25.0, 0.0), 0.94, 12.0)]
    truth = np.tile([120.0, 0.0, 0.0], (len(checks), 1))
    cal = library_limits(checker, checker.calibration, checks, truth, np.ones(len(checks), bool))
    bound = np.sqrt(np.asarray(cal.library_floor_deg) ** 2 + (12.0 * np.asarray(cal.library_scale)) ** 2).max()
    assert cal.library_max_bound_deg < bound <= checker.calibration.max_bound_deg, (cal.library_max_bound_deg, bound)
    assert cal.library_iou_min == pytest.approx(np.quantile(ious, 0.01) - 0.005, abs=1e-4)


def test_the_library_ambiguity_margin_chosen_flags_wrong_answers_a_rival_fits_nearly_as_well(shipped):
    """The rule, on made-up answers: wrong ones (its other branch, 60 deg off) that fit well (IoU 0.93) but whose
    rival, the truth's side, fits 0.01 worse force a high IoU threshold under the cube's 0.002 margin; a margin over
    0.01 flags them as ambiguous instead, so the threshold drops to the correct answers' 1st percentile and every
    correct answer (no rival within 0.05) is trusted. The chosen margin is that one, and it holds for the library
    path's answers alone: an answer inside the cube, found by the networks, keeps the 0.002."""
    from dataclasses import replace

    from inference.checked import Alternative

    _, checker = shipped

    def answer(angles, iou, gap, searched=1.0):
        feats = {"median": 0.3, "doubt": 0.05, "iou": iou, "searched": searched, **{f"raw_{a}": 1.0 for a in "zyx"}}
        rival = [Alternative((120.0, 0.0, 0.0), iou - gap, gap, 60.0, "other-branch")]
        return Checked(np.array(angles, float), None, True, Quality(iou, (1.0,) * 3, True, []), rival, feats)

    ious = np.linspace(0.80, 0.95, 40)
    checks = [answer((120.5, 0.0, 0.0), iou, 0.05) for iou in ious]
    checks += [answer((120.0, 30.0, 50.0), 0.93, 0.01), answer((120.0, -30.0, 50.0), 0.935, 0.01)]
    truth = np.tile([120.0, 0.0, 0.0], (len(checks), 1))
    cal = library_limits(
        checker, replace(checker.calibration, ambiguity_margin=0.002), checks, truth, np.ones(42, bool)
    )
    assert cal.library_ambiguity_margin > 0.01, cal.library_ambiguity_margin
    assert cal.library_iou_min == pytest.approx(np.quantile(ious, 0.01) - 0.005, abs=1e-4)
    inside = answer((10.0, 5.0, 0.0), 0.99, 0.005, searched=0.0)  # the networks' answer in the cube, a rival 0.005 off
    compare = [answer((120.0, 30.0, 50.0), 0.93, 0.005)]  # a library answer with the same rival
    from inference.trust import trusted_under

    assert trusted_under(checker, cal, [inside]).tolist() == [True]
    assert trusted_under(checker, cal, compare).tolist() == [False]


def test_a_recalibrated_network_path_widens_its_bound_limit_and_margin_as_far_as_its_wrong_answers_allow(shipped):
    """The rule, on made-up network answers of another radar (inside the cube, every other check passed; bound =
    raw under a unit scale and no floor): the correct ones are bounded at 5.5-6.5 deg with a rival 0.0015 behind,
    the wrong ones (8 and 20 deg off) at 9 deg or with a rival that fits 0.003 better. The 5 deg limit and 0.002
    margin flag every correct answer; the tightest limit over the correct answers' bounds (7 deg; 10 would trust the
    wrong one's 9) and the widest margin under the correct answers' rival gap (0.001: none still flags the rival that fits better)
    trust them all. The choice is recorded; the base limits stay where nothing is gained."""
    from dataclasses import replace

    from inference.checked import Alternative
    from inference.trust import network_limits, trusted_under

    _, checker = shipped
    base = replace(checker.calibration, scale=(1.0, 1.0, 1.0), floor_deg=(0.0, 0.0, 0.0), iou_min=0.9)

    def answer(angles, raw, gap):
        feats = {"median": 0.3, "doubt": 0.0, "iou": 0.97, "searched": 0.0, **{f"raw_{a}": raw for a in "zyx"}}
        rival = [Alternative((-10.0, 5.0, 0.0), 0.97 - gap, gap, 30.0, "other-branch")]
        return Checked(np.array(angles, float), None, True, Quality(0.97, (raw,) * 3, True, []), rival, feats)

    right = [answer((10.0, 5.0, 0.3), raw, 0.0015) for raw in np.linspace(5.5, 6.5, 20)]
    wrong = [answer((10.0, 13.0, 0.0), 9.0, 0.05), answer((30.0, 5.0, 0.0), 3.0, -0.003)]
    truth = np.tile([10.0, 5.0, 0.0], (22, 1))
    assert not trusted_under(checker, base, right).any()
    cal = network_limits(checker, base, right + wrong, truth)
    assert (cal.max_bound_deg, cal.ambiguity_margin) == (7.0, 0.001)
    assert trusted_under(checker, cal, right).all() and not trusted_under(checker, cal, wrong).any()
    assert cal.made["network_limits"]["correct_trusted"] == 20
    # Correct answers the base limits already trust: nothing to gain, the base limits kept.
    tight = [answer((10.0, 5.0, 0.3), raw, 0.05) for raw in np.linspace(1.0, 3.0, 20)]
    kept = network_limits(checker, base, tight + wrong, truth)
    assert (kept.max_bound_deg, kept.ambiguity_margin) == (base.max_bound_deg, base.ambiguity_margin)


def test_the_library_search_is_triggered_by_its_own_threshold_not_the_trust_threshold(shipped):
    """A set recalibrated on another radar keeps its base set's search trigger (Calibration.search_iou_min) while
    its trust threshold falls: whether a frame is searched follows the trigger alone, and without one, iou_min."""
    from dataclasses import replace

    est, checker = shipped
    frames, _, _ = good_frames(1, FRESH_SEED + 4300)
    res = est.estimate(frames)
    kept = checker.calibration
    searched = {}
    try:
        for name, cal in {
            "trigger above, trust threshold below": replace(kept, iou_min=0.0, search_iou_min=1.0),
            "trigger below, trust threshold above": replace(kept, iou_min=1.0, search_iou_min=0.0),
            "no trigger, trust threshold above": replace(kept, iou_min=1.0, search_iou_min=None),
        }.items():
            checker.calibration = cal
            c = checker.check(frames[0], res.enhanced[0], res.angles_deg[0], search_enhancer=est.search_enhancer)
            searched[name] = c.features["searched"] > 0.5
    finally:
        checker.calibration = kept
    assert searched == {
        "trigger above, trust threshold below": True,
        "trigger below, trust threshold above": False,
        "no trigger, trust threshold above": True,
    }


@pytest.mark.parametrize("index", [26, 174])
def test_a_wrong_branch_answer_over_so3_comes_back_to_the_truth_side(shipped, index):
    """Two frames of bench.so3's draw (seed 77000) that came back on the wrong branch, untrusted, with the truth side
    absent from the alternatives (issue 43's goal: listed within 5 deg). 174: the answer 9.7 deg off the truth's
    mirror, its other branch refit in Euler steps stalled 7.4 deg from the truth. 26: the bright parts chose the
    wrong branch's fit over the library fit 8.3 deg from the truth, whose own other branch was never refit. The
    simulator's truth fits better than either (soft IoU 0.790 / 0.885): the answer must be the truth side."""
    from inference.simulation.catalogue import at_attitudes
    from inference.simulation.dataset import DatasetSpec, frame_truth

    est, checker = shipped
    angles, snr, seed = frame_truth(DatasetSpec(n=200, seed=77000, attitudes="so3"), index)
    frames, _ = at_attitudes(np.array([angles], float), np.array([np.nan if snr is None else snr]), [seed])
    res = est.estimate(frames)
    c = checker.check(frames[0], res.enhanced[0], res.angles_deg[0], search_enhancer=est.search_enhancer)
    assert geodesic_deg(c.angles_deg, np.array(angles))[0] < 5.0, (angles, c.angles_deg, c.alternatives)


@pytest.mark.parametrize(
    ("seed", "attitudes", "index", "before"),
    [(77000, "so3", 141, 21.5), (77000, "so3", 293, 179.3), (77002, "cube", 96, 47.2), (77002, "cube", 312, 24.6)],
)
def test_a_search_answer_settles_in_the_basin_that_fits_best_not_the_first_it_finds(
    shipped, seed, attitudes, index, before
):
    """Frames of bench.so3's 600-frame draws the search answered ``before`` deg off the simulator's truth, whose own
    basin fits their silhouette better (design/measurements.md, "Neighbouring basins and the library's starts"):

    - 141: the fine fit settled in a basin 21 deg off, tilted out of the image plane; the truth's basin fits better
      (soft IoU 0.948 against 0.940): the answer's tilts reach it.
    - 293 (trusted, 179 deg off): the library entry 13 deg from the truth began 0.06 behind the best entry, and the
      coarse fit pruned it before it moved; refined, it ends the coarse fit 0.09 ahead.
    - 96, 312: the cube's frames at the noise floor (both flagged), searched on the search UNet++'s poorer silhouette
      there; inside the cube the networks' UNet++ is the one trained on it. Within 10 deg before that UNet++ came."""
    from inference.simulation.catalogue import at_attitudes
    from inference.simulation.dataset import DatasetSpec, frame_truth

    est, checker = shipped
    spec = DatasetSpec(n=600, seed=seed, attitudes="so3") if attitudes == "so3" else DatasetSpec(n=600, seed=seed)
    angles, snr, frame_seed = frame_truth(spec, index)
    frames, _ = at_attitudes(np.array([angles], float), np.array([np.nan if snr is None else snr]), [frame_seed])
    res = est.estimate(frames)
    c = checker.check(frames[0], res.enhanced[0], res.angles_deg[0], search_enhancer=est.search_enhancer)
    err = geodesic_deg(c.angles_deg, np.array(angles))[0]
    assert err < min(10.0, before / 2), (angles, c.angles_deg, c.quality.reasons)


@pytest.mark.parametrize(("seed", "index"), [(77000, 509), (77001, 195), (77001, 427)])
def test_a_search_answer_on_the_wrong_branch_lists_the_truth_side_its_tilts_reach(shipped, seed, index):
    """Frames over SO(3) (bench.so3's draws of 600, default scattering) the search answered on the wrong branch
    without the truth side among the alternatives (issue 43: listed within 5 deg):

    - 509: the answer and the other branch's best fit both lie in a valley 30 deg long (soft IoU within 0.002); the
      other branch's fit, 13.7 deg from the truth, reaches a fit 3 deg from it once tilted.
    - 195: the coarse fit dragged the answer's exact mirror, 1.4 deg from the truth, into a neighbouring basin
      11.7 deg off; refined fine from the mirror itself it stays.
    - 427 (179 deg off): the other branch's refit stopped 16 deg from the truth at soft IoU 0.67 where the truth's
      basin fits at 0.78, better than the answer (0.73); its tilts reach it.

    The answer or one of its alternatives must lie within 5 deg of the simulator's truth."""
    from inference.simulation.catalogue import at_attitudes
    from inference.simulation.dataset import DatasetSpec, frame_truth

    est, checker = shipped
    angles, snr, frame_seed = frame_truth(DatasetSpec(n=600, seed=seed, attitudes="so3"), index)
    frames, _ = at_attitudes(np.array([angles], float), np.array([np.nan if snr is None else snr]), [frame_seed])
    res = est.estimate(frames)
    c = checker.check(frames[0], res.enhanced[0], res.angles_deg[0], search_enhancer=est.search_enhancer)
    found = [c.angles_deg, *(np.array(a.angles_deg) for a in c.alternatives)]
    nearest = min(float(geodesic_deg(a, np.array(angles))[0]) for a in found)
    assert nearest <= 5.0, (angles, c.angles_deg, [a.angles_deg for a in c.alternatives])


def test_the_bright_parts_choose_the_truth_side_branch_when_the_wrong_one_fits_a_little_better(shipped):
    """Frame 377 of a fresh 600-frame draw of the robust preset over SO(3) (seed 78001): the wrong branch's
    silhouette fits 0.031 better than the truth side's (UNet++ draws this preset poorly), past the library path's
    ambiguity margin 0.02, so it came back 148 deg off the simulator's truth, trusted. Its bright parts agree 0.80
    with the frame, the truth side's 0.94: the answer must be the truth side, listing the wrong branch as an
    alternative that fits better, and not trusted (design/measurements.md, "The bright parts choose between the
    branches from further off")."""
    from inference.fit import mirror
    from inference.simulation.dataset import DatasetSpec, render_frames

    est, checker = shipped
    arr = render_frames(DatasetSpec(n=600, seed=78001, attitudes="so3", variety="robust"), checker.radar, 377, 378)
    frames, truth = arr["image"].astype(np.float32), arr["angles_deg"][0].astype(float)
    res = est.estimate(frames)
    c = checker.check(frames[0], res.enhanced[0], res.angles_deg[0], search_enhancer=est.search_enhancer)
    assert geodesic_deg(c.angles_deg, truth)[0] < 2.0, (truth, c.angles_deg, c.alternatives)
    assert not c.quality.trusted and any("its bright parts worse" in r for r in c.quality.reasons), c.quality.reasons
    assert any(geodesic_deg(np.array(a.angles_deg), mirror(truth))[0] < 5.0 and a.fit_gap < 0 for a in c.alternatives)


def test_a_frame_whose_truth_lies_past_the_fourth_library_match_is_not_answered_half_a_turn_off(shipped):
    """A frame at bench frame 293's attitude with other noise (SNR 8 dB, seed 4302), sent to the service: with the
    library's best four matches as the search's starts it came back 179 deg off the simulator's truth, trusted (IoU
    0.81; the truth fits at 0.92). The entries that lead to the truth were the fifth and sixth matches."""
    from inference.simulation.catalogue import at_attitudes

    est, checker = shipped
    truth = np.array([-38.6, 62.6, -126.5])
    frames, _ = at_attitudes(truth[None], np.array([8.0]), [4302])
    res = est.estimate(frames)
    c = checker.check(frames[0], res.enhanced[0], res.angles_deg[0], search_enhancer=est.search_enhancer)
    assert geodesic_deg(c.angles_deg, truth)[0] < 5.0, (c.angles_deg, c.quality)


def test_an_answers_tilts_turn_it_out_of_the_image_plane_by_the_stated_angle(shipped):
    """``tilted``, against scipy's rotations: each of the four attitudes is the answer turned by ``TILT_DEG`` about an
    axis in the image plane (range and cross-range, either way), none about the image's normal, whatever the
    attitude (y near 90 deg included, where Euler steps lose an axis)."""
    from scipy.spatial.transform import Rotation

    from inference.trust import TILT_DEG, tilted

    _, checker = shipped
    for a in ([10.0, 20.0, 30.0], [-150.0, 89.0, 40.0], [0.0, 0.0, 0.0]):
        base = Rotation.from_euler("ZYX", a, degrees=True)
        turns = [Rotation.from_euler("ZYX", t, degrees=True) * base.inv() for t in tilted(checker.renderer, a)]
        vecs = np.degrees([t.as_rotvec() for t in turns])
        assert np.allclose(np.linalg.norm(vecs, axis=1), TILT_DEG, atol=1e-6)
        assert np.allclose(vecs[:, 2], 0.0, atol=1e-6)  # about axes in the image plane
        assert np.allclose(np.abs(vecs[:, :2]).max(axis=1), TILT_DEG, atol=1e-6)  # range or cross-range
        assert len({tuple(np.round(v, 6)) for v in vecs}) == 4


def test_each_threshold_is_calibrated_on_the_answers_it_judges(shipped):
    """The rule, on made-up answers, as on another radar's 40 held-out frames (harsh 100/5: 23 of them searched at
    the base set's trigger, too few for a library calibration of their own). Half the frames' network answers fit
    (IoU 0.98, UNet++ unsure of 4-6 % of the silhouette); the other half's do not (IoU 0.90, under the trigger
    0.97), so the search answers them, correctly, 20-30 deg from Swin's wrong answer, on silhouettes UNet++ is unsure
    of for 15-20 %. Those answers are held to the network path's doubt threshold and bounds, so the threshold must
    cover their doubt (by hand: the 99th percentile of all 40, 0.199, times 1.25), and the "moved from Swin" check
    must not judge them (the search is there because Swin was wrong). Before, the thresholds came from the 20
    network answers alone (doubt under 7.5 %) and every searched answer was flagged twice."""
    import copy

    from inference.trust import bounds_from, calibrate, trusted_under

    _, shipped_checker = shipped
    checker = copy.copy(shipped_checker)
    n, half = 40, 20
    rng = np.random.default_rng(5)
    truth = rng.uniform(-30.0, 30.0, (n, 3))
    doubt = np.r_[np.linspace(0.04, 0.06, half), np.linspace(0.15, 0.20, half)]
    swin_off = np.r_[np.linspace(0.5, 2.0, half), np.linspace(20.0, 30.0, half)]

    def one(k: int, cal) -> Checked:
        searched = k >= half and 0.90 < cal.search_below
        err = 0.4 if k < half or searched else swin_off[k]
        angles = truth[k] + np.array([err, 0.0, 0.0])
        feats = {"median": 0.3, "doubt": doubt[k], "iou": 0.98 if k < half else (0.93 if searched else 0.90)}
        feats.update({"searched": float(searched), "soft_iou": feats["iou"], "moved_deg": abs(swin_off[k] - err)})
        feats.update({f"raw_{a}": 1.0 for a in "zyx"})
        bound = bounds_from(np.ones(3), *cal.bounds_model(searched))
        reasons = checker._reasons(feats, angles, bound, [], True, searched)
        return Checked(angles, truth[k], True, Quality(feats["iou"], tuple(bound), not reasons, reasons), [], feats)

    checker.check_many = lambda frames, *a, **k: [one(i, checker.calibration) for i in range(len(frames))]
    cal, checks = calibrate(checker, np.zeros((n, 4, 4)), np.zeros((n, 4, 4)), truth, truth, search_iou_min=0.97)
    assert [c.features["searched"] for c in checks] == [0.0] * half + [1.0] * half
    assert not cal.covers_library
    assert cal.doubt_max == pytest.approx(np.quantile(doubt, 0.99) * 1.25, abs=1e-4)
    assert cal.moved_max_deg == pytest.approx(max(np.quantile(swin_off[:half] - 0.4, 0.99) * 1.5, 3.0), abs=1e-3)
    assert trusted_under(checker, cal, checks).all(), [c.quality.reasons for c in checks if not c.quality.trusted]


def test_a_library_search_fits_the_search_unets_silhouette_not_the_networks(shipped):
    """``search_enhancer``: the UNet++ whose silhouette a search fits. Here the networks' enhanced frame is blank (no
    answer fits it, so the frame is searched) and the search's silhouette is the simulator's own label of an attitude
    far outside the networks' cube: the answer must be that attitude (or list it: a silhouette alone leaves the
    near-mirror pair), fitting the label, never the blank frame."""
    from inference.simulation.catalogue import at_attitudes

    est, checker = shipped
    truth = np.array([150.0, -55.0, 120.0])
    frames, labels = at_attitudes(truth[None], np.array([10.0]), [4301])
    blank = np.zeros_like(frames[0])
    calls = []

    def label_of(frame):
        calls.append(frame.shape)
        return labels[0].astype(np.float32)

    c = checker.check(frames[0], blank, np.zeros(3), search_enhancer=label_of)
    assert calls == [frames[0].shape] and c.features["searched"] > 0.5
    found = [np.asarray(c.angles_deg), *[np.array(a.angles_deg) for a in c.alternatives]]
    assert min(geodesic_deg(np.array(found), truth)) < 3.0, (c.angles_deg, c.alternatives)
    assert c.quality.silhouette_iou > 0.85  # scored on the search's silhouette
    without = checker.check(frames[0], blank, np.zeros(3))
    assert without.quality.silhouette_iou == 0.0 and not without.quality.trusted


def test_a_network_answer_that_cannot_fit_is_not_fitted_and_the_answers_are_those_of_fitting_it(shipped, monkeypatch):
    """``NETWORK_FIT_GAIN``: where neither Swin's answer nor its near-mirror comes within the gain of
    ``search_below``, the check skips their fits. Against the brute force on fresh frames over SO(3): fitting them
    (as the check would) raises the better one's IoU by less than the gain, so it never reaches ``search_below``;
    and the checked answers, trust and alternatives are those of the check that fits every network answer."""
    import inference.trust as trust
    from inference.fit import fit, mirror, silhouette_iou

    est, checker = shipped
    frames, _, _ = good_frames(12, FRESH_SEED + 47, attitudes="so3")
    res = est.estimate(frames)
    below = checker.calibration.search_below
    skipped = 0
    for k in range(len(frames)):
        net, enh = res.angles_deg[k], res.enhanced[k].astype(np.float64)
        raw = float(np.max(silhouette_iou(checker.renderer, np.stack([net, mirror(net)]), enh)))
        fitted = fit(checker.renderer, enh, {"network": net, "mirror": mirror(net)}, prior_at=net, keep=("mirror",))
        gain = float(silhouette_iou(checker.renderer, fitted[0].angles_deg, enh)[0]) - raw
        assert gain < trust.NETWORK_FIT_GAIN, (k, raw, gain)
        skipped += raw < below - trust.NETWORK_FIT_GAIN
    assert skipped >= len(frames) // 2  # most of Swin's in-cube answers are far off on frames over SO(3)
    quick = checker.check_many(frames, res.enhanced, res.angles_deg, search_enhancer=est.search_enhancer)
    monkeypatch.setattr(trust, "NETWORK_FIT_GAIN", 10.0)  # every network answer fitted, as before
    full = checker.check_many(frames, res.enhanced, res.angles_deg, search_enhancer=est.search_enhancer)
    for q, f in zip(quick, full, strict=True):
        np.testing.assert_allclose(q.angles_deg, f.angles_deg, atol=1e-9)
        assert q.quality == f.quality
        assert [a.angles_deg for a in q.alternatives] == [a.angles_deg for a in f.alternatives]


@pytest.mark.parametrize("n", [20, 40, 100])
def test_bounds_fitted_on_few_frames_cover_ninety_percent_of_the_next_frames(n):
    """``fit_bounds`` on n frames, held to the closed form: errors drawn as N(0, (0.3 raw)^2 + 0.05^2) deg, whose
    chance of lying within a bound b is erf(b / (sigma sqrt 2)). Averaged over 1,000 draws of n calibration frames,
    the bound must cover at least 89 % of the next frames (nominal 90 %; 89.8 / 89.4 / 89.5 % at n = 20 / 40 / 100).
    The empirical 90 % quantile covered 85.6 / 87.3 / 88.6 % (an adapted set's held-out scenes hold 40 frames)."""
    from scipy.special import erf

    from inference.trust import fit_bounds

    rng = np.random.default_rng(20261206)
    fresh_raw = rng.lognormal(0.0, 0.5, 4000)
    fresh_sigma = np.sqrt((0.3 * fresh_raw) ** 2 + 0.05**2)
    covered = []
    for _ in range(1000):
        raw = rng.lognormal(0.0, 0.5, n)
        err = rng.normal(0.0, np.sqrt((0.3 * raw) ** 2 + 0.05**2))
        scale, floor = fit_bounds(raw, err)
        bound = np.sqrt(floor**2 + (scale * fresh_raw) ** 2)
        covered.append(np.mean(erf(bound / (fresh_sigma * np.sqrt(2.0)))))
    assert np.mean(covered) >= 0.89, np.mean(covered)


def test_network_answers_that_fit_under_the_search_trigger_are_searched_and_keep_the_better_fit(shipped):
    """``SEARCH_SHARE``: the search trigger sits above the trust threshold, so a network answer the threshold trusts
    with little margin is re-examined by the library search. Robust-preset frames in the cube fit the networks'
    silhouettes worse than our own frames (IoU 0.96 at the median against 0.99), most of them between the two. Against
    the brute force, the same frames checked on the network path alone (``search`` off): every frame under the
    trigger is searched, and each searched answer inside the cube fits the networks' silhouette at least as well as
    the network's fit, to the bright parts' tie-break margin (the search keeps the network's fits among its starts;
    where the bright parts chose the answer's other branch, which then fits better and is listed, to that margin)."""
    from inference.trust import BRANCH_BRIGHTNESS_MARGIN, BRIGHTNESS_MARGIN, in_cube

    est, checker = shipped
    cal = checker.calibration
    assert cal.search_below > cal.iou_min
    frames, truth, _ = good_frames(12, FRESH_SEED + 53, variety="robust")
    res = est.estimate(frames)
    between = 0
    for k in range(len(frames)):
        alone = checker.check(frames[k], res.enhanced[k], res.angles_deg[k], search=False)
        c = checker.check(frames[k], res.enhanced[k], res.angles_deg[k], search_enhancer=est.search_enhancer)
        under = alone.features["iou"] < cal.search_below
        assert (c.features["searched"] > 0.5) == under, (k, alone.features["iou"])
        if not under:
            continue
        between += alone.features["iou"] >= cal.iou_min
        if in_cube(c.angles_deg):
            chosen = any(a.fit_gap < 0 for a in c.alternatives)  # by the bright parts, over a better fit
            margin = BRANCH_BRIGHTNESS_MARGIN if chosen else BRIGHTNESS_MARGIN
            assert c.features["soft_iou"] >= alone.features["soft_iou"] - margin, k
        assert not (c.quality.trusted and geodesic_deg(c.angles_deg, truth[k])[0] > 5.0), k
    assert between >= 3  # the frames the trigger adds: trusted by the threshold, now searched


def test_the_answers_unrefined_near_mirror_is_listed_but_never_judged_as_a_rival_fit(shipped):
    """The same answer with one alternative fitting as well (gap 0): flagged as ambiguous where that alternative is
    a fit, not where it is the answer's exact near-mirror listed unrefined (the margins were calibrated on the fitted
    alternatives, which are judged instead); the API says which is which."""
    from app.schemas.estimates import AlternativePublic
    from inference.checked import Alternative
    from inference.trust import AMBIGUOUS, NEAR_MIRROR, trusted_under

    _, checker = shipped
    feats = {"median": 0.3, "doubt": 0.0, "iou": 0.99, "searched": 0.0, **{f"raw_{a}": 0.1 for a in "zyx"}}

    def answer(start):
        rival = [Alternative((10.0, -20.0, -30.0), 0.99, 0.0, 70.0, start)]
        return Checked(np.array([10.0, 20.0, 30.0]), None, True, Quality(0.99, (0.5,) * 3, True, []), rival, feats)

    fitted, twin = answer("other-branch"), answer(NEAR_MIRROR)
    assert trusted_under(checker, checker.calibration, [fitted, twin]).tolist() == [False, True]
    bound = np.full(3, 0.5)
    reasons = checker._reasons(feats, fitted.angles_deg, bound, fitted.alternatives, False, False)
    assert reasons and reasons[0].endswith(AMBIGUOUS)
    assert [AlternativePublic.from_alternative(c.alternatives[0]).fitted for c in (fitted, twin)] == [True, False]
