"""How the world becomes pixels: Mitsuba variant choice, fisheye ray tracing, the camera response.

Import :mod:`renderers.variant` and call ``select_variant`` before anything imports drjit.
"""
