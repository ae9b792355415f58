"""Labelled frames in: each uploaded file (``inference.labelled``'s .npz format) read, its label placed by the plan
where it is given in J2000, checked as a whole, then stored (frames as blobs, then the rows in one transaction)."""

from __future__ import annotations

import hashlib
import io
import json
from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np
from sqlalchemy.orm import Session

from app import crud
from app.core.config import Settings
from app.db.models import LabelledFrame, utcnow
from app.errors import InputError
from app.schemas import LabelledDeleted, LabelledFramePublic, LabelledSummary, LabelledUpload
from app.services import images, storage
from app.services.scenes import scene_for, windows_of
from app.services.uploads import DecodeBudget, decode
from inference.errors import InferenceError
from inference.labelled import MAX_SIGMA_DEG, FrameRead, coverage, observed_times, read_frame
from scene.errors import SceneError
from scene.geometry import Window, check_times
from scene.labels import plan_resolver


@dataclass(frozen=True)
class Placing:
    """What places labels given in J2000: a plan's or a campaign's target and station (the scene's geometry) and the
    access windows the frames' times must fall in."""

    request: dict[str, Any]  # plan-shaped: target, observer, ground_station
    windows: list[Window]
    station_name: str
    plan_id: str | None = None
    campaign_id: str | None = None


def _placing(
    session: Session, operator_id: str, plan_id: str | None, campaign_id: str | None, target: str
) -> Placing | None:
    if plan_id is not None and campaign_id is not None:
        raise InputError(["campaign_id"], "give plan_id or campaign_id, not both: one scene's geometry places labels")
    if plan_id is not None:
        plan = crud.get_plan(session=session, operator_id=operator_id, plan_id=plan_id)
        if plan is None:
            raise InputError(["plan_id"], f"no plan {plan_id} belongs to you")
        others = crud.labelled_targets_of_plan(session=session, operator_id=operator_id, plan_id=plan_id) - {target}
        if others:
            raise InputError(
                ["plan_id"],
                f"plan {plan_id} already labels frames of target {sorted(others)[0]!r}: a plan's scene images one "
                f"target, not {target!r}",
            )
        return Placing(plan.request, windows_of(plan.result, plan.station_name), plan.station_name, plan_id=plan.id)
    if campaign_id is not None:
        campaign = crud.get_campaign(session=session, operator_id=operator_id, campaign_id=campaign_id)
        if campaign is None:
            raise InputError(["campaign_id"], f"no campaign {campaign_id} belongs to you")
        # A campaign's scenes image its target from its station: the scene's geometry is the plan's, over any of
        # the campaign's access windows (the observer, which the campaign moves, plays no part in it).
        req = {k: campaign.request[k] for k in ("target", "observer", "ground_station")}
        return Placing(
            req, windows_of(campaign.result, campaign.station_name), campaign.station_name, campaign_id=campaign.id
        )
    return None


IMAGE_MAGIC = (b"\x89PNG", b"II*\x00", b"MM\x00*", b"\x93NUMPY")  # PNG, TIFF, .npy; anything else is read as an .npz


@dataclass(frozen=True)
class FormLabels:
    """Labels sent as form fields, one per image file (.png, .tif, .npy) in the order of the files; an .npz carries
    its own. ``angles_deg`` "z,y,x"; or ``quaternion_j2000`` "w,x,y,z" with ``observed_at`` (ISO 8601, UTC)."""

    angles_deg: list[str] | None = None
    quaternion_j2000: list[str] | None = None
    observed_at: list[str] | None = None


def _numbers(text: str, n: int, field: str, k: int) -> list[float]:
    try:
        values = [float(v) for v in text.replace(" ", "").split(",")]
    except ValueError:
        values = []
    if len(values) != n or not all(np.isfinite(values)):
        raise InputError([field, k], f"{n} finite numbers separated by commas; got {text!r}")
    return values


