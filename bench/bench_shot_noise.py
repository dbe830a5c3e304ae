#!/usr/bin/env python3
"""Benchmark the two shot-noise draws of ``noise.apply_sensor_noise`` on mission-like images, and how each keeps its
counts when the render moves in its last digits.

The mission images of a noisy condition (``degrade.degrade_images``) draw their
shot noise by the inverse CDF (``shot_draw="inverse_cdf"``, one uniform a
pixel through ``noise.poisson_quantile``); the noise experiments of Table 1
keep numpy's Poisson sampler (``"sampler"``). This script makes ``--images``
images of 512 x 512 pixels like a paper set's (a lit disc of radiance 0 to 0.9
on a dark sky, blurred by the ``amica`` condition's PSF), and for each draw,
in this one process:

- the seconds a draw of one image takes under the ``amica_12bit`` sensor
  (best of ``--repeats``, the mean over the images), and the ratio;
- the share of an image's codes that change when a fifth of its pixels move
  by a relative ``--shift``, the largest over the images, and how many
  images have more than 1 % of their codes changed (the sampler's noise fell
  out of step). A render made on another processor differs by about 1e-7;
  on the 36 rendered images of a paper set (light 0, albedo 0.7, k 1, with
  the PSF) that shift put the sampler out of step on 4 images and 1e-6 on 11,
  the inverse CDF on none. These synthetic images, with fewer dim pixels,
  need the default 1e-6 to show it.

    .venv/bin/python bench/bench_shot_noise.py                 # ~30 s
    .venv/bin/python bench/bench_shot_noise.py --images 4
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from asteroid_photometry.world import degrade, noise  # noqa: E402
from timing import best_of  # noqa: E402

SIZE = 512
FWHM_PX = 1.5


def mission_like_image(rng) -> np.ndarray:
    """A lit disc (radius 150 pixels, off centre by a few) of radiance 0 to 0.9 on a dark sky, blurred by the PSF."""
    vv, uu = np.mgrid[0:SIZE, 0:SIZE]
    cv, cu = SIZE / 2 + rng.uniform(-8, 8, 2)
    image = np.where(np.hypot(vv + 0.5 - cv, uu + 0.5 - cu) < 150, rng.uniform(0.0, 0.9, (SIZE, SIZE)), 0.0)
    return degrade.apply_psf(image, degrade.psf_kernel(FWHM_PX))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=12)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--shift", type=float, default=1e-6, help="the relative shift of the moved pixels")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    sensor = noise.sensor_from_config(noise.PROPOSED_NOISE_LEVELS[1])
    rng = np.random.default_rng(args.seed)
    seconds = {draw: [] for draw in noise.SHOT_DRAWS}
    changed = {draw: [] for draw in noise.SHOT_DRAWS}
    for index in range(args.images):
        image = mission_like_image(rng)
        moved = image * (1.0 + args.shift * (rng.random(image.shape) < 0.2))
        for draw in noise.SHOT_DRAWS:
            t, first = best_of(args.repeats, lambda: noise.apply_sensor_noise(image, sensor, index, shot_draw=draw))
            seconds[draw].append(t)
            changed[draw].append(float(np.mean(first != noise.apply_sensor_noise(moved, sensor, index, shot_draw=draw))))
    print(f"{args.images} images of {SIZE} x {SIZE}, a fifth of the pixels moved by a relative {args.shift:g}")
    print(f"{'draw':12s} {'s an image':>10s} {'codes changed (max)':>20s} {'images > 1 %':>13s}")
    for draw in noise.SHOT_DRAWS:
        print(f"{draw:12s} {np.mean(seconds[draw]):10.3f} {max(changed[draw]):20.2e} {sum(c > 0.01 for c in changed[draw]):13d}")
    ratio = np.mean(seconds["inverse_cdf"]) / np.mean(seconds["sampler"])
    print(f"ratio inverse_cdf / sampler: {ratio:.1f}")
    return ratio, changed


if __name__ == "__main__":
    main()
