"""A pass: its frames, each checked and placed in LVLH, fused into one attitude."""

from __future__ import annotations

import math
from datetime import datetime
from typing import TYPE_CHECKING

from pydantic import Field

from app.schemas.common import Described, StoredResult, utc_or_none
from app.schemas.estimates import AlternativePublic, AttitudePublic, CheckedPublic, QualityPublic

if TYPE_CHECKING:
    from app.db.models import Pass
    from inference.fit import CommonFit
    from scene.fusion import FusedFrame, PassAttitude


class PassFramePublic(Described):
    index: int
    """the frame's place in the upload (0-based)"""
    name: str
    """the frame's file name or stack member"""
    observed_at: datetime
    """when the frame was observed (UTC)"""
    attitude: AttitudePublic = Field(description="the frame's fitted attitude, in its own observation frame")
    attitude_network: AttitudePublic | None = None
    """Swin's own estimate for this frame"""
    refined: bool
    """whether the frame was fitted"""
    quality: QualityPublic
    """the frame's checks and bounds"""
    alternatives: list[AlternativePublic]
    """other attitudes that fit the frame nearly as well"""
    attitude_lvlh: AttitudePublic = Field(
        description="the branch the fusion took for this frame, body to LVLH at the frame's time, placed as the "
        "pass's answer sees it: for a turning target through the observation frame its rate turns"
    )
    branch: str = Field(description="answer, near-mirror, or alternative N: which of the frame's candidates agreed")
    used: bool
    """whether the fusion used this frame"""
    rejected_because: str | None = None
    """why it was not used, in words; null when used"""
    residual_deg: float = Field(
        description="rotation angle between this frame's branch and the fused attitude (for a turning target, the "
        "turning model's prediction for the frame)"
    )
    sweep_deg_s: float | None = Field(
        default=None,
        description="the line of sight's rate relative to the body as the radar measured it (aperture_deg / "
        "integration_s, deg/s); null when integration_s was not sent",
    )
    sweep_sigma_deg_s: float | None = Field(
        default=None,
        description="the 1-sigma error the fit gives sweep_deg_s (deg/s): 2 % of it, and more at a pass's ends, "
        "where one frame integrates for minutes and the rate changes over it; null without integration_s",
    )
    sweep_model_deg_s: float | None = Field(
        default=None,
        description="that rate as the pass's answer predicts it: the line of sight's own rate in LVLH for a still "
        "target, less the spin's part for a turning one",
    )

    @classmethod
    def from_frame(cls, f: FusedFrame) -> PassFramePublic:
        """Return one frame's part in a fused pass."""

        def deg_s(rad_s: float | None) -> float | None:
            return None if rad_s is None else round(math.degrees(rad_s), 5)

        return cls(
            index=f.index,
            name=f.name,
            observed_at=f.observed_at,
            **CheckedPublic.fields_of(f.checked),
            attitude_lvlh=AttitudePublic.from_matrix(f.attitude_lvlh),
            branch=f.branch,
            used=f.used,
            rejected_because=f.rejected_because,
            residual_deg=round(f.residual_deg, 4),
            sweep_deg_s=deg_s(f.sweep_rad_s),
            sweep_sigma_deg_s=deg_s(f.sweep_sigma_rad_s),
            sweep_model_deg_s=deg_s(f.sweep_model_rad_s),
        )


class PassAttitudeJ2000(AttitudePublic):
    at: datetime = Field(description="LVLH turns with the orbit: the J2000 attitude holds at this moment (mid-pass)")


class PassCommonFit(Described):
    frames: int
    """the frames fitted together"""
    moved_deg: float
    """how far (deg) the common fit moved the frames' robust mean"""
    silhouette_iou: float
    """the frames' mean soft IoU with the fitted attitude's silhouette"""

    @classmethod
    def from_common(cls, c: CommonFit) -> PassCommonFit:
        return cls(frames=c.frames, moved_deg=round(c.moved_deg, 4), silhouette_iou=round(c.iou, 4))


