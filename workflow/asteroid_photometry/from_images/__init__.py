"""Table 2's geometry from images alone: structure from motion, registration to the shape model, the oriented cloud, the photometric refinement."""
