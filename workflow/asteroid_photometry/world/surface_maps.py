"""Spatially varying albedo and Minnaert k over the body: the per-facet truth for the render stage.

The paper renders every set with one albedo and one k; a real surface
varies. This module draws smooth random maps over the shape model's facets
(one value per facet, at its centroid, body frame) from a set's mean albedo
and k and a spec, the config's ``surface_maps`` entry:

- ``{kind: uniform}``: every facet has the set's albedo and k (the paper).
- ``{kind: random_field, albedo_contrast: 0.2, k_contrast: 0.1,
  correlation_length_m: 50}``: ``albedo = mean * (1 + albedo_contrast *
  f1)`` clipped to [0.02, 1] (a relative contrast: the albedo's standard
  deviation over the facets, before clipping, is ``albedo_contrast`` times
  its mean) and ``k = mean + k_contrast * f2`` clipped to [0.3, 1.3] (an
  absolute one), with ``f1``, ``f2`` two independent smooth fields.

An optional ``name`` labels the entry. ``render.render_image_set`` takes
the two arrays as its ``albedo`` and ``minnaert_k``; ``save_facet_maps``
writes them as the truth that the fit is scored against.

The fields are Gaussian random fields with the squared-exponential
correlation ``exp(-d**2 / (2 L**2))``, ``d`` the straight-line distance
between two facet centroids and ``L`` the correlation length (correlation
0.61 at ``d = L``, 0.14 at ``2 L``), drawn as a sum of random Fourier
features (Rahimi and Recht 2007): ``sqrt(2 / M) sum_j cos(w_j . x + phi_j)``
with ``w_j ~ Normal(0, I / L**2)`` and ``phi_j ~ Uniform(0, 2 pi)``, whose
covariance is exactly that kernel in expectation. Each field is then
standardised over the facets (mean 0, standard deviation 1 exactly), so
the map's mean is the set's value up to clipping.
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

CONFIG_KEY = "surface_maps"
ALBEDO_RANGE = (0.02, 1.0)
MINNAERT_K_RANGE = (0.3, 1.3)
N_FOURIER_FEATURES = 1024
# Points x features per block of the feature sum: bounds the memory (8 bytes each).
_BLOCK_ELEMENTS = 1 << 21

SPEC_KEYS = {
    "uniform": {"kind", "name"},
    "random_field": {"kind", "name", "albedo_contrast", "k_contrast", "correlation_length_m"},
}


def smooth_random_field(points_m: np.ndarray, correlation_length_m: float, rng, n_features: int = N_FOURIER_FEATURES) -> np.ndarray:
    """A smooth zero-mean, unit-variance random field at ``points_m`` (N, 3), metres: shape (N,).

    Squared-exponential correlation of length ``correlation_length_m`` in
    straight-line distance (module docstring); standardised over the points.
    ``rng`` is a ``numpy.random.Generator`` or a seed. Memory is bounded by
    blocks of points (a few tens of MB), whatever N.
    """
    rng = np.random.default_rng(rng)
    points = np.asarray(points_m, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < 2:
        raise ValueError(f"smooth_random_field: points_m must be an (N, 3) array with N >= 2, got shape {points.shape}")
    if not math.isfinite(correlation_length_m) or correlation_length_m <= 0:
        raise ValueError(f"smooth_random_field: correlation_length_m must be > 0, got {correlation_length_m!r}")
    frequencies = rng.normal(0.0, 1.0 / correlation_length_m, size=(n_features, 3))
    phases = rng.uniform(0.0, 2.0 * np.pi, size=n_features)
    # Relative to the points' centre: same field in law, smaller arguments to cos.
    points = points - points.mean(axis=0)
    field = np.empty(len(points))
    block = max(1, _BLOCK_ELEMENTS // n_features)
    for start in range(0, len(points), block):
        field[start : start + block] = np.cos(points[start : start + block] @ frequencies.T + phases).sum(axis=1)
    field -= field.mean()
    spread = field.std()
    if not spread > 0:
        raise ValueError("smooth_random_field: the field is constant over the points (are they all the same point?)")
    return field / spread


def _contrast(spec: dict, key: str, where: str) -> float:
    value = spec.get(key)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise ValueError(f"{where}: {key} must be a number >= 0, got {value!r}")
    return float(value)


def validate_spec(spec: dict) -> dict:
    """The spec, checked: a known ``kind``, its keys and no others; errors name ``surface_maps``."""
    if not isinstance(spec, dict):
        raise ValueError(f"config key '{CONFIG_KEY}': expected a mapping with a 'kind', got {spec!r}")
    name = spec.get("name")
    where = f"config key '{CONFIG_KEY}'" + (f", entry {name!r}" if name else "")
    kind = spec.get("kind")
    if kind not in SPEC_KEYS:
        raise ValueError(f"{where}: kind must be one of {sorted(SPEC_KEYS)}, got {kind!r}")
    unknown = sorted(set(spec) - SPEC_KEYS[kind])
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown} for kind {kind!r}; allowed: {sorted(SPEC_KEYS[kind])}")
    if kind == "random_field":
        for key in ("albedo_contrast", "k_contrast"):
            _contrast(spec, key, where)
        length = spec.get("correlation_length_m")
        if isinstance(length, bool) or not isinstance(length, (int, float)) or not math.isfinite(length) or length <= 0:
            raise ValueError(f"{where}: correlation_length_m must be a number > 0 (metres), got {length!r}")
    return spec


def facet_maps(centroids_m: np.ndarray, spec: dict, seed: int, albedo: float, minnaert_k: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-facet ``(albedo, minnaert_k)``, each (F,), around the set's ``albedo`` and ``minnaert_k``.

    ``centroids_m`` (F, 3) are the facet centroids in the body frame; ``spec``
    is a ``surface_maps`` entry (module docstring). The maps depend only on
    the centroids, the spec, ``seed`` and the two means: the same seed with
    another mean gives the same pattern, scaled. The albedo and k fields are
    independent.
    """
    spec = validate_spec(spec)
    centroids = np.asarray(centroids_m, dtype=np.float64)
    if centroids.ndim != 2 or centroids.shape[1] != 3:
        raise ValueError(f"facet_maps: centroids_m must be (F, 3), got shape {centroids.shape}")
    if not (math.isfinite(albedo) and albedo > 0 and math.isfinite(minnaert_k) and minnaert_k > 0):
        raise ValueError(f"facet_maps: the set's albedo and minnaert_k must be > 0, got {albedo!r}, {minnaert_k!r}")
    n_facets = len(centroids)
    if spec["kind"] == "uniform":
        return np.full(n_facets, float(albedo)), np.full(n_facets, float(minnaert_k))

    albedo_rng, k_rng = (np.random.default_rng(child) for child in np.random.SeedSequence(int(seed)).spawn(2))
    length = float(spec["correlation_length_m"])
    albedo_field = smooth_random_field(centroids, length, albedo_rng)
    k_field = smooth_random_field(centroids, length, k_rng)
    raw_albedo = albedo * (1.0 + spec["albedo_contrast"] * albedo_field)
    raw_k = minnaert_k + spec["k_contrast"] * k_field
    albedo_map = np.clip(raw_albedo, *ALBEDO_RANGE)
    k_map = np.clip(raw_k, *MINNAERT_K_RANGE)
    clipped_albedo = int((albedo_map != raw_albedo).sum())
    clipped_k = int((k_map != raw_k).sum())
    if clipped_albedo or clipped_k:
        log.warning(
            "surface maps: %d of %d facets clipped to albedo %s and %d to k %s; means now %.4f and %.4f",
            clipped_albedo, n_facets, ALBEDO_RANGE, clipped_k, MINNAERT_K_RANGE, albedo_map.mean(), k_map.mean(),
        )
    return albedo_map, k_map


def save_facet_maps(path, albedo: np.ndarray, minnaert_k: np.ndarray, spec: dict | None = None, seed: int | None = None) -> Path:
    """Write the per-facet truth to ``path`` (.npz): ``albedo``, ``minnaert_k`` (F,), the spec as JSON and the seed (-1: none)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as handle:  # a handle: np.savez would append .npz to another suffix
        np.savez_compressed(
            handle,
            albedo=np.asarray(albedo, dtype=np.float64),
            minnaert_k=np.asarray(minnaert_k, dtype=np.float64),
            spec_json=np.str_(json.dumps(spec, sort_keys=True)),  # "null" when not given
            seed=np.int64(-1 if seed is None else seed),
        )
    return path


def load_facet_maps(path) -> tuple[np.ndarray, np.ndarray]:
    """The per-facet ``(albedo, minnaert_k)`` written by ``save_facet_maps``."""
    with np.load(path) as data:
        return data["albedo"], data["minnaert_k"]


FACET_MAPS_FILE = "facet_maps.npz"
