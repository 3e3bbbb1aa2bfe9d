"""The camera twin held to the real sensor: observations checked against trial profiles
(:mod:`bench.twin.evidence`) and the estimates calibrated to them (:mod:`bench.twin.calibrate`)."""
