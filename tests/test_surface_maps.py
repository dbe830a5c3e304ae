"""Smooth random albedo and k maps: field statistics, correlation length, determinism, clipping, specs."""

import tracemalloc

import numpy as np
import pytest
from scipy.spatial import cKDTree

from asteroid_photometry.world import surface_maps

FIELD_SPEC = {"kind": "random_field", "albedo_contrast": 0.2, "k_contrast": 0.1, "correlation_length_m": 30.0}


def sphere_points(n, radius_m=200.0):
    """Nearly uniform points on a sphere (Fibonacci lattice), like facet centroids."""
    index = np.arange(n) + 0.5
    z = 1 - 2 * index / n
    azimuth = np.pi * (1 + 5**0.5) * index
    ring = np.sqrt(1 - z**2)
    return radius_m * np.column_stack([ring * np.cos(azimuth), ring * np.sin(azimuth), z])


def correlogram(points, fields, max_distance, n_bins):
    """Mean product of the standardised fields over point pairs, per distance bin; averaged over fields."""
    pairs = cKDTree(points).query_pairs(max_distance, output_type="ndarray")
    distance = np.linalg.norm(points[pairs[:, 0]] - points[pairs[:, 1]], axis=1)
    bins = np.minimum((distance / max_distance * n_bins).astype(int), n_bins - 1)
    products = np.mean([field[pairs[:, 0]] * field[pairs[:, 1]] for field in fields], axis=0)
    centres = (np.arange(n_bins) + 0.5) * max_distance / n_bins
    counts = np.bincount(bins, minlength=n_bins)
    filled = counts >= 100
    return centres[filled], np.bincount(bins, products, n_bins)[filled] / counts[filled]


@pytest.mark.parametrize("length_m", [15.0, 40.0])
def test_field_is_standardised_and_correlated_over_the_requested_length(length_m):
    points = sphere_points(6000)
    fields = [surface_maps.smooth_random_field(points, length_m, np.random.default_rng(seed)) for seed in range(8)]
    for field in fields:
        assert field.shape == (len(points),)
        assert abs(field.mean()) < 1e-12 and field.std() == pytest.approx(1.0)
    distances, correlation = correlogram(points, fields, 3 * length_m, 15)
    assert len(distances) >= 12
    expected = np.exp(-(distances**2) / (2 * length_m**2))
    assert np.abs(correlation - expected).max() < 0.12
    # Where the correlation falls to exp(-1/2): the correlation length.
    fitted = np.interp(-np.exp(-0.5), -correlation, distances)
    assert fitted == pytest.approx(length_m, rel=0.15)


def test_field_is_roughly_gaussian_and_smooth():
    points = sphere_points(8000)
    field = surface_maps.smooth_random_field(points, 20.0, np.random.default_rng(0))
    assert np.mean(np.abs(field) > 2) == pytest.approx(0.0455, abs=0.03)
    # Nearest neighbours (about 8 m apart) differ as the kernel says, far less than random pairs (sqrt 2).
    distance, neighbour = cKDTree(points).query(points, k=2)
    expected = np.sqrt(2 * (1 - np.exp(-np.mean(distance[:, 1] ** 2) / (2 * 20.0**2))))
    assert np.std(field - field[neighbour[:, 1]]) == pytest.approx(expected, rel=0.2)
    assert expected < 0.5


def test_field_is_deterministic_by_seed():
    points = sphere_points(500)
    first = surface_maps.smooth_random_field(points, 25.0, np.random.default_rng(4))
    assert np.array_equal(first, surface_maps.smooth_random_field(points, 25.0, np.random.default_rng(4)))
    assert np.array_equal(first, surface_maps.smooth_random_field(points, 25.0, 4))
    assert not np.allclose(first, surface_maps.smooth_random_field(points, 25.0, 5))


def test_field_on_50000_points_is_memory_safe():
    points = sphere_points(50_000, radius_m=300.0)
    tracemalloc.start()
    try:
        field = surface_maps.smooth_random_field(points, 50.0, np.random.default_rng(0))
        peak_bytes = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert field.shape == (50_000,) and np.isfinite(field).all()
    assert peak_bytes < 80e6  # a dense 50,000 x 1024 feature matrix alone would be 400 MB


