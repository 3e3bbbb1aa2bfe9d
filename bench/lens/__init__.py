"""``whiskerbench lens measure``: edge fits, PSF bins, photon transfer, JPEG quality and the
processing calibration that turn real footage into a camera profile."""
