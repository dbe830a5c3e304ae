"""Image sets read back, checked: a rendered set (frames.json, the renderer's record, truth included) and a mission set (mission.json, what a mission knows)."""

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



def _read_set_file(path: Path) -> dict:
    """A set's JSON file (``frames.json``, ``mission.json``), with its stage's recorded failure raised."""
    if not path.exists():
        raise FileNotFoundError(f"{path} is missing: {path.parent} is not a complete image set (rendered or mission set)")
    try:
        content = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise BadInput(f"{path}: not valid JSON ({error})") from None
    check_status(content, path)
    return content


def _read_checked_images(directory: Path, entries: list, intrinsics: dict) -> list[np.ndarray]:
    """The images a set's file lists, each checked (``check_image``); :class:`DataFailure` if any is blank."""
    images = []
    for entry in entries:
        image = render.read_image(directory / entry["file"])
        check_image(image, directory / entry["file"], intrinsics)
        images.append(image)
    blank = [entry["file"] for entry, image in zip(entries, images) if not image.max() > 0]
    if blank:
        raise DataFailure(f"{len(blank)} of {len(images)} images are blank (no pixel above 0: {', '.join(blank[:3])}{' ...' if len(blank) > 3 else ''})")
    return images


def read_rendered_images(render_dir) -> tuple[dict, list[np.ndarray]]:
    """A rendered set's ``frames.json`` and images, checked (``check_frames``, ``check_image``).

    Raises :class:`BadInput` for a malformed file; a set marked failed by
    the stage that wrote it, or one with blank images (nothing above 0),
    raises :class:`DataFailure`.
    """
    render_dir = Path(render_dir)
    frames_path = render_dir / "frames.json"
    frames = _read_set_file(frames_path)
    check_frames(frames, frames_path)
    return frames, _read_checked_images(render_dir, frames["images"], frames["intrinsics"])


#: The file of a mission set (``read_mission``): what a mission knows beside its images.
MISSION_FILE = "mission.json"


def check_mission(mission: dict, mission_path: Path) -> None:
    """Refuse a ``mission.json`` without intrinsics, images in order, or (where it has them) well-formed navigation priors."""
    intrinsics = mission.get("intrinsics")
    if not isinstance(intrinsics, dict) or not all(isinstance(intrinsics.get(key), int) and intrinsics[key] > 0 for key in ("width", "height")):
        raise BadInput(f"{mission_path}: expected 'intrinsics' with a positive integer 'width' and 'height', got {intrinsics!r}")
    entries = mission.get("images")
    if not isinstance(entries, list) or not entries or not all(isinstance(entry, dict) and isinstance(entry.get("file"), str) for entry in entries):
        raise BadInput(f"{mission_path}: expected a non-empty list 'images' of entries with a 'file', got {entries!r}")
    if [entry.get("index") for entry in entries] != list(range(len(entries))):
        raise BadInput(f"{mission_path}: the images must be listed in order with 'index' 0, 1, ..., {len(entries) - 1}")
    for entry in entries:
        if not (mission_path.parent / entry["file"]).is_file():
            raise BadInput(f"{mission_path}: the image file {mission_path.parent / entry['file']} is missing")
    navigation = mission.get("navigation")
    if navigation is not None:
        try:
            centres = np.asarray(navigation.get("camera_centres_body_m"), dtype=float)
        except (AttributeError, TypeError, ValueError):
            centres = np.empty(0)
        sigma = navigation.get("sigma_m") if isinstance(navigation, dict) else None
        if centres.shape != (len(entries), 3) or not np.all(np.isfinite(centres)) or not (isinstance(sigma, (int, float)) and sigma > 0):
            raise BadInput(
                f"{mission_path}: 'navigation' must hold 'camera_centres_body_m', one finite (x, y, z) per image ({len(entries)}), "
                f"and a positive 'sigma_m', got centres of shape {centres.shape} and sigma_m {sigma!r}"
            )


def read_mission(mission_dir) -> tuple[dict, list[np.ndarray]]:
    """A mission set's ``mission.json`` and images, checked: what the image-only path starts from.

    The file holds what a mission knows: the intrinsics, the images in the
    order they were taken (with their times), the navigation solution's
    camera positions and their stated accuracy, and the sensor's noise model
    (``sensor``, or null for noise-free images). No pose, no light, no
    albedo or k. Errors as ``read_rendered_images``.
    """
    mission = read_mission_file(mission_dir)
    return mission, _read_checked_images(Path(mission_dir), mission["images"], mission["intrinsics"])


def read_mission_file(mission_dir) -> dict:
    """A mission set's ``mission.json`` alone, checked as by ``read_mission`` (its images are not read)."""
    mission_path = Path(mission_dir) / MISSION_FILE
    mission = _read_set_file(mission_path)
    check_mission(mission, mission_path)
    return mission


def mission_navigation(mission: dict) -> tuple[np.ndarray | None, float | None]:
    """The navigation priors of a mission set: ``(camera centres (n, 3) in the body frame, metres; their sigma)``, or ``(None, None)``."""
    navigation = mission.get("navigation")
    if navigation is None:
        return None, None
    return np.asarray(navigation["camera_centres_body_m"], dtype=float), float(navigation["sigma_m"])
