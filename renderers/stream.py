"""How frames leave the camera: MJPEG (or raw), and the grey image the detector sees.

A colour frame is JPEG-encoded as the camera's USB bridge would (IJG quality, the profile's chroma
subsampling) and decoded to grey: OpenCV's ``IMREAD_GRAYSCALE`` decodes only the luma (Y), whose
8 x 8 blocks depend on nothing outside themselves. The encoder's block grid starts at the frame's
top-left pixel, so a crop reproduces the full frame's decode bit for bit if it starts on that
grid and its last block column and row are whole (the encoder pads a partial block by repeating
the crop's edge, which the full frame does not). The luma alone needs only the 8-px grid; the
stage asks for the MCU grid, ``Stream.block_px`` (16 px for 4:2:2 and 4:2:0), so that a colour
decode would match as well. Without MJPEG the grey image is OpenCV's RGB -> grey conversion,
with the same Rec. 601 weights as JPEG's Y.
"""

from __future__ import annotations

import cv2
import numpy as np

from scenes.profile import Stream

SAMPLING_FACTORS = {
    "4:4:4": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444,
    "4:2:2": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_422,
    "4:2:0": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420,
}


def check_block_grid(origin_px: tuple[int, int], stream: Stream) -> None:
    """ValueError unless a crop at ``origin_px`` starts on the stream's block grid."""
    block = stream.block_px
    if origin_px[0] % block or origin_px[1] % block:
        raise ValueError(
            f"origin_px={tuple(origin_px)}: an MJPEG crop must start on the frame's "
            f"{block}-px block grid ({stream.chroma_subsampling}); round x0 and y0 down to "
            f"multiples of {block}"
        )


def encode_frame(bgr_u8: np.ndarray, stream: Stream) -> bytes:
    """The JPEG bytes of one frame: (H, W, 3) BGR or (H, W) grey uint8, at the stream's quality
    and (for colour) chroma subsampling."""
    image = np.asarray(bgr_u8)
    if image.dtype != np.uint8 or image.ndim not in (2, 3):
        raise ValueError(f"frame: {image.dtype} {image.shape}; expected (H, W[, 3]) uint8")
    params = [cv2.IMWRITE_JPEG_QUALITY, int(stream.quality)]
    if image.ndim == 3:
        params += [cv2.IMWRITE_JPEG_SAMPLING_FACTOR, SAMPLING_FACTORS[stream.chroma_subsampling]]
    ok, buf = cv2.imencode(".jpg", image, params)
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()


def decode_grey(jpeg: bytes) -> np.ndarray:
    """The luma of a JPEG frame, (H, W) uint8."""
    image = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise ValueError("not a decodable JPEG frame")
    return image


def grey_images(
    images: np.ndarray, stream: Stream, origin_px: tuple[int, int] = (0, 0), mjpeg: bool = True
) -> np.ndarray:
    """What the detector sees: (N, H, W) uint8 from (N, H, W, 3) RGB or (N, H, W) grey uint8.

    With ``mjpeg`` and an MJPEG stream each frame goes through :func:`encode_frame` and
    :func:`decode_grey`; a crop not on the block grid raises ValueError.
    """
    colour = images.ndim == 4
    if mjpeg and stream.codec == "mjpeg":
        check_block_grid(origin_px, stream)
        frames = images[..., ::-1] if colour else images  # RGB -> BGR for the encoder
        return np.stack(
            [decode_grey(encode_frame(np.ascontiguousarray(f), stream)) for f in frames]
        )
    if not colour:
        return images
    n, height, width, _ = images.shape
    rows = np.ascontiguousarray(images.reshape(n * height, width, 3))
    return cv2.cvtColor(rows, cv2.COLOR_RGB2GRAY).reshape(n, height, width)
