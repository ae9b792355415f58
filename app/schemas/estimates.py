"""An estimate: a frame's checked attitude, in its observation frame and, placed by a plan, in LVLH and J2000."""

from __future__ import annotations

import math
from collections.abc import Sequence
from datetime import datetime
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from app.schemas.common import Described, StoredResult, utc_or_none
from inference.rotations import euler_from_matrix, euler_to_quaternion, reversed_reading, rotation_matrix

if TYPE_CHECKING:
    from app.db.models import Estimate
    from inference.checked import Alternative, Checked, Quality


def _attitude_fields(angles_deg: Sequence[float] | NDArray[np.floating]) -> dict[str, Any]:
    z, y, x = (float(a) for a in angles_deg)
    return {
        "euler_zyx_deg": [z, y, x],
        "quaternion_wxyz": list(euler_to_quaternion(z, y, x)),
        "rotation_matrix": rotation_matrix(z, y, x).round(12).tolist(),
    }


class AttitudePublic(Described):
    euler_zyx_deg: list[float] = Field(description="Euler angles z, y, x (deg): R = Rz Ry Rx, body to frame")
    quaternion_wxyz: list[float]
    """the same rotation as a unit quaternion, scalar first (body to frame)"""
    rotation_matrix: list[list[float]]
    """the same rotation as a 3 x 3 matrix, rows the frame's axes in body coordinates (body to frame: v_frame = R v_body)"""

    @classmethod
    def from_euler(cls, angles_deg: Sequence[float] | NDArray[np.floating]) -> AttitudePublic:
        """Return an attitude given as Euler z, y, x (deg)."""
        return cls(**_attitude_fields(angles_deg))

    @classmethod
    def from_matrix(cls, r: NDArray[np.float64]) -> AttitudePublic:
        """Return an attitude given as a rotation matrix, which it keeps as given (not rebuilt from its angles)."""
        return cls(**{**_attitude_fields(euler_from_matrix(r)), "rotation_matrix": np.asarray(r).round(12).tolist()})


class QualityPublic(Described):
    silhouette_iou: float = Field(
        description="IoU of the fitted projection (the label the simulator would draw) with UNet++'s silhouette; "
        "fresh frames of the default target: 0.98-0.99"
    )
    uncertainty_deg: list[float | None] = Field(
        description="90 % bound on the error of z, y, x (deg), calibrated on fresh frames (inference/models/shipped/"
        "trust.json); null where the fit's curvature bounds nothing"
    )
    trusted: bool = Field(description="false when any check failed; reasons says which")
    reasons: list[str] = Field(description="each failed check in words; empty when trusted")

    @classmethod
    def from_quality(cls, q: Quality) -> QualityPublic:
        return cls(
            silhouette_iou=q.silhouette_iou,
            uncertainty_deg=[b if math.isfinite(b) else None for b in q.uncertainty_deg],
            trusted=q.trusted,
            reasons=list(q.reasons),
        )


class AlternativePublic(AttitudePublic):
    silhouette_iou: float
    """IoU of this attitude's projection with UNet++'s silhouette"""
    fit_gap: float = Field(
        description="how much lower its soft IoU is than the answer's; negative when it fits better but the answer "
        "stays nearer Swin's estimate (Swin saw the brightness the silhouette lacks)"
    )
    distance_deg: float = Field(description="rotation angle between it and the answer")
    fitted: bool = Field(
        default=True,
        description="false for the answer's exact near-mirror (z, -y, -x), listed as it is where the fit on that "
        "branch settled over 2 deg from it: the other branch read as accurately as the answer's own, which the "
        "silhouette alone does not single out (never counted as a rival fit by the ambiguity check)",
    )

    @classmethod
    def from_alternative(cls, a: Alternative) -> AlternativePublic:
        from inference.trust import NEAR_MIRROR  # loaded already: ``a`` came from it

        return cls(
            **_attitude_fields(a.angles_deg),
            silhouette_iou=round(a.silhouette_iou, 4),
            fit_gap=round(a.fit_gap, 5),
            distance_deg=round(a.distance_deg, 2),
            fitted=a.start != NEAR_MIRROR,
        )


