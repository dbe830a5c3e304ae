"""Asteroid photometry: render Itokawa with a Minnaert law and recover its parameters.

The library behind the Snakemake workflow, by domain (docs/architecture.md
draws it). Imports go one way, down this list:

- ``reflectance``: the photometric laws (Lambert, Lommel-Seeliger,
  Lunar-Lambert, Minnaert, Hapke), each written once.
- ``core``: the config's schema, atomic file writes, failure records, logging,
  the footprint of a run.
- ``world``: the synthetic world: shape models, cameras, the Mitsuba renderer
  and its plugins, the sensor, surface maps, visibility and sampling, the
  configured image sets, reading a rendered set back.
- ``estimation``: observations, the estimators (the paper's LM, Iwano's
  baseline, variable projection), the Fisher information, the model-family
  fits, and one registry to run them.
- ``from_images``: structure from motion, registration to the shape model,
  the oriented cloud and its photometric refinement.
- ``evaluation``: the truth (read in one place), metrics, reconstruction
  quality, tables, plots and the summary.
- ``experiments``: the file-level stages the rule scripts call (Table 1 and
  its sweeps, the Monte Carlo, Table 2, the geometry study, model mismatch).

Conventions used everywhere
---------------------------
- Lengths are in metres unless a name says ``_km``. Angles are in radians
  unless a name says ``_deg``.
- Body frame: the shape model's own frame (origin at the centre of mass,
  +z the spin pole), converted from kilometres to metres on load.
- Camera frame: OpenCV/COLMAP convention, +x right, +y down, +z along the
  optical axis (towards the scene). Pixel coordinates are continuous with
  the top-left corner of the top-left pixel at (0, 0), so the centre of
  pixel (col, row) is (col + 0.5, row + 0.5) and the principal point of a
  W x H image is (W/2, H/2).
- ``body_to_camera`` is a 4x4 matrix mapping body-frame points to the
  camera frame: ``X_cam = R @ X_body + t``.
- ``light_dir_cam`` is the unit vector from the surface towards the Sun, in
  the camera frame; the light angle is the angle between it and the
  direction towards the camera, ``-z``: ``light_deg = degrees(arccos(-l_z))``.
- Minnaert brightness of point p in image i:
  ``b = albedo * cos_i**k * cos_o**(k - 1)`` with ``cos_i = n . l`` and
  ``cos_o = n . v``, ``v`` the unit vector from the point to the camera.
"""
