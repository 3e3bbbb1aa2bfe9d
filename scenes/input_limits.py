"""Bounds on the files a user hands over, checked from a file's size and header before it is
parsed or decoded, so that a small hostile file cannot allocate gigabytes.

Every reader of a user's file takes its bound from here (docs/limits.md lists them). They live
in ``scenes``, the lowest layer that reads files, so that every layer above can import them;
:mod:`bench.cli.limits` bounds what the options ask for, these bound what the files hold.
"""

from __future__ import annotations

# --- JSON and YAML settings: camera profiles, observations, calibrations (a few kB each)
#: Largest settings file read (profile JSON, observations JSON, calibration YAML/JSON/text).
SETTINGS_BYTES = 1 << 20
#: Deepest nesting of a settings file (the shipped profiles nest 3 levels).
SETTINGS_DEPTH = 8
#: Most YAML nodes (scalars, lists, mappings) in a calibration file: a Kalibr camchain of 8
#: cameras has under 200.
YAML_NODES = 10_000
# YAML aliases (``*name``) are refused outright: no calibration format uses them, and they are
# how a few hundred bytes expand into gigabytes once walked ("billion laughs").

# --- JSON records inside run and dataset folders (manifest.json, sample.json, camera.json)
#: Largest record read: the biggest written here is 117 kB (results/indoor).
RECORD_BYTES = 64 << 20
#: Deepest nesting of a record (the deepest written here is 8).
RECORD_DEPTH = 32

# --- tables
#: Largest ground-truth CSV (``detect-images --truth``): about 100 bytes a row, a million rows.
TRUTH_CSV_BYTES = 100 << 20
#: Largest detections file read by ``score --results`` / ``compare --results``.
RESULTS_FILE_BYTES = 1 << 30

# --- images and video frames
#: Largest image or video frame (pixels): a 100 MP photograph; decoded in colour, 300 MB.
FRAME_PIXELS = 100_000_000
#: Largest side of an image or video frame (pixels), whatever the other side.
FRAME_SIDE_PX = 65_535
#: Largest image file read (bytes): an uncompressed 8-bit RGBA image of FRAME_PIXELS, plus
#: room for metadata.
IMAGE_BYTES = 4 * FRAME_PIXELS + (16 << 20)
#: Bits per sample of an image: 8 (16-bit and float images are refused, see
#: :func:`bench.common.stills.read_grey`).
IMAGE_BITS = 8
#: Most images one ``detect-images`` run reads (bounds its tables and manifest digests).
IMAGES_PER_RUN = 10_000
#: Most frames of a video (declared by its container, and counted as packets before decoding):
#: over 9 hours at 30 frames/s.
VIDEO_FRAMES = 1_000_000