class CheckedPublic(Described):
    """A frame's checked answer: the fitted attitude, the networks' own, its quality and its lookalikes."""

    attitude: AttitudePublic = Field(
        description="in the ISAR observation frame: the fitted attitude (Swin's own when refine=false)"
    )
    attitude_network: AttitudePublic | None = Field(
        None, description="Swin's own estimate, the fit's start (null for a target without trained networks)"
    )
    refined: bool = Field(True, description="whether the attitude was fitted to the target's projection")
    refined_on: str = Field(
        "silhouette",
        description="what the answer was refined on: 'image' (the frame's likelihood under the model set's "
        "reflectivity map), 'silhouette' (the target's projection fitted to UNet++'s silhouette) or 'network' "
        "(Swin's own answer, refine=false)",
    )
    likelihood: dict[str, float] | None = Field(
        None,
        description="where refined_on is 'image': the answer's negative log-likelihood per pixel under the map "
        "(nll_per_pixel), and its speckle deviance per pixel (deviance) against the most the map's held-out "
        "labelled frames showed (deviance_max); over that, the frame is flagged as not this radar's look",
    )
    attitude_reversed: AttitudePublic | None = Field(
        None,
        description="the attitude the same frame shows read with its cross-range axis reversed: the answer turned "
        "half about the line of sight (RX_180 R). A single frame cannot tell the two apart, whatever the scattering, "
        "since that half turn keeps the line of sight's direction in the body; the answer assumes docs/estimation.md's image "
        "convention. This one holds where the radar's cross-range sense is the opposite, or the target turns against "
        "the line of sight faster than it sweeps (a pass tells: its fusion reads such frames so). Null on answers "
        "stored before it",
    )

    @staticmethod
    def fields_of(c: Checked) -> dict[str, Any]:
        """The checked answer's fields, for any schema that carries them (an estimate, a pass's frame)."""
        return {
            "attitude": AttitudePublic.from_euler(c.angles_deg),
            "attitude_network": None if c.network_deg is None else AttitudePublic.from_euler(c.network_deg),
            "refined": c.refined,
            "refined_on": c.refined_on,
            "likelihood": c.image_fit,
            "attitude_reversed": AttitudePublic.from_euler(reversed_reading(c.angles_deg)),
            "quality": QualityPublic.from_quality(c.quality),
            "alternatives": [AlternativePublic.from_alternative(a) for a in c.alternatives],
        }


