"""Every detector backend on exact images: ids, corner order and corner positions in the
project's conventions (no systematic offset), the peers' own poses, and the AprilTag adapter's
families and memory safety. A peer's tests skip where it is not installed."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from pipeline.backends import APRILTAG_FAMILIES, BACKENDS, PoseRequest, available, get_backend
from pipeline.detect import DetectorConfig, detect_markers
from scenes.conventions import make_T, rot_x, rot_y, rotation_angle_deg
from scenes.marker import get_dictionary

FAMILIES = ("4x4_50", "apriltag_36h11", "apriltag_16h5")
PEERS = ("locus", "apriltag")


def _backends(names=tuple(BACKENDS)) -> list:
    return [
        pytest.param(n, marks=pytest.mark.skipif(not available(n), reason=f"{n} not installed"))
        for n in names
    ]


def render(family: str, marker_id: int, H: np.ndarray, shape: tuple[int, int], ss: int = 8):
    """An exact image of a marker mapped by ``H`` (3x3, marker modules -> pixels), and its true
    corners (4, 2) in ArUco order.

    Marker modules: (0, 0) is the black square's top-left corner as OpenCV draws the marker, +x
    right, +y down, the square ends at (n, n) with n = code cells + 2. Each pixel is the mean of
    ``ss`` x ``ss`` point samples of the binary marker (pixel (i, j) covers [i - 0.5, i + 0.5]).
    """
    dictionary = get_dictionary(family)
    n = int(dictionary.markerSize) + 2
    cells = dictionary.generateImageMarker(marker_id, n, borderBits=1).astype(float)
    h, w = shape
    sub = (np.arange(ss) + 0.5) / ss - 0.5
    y = (np.arange(h)[:, None] + sub[None, :]).ravel()
    x = (np.arange(w)[:, None] + sub[None, :]).ravel()
    X, Y = np.meshgrid(x, y)
    m = np.linalg.inv(H) @ np.stack([X.ravel(), Y.ravel(), np.ones(X.size)])
    mx, my = np.floor(m[:2] / m[2]).astype(int)
    inside = (mx >= 0) & (mx < n) & (my >= 0) & (my < n)
    values = np.full(X.size, 255.0)
    values[inside] = cells[my[inside], mx[inside]]
    image = values.reshape(h, ss, w, ss).mean(axis=(1, 3))
    square = np.array([[0.0, 0, 1], [n, 0, 1], [n, n, 1], [0, n, 1]]).T
    corners = H @ square
    return np.round(image).astype(np.uint8), (corners[:2] / corners[2]).T


def square_H(module_px: float, x0: float, y0: float) -> np.ndarray:
    """Modules -> pixels for an upright square whose top-left corner is at (x0, y0) px."""
    return np.array([[module_px, 0.0, x0], [0.0, module_px, y0], [0.0, 0.0, 1.0]])


def rot90_corners(corners: np.ndarray, k: int, shape: tuple[int, int]) -> np.ndarray:
    """Where points go under ``np.rot90(image, k)`` (pixel centres at integers)."""
    h, w = shape
    for _ in range(k):
        corners = np.column_stack([corners[:, 1], w - 1 - corners[:, 0]])
        h, w = w, h
    return corners


PERSPECTIVE_H = np.array([[9.0, 1.8, 60.0], [-1.2, 8.5, 70.0], [0.004, 0.0025, 1.0]])


@cache
def perspective_marker(family: str) -> tuple[np.ndarray, np.ndarray]:
    """Marker 3 under a strong perspective (PERSPECTIVE_H), rendered once per family."""
    return render(family, 3, PERSPECTIVE_H, (230, 230))


def _detect(image: np.ndarray, family: str, backend: str, refinement: str = "none"):
    config = DetectorConfig(dictionary=family, backend=backend, corner_refinement=refinement)
    return detect_markers(image, config)


def _error_px(found: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Mean corner error (px) and the length of the mean signed offset (px)."""
    offset = found - truth
    return float(np.linalg.norm(offset, axis=1).mean()), float(np.linalg.norm(offset.mean(0)))


# -- corners on exact images ------------------------------------------------------------------


