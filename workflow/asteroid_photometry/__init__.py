"""Asteroid photometry: render Itokawa with a Minnaert law and recover its parameters.

The library behind the Snakemake workflow. Each module is one stage:

- ``shape``: read, verify and describe the Itokawa shape models (body frame).
- ``cameras``: intrinsics and per-image poses of the turning body.
- ``render``: the Minnaert BSDF as a Mitsuba plugin and the image renderer.
- ``observe``: visibility, shadows and brightness sampling of surface points.
- ``estimate``: the paper's joint Levenberg-Marquardt fit and Iwano's baseline.
- ``varpro``: the default estimator (variable projection, weighted, robust).
- ``noise`` / ``fisher``: the sensor model and the Cramer-Rao bound.
- ``surface_maps``: spatially varying albedo and k.
- ``reconstruct`` / ``cloud`` / ``register`` / ``quality`` / ``refine`` /
  ``table2``: Table 2 from images alone, scored against the truth.
- ``sensitivity``: what the estimator needs from the geometry.
- ``photometry`` / ``render_models`` / ``model_fit`` / ``mismatch``: the
  photometric model family (Lambert, Lommel-Seeliger, Lunar-Lambert,
  Minnaert, Hapke), its Mitsuba plugin, its fits and the model-mismatch
  experiment.
- ``stages``: the file-level stages the rule scripts call.
- ``metrics`` / ``plots``: comparison with the truth and with the paper.

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
