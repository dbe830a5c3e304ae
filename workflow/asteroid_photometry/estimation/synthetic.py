"""Observations of a turning body with a known truth, noiseless or noisy, for the tests and the benchmarks."""

from __future__ import annotations

import numpy as np

from asteroid_photometry.estimation.core import Observations
from asteroid_photometry.reflectance.laws import minnaert_brightness

# --------------------------------------------------------------------------
# Synthetic data
# --------------------------------------------------------------------------


def synthetic_observations(
    n_points: int,
    n_views: int,
    light_dir_cam,
    albedo,
    minnaert_k,
    rng: np.random.Generator,
    noise_sigma: float = 0.0,
    min_cos: float = 0.1,
    *,
    body_radius_m: float = 250.0,
    camera_distance_m: float = 5000.0,
    max_abs_spin_component: float = 0.85,
) -> Observations:
    """Observations of a turning body with a known truth (for tests and benchmarks).

    Geometry: the camera sits at the origin of the camera frame looking along
    +z; the body's centre is ``camera_distance_m`` down the axis and it spins
    about the camera's y axis (perpendicular to the optical axis), as in the
    paper's image sets. Point ``p`` has a random body-frame unit normal
    (uniform on the sphere within the band ``|n_y| <= max_abs_spin_component``,
    so that every point turns through a useful arc) and a body-frame position
    ``body_radius_m * u * n`` with ``u`` uniform in [0.6, 1]. The view vector
    is the true unit vector from the rotated point to the camera, so it
    departs from ``-z`` by up to ``atan(body_radius / distance)`` (about 3 deg
    by default): a realistic slight perspective.

    Each point is seen at ``n_views`` spin angles, stratified (one uniformly
    jittered angle per equal sub-interval) over the arc where it is both lit
    and visible, so ``cos_o`` and ``cos_i`` sweep from near ``min_cos`` to
    near their maximum and k is identifiable. Only rows with
    ``cos_i > min_cos`` and ``cos_o > min_cos`` are kept, so a point has at
    most ``n_views`` rows. ``albedo`` and ``minnaert_k`` are scalars or
    (n_points,) arrays. ``noise_sigma`` adds Gaussian noise (brightness
    units) to ``b``; noisy ``b`` may be slightly negative near the terminator.
    Deterministic given ``rng``.
    """
    n_points, n_views = int(n_points), int(n_views)
    if n_points < 0 or n_views < 1:
        raise ValueError(f"synthetic_observations: need n_points >= 0 and n_views >= 1, got {n_points}, {n_views}")
    light = np.asarray(light_dir_cam, dtype=np.float64)
    light = light / np.linalg.norm(light)
    albedo = np.broadcast_to(np.asarray(albedo, dtype=np.float64), (n_points,))
    minnaert_k = np.broadcast_to(np.asarray(minnaert_k, dtype=np.float64), (n_points,))

    # Body-frame normals: uniform on the sphere restricted to a band about the spin equator.
    n_y = rng.uniform(-max_abs_spin_component, max_abs_spin_component, n_points)
    azimuth = rng.uniform(0.0, 2.0 * np.pi, n_points)
    ring = np.sqrt(1.0 - n_y**2)
    normal_body = np.column_stack([ring * np.cos(azimuth), n_y, ring * np.sin(azimuth)])
    position_body = body_radius_m * rng.uniform(0.6, 1.0, n_points)[:, None] * normal_body

    # After a spin by theta about y: n_z(theta) = -n_x sin(theta) + n_z cos(theta), so with the
    # camera towards -z, cos_o ~ r_o cos(theta - theta_o) and cos_i = r_i cos(theta - theta_i) + c_i.
    n_x, n_z = normal_body[:, 0], normal_body[:, 2]
    r_o = np.hypot(n_x, n_z)
    theta_o = np.arctan2(n_x, -n_z)
    coef_cos = n_x * light[0] + n_z * light[2]
    coef_sin = n_z * light[0] - n_x * light[2]
    r_i = np.hypot(coef_cos, coef_sin)
    theta_i = np.arctan2(coef_sin, coef_cos)
    c_i = n_y * light[1]
    with np.errstate(invalid="ignore", divide="ignore"):
        half_o = np.arccos(np.clip(min_cos / r_o, -1.0, 1.0))
        half_i = np.arccos(np.clip((min_cos - c_i) / np.where(r_i > 0, r_i, np.inf), -1.0, 1.0))
    offset = np.angle(np.exp(1j * (theta_i - theta_o)))  # lit arc centre relative to visible arc centre
    # Leave a margin for the perspective, which shifts cos_o a little from the -z approximation.
    margin = np.radians(4.0)
    low = np.maximum(-half_o, offset - half_i) + margin
    high = np.minimum(half_o, offset + half_i) - margin
    usable = high > low

    strata = (np.arange(n_views)[None, :] + rng.uniform(0.0, 1.0, (n_points, n_views))) / n_views
    theta = theta_o[:, None] + low[:, None] + (high - low)[:, None] * strata
    point_index = np.repeat(np.arange(n_points, dtype=np.int64), n_views)
    keep_point = np.repeat(usable, n_views)
    theta = theta.ravel()[keep_point]
    point_index = point_index[keep_point]

    # Rotate by theta about y: (x, y, z) -> (c x + s z, y, c z - s x), without per-row matrices.
    cos_theta, sin_theta = np.cos(theta), np.sin(theta)

    def rotated(vectors_body):
        vectors = vectors_body[point_index]
        out = np.empty_like(vectors)
        out[:, 0] = cos_theta * vectors[:, 0] + sin_theta * vectors[:, 2]
        out[:, 1] = vectors[:, 1]
        out[:, 2] = cos_theta * vectors[:, 2] - sin_theta * vectors[:, 0]
        return out

    normal_cam = rotated(normal_body)
    position_cam = rotated(position_body)
    del cos_theta, sin_theta
    position_cam[:, 2] += camera_distance_m
    view_cam = -position_cam / np.linalg.norm(position_cam, axis=1, keepdims=True)
    normal_cam /= np.linalg.norm(normal_cam, axis=1, keepdims=True)

    cos_i = normal_cam @ light
    cos_o = np.einsum("ij,ij->i", normal_cam, view_cam)
    keep = (cos_i > min_cos) & (cos_o > min_cos)
    point_index, normal_cam, view_cam = point_index[keep], normal_cam[keep], view_cam[keep]
    cos_i, cos_o = cos_i[keep], cos_o[keep]
    k_row = minnaert_k[point_index]
    brightness = minnaert_brightness(albedo[point_index], k_row, cos_i, cos_o)
    if noise_sigma > 0.0:
        brightness = brightness + rng.normal(0.0, noise_sigma, brightness.shape)
    return Observations(
        point_index=point_index,
        normal_cam=normal_cam,
        view_cam=view_cam,
        brightness=brightness,
        n_points=n_points,
    )
