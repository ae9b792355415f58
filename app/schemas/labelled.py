"""Labelled frames: a radar's frames with the attitude a GSA scene's optical observer measured."""

from __future__ import annotations

from datetime import datetime
from typing import TYPE_CHECKING

from app.schemas.common import Described, utc_or_none

if TYPE_CHECKING:
    from app.db.models import LabelledFrame


class LabelledFramePublic(Described):
    id: str
    """the labelled frame's id"""
    created_at: datetime
    """when it was stored (UTC)"""
    target: str
    """the target model the frame shows"""
    name: str
    """the uploaded file's name"""
    scene: str
    """the scene it belongs to (frames of one scene are never split across an adaptation's training and validation)"""
    angles_deg: list[float]
    """the label: Euler z, y, x (deg), body to the frame's observation frame; z and x in (-180, 180], y in [-90, 90]"""
    quaternion_j2000: list[float] | None = None
    """the optical attitude as given (body to J2000, w x y z), where the label came in that form"""
    observed_at: datetime | None = None
    """when the frame was observed (UTC), where given"""
    plan_id: str | None = None
    """the plan whose geometry placed it, where one did"""
    campaign_id: str | None = None
    """the campaign whose geometry placed it, where one did"""
    station_name: str | None = None
    """the plan's (or campaign's) station"""
    attitude_sigma_deg: float | None = None
    """the optical estimate's own 1-sigma (deg), where given"""
    snr_db: float | None = None
    """the frame's SNR (dB), where given"""
    cells_m: list[float] | None = None
    """the frame's range and cross-range cells (m) as uploaded, where given (stored resampled to the models' cells)"""
    frame_sha256: str
    """the stored frame (the models' input, a PNG) by content"""

    @classmethod
    def from_row(cls, row: LabelledFrame) -> LabelledFramePublic:
        return cls(
            id=row.id,
            created_at=utc_or_none(row.created_at) or row.created_at,
            target=row.target,
            name=row.input_name,
            scene=row.scene,
            angles_deg=list(row.angles_deg),
            quaternion_j2000=list(row.quaternion_j2000) if row.quaternion_j2000 else None,
            observed_at=utc_or_none(row.observed_at),
            plan_id=row.plan_id,
            campaign_id=row.campaign_id,
            station_name=row.station_name,
            attitude_sigma_deg=row.attitude_sigma_deg,
            snr_db=row.snr_db,
            cells_m=list(row.cells_m) if row.cells_m else None,
            frame_sha256=row.frame_sha256,
        )


class LabelledSummary(Described):
    target: str
    """the target model"""
    count: int
    """the caller's labelled frames of this target, all pages"""
    per_scene: dict[str, int]
    """frames per scene"""
    coverage: float
    """the share of the networks' attitude cube (+-45 deg, in 15 deg cells) holding at least one labelled frame"""


class LabelledDeleted(LabelledSummary):
    """What is left after a deletion (the counts are of the frames that remain)."""

    deleted: int
    """the labelled frames deleted"""


class LabelledFramesPublic(LabelledSummary):
    data: list[LabelledFramePublic]
    """this page, newest first"""


class LabelledUpload(LabelledSummary):
    stored: list[LabelledFramePublic]
    """the frames this request stored"""
    already_stored: list[str]
    """uploaded files the caller had already stored for this target (by content): not stored twice"""
