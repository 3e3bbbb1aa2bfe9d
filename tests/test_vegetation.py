"""Procedural vegetation: determinism, derived foliage forces, geometry and reachability."""

import math

import numpy as np
import pytest
import trimesh

from scenes.array import ArraySpec
from scenes.branch_reach import branch_reach_error, gap_of_branch
from scenes.foliage_materials import PAPER_MODULUS_MPA, PAPER_SLIP_FRICTION
from scenes.foliage_meshes import CONTACT_RIM_POINTS
from scenes.vegetation import (
    FOLIAGE_KINDS,
    NATURAL_TRIANGLE_BUDGET,
    SAMPLING_PENETRATION_MM,
    VegetationSpec,
    build_vegetation,
)

ARRAY = ArraySpec()
TIP_MM = 350.0  # 210 mm frame radius + 140 mm whisker
SPEC_BRANCHES = [(0.0,), (50.0,), (100.0,), (150.0,), (0.0, 50.0), (0.0, 100.0)]


def build(foliage, distance="intermediate", branches=(), seed=0):
    return build_vegetation(VegetationSpec(foliage, distance, branches, seed), ARRAY)


def part(veg, name):
    (found,) = [p for p in veg.parts if p.name == name]
    return found


def paper_force_N(thickness_mm, width_mm=12.0, clamp_mm=35.0):
    """The docstring's derivation, restated: a clamped strip slipping at slope atan(friction)."""
    D = PAPER_MODULUS_MPA * thickness_mm**3 / 12.0
    return 2.0 * D * width_mm * PAPER_SLIP_FRICTION / clamp_mm**2


def marker_mm(force_N, lever_mm):
    return 8.0 * math.sin(force_N * lever_mm / 5.7)


@pytest.mark.parametrize("foliage", FOLIAGE_KINDS)
def test_same_seed_same_scene_other_seed_differs(foliage):
    a, b = (
        build(foliage, branches=(0.0, 50.0), seed=4),
        build(foliage, branches=(0.0, 50.0), seed=4),
    )
    assert a.contacts == b.contacts and a.branches == b.branches and a.z_front_mm == b.z_front_mm
    for pa, pb in zip(a.parts, b.parts, strict=True):
        assert pa.name == pb.name and pa.albedo_rgb == pb.albedo_rgb
        np.testing.assert_array_equal(pa.mesh.vertices, pb.mesh.vertices)
        np.testing.assert_array_equal(pa.mesh.faces, pb.mesh.faces)
    if foliage != "none":
        assert build(foliage, branches=(0.0, 50.0), seed=5).contacts != a.contacts


def test_paper_forces_follow_the_documented_derivation():
    soft, stiff = build("soft").contacts, build("stiff").contacts
    for contacts, t in ((soft, 0.10), (stiff, 0.19)):
        EI = PAPER_MODULUS_MPA * t**3 / 12.0 * 12.0
        for c in contacts:
            assert c.force_limit_N == pytest.approx(paper_force_N(t), rel=1e-12)
            assert c.stiffness_N_per_mm == pytest.approx(3.0 * EI / 35.0**3, rel=1e-12)
            assert c.give_way_mm == pytest.approx(2.0 / 3.0 * 35.0 * PAPER_SLIP_FRICTION, rel=1e-12)
            assert abs(c.vertical_ratio) <= 0.2
    assert soft[0].force_limit_N == pytest.approx(1.91e-3, rel=1e-2)  # the docstring's figures
    assert stiff[0].force_limit_N == pytest.approx(13.1e-3, rel=1e-2)
    assert soft[0].force_limit_N < stiff[0].force_limit_N


def test_paper_deflects_a_marker_by_the_documented_amounts():
    lever = TIP_MM - SAMPLING_PENETRATION_MM["far"] - 210.0  # central whisker meets the strips
    soft = marker_mm(build("soft").contacts[0].force_limit_N, lever)
    stiff = marker_mm(build("stiff").contacts[0].force_limit_N, lever)
    assert soft == pytest.approx(0.25, abs=0.01) and stiff == pytest.approx(1.73, abs=0.01)
    assert stiff < 8.0  # below the marker's full travel: one strip never saturates it


@pytest.mark.parametrize("kind", ["soft", "stiff"])
def test_strips_cover_the_band_in_a_thin_layer_in_front_of_branches(kind):
    veg = build(kind, "far", branches=(0.0,))
    lo, hi = part(veg, "strips").mesh.bounds
    assert lo[1] <= -250.0 and hi[1] >= 250.0
    assert lo[0] <= -600.0 and hi[0] >= 600.0
    assert lo[2] >= veg.z_front_mm - 1e-9
    assert hi[2] <= veg.z_front_mm + 6.0 + 1e-9
    assert hi[2] < veg.branches[0].z_mm - veg.branches[0].radius_mm
    x = np.array([c.x_mm for c in veg.contacts])
    assert x.min() <= -600.0 and x.max() >= 600.0
    assert np.diff(x).min() >= 12.0 and np.diff(x).max() <= 16.0  # width + gap, jittered
    assert all(veg.z_front_mm <= c.z_mm <= veg.z_front_mm + 6.0 for c in veg.contacts)