def as_labelled_npz(
    files: list[tuple[str, bytes]], labels: FormLabels, budget: DecodeBudget | None = None
) -> list[tuple[bytes, bytes]]:
    """Each file as the labelled-frame .npz ``read_frame`` reads, with the bytes that identify it: an .npz as it is;
    an image file (.png, .tif, .npy: one 2-D frame) with the next form label, identified by its bytes and that
    label. Refuses a count of labels that does not match the images. An image is charged to the request's decode
    ``budget`` from its header before it is decoded here, and again when ``read_frame`` reads it packed (an image
    file counts twice against the budget: the safe side)."""
    images_at = [k for k, (_, data) in enumerate(files) if data.startswith(IMAGE_MAGIC)]
    angles, quats, times = labels.angles_deg or [], labels.quaternion_j2000 or [], labels.observed_at or []
    if angles and quats:
        raise InputError(["angles_deg"], "give angles_deg or quaternion_j2000 for the image files, not both")
    given, field = (angles, "angles_deg") if angles or not quats else (quats, "quaternion_j2000")
    if len(given) != len(images_at):
        raise InputError(
            [field],
            f"{len(images_at)} image file(s) (.png, .tif, .npy) need one {field} each, in the order of the files "
            f"(an .npz carries its own label); got {len(given)}",
        )
    if times and len(times) != len(images_at):
        raise InputError(["observed_at"], f"one observed_at per image file ({len(images_at)}); got {len(times)}")
    out = [(data, data) for _, data in files]
    for j, k in enumerate(images_at):
        name, data = files[k]
        frame = decode(data, name, allow_stack=False, budget=budget)[0].magnitude
        arrays: dict[str, Any] = {"image": frame}
        if field == "angles_deg":
            arrays["angles_deg"] = np.array(_numbers(given[j], 3, field, j))
        else:
            arrays["quaternion_j2000"] = np.array(_numbers(given[j], 4, field, j))
        if times:
            arrays["observed_at"] = np.array(times[j])
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        label = {key: v.tolist() for key, v in arrays.items() if key != "image"}
        out[k] = (buf.getvalue(), data + b"\0" + json.dumps(label, sort_keys=True).encode())
    return out


def read_labelled(
    *,
    files: list[tuple[str, bytes]],
    size: int,
    model_cells_m: tuple[float, float],
    plan: Placing | None,
    budget: DecodeBudget | None = None,
) -> list[FrameRead]:
    """Read every file (all before anything is stored); J2000 labels placed by the plan's (or campaign's) geometry;
    each image's size charged to ``budget`` from its header before it is read."""
    resolve = None
    if plan is not None:
        times = observed_times(files)
        try:
            if times:
                check_times(plan.windows, times)
                resolve = plan_resolver(
                    scene_for(plan.request, min(times) - timedelta(seconds=1), max(times) + timedelta(seconds=1))
                )
        except SceneError as exc:
            raise InputError(["observed_at"], str(exc)) from None
    out = []
    for name, data in files:
        try:
            charge = budget.charge if budget is not None else None
            out.append(read_frame(Path(name), size, model_cells_m, resolve, data=data, charge=charge))
        except InferenceError as exc:
            raise InputError(["files", name, exc.field or "file"], str(exc)) from None
        except SceneError as exc:
            raise InputError(["files", name, "observed_at"], str(exc)) from None
    return out


