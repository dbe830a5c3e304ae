"""Helpers shared by the estimator tests: light directions and per-point truths of synthetic sets."""

import numpy as np


def light_at(angle_deg, azimuth_deg=30.0):
    """Camera-frame light direction at a given light angle from -z."""
    theta, phi = np.radians(angle_deg), np.radians(azimuth_deg)
    return np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), -np.cos(theta)])


def per_point_truth(n_points, seed):
    """Per-point albedo in [0.3, 0.8] and k in [0.6, 1.0]."""
    rng = np.random.default_rng(seed)
    return rng.uniform(0.3, 0.8, n_points), rng.uniform(0.6, 1.0, n_points)
