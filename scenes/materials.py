"""Reflectances of the materials the renderers draw: Lambertian albedos, one place for all.

None of these was measured on the real parts; each line says what its value rests on, so that a
measurement (a grey card beside the part, under the same light) can replace it in one place.
The vegetation's colours live with its meshes (:mod:`scenes.vegetation`).
"""

from __future__ import annotations

#: The print's white paper. Estimate: matte office paper reflects about 0.7-0.9 of visible light.
WHITE_ALBEDO = 0.8
#: The print's black toner. Estimate: matte black toner reflects a few percent.
BLACK_ALBEDO = 0.04
#: The white carrier plate around the print. Estimate: taken to be the print's white paper.
CARRIER_ALBEDO = WHITE_ALBEDO
#: A whisker rod: translucent white polyester (SPEC 1), seen as a light grey. Estimate.
ROD_ALBEDO = 0.55
#: The dark printed arc plate behind the markers. Estimate: a dark grey print.
PLATE_ALBEDO = 0.12
#: The leaf canopy. Traced for shadow rays only, so this value never reaches a pixel.
CANOPY_ALBEDO = 0.3
