"""Methods from outside the project in ``compare``, beside the pipelines it runs itself.

An item of ``compare --pipelines`` is one of

- a pipeline: a preset, a variant, or a detector plugin ``plugin:SPEC``
  (:mod:`pipeline.backends.plugin`): detected, timed and swept here;
- ``results:PATH``: another tool's detections (a file or folder, ``docs/results_format.md``),
  scored as ``score --detections`` does with the ``paper`` preset's stages after detection;
  its speed is the file's ``frame_time_s`` where it has them, else none (accuracy only);
- ``branch-plugin:SPEC``: a branch finder (:mod:`bench.evaluate.branch_plugin`), scored as
  ``score --branches`` does; accuracy only.

Outside methods are scored on the dataset only (the sweeps detect markers in rendered images,
which a results file or a branch finder cannot be given). :func:`prepare` reads and checks
every results file and resolves every branch finder before any work (ValueError, one line).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from bench.common.executor import TaskPool
from bench.dataset.verify import VerifiedDataset
from bench.evaluate.branch_plugin import PREFIX as BRANCH_PLUGIN
from pipeline.presets import PRESETS, PipelineConfig, get_pipeline

if TYPE_CHECKING:
    import pandas as pd

RESULTS = "results:"


@dataclass(frozen=True)
class OutsideMethod:
    """A ``results:PATH`` or ``branch-plugin:SPEC`` item: its name is the item as given."""

    name: str

    @property
    def folder_name(self) -> str:
        """Its scores' folder name: ``results:runs/mine.csv`` -> ``results:runs~mine.csv``."""
        return self.name.replace("/", "~")

    @property
    def target(self) -> str:
        """What follows the prefix: the results path or the plugin's SPEC."""
        return self.name.partition(":")[2]


Method = PipelineConfig | OutsideMethod


def parse_method(text: str) -> Method:
    """An item of ``--pipelines`` (see the module docstring); ValueError (one line) when a
    pipeline name is bad or a detector plugin cannot be resolved. Results files and branch
    finders are checked by :func:`prepare`, with the dataset."""
    if text.startswith((RESULTS, BRANCH_PLUGIN)):
        method = OutsideMethod(text)
        if not method.target:
            raise ValueError(f"{text!r}: expected {text}PATH_OR_SPEC")
        return method
    return get_pipeline(text)


def prepare(methods: list[Method], verified: VerifiedDataset) -> dict[str, object]:
    """Each outside method's validated input, by name: a results file's
    :class:`~bench.evaluate.results_file.ExternalDetections`, a branch finder's SPEC;
    ValueError (one line) on a bad file or a SPEC that cannot be resolved."""
    from bench.evaluate.branch_plugin import check
    from bench.evaluate.results_file import read_detections, sample_facts

    prepared: dict[str, object] = {}
    facts = None
    for method in methods:
        if not isinstance(method, OutsideMethod):
            continue
        if method.name.startswith(BRANCH_PLUGIN):
            prepared[method.name] = check(method.name)
            continue
        facts = facts or sample_facts(verified)
        try:
            prepared[method.name] = read_detections(Path(method.target), verified, facts)
        except ValueError as exc:
            raise ValueError(f"{method.name}: {exc}") from None
    return prepared


def score_outside(
    method: OutsideMethod,
    prepared: object,
    dataset: Path,
    verified: VerifiedDataset,
    pool: TaskPool,
) -> tuple[pd.DataFrame, float]:
    """(its ``samples.csv`` table, its frames/s: NaN without timing) of an outside method,
    written to ``<dataset>/scores/<folder name>``; BackendError when a branch finder fails."""
    from bench.evaluate.branch_plugin import run_branch_plugin
    from bench.evaluate.branches_file import score_branches
    from bench.evaluate.score import score_dataset

    out = dataset / "scores" / method.folder_name
    if method.name.startswith(BRANCH_PLUGIN):
        estimates, refused = run_branch_plugin(method.name, verified)
        table = score_branches(
            method.name, verified, estimates, method.name, out, refused, plugin=method.name
        )
        return table, float("nan")
    config = dataclasses.replace(PRESETS["paper"], name=method.name)  # stages after detection
    table = score_dataset(dataset, config, out, verified, pool=pool, external=prepared)
    scored = table.loc[table["outcome"] != "refused", "frames_per_s"].astype(float)
    return table, float(scored.mean()) if scored.notna().any() else float("nan")
