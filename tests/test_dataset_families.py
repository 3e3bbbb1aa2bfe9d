"""``whiskerbench dataset --family``: the array's markers printed in another family, found where
the labels say by a detector of that family; the settings follow the family."""

from __future__ import annotations

import numpy as np
import pytest
from test_dataset import SMALL

from bench.cli.dataset import dataset_config
from bench.cli.main import _parser
from bench.dataset.config import DatasetConfig, DatasetConfigError, array_of_family
from bench.dataset.labels import corners_of_frame
from pipeline.backends import available
from pipeline.detect import DetectorConfig, detect_markers
from scenes.array import ArraySpec


@pytest.mark.slow  # one full frame: about 5 s
def test_an_apriltag_array_is_found_where_the_labels_say(variant):
    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    from bench.dataset.sample import sample_recorder, simulate_sample

    config = DatasetConfig(**{**SMALL, "array": array_of_family("apriltag_36h11")})
    sample = config.samples()[0]
    sim = simulate_sample(config, sample)
    frame = sample_recorder(config, sample, sim).frame(0)
    corners, ids, _ = corners_of_frame(sim.labels, 0)
    detectors = [DetectorConfig("apriltag_36h11", "lines")]
    if available("locus"):
        detectors.append(DetectorConfig("apriltag_36h11", "none", backend="locus"))
    for detector in detectors:
        got = {
            d.marker_id: d.corners_px
            for d in detect_markers(frame, detector, camera=config.camera.lens)
        }
        assert sorted(got) == sorted(ids.tolist()), detector.backend
        errors = [np.linalg.norm(got[m] - corners[i], axis=1) for i, m in enumerate(ids)]
        assert np.median(np.concatenate(errors)) < 0.5, detector.backend
    assert not detect_markers(frame, DetectorConfig("4x4_50"))  # printed in 36h11, not 4x4


def test_the_family_is_the_arrays_and_in_the_settings():
    args = _parser().parse_args(["dataset", "--quick", "--family", "APRILTAG_16h5"])
    config = dataset_config(args)
    assert config.array.dictionary == "apriltag_16h5"
    assert config.to_json()["array"]["dictionary"] == "apriltag_16h5"
    plain = dataset_config(_parser().parse_args(["dataset", "--quick"]))
    same = dataset_config(_parser().parse_args(["dataset", "--quick", "--family", "4x4_50"]))
    assert same.settings_hash() == plain.settings_hash() != config.settings_hash()
    assert same.array == ArraySpec()


def test_a_family_without_the_arrays_ids_is_refused():
    array = ArraySpec(marker_ids=tuple(range(20, 33)))  # apriltag_16h5 has ids 0..29
    with pytest.raises(DatasetConfigError, match="ids 0..29") as info:
        array_of_family("apriltag_16h5", array)
    assert info.value.field == "family"
    assert array_of_family("apriltag_36h11", array).marker_ids == array.marker_ids
