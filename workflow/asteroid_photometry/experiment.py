"""The experiment's design: which image sets the config asks for, and their names.

A set is one combination of light angle, albedo and Minnaert k; its id,
e.g. ``light10_albedo0.7_k0.9``, names its files throughout the workflow.
"""

from __future__ import annotations

import hashlib
import itertools
from dataclasses import dataclass


@dataclass(frozen=True)
class ImageSet:
    light_angle_deg: float
    albedo: float
    minnaert_k: float

    @property
    def light_tag(self) -> str:
        """Names the per-light-angle files shared by the sets with this light."""
        return f"light{self.light_angle_deg:g}"

    @property
    def set_id(self) -> str:
        return f"{self.light_tag}_albedo{self.albedo:g}_k{self.minnaert_k:g}"

    @property
    def seed(self) -> int:
        """A render seed that depends on the set's parameters only, not on the other sets."""
        key = f"{self.light_angle_deg:.6f}/{self.albedo:.6f}/{self.minnaert_k:.6f}".encode()
        return int.from_bytes(hashlib.sha256(key).digest()[:4], "little")


def image_sets(config: dict) -> dict[str, ImageSet]:
    """All sets of the config, keyed by set id, ordered as the paper's Table 1 (light, k, albedo)."""
    sets = [
        ImageSet(float(light), float(albedo), float(k))
        for light, k, albedo in itertools.product(config["light_angles_deg"], config["minnaert_k"], config["albedos"])
    ]
    return {s.set_id: s for s in sets}