@pytest.mark.parametrize("backend", _backends())
@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("turns", range(4))
def test_ids_corner_order_and_offset_on_exact_turned_markers(backend, family, turns) -> None:
    """An upright marker with integer-aligned edges, turned by np.rot90: the id, the corners in
    ArUco order (TL of the marker first wherever it lies), and no systematic offset. The peers'
    own corners are exact; OpenCV's unrefined ones are the contour's pixel centres, 0.5 px inside
    at every corner, so only its mean offset is zero."""
    shape = (151, 173)  # odd sides: rows of odd length
    image, truth = render(family, 5, square_H(10.0, 39.5, 29.5), shape, ss=1)
    found = _detect(np.ascontiguousarray(np.rot90(image, turns)), family, backend)
    assert [d.marker_id for d in found] == [5]
    error, offset = _error_px(found[0].corners_px, rot90_corners(truth, turns, shape))
    assert offset < 0.05
    assert error < (0.75 if backend == "opencv" else 0.05)


@pytest.mark.parametrize("backend", _backends(PEERS))
@pytest.mark.parametrize("family", FAMILIES)
def test_peer_corners_on_an_exact_perspective_marker(backend, family) -> None:
    """A marker under a strong perspective, rendered exactly: the peers' corners, in order,
    within 0.05 px on average of the true corners."""
    image, truth = perspective_marker(family)
    found = _detect(image, family, backend)
    assert [d.marker_id for d in found] == [3]
    error, _ = _error_px(found[0].corners_px, truth)
    assert error < 0.05


@pytest.mark.parametrize("family", FAMILIES)
def test_opencv_subpix_corners_on_an_exact_perspective_marker(family) -> None:
    """OpenCV with its "subpix" refinement on the same exact perspective image: in order and
    within 0.35 px on average (cornerSubPix pulls the outer, L-shaped corners inwards: see
    :mod:`pipeline.detect`)."""
    image, truth = perspective_marker(family)
    found = _detect(image, family, "opencv", "subpix")
    assert [d.marker_id for d in found] == [3]
    error, _ = _error_px(found[0].corners_px, truth)
    assert error < 0.35


# -- own poses ---------------------------------------------------------------------------------

K_FX, K_CX, K_CY, SIZE_MM = 800.0, 160.5, 120.0, 20.0
FACING = np.diag([1.0, -1.0, -1.0])  # R_cam_marker: marker +y image-up, +z towards the camera


#: T_cam_marker of the pose tests: fronto-parallel, and tilted by 35 and 25 deg.
POSES = {
    "facing": make_T(FACING, [4.0, -3.0, 150.0]),
    "tilted": make_T(rot_y(np.radians(35)) @ rot_x(np.radians(-25)) @ FACING, [4.0, -3.0, 150.0]),
}


@cache
def pinhole_marker(family: str, pose: str) -> np.ndarray:
    """Marker 2 at POSES[pose] seen by the pinhole K (fx = fy = K_FX, centre K_CX, K_CY)."""
    n = int(get_dictionary(family).markerSize) + 2
    K = np.array([[K_FX, 0.0, K_CX], [0.0, K_FX, K_CY], [0.0, 0.0, 1.0]])
    modules_to_marker = np.array(
        [[SIZE_MM / n, 0.0, -SIZE_MM / 2], [0.0, -SIZE_MM / n, SIZE_MM / 2], [0.0, 0.0, 1.0]]
    )
    T = POSES[pose]
    Rt = np.column_stack([T[:3, 0], T[:3, 1], T[:3, 3]])  # marker plane (x, y, 1) -> camera
    return render(family, 2, K @ Rt @ modules_to_marker, (240, 320), ss=6)[0]


@pytest.mark.parametrize("backend", _backends(PEERS))
@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("pose", POSES)
def test_peer_own_pose_matches_the_truth(backend, family, pose) -> None:
    """A fronto-parallel and a tilted marker: the backend's own T_cam_marker within 1 deg and
    1% of the distance, in the project's marker frame (+z out of the face: towards the
    camera)."""
    image, truth = pinhole_marker(family, pose), POSES[pose]
    config = DetectorConfig(dictionary=family, backend=backend, corner_refinement="none")
    request = PoseRequest(K_FX, K_FX, K_CX, K_CY, SIZE_MM)
    found = get_backend(backend).detect(image, config, max(image.shape), request)
    assert list(found.ids) == [2]
    T = found.own_T_cam_marker[0]
    assert T[2, 2] < 0  # the marker faces the camera
    assert rotation_angle_deg(T[:3, :3], truth[:3, :3]) < 1.0
    assert np.linalg.norm(T[:3, 3] - truth[:3, 3]) < 0.01 * np.linalg.norm(truth[:3, 3])


# -- the AprilTag adapter: families, ids, safety, a missing library -----------------------------

