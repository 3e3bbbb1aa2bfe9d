"""The measured numbers written into a camera profile, each with its ``sources`` entry.

Every replaced section drops the input's stale source entries for it and gains one that names
the footage, the date and what was measured (the profile format's rule: every number carries
its source).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from scenes.profile import CHROMA_SUBSAMPLING, CameraProfile, PsfTable


def _without(sources: dict[str, str], section: str) -> dict[str, str]:
    return {k: v for k, v in sources.items() if k != section and not k.startswith(section + ".")}


def with_stream(profile: CameraProfile, stream: dict, stem: str) -> CameraProfile:
    """MJPEG quality and chroma subsampling from a stream report (unchanged without JPEG)."""
    if stream.get("codec") != "mjpeg":
        return profile
    subsampling = stream["chroma_subsampling"]
    known = subsampling in CHROMA_SUBSAMPLING
    sources = _without(profile.sources, "stream")
    sources["stream"] = (
        f"{stem}: DQT luma table of the first JPEG frame matches IJG quality "
        f"{stream['quality']} (mean abs error {stream['luma_match_mean_abs_error']:.2f}); "
        + (
            f"chroma {subsampling} from SOF"
            if known
            else f"chroma {subsampling} in SOF is not a profile option: kept "
            f"{profile.stream.chroma_subsampling}"
        )
    )
    new_stream = dataclasses.replace(
        profile.stream,
        codec="mjpeg",
        quality=stream["quality"],
        chroma_subsampling=subsampling if known else profile.stream.chroma_subsampling,
    )
    return dataclasses.replace(profile, stream=new_stream, sources=sources)


def with_psf(profile: CameraProfile, report: dict, solved: list[dict], stem: str) -> CameraProfile:
    """The PSF table from the solved field bins (their mean field angles, in order)."""
    psf = PsfTable(
        theta_deg=tuple(b["theta_mean_deg"] for b in solved),
        sigma_radial_px=tuple(b["sigma_radial_px"] for b in solved),
        sigma_tangential_px=tuple(b["sigma_tangential_px"] for b in solved),
    )
    flagged = [
        f"{b['theta_mean_deg']:.0f} deg {b['mode']}" for b in solved if b["mode"] != "anisotropic"
    ]
    calibrated = "note" not in report["processing_calibration"]
    sources = _without(profile.sources, "psf")
    sources["psf"] = (
        f"{stem}: {report['edges_used']} marker edges in {report['frames_read']} frames "
        f"({report['markers_found']} markers), edge-spread fits, {len(solved)} field bins of "
        f"{report['settings']['bin_deg']:g} deg"
        + (
            "; less the blur the camera's processing adds, probed through the twin"
            if calibrated
            else ""
        )
        + (f"; flagged: {', '.join(flagged)}" if flagged else "")
    )
    return dataclasses.replace(profile, psf=psf, sources=sources)


def with_noise(profile: CameraProfile, noise: dict, stem: str, jpeg: bool) -> CameraProfile:
    """Full well and read noise from a photon-transfer fit (unchanged without one); ``jpeg``:
    the frames were JPEG-compressed."""
    if "full_well_e" not in noise:
        return profile
    sensor = dataclasses.replace(
        profile.sensor,
        full_well_e=float(np.clip(noise["full_well_e"], 1.0, 1e7)),
        read_noise_e=float(np.clip(noise["read_noise_e"], 0.0, 1e4)),
    )
    sources = dict(profile.sources)
    for key in ("full_well_e", "read_noise_e"):
        sources[f"sensor.{key}"] = (
            f"{stem}: photon transfer over {sum(noise['runs_frames'])} still frames, relative "
            f"rms residual {noise['relative_rms_residual']:.3f}"
            + ("; through JPEG compression, which removes noise" if jpeg else "")
        )
    return dataclasses.replace(profile, sensor=sensor, sources=sources)