@pytest.mark.parametrize("distance", list(SAMPLING_PENETRATION_MM))
@pytest.mark.parametrize("branches", SPEC_BRANCHES)
def test_branches_at_their_x_behind_the_foliage(distance, branches):
    veg = build("soft", distance, branches)
    z = TIP_MM - SAMPLING_PENETRATION_MM[distance] + 12.0
    assert veg.z_front_mm == TIP_MM - SAMPLING_PENETRATION_MM[distance]
    assert [(b.x_mm, b.z_mm, b.radius_mm) for b in veg.branches] == [(x, z, 5.0) for x in branches]
    mesh = part(veg, "branches").mesh
    lo, hi = mesh.bounds
    assert lo[1] <= -400.0 + 1e-9 and hi[1] >= 400.0 - 1e-9
    section = trimesh.intersections.mesh_plane(mesh, [0.0, 1.0, 0.0], [0.0, 0.0, 0.0])
    for point in section.reshape(-1, 3):
        r = min(math.hypot(point[0] - x, point[2] - z) for x in branches)
        assert 5.0 * math.cos(math.pi / 24) - 1e-9 <= r <= 5.0 + 1e-9  # on the 24-gon


def test_no_foliage_means_branches_alone():
    veg = build("none", branches=(50.0,))
    assert veg.contacts == () and [p.name for p in veg.parts] == ["branches"]
    assert build("none").parts == ()


def test_closed_meshes_face_outwards_and_leaves_are_two_sided():
    for kind in ("soft", "sparse", "dense"):
        veg = build(kind, branches=(0.0,))
        for p in veg.parts:
            assert all(0.0 <= c <= 1.0 for c in p.albedo_rgb)
            if p.name == "leaves":
                half = len(p.mesh.faces) // 2
                np.testing.assert_array_equal(p.mesh.faces[half:], p.mesh.faces[:half, ::-1])
            else:
                assert p.mesh.is_winding_consistent and p.mesh.volume > 0


@pytest.mark.parametrize("distance", list(SAMPLING_PENETRATION_MM))
def test_every_spec_branch_is_reachable_and_far_ones_are_named(distance):
    for branches in SPEC_BRANCHES:
        assert branch_reach_error(branches, distance, ARRAY, 50.0) is None
    message = branch_reach_error((0.0, 400.0), distance, ARRAY, 50.0)
    assert message is not None and "\n" not in message
    assert "400" in message and distance in message and "reachable x" in message


def test_reachable_range_matches_the_geometry_at_far():
    # At far (branch z = 317) the outermost whiskers crossing z = 317 are at +/-22.5 deg; the
    # branch touches when its centre is within 5 + 0.75 mm of the rod, then the sweep adds 50.
    z = TIP_MM - SAMPLING_PENETRATION_MM["far"] + 12.0
    edge = z * math.tan(math.radians(22.5)) + 5.75 / math.cos(math.radians(22.5)) + 50.0
    message = branch_reach_error((400.0,), "far", ARRAY, 50.0)
    low, high = (float(v) for v in message.split("reachable x: ")[1].split(" mm")[0].split(".."))
    assert high == pytest.approx(edge, abs=1.5) and low == -high


def test_without_a_sweep_a_branch_between_rods_is_out_of_reach():
    z = TIP_MM - SAMPLING_PENETRATION_MM["far"] + 12.0
    between = z * math.tan(math.radians(3.75))  # midway between whiskers 6 and 7: 20 mm from each
    assert branch_reach_error((0.0,), "far", ARRAY, 0.0) is None
    assert branch_reach_error((between,), "far", ARRAY, 0.0) is not None
    assert branch_reach_error((between,), "far", ARRAY, 20.0) is None


@pytest.mark.parametrize("distance", list(SAMPLING_PENETRATION_MM))
def test_gap_of_branch(distance):
    z = TIP_MM - SAMPLING_PENETRATION_MM[distance] + 12.0
    psi = np.radians(np.linspace(-45.0, 45.0, 13))
    assert gap_of_branch(0.0, distance, ARRAY) == (6, 7)  # on whisker 6: the gap to its right
    assert gap_of_branch(-1.0, distance, ARRAY) == (5, 6)
    assert gap_of_branch(z * math.tan((psi[3] + psi[4]) / 2), distance, ARRAY) == (3, 4)
    assert gap_of_branch(z * math.tan(psi[3]), distance, ARRAY) == (3, 4)
    assert gap_of_branch(z * math.tan(psi[9] - 1e-3), distance, ARRAY) == (8, 9)
    assert gap_of_branch(-5000.0, distance, ARRAY) == (0, 1)  # clamped at the ends
    assert gap_of_branch(5000.0, distance, ARRAY) == (11, 12)
    assert gap_of_branch(z * math.tan(psi[12]), distance, ARRAY) == (11, 12)


