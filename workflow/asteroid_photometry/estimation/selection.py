"""Select, fit, reselect: observations chosen with the light estimated from them.

Which observations an estimator may use depends on the light: the incidence
cut drops grazing illumination and the cast shadows drop what the Sun does
not reach. The light is what is being estimated, so the selection is
iterated from a first one that needs no light:

1. a first selection made without a light (the caller's: what the geometry
   alone allows, less the samples the images themselves show dark), and a
   fit on it;
2. the observations the fitted light selects (``lit``), and a fit on them;
3. again, until the light's selection is the one its light was fitted on (a
   fixed point: the selection reproduces itself), or after
   ``max_reselections`` reselections.

The light never comes from anywhere but the fits: this module sees masks
and the callables that make them.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from asteroid_photometry.estimation.core import angle_between_deg, light_angle_deg

log = logging.getLogger(__name__)

#: At most this many selections made with an estimated light after the first one.
MAX_RESELECTIONS = 3


@dataclass
class Selection:
    """The final selection and how it was reached."""

    mask: np.ndarray  # (n_candidates,) bool: the observations selected
    light_dir_cam: np.ndarray  # the light fitted on ``mask`` (with ``converged``, it selects ``mask`` itself)
    passes: int  # fits made: the light-free first selection's, then one per reselection that changed the observations
    converged: bool  # the last fit's light selects the observations it was fitted on
    sizes: list[int] = field(default_factory=list)  # observations selected in each pass


def select_with_estimated_light(
    first: np.ndarray,
    fit_light: Callable[[np.ndarray], np.ndarray],
    lit: Callable[[np.ndarray], np.ndarray],
    max_reselections: int = MAX_RESELECTIONS,
) -> Selection:
    """Iterate select, fit, reselect from the light-free selection ``first`` (a boolean mask over the candidates).

    ``fit_light(mask)`` fits the observations ``mask`` and returns the light
    (a camera-frame unit vector); ``lit(light)`` is the selection that light
    makes (a mask of the same length).
    """
    mask = np.asarray(first, dtype=bool)
    sizes = [int(mask.sum())]
    light = np.asarray(fit_light(mask), dtype=float)
    passes = 1
    log.info("selection pass 1 (no light): %d observations, light fitted at %.4f deg from the camera", sizes[-1], float(light_angle_deg(light)))
    for _ in range(max_reselections):
        reselected = np.asarray(lit(light), dtype=bool)
        if reselected.shape != mask.shape:
            raise ValueError(f"lit() returned a mask of shape {reselected.shape}, expected {mask.shape}")
        if np.array_equal(reselected, mask):
            log.info("selection converged after %d passes: the fitted light selects the %d observations it was fitted on", passes, sizes[-1])
            return Selection(mask, light, passes, True, sizes)
        added, dropped = int((reselected & ~mask).sum()), int((mask & ~reselected).sum())
        mask = reselected
        previous, light = light, np.asarray(fit_light(mask), dtype=float)
        passes += 1
        sizes.append(int(mask.sum()))
        log.info(
            "selection pass %d: %d observations (%d added, %d dropped), light moved %.2e deg",
            passes, sizes[-1], added, dropped, float(angle_between_deg(previous, light)),
        )
    converged = bool(np.array_equal(np.asarray(lit(light), dtype=bool), mask))
    if not converged:
        log.warning("selection not converged after %d reselections: the last light would select other observations", max_reselections)
    return Selection(mask, light, passes, converged, sizes)

