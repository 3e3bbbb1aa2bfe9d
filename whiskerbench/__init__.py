"""whiskerbench's public API: one import for what the ``whiskerbench`` command does.

The work stays where it is (``scenes`` -> ``renderers`` -> ``pipeline`` -> ``bench``); this package
only names it. Each name is imported from its home on first use (PEP 562 ``__getattr__``), so
``import whiskerbench`` loads no Mitsuba, Dr.Jit, OpenCV or pandas: a script that only reads a
profile or scores a dataset never pays for the renderer, and a function that renders selects the
Mitsuba variant itself when it is called, before Dr.Jit is first imported. docs/api.md says what
each name does, with an example.
"""

from __future__ import annotations

import importlib

#: Public name -> ``"module:attribute"`` of its home, in the order docs/api.md lists them: the one
#: table that ``__getattr__``, ``__all__``, ``__dir__`` and the API docs' test follow.
_API = {
    # The camera twin: lens models, profiles, the prototype's record, calibration against it.
    "FisheyeCamera": "scenes.camera:FisheyeCamera",
    "CameraProfile": "scenes.profile:CameraProfile",
    "load_profile": "scenes.profile:load_profile",
    "shipped_profiles": "scenes.profile:shipped_profiles",
    "load_observations": "scenes.observations:load_observations",
    "run_calibration": "bench.twin.run:run_calibration",
    # The marker detectability study.
    "StudyConfig": "bench.study.config:StudyConfig",
    "run_study": "bench.study.run:run_study",
    # Benchmark datasets: generate (one sample is a grid of one cell), open.
    "DatasetConfig": "bench.dataset.config:DatasetConfig",
    "run_dataset": "bench.dataset.generate:run_dataset",
    "open_dataset": "bench.dataset.loader:open_dataset",
    # Detection and branch-finding pipelines: detect, score, compare.
    "DetectorConfig": "pipeline.detect:DetectorConfig",
    "detect_markers": "pipeline.detect:detect_markers",
    "PipelineConfig": "pipeline.presets:PipelineConfig",
    "PRESETS": "pipeline.presets:PRESETS",
    "get_pipeline": "pipeline.presets:get_pipeline",
    "run_detect": "bench.evaluate.detect:run_detect",
    "score_dataset": "bench.evaluate.score:score_dataset",
    "run_compare": "bench.evaluate.compare:run_compare",
}

__all__ = list(_API)


def __getattr__(name: str):
    """Import a public name from its home on first access and keep it here for the next."""
    try:
        module, _, attribute = _API[name].partition(":")
    except KeyError:
        raise AttributeError(f"module 'whiskerbench' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module), attribute)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    """The public names beside the module's own, so completion offers them before first use."""
    return sorted(set(globals()) | set(__all__))