def _distance_to_segments(point, segments):
    a, b = segments[:, 0], segments[:, 1]
    s = np.clip(np.sum((point - a) * (b - a), axis=1) / np.sum((b - a) ** 2, axis=1), 0, 1)
    return np.linalg.norm(point - (a + s[:, None] * (b - a)), axis=1).min()


def _leaf_chord_midpoints(leaves):
    """Where each leaf polygon (fan centre + rim, as laid out in the mesh) crosses y = 0."""
    n_leaves = len(leaves.vertices) // (CONTACT_RIM_POINTS + 1)
    rims = leaves.vertices.reshape(n_leaves, CONTACT_RIM_POINTS + 1, 3)[:, 1:]
    out = []
    for rim in rims:
        crossings = []
        for p, q in zip(rim, np.roll(rim, -1, axis=0), strict=True):
            if (p[1] > 0) != (q[1] > 0):
                crossings.append(p + p[1] / (p[1] - q[1]) * (q - p))
        if crossings:
            out.append(np.mean(crossings, axis=0))
    return np.array(out)


@pytest.mark.parametrize("kind", ["sparse", "dense"])
@pytest.mark.parametrize("distance", list(SAMPLING_PENETRATION_MM))
def test_natural_contacts_exactly_where_foliage_crosses_the_array_plane(kind, distance):
    veg = build(kind, distance, seed=2)
    contacts = np.array([[c.x_mm, 0.0, c.z_mm] for c in veg.contacts])
    assert len(contacts) > 0
    assert contacts[:, 2].min() >= veg.z_front_mm and contacts[:, 2].max() <= TIP_MM
    twigs, leaves = part(veg, "twigs").mesh, part(veg, "leaves").mesh
    twig_section = trimesh.intersections.mesh_plane(twigs, [0, 1, 0], [0, 0, 0])
    chords = _leaf_chord_midpoints(leaves)
    reachable_chords = chords[chords[:, 2] <= TIP_MM]
    on_leaf = [np.linalg.norm(reachable_chords - c, axis=1).min() < 1e-9 for c in contacts]
    on_twig = [_distance_to_segments(c, twig_section) <= 1.0 for c in contacts]
    assert all(a or b for a, b in zip(on_leaf, on_twig, strict=True))
    assert sum(on_leaf) == len(reachable_chords)  # every reachable leaf crossing is a contact
    vertices = np.concatenate([twigs.vertices, leaves.vertices])
    assert vertices[:, 2].min() >= veg.z_front_mm - 1e-9


@pytest.mark.slow
def test_natural_forces_leaves_soft_twigs_stiffer_dense_stiffer():
    def limits(kind):  # pooled over a few seeds: one scene has only a handful of twig crossings
        leaf, twig = [], []
        for seed in range(6):
            veg = build(kind, "close", seed=seed)
            chords = _leaf_chord_midpoints(part(veg, "leaves").mesh)
            for c in veg.contacts:
                d = np.linalg.norm(chords - [c.x_mm, 0.0, c.z_mm], axis=1).min()
                (leaf if d < 1e-9 else twig).append(c.force_limit_N)
        return np.median(leaf), np.median(twig), len(leaf)

    sparse, dense = limits("sparse"), limits("dense")
    assert sparse[0] < sparse[1] and dense[0] < dense[1]
    assert sparse[0] < dense[0] and sparse[1] < dense[1] and sparse[2] < dense[2]


@pytest.mark.parametrize("kind", ["sparse", "dense"])
def test_natural_meshes_within_triangle_budget(kind):
    for seed in range(3):
        veg = build(kind, seed=seed)
        assert sum(len(p.mesh.faces) for p in veg.parts) <= NATURAL_TRIANGLE_BUDGET


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"foliage": "grass", "distance": "far"}, "foliage"),
        ({"foliage": "soft", "distance": "near"}, "distance"),
        ({"foliage": "soft", "distance": "far", "branches_mm": (0.0, math.nan)}, "branches_mm"),
    ],
)
def test_bad_specs_are_rejected(kwargs, field):
    with pytest.raises(ValueError, match=field):
        VegetationSpec(**kwargs)


def test_unknown_names_list_the_choices():
    with pytest.raises(ValueError, match="dense"):
        VegetationSpec("grass", "far")
    with pytest.raises(ValueError, match="intermediate"):
        VegetationSpec("soft", "near")
    with pytest.raises(ValueError, match="distance"):
        gap_of_branch(0.0, "near", ARRAY)
