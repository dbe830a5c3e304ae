"""The synthetic world: the shape model, the cameras, the renders, the sensor, the surface maps.

Everything here describes or makes what a camera would see; nothing here
estimates or scores. :mod:`.images` reads a rendered set back.
"""
