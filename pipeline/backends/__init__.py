"""Marker detector backends: which library finds the markers, behind one small interface.

A backend is one adapter module with one function, ``detect(image, config, frame_side_px,
pose) -> Found``: the ids and corners it finds in an 8-bit grey image, mapped to the project's
conventions (:mod:`scenes.conventions`: pixel centres at integer coordinates, ArUco corner
order), and, where the library estimates poses itself and ``pose`` asks for them, its own
``T_cam_marker``. Libraries differ from those conventions by half a pixel and in corner order;
each adapter says how it maps them, and ``tests/test_backends.py`` checks every adapter on exact
images: the peers' own corners within 0.05 px on average, OpenCV's with no mean offset (its
unrefined corners are pixel centres on the contour, 0.5 px inside each corner).

The table :data:`BACKENDS` is the whole registry: a new backend is one adapter and one row.
Peers are an optional extra (``pip install -e .[peers]``): their adapters import the library
only when called, and a missing one raises :class:`BackendUnavailableError` saying how to get it.
Peers run in a worker process (:mod:`pipeline.backends.isolated`), so a crash in their native
code costs the frame, not the run.

A user's own detector is a backend too, named ``plugin:SPEC`` (:mod:`pipeline.backends.plugin`,
``docs/plugins.md``): :func:`get_backend` builds its row when first asked, so every place that
takes a backend name takes a plugin's.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from scenes.marker import dictionary_names

if TYPE_CHECKING:
    from pipeline.detect import DetectorConfig


class Found(NamedTuple):
    """What a backend found: ids (N,), corners (N, 4, 2) in the image's own pixels, and its
    own poses (N, 4, 4) T_cam_marker in mm where asked for and available, else None."""

    ids: np.ndarray
    corners_px: np.ndarray
    own_T_cam_marker: np.ndarray | None = None


class PoseRequest(NamedTuple):
    """What a backend's own pose needs: pinhole intrinsics of the image it is given (the crop's
    principal point already shifted) and the marker's side (mm). Both peers model only pinhole
    lenses, so their own poses ignore the fisheye: that is what they offer, reported as such.
    ``whole_frame``: the image is the camera's whole frame, not a crop (a plugin's own pose is
    only kept then: it knows nothing of crops)."""

    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    size_mm: float
    whole_frame: bool = False


class BackendUnavailableError(RuntimeError):
    """A backend whose library is not installed; the message says how to install it."""


class BackendCrashError(RuntimeError):
    """A backend's worker process died or hung on an image; the message names the backend."""


class BackendError(RuntimeError):
    """A backend raised, or answered outside its contract (a plugin's wrong shape, NaN
    corners); the message, one line, names the backend. Unlike a crash it is not one frame's
    bad luck: the run of that backend stops."""


@dataclass(frozen=True)
class Backend:
    """One row of the registry: the adapter module, the families it decodes, its library."""

    name: str
    adapter: str  # module with detect(image, config, frame_side_px, pose) -> Found
    families: tuple[str, ...]
    library: str  # what it is, its licence and where it comes from
    own_pose: bool  # whether the library estimates poses itself
    isolated: bool  # run in a worker process (native code the project does not control)
    #: Searched on the whole frame, not the image circle's box, where the search is "full"
    #: (a plugin's own pose is in the frame's pixels).
    whole_frame: bool = False

    def detect(
        self,
        image: np.ndarray,
        config: DetectorConfig,
        frame_side_px: int,
        pose: PoseRequest | None = None,
    ) -> Found:
        """Run the adapter in this process (the worker process calls this)."""
        return _adapter(self.adapter).detect(image, config, frame_side_px, pose)


@cache
def _adapter(module: str):
    return importlib.import_module(module)


#: ArUco and AprilTag families by this project's names (OpenCV's, lower case, no ``DICT_``).
LOCUS_FAMILIES = ("4x4_50", "4x4_100", "6x6_250", "apriltag_16h5", "apriltag_36h11")
APRILTAG_FAMILIES = ("apriltag_16h5", "apriltag_25h9", "apriltag_36h10", "apriltag_36h11")
ARUCO_FAMILIES = tuple(n for n in dictionary_names() if not n.startswith("apriltag"))

BACKENDS: dict[str, Backend] = {
    b.name: b
    for b in (
        Backend(
            "opencv",
            "pipeline.backends.opencv",
            tuple(dictionary_names()),
            "OpenCV 5 ArucoDetector (opencv-contrib-python-headless, Apache-2.0)",
            own_pose=False,
            isolated=False,
        ),
        Backend(
            "locus",
            "pipeline.backends.locus",
            LOCUS_FAMILIES,
            "locus-tag (PyPI, MIT or Apache-2.0)",
            own_pose=True,
            isolated=True,
        ),
        Backend(
            "apriltag",
            "pipeline.backends.apriltag3",
            APRILTAG_FAMILIES + ARUCO_FAMILIES,
            "AprilTag 3 C library as bundled by apriltag-python (PyPI, BSD-2)",
            own_pose=True,
            isolated=True,
        ),
    )
}
#: How to get the peers: the optional extra of pyproject.toml.
PEERS_INSTALL = "pip install -e '.[peers]'"


#: How a plugin backend's name starts (:mod:`pipeline.backends.plugin`).
PLUGIN_PREFIX = "plugin:"


def get_backend(name: str) -> Backend:
    """The registry row, a plugin's (``plugin:SPEC``, resolved on first use: ValueError in one
    line if it cannot be), or ValueError naming the choices."""
    if name in BACKENDS:
        return BACKENDS[name]
    if isinstance(name, str) and name.startswith(PLUGIN_PREFIX):
        from pipeline.backends.plugin import plugin_backend

        return plugin_backend(name)
    raise ValueError(
        f"detector={name!r}: choose from {', '.join(BACKENDS)}, or plugin:SPEC (docs/plugins.md)"
    )


def backend_name(text: str) -> str:
    """A ``--detector`` value as a backend name: a built-in's name, or a plugin's SPEC (or
    ``plugin:SPEC``) as ``plugin:SPEC``."""
    text = text.strip()
    return text if text in BACKENDS or text.startswith(PLUGIN_PREFIX) else PLUGIN_PREFIX + text


def check_family(backend: str, family: str) -> None:
    """ValueError (one line) if ``backend`` cannot decode ``family``."""
    families = get_backend(backend).families
    if family not in families:
        raise ValueError(
            f"detector {backend} cannot detect family {family}; it detects {', '.join(families)}"
        )


def missing_library(backend: str, package: str) -> BackendUnavailableError:
    """The error for a peer whose library is not installed."""
    return BackendUnavailableError(
        f"detector {backend} needs the {package} package, not installed: {PEERS_INSTALL}"
    )


def available(backend: str) -> bool:
    """Whether the backend's library imports here (it is installed)."""
    try:
        _adapter(get_backend(backend).adapter).load()
    except BackendUnavailableError:
        return False
    return True


def require(backend: str) -> None:
    """BackendUnavailableError (its message says how to install) unless the backend can run here."""
    _adapter(get_backend(backend).adapter).load()
