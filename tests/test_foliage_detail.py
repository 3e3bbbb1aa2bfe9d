"""Foliage detail levels change only rendered tessellation; a layout seed fixes the foliage."""

import hashlib

import numpy as np
import pytest

import scenes.vegetation as vegetation
from scenes.array import ArraySpec
from scenes.foliage_materials import NaturalKind
from scenes.foliage_meshes import DETAIL_LEVELS, FoliageDetail, get_detail
from scenes.vegetation import FOLIAGE_KINDS, VegetationSpec, build_vegetation

ARRAY = ArraySpec()
LEVELS = ("coarse", "default", "fine")


def build(foliage, branches=(0.0, 100.0), seed=7, detail="default", distance="close"):
    return build_vegetation(VegetationSpec(foliage, distance, branches, seed), ARRAY, detail)


def faces(veg):
    return {p.name: len(p.mesh.faces) for p in veg.parts}


def assert_same_meshes(a, b):
    assert [p.name for p in a] == [p.name for p in b]
    for pa, pb in zip(a, b, strict=True):
        assert pa.albedo_rgb == pb.albedo_rgb
        np.testing.assert_array_equal(pa.mesh.vertices, pb.mesh.vertices)
        np.testing.assert_array_equal(pa.mesh.faces, pb.mesh.faces)


@pytest.mark.parametrize("foliage", FOLIAGE_KINDS)
@pytest.mark.parametrize("distance", ["far", "close"])
def test_every_level_gives_the_same_contacts_and_branches(foliage, distance):
    default = build(foliage, distance=distance)
    for level in ("coarse", "fine", FoliageDetail(5, 4, 7)):
        other = build(foliage, distance=distance, detail=level)
        assert other.contacts == default.contacts and other.branches == default.branches
        assert other.z_front_mm == default.z_front_mm and other.detail == get_detail(level)


@pytest.mark.parametrize("foliage", FOLIAGE_KINDS)
def test_triangle_counts_grow_with_the_level(foliage):
    counts = [faces(build(foliage, detail=level)) for level in LEVELS]
    totals = [sum(c.values()) for c in counts]
    assert totals[0] < totals[1] < totals[2]  # every scene here has branches
    for name in ("twigs", "leaves", "branches"):
        if name in counts[0]:
            assert counts[0][name] < counts[1][name] < counts[2][name]
    if "strips" in counts[0]:
        assert counts[0]["strips"] == counts[1]["strips"] == counts[2]["strips"]  # boxes


def test_default_level_is_the_default_argument():
    for foliage in ("stiff", "dense"):
        assert_same_meshes(
            build_vegetation(VegetationSpec(foliage, "far", (50.0,), 3), ARRAY).parts,
            build(foliage, (50.0,), 3, "default", "far").parts,
        )


# Hashes of the meshes built before the detail levels existed, with the species numbers of that
# time (the sourced leaf sizes came in the same change and move the leaves, not their
# tessellation). Vertices rounded to 0.1 um so that last-bit differences between platforms pass.
BEFORE_NATURAL = {
    "sparse": NaturalKind(40, 12, 1.1, (40.0, 90.0), (0.45, 0.6), 0.2, 8.0, (0.18, 0.36, 0.10)),
    "dense": NaturalKind(75, 16, 1.4, (60.0, 110.0), (0.8, 1.0), 0.3, 20.0, (0.20, 0.32, 0.14)),
}
BEFORE_HASHES = [
    (("soft", "far", (0.0,), 1), "c4d7b6ecc98c7d0b"),
    (("stiff", "close", (0.0, 100.0), 4), "e49d3a8faeadde22"),
    (("sparse", "intermediate", (50.0,), 2), "40a676a6358e5f1b"),
    (("dense", "close", (), 3), "5546b7d110324681"),
]


@pytest.mark.parametrize(("spec", "expected"), BEFORE_HASHES)
def test_default_level_meshes_are_those_built_before_the_levels(monkeypatch, spec, expected):
    monkeypatch.setattr(vegetation, "NATURAL", BEFORE_NATURAL)
    digest = hashlib.sha256()
    for p in build_vegetation(VegetationSpec(*spec), ARRAY, "default").parts:
        digest.update(p.name.encode())
        digest.update((np.round(p.mesh.vertices, 4) + 0.0).tobytes())
        digest.update(np.asarray(p.mesh.faces, np.int64).tobytes())
    assert digest.hexdigest()[:16] == expected


@pytest.mark.parametrize("foliage", ["sparse", "dense"])
def test_fine_leaf_outlines_pass_through_the_contact_outlines(foliage):
    def rims(level):
        k = DETAIL_LEVELS[level].leaf_rim_points
        leaves = next(p.mesh for p in build(foliage, detail=level).parts if p.name == "leaves")
        return leaves.vertices.reshape(-1, k + 1, 3)[:, 1:], k

    (fine, k_fine), (default, k_default) = rims("fine"), rims("default")
    np.testing.assert_allclose(fine[:, :: k_fine // k_default], default, atol=1e-9)


@pytest.mark.parametrize("foliage", FOLIAGE_KINDS)
def test_a_layout_seed_gives_the_same_foliage_with_and_without_branches(foliage):
    bare = build(foliage, branches=())
    for branches in [(0.0,), (50.0,), (0.0, 100.0)]:
        twin = build(foliage, branches=branches)
        assert twin.contacts == bare.contacts
        assert_same_meshes([p for p in twin.parts if p.name != "branches"], bare.parts)
        assert [p.name for p in twin.parts][-1] == "branches"
        assert [b.x_mm for b in twin.branches] == list(branches)


def test_unknown_levels_and_too_few_sections_are_rejected():
    with pytest.raises(ValueError, match="detail: unknown 'ultra'; choose from coarse"):
        build("soft", detail="ultra")
    with pytest.raises(ValueError, match="twig_sections"):
        FoliageDetail(leaf_rim_points=8, twig_sections=2, branch_sections=24)
