"""Branch-finder plugins: a user's whole branch pipeline, each sample in a process of its own.

A branch finder (``docs/plugins.md``) is ``find_branches(frames, camera, meta) -> [(i, i + 1),
...]``: ``frames`` an iterator over the sample's frames ((H, W) uint8 grey, in order), ``camera``
its :class:`scenes.camera.FisheyeCamera`, ``meta`` what the method may know of the sample
(:func:`sample_meta`: its id, frame count and rate, the array; not its truth). It answers the
gaps between whiskers i and i + 1 that it believes hold a branch, as ``score --branches`` reads
them (``docs/results_format.md``); an empty list: no branch. It is named ``branch-plugin:SPEC``
(SPEC as a detector plugin's, :mod:`pipeline.backends.plugin`, entry points in
``whiskerbench.branch_finders``).

Each sample runs in a fresh ``python -m bench.evaluate.branch_plugin`` child that decodes the
video itself: a crash (a signal) or a hang past the limit (:func:`sample_limit_s`) costs that
sample, scored ``refused`` with the reason (its prints go to stderr);
:data:`MAX_STRAIGHT_FAILURES` in a row stop the plugin. A plugin that raises or answers outside
the format is :class:`pipeline.backends.BackendError` naming it: its run stops (``compare``
goes on with the other methods).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from bench.dataset.verify import VerifiedDataset
from pipeline.backends import BackendError
from pipeline.backends.plugin import BRANCH_FINDERS, resolve, timeout_s
from scenes.array import ArraySpec

PREFIX = "branch-plugin:"
MAX_STRAIGHT_FAILURES = 3
_ROOT = Path(__file__).resolve().parents[2]  # the project, for the child's imports


def check(name: str) -> str:
    """The SPEC of ``branch-plugin:SPEC``, resolved here; PluginError (a ValueError, one line)
    if it cannot be: refused before any work."""
    spec = name[len(PREFIX) :]
    resolve(spec, BRANCH_FINDERS)
    return spec


def sample_meta(record: dict) -> dict:
    """What a branch finder is told of a sample (its ``sample.json`` less the truth)."""
    array = record.get("array") or ArraySpec().to_json()
    return {
        "sample_id": record["sample_id"],
        "frames": int(record["frames"]),
        "fps": float(record["protocol"]["fps"]),
        "array": {**array, "n_whiskers": len(array["marker_ids"])},
    }


def sample_limit_s(frames: int) -> float:
    """The longest a branch finder may take on a sample: the plugin limit per image
    (:func:`pipeline.backends.plugin.timeout_s`) per frame."""
    return timeout_s() * max(frames, 1)


def run_branch_plugin(
    name: str, verified: VerifiedDataset
) -> tuple[dict[str, list[list[int]]], dict[str, str]]:
    """(estimated gaps per sample, why each refused sample was refused) of the plugin ``name``
    on every sample; BackendError when it raises, answers outside the format or fails
    :data:`MAX_STRAIGHT_FAILURES` samples in a row."""
    spec = check(name)
    estimates, refused = {}, {}
    straight = 0
    for sample_id, record in sorted(verified.records.items()):
        folder = verified.folder / sample_id
        outcome = _run_sample(spec, name, folder, sample_meta(record))
        if isinstance(outcome, str):
            refused[sample_id] = outcome
            straight += 1
            if straight >= MAX_STRAIGHT_FAILURES:
                raise BackendError(f"{name}: {outcome}; {straight} samples in a row: stopped")
            continue
        straight = 0
        estimates[sample_id] = outcome
    return estimates, refused


def _run_sample(spec: str, name: str, folder: Path, meta: dict) -> list[list[int]] | str:
    """The sample's gaps, or why the child gave none (a crash or a hang: the sample's loss)."""
    limit = sample_limit_s(meta["frames"])
    path = os.pathsep.join(filter(None, [str(_ROOT), os.environ.get("PYTHONPATH")]))
    with tempfile.TemporaryDirectory() as tmp:
        answer = Path(tmp) / "answer.json"
        argv = [sys.executable, "-m", "bench.evaluate.branch_plugin", spec, str(folder),
                json.dumps(meta), str(answer)]  # fmt: skip
        try:
            done = subprocess.run(
                argv, env=dict(os.environ, PYTHONPATH=path), stdin=subprocess.DEVNULL,
                stdout=2, timeout=limit, check=False,
            )  # fmt: skip
        except subprocess.TimeoutExpired:
            return f"{name} did not answer within {limit:g} s; its process was stopped"
        if not answer.is_file():
            code = done.returncode
            how = f"signal {-code}" if code < 0 else f"exit status {code}"
            return f"{name} crashed ({how})"
        status, value = json.loads(answer.read_text())
    if status != "ok":
        raise BackendError(f"{name} on {meta['sample_id']}: {value}")
    return value


def checked_gaps(answer, n_whiskers: int) -> list[list[int]]:
    """A branch finder's answer as sorted gaps [[i, i + 1], ...]; ValueError saying what is
    wrong (not a list of (i, i + 1) pairs of whisker indices, a gap twice)."""
    want = f"expected a list of (i, i + 1) gaps, i in 0..{n_whiskers - 2}"
    if isinstance(answer, str | bytes | dict) or not hasattr(answer, "__iter__"):
        raise ValueError(f"returned a {type(answer).__name__}; {want}")
    gaps = []
    for k, gap in enumerate(answer):
        try:
            left, right = (int(v) if float(v) == int(v) else None for v in gap)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"returned gap {k}: {gap!r}; {want}") from None
        if left is None or right != left + 1 or not 0 <= left <= n_whiskers - 2:
            raise ValueError(f"returned gap {k}: {gap!r}; {want}")
        if [left, right] in gaps:
            raise ValueError(f"returned gap {k}: {gap!r} twice; {want}, each once")
        gaps.append([left, right])
    return sorted(gaps)


def _child(spec: str, folder: Path, meta: dict, answer: Path) -> None:
    """The child: resolve, run on the sample's frames, write ``[status, value]`` to ``answer``."""
    from bench.common.video import read_video
    from scenes.profile import load_profile

    try:
        function = resolve(spec, BRANCH_FINDERS)
        camera = load_profile(folder / "camera.json").lens
        try:
            result = function(read_video(folder / "video.mp4"), camera, meta)
        except Exception as exc:  # noqa: BLE001 - the plugin's own failure, reported by name
            what = " ".join(f"{type(exc).__name__}: {exc}".split())
            raise ValueError(f"raised {what}") from None
        value = ["ok", checked_gaps(result, meta["array"]["n_whiskers"])]
    except ValueError as exc:
        value = ["failed", " ".join(str(exc).split())[:400]]
    answer.write_text(json.dumps(value))


if __name__ == "__main__":
    _child(sys.argv[1], Path(sys.argv[2]), json.loads(sys.argv[3]), Path(sys.argv[4]))
