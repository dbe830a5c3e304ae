"""The experiment's design: which image sets the config asks for, and their names.

A base set is one combination of light angle, albedo and Minnaert k,
rendered noiseless with a uniform surface (the paper's Table 1); its id,
e.g. ``light10_albedo0.7_k0.9``, names its files throughout the workflow.
Two sweeps add variants of every base set:

- ``noise_levels``: the base set's images with sensor noise added,
  ``light10_albedo0.7_k0.9_noise-amica12``;
- ``surface_maps``: the base set rendered with spatially varying albedo and
  k around its values, ``light10_albedo0.7_k0.9_map-field``.

Table 2's imaging conditions start from a base set's render, or its
surface-map variant's. A condition that changes the images themselves (its
views out of the equator, the Sun out of the camera's x-z plane, relief below
the shape model's facets: ``core.config.renders_own_sets``) renders its own copy
of that set, named ``<set>_imaging-<condition>``
(:func:`condition_rendered_set`).
"""

from __future__ import annotations

import hashlib
import itertools
from dataclasses import dataclass, replace

from asteroid_photometry.core.config import renders_own_sets


@dataclass(frozen=True)
class ImageSet:
    light_angle_deg: float
    albedo: float
    minnaert_k: float
    noise_level: str | None = None
    surface_map: str | None = None

    @property
    def light_tag(self) -> str:
        """Names the per-light-angle files shared by the sets with this light."""
        return f"light{self.light_angle_deg:g}"

    @property
    def base(self) -> "ImageSet":
        """The noiseless, uniform set this one varies."""
        return replace(self, noise_level=None, surface_map=None)

    @property
    def is_base(self) -> bool:
        return self.noise_level is None and self.surface_map is None

    @property
    def set_id(self) -> str:
        name = f"{self.light_tag}_albedo{self.albedo:g}_k{self.minnaert_k:g}"
        if self.surface_map:
            name += f"_map-{self.surface_map}"
        if self.noise_level:
            name += f"_noise-{self.noise_level}"
        return name

    @property
    def seed(self) -> int:
        """A seed that depends on this set's own parameters only, not on the other sets."""
        key = f"{self.light_angle_deg:.6f}/{self.albedo:.6f}/{self.minnaert_k:.6f}/{self.surface_map}/{self.noise_level}".encode()
        return int.from_bytes(hashlib.sha256(key).digest()[:4], "little")


def base_sets(config: dict) -> list[ImageSet]:
    """The paper's sets, ordered as its Table 1 (light, k, albedo)."""
    return [
        ImageSet(float(light), float(albedo), float(k))
        for light, k, albedo in itertools.product(config["light_angles_deg"], config["minnaert_k"], config["albedos"])
    ]


def image_sets(config: dict) -> dict[str, ImageSet]:
    """All sets of the config, keyed by set id: the base sets, then their noisy and mapped variants."""
    bases = base_sets(config)
    sets = list(bases)
    sets += [replace(s, noise_level=level["name"]) for level in config.get("noise_levels", []) for s in bases]
    sets += [replace(s, surface_map=spec["name"]) for spec in config.get("surface_maps", []) for s in bases]
    by_id = {s.set_id: s for s in sets}
    if len(by_id) != len(sets):
        raise ValueError("config keys 'noise_levels' / 'surface_maps': two entries share a name")
    return by_id


def named_entry(config: dict, key: str, name: str) -> dict:
    """The entry called ``name`` of the config list ``key`` (``noise_levels`` or ``surface_maps``)."""
    for entry in config.get(key, []):
        if entry["name"] == name:
            return entry
    raise KeyError(f"config key {key!r} has no entry named {name!r}")


def condition_rendered_set(set_id: str, condition: dict) -> str:
    """The id of the rendered set that ``condition`` starts from for base set ``set_id``: the base set,
    its variant with the condition's surface map, and either with ``_imaging-<name>`` where the condition
    renders its own (``light10_albedo0.7_k0.9_map-field_imaging-oblique``)."""
    surface_map = condition.get("surface_map")
    rendered = set_id + (f"_map-{surface_map}" if surface_map else "")
    return rendered + (f"_imaging-{condition['name']}" if renders_own_sets(condition) else "")