def test_facet_maps_means_contrasts_and_determinism():
    centroids = sphere_points(5000)
    albedo, minnaert_k = surface_maps.facet_maps(centroids, FIELD_SPEC, seed=11, albedo=0.5, minnaert_k=0.8)
    assert albedo.shape == minnaert_k.shape == (5000,)
    assert albedo.mean() == pytest.approx(0.5, abs=1e-9) and albedo.std() == pytest.approx(0.1)
    assert minnaert_k.mean() == pytest.approx(0.8, abs=1e-9) and minnaert_k.std() == pytest.approx(0.1)
    # Independent albedo and k fields.
    assert abs(np.corrcoef(albedo, minnaert_k)[0, 1]) < 0.2
    # The same seed gives the same maps; another mean scales the same pattern.
    again = surface_maps.facet_maps(centroids, FIELD_SPEC, 11, 0.5, 0.8)
    assert np.array_equal(again[0], albedo) and np.array_equal(again[1], minnaert_k)
    brighter, steeper = surface_maps.facet_maps(centroids, FIELD_SPEC, 11, 0.7, 0.9)
    unclipped = brighter < 1.0
    assert unclipped.mean() > 0.95
    assert np.allclose(brighter[unclipped] / albedo[unclipped], 0.7 / 0.5) and np.allclose(steeper - minnaert_k, 0.1)
    other = surface_maps.facet_maps(centroids, FIELD_SPEC, 12, 0.5, 0.8)
    assert not np.allclose(other[0], albedo)


def test_facet_maps_clip():
    centroids = sphere_points(3000)
    spec = {**FIELD_SPEC, "albedo_contrast": 1.5, "k_contrast": 0.6}
    albedo, minnaert_k = surface_maps.facet_maps(centroids, spec, 0, 0.7, 0.9)
    assert albedo.min() == 0.02 and albedo.max() == 1.0
    assert minnaert_k.min() == 0.3 and minnaert_k.max() == 1.3
    inside = (albedo > 0.02) & (albedo < 1.0)
    assert 0.3 < inside.mean() < 0.95


def test_uniform_maps_are_the_set_values():
    albedo, minnaert_k = surface_maps.facet_maps(sphere_points(100), {"kind": "uniform", "name": "paper"}, 0, 0.6, 0.75)
    assert np.all(albedo == 0.6) and np.all(minnaert_k == 0.75)


@pytest.mark.parametrize(
    "spec, message",
    [
        ({"kind": "checkerboard"}, "kind"),
        ({"kind": "uniform", "albedo_contrast": 0.1}, "albedo_contrast"),
        ({**FIELD_SPEC, "albedo_contrast": -0.1}, "albedo_contrast"),
        ({**FIELD_SPEC, "k_contrast": "large"}, "k_contrast"),
        ({**FIELD_SPEC, "correlation_length_m": 0}, "correlation_length_m"),
        ({key: value for key, value in FIELD_SPEC.items() if key != "correlation_length_m"}, "correlation_length_m"),
        ({**FIELD_SPEC, "correlation_length_km": 0.05}, "correlation_length_km"),
        ("uniform", "mapping"),
    ],
)
def test_bad_specs_are_refused_naming_the_config_key(spec, message):
    with pytest.raises(ValueError, match=message) as error:
        surface_maps.facet_maps(sphere_points(10), spec, 0, 0.5, 0.8)
    assert "surface_maps" in str(error.value)


def test_save_and_load_round_trip(tmp_path):
    albedo, minnaert_k = surface_maps.facet_maps(sphere_points(200), FIELD_SPEC, 3, 0.5, 0.8)
    path = surface_maps.save_facet_maps(tmp_path / "truth" / "facet_maps.npz", albedo, minnaert_k, FIELD_SPEC, 3)
    assert path.exists()
    loaded_albedo, loaded_k = surface_maps.load_facet_maps(path)
    assert np.array_equal(loaded_albedo, albedo) and np.array_equal(loaded_k, minnaert_k)
