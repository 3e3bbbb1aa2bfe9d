"""Plugins: a user's own detector (or branch finder) named on the command line, run as a backend.

A plugin is a Python callable named by a SPEC (``docs/plugins.md``), one of

``package.module:function``
    imported as Python imports it, with the current folder as the last place searched
    (an installed package wins over a folder of the same name);
``path/to/file.py:function``
    the file loaded from its path (relative to the current folder), its folder searched for
    the modules it imports;
``NAME``
    an entry point ``NAME`` in the group :data:`DETECTORS` (detectors) or :data:`BRANCH_FINDERS`
    (branch finders) of an installed package's metadata.

``function`` may be dotted (``module:Class.method``). A detector plugin is the backend
``plugin:SPEC``: ``detect(image) -> [(marker_id, corners), ...]`` with ``image`` an (H, W) uint8
grey image (the frame or a crop of it) and ``corners`` (4, 2) float (x, y) pixels of that image
in ArUco order, the centre of its top-left pixel at (0, 0) (:mod:`scenes.conventions`); an item
may carry a third element, the plugin's own ``T_cam_marker`` (4, 4, mm), kept as the backend's
own pose where the image is the whole frame. It runs in a worker process, as the peers do
(:mod:`pipeline.backends.isolated`), with its own time limit (:func:`timeout_s`).

A SPEC that cannot be resolved (bad syntax, no such module, file, attribute or entry point, not
callable, an import that raises) is :class:`PluginError`, a ValueError in one line: refused at
the boundary, before any work. What the callable returns is checked on every call
(:func:`checked`); a bad answer is :class:`pipeline.backends.BackendError` naming the plugin.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import math
import os
import re
import sys
from collections.abc import Callable
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pipeline.backends import PLUGIN_PREFIX, Backend, BackendError, Found, PoseRequest
from scenes.bounded_read import input_problem
from scenes.marker import dictionary_names

if TYPE_CHECKING:
    from pipeline.detect import DetectorConfig

#: Entry point groups a package registers its plugins in.
DETECTORS = "whiskerbench.detectors"
BRANCH_FINDERS = "whiskerbench.branch_finders"
#: The environment variable that sets a detector plugin's time limit per image (s).
TIMEOUT_ENV = "WHISKERBENCH_PLUGIN_TIMEOUT_S"
DEFAULT_TIMEOUT_S = 30.0
#: Most detections a plugin may return for one image.
MAX_DETECTIONS = 10_000

_MODULE = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*")
_NAME = re.compile(r"[A-Za-z0-9_][\w.+-]*")
#: A plugin pipeline's name: ``plugin:SPEC`` then ``/CHOICE=VALUE`` parts. A file SPEC may hold
#: slashes; it ends at ``.py:function``.
_PIPELINE = re.compile(r"(?P<spec>.+?\.py:[\w.]+|[^/]+)(?P<rest>(/.*)?)", re.DOTALL)


class PluginError(ValueError):
    """A plugin SPEC that cannot be resolved; one line naming it."""


def split_name(name: str) -> tuple[str, str]:
    """``plugin:SPEC/choice=value...`` -> (``plugin:SPEC``, ``/choice=value...``)."""
    match = _PIPELINE.fullmatch(name[len(PLUGIN_PREFIX) :])
    if match is None:
        raise PluginError(f"{name!r}: expected plugin:SPEC (docs/plugins.md)")
    return PLUGIN_PREFIX + match["spec"], match["rest"]


def resolve(spec: str, group: str = DETECTORS) -> Callable:
    """The callable ``spec`` names (see the module docstring); PluginError if none."""
    return _resolve(spec, group, os.getcwd())


@cache
def _resolve(spec: str, group: str, cwd: str) -> Callable:
    where, colon, attribute = spec.rpartition(":")
    if not colon:
        target = _entry_point(spec, group)
        what = f"entry point {spec!r} ({group})"
    else:
        if not all(part.isidentifier() for part in attribute.split(".")):
            raise PluginError(
                f"plugin {spec!r}: {attribute!r} is not a function name; expected "
                "module:function or path/file.py:function"
            )
        owner = _from_file(spec, where, cwd) if where.endswith(".py") else _module(spec, where, cwd)
        target = owner
        for part in attribute.split("."):
            if not hasattr(target, part):
                raise PluginError(f"plugin {spec!r}: {where} has no attribute {attribute!r}")
            target = getattr(target, part)
        what = f"{where}:{attribute}"
    if not callable(target):
        raise PluginError(
            f"plugin {spec!r}: {what} is a {type(target).__name__}, not callable; expected a "
            "function"
        )
    return target


def _module(spec: str, module: str, cwd: str):
    if not _MODULE.fullmatch(module):
        raise PluginError(
            f"plugin {spec!r}: {module!r} is not a module name; expected module:function or "
            "path/file.py:function"
        )
    if cwd not in sys.path:
        sys.path.append(cwd)  # last: an installed package wins over a folder of its name
    try:
        return importlib.import_module(module)
    except Exception as exc:  # noqa: BLE001 - the user's code may raise anything on import
        raise PluginError(f"plugin {spec!r}: cannot import {module}: {_one_line(exc)}") from None


def _from_file(spec: str, file: str, cwd: str):
    given = Path(cwd, file)
    if not given.is_file():  # named as given: resolving a link loop would hide it
        raise PluginError(f"plugin {spec!r}: {given}: {input_problem(given) or 'no such file'}")
    path = given.resolve()
    name = "whiskerbench_plugin_" + hashlib.sha256(str(path).encode()).hexdigest()[:12]
    if name in sys.modules:
        return sys.modules[name]
    if str(path.parent) not in sys.path:
        sys.path.append(str(path.parent))  # the modules beside it
    module_spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(module_spec)
    sys.modules[name] = module
    try:
        module_spec.loader.exec_module(module)
    except Exception as exc:  # noqa: BLE001 - the user's code may raise anything on import
        del sys.modules[name]
        raise PluginError(f"plugin {spec!r}: cannot load {file}: {_one_line(exc)}") from None
    return module


def _entry_point(name: str, group: str) -> Callable:
    from importlib.metadata import entry_points

    if not _NAME.fullmatch(name):
        raise PluginError(
            f"plugin {name!r}: expected module:function, path/file.py:function or the name of "
            f"an entry point in {group}"
        )
    found = [e for e in entry_points(group=group) if e.name == name]
    if not found:
        known = sorted({e.name for e in entry_points(group=group)})
        builtin = ", built-in detectors: opencv, locus, apriltag" if group == DETECTORS else ""
        raise PluginError(
            f"plugin {name!r}: no entry point of that name in {group} (installed: "
            f"{', '.join(known) or 'none'}{builtin}); or give module:function"
        )
    if len({e.value for e in found}) > 1:
        raise PluginError(
            f"plugin {name!r}: {len(found)} packages register it in {group}; give "
            "module:function instead"
        )
    try:
        return found[0].load()
    except Exception as exc:  # noqa: BLE001 - the user's code may raise anything on import
        raise PluginError(
            f"plugin {name!r}: cannot load {found[0].value}: {_one_line(exc)}"
        ) from None


def _one_line(exc: BaseException) -> str:
    text = " ".join(f"{type(exc).__name__}: {exc}".split())
    return text if len(text) <= 300 else text[:297] + "..."


# -- the detector backend -------------------------------------------------------------------


@cache
def plugin_backend(name: str) -> Backend:
    """The registry row of the backend ``plugin:SPEC``; PluginError if SPEC cannot be resolved
    (resolved here, in the asking process: refused before any work)."""
    spec = name[len(PLUGIN_PREFIX) :]
    if not spec or name != split_name(name)[0]:
        raise PluginError(f"{name!r}: expected plugin:SPEC (docs/plugins.md)")
    resolve(spec, DETECTORS)
    return Backend(
        name,
        "pipeline.backends.plugin",
        tuple(dictionary_names()),  # the callable is told no family: it reads what it reads
        f"plugin {spec}",
        own_pose=True,
        isolated=True,
        whole_frame=True,
    )


def load() -> None:
    """A plugin is resolved when its row is built (:func:`plugin_backend`): nothing to do."""


#: A plugin's worker runs on one core, as the project's pipelines are timed (``compare``
#: measures single-core speed): the thread pools of the common numeric libraries, one thread.
ONE_THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def one_thread() -> None:
    """OpenCV on one thread in a plugin's worker, before the plugin loads (it may change it)."""
    import cv2

    cv2.setNumThreads(1)