def create_labelled(
    *,
    session: Session,
    operator_id: str,
    settings: Settings,
    target: str,
    size: int,
    model_cells_m: tuple[float, float],
    files: list[tuple[str, bytes]],
    plan_id: str | None = None,
    scene: str | None = None,
    attitude_sigma_deg: float | None = None,
    campaign_id: str | None = None,
    angles_deg: list[str] | None = None,
    quaternion_j2000: list[str] | None = None,
    observed_at: list[str] | None = None,
) -> LabelledUpload:
    """Store the uploaded labelled frames of ``target`` (see the module's text); return what was stored.

    An image file (.png, .tif, .npy) takes its label from the form's ``angles_deg``, or ``quaternion_j2000`` with
    ``observed_at`` (``FormLabels``: one per image file, in order); its stored
    identity is its bytes and its label together, so the same image under another label is another frame."""
    if not files:
        raise InputError(["files"], "no frames in the upload")
    if len(files) > settings.max_batch_frames:
        raise InputError(["files"], f"{len(files)} files is over the batch limit of {settings.max_batch_frames}")
    if attitude_sigma_deg is not None and not 0.0 <= attitude_sigma_deg <= MAX_SIGMA_DEG:
        raise InputError(["attitude_sigma_deg"], f"between 0 and {MAX_SIGMA_DEG:g} deg")
    plan = _placing(session, operator_id, plan_id, campaign_id, target)
    budget = DecodeBudget.of(settings)
    packed = as_labelled_npz(files, FormLabels(angles_deg, quaternion_j2000, observed_at), budget)
    digests = [hashlib.sha256(identity).hexdigest() for _, identity in packed]
    files = [(name, data) for (name, _), (data, _) in zip(files, packed, strict=True)]
    reads = read_labelled(files=files, size=size, model_cells_m=model_cells_m, plan=plan, budget=budget)
    for (name, _), r in zip(files, reads, strict=True):
        if r.quaternion_j2000 is not None and plan is None:  # the reader refuses these without a plan
            raise InputError(["files", name, "plan_id"], "a label in J2000 needs plan_id (or campaign_id)")
    known = crud.labelled_inputs(session=session, operator_id=operator_id, target=target, digests=digests)
    station = plan.station_name if plan is not None else None
    rows, blobs, seen = [], [], set(known)
    for (name, _), digest, r in zip(files, digests, reads, strict=True):
        if digest in seen:
            continue
        seen.add(digest)
        blob = images.png_bytes(r.frame)
        blobs.append(blob)
        rows.append(
            LabelledFrame(
                operator_id=operator_id,
                created_at=utcnow(),
                target=target,
                scene=(r.scene if r.scene_given or scene is None else scene)[:200],
                plan_id=plan.plan_id if plan is not None else None,
                campaign_id=plan.campaign_id if plan is not None else None,
                station_name=station,
                observed_at=datetime.fromisoformat(r.observed_at) if r.observed_at else None,
                input_name=name[:255],
                input_sha256=digest,
                angles_deg=[round(a, 6) for a in r.angles_deg],
                quaternion_j2000=list(r.quaternion_j2000) if r.quaternion_j2000 else None,
                attitude_sigma_deg=r.sigma_deg if r.sigma_deg is not None else attitude_sigma_deg,
                snr_db=r.snr_db,
                cells_m=None,
                frame_sha256=images.store_blob(settings.data_dir, blob),
            )
        )
    if blobs:
        storage.check_room(session, settings, operator_id, sum(map(len, blobs)), f"these {len(blobs)} frames")
    stored = crud.create_labelled(session=session, rows=rows) if rows else []
    for blob in blobs:  # a concurrent sweep may have removed a blob before its row existed
        images.store_blob(settings.data_dir, blob)
    summary = summarise(session=session, operator_id=operator_id, target=target)
    return LabelledUpload(
        **summary.model_dump(),
        stored=[LabelledFramePublic.from_row(r) for r in stored],
        already_stored=[name for (name, _), d in zip(files, digests, strict=True) if d in known],
    )


def delete_labelled(
    *, session: Session, settings: Settings, operator_id: str, target: str, scene: str | None, every: bool
) -> LabelledDeleted:
    """Delete the operator's labelled frames of ``target``: one scene's (``scene``), or all of them (``every``,
    asked for by name so that a forgotten parameter deletes nothing); their images go where no row needs them."""
    if scene is None and not every:
        raise InputError(
            ["scene"],
            f"name the scene whose labelled frames of {target} to delete (scene=S), or all=true to delete all of them",
            where="query",
        )
    digests = crud.delete_labelled(session=session, operator_id=operator_id, target=target, scene=scene)
    for d in set(digests):
        if not crud.blob_in_use(session=session, digest=d):
            images.blob_path(Path(settings.data_dir), d).unlink(missing_ok=True)
    summary = summarise(session=session, operator_id=operator_id, target=target)
    return LabelledDeleted(**summary.model_dump(), deleted=len(digests))


def summarise(*, session: Session, operator_id: str, target: str) -> LabelledSummary:
    per_scene, angles = crud.labelled_summary(session=session, operator_id=operator_id, target=target)
    return LabelledSummary(
        target=target,
        count=sum(per_scene.values()),
        per_scene=per_scene,
        coverage=round(coverage(np.array(angles, float).reshape(-1, 3)), 4) if angles else 0.0,
    )


def frames_of(*, session: Session, operator_id: str, target: str, data_dir: Path) -> Any:
    """The operator's labelled frames of ``target`` as ``inference.labelled.LabelledFrames`` (for an adaptation)."""
    from PIL import Image

    from inference.labelled import LabelledFrames

    rows, _ = crud.list_labelled(session=session, operator_id=operator_id, target=target, limit=10**6, offset=0)
    rows = sorted(rows, key=lambda r: (r.created_at, r.id))
    frames = []
    for r in rows:
        with Image.open(images.blob_path(data_dir, r.frame_sha256)) as im:
            frames.append(np.asarray(im, np.float32) / 255.0)
    return LabelledFrames(
        np.stack(frames) if frames else np.zeros((0, 0, 0), np.float32),
        np.array([r.angles_deg for r in rows], float).reshape(-1, 3),
        tuple(r.scene for r in rows),
        tuple(f"{r.id}:{r.input_name}" for r in rows),
        np.array([np.nan if r.snr_db is None else r.snr_db for r in rows]),
        np.array([np.nan if r.attitude_sigma_deg is None else r.attitude_sigma_deg for r in rows]),
        tuple(r.observed_at.isoformat() if r.observed_at else None for r in rows),
    )
