"""A rendered set read back: its navigation file (frames.json) and its linear images, checked."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from asteroid_photometry.core.failures import BadInput, check_status, DataFailure
from asteroid_photometry.world import render


def write_linear_exr(path, image: np.ndarray) -> None:
    import mitsuba as mi

    if not mi.variant():
        mi.set_variant("scalar_rgb")
    mi.Bitmap(np.ascontiguousarray(image, dtype=np.float32)[..., None]).write(str(path))



def check_frames(frames: dict, frames_path: Path) -> None:
    """Refuse a ``frames.json`` (the set's navigation file) without intrinsics, or whose images or poses are not all there and well formed."""
    render_dir = frames_path.parent
    intrinsics = frames.get("intrinsics")
    if not isinstance(intrinsics, dict) or not all(isinstance(intrinsics.get(key), int) and intrinsics[key] > 0 for key in ("width", "height")):
        raise BadInput(f"{frames_path}: expected 'intrinsics' with a positive integer 'width' and 'height', got {intrinsics!r}")
    entries = frames.get("images")
    if not isinstance(entries, list) or not entries:
        raise BadInput(f"{frames_path}: expected a non-empty list 'images', one entry per image, got {entries!r}")
    for position, entry in enumerate(entries):
        if not isinstance(entry, dict) or not isinstance(entry.get("file"), str):
            raise BadInput(f"{frames_path}: image entry {position} has no 'file' name: {entry!r}")
        where = f"{frames_path}: image entry {position} ({entry['file']})"
        if not (render_dir / entry["file"]).is_file():
            raise BadInput(f"{where}: the image file {render_dir / entry['file']} is missing")
        try:
            pose = np.asarray(entry.get("body_to_camera"), dtype=float)
        except (TypeError, ValueError):
            pose = np.empty(0)
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise BadInput(f"{where}: 'body_to_camera' must be a finite 4x4 matrix, got {entry.get('body_to_camera')!r}")
        rotation = pose[:3, :3]
        if not np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-6) or np.linalg.det(rotation) <= 0 or not np.allclose(pose[3], [0, 0, 0, 1]):
            raise BadInput(f"{where}: 'body_to_camera' must be a rigid transform (rotation with determinant +1, last row 0 0 0 1), got {pose.tolist()}")
    listed = {entry["file"] for entry in entries}
    unlisted = sorted(path.name for path in render_dir.glob("image_*.exr") if path.name not in listed)
    if unlisted:
        raise BadInput(f"{frames_path}: lists {len(entries)} images but not {', '.join(unlisted[:5])}{' ...' if len(unlisted) > 5 else ''} found beside it")



def check_image(image: np.ndarray, path, intrinsics: dict) -> None:
    """Refuse an image of another size than its intrinsics, or with NaN, infinite or negative pixels."""
    expected = (intrinsics["height"], intrinsics["width"])
    if image.shape != expected:
        raise BadInput(f"{path}: the image is {image.shape[1] if image.ndim > 1 else '?'} x {image.shape[0]} px, but the intrinsics in frames.json say {expected[1]} x {expected[0]}")
    bad = int(np.count_nonzero(~np.isfinite(image)))
    if bad:
        raise BadInput(f"{path}: {bad} NaN or infinite pixels; expected finite linear radiance")
    negative = int(np.count_nonzero(image < 0))
    if negative:
        raise BadInput(f"{path}: {negative} negative pixels (lowest {image.min():.3g}); expected linear radiance >= 0")



def read_rendered_images(render_dir) -> tuple[dict, list[np.ndarray]]:
    """A rendered set's ``frames.json`` and images, checked (``check_frames``, ``check_image``).

    Raises :class:`BadInput` for a malformed file; a set marked failed by
    the stage that wrote it, or one with blank images (nothing above 0),
    raises :class:`DataFailure`.
    """
    render_dir = Path(render_dir)
    frames_path = render_dir / "frames.json"
    if not frames_path.exists():
        raise FileNotFoundError(f"{frames_path} is missing: {render_dir} is not a complete rendered set")
    try:
        frames = json.loads(frames_path.read_text())
    except json.JSONDecodeError as error:
        raise BadInput(f"{frames_path}: not valid JSON ({error})") from None
    check_status(frames, frames_path)
    check_frames(frames, frames_path)
    images = []
    for entry in frames["images"]:
        image = render.read_image(render_dir / entry["file"])
        check_image(image, render_dir / entry["file"], frames["intrinsics"])
        images.append(image)
    blank = [entry["file"] for entry, image in zip(frames["images"], images) if not image.max() > 0]
    if blank:
        raise DataFailure(f"{len(blank)} of {len(images)} images are blank (no pixel above 0: {', '.join(blank[:3])}{' ...' if len(blank) > 3 else ''})")
    return frames, images