def timeout_s() -> float:
    """A detector plugin's time limit per image (s): :data:`TIMEOUT_ENV`, else
    :data:`DEFAULT_TIMEOUT_S`; BackendError on a value that is not a number > 0."""
    text = os.environ.get(TIMEOUT_ENV)
    if text is None:
        return DEFAULT_TIMEOUT_S
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise BackendError(f"{TIMEOUT_ENV}={text!r}: expected seconds, a number > 0")
    return value


def detect(
    image: np.ndarray, config: DetectorConfig, frame_side_px: int, pose: PoseRequest | None
) -> Found:
    """The plugin's answer on ``image``, checked (:func:`checked`); BackendError if it raises."""
    function = resolve(config.backend[len(PLUGIN_PREFIX) :], DETECTORS)
    try:
        answer = function(image)
    except Exception as exc:  # noqa: BLE001 - the plugin's own failure, reported by name
        raise BackendError(
            f"{config.backend} raised {_one_line(exc)} on a {image.shape[1]}x{image.shape[0]} image"
        ) from None
    return checked(answer, config.backend, pose is not None and pose.whole_frame)


def checked(answer, name: str, keep_pose: bool) -> Found:
    """A plugin's answer as a :class:`Found`, or BackendError naming what is wrong: a list of
    (marker_id, corners (4, 2)[, T_cam_marker (4, 4)]) with an integer id >= 0 and finite
    values. Its poses are kept only with ``keep_pose``."""

    def bad(k: int | None, what: str) -> BackendError:
        where = "" if k is None else f" detection {k}:"
        return BackendError(
            f"{name} returned{where} {what}; expected a list of (marker_id, corners (4, 2)) "
            "or (marker_id, corners, T_cam_marker (4, 4)) (docs/plugins.md)"
        )

    if isinstance(answer, str | bytes | np.ndarray | dict) or not hasattr(answer, "__iter__"):
        raise bad(None, f"a {type(answer).__name__}")
    items = list(answer)
    if len(items) > MAX_DETECTIONS:
        raise bad(None, f"{len(items)} detections, more than {MAX_DETECTIONS}")
    ids, corners, poses = [], [], []
    for k, item in enumerate(items):
        if not isinstance(item, tuple | list) or len(item) not in (2, 3):
            raise bad(
                k,
                f"a {type(item).__name__}"
                + (f" of {len(item)}" if hasattr(item, "__len__") else ""),
            )
        marker_id = item[0]
        if isinstance(marker_id, bool) or not isinstance(marker_id, int | np.integer):
            raise bad(k, f"marker_id {marker_id!r}, not an integer")
        if marker_id < 0:
            raise bad(k, f"marker_id {marker_id}, negative")
        quad = _array(item[1], (4, 2), k, "corners", bad)
        ids.append(int(marker_id))
        corners.append(quad)
        if len(item) == 3:
            poses.append(_array(item[2], (4, 4), k, "T_cam_marker", bad))
    own = None
    if keep_pose and poses and len(poses) == len(ids):
        own = np.array(poses)
    return Found(np.array(ids, dtype=int), np.array(corners, dtype=float).reshape(-1, 4, 2), own)


def _array(value, shape: tuple[int, ...], k: int, what: str, bad) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise bad(k, f"{what} that are not numbers") from None
    if array.shape != shape:
        raise bad(k, f"{what} of shape {array.shape}, not {shape}")
    if not np.isfinite(array).all():
        raise bad(k, f"{what} with NaN or infinite values")
    return array
