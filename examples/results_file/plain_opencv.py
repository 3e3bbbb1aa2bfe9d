"""Another tool's results file: OpenCV's ArUco detector at its defaults on a whiskerbench
dataset, read with the loader, written in the documented detections format
(docs/results_format.md). No whiskerbench code but the loader.

    python examples/results_file/plain_opencv.py data/quick plain.csv
    whiskerbench score data/quick --detections plain.csv --name plain-opencv
"""

import sys
import time

import cv2
import pandas as pd

from whiskerbench import open_dataset


def main(dataset: str, out: str) -> None:
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    detector = cv2.aruco.ArucoDetector(dictionary)
    rows = []
    for sample in open_dataset(dataset):
        for frame in sample.frames():
            start = time.perf_counter()
            corners, ids, _ = detector.detectMarkers(frame.image)
            spent = time.perf_counter() - start  # the file's own timing: frames/s when scored
            for marker_id, quad in zip([] if ids is None else ids.ravel(), corners, strict=True):
                row = {"sample_id": sample.id, "frame": frame.index, "marker_id": int(marker_id)}
                for k, (x, y) in enumerate(quad.reshape(4, 2)):
                    row[f"c{k}_x_px"], row[f"c{k}_y_px"] = float(x), float(y)
                rows.append({**row, "frame_time_s": spent})
    pd.DataFrame(rows).to_csv(out, index=False)


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit("usage: plain_opencv.py DATASET OUT.csv")
    main(sys.argv[1], sys.argv[2])