needs_apriltag = pytest.mark.skipif(not available("apriltag"), reason="apriltag not installed")


@needs_apriltag
@pytest.mark.parametrize(("side", "name"), [(4, "tag16h5"), (5, "tag25h9"), (6, "tag36h11")])
def test_aruco_bit_layout_is_the_librarys_own(side, name) -> None:
    """The layout the ArUco families are built in equals the library's own families' (its
    decoder's rotation of a code word is a rotation of the marker only in that layout)."""
    from pipeline.backends.apriltag3 import load
    from pipeline.backends.tag_family import bit_layout

    family = getattr(load(), f"{name}_create")().contents
    library = [(family.bit_x[i], family.bit_y[i]) for i in range(family.nbits)]
    assert bit_layout(side).tolist() == [list(cell) for cell in library]


@needs_apriltag
@pytest.mark.parametrize("family", APRILTAG_FAMILIES)
def test_opencv_apriltag_ids_are_the_librarys(family) -> None:
    """OpenCV's drawing of AprilTag id k is read as id k by the library through its own Python
    module (an independent route from this project's ctypes adapter)."""
    import apriltag

    detector = apriltag.apriltag("tag" + family.removeprefix("apriltag_"))
    last = len(get_dictionary(family).bytesList) - 1
    for marker_id in (0, 1, last):
        image, _ = render(family, marker_id, square_H(8.0, 19.5, 19.5), (110, 110), ss=1)
        assert [d["id"] for d in detector.detect(image)] == [marker_id]


@needs_apriltag
@pytest.mark.slow
@pytest.mark.parametrize("family", BACKENDS["apriltag"].families)
def test_apriltag_reads_every_family_with_opencvs_ids(family) -> None:
    """Every family the registry lists for the adapter: the first id and the last but one,
    upright and turned, read with OpenCV's ids and corners in order (several seconds in all:
    the 1000-code families' decode tables). Not the last: aruco_original's last id looks the
    same turned by a half turn, so no detector can order its corners."""
    last = len(get_dictionary(family).bytesList) - 1
    for marker_id in (0, last - 1):
        shape = (130, 130)
        image, truth = render(family, marker_id, square_H(10.0, 19.5, 19.5), shape, ss=1)
        for turns in (0, 1):
            turned = np.ascontiguousarray(np.rot90(image, turns))
            found = get_backend("apriltag").detect(
                turned, DetectorConfig(family, "none", backend="apriltag"), 130, None
            )
            assert list(found.ids) == [marker_id]
            assert _error_px(found.corners_px[0], rot90_corners(truth, turns, shape))[0] < 0.05


@needs_apriltag
def test_apriltag_adapter_guards_the_c_library() -> None:
    """A strided view is read as its copy; an image under 8 px a side is not passed; only 2-D
    8-bit images are accepted."""
    image, _ = render("4x4_50", 1, square_H(6.0, 9.5, 9.5), (60, 60), ss=1)
    config = DetectorConfig(dictionary="4x4_50", backend="apriltag", corner_refinement="none")
    detect = get_backend("apriltag").detect
    wide = np.zeros((60, 120), np.uint8)
    wide[:, ::2] = image
    contiguous = detect(image, config, 60, None)
    strided = detect(wide[:, ::2], config, 60, None)
    assert list(strided.ids) == list(contiguous.ids) == [1]
    np.testing.assert_array_equal(strided.corners_px, contiguous.corners_px)
    assert len(detect(np.zeros((7, 60), np.uint8), config, 60, None).ids) == 0
    with pytest.raises(ValueError, match="8-bit grey"):
        detect(image.astype(np.float32), config, 60, None)


def test_a_missing_apriltag_library_says_how_to_install(monkeypatch) -> None:
    """Without apriltag-python: one line naming the package and the peers extra, raised before
    any worker starts."""
    from pipeline.backends import PEERS_INSTALL, BackendUnavailableError, apriltag3

    monkeypatch.setattr(apriltag3, "find_spec", lambda name: None)
    with pytest.raises(BackendUnavailableError) as error:
        apriltag3.load.__wrapped__()
    assert "apriltag-python" in str(error.value) and PEERS_INSTALL in str(error.value)
    monkeypatch.setattr(apriltag3, "load", apriltag3.load.__wrapped__)
    assert not available("apriltag")
    with pytest.raises(BackendUnavailableError, match="apriltag-python"):
        _detect(np.full((40, 40), 255, np.uint8), "4x4_50", "apriltag")