class PassResult(StoredResult):
    """What a pass answers and stores, beside its row's columns."""

    target: str
    """the target model the frames were fitted to"""
    attitude_lvlh: AttitudePublic = Field(
        description="the fused attitude, body to LVLH (x radial, y along-track, z normal)"
    )
    attitude_j2000: PassAttitudeJ2000
    """the fused attitude in J2000/GCRS at the pass's middle"""
    uncertainty_deg: list[float] = Field(description="90 % bound on the fused LVLH Euler z, y, x (deg)")
    alternative_lvlh: AttitudePublic | None = Field(
        default=None,
        description="another attitude (body to LVLH) that as many of the pass's frames agree with as with "
        "attitude_lvlh: the near-mirror, where the image plane barely turns over the pass (a reflection through it "
        "is then the same for every frame, so the pass's geometry cannot tell the two apart and the frames' own "
        "answers chose; uncertainty_deg does not cover it). Null when the frames tell them apart, and for a "
        "turning target",
    )
    trusted: bool = Field(
        default=True,
        description="false when fewer than 3 trusted frames agree: the fused attitude rests on too little",
    )
    used: int
    """how many frames the fusion used"""
    rejected: int
    """how many it did not use"""
    stable: bool | None = Field(
        description="true: three-axis stable over the pass; false: the frames show a body rate beyond their scatter; "
        "null: undecided, fewer than 3 trusted frames agree (see stability)"
    )
    rate_deg_s: list[float] = Field(description="the fitted body rate (deg/s, body axes)")
    rate_sigma_deg_s: list[float | None]
    """the fitted turning rate's standard error, deg/s (the turning model)"""
    turning_chi2: float | None = Field(
        default=None,
        description="how much better (chi-square, 3 degrees of freedom) a constant-rate model fits the frames than a "
        "still attitude; the target is called turning over 30",
    )
    common_fit: PassCommonFit | None = Field(
        default=None,
        description="a still pass's attitude_lvlh is the robust mean of its frames' answers, then fitted to the used "
        "frames' silhouettes all at once (their mean soft IoU, on a denser skin than a single frame's fit): how "
        "many frames, and how far the fit moved the mean. Null for a turning or undecided pass, or with fewer "
        "than 2 frames' silhouettes",
    )
    stability: str
    """the stability verdict in words: still in LVLH, or turning at a rate"""
    refined_on: str = Field(
        default="silhouette",
        description="what a still pass's attitude_lvlh was last refined on: 'image' (the used frames' images "
        "together, one attitude in LVLH, under the model set's reflectivity map) or 'silhouette' (no map, a map "
        "whose build found held-out passes not sharpened, a turning or undecided pass, or nothing better found)",
    )
    likelihood: dict[str, float] | None = Field(
        default=None,
        description="where refined_on is 'image': the frames refined together, their mean negative log-likelihood "
        "per pixel under the map at the silhouette fusion's attitude and after (start_nll_per_pixel, "
        "nll_per_pixel), and how far (deg) the refinement moved the attitude (moved_deg)",
    )
    frames: list[PassFramePublic]
    """every frame's own answer and its part in the fusion"""

    attitude_at: datetime | None = None
    """the moment attitude_j2000 holds (mid-pass), and a turning target's attitude_lvlh: the turning model's reference"""
    timings_s: dict[str, float] | None = None
    """where the time went, seconds per frame (decoding, the networks, the fit)"""

    @classmethod
    def from_pass(cls, p: PassAttitude, *, target: str, timings_s: dict[str, float] | None = None) -> PassResult:
        """Return a fused pass as the answer (angles and rates rounded as the answer states them)."""
        return cls(
            target=target,
            attitude_lvlh=AttitudePublic.from_matrix(p.attitude_lvlh),
            attitude_j2000=PassAttitudeJ2000(**dict(AttitudePublic.from_matrix(p.attitude_j2000)), at=p.attitude_at),
            uncertainty_deg=[round(b, 4) for b in p.uncertainty_deg],
            alternative_lvlh=None if p.alternative_lvlh is None else AttitudePublic.from_matrix(p.alternative_lvlh),
            trusted=p.trusted,
            used=p.used,
            rejected=p.rejected,
            stable=p.stable,
            rate_deg_s=[round(float(r), 5) for r in p.rate_deg_s],
            rate_sigma_deg_s=[round(float(r), 5) if math.isfinite(r) else None for r in p.rate_sigma_deg_s],
            turning_chi2=None if p.turning_chi2 is None else round(p.turning_chi2, 2),
            common_fit=None if p.common_fit is None else PassCommonFit.from_common(p.common_fit),
            stability=p.stability,
            refined_on=p.refined_on,
            likelihood=p.image_fit,
            frames=[PassFramePublic.from_frame(f) for f in p.frames],
            attitude_at=p.attitude_at,
            timings_s=timings_s,
        )


class _PassRow(Described):
    id: str
    """the pass's id"""
    created_at: datetime
    """when it was stored (UTC)"""
    plan_id: str | None
    """the plan the pass belongs to"""


class PassPublic(PassResult, _PassRow):
    @classmethod
    def from_row(cls, p: Pass) -> PassPublic:
        """Return a stored pass row, of any stored format, as the answer."""
        return cls.model_validate(
            {"id": p.id, "created_at": utc_or_none(p.created_at), "plan_id": p.plan_id, **PassResult.upgraded(p.result)}
        )


class PassSummary(Described):
    id: str
    """the pass's id"""
    created_at: datetime
    """when it was stored (UTC)"""
    plan_id: str | None
    """the plan the pass belongs to"""
    target: str
    """the target model the frames were read with"""
    frames: int
    """how many frames the pass had"""
    used: int
    """how many the fusion used"""
    trusted: bool
    """whether at least 3 trusted frames agree"""
    stable: bool | None
    """three-axis stable over the pass (true), turning (false), undecided (null)"""
    attitude_at: datetime | None
    """the moment the pass's attitude holds (mid-pass)"""

    @classmethod
    def from_row(cls, p: Pass) -> PassSummary:
        r = PassResult.upgraded(p.result)
        return cls(
            id=p.id,
            created_at=utc_or_none(p.created_at),
            plan_id=p.plan_id,
            target=r.get("target", ""),
            frames=len(r.get("frames", [])),
            used=r.get("used", 0),
            trusted=r.get("trusted", True),
            stable=r.get("stable"),
            attitude_at=r.get("attitude_at"),
        )


class PassesPublic(Described):
    data: list[PassSummary]
    """the passes of this page, newest first"""
    count: int
    """how many passes match in all"""
