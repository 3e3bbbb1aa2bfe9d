"""Material numbers of the foliage (SPEC 2), each with its source or marked *estimate*.

Paper strips stand for the lab's laser-cut 80 and 160 g/m2 sheets; the natural kinds for Cornus
mas (sparse) and Tilia tomentosa (dense). Nothing here was measured on the lab's parts: where a
source exists its figure is used; an *estimate* is a module constant a study can sweep, with the
range worth sweeping beside it. The slip friction of the whisker rod on each foliage comes from
:mod:`scenes.rod_materials`, the one home of the rod's contact numbers.

Sources (facts only):
[scirep]   Scientific Reports 4, 6275 (2014), Table 2 "Comparison of the physical properties of
           some papers": printing paper about 110 um thick, Young's modulus 2.92 GPa.
[caliper]  prepressure.com printing dictionary, "caliper": 80 g/m2 writing paper is 0.004 in
           (0.10 mm); "Structural Characteristics of Paper" course notes (scribd 268084097):
           75 g/m2 copy paper 4 mils = 102 um, apparent density 0.74 g/cm3; mcgpaper.com weight
           table: 75.2 g/m2 0.097 mm, 90.3 g/m2 0.12 mm, 105 g/m2 0.147 mm.
[cannell]  Cannell and Morgan, Tree Physiology 3, 355-364 (1987): Young's modulus in bending of
           living branch sections with bark 0.7-4.6 GPa, lower where the water content is higher
           (green trunks 2.4-7.5 GPa).
[cmas]     Cornus mas: leaves 4-10 cm long, 2-4 cm broad, ovate to oblong (Wikipedia, "Cornus
           mas"); ovate-elliptic, 5-10 cm (Spencer, Horticultural Flora of South-eastern
           Australia 3, 2002); 2-4 in long, 0.75-1.5 in wide (ps4910 plant notes).
[ttom]     Tilia tomentosa: blades 5-11 cm long x 5-10 cm wide, petioles 2-4 cm (KPU Plant
           Database); 4-13 cm long and broad, petiole 2.5-4 cm (Midsummer Common tree notes);
           2-5 in long, equally wide (Philadelphia tree key).
[xrite]    X-Rite ColorChecker Classic, patch 4 "Foliage" (the chart's stand-in for green leaves):
           sRGB (87, 108, 67), i.e. linear RGB (0.095, 0.150, 0.056), luminance Y 13.3 %.
"""

from __future__ import annotations

from dataclasses import dataclass

from scenes.rod_materials import (
    ROD_ON_LEAF_FRICTION,
    ROD_ON_PAPER_FRICTION,
    ROD_ON_TWIG_FRICTION,
)

RGB = tuple[float, float, float]

# -- paper strips ----------------------------------------------------------------------------

#: In-plane Young's modulus of printing paper (MPa) [scirep]. Machine and cross directions
#: differ about twofold and the strips' grain is unknown: sweep 2000-6000.
PAPER_MODULUS_MPA = 2920.0
#: Calliper (mm): soft = 80 g/m2 [caliper: 0.097-0.102 mm for 75-80 g/m2]; stiff = 160 g/m2,
#: *estimate*: grammage over the apparent density of copy grades (0.74-0.85 g/cm3 [caliper])
#: gives 0.19-0.22 mm. Sweep 0.17-0.22.
PAPER_THICKNESS_MM = {"soft": 0.10, "stiff": 0.19}
#: Slip friction of the whisker rod on paper [scenes.rod_materials: estimate].
PAPER_SLIP_FRICTION = ROD_ON_PAPER_FRICTION
#: The green paper of the strips, linear RGB, *estimate* (the lab's paper was never measured).
PAPER_ALBEDO: RGB = (0.32, 0.52, 0.22)

# -- natural foliage -------------------------------------------------------------------------

#: Young's modulus of young twigs (MPa), near the low end of living branches' 0.7-4.6 GPa
#: [cannell]: current-year shoots are the wettest wood. Sweep 700-4600.
TWIG_MODULUS_MPA = 1000.0
#: Effective Young's modulus of a leaf lamina in bending (MPa), *estimate*: no figure for these
#: species was found. Sweep 30-300.
LEAF_MODULUS_MPA = 100.0
#: Slip friction of the whisker rod on a twig's bark and on a leaf blade
#: [scenes.rod_materials: estimates].
TWIG_SLIP_FRICTION = ROD_ON_TWIG_FRICTION
LEAF_SLIP_FRICTION = ROD_ON_LEAF_FRICTION
#: Bark of young twigs, linear RGB, *estimate*.
TWIG_ALBEDO: RGB = (0.30, 0.20, 0.12)
#: Green leaves, linear RGB [xrite]. Tilia tomentosa's silvery underside is not modelled.
LEAF_ALBEDO: RGB = (0.095, 0.150, 0.056)


@dataclass(frozen=True)
class NaturalKind:
    """Per-species numbers of natural foliage; each field's source is in :data:`NATURAL`."""

    twigs: int
    leaves_per_twig: int
    twig_diameter_mm: float
    leaf_length_mm: tuple[float, float]
    leaf_aspect: tuple[float, float]  # width / length
    leaf_thickness_mm: float
    petiole_mm: float
    leaf_albedo: RGB


#: twigs, leaves per twig, twig diameter and leaf thickness are *estimates* (dense: more, larger,
#: stiffer); leaf length and aspect come from [cmas] and [ttom]; Tilia's petiole is the middle of
#: [ttom]'s 20-40 mm, Cornus's short petiole an *estimate*.
NATURAL: dict[str, NaturalKind] = {
    "sparse": NaturalKind(40, 12, 1.1, (40.0, 100.0), (0.4, 0.5), 0.2, 8.0, LEAF_ALBEDO),
    "dense": NaturalKind(75, 16, 1.4, (50.0, 110.0), (0.9, 1.0), 0.3, 30.0, LEAF_ALBEDO),
}

# -- branches --------------------------------------------------------------------------------

#: The artificial branch's wooden dowel, linear RGB, *estimate*.
BRANCH_ALBEDO: RGB = (0.45, 0.32, 0.20)