class EstimateResult(CheckedPublic, StoredResult):
    """What an estimate answers and stores, beside its row's columns."""

    target: str | None = Field(None, description="the target model the frame was fitted to")
    quality: QualityPublic | None = Field(None, description="how sure the answer is (null on estimates made before it)")
    alternatives: list[AlternativePublic] = Field(
        default_factory=list,
        description="other attitudes that fit nearly as well, and always the other branch of the near-mirror pair "
        "(z, -y, -x), fitted, with how much worse it fits (fit_gap); and the answer's exact near-mirror (fitted "
        "false) where that fit settled over 2 deg from it",
    )
    attitude_lvlh: AttitudePublic | None = None
    """the attitude in the target's LVLH frame (with plan_id and observed_at)"""
    attitude_j2000: AttitudePublic | None = None
    """the attitude in J2000/GCRS (with plan_id and observed_at)"""
    model: dict[str, Any]
    """the models that answered: their card's name and file hashes"""
    timings_s: dict[str, float]
    """where the time went, seconds (decoding, the networks, the fit)"""
    input_normalised: bool = Field(
        False, description="true when the frame was sent already normalised (normalised=true) and taken as sent"
    )
    cells_m: list[float] | None = None
    """the frame's range and cross-range cells (m) as sent, or null: the models' own"""
    model_cells_m: list[float] | None = None
    """the range and cross-range cells (m) of the frame the models read, as stored (original.png, enhanced.png,
    outline.png): those images' scale; null on estimates made before it was kept"""

    @classmethod
    def from_checked(
        cls,
        c: Checked,
        *,
        target: str,
        model: dict[str, Any],
        timings_s: dict[str, float],
        input_normalised: bool,
        cells_m: tuple[float, float] | None,
        in_frames: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
        model_cells_m: tuple[float, float] | None = None,
    ) -> EstimateResult:
        """Return a checked frame as the estimate's result; ``in_frames``: its attitude as body to LVLH and J2000."""
        return cls(
            **CheckedPublic.fields_of(c),
            target=target,
            attitude_lvlh=None if in_frames is None else AttitudePublic.from_matrix(in_frames[0]),
            attitude_j2000=None if in_frames is None else AttitudePublic.from_matrix(in_frames[1]),
            model=model,
            timings_s=timings_s,
            input_normalised=input_normalised,
            cells_m=None if cells_m is None else list(cells_m),
            model_cells_m=None if model_cells_m is None else list(model_cells_m),
        )

    @classmethod
    def _from_format(cls, version: int, fields: dict[str, Any]) -> None:
        if version == 1:
            fields.setdefault("refined", False)  # rows from before the fit was optional were never fitted


class _EstimateRow(Described):
    id: str
    """the estimate's id"""
    created_at: datetime
    """when it was stored (UTC)"""
    plan_id: str | None
    """the plan the frame belongs to, if one was given"""
    observed_at: datetime | None
    """when the frame was observed (UTC), if given"""
    input_name: str
    """the uploaded file's name (with the member and index for stacks)"""
    input_sha256: str
    """sha256 of the uploaded file"""
    shape: list[int]
    """the uploaded frame's shape [rows, columns]"""
    dtype: str
    """the uploaded array's type"""
    snr_db: float | None
    """the SNR the caller stated, dB, if any"""


class EstimatePublic(EstimateResult, _EstimateRow):
    links: dict[str, str]
    """the estimate's own URL and its images' URLs"""
    pass_ids: list[str] = Field(
        default_factory=list,
        description="your fused passes of the same plan whose frames span this frame's observed_at (the pass it was "
        "observed in), oldest first; given by GET /v1/estimates/{id}, empty in lists",
    )

    @classmethod
    def from_row(cls, e: Estimate, pass_ids: list[str] | None = None) -> EstimatePublic:
        """Return a stored estimate row, of any stored format, as the answer."""
        return cls.model_validate(
            {
                "id": e.id,
                "created_at": utc_or_none(e.created_at),
                "plan_id": e.plan_id,
                "observed_at": utc_or_none(e.observed_at),
                "input_name": e.input_name,
                "input_sha256": e.input_sha256,
                "shape": e.shape,
                "dtype": e.dtype,
                "snr_db": e.snr_db,
                "pass_ids": pass_ids or [],
                **EstimateResult.upgraded(e.result),
                "links": {
                    "self": f"/v1/estimates/{e.id}",
                    "enhanced_png": f"/v1/estimates/{e.id}/enhanced.png",
                    "original_png": f"/v1/estimates/{e.id}/original.png",
                },
            }
        )


class EstimatesPublic(Described):
    data: list[EstimatePublic]
    """the estimates of this page"""
    count: int
    """how many estimates match in all"""


class ScenePublic(Described):
    plan_id: str
    """the plan"""
    target_name: str
    """its target's name"""
    t_access: datetime | None
    """its chosen t_access (UTC), or null"""
    miss_km: float | None
    """its chosen miss, km, or null"""
    estimates: list[EstimatePublic]
    """the estimates tied to the plan"""


class ScenesPublic(Described):
    data: list[ScenePublic]
    """the scenes of this page, newest first"""
    count: int
    """how many plans the caller has"""
