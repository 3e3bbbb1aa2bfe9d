"""Material numbers of the whisker rod, its coupling and its contacts, each with its source.

The rod is polyester (SPEC 1: PET or PBT, 1.5 mm diameter, 140 mm). Values marked *estimate*
have no measurement behind them for this pairing; they are defaults the study can sweep (they are
fields of :class:`scenes.array.ArraySpec` or arguments of the mechanics), with the range worth
sweeping beside them.

Sources (facts only):
[thyssen]  thyssenkrupp Materials, "PET (Polyethylene terephthalate) Product Guide": PET
           (TECAPET, Ertalyte) rod and plate, tensile modulus 3,172-3,241 MPa, density
           1.38-1.41 g/cm3.
[polytech] Polytech Industrial, "PET thermoplastic polyester" rod datasheet: tensile modulus
           460,000 psi (ASTM D638) = 3,172 MPa, specific gravity 1.41.
[mechsp]   Mechspares, "Polyethylene Terephthalate (PET)" datasheet: specific gravity 1.38
           (ASTM D792).
[mt238]    Mettler Toledo, Thermal Analysis Handbook HB238, "Dynamic Mechanical Analysis of PET":
           the glass transition (main loss peak) is at about 80 C; below it only a small
           beta relaxation, i.e. PET at room temperature is a low-loss glassy solid.
[design]   designengineers.blogspot.com, "Coefficients of friction: static ranges": PBT
           0.30-0.40, dry wood 0.30-0.50, PE 0.40-0.50 (static; counterface not stated).
[bopet]    BOPET film datasheet (madeinchina.com, 8 um matte film): coefficient of friction
           film on film, static 0.55, dynamic 0.50 (ASTM D1894).
"""

from __future__ import annotations

#: Young's modulus of PET rod stock (MPa) [thyssen, polytech]; drawn monofilament can be
#: stiffer, PBT softer (about 2.5 GPa): sweep 2500-4500.
ROD_MODULUS_MPA = 3172.0
#: Density of PET (kg/m3) [mechsp, thyssen: 1380-1410].
ROD_DENSITY_KG_M3 = 1380.0
#: Loss factor eta of the coupling's plastic foil at the whisker's ringing frequency (~8 Hz),
#: *estimate*: glassy PET at room temperature sits well below its 80 C loss peak [mt238], where
#: tan(delta) of glassy polymers is of order 0.01-0.03. Sweep 0.005-0.1 (air drag and the
#: clamping of the foil add loss; a higher value rings less).
COUPLING_LOSS_FACTOR = 0.02
#: Density of the marker's printed carrier (kg/m3), *estimate*: a 3-D printed PLA plate
#: (PLA about 1240; infill makes it lighter). It adds about 2 % to the whisker's inertia.
CARRIER_DENSITY_KG_M3 = 1240.0

#: Coulomb friction, polyester rod on the dry wooden branch (bark or dowel), *estimate* from the
#: static ranges of PBT (0.30-0.40) and dry wood (0.30-0.50) [design]. Sweep 0.2-0.5.
ROD_ON_WOOD_FRICTION = 0.35
#: Polyester rod on paper, *estimate*: below PET film on itself (0.50-0.55) [bopet], within the
#: PBT range [design]. Sweep 0.3-0.6.
ROD_ON_PAPER_FRICTION = 0.4
#: Polyester rod on a leaf blade, *estimate*: waxy cuticles slide more easily than paper; no
#: measurement for this pairing was found. Sweep 0.2-0.5.
ROD_ON_LEAF_FRICTION = 0.3
#: Polyester rod on a twig's bark: the wooden branch's value (*estimate*, see above).
ROD_ON_TWIG_FRICTION = ROD_ON_WOOD_FRICTION
